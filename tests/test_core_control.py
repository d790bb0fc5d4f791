"""The compiled core's kinematics and controllers (vsfleet/_core/vs_kin.c, vs_control.c) against
their numpy references (vsfleet.kinematics.*_reference, each controller's ``reference`` method).

Numbers agree within 1e-9 (the core computes its own sin/cos/atan2, so not bit for bit), discrete
state (direction, ready) exactly; the core refuses NaN and infinity with NonFiniteError.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from vsfleet.control import ControlInput, Held, Precision, PrecisionState, make_controller
from vsfleet.envelope import Envelope, Envelopes
from vsfleet.errors import NonFiniteError
from vsfleet.kinematics import (
    TimeStepError,
    integrate_arcs,
    integrate_arcs_reference,
    limit_wheels,
    limit_wheels_v,
    limit_wheels_v_reference,
    sinc_v,
    sinc_v_reference,
    wrap_angles,
    wrap_angles_reference,
)

TOL = 1e-9
DT = 1.0 / 30.0
NAMES = ("precision", "tracking", "arc", "turn_then_go")
STATE_FIELDS = ("pose_world", "gains", "history_m_s", "target_world", "feed_m_s", "turn_rad_s", "offset_world")
CHEAP = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LOOPS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(-50.0, 50.0, allow_nan=False)
speeds = st.floats(-1.0, 1.0, allow_nan=False)
awkward = st.sampled_from([math.nan, math.inf, -math.inf])


def rows(draw, n, cols, elements):
    return np.array(draw(st.lists(st.lists(elements, min_size=cols, max_size=cols), min_size=n, max_size=n)),
                    dtype=float).reshape(n, cols)


# --------------------------------------------------------------------------- kinematics


@st.composite
def arcs(draw):
    n = draw(st.integers(0, 8))
    pose = rows(draw, n, 3, finite)
    wheels = rows(draw, n, 2, speeds)
    kind = draw(st.sampled_from(["any", "straight", "nearly straight", "spin", "still"]))
    if kind == "straight":
        wheels[:, 1] = wheels[:, 0]
    elif kind == "nearly straight":   # w dt / 2 below 1e-4: the sinc's series
        wheels[:, 1] = wheels[:, 0] + draw(st.floats(-1e-4, 1e-4))
    elif kind == "spin":
        wheels[:, 1] = -wheels[:, 0]
    elif kind == "still":
        wheels[:] = 0.0
    dt = draw(st.sampled_from([0.0, DT, 0.001, 0.5, -DT]))
    base = np.array(draw(st.lists(st.floats(0.01, 1.0), min_size=n, max_size=n)), dtype=float)
    return pose, wheels, dt, base


@CHEAP
@given(arcs())
def test_integrate_arcs_drives_the_same_arcs_as_the_reference(case):
    pose, wheels, dt, base = case
    out = integrate_arcs(pose, wheels, dt, base)
    assert out.shape == (len(pose), 3)
    np.testing.assert_allclose(out, integrate_arcs_reference(pose, wheels, dt, base), rtol=0, atol=TOL)


def test_integrate_arcs_at_a_zero_tick_gives_the_poses_back_bit_for_bit():
    pose = np.array([[0.1, -0.2, 3.0], [5.0, 6.0, -1.0]])
    assert integrate_arcs(pose, np.array([[0.3, -0.1], [0.2, 0.2]]), 0.0, np.array([0.1, 0.1])).tobytes() \
        == pose.tobytes()


def test_integrate_arcs_takes_lists_a_scalar_wheel_base_and_strided_arrays_as_the_reference_does():
    pose = np.asfortranarray([[0.0, 0.0, 0.5], [1.0, 2.0, -0.5]])
    wheels = np.array([[0.1, 0.2, 9.0], [0.3, 0.3, 9.0]])[:, :2]          # not contiguous
    expected = integrate_arcs_reference(pose, wheels, DT, 0.1)
    np.testing.assert_allclose(integrate_arcs(pose, wheels, DT, 0.1), expected, atol=TOL)
    np.testing.assert_allclose(integrate_arcs(pose.tolist(), wheels.tolist(), DT, [0.1, 0.1]), expected, atol=TOL)
    dts = np.array([DT, 2 * DT])                                          # a dt per row: the reference runs
    np.testing.assert_array_equal(integrate_arcs(pose, wheels, dts, 0.1),
                                  integrate_arcs_reference(pose, wheels, dts, 0.1))


@pytest.mark.parametrize("where", ["pose", "wheels", "dt", "base"])
@given(bad=awkward)
@settings(max_examples=10, deadline=None)
def test_integrate_arcs_refuses_nan_and_infinity_with_the_typed_error(where, bad):
    pose, wheels, dt, base = np.zeros((2, 3)), np.full((2, 2), 0.1), DT, np.full(2, 0.1)
    if where == "pose":
        pose[1, 2] = bad
    elif where == "wheels":
        wheels[0, 1] = bad
    elif where == "dt":
        dt = bad
    else:
        base[1] = bad
    with pytest.raises(NonFiniteError):
        integrate_arcs(pose, wheels, dt, base)


def test_integrate_arcs_refuses_a_result_that_overflows_and_a_zero_wheel_base():
    with pytest.raises(NonFiniteError):
        integrate_arcs(np.array([[1e308, 0.0, 0.0]]), np.array([[1e300, 1e300]]), 1e10, np.array([0.1]))
    with pytest.raises(NonFiniteError):
        integrate_arcs(np.zeros((1, 3)), np.array([[0.1, 0.2]]), DT, np.array([0.0]))


def test_integrate_arcs_of_no_robots_is_an_empty_array():
    assert integrate_arcs(np.zeros((0, 3)), np.zeros((0, 2)), DT, np.zeros(0)).shape == (0, 3)


@st.composite
def commands(draw):
    n = draw(st.integers(0, 10))
    scale = st.sampled_from([0.0, 0.01, 0.1, 1.0, 3.0])
    u = rows(draw, n, 2, speeds) * rows(draw, n, 2, scale)
    p = rows(draw, n, 2, speeds) * rows(draw, n, 2, scale)
    if n and draw(st.booleans()):
        u[draw(st.integers(0, n - 1))] = 0.0
    if n and draw(st.booleans()):
        p[draw(st.integers(0, n - 1))] = u[0]   # a command equal to another row's previous one
    vmax = np.array(draw(st.lists(st.floats(0.01, 1.0), min_size=n, max_size=n)), dtype=float)
    amax = np.array(draw(st.lists(st.floats(0.01, 5.0), min_size=n, max_size=n)), dtype=float)
    dt = draw(st.sampled_from([DT, 0.01, 0.2, 1.0]))
    return u, p, dt, vmax, amax


@CHEAP
@given(commands())
def test_limit_wheels_v_clips_every_row_as_the_reference(case):
    u, p, dt, vmax, amax = case
    np.testing.assert_allclose(limit_wheels_v(u, p, dt, vmax, amax), limit_wheels_v_reference(u, p, dt, vmax, amax),
                               rtol=0, atol=TOL)


def test_limit_wheels_v_takes_every_branch_of_the_rule_as_the_reference():
    rng = np.random.default_rng(7)
    n = 5000
    u = rng.uniform(-1.0, 1.0, (n, 2)) * rng.choice([0.0, 0.1, 1.0], (n, 2))
    p = rng.uniform(-0.6, 0.6, (n, 2)) * rng.choice([0.0, 0.1, 1.0, 3.0], (n, 2))   # 3.0: prev beyond the box
    vmax, amax = np.full(n, 0.3), rng.choice([0.5, 1.0, 10.0], n)
    got, expected = limit_wheels_v(u, p, DT, vmax, amax), limit_wheels_v_reference(u, p, DT, vmax, amax)
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)
    assert np.array_equal(got == u, expected == u)          # the same rows left unchanged


def test_two_corners_on_one_ray_from_the_origin_tie_and_the_nearer_to_the_command_is_taken():
    """A wheel braking to zero in one tick: its bound p - a dt is -5.6e-17, so the box's corners (0.3229, -5.6e-17)
    and (0.4634, -5.6e-17) differ in angle to the command by less than an ulp of it. Two commands an ulp apart (the
    core's and the reference's in a closed loop) once took different corners, 0.14 m/s apart; within
    CORNER_TIE_RAD they tie, and both take the corner nearer to the command, by either implementation."""
    prev = np.array([[float.fromhex("0x1.a05d38c7ae9f5p-2"), float.fromhex("0x1.56fa2bef9adb4p-4")]])
    dt, vmax = float.fromhex("0x1.1111111111111p-5"), np.array([float.fromhex("0x1.da90a16e81332p-2")])
    amax = np.array([float.fromhex("0x1.418a8930a12ddp+1")])
    outs = []
    commands = (("0x1.4afeef4a48defp-1", "-0x1.d2f491a379b44p+0"),    # the reference's
                ("0x1.4afeef4a48deep-1", "-0x1.d2f491a379b45p+0"))    # the core's: each wheel an ulp off
    for vl, vr in commands:
        u = np.array([[float.fromhex(vl), float.fromhex(vr)]])
        outs += [limit_wheels_v(u, prev, dt, vmax, amax), limit_wheels_v_reference(u, prev, dt, vmax, amax),
                 np.array([limit_wheels(float(u[0, 0]), float(u[0, 1]), tuple(prev[0]), dt,
                                        Envelope(0.1, float(vmax[0]), float(amax[0])))])]
    for out in outs:
        assert out[0].tolist() == [vmax[0], prev[0, 1] - amax[0] * dt]   # the corner nearer to u, at the speed cap


def test_limit_wheels_v_refuses_non_finite_commands_and_a_bad_tick_with_the_typed_errors():
    ok = (np.zeros((1, 2)), np.zeros((1, 2)), DT, np.full(1, 0.3), np.full(1, 1.0))
    for i, bad in ((0, np.array([[math.nan, 0.0]])), (1, np.array([[0.0, math.inf]])), (3, np.array([math.inf])),
                   (4, np.array([math.nan]))):
        args = list(ok)
        args[i] = bad
        with pytest.raises(NonFiniteError):
            limit_wheels_v(*args)
    for dt in (0.0, -DT, math.nan):
        with pytest.raises(TimeStepError):
            limit_wheels_v(ok[0], ok[1], dt, ok[3], ok[4])
    assert limit_wheels_v(np.zeros((0, 2)), np.zeros((0, 2)), DT, np.zeros(0), np.zeros(0)).shape == (0, 2)


@CHEAP
@given(st.lists(st.one_of(st.floats(-1e-3, 1e-3), st.floats(-1e6, 1e6), st.sampled_from(
    [0.0, -0.0, 1e-4, -1e-4, np.nextafter(1e-4, 0.0), 1e-300, math.pi, -math.pi, 3 * math.pi])), max_size=20))
def test_sinc_v_and_wrap_angles_give_the_references_values(xs):
    x = np.array(xs, dtype=float)
    np.testing.assert_allclose(sinc_v(x), sinc_v_reference(x), rtol=0, atol=TOL)
    assert wrap_angles(x).tobytes() == wrap_angles_reference(x).tobytes()   # exact fmod: the same bits


def test_sinc_v_and_wrap_angles_keep_the_shape_and_refuse_non_finite_values():
    x = np.linspace(-7.0, 7.0, 12).reshape(3, 4)
    assert sinc_v(x).shape == wrap_angles(x).shape == (3, 4)
    assert sinc_v(0.0) == 1.0 and wrap_angles(math.pi) == -math.pi
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(NonFiniteError):
            sinc_v(np.array([0.0, bad]))
        with pytest.raises(NonFiniteError):
            wrap_angles(np.array([bad]))


# --------------------------------------------------------------------------- controllers


def assert_close(a, b, err_msg: str) -> None:
    """np.testing.assert_allclose(a, b, rtol=0, atol=TOL), not run where a and b are arrays of the same shape, dtype
    and bytes (where it passes: the same values, NaN where NaN): about 1 us against its 80 us, and the closed loops
    below compare seven arrays on each of ~7000 ticks, almost always bit for bit the same."""
    if not (type(a) is np.ndarray and type(b) is np.ndarray and a.shape == b.shape and a.dtype == b.dtype
            and a.tobytes() == b.tobytes()):
        np.testing.assert_allclose(a, b, rtol=0, atol=TOL, err_msg=err_msg)


def assert_same(core, ref, name):
    state_c, wheels_c = core
    state_r, wheels_r = ref
    assert_close(wheels_c, wheels_r, name)
    assert wheels_c.shape == wheels_r.shape and wheels_c.dtype == wheels_r.dtype
    if isinstance(state_c, PrecisionState):
        for f in STATE_FIELDS:
            a, b = getattr(state_c, f), getattr(state_r, f)
            assert a.shape == b.shape and a.dtype == b.dtype, f
            assert_close(a, b, f"{name}: {f}")
        assert np.array_equal(state_c.direction, state_r.direction)
        assert state_c.ready.dtype == state_r.ready.dtype == bool
        assert np.array_equal(state_c.ready, state_r.ready)
    else:
        assert state_c == state_r


def plant(pose, wheels, gain, base):
    """The robots' true motion: wheel gains off by a few percent, headings wrapped."""
    pose = integrate_arcs_reference(pose, wheels * gain, DT, base)
    pose[:, 2] = wrap_angles_reference(pose[:, 2])
    return pose


