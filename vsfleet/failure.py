"""The paper's "higher level": deciding, with no leader, that a robot has failed.

Every agent runs the same rule on the same frames, so all of them decide on the
same frame. The rule is:

- A robot is **non-compliant** in a frame when its distance to its structure point
  exceeds ``fail_deviation_m``. For a robot already dropped from the fit, this is
  its distance to its point on the structure fitted to the others.
- A robot that has been non-compliant in every frame for ``fail_after_s`` of
  tracker time (measured from the first such frame) has **failed**. A frame in
  which the robot is missing counts as non-compliant.
- What follows depends on the mission's ``on_failure``:
  - ``hold`` (the paper's behaviour): the failure is reported and nothing else
    changes. The structure waits for the robot.
  - ``drop``: the robot is taken out of the fit and its own agent stops it.
  - ``rejoin``: as ``drop``, but a dropped robot that has been within
    ``rejoin_deviation_m`` of its point for ``rejoin_after_s`` is taken back.

Agents that saw different frames can decide one frame apart. An agent that joins
late starts from "all healthy".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from .errors import VsfleetValueError


@dataclass(frozen=True)
class FailurePolicy:
    """Thresholds [m, s on the tracker's clock] and the mode (hold, drop, rejoin)."""

    mode: str = "hold"
    fail_deviation_m: float = 0.05
    fail_after_s: float = 2.0
    rejoin_deviation_m: float = 0.02
    rejoin_after_s: float = 1.0

    def __post_init__(self) -> None:
        if self.mode not in ("hold", "drop", "rejoin"):
            raise VsfleetValueError(f"on_failure must be hold, drop or rejoin, got {self.mode!r}")
        for name in ("fail_deviation_m", "fail_after_s", "rejoin_deviation_m", "rejoin_after_s"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0.0:
                raise VsfleetValueError(f"{name} must be finite and >= 0, got {v!r}")


@dataclass(frozen=True)
class Health:
    """Per robot: since when [s] it has been non-compliant (or compliant, once dropped), and its status."""

    since_t: dict[str, float] = field(default_factory=dict)
    failed: frozenset[str] = frozenset()
    dropped: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Decision:
    """A change of a robot's status at frame time t: 'fail', 'drop', 'rejoin' or 'recover' (hold)."""

    t: float
    robot: str
    kind: str
    deviation_m: float


def update_health(policy: FailurePolicy, health: Health, deviations_m: Mapping[str, float],
                  robots: tuple[str, ...], t: float) -> tuple[Health, list[Decision]]:
    """Advance the failure state by one frame at tracker time t [s].

    deviations_m: each seen robot's distance [m] to its structure point; robots of
    ``robots`` absent from it were not seen in this frame.
    """
    since = dict(health.since_t)
    failed, dropped = set(health.failed), set(health.dropped)
    decisions: list[Decision] = []
    for r in robots:
        d = deviations_m.get(r, math.inf)
        if r in dropped:
            if policy.mode != "rejoin":
                continue
            if d <= policy.rejoin_deviation_m:
                start = since.setdefault(r, t)
                if t - start >= policy.rejoin_after_s:
                    dropped.discard(r)
                    failed.discard(r)
                    since.pop(r, None)
                    decisions.append(Decision(t, r, "rejoin", d))
            else:
                since.pop(r, None)
            continue
        if d > policy.fail_deviation_m:
            start = since.setdefault(r, t)
            if r not in failed and t - start >= policy.fail_after_s:
                failed.add(r)
                decisions.append(Decision(t, r, "fail", d))
                if policy.mode in ("drop", "rejoin"):
                    dropped.add(r)
                    since.pop(r, None)
                    decisions.append(Decision(t, r, "drop", d))
        else:
            since.pop(r, None)
            if r in failed:  # hold: a robot that complies again is healthy again
                failed.discard(r)
                decisions.append(Decision(t, r, "recover", d))
    return Health(since, frozenset(failed), frozenset(dropped)), decisions
