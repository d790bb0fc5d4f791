"""Assembling tracker frames and choosing the active mission. No I/O; the clock is passed in.

Frame rule (docs/protocol.md):
- Poses are ordered by ``(t, seq)``. A pose is kept per robot if it is newer
  than the one held; older or duplicate poses are dropped (counted). A pose
  whose ``t`` is more than ``max_future_s`` ahead of the local clock is refused.
- The newest frame is the ``(t, seq)`` of the newest pose held. It is complete
  when every mission robot's held pose has that ``seq`` from the same ``src``
  (tracker or camera). The agent then runs its control step at once. With
  several trackers, each robot's freshest pose wins, whichever source it is from.
- Otherwise, ``deadline_s`` after the first pose that arrived while no frame was
  pending, the agent runs the newest frame with the freshest poses it holds.
- Poses older than ``max_age_s`` before the frame's time are left out.
- A frame whose ``t`` is more than ``max_stale_s`` behind the local clock is
  stale: it is not run (counted in ``stale``), so no command answers it and the
  robots halt after their command's ttl.
- A frame runs at most once, and never one older than the last frame run (by
  ``(t, seq)``). So a tracker that restarts its ``seq`` is followed at once.
"""

from __future__ import annotations

from dataclasses import dataclass

from vsfleet.wire import Mission, PoseMsg


@dataclass(frozen=True)
class Frame:
    """Poses (x, y, th) [m, rad; world] of the robots used for frame ``seq`` at tracker time ``t``."""

    seq: int
    t: float
    poses: dict[str, tuple[float, float, float]]
    complete: bool
    fresh: frozenset[str] = frozenset()  # robots whose pose is of this very frame (same src and seq)


class FrameAssembler:
    def __init__(self, robots: tuple[str, ...], deadline_s: float = 0.02, max_age_s: float = 0.25,
                 max_future_s: float = 1.0, max_stale_s: float = 0.5):
        self.robots = tuple(robots)
        self.deadline_s = deadline_s
        self.max_age_s = max_age_s
        self.max_future_s = max_future_s
        self.max_stale_s = max_stale_s
        self.latest: dict[str, PoseMsg] = {}
        self.done: tuple[float, int] = (float("-inf"), -1)
        self.deadline_at: float | None = None
        self.dropped_old = 0
        self.refused_future = 0
        self.stale = 0

    def set_robots(self, robots: tuple[str, ...]) -> None:
        self.robots = tuple(robots)

    def offer(self, robot: str, msg: PoseMsg, now: float) -> bool:
        """Keep ``msg`` if it is newer than the pose held for ``robot``; False if dropped."""
        if msg.t > now + self.max_future_s:
            self.refused_future += 1
            return False
        held = self.latest.get(robot)
        if held is not None and (msg.t, msg.seq) <= (held.t, held.seq):
            self.dropped_old += 1
            return False
        self.latest[robot] = msg
        if (msg.t, msg.seq) > self.done and self.deadline_at is None:
            self.deadline_at = now + self.deadline_s
        return True

    def time_to_deadline(self, now: float) -> float | None:
        if self.deadline_at is None:
            return None
        return max(0.0, self.deadline_at - now)

    def ready(self, now: float) -> Frame | None:
        """The frame to process now, if any (complete, or its deadline has passed)."""
        robots = self.robots
        if not robots or not self.latest:
            return None
        newest = max(self.latest.values(), key=lambda m: (m.t, m.seq))
        key = (newest.t, newest.seq)
        if key <= self.done:
            self.deadline_at = None
            return None
        held = {r: self.latest.get(r) for r in robots}
        fresh = frozenset(r for r, m in held.items()
                          if m is not None and m.seq == newest.seq and m.src == newest.src)
        complete = len(fresh) == len(held)
        if not complete and (self.deadline_at is None or now < self.deadline_at):
            return None
        if newest.t < now - self.max_stale_s:
            self.done = key
            self.deadline_at = None
            self.stale += 1
            return None
        poses = {r: (m.x, m.y, m.th) for r, m in held.items()
                 if m is not None and newest.t - self.max_age_s <= m.t}
        self.done = key
        self.deadline_at = None
        return Frame(seq=newest.seq, t=newest.t, poses=poses, complete=complete, fresh=fresh)


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
        eligible = [m for m in self.by_version.values() if m.effective_t <= t]
        if not eligible:
            return None
        best = max(eligible, key=lambda m: m.version)
        for v in [v for v in self.by_version if v < best.version]:
            del self.by_version[v]
        return best