@st.composite
def loops(draw):
    return dict(name=draw(st.sampled_from(NAMES)), n=draw(st.integers(0, 6)), seed=draw(st.integers(0, 2**32 - 1)),
                age=draw(st.sampled_from([0.0, 0.004, DT, 0.05, 2 * DT, 0.12, 0.3, 1.0])),
                deadband=draw(st.sampled_from([0.0, 0.004, 0.05])), ticks=draw(st.integers(50, 200)),
                noise=draw(st.sampled_from([0.0, 0.0005, 0.003])), path=draw(st.sampled_from(["circle", "line", "still",
                                                                                                "reverse", "jumps"])))


@LOOPS
@given(loops())
# hypothesis found it (2026-12-06): at tick 11 robot 3 brakes a wheel to zero, two corners of its box lie on one ray
# from the origin, and the core's command, an ulp off the reference's, chose the other corner (CORNER_TIE_RAD)
@example(case={"name": "precision", "n": 5, "seed": 6917, "age": 1.0, "deadband": 0.0, "ticks": 50, "noise": 0.003,
               "path": "circle"})
def test_every_controller_in_a_closed_loop_computes_the_references_wheels_and_state(case):
    """50-200 ticks of a noisy closed loop with random envelopes, robots going inactive and coming back;
    the core and the reference each carry their own state the whole way."""
    rng = np.random.default_rng(case["seed"])
    n, ticks = case["n"], case["ticks"]
    ctrl = make_controller(case["name"], deadband_m=case["deadband"])
    env = Envelopes(rng.uniform(0.05, 0.2, n), rng.uniform(0.1, 0.6, n), rng.uniform(0.3, 3.0, n))
    gain = rng.uniform(0.95, 1.05, (n, 2))
    pose = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    phase = rng.uniform(0.0, 2 * math.pi, n)
    speed = rng.uniform(0.0, 0.3)

    def point(t):
        if case["path"] == "circle":
            a = speed * t / 0.4 + phase
            return np.column_stack([0.4 * np.cos(a), 0.4 * np.sin(a)])
        if case["path"] == "line":
            return np.column_stack([speed * t + 0.1 * np.cos(phase), 0.1 * np.sin(phase)])
        if case["path"] == "reverse":   # moves backwards of the robots' start headings
            return np.column_stack([-speed * t * np.cos(pose0[:, 2]), -speed * t * np.sin(pose0[:, 2])]) + pose0[:, :2]
        if case["path"] == "jumps":
            return np.column_stack([0.2 * np.cos(phase + (t > 2.0)), 0.2 * np.sin(phase)])
        return np.column_stack([0.05 * np.cos(phase), 0.05 * np.sin(phase)])

    pose0 = pose.copy()
    state_c = state_r = ctrl.initial(n)
    prev = np.zeros((n, 2))
    active = np.ones(n, dtype=bool)
    for k in range(ticks):
        if n and rng.uniform() < 0.1:   # a robot disappears or comes back
            active[rng.integers(n)] ^= True
        seen = pose + rng.normal(0.0, case["noise"], pose.shape) * np.array([1.0, 1.0, 3.0])
        inp = ControlInput(np.where(active[:, None], seen, 0.0), point(k * DT), point((k + 1) * DT), prev, DT,
                           case["age"], env, active.copy())
        core, ref = ctrl(state_c, inp), ctrl.reference(state_r, inp)
        assert_same(core, ref, f"tick {k}")
        state_c, state_r = core[0], ref[0]
        prev = core[1]
        pose = plant(pose, prev, gain, env.wheel_base_m)


