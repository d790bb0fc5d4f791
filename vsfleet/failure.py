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
- **The assembly phase** (issue 28): a robot on its way to its point is not a
  failed robot, so the deviation test does not judge a seen robot that is on its
  way in the frame (the progress test still does). On its way means either:
  - it approaches its point: over a window spanning at least 80% of
    ``fail_after_s`` (the progress test's), its deviation shrank by more than
    ``min_approach_m`` (from the window's oldest frame to this one); or
  - it is held back: the fleet-wide safety filter cut its command in this frame,
    or the assembly tie-break sent it round another robot
    (``vsfleet.step.assembly_targets``); ``vsfleet.step`` passes ``held``, and every
    agent runs the same filter and tie-break on the same frame, so all of them
    agree. A robot waiting its turn in a crowd does what it is told, which is to
    wait.
  A halted robot, or one with a dead wheel, still fails the progress test when its
  command would move it (within ``fail_after_s``, held or not); a
  robot still and off its point that nothing holds still fails the deviation
  test; an unseen robot is never on its way. A deadlock (robots held against
  each other for good) is then no failure: the stall watch reports it
  (``vsfleet.step.stall_state``). Measured (bench/crowd.py, 10 robots packed 2 cm
  apart in a shuffled order, seeds 1-6, 60 s, 2026-12-04, shared 2-core host):
  fail decisions 7-11 per run (seeds 2-6; 2 robots still failed at the end)
  before; 0-2, all recovered within 3 s, after; with the tie-break as well
  (seeds 1-12, 90 s), 0-1 per run, none standing at the end.
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
    ``rejoin_deviation_m`` of its point, and not stuck, for ``rejoin_after_s`` is
    taken back. Not stuck: taken back while its window still says stuck, it
    failed again on the next frame (the stuck test counts a whole window back),
    and agents whose windows differed flapped fail/rejoin every 30 frames
    (tests/integration/test_faults.py under load, 2026-12-05).

Agents that saw different frames can decide one frame apart. An agent that joins
late starts from "all healthy", or from its peers' state (:func:`with_health`).

Everything runs on arrays of all robots (rows in the mission's sorted id order):
:class:`FailureState` and :func:`failure_step`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Sequence

from .lazy import lazy_numpy
from . import _core
from .coreconst import DECISION_KINDS, FAILURE_MODES, FAILURE_NM_PER_M as _NM_PER_M, FAILURE_SETTLED_RATIO
from .errors import VsfleetValueError

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

# the rule's decisions (DECISION_KINDS, by their codes in vs_failure.h: VS_DECISION_*; vsfleet.wire's
# EVENT_KINDS begins with them) and its modes (FAILURE_MODES, VS_FAILURE_*) are the core's (vsfleet.coreconst)


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
    min_approach_m: float = 0.02

    def __post_init__(self) -> None:
        if self.mode not in FAILURE_MODES:
            raise VsfleetValueError(f"on_failure must be hold, drop or rejoin, got {self.mode!r}")
        for name in ("fail_deviation_m", "fail_after_s", "rejoin_deviation_m", "rejoin_after_s",
                     "recover_after_s", "min_progress_ratio", "min_expected_m", "min_approach_m"):
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


# The motion window's displacements are held in integer nanometres: their sums are then exact, so
# they do not depend on the order of the items in the ring (agents that missed different frames
# hold the same items in different slots, and still sum them to the same bits): _NM_PER_M per metre.


@dataclass(frozen=True)
class FailureState:
    """The failure rule's state over n robots (rows), arrays only.

    since_t (n,) [s]: since when the robot has been non-compliant (compliant, once failed);
    NaN = not counting. failed, dropped (n,) bool. Motion: last_t (n,) [s] (NaN = never seen
    fresh), last_xy (n, 2) [m; world], last_expected (n, 2) [m] (the step its command should
    make), and a ring of W frames per robot: window_t (n, W) [s] (NaN = empty), window_nm (n, W, 4)
    int64 (expected dx, dy, observed dx, dy [nm]), head (n,) the next slot to write; sums_nm (n, 4)
    int64: the sum of the items still in the window (in_window (n, W)), kept as items come and go;
    window_dev_m (n, W) [m]: the robot's deviation in each item's frame (the assembly phase).
    """

    since_t: np.ndarray
    failed: np.ndarray
    dropped: np.ndarray
    last_t: np.ndarray
    last_xy: np.ndarray
    last_expected: np.ndarray
    window_t: np.ndarray
    window_nm: np.ndarray
    head: np.ndarray
    in_window: np.ndarray
    sums_nm: np.ndarray
    window_dev_m: np.ndarray

    @classmethod
    def initial(cls, n: int, policy: FailurePolicy, step_s: float) -> "FailureState":
        """All healthy, nothing seen; the window holds fail_after_s of frames at step_s [s] (+ margin)."""
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise VsfleetValueError(f"step_s must be finite and > 0, got {step_s!r}")
        slots = int(math.ceil(policy.fail_after_s / step_s)) + 4
        return cls(np.full(n, np.nan), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool),
                   *_empty_motion(n, slots))

    @property
    def motion(self) -> tuple[np.ndarray, ...]:
        return (self.last_t, self.last_xy, self.last_expected, self.window_t, self.window_nm, self.head,
                self.in_window, self.sums_nm, self.window_dev_m)


def _empty_motion(n: int, slots: int) -> tuple[np.ndarray, ...]:
    return (np.full(n, np.nan), np.zeros((n, 2)), np.zeros((n, 2)), np.full((n, slots), np.nan),
            np.zeros((n, slots, 4), dtype=np.int64), np.zeros(n, dtype=np.int64), np.zeros((n, slots), dtype=bool),
            np.zeros((n, 4), dtype=np.int64), np.zeros((n, slots)))


def with_health(state: FailureState, health: Health, robots: Sequence[str],
                timers: bool = True) -> FailureState:
    """The state with a peer's health (dict form, as on the wire) adopted: failed, dropped and,
    with ``timers``, since_t. Robots not in ``robots`` are ignored."""
    failed = np.array([r in health.failed for r in robots], dtype=bool)
    dropped = np.array([r in health.dropped for r in robots], dtype=bool)
    since = (np.array([health.since_t.get(r, math.nan) for r in robots], dtype=float) if timers
             else state.since_t)
    return FailureState(since, failed, dropped, *state.motion)


def to_health(state: FailureState, robots: Sequence[str]) -> Health:
    """The dict form of the health part (what HealthMsg carries): since {robot: t}, failed, dropped."""
    return Health(since_t={r: float(t) for r, t in zip(robots, state.since_t) if not math.isnan(t)},
                  failed=frozenset(r for r, f in zip(robots, state.failed) if f),
                  dropped=frozenset(r for r, d in zip(robots, state.dropped) if d))


def restart_timers(state: FailureState) -> FailureState:
    """After a gap: keep who failed or dropped, forget the timers and the motion window."""
    n, slots = state.window_t.shape
    return FailureState(np.full(n, np.nan), state.failed, state.dropped, *_empty_motion(n, slots))


def _motion(policy: FailurePolicy, state: FailureState, t: float, fresh: np.ndarray, xy: np.ndarray,
            expected_step_m: np.ndarray, step_s: float | None, max_gap_s: float, dev: np.ndarray):
    """The motion test on fresh rows: the new motion arrays, each row's progress ratio (NaN
    where unknown) and whether it approaches its point (the assembly phase). Net sums over the
    items of the last fail_after_s (see the module docstring)."""
    had = fresh & np.isfinite(state.last_t)
    expected = state.last_expected
    if step_s is not None:
        scale = np.minimum(t - np.where(had, state.last_t, t), max_gap_s) / step_s
        expected = expected * scale[:, None]
    window_t, window_nm, head = state.window_t, state.window_nm, state.head
    in_window, sums, window_dev = state.in_window, state.sums_nm, state.window_dev_m
    expire = in_window & ~(window_t > t - policy.fail_after_s)   # items that left the window
    rows = had.nonzero()[0]
    slots = window_t.shape[1]
    at = head[rows] % slots                                     # a full ring overwrites its oldest item
    if rows.size:
        expire = expire.copy()
        expire[rows, at] |= in_window[rows, at]
    if expire.any() or rows.size:
        in_window = in_window & ~expire
        sums = sums - np.where(expire[:, :, None], window_nm, 0).sum(axis=1)   # int64: exact in any order
    if rows.size:
        window_t, window_nm, head, window_dev = window_t.copy(), window_nm.copy(), head.copy(), window_dev.copy()
        window_t[rows, at] = t
        window_dev[rows, at] = dev[rows]
        item = np.concatenate([expected[rows], xy[rows] - state.last_xy[rows]], axis=1)
        q = np.rint(item * _NM_PER_M).astype(np.int64)
        window_nm[rows, at] = q
        in_window[rows, at] = True
        sums[rows] += q
        head[rows] += 1
    total = sums.astype(float) / _NM_PER_M
    sx, sy, ox, oy = total[:, 0], total[:, 1], total[:, 2], total[:, 3]
    e2 = sx * sx + sy * sy
    times = np.where(in_window, window_t, np.inf)
    oldest = times.argmin(axis=1)                                # the first slot of the earliest time
    first_t = times[np.arange(len(times)), oldest]
    settled = had & (t - first_t >= FAILURE_SETTLED_RATIO * policy.fail_after_s)
    known = settled & (e2 >= policy.min_expected_m ** 2)
    ratio = np.where(known, (ox * sx + oy * sy) / np.where(known, e2, 1.0), np.nan)
    # the assembly phase: over a settled window its deviation shrank by more than min_approach_m
    # (from the oldest item's frame, the first slot of the earliest time, to this one)
    first_dev = window_dev[np.arange(len(times)), oldest]
    finite = np.isfinite(dev)
    approach = settled & finite & (first_dev - np.where(finite, dev, 0.0) > policy.min_approach_m)
    last_t = np.where(fresh, t, state.last_t)
    last_xy = np.where(fresh[:, None], xy, state.last_xy)
    last_expected = np.where(fresh[:, None], expected_step_m, state.last_expected)
    return last_t, last_xy, last_expected, window_t, window_nm, head, in_window, sums, window_dev, ratio, approach


def failure_step(policy: FailurePolicy, state: FailureState, robots: Sequence[str], t: float,
                 seen: np.ndarray, fresh: np.ndarray, xy_world: np.ndarray, deviations_m: np.ndarray,
                 expected_step_m: np.ndarray, step_s: float | None = None,
                 max_gap_s: float = math.inf, held: np.ndarray | None = None) -> tuple[FailureState, list[Decision]]:
    """Advance the failure rule by one frame at tracker time t [s], for every robot at once.

    The compiled core (vsfleet/_core/vs_failure.c) runs the rule of :func:`failure_step_reference`,
    which documents the arguments; it computes the same bits. It also refuses what the reference
    would carry along: a non-finite t, step_s or max_gap_s, a NaN deviation of a seen robot, a
    non-finite (NonFiniteError) or beyond 1e9 m (VsfleetValueError) position or expected step of
    a fresh robot, step_s <= 0 and max_gap_s < 0 (VsfleetValueError).
    """
    n = len(robots)
    seen = np.ascontiguousarray(seen, dtype=bool)
    fresh = np.ascontiguousarray(fresh, dtype=bool)
    if fresh.shape != (n,):                           # one flag for all, as the reference takes it
        try:
            fresh = np.ascontiguousarray(np.broadcast_to(fresh, (n,)))
        except ValueError:
            raise VsfleetValueError("failure_step: arrays must have n rows, one per robot") from None
    xy = np.ascontiguousarray(xy_world, dtype=float)
    dev = np.ascontiguousarray(deviations_m, dtype=float)
    exp_m = np.ascontiguousarray(expected_step_m, dtype=float)
    held_in = None if held is None else np.ascontiguousarray(held, dtype=bool)
    if (seen.shape != (n,) or xy.shape != (n, 2) or dev.shape != (n,) or exp_m.shape != (n, 2)
            or (held_in is not None and held_in.shape != (n,))):
        raise VsfleetValueError("failure_step: arrays must have n rows, one per robot")
    # the new state: one copy of each array, updated in place by the core
    new = [a.copy() for a in (state.since_t, state.failed, state.dropped, state.last_t, state.last_xy,
                              state.last_expected, state.window_t, state.window_nm, state.head,
                              state.in_window, state.sums_nm, state.window_dev_m)]
    made = _core.failure_step(policy, t, seen, fresh, xy, dev, exp_m, step_s, max_gap_s, *new, held_in)
    decisions = [Decision(t, robots[i], DECISION_KINDS[k], d) for i, k, d in made] if made else []
    # FailureState(*new) without the frozen dataclass's __init__ (twelve object.__setattr__: 1.2 us of a
    # 7 us call at n = 3); the fields are the same
    out = object.__new__(FailureState)
    out.__dict__.update(zip(_STATE_FIELDS, new))
    return out, decisions


_STATE_FIELDS = tuple(f.name for f in dataclasses.fields(FailureState))


def failure_step_reference(policy: FailurePolicy, state: FailureState, robots: Sequence[str], t: float,
                           seen: np.ndarray, fresh: np.ndarray, xy_world: np.ndarray, deviations_m: np.ndarray,
                           expected_step_m: np.ndarray, step_s: float | None = None,
                           max_gap_s: float = math.inf,
                           held: np.ndarray | None = None) -> tuple[FailureState, list[Decision]]:
    """Advance the failure rule by one frame at tracker time t [s], for every robot at once
    (numpy; the readable reference of the compiled core behind :func:`failure_step`).

    seen (n,): in the frame; fresh (n,): its pose is of this very frame (only those enter the
    motion test); xy_world (n, 2) [m]; deviations_m (n,) [m]: distance to the point it is judged
    on (inf when unseen); expected_step_m (n, 2) [m; world]: the displacement its predicted
    command should make in step_s [s] (zero when not commanded). A step of a robot missed for a
    while is scaled to the time that passed, capped at max_gap_s (the command ttl). held (n,)
    (None: none): the safety filter cut the robot's command in this frame (vsfleet.step), which
    puts it in the assembly phase (see the module docstring).
    """
    n = len(robots)
    seen = np.asarray(seen, dtype=bool)
    fresh = np.asarray(fresh, dtype=bool) & seen
    xy = np.asarray(xy_world, dtype=float)
    dev = np.where(seen, np.asarray(deviations_m, dtype=float), np.inf)
    exp_m = np.asarray(expected_step_m, dtype=float)
    held = np.zeros(n, dtype=bool) if held is None else np.asarray(held, dtype=bool)
    if (seen.shape != (n,) or xy.shape != (n, 2) or dev.shape != (n,) or exp_m.shape != (n, 2)
            or held.shape != (n,)):
        raise VsfleetValueError("failure_step: arrays must have n rows, one per robot")
    *motion, ratio, approach = _motion(policy, state, t, fresh, np.where(fresh[:, None], xy, 0.0),
                                       exp_m, step_s, max_gap_s, dev)
    since, failed, dropped = state.since_t.copy(), state.failed.copy(), state.dropped.copy()
    in_fit = seen & ~dropped
    structure_off = np.count_nonzero(in_fit) >= 2 and float(dev[in_fit].min()) > policy.fail_deviation_m
    stuck = np.isfinite(ratio) & (ratio < policy.min_progress_ratio)
    # the assembly phase: a seen robot that approaches its point, or that the safety filter holds
    # back, is on its way: the deviation test does not judge it (the progress test still does)
    on_way = np.isfinite(dev) & (approach | (held & seen))
    off = (dev > policy.fail_deviation_m) & ~(structure_off & np.isfinite(dev)) & ~on_way
    complies = ~(off | stuck)
    decisions: list[Decision] = []
    mode = policy.mode
    # dropped robots: rejoin only (their since_t counts compliant time)
    near = (dev <= policy.rejoin_deviation_m) & ~stuck   # and moving as commanded (module docstring)
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
    for i in (back | recover | fail).nonzero()[0]:    # decisions only: rare, never per frame
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
    return FailureState(since, failed, dropped, *motion), decisions
