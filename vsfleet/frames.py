"""Merging tracker frames and choosing the active mission: pure, the clock is passed in.

Frame rule (docs/protocol.md, "Frames"):
- Every source publishes one message per frame on ``vs/<fleet>/frame/<src>``.
  Each robot's freshest pose, by ``(t, seq)``, is held, whichever source it
  came from; an older or equal pose is dropped (counted).
- A frame is run when it arrives if every mission robot has a pose of its
  instant (listed in the frame itself, or in another source's frame at most
  half of ``deadline_s`` older; then the frame is "complete"), or if its source
  is the only one heard from within ``max_age_s``. A pose held over from an
  earlier frame of the same source is never of the instant.
  Otherwise the agent waits ``deadline_s`` (for the other cameras' frames of
  the same instant), then runs the newest frame with the freshest poses held.
- A frame runs with each robot's freshest pose, left out if it is older than
  ``max_age_s`` before the frame's ``t``. A mission robot with no such pose is
  missing: left out of the fit, still bounding the advance; an agent whose own
  robot is missing commands it to stop.
- A frame whose ``t`` is more than ``max_future_s`` ahead of the local clock is
  refused (counted): a skewed tracker must not block the frames after it.
- Two sources that see the same robot (two trackers of one fleet, or two cameras
  whose views overlap): the robot's pose is taken from the source whose name is
  first in sort order among those that listed it within ``max_age_s`` before
  the frame; the other source's pose of it is shadowed (counted), and a frame
  whose every pose is shadowed is not run. So every agent follows the same
  source whatever order the two sources' frames reach it in, and the copies
  agree; the other takes over ``max_age_s`` after the first falls silent.
- A frame runs at most once, and never one older (by ``(t, seq)``) than the
  last frame run; so a tracker that restarts its ``seq`` is followed at once.
"""

from __future__ import annotations

from dataclasses import dataclass

from .wire import FrameMsg, Mission


@dataclass(frozen=True)
class Frame:
    """Merged poses (x, y, th) [m, rad; world] for frame ``seq`` of ``src`` at tracker time ``t`` [s].

    fresh: the robots whose pose is of this frame's instant: listed in it, or in another source's
    frame at most half the deadline older (the failure rule's motion test takes only those, never a
    pose held over from an earlier frame of the same source); complete: every robot asked for is fresh.
    """

    seq: int
    t: float
    poses: dict[str, tuple[float, float, float]]
    complete: bool
    fresh: frozenset[str] = frozenset()
    src: str = ""
    sources: frozenset[str] = frozenset()   # the sources whose poses this frame runs with


#: [s] a pose older than this before a frame's t is left out, and a source silent this long is no longer heard
#: (the other takes over): FrameMerger's default, the agent's (agent.main.Agent) and agentcore's
MAX_AGE_S = 0.25