def one_input(n=3, seed=1, **over):
    rng = np.random.default_rng(seed)
    env = Envelopes(np.full(n, 0.1), np.full(n, 0.3), np.full(n, 1.0))
    pose = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(-3, 3, n)])
    now = pose[:, :2] + rng.normal(0, 0.05, (n, 2))
    fields = dict(pose_world=pose, point_now_world=now, point_next_world=now + 0.003, wheels_prev_m_s=np.zeros((n, 2)),
                  dt_s=DT, age_s=DT, envelopes=env, active=np.ones(n, dtype=bool))
    fields.update(over)
    return ControlInput(**fields)


@pytest.mark.parametrize("name", NAMES)
def test_a_controller_with_no_robots_returns_empty_wheels(name):
    ctrl = make_controller(name)
    inp = ControlInput(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), DT, 0.0,
                       Envelopes(np.zeros(0), np.zeros(0), np.zeros(0)), np.zeros(0, dtype=bool))
    state, wheels = ctrl(ctrl.initial(0), inp)
    assert wheels.shape == (0, 2)
    assert_same((state, wheels), ctrl.reference(ctrl.initial(0), inp), name)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("field", ["pose_world", "point_now_world", "point_next_world", "wheels_prev_m_s"])
@given(bad=awkward)
@settings(max_examples=6, deadline=None)
def test_every_controller_refuses_nan_and_infinity_in_its_input_with_the_typed_error(name, field, bad):
    inp = one_input()
    a = getattr(inp, field).copy()
    a[1, 0] = bad
    ctrl = make_controller(name)
    with pytest.raises(NonFiniteError):
        ctrl(ctrl.initial(3), one_input(**{field: a}))


