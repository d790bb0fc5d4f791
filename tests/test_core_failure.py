"""The failure rule in the compiled core (vsfleet._core via vsfleet.failure.failure_step) against the numpy
reference (vsfleet.failure.failure_step_reference): the same frames in, the same state and decisions out."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vsfleet import _core
from vsfleet.errors import NonFiniteError, VsfleetValueError
from vsfleet.failure import (FailurePolicy, FailureState, Health, failure_step, failure_step_reference,
                             restart_timers, with_health)

FIELDS = ("since_t", "failed", "dropped", "last_t", "last_xy", "last_expected", "window_t", "window_nm", "head",
          "in_window", "sums_nm", "window_dev_m")
TOL = 1e-9
# the reference divides 0 by 0 where min_expected_m = 0 lets an all-zero window be judged (a NaN ratio: not stuck)
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered in divide:RuntimeWarning")


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """The same shape, dtype and bytes: then every check of assert_same_state holds (NaN where NaN, equal values).
    About 1 us against numpy.testing's 80 us a field: the random sequences below compare 12 fields on each of
    ~25 000 frames, and the arrays are almost always bit for bit the same; any difference takes the full checks."""
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_same_state(core: FailureState, ref: FailureState, where: str = "") -> None:
    for name in FIELDS:
        a, b = getattr(core, name), getattr(ref, name)
        if _same_bits(a, b):
            continue
        assert a.shape == b.shape and a.dtype == b.dtype, (name, where)
        if a.dtype.kind == "f":
            assert np.array_equal(np.isnan(a), np.isnan(b)), (name, where, a, b)
            np.testing.assert_allclose(a, b, rtol=0.0, atol=TOL, equal_nan=True, err_msg=f"{name} {where}")
        else:
            assert np.array_equal(a, b), (name, where, a, b)


def assert_same_decisions(core, ref, where: str = "") -> None:
    assert [(d.robot, d.kind, d.t) for d in core] == [(d.robot, d.kind, d.t) for d in ref], where
    for c, r in zip(core, ref):
        assert c.deviation_m == r.deviation_m or abs(c.deviation_m - r.deviation_m) <= TOL, where


def both(policy, state_core, state_ref, robots, t, *args, **kw):
    """One frame through the core and the reference, each on its own state; compared."""
    core, made_core = failure_step(policy, state_core, robots, t, *args, **kw)
    ref, made_ref = failure_step_reference(policy, state_ref, robots, t, *args, **kw)
    assert_same_state(core, ref, f"t={t}")
    assert_same_decisions(made_core, made_ref, f"t={t}")
    return core, ref, made_core


# ---------------------------------------------------------------- random frame sequences

BEHAVIOURS = ("moves", "stops", "slow", "reverses", "vanishes", "far", "noisy")
# each behaviour's factor on the expected motion and jitter [m], by its index in BEHAVIOURS
FACTOR = np.array([{"stops": 0.0, "slow": 0.5, "reverses": -1.0}.get(b, 1.0) for b in BEHAVIOURS])
NOISE = np.array([3e-3 if b == "noisy" else 1e-4 for b in BEHAVIOURS])
VANISHES, FAR = BEHAVIOURS.index("vanishes"), BEHAVIOURS.index("far")


@st.composite
def scenarios(draw):
    mode = draw(st.sampled_from(("hold", "drop", "rejoin")))
    step_s = draw(st.sampled_from((1 / 30, 0.05, 0.1)))
    policy = FailurePolicy(
        mode,
        fail_deviation_m=draw(st.sampled_from((0.0, 0.02, 0.05)) | st.floats(0.0, 0.1)),
        fail_after_s=draw(st.sampled_from((0.0, 0.1, 0.5, 1.0)) | st.floats(0.05, 1.5)),
        rejoin_deviation_m=draw(st.sampled_from((0.0, 0.02)) | st.floats(0.0, 0.05)),
        rejoin_after_s=draw(st.sampled_from((0.0, 0.3, 1.0)) | st.floats(0.0, 1.0)),
        recover_after_s=draw(st.sampled_from((0.0, 0.5)) | st.floats(0.0, 1.0)),
        min_progress_ratio=draw(st.sampled_from((0.0, 0.3, 1.0)) | st.floats(0.0, 1.0)),
        min_expected_m=draw(st.sampled_from((0.0, 0.005, 0.02, 0.05)) | st.floats(0.0, 0.1)),
        min_approach_m=draw(st.sampled_from((0.0, 0.02, 1.0)) | st.floats(0.0, 0.1)))
    return dict(policy=policy, step_s=step_s, n=draw(st.integers(1, 6)), frames=draw(st.integers(50, 300)),
                seed=draw(st.integers(0, 2 ** 32 - 1)),
                frame_dt=draw(st.sampled_from((1.0, 0.5, 1.7))),       # < 1: the ring overwrites its oldest
                scaled=draw(st.booleans()), max_gap_s=draw(st.sampled_from((math.inf, 0.3, 0.05))),
                t0=draw(st.sampled_from((0.0, 100.0, 1e5))), from_peers=draw(st.booleans()))


def frames_of(sc):
    """Frames of robots that move, stop, slow, reverse, vanish and return, stray far, or jitter."""
    rng = np.random.default_rng(sc["seed"])
    n, step_s, policy = sc["n"], sc["step_s"], sc["policy"]
    heading = rng.uniform(-math.pi, math.pi, n)
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    xy = rng.uniform(-2.0, 2.0, (n, 2))
    if rng.random() < 0.2:
        xy[:] = xy[0]                                  # every robot on the same spot
    behaviour = rng.integers(0, len(BEHAVIOURS), n)
    t = sc["t0"]
    for k in range(sc["frames"]):
        if rng.random() < 0.05:
            behaviour = rng.integers(0, len(BEHAVIOURS), n)
        gap = step_s * sc["frame_dt"] * (1.0 + rng.uniform(-0.2, 0.2))
        if rng.random() < 0.03:
            gap *= rng.integers(2, 15)                   # frames missed: a step scaled (and capped)
        t = t + gap
        commanded = rng.random(n) < 0.9
        expected = np.where(commanded[:, None], 0.1 * step_s * direction, 0.0)
        xy = xy + FACTOR[behaviour][:, None] * expected * (gap / step_s)
        xy = xy + rng.normal(0.0, 1.0, (n, 2)) * NOISE[behaviour][:, None]
        seen = (behaviour != VANISHES) & (rng.random(n) < 0.95)
        fresh = seen & (rng.random(n) < 0.9)
        dev = rng.uniform(0.0, 0.03, n)
        dev = np.where(behaviour == FAR, rng.uniform(0.05, 0.5, n), dev)
        r = rng.random()
        if r < 0.05:
            dev[:] = rng.uniform(0.06, 0.3)              # everyone off: the structure is blamed
        elif r < 0.1:
            dev = np.where(rng.random(n) < 0.5, policy.fail_deviation_m, policy.rejoin_deviation_m)  # at a threshold
        elif r < 0.12:
            dev[:] = 0.0
        dev = np.where(seen, dev, np.where(rng.random(n) < 0.5, np.inf, np.nan))  # unseen rows are not read
        xy_in = np.where(fresh[:, None], xy, np.where(rng.random((n, 1)) < 0.5, 0.0, np.nan))
        yield t, seen, fresh, xy_in, dev, expected


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_the_core_keeps_the_same_state_and_decides_the_same_as_the_reference_on_every_frame(sc):
    policy, n, step_s = sc["policy"], sc["n"], sc["step_s"]
    robots = tuple(f"r{i}" for i in range(n))
    state = FailureState.initial(n, policy, step_s)
    if sc["from_peers"]:
        rng = np.random.default_rng(sc["seed"] + 1)
        failed = frozenset(r for r in robots if rng.random() < 0.4)
        dropped = frozenset(r for r in failed if policy.mode != "hold" and rng.random() < 0.7)
        state = with_health(state, Health(since_t={r: sc["t0"] - rng.uniform(0, 1) for r in robots
                                                   if rng.random() < 0.5}, failed=failed, dropped=dropped), robots)
    core = ref = state
    kw = dict(step_s=step_s if sc["scaled"] else None, max_gap_s=sc["max_gap_s"])
    held_rng = np.random.default_rng(sc["seed"] + 2)   # the safety filter's holds (None: no filter)
    held_share = held_rng.choice([0.0, 0.1, 0.5])
    for k, (t, seen, fresh, xy, dev, expected) in enumerate(frames_of(sc)):
        if k == sc["frames"] // 2 and sc["seed"] % 5 == 0:
            core, ref = restart_timers(core), restart_timers(ref)
        held = (held_rng.random(n) < held_share) if held_share else None
        core, ref, _ = both(policy, core, ref, robots, t, seen, fresh, xy, dev, expected, held=held, **kw)


def test_every_mode_makes_decisions_in_the_random_sequences():
    """The random sequences above are not vacuous: each mode fails, drops, rejoins and recovers robots."""
    kinds = {"hold": set(), "drop": set(), "rejoin": set()}
    for mode in kinds:
        policy = FailurePolicy(mode, fail_after_s=0.5, rejoin_after_s=0.3, recover_after_s=0.2, min_expected_m=0.02)
        for seed in range(3):
            sc = dict(policy=policy, step_s=0.05, n=4, frames=300, seed=seed, frame_dt=1.0, scaled=True,
                      max_gap_s=0.3, t0=100.0, from_peers=False)
            robots = ("a", "b", "c", "d")
            core = ref = FailureState.initial(4, policy, 0.05)
            for t, seen, fresh, xy, dev, expected in frames_of(sc):
                core, ref, made = both(policy, core, ref, robots, t, seen, fresh, xy, dev, expected, 0.05, 0.3)
                kinds[mode] |= {d.kind for d in made}
    assert kinds == {"hold": {"fail", "recover"}, "drop": {"fail", "drop"}, "rejoin": {"fail", "drop", "rejoin"}}


# ---------------------------------------------------------------- examples

def r2_halted(policy: FailurePolicy, frames: int, halted) -> list[tuple[int, str, str]]:
    """Two robots commanded at 0.1 m/s at 30 Hz, on their points (deviation 0), r2 still on the frames k where
    halted(k); every frame through the core and the reference (both); returns (frame, robot, kind) decided."""
    dt, robots = 1 / 30, ("r1", "r2")
    core = ref = FailureState.initial(2, policy, dt)
    xy, decided = np.zeros((2, 2)), []
    for k in range(frames):
        t = 10.0 + k * dt
        expected = np.array([[0.1 * dt, 0.0], [0.0, 0.1 * dt]])
        xy = xy + (expected * [[1.0], [0.0]] if halted(k) else expected)
        core, ref, made = both(policy, core, ref, robots, t, np.ones(2, bool), np.ones(2, bool), xy,
                               np.zeros(2), expected, dt, 0.3)
        decided += [(k, d.robot, d.kind) for d in made]
    return decided


def test_a_halted_robot_fails_the_progress_test_on_the_same_frame_in_the_core_and_the_reference():
    decided = r2_halted(FailurePolicy("drop", fail_after_s=1.0), 150, lambda k: k >= 40)   # r2 halts at frame 40
    assert [(r, kind) for _, r, kind in decided] == [("r2", "fail"), ("r2", "drop")]


def test_a_dropped_robot_near_its_point_but_not_moving_as_commanded_is_not_taken_back_to_fail_again():
    """rejoin: near its point is not enough while the window says stuck. Taken back so, the robot failed
    again on the next frame (stuck counts a whole window back), and the fleet flapped fail/rejoin every
    30 frames (tests/integration/test_faults.py under load, 2026-12-05)."""
    policy = FailurePolicy("rejoin", fail_after_s=1.0, rejoin_deviation_m=0.02, rejoin_after_s=1.0)
    # r2 halts at frame 40 and stays on its point (deviation 0), commanded on (rejoin drives it); from frame 200
    # it moves as commanded again
    decided = r2_halted(policy, 330, lambda k: 40 <= k < 200)
    kinds = [(r, kind) for _, r, kind in decided]
    assert kinds == [("r2", "fail"), ("r2", "drop"), ("r2", "rejoin")], decided
    fail_k, rejoin_k = decided[0][0], decided[2][0]
    assert 40 < fail_k < 80
    # taken back only once it moved as commanded long enough for its window to say so, and then kept
    assert rejoin_k > 200 + 30, decided


def test_a_full_ring_overwrites_its_oldest_item_alike():
    """Frames four times faster than step_s: the ring of ceil(fail_after_s / step_s) + 4 slots wraps."""
    policy = FailurePolicy("hold", fail_after_s=0.5, min_expected_m=0.0)
    core = ref = FailureState.initial(1, policy, 0.1)
    for k in range(60):
        core, ref, _ = both(policy, core, ref, ("r",), 0.025 * k, [True], [True], [[0.001 * k, 0.0]], [0.0],
                            [[0.001, 0.0]], 0.1)
    assert int(core.head[0]) == 59 and core.in_window.all()


def test_zero_robots_step_to_an_empty_state_and_no_decisions():
    policy = FailurePolicy("rejoin")
    state = FailureState.initial(0, policy, 0.1)
    core, made = failure_step(policy, state, (), 1.0, np.zeros(0, bool), np.zeros(0, bool), np.zeros((0, 2)),
                              np.zeros(0), np.zeros((0, 2)), 0.1)
    ref, _ = failure_step_reference(policy, state, (), 1.0, np.zeros(0, bool), np.zeros(0, bool),
                                    np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)), 0.1)
    assert made == [] and core.window_t.shape == (0, 24)
    assert_same_state(core, ref)


def test_coincident_robots_all_off_blame_the_structure_and_an_unseen_one_still_fails():
    policy = FailurePolicy("drop", fail_after_s=0.2)
    robots = ("a", "b", "c")
    core = ref = FailureState.initial(3, policy, 0.1)
    made_all = []
    for k in range(10):
        seen = np.array([True, True, False])
        core, ref, made = both(policy, core, ref, robots, 0.1 * k, seen, seen, np.ones((3, 2)),
                               np.array([0.07, 0.07, np.inf]), np.zeros((3, 2)), 0.1)
        made_all += made
    assert [(d.robot, d.kind) for d in made_all] == [("c", "fail"), ("c", "drop")]
    assert math.isinf(made_all[0].deviation_m)


def test_the_input_state_is_left_as_it_was():
    policy = FailurePolicy("hold")
    state = FailureState.initial(2, policy, 0.1)
    before = [getattr(state, f).copy() for f in FIELDS]
    failure_step(policy, state, ("a", "b"), 1.0, [True, True], [True, True], [[1.0, 2.0], [3.0, 4.0]],
                 [0.2, 0.0], [[0.01, 0.0], [0.0, 0.01]], 0.1)
    for f, b in zip(FIELDS, before):
        assert np.array_equal(getattr(state, f), b, equal_nan=True), f


# ---------------------------------------------------------------- refused inputs

def call(policy=FailurePolicy("hold"), t=1.0, seen=(True, True), fresh=(True, True), xy=((0.0, 0.0), (1.0, 1.0)),
         dev=(0.0, 0.0), expected=((0.0, 0.0), (0.0, 0.0)), step_s=0.1, max_gap_s=math.inf, state=None):
    state = state if state is not None else FailureState.initial(2, policy, 0.1)
    return failure_step(policy, state, ("a", "b"), t, np.array(seen), np.array(fresh), np.array(xy, dtype=float),
                        np.array(dev, dtype=float), np.array(expected, dtype=float), step_s, max_gap_s)


@pytest.mark.parametrize("t", [math.nan, math.inf, -math.inf])
def test_a_non_finite_frame_time_is_refused_with_a_typed_error(t):
    with pytest.raises(NonFiniteError):
        call(t=t)


@pytest.mark.parametrize("kw", [dict(dev=(math.nan, 0.0)), dict(dev=(0.0, -math.inf)), dict(xy=((math.nan, 0.0), (0, 0))),
                                dict(expected=((0.0, math.inf), (0, 0))), dict(step_s=math.nan),
                                dict(max_gap_s=math.nan)])
def test_non_finite_values_that_the_rule_would_read_are_refused(kw):
    with pytest.raises(NonFiniteError):
        call(**kw)


@pytest.mark.parametrize("kw", [dict(xy=((1e300, 0.0), (0, 0))), dict(expected=((0.0, -1e300), (0, 0))),
                                dict(xy=((2e9, 0.0), (0, 0))), dict(step_s=0.0), dict(step_s=-0.1),
                                dict(max_gap_s=-1.0), dict(seen=(True,)), dict(xy=((0.0, 0.0),))])
def test_out_of_range_or_misshapen_inputs_are_refused_with_a_value_error(kw):
    with pytest.raises(VsfleetValueError):
        call(**kw)


def test_a_huge_scaled_step_that_would_not_fit_int64_nanometres_is_refused():
    policy = FailurePolicy("hold")
    state, _ = call(expected=((1e9, 0.0), (0.0, 0.0)))
    with pytest.raises(VsfleetValueError):
        call(t=1e6, state=state)                      # 1e9 m * (1e6 s / 0.1 s): beyond 2^63 nm
    state, _ = call(expected=((1e9, 0.0), (0.0, 0.0)), policy=policy)
    call(t=1e6, state=state, max_gap_s=0.5)           # capped by max_gap_s: 5e18 nm fits


def test_values_the_rule_does_not_read_are_not_refused():
    """Unseen rows' deviations and non-fresh rows' positions and steps are ignored, as by the reference."""
    core, made = call(seen=(True, False), fresh=(True, False), dev=(0.0, math.nan),
                      xy=((0.0, 0.0), (math.nan, 1e300)), expected=((0.0, 0.0), (math.inf, 0.0)))
    assert made == [] and np.isnan(core.last_t[1])


def test_one_fresh_flag_for_all_robots_is_taken_as_by_the_reference():
    policy = FailurePolicy("hold")
    core = ref = FailureState.initial(3, policy, 0.1)
    for k in range(3):
        core, ref, _ = both(policy, core, ref, ("a", "b", "c"), 0.1 * k, np.ones(3, bool), True,
                            np.full((3, 2), 0.01 * k), np.zeros(3), np.full((3, 2), 0.01), 0.1)
    assert (core.head == 2).all()


def test_a_state_of_another_size_is_refused_with_a_value_error():
    policy = FailurePolicy("hold")
    with pytest.raises(VsfleetValueError):
        call(state=FailureState.initial(3, policy, 0.1))


def test_the_binding_refuses_arrays_of_the_wrong_kind():
    policy = FailurePolicy("hold")
    s = FailureState.initial(1, policy, 0.1)
    args = [policy, 1.0, np.ones(1, bool), np.ones(1, bool), np.zeros((1, 2)), np.zeros(1), np.zeros((1, 2)), 0.1,
            math.inf] + [getattr(s, f).copy() for f in FIELDS] + [None]
    assert _core.failure_step(*args) == ()
    assert _core.failure_step(*args[:-1], np.ones(1, bool)) == ()   # held: bool (n) or None
    with pytest.raises(TypeError):
        _core.failure_step(*args[:-1], np.ones(1, np.int64))
    bad = list(args)
    bad[2] = np.ones(1, dtype=np.int64)                # seen as int64, not bool
    with pytest.raises(TypeError):
        _core.failure_step(*bad)
    bad = list(args)
    bad[17] = np.zeros(1, dtype=np.int32)              # head as int32
    with pytest.raises(TypeError):
        _core.failure_step(*bad)
    bad = list(args)
    bad[9] = bad[9].copy()
    bad[9].flags.writeable = False                     # the state is written in place
    with pytest.raises(TypeError):
        _core.failure_step(*bad)