class FrameMerger:
    """The freshest pose per robot across sources, and the rule for when a frame runs.

    The common case, one source whose frames list every mission robot, costs no Python loop over the
    robots: a frame's poses are taken with dict updates, and a frame whose every robot's pose came with it
    is recognised by one count. The other cases take the same rule robot by robot (tests/test_frames.py
    holds both to tests/frames_reference.py, the plain one-loop merger, bit for bit).
    """

    MAX_SOURCES = 16

    def __init__(self, robots: tuple[str, ...] = (), deadline_s: float = 0.02, max_age_s: float = MAX_AGE_S,
                 max_future_s: float = 1.0) -> None:
        self.deadline_s = deadline_s
        self.max_age_s = max_age_s
        self.max_future_s = max_future_s
        # robot -> (t, seq, src) of the frame its held pose came from (one tuple shared by that frame's robots)
        self.held: dict[str, tuple[float, int, str]] = {}
        self.held_pose: dict[str, tuple[float, float, float]] = {}   # robot -> its held pose
        self.newest_held: tuple[float, int] = (float("-inf"), -1)   # >= every held (t, seq)
        self.heard: dict[str, float] = {}       # source -> t of its newest frame
        self.pending: FrameMsg | None = None
        self.deadline_at: float | None = None
        self.done: tuple[float, int] = (float("-inf"), -1)
        self.dropped_old = 0      # poses older than the one held
        self.refused_sources = 0  # frames from a source beyond MAX_SOURCES
        self.refused_future = 0   # frames stamped more than max_future_s ahead of the local clock
        self.ignored = 0          # poses of objects that no mission names (not an error)
        self.shadowed = 0         # poses of a robot that a source first in sort order also sees
        self.listed: dict[str, dict[str, float]] = {}   # source -> robot -> t of its newest frame listing it
        self.listed_newest: dict[str, float] = {}        # source -> >= every t in listed[source]
        self.set_robots(tuple(robots))

    def set_robots(self, robots: tuple[str, ...], known: tuple[str, ...] | None = None) -> None:
        """The robots a frame must list (the newest mission's), and every robot whose pose is kept."""
        self.robots = tuple(robots)
        self.robot_set = frozenset(self.robots)
        self.known = frozenset(robots if known is None else known)
        self.held = {r: h for r, h in self.held.items() if r in self.known}
        self.held_pose = {r: p for r, p in self.held_pose.items() if r in self.known}
        self.listed = {s: {r: t for r, t in by.items() if r in self.known} for s, by in self.listed.items()}

    def offer(self, msg: FrameMsg, now: float) -> bool:
        """Take a frame's poses; False if it is refused or no newer than the last frame run."""
        if msg.t > now + self.max_future_s:
            self.refused_future += 1
            return False
        src = msg.src
        if src not in self.heard and len(self.heard) >= self.MAX_SOURCES:
            self.heard = {s: t for s, t in self.heard.items() if t >= msg.t - self.max_age_s}
            self.listed = {s: by for s, by in self.listed.items() if s in self.heard}
            self.listed_newest = {s: t for s, t in self.listed_newest.items() if s in self.heard}
            if len(self.heard) >= self.MAX_SOURCES:
                self.refused_sources += 1
                return False
        key = (msg.t, msg.seq)
        poses = msg.poses
        # the robots some mission names (all of them, usually)
        robots = poses if poses.keys() <= self.known else [r for r in poses if r in self.known]
        self.ignored += len(poses) - len(robots)
        # which robots this source lists, and when last
        listed = self.listed.get(src)
        if listed is None:
            listed = self.listed[src] = {}
        if msg.t >= self.listed_newest.get(src, float("-inf")):   # its newest frame: msg.t is every robot's max
            listed.update(dict.fromkeys(robots, msg.t))
            self.listed_newest[src] = msg.t
        else:
            for r in robots:
                listed[r] = max(msg.t, listed.get(r, float("-inf")))
        # a robot that a heard source first in sort order listed within max_age_s is that source's to give
        first = [self.listed[s] for s in self.heard if s < src and s in self.listed]
        taken = robots
        if first:
            oldest = msg.t - self.max_age_s
            theirs = {r for by in first for r, t in by.items() if t >= oldest}
            taken = [r for r in robots if r not in theirs]
            self.shadowed += len(robots) - len(taken)
        if taken:
            stamp = (msg.t, msg.seq, src)
            if key > self.newest_held:   # newer than every pose held (one source's next frame): all taken
                self.held.update(dict.fromkeys(taken, stamp))
                self.held_pose.update(poses if taken is poses else {r: poses[r] for r in taken})
                self.newest_held = key
            else:
                for r in taken:
                    held = self.held.get(r)
                    if held is not None and key <= (held[0], held[1]):
                        self.dropped_old += 1
                        continue
                    self.held[r] = stamp        # (key <= newest_held here: it stays the bound)
                    self.held_pose[r] = poses[r]
        elif robots:
            return False             # every pose shadowed: this source is not the one followed
        self.heard[src] = max(msg.t, self.heard.get(src, float("-inf")))
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
        oldest = msg.t - self.max_age_s
        stamp = (msg.t, msg.seq, msg.src)
        stamps = list(map(self.held.get, self.robots))
        if stamps.count(stamp) == len(stamps) and msg.t >= oldest:
            # every robot's pose came with this very frame (one source listing every robot): of its instant
            complete, fresh, sources = True, self.robot_set, frozenset((msg.src,))
            poses = dict(zip(self.robots, map(self.held_pose.__getitem__, self.robots)))
        else:
            complete, poses, fresh, sources = self._merge(msg, stamps)
        if not complete and self.deadline_at is not None and now < self.deadline_at \
                and not all(s == msg.src or t < oldest for s, t in self.heard.items()):
            return None   # another source's frame of this instant may still come
        self.pending, self.deadline_at = None, None
        self.done = (msg.t, msg.seq)
        return Frame(seq=msg.seq, t=msg.t, poses=poses, complete=complete, fresh=fresh, src=msg.src,
                     sources=sources)

    def _merge(self, msg: FrameMsg, stamps: list) -> tuple[bool, dict, frozenset[str], frozenset[str]]:
        """(complete, poses, fresh, sources) of the robots' held poses (stamps: each robot's, in order) for
        msg's frame: every robot's pose no older than max_age_s, which of them are of msg's instant, and
        whether every robot has one of its instant (complete).

        A held pose is of msg's instant if msg itself brought it, or another source's frame at most half
        the deadline older did. Never a pose held over from an earlier frame of msg's own source: one
        source's frames are distinct instants, and which of them an agent got (a newer frame replaces one
        not yet run) differs between agents, so such a pose would make copies disagree."""
        oldest, near = msg.t - self.max_age_s, msg.t - 0.5 * self.deadline_s
        complete, poses, fresh, sources = True, {}, [], set()
        for r, held in zip(self.robots, stamps):
            if held is None:
                complete = False
                continue
            t, seq, src = held
            instant = (t == msg.t and seq == msg.seq) if src == msg.src else t >= near
            complete = complete and instant
            if t < oldest:
                continue
            poses[r] = self.held_pose[r]
            sources.add(src)
            if instant:
                fresh.append(r)
        return complete, poses, frozenset(fresh), frozenset(sources)


class MissionBook:
    """Every mission version seen; the active one at tracker time t is the newest effective one.

    Versions older than the active one are forgotten; at most MAX_PENDING versions are held.
    """

    MAX_PENDING = 64

    def __init__(self) -> None:
        self.by_version: dict[int, Mission] = {}

    def add(self, mission: Mission) -> bool:
        """Record a mission; False if that version is known or too many are pending."""
        if mission.version in self.by_version or len(self.by_version) >= self.MAX_PENDING:
            return False
        self.by_version[mission.version] = mission
        return True

    def latest(self) -> Mission | None:
        return self.by_version[max(self.by_version)] if self.by_version else None

    def active(self, t: float) -> Mission | None:
        if len(self.by_version) == 1:   # one mission held (the usual case): no older one to forget
            (only,) = self.by_version.values()
            return only if only.effective_t <= t else None
        eligible = [m for m in self.by_version.values() if m.effective_t <= t]
        if not eligible:
            return None
        best = max(eligible, key=lambda m: m.version)
        for v in [v for v in self.by_version if v < best.version]:
            del self.by_version[v]
        return best

    def robots(self) -> tuple[str, ...]:
        """Every robot any held mission names, sorted (the merger keeps their poses)."""
        return tuple(sorted({r for m in self.by_version.values() for r in m.robot_ids}))