@pytest.mark.parametrize("field", STATE_FIELDS + ("direction",))
def test_precision_refuses_a_state_holding_nan_or_infinity(field):
    ctrl = Precision()
    state = ctrl.initial(3)
    a = np.array(getattr(state, field), dtype=float)
    a.reshape(-1)[-1] = math.nan
    bad = PrecisionState(**{**state.__dict__, field: a})
    with pytest.raises(NonFiniteError):
        ctrl(bad, one_input())


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("huge", [1e300, -1e300, 1e154])
def test_huge_finite_inputs_either_match_the_reference_or_are_refused_where_it_overflows(name, huge):
    ctrl = make_controller(name)
    for field in ("pose_world", "point_now_world", "point_next_world"):
        a = getattr(one_input(), field).copy()
        a[0, 0] = huge
        inp = one_input(**{field: a})
        ref = ctrl.reference(ctrl.initial(3), inp)
        try:
            core = ctrl(ctrl.initial(3), inp)
        except NonFiniteError:
            state = ref[0]
            assert isinstance(state, PrecisionState) and not all(
                np.all(np.isfinite(getattr(state, f))) for f in STATE_FIELDS)
            continue
        assert_same(core, ref, f"{name} {field}")


def test_precision_keeps_an_inactive_rows_state_bit_for_bit_and_commands_it_zero():
    ctrl = Precision()
    state = ctrl.initial(4)
    for k in range(5):
        state, _ = ctrl(state, one_input(n=4, seed=k))
    active = np.array([True, False, True, True])
    new, wheels = ctrl(state, one_input(n=4, seed=9, active=active))
    assert np.all(wheels[1] == 0.0)
    for f in STATE_FIELDS + ("direction", "ready"):
        assert getattr(new, f)[1].tobytes() == getattr(state, f)[1].tobytes()


