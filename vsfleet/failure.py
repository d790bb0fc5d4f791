"""The paper's "higher level": deciding, with no leader, that a robot has failed.

Every agent runs the same rule on the same frames, so all of them decide on the
same frame. The rule is:

- A robot is **non-compliant** in a frame when either:
  - its distance to its structure point exceeds ``fail_deviation_m`` (for a robot
    already dropped from the fit, its point on the structure fitted to the
    others), while at least one other robot in the fit is within it. When every
    robot in the fit is off by more, the structure is off, not one robot (under
    ``linf`` the residuals even out), and the test says nothing; or
  - it does not move as commanded. Every agent predicts every robot's command
    (the same deterministic function its own agent runs) and so the
    displacement each command should produce in one frame. Over the last
    ``fail_after_s``, the robot's net observed displacement along the net
    predicted one must be at least ``min_progress_ratio`` of it, once the net
    prediction reaches ``min_expected_m``. A halted robot, or one with a dead wheel, fails
    this test. It fails it even when the structure has stopped for it, which the
    deviation test cannot see under ``linf``, where the residuals even out. A
    robot slowed to 50% passes.
- A robot that has been non-compliant in every frame for ``fail_after_s`` of
  tracker time (measured from the first such frame) has **failed**. A frame in
  which the robot is missing counts as non-compliant.
- What follows depends on the mission's ``on_failure``:
  - ``hold`` (the paper's behaviour): the failure is reported and the robot
    stays in the fit, so the structure waits for it. From then on every robot's
    deviation is measured on the structure fitted without the failed robots
    (when two or more others remain; ``vsfleet.step.control_step(judged_apart=)``):
    the healthy robots a failed robot bends are not flagged for it. A failed
    robot that has complied for ``recover_after_s`` is healthy again
    (``recover``); the wait keeps the flag from flapping at the threshold. With only
    two robots left to judge by, a rigid fit gives both the same deviation (half
    the error in their separation), so the deviation test cannot single out one
    of them; the progress test still judges each.
  - ``drop``: the robot is taken out of the fit and its own agent stops it.
  - ``rejoin``: as ``drop``, but a dropped robot that has been within
    ``rejoin_deviation_m`` of its point for ``rejoin_after_s`` is taken back.

Agents that saw different frames can decide one frame apart. An agent that joins
late starts from "all healthy", or from its peers' state (:func:`with_health`).

Everything runs on arrays of all robots (rows in the mission's sorted id order):
:class:`FailureState` and :func:`failure_step`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from .errors import VsfleetValueError


@dataclass(frozen=True)
class FailurePolicy:
    """Thresholds [m, s on the tracker's clock] and the mode (hold, drop, rejoin)."""

    mode: str = "hold"
    fail_deviation_m: float = 0.05
    fail_after_s: float = 2.0
    rejoin_deviation_m: float = 0.02
    rejoin_after_s: float = 1.0
    recover_after_s: float = 0.5
    min_progress_ratio: float = 0.3
    min_expected_m: float = 0.05

    def __post_init__(self) -> None:
        if self.mode not in ("hold", "drop", "rejoin"):
            raise VsfleetValueError(f"on_failure must be hold, drop or rejoin, got {self.mode!r}")
        for name in ("fail_deviation_m", "fail_after_s", "rejoin_deviation_m", "rejoin_after_s",
                     "recover_after_s", "min_progress_ratio", "min_expected_m"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0.0:
                raise VsfleetValueError(f"{name} must be finite and >= 0, got {v!r}")


@dataclass(frozen=True)
class Health:
    """Per robot: since when [s] it has been non-compliant (or compliant, once failed), and its status."""

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


# The motion window of FailureState: (t, expected dx, expected dy, observed dx, observed dy) per slot.
_T, _EX, _EY, _OX, _OY = range(5)


@dataclass(frozen=True)
class FailureState:
    """The failure rule's state over n robots (rows), arrays only.

    since_t (n,) [s]: since when the robot has been non-compliant (compliant, once failed);
    NaN = not counting. failed, dropped (n,) bool. Motion: last_t (n,) [s] (NaN = never seen
    fresh), last_xy (n, 2) [m; world], last_expected (n, 2) [m] (the step its command should
    make), window (n, W, 5) of (t, expected dx, dy, observed dx, dy), a ring per robot written
    at next_slot (n,) (t NaN = empty; the oldest item is overwritten when a window is full).
    """

    since_t: np.ndarray
    failed: np.ndarray
    dropped: np.ndarray
    last_t: np.ndarray
    last_xy: np.ndarray
    last_expected: np.ndarray
    window: np.ndarray
    next_slot: np.ndarray

    @classmethod
    def initial(cls, n: int, policy: FailurePolicy, step_s: float) -> "FailureState":
        """All healthy, nothing seen; the window holds fail_after_s of frames at step_s [s] (+ margin)."""
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise VsfleetValueError(f"step_s must be finite and > 0, got {step_s!r}")
        slots = int(math.ceil(policy.fail_after_s / step_s)) + 4
        window = np.full((n, slots, 5), np.nan)
        return cls(np.full(n, np.nan), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool),
                   np.full(n, np.nan), np.zeros((n, 2)), np.zeros((n, 2)), window, np.zeros(n, dtype=int))


def with_health(state: FailureState, health: Health, robots: Sequence[str],
                timers: bool = True) -> FailureState:
    """The state with a peer's health (dict form, as on the wire) adopted: failed, dropped and,
    with ``timers``, since_t. Robots not in ``robots`` are ignored."""
    failed = np.array([r in health.failed for r in robots], dtype=bool)
    dropped = np.array([r in health.dropped for r in robots], dtype=bool)
    since = (np.array([health.since_t.get(r, math.nan) for r in robots], dtype=float) if timers
             else state.since_t)
    return FailureState(since, failed, dropped, state.last_t, state.last_xy, state.last_expected, state.window,
                        state.next_slot)


def to_health(state: FailureState, robots: Sequence[str]) -> Health:
    """The dict form of the health part (what HealthMsg carries): since {robot: t}, failed, dropped."""
    return Health(since_t={r: float(t) for r, t in zip(robots, state.since_t) if not math.isnan(t)},
                  failed=frozenset(r for r, f in zip(robots, state.failed) if f),
                  dropped=frozenset(r for r, d in zip(robots, state.dropped) if d))


def restart_timers(state: FailureState) -> FailureState:
    """After a gap: keep who failed or dropped, forget the timers and the motion window."""
    fresh = FailureState.initial(state.since_t.shape[0], FailurePolicy(), 1.0)
    return FailureState(np.full_like(state.since_t, np.nan), state.failed, state.dropped,
                        fresh.last_t, fresh.last_xy, fresh.last_expected, np.full_like(state.window, np.nan),
                        fresh.next_slot)


def _motion(policy: FailurePolicy, state: FailureState, t: float, fresh: np.ndarray, xy: np.ndarray,
            expected_step_m: np.ndarray, step_s: float | None, max_gap_s: float):
    """The motion test on fresh rows: the new (last_*, window) and each row's progress ratio
    (NaN where unknown): net sums over the last fail_after_s, as the module docstring says."""
    had = fresh & np.isfinite(state.last_t)
    ex, ey = state.last_expected[:, 0], state.last_expected[:, 1]
    if step_s is not None:
        scale = np.minimum(t - np.where(had, state.last_t, t), max_gap_s) / step_s
        ex, ey = ex * scale, ey * scale
    item = np.stack([np.full_like(ex, t), ex, ey, xy[:, 0] - state.last_xy[:, 0],
                     xy[:, 1] - state.last_xy[:, 1]], axis=1)
    rows = np.flatnonzero(had)
    window, slot = state.window, state.next_slot
    if rows.size:
        window = window.copy()
        window[rows, slot[rows]] = item[rows]
        slot = slot.copy()
        slot[rows] = (slot[rows] + 1) % window.shape[1]
    times = window[:, :, _T]
    valid = times > t - policy.fail_after_s               # NaN compares False: empty slots
    sums = np.where(valid[:, :, None], window, 0.0).sum(axis=1)
    sx, sy, ox, oy = sums[:, _EX], sums[:, _EY], sums[:, _OX], sums[:, _OY]
    e2 = sx * sx + sy * sy
    first_t = np.where(valid, times, np.inf).min(axis=1)
    known = had & (t - first_t >= 0.8 * policy.fail_after_s) & (e2 >= policy.min_expected_m ** 2)
    ratio = np.where(known, (ox * sx + oy * sy) / np.where(known, e2, 1.0), np.nan)
    last_t = np.where(fresh, t, state.last_t)
    last_xy = np.where(fresh[:, None], xy, state.last_xy)
    last_expected = np.where(fresh[:, None], expected_step_m, state.last_expected)
    return last_t, last_xy, last_expected, window, slot, ratio


def failure_step(policy: FailurePolicy, state: FailureState, robots: Sequence[str], t: float,
                 seen: np.ndarray, fresh: np.ndarray, xy_world: np.ndarray, deviations_m: np.ndarray,
                 expected_step_m: np.ndarray, step_s: float | None = None,
                 max_gap_s: float = math.inf) -> tuple[FailureState, list[Decision]]:
    """Advance the failure rule by one frame at tracker time t [s], for every robot at once.

    seen (n,): in the frame; fresh (n,): its pose is of this very frame (only those enter the
    motion test); xy_world (n, 2) [m]; deviations_m (n,) [m]: distance to the point it is judged
    on (inf when unseen); expected_step_m (n, 2) [m; world]: the displacement its predicted
    command should make in step_s [s] (zero when not commanded). A step of a robot missed for a
    while is scaled to the time that passed, capped at max_gap_s (the command ttl).
    """
    n = len(robots)
    seen = np.asarray(seen, dtype=bool)
    fresh = np.asarray(fresh, dtype=bool) & seen
    xy = np.asarray(xy_world, dtype=float)
    dev = np.where(seen, np.asarray(deviations_m, dtype=float), np.inf)
    exp_m = np.asarray(expected_step_m, dtype=float)
    if seen.shape != (n,) or xy.shape != (n, 2) or dev.shape != (n,) or exp_m.shape != (n, 2):
        raise VsfleetValueError("failure_step: arrays must have n rows, one per robot")
    last_t, last_xy, last_exp, window, slot, ratio = _motion(policy, state, t, fresh, np.where(fresh[:, None], xy, 0.0),
                                                       exp_m, step_s, max_gap_s)
    since, failed, dropped = state.since_t.copy(), state.failed.copy(), state.dropped.copy()
    in_fit = seen & ~dropped
    structure_off = int(in_fit.sum()) >= 2 and float(np.min(dev[in_fit])) > policy.fail_deviation_m
    stuck = np.isfinite(ratio) & (ratio < policy.min_progress_ratio)
    off = (dev > policy.fail_deviation_m) & ~(structure_off & np.isfinite(dev))
    complies = ~(off | stuck)
    decisions: list[Decision] = []
    mode = policy.mode
    # dropped robots: rejoin only (their since_t counts compliant time)
    near = dev <= policy.rejoin_deviation_m
    if mode == "rejoin":
        start = np.where(dropped & near & np.isnan(since), t, since)
        back = dropped & near & (t - start >= policy.rejoin_after_s)
        since = np.where(dropped, np.where(near, np.where(back, np.nan, start), np.nan), since)
    else:
        back = np.zeros(n, dtype=bool)
    # failed (hold): healthy again after complying for recover_after_s
    hold_failed = failed & ~dropped
    start = np.where(hold_failed & complies & np.isnan(since), t, since)
    recover = hold_failed & complies & (t - start >= policy.recover_after_s)
    since = np.where(hold_failed, np.where(complies & ~recover, start, np.nan), since)
    # healthy: fail after fail_after_s of non-compliance (stuck counts from a whole window back)
    healthy = ~failed & ~dropped
    start = np.where(healthy & ~complies & np.isnan(since), t - np.where(stuck, policy.fail_after_s, 0.0), since)
    fail = healthy & ~complies & (t - start >= policy.fail_after_s)
    since = np.where(healthy, np.where(~complies & ~fail, start, np.nan), since)
    for i in np.flatnonzero(back | recover | fail):    # decisions only: rare, never per frame
        r, d = robots[i], float(dev[i])
        if back[i]:
            decisions.append(Decision(t, r, "rejoin", d))
        elif recover[i]:
            decisions.append(Decision(t, r, "recover", d))
        else:
            decisions.append(Decision(t, r, "fail", d))
            if mode in ("drop", "rejoin"):
                decisions.append(Decision(t, r, "drop", d))
    failed = (failed | fail) & ~back & ~recover
    dropped = (dropped | (fail if mode in ("drop", "rejoin") else False)) & ~back
    return FailureState(since, failed, dropped, last_t, last_xy, last_exp, window, slot), decisions
