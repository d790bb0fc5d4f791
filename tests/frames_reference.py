"""The plain frame merger (what vsfleet.frames.FrameMerger was before its fast paths); tests only.

The same rule (vsfleet/frames.py's docstring), written as one loop over the robots of every frame:
tests/test_frames.py runs random streams of frames from several sources through both and asks the
same frames, bit for bit, and the same counts.
"""

from __future__ import annotations

from vsfleet.frames import Frame
from vsfleet.wire import FrameMsg


class FrameMerger:
    """The freshest pose per robot across sources, and the rule for when a frame runs."""

    MAX_SOURCES = 16

    def __init__(self, robots: tuple[str, ...] = (), deadline_s: float = 0.02, max_age_s: float = 0.25,
                 max_future_s: float = 1.0) -> None:
        self.robots = tuple(robots)
        self.known = frozenset(robots)
        self.deadline_s = deadline_s
        self.max_age_s = max_age_s
        self.max_future_s = max_future_s
        self.held: dict[str, tuple[float, int, str, tuple[float, float, float]]] = {}
        self.heard: dict[str, float] = {}       # source -> t of its newest frame
        self.pending: FrameMsg | None = None
        self.deadline_at: float | None = None
        self.done: tuple[float, int] = (float("-inf"), -1)
        self.dropped_old = 0      # poses older than the one held
        self.refused_sources = 0  # frames from a source beyond MAX_SOURCES
        self.refused_future = 0   # frames stamped more than max_future_s ahead of the local clock
        self.ignored = 0          # poses of objects that no mission names (not an error)
        self.shadowed = 0         # poses of a robot that a source first in sort order also sees
        self.listed: dict[tuple[str, str], float] = {}   # (source, robot) -> t of its newest frame listing it

    def set_robots(self, robots: tuple[str, ...], known: tuple[str, ...] | None = None) -> None:
        """The robots a frame must list (the newest mission's), and every robot whose pose is kept."""
        self.robots = tuple(robots)
        self.known = frozenset(robots if known is None else known)
        self.held = {r: h for r, h in self.held.items() if r in self.known}
        self.listed = {k: t for k, t in self.listed.items() if k[1] in self.known}

    def offer(self, msg: FrameMsg, now: float) -> bool:
        """Take a frame's poses; False if it is refused or no newer than the last frame run."""
        if msg.t > now + self.max_future_s:
            self.refused_future += 1
            return False
        if msg.src not in self.heard and len(self.heard) >= self.MAX_SOURCES:
            self.heard = {s: t for s, t in self.heard.items() if t >= msg.t - self.max_age_s}
            self.listed = {k: t for k, t in self.listed.items() if k[0] in self.heard}
            if len(self.heard) >= self.MAX_SOURCES:
                self.refused_sources += 1
                return False
        key = (msg.t, msg.seq)
        oldest = msg.t - self.max_age_s
        taken = 0
        for robot, pose in msg.poses.items():
            if robot not in self.known:
                self.ignored += 1
                continue
            self.listed[(msg.src, robot)] = max(msg.t, self.listed.get((msg.src, robot), float("-inf")))
            if any(src < msg.src and self.listed.get((src, robot), float("-inf")) >= oldest for src in self.heard):
                self.shadowed += 1   # a source first in sort order sees this robot: its pose is the one taken
                continue
            taken += 1
            held = self.held.get(robot)
            if held is not None and key <= (held[0], held[1]):
                self.dropped_old += 1
                continue
            self.held[robot] = (msg.t, msg.seq, msg.src, pose)
        if taken == 0 and any(r in self.known for r in msg.poses):
            return False             # every pose shadowed: this source is not the one followed
        self.heard[msg.src] = max(msg.t, self.heard.get(msg.src, float("-inf")))
        if key <= self.done:
            return False
        if self.pending is None or key > (self.pending.t, self.pending.seq):
            if self.pending is None:
                self.deadline_at = now + self.deadline_s
            self.pending = msg
        return True

    def time_to_deadline(self, now: float) -> float | None:
        return None if self.deadline_at is None else max(0.0, self.deadline_at - now)

    def ready(self, now: float) -> Frame | None:
        """The frame to run now, if any."""
        msg = self.pending
        if msg is None or not self.robots:
            return None
        listed = self._instant(msg)
        alone = all(s == msg.src or t < msg.t - self.max_age_s for s, t in self.heard.items())
        if not (listed or alone) and self.deadline_at is not None and now < self.deadline_at:
            return None
        self.pending, self.deadline_at = None, None
        self.done = (msg.t, msg.seq)
        oldest = msg.t - self.max_age_s
        poses, fresh, sources = {}, [], set()
        for r in self.robots:
            held = self.held.get(r)
            if held is None or held[0] < oldest:
                continue
            poses[r] = held[3]
            sources.add(held[2])
            if self._of_instant(held, msg):
                fresh.append(r)
        return Frame(seq=msg.seq, t=msg.t, poses=poses, complete=listed, fresh=frozenset(fresh), src=msg.src,
                     sources=frozenset(sources))

    def _of_instant(self, held: tuple[float, int, str, tuple[float, float, float]], msg: FrameMsg) -> bool:
        """A held pose is of msg's instant if msg itself brought it, or another source's frame at most
        half the deadline older did. Never a pose held over from an earlier frame of msg's own source:
        one source's frames are distinct instants, and which of them an agent got (a newer frame
        replaces one not yet run) differs between agents, so such a pose would make copies disagree."""
        if held[2] == msg.src:
            return held[0] == msg.t and held[1] == msg.seq
        return held[0] >= msg.t - 0.5 * self.deadline_s

    def _instant(self, msg: FrameMsg) -> bool:
        """Every robot has a pose of msg's instant (_of_instant)."""
        held = self.held
        return all(r in held and self._of_instant(held[r], msg) for r in self.robots)