def test_precision_takes_a_state_of_other_dtypes_and_strides_as_the_reference():
    ctrl = Precision()
    state = ctrl.initial(3)
    state, _ = ctrl(state, one_input())
    odd = PrecisionState(pose_world=np.asfortranarray(state.pose_world), gains=state.gains.tolist(),
                         history_m_s=state.history_m_s, target_world=state.target_world,
                         feed_m_s=state.feed_m_s, turn_rad_s=state.turn_rad_s,
                         direction=state.direction.astype(np.float32), offset_world=state.offset_world.T.copy().T,
                         ready=state.ready.astype(np.uint8))
    inp = one_input(seed=4, pose_world=np.asfortranarray(one_input(seed=4).pose_world))
    assert_same(ctrl(odd, inp), ctrl.reference(state, inp), "odd")


def test_precision_on_three_robots_gives_the_references_first_and_later_commands():
    ctrl = Precision()
    sc = sr = ctrl.initial(3)
    for k in range(10):
        inp = one_input(seed=k, age_s=0.05)
        (sc, wc), (sr, wr) = ctrl(sc, inp), ctrl.reference(sr, inp)
        assert_same((sc, wc), (sr, wr), f"tick {k}")
        assert np.any(wc != 0.0)


def test_held_brakes_a_robot_resting_on_its_point_as_the_reference_does():
    ctrl = make_controller("precision", deadband_m=0.01)
    assert isinstance(ctrl, Held)
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    now = np.array([[0.002, 0.0], [1.5, 1.0]])                      # robot 0 within the deadband, 1 not
    inp = ControlInput(pose, now, now, np.array([[0.2, 0.2], [0.0, 0.0]]), DT, 0.0,
                       Envelopes(np.full(2, 0.1), np.full(2, 0.3), np.full(2, 1.0)), np.ones(2, dtype=bool))
    core, ref = ctrl(ctrl.initial(2), inp), ctrl.reference(ctrl.initial(2), inp)
    assert_same(core, ref, "held")
    assert core[1][0] == pytest.approx([0.2 - DT, 0.2 - DT])        # braking at the acceleration limit
    assert np.all(core[1][1] > 0.0)


