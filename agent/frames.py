"""Assembling tracker frames and choosing the active mission. No I/O; the clock is passed in.

Frame rule (docs/protocol.md):
- A pose is kept per robot if it is newer than the one held: larger ``t``, or
  equal ``t`` and larger ``seq``. Older or duplicate poses are dropped (counted).
- A frame ``S`` is complete when every mission robot's held pose has ``seq == S``.
  The agent then runs its control step at once.
- Otherwise, ``deadline_s`` after the first pose of frame S arrived, it runs
  anyway with the freshest poses it holds.
- Poses older than ``max_age_s`` before the frame's time are left out of the fit.
- Each frame is processed at most once, and never a frame older than the last one processed.
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


class FrameAssembler:
    def __init__(self, robots: tuple[str, ...], deadline_s: float = 0.02, max_age_s: float = 0.25):
        self.robots = tuple(robots)
        self.deadline_s = deadline_s
        self.max_age_s = max_age_s
        self.latest: dict[str, PoseMsg] = {}
        self.newest_seq = -1
        self.done_seq = -1
        self.deadline_at: float | None = None
        self.dropped_old = 0

    def set_robots(self, robots: tuple[str, ...]) -> None:
        self.robots = tuple(robots)

    def offer(self, robot: str, msg: PoseMsg, now: float) -> bool:
        """Keep ``msg`` if it is newer than the pose held for ``robot``; False if dropped."""
        held = self.latest.get(robot)
        if held is not None and (msg.t, msg.seq) <= (held.t, held.seq):
            self.dropped_old += 1
            return False
        self.latest[robot] = msg
        if msg.seq > self.newest_seq:
            self.newest_seq = msg.seq
            if msg.seq > self.done_seq:
                self.deadline_at = now + self.deadline_s
        return True

    def time_to_deadline(self, now: float) -> float | None:
        if self.deadline_at is None:
            return None
        return max(0.0, self.deadline_at - now)

    def ready(self, now: float) -> Frame | None:
        """The frame to process now, if any (complete, or its deadline has passed)."""
        s = self.newest_seq
        if s <= self.done_seq or not self.robots:
            return None
        held = [self.latest.get(r) for r in self.robots]
        complete = all(m is not None and m.seq == s for m in held)
        if not complete and (self.deadline_at is None or now < self.deadline_at):
            return None
        t_frame = max(m.t for m in self.latest.values() if m.seq == s)
        poses = {r: (m.x, m.y, m.th) for r, m in zip(self.robots, held)
                 if m is not None and m.t >= t_frame - self.max_age_s}
        self.done_seq = s
        self.deadline_at = None
        return Frame(seq=s, t=t_frame, poses=poses, complete=complete)


class MissionBook:
    """Every mission version seen; the active one at tracker time t is the newest effective one."""

    def __init__(self) -> None:
        self.by_version: dict[int, Mission] = {}

    def add(self, mission: Mission) -> bool:
        """Record a mission; False if that version is already known."""
        if mission.version in self.by_version:
            return False
        self.by_version[mission.version] = mission
        # Keep the newest few: older versions can no longer become active once a newer one is.
        for v in sorted(self.by_version)[:-8]:
            del self.by_version[v]
        return True

    def latest(self) -> Mission | None:
        return self.by_version[max(self.by_version)] if self.by_version else None

    def active(self, t: float) -> Mission | None:
        eligible = [m for m in self.by_version.values() if m.effective_t <= t]
        return max(eligible, key=lambda m: m.version) if eligible else None