def test_a_robots_command_from_the_core_is_the_same_bits_whatever_the_other_rows_hold():
    ctrl = Precision()
    inp = one_input(n=6, seed=3)
    _, all_rows = ctrl(ctrl.initial(6), inp)
    alone = ControlInput(inp.pose_world[4:5], inp.point_now_world[4:5], inp.point_next_world[4:5],
                         inp.wheels_prev_m_s[4:5], DT, inp.age_s, Envelopes.of([inp.envelopes.row(4)]),
                         np.array([True]))
    _, one = ctrl(ctrl.initial(1), alone)
    assert one[0].tobytes() == all_rows[4].tobytes()


@pytest.mark.parametrize("impl", ["core", "reference"])
def test_the_gain_boost_reads_the_offsets_running_mean_so_noise_alone_does_not_trip_it(impl):
    """Precision adapts its wheel gains faster for a robot off its point (issue 30), reading the running mean of
    the offset (gain_boost_mean_ratio of the way to each frame's). An offset that flips +-6 mm every frame, the
    tracker's noise at sigma 3-5 mm, keeps the mean under the boost's 5 mm and the gains where they were as with
    the boost off; an offset that stays at 8 mm takes the mean past 5 mm within 3 frames (issue 30's slowed robot),
    and the gains then move faster than with the boost off."""
    def run(offsets_m, **gains):
        ctrl = Precision(**gains)
        state = ctrl.initial(1)
        step = ctrl if impl == "core" else ctrl.reference
        means, g = [], []
        for k, off in enumerate(offsets_m):
            x = 0.003 * k
            pose = np.array([[x + off, 0.0, 0.0]])
            inp = ControlInput(pose, np.array([[x, 0.0]]), np.array([[x + 0.003, 0.0]]), np.array([[0.09, 0.09]]),
                               DT, DT, Envelopes(np.full(1, 0.12), np.full(1, 0.3), np.full(1, 1.0)),
                               np.ones(1, dtype=bool))
            state, _ = step(state, inp)
            means.append(float(np.hypot(*np.asarray(state.offset_world)[0])))
            g.append(np.asarray(state.gains)[0].copy())
        return np.array(means), np.array(g)

    noise = [0.006 * (-1) ** k for k in range(60)]
    means, gains = run(noise)
    _, gains_off = run(noise, gain_boost_per_m=0.0)
    assert means[5:].max() < 0.0015                       # +-6 mm a frame: the mean stays near 0
    assert np.array_equal(gains, gains_off)               # so the boost never engages
    lag = [0.008] * 10
    means, gains = run(lag)
    _, gains_off = run(lag, gain_boost_per_m=0.0)
    assert means[2] > 0.005 and means[1] < 0.005          # 8 mm held: past 5 mm at the third frame
    assert np.abs(gains[-1] - 1.0).max() > 1.5 * np.abs(gains_off[-1] - 1.0).max()
    _, gains_each = run(noise, gain_boost_mean_ratio=1.0)   # each frame's offset (before): noise trips the boost
    assert not np.array_equal(gains_each, gains_off)
