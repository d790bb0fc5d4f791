"""The compiled safety filter (vsfleet/_core/vs_safety.c) against its numpy reference, and its properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vsfleet.errors import NonFiniteError, ShapeError, VsfleetValueError
from vsfleet.kinematics import integrate_arcs, limit_wheels_v, limit_wheels_v_reference
from vsfleet.safety import (SafetyInfo, SafetyParamError, SafetyParams, safety_filter,
                            safety_filter_reference)

BASE, VMAX, AMAX = 0.12, 0.3, 0.8
SETTINGS = settings(max_examples=125, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


@st.composite
def fleets(draw):
    n = draw(st.integers(0, 12))
    spread = draw(st.sampled_from([0.05, 0.3, 1.0, 1e-6]))
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    pose = np.c_[rng.uniform(-spread, spread, (n, 2)), rng.uniform(-10, 10, n)]
    if n >= 2 and draw(st.booleans()):
        pose[1, :2] = pose[0, :2]                       # coincident robots
    radius = rng.uniform(0.0, 0.08, n)
    nominal = rng.uniform(-0.5, 0.5, (n, 2))
    k = draw(st.integers(0, 4))
    obstacles = np.c_[rng.uniform(-spread, spread, (k, 2)), rng.uniform(0.0, 0.2, k)]
    active = rng.random(n) > draw(st.sampled_from([0.0, 0.3]))
    params = SafetyParams(margin_m=draw(st.sampled_from([0.0, 0.01])),
                          gamma_per_s=draw(st.sampled_from([1.0, 5.0, 30.0])),
                          offset_m=draw(st.sampled_from([0.0, 0.03])), dt_s=1 / 30)
    kw = dict(wheel_base_m=rng.uniform(0.05, 0.3, n), wheel_speed_max_m_s=rng.uniform(0.1, 0.5, n),
              obstacles=obstacles, active=active, params=params)
    if draw(st.booleans()):
        kw.update(wheel_accel_max_m_s2=rng.uniform(0.2, 2.0, n), wheels_prev_m_s=rng.uniform(-0.5, 0.5, (n, 2)))
    return pose, radius, nominal, kw


@SETTINGS
@given(fleets())
def test_the_core_agrees_with_the_reference_within_1e_9_and_counts_equal(fleet):
    pose, radius, nominal, kw = fleet
    got, info = safety_filter(pose, radius, nominal, **kw)
    want, info_ref = safety_filter_reference(pose, radius, nominal, **kw)
    assert info == info_ref
    assert got.shape == want.shape == (len(pose), 2)
    assert np.all(np.abs(got - want) <= 1e-9)


@SETTINGS
@given(fleets())
def test_every_safe_command_is_within_the_speed_box_and_meets_its_rows(fleet):
    pose, radius, nominal, kw = fleet
    got, info = safety_filter(pose, radius, nominal, **kw)
    vmax = kw["wheel_speed_max_m_s"]
    assert np.all(np.abs(got) <= vmax[:, None] * (1 + 1e-9))
    assert np.all(got[~kw["active"]] == 0.0)
    assert info.n_stopped == 0


def _row_of(pose, i, q_off, d_off, q_c, d_c, share, params, base):
    """a.u >= b of robot i's barrier against a body (written out again for the test): the control
    points' barrier while it holds, else the centres'; and its h."""
    c, s = math.cos(pose[i, 2]), math.sin(pose[i, 2])
    l = params.offset_m
    dx, dy = pose[i, 0] + l * c - q_off[0], pose[i, 1] + l * s - q_off[1]
    h = dx * dx + dy * dy - d_off ** 2
    if h < 0.0 or l == 0.0:
        l = 0.0
        dx, dy = pose[i, 0] - q_c[0], pose[i, 1] - q_c[1]
        h = dx * dx + dy * dy - d_c ** 2
    g, q = 2 * (dx * c + dy * s), 2 * l * (dy * c - dx * s)
    return np.array([0.5 * g - q / base, 0.5 * g + q / base]), -params.gamma_per_s * h * share, h


@SETTINGS
@given(fleets())
def test_each_robot_keeps_its_share_of_every_barrier_that_starts_safe(fleet):
    pose, radius, nominal, kw = fleet
    got, _ = safety_filter(pose, radius, nominal, **kw)
    p, act, base = kw["params"], kw["active"], kw["wheel_base_m"]
    l, mg = p.offset_m, p.margin_m
    brake = np.zeros(len(pose))   # each moving robot's stopping distance joins its radius
    if "wheels_prev_m_s" in kw:
        w = kw["wheels_prev_m_s"]
        brake = np.where(act, (w[:, 0] ** 2 + w[:, 1] ** 2) / (4 * kw["wheel_accel_max_m_s2"]), 0.0)
    rows = []
    for i in np.flatnonzero(act):
        for j in range(len(pose)):
            if j == i:
                continue
            ri_rj = radius[i] + radius[j] + brake[i] + brake[j]
            if act[j]:
                q = pose[j, :2] + l * np.array([math.cos(pose[j, 2]), math.sin(pose[j, 2])])
                rows.append((i, _row_of(pose, i, q, ri_rj + 2 * l + mg, pose[j, :2], ri_rj + mg, 0.5, p, base[i])))
            else:
                rows.append((i, _row_of(pose, i, pose[j, :2], ri_rj + l + mg, pose[j, :2], ri_rj + mg, 1.0, p,
                                        base[i])))
        for o in kw["obstacles"]:
            rr = radius[i] + o[2] + brake[i]
            rows.append((i, _row_of(pose, i, o[:2], rr + l + mg, o[:2], rr + mg, 1.0, p, base[i])))
    for i, (a, b, h) in rows:
        want = b if h >= 0.0 else 0.0    # inside the margin: at least not closing
        assert a @ got[i] >= want - 1e-9 * (1 + abs(b) + np.abs(a).sum())


def test_nominal_commands_that_are_already_safe_pass_unchanged_bit_for_bit():
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, math.pi], [0.0, 1.0, 0.0]])
    nominal = np.array([[0.1, 0.1], [0.2, 0.1], [-0.05, 0.3]])
    for fn in (safety_filter, safety_filter_reference):
        out, info = fn(pose, 0.05, nominal, wheel_base_m=BASE, wheel_speed_max_m_s=VMAX,
                       obstacles=np.array([[3.0, 3.0, 0.2]]))
        assert np.array_equal(out, nominal)
        assert info.n_modified == 0


def test_two_robots_head_on_are_slowed_and_a_robot_at_an_obstacle_stops_going_in():
    pose = np.array([[0.0, 0.0, 0.0], [0.13, 0.0, math.pi]])    # 3 cm gap, facing each other
    out, info = safety_filter(pose, 0.05, np.full((2, 2), 0.3), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX,
                              params=SafetyParams(margin_m=0.01, gamma_per_s=5.0))
    # h = 0.13^2 - 0.11^2 = 0.0048; each robot: 2 d.e v >= -5 h / 2 -> v <= 0.0462 m/s
    assert np.allclose(out, 0.5 * 5 * 0.0048 / (2 * 0.13), atol=1e-12)
    assert info.n_modified == 2
    pose = np.array([[0.0, 0.0, 0.0]])
    out, _ = safety_filter(pose, 0.05, np.array([[0.3, 0.3]]), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX,
                           obstacles=np.array([[0.16, 0.0, 0.1]]), params=SafetyParams(margin_m=0.01))
    assert np.allclose(out, 0.0, atol=1e-15)   # h = 0 at the margin: no closing speed left


def test_an_inactive_robot_is_a_fixed_disk_and_its_row_is_zero():
    pose = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]])
    nominal = np.array([[0.3, 0.3], [0.3, 0.3]])
    kw = dict(wheel_base_m=BASE, wheel_speed_max_m_s=VMAX, params=SafetyParams(margin_m=0.01, gamma_per_s=5.0))
    alone, _ = safety_filter(pose[:1], 0.05, nominal[:1], obstacles=np.array([[0.2, 0.0, 0.05]]), **kw)
    out, _ = safety_filter(pose, 0.05, nominal, active=np.array([True, False]), **kw)
    assert np.array_equal(out[1], [0.0, 0.0])
    assert np.allclose(out[0], alone[0], atol=1e-15)
    # against a fixed disk the robot has the whole closing budget (-gamma h); against an active robot
    # (even one asked to stand still) only its half
    both, _ = safety_filter(pose, 0.05, np.array([[0.3, 0.3], [0.0, 0.0]]), **kw)
    assert out[0, 0] == 0.3 and both[0, 0] < 0.3


def test_the_accel_box_is_kept_while_it_allows_a_safe_command():
    pose = np.array([[0.0, 0.0, 0.0]])
    out, info = safety_filter(pose, 0.05, np.array([[0.3, -0.3]]), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX,
                              wheel_accel_max_m_s2=0.6, wheels_prev_m_s=np.zeros((1, 2)),
                              params=SafetyParams(dt_s=0.05))
    assert np.allclose(out, [[0.03, -0.03]], atol=1e-15)
    assert info.n_accel_relaxed == 0


def test_robots_squeezed_inside_the_margin_are_softened_not_stopped():
    pose = np.array([[-0.105, 0.0, 0.0], [0.0, 0.0, 0.0], [0.105, 0.0, 0.0]])   # 5 mm gaps, margin 1 cm
    out, info = safety_filter(pose, 0.05, np.array([[0.1, 0.1], [0.1, 0.1], [0.1, 0.1]]), wheel_base_m=BASE,
                              wheel_speed_max_m_s=VMAX, params=SafetyParams(margin_m=0.01))
    assert info.n_softened == 1 and info.n_stopped == 0
    assert out[1, 0] + out[1, 1] == pytest.approx(0.0, abs=1e-12)   # the middle one: no closing either way
    assert out[0].sum() < 0 and out[2].sum() > 0                    # the outer ones move away


# A robot squeezed between two obstacles, 2 cm from each (inside the braking room: h < 0 both ways), with
# an accel limit: the filter softens both rows to "do not close" (v = 0) and, as no such command is in
# the accel box, drops the box (n_accel_relaxed). Its stop then passes the wheel limiter (as a plant's
# envelope, bench/safety.py), with the same previous command. Before the mend the limiter pinned a wheel
# whose previous command lay beyond the speed box to +-vmax (the stop became full speed ahead, into the
# obstacle), and its corner rule kept a wheel at speed, or sped it up, when the command turned in place.
SQUEEZE = np.array([[0.12, 0.0, 0.05], [-0.12, 0.0, 0.05]])
STOP_CASES = [
    # previous command, nominal, the filter's stop, the limiter's result (slowest reachable wheel speeds)
    ((0.4, 0.4), (0.3, 0.3), (0.0, 0.0), (0.0, 0.0)),                  # prev beyond vmax = 0.3: was (0.3, 0.3)
    ((0.2, 0.2), (0.3, 0.2), (0.05, -0.05), (0.2 - AMAX / 30, 0.2 - AMAX / 30)),   # was (0.2267, 0.1733)
    ((0.2, 0.2), (0.3, 0.3), (0.0, 0.0), (0.2 - AMAX / 30, 0.2 - AMAX / 30)),      # braking at amax
]


@pytest.mark.parametrize("filt, limit", [(safety_filter, limit_wheels_v),
                                         (safety_filter_reference, limit_wheels_v_reference)])
@pytest.mark.parametrize("prev, nominal, stop, sent", STOP_CASES)
def test_a_stop_from_the_filter_is_not_undone_by_the_wheel_limiter(filt, limit, prev, nominal, stop, sent):
    prev, one = np.array([prev]), np.ones(1)
    x, info = filt(np.zeros((1, 3)), 0.05, np.array([nominal]), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX,
                   obstacles=SQUEEZE, wheel_accel_max_m_s2=AMAX, wheels_prev_m_s=prev, params=SafetyParams())
    assert info.n_softened == 1 and info.n_accel_relaxed == 1 and info.n_stopped == 0
    np.testing.assert_allclose(x, [stop], rtol=0, atol=1e-12)         # v = 0: closes on neither obstacle
    out = limit(x, prev, 1 / 30, VMAX * one, AMAX * one)
    np.testing.assert_allclose(out, [sent], rtol=0, atol=1e-12)
    # never faster toward either obstacle than the previous command, nor than braking at amax allows
    assert abs(out[0].sum()) <= max(abs(x[0].sum()), abs(prev[0].sum()) - 2 * AMAX / 30) + 1e-12


def _gaps(poses, radius, obstacles):
    """The smallest gap between two bodies or a body and an obstacle, for each of the fleet's poses (k, n, 3)."""
    x, y = poses[:, :, 0], poses[:, :, 1]
    n = poses.shape[1]
    d = np.hypot(x[:, :, None] - x[:, None, :], y[:, :, None] - y[:, None, :])
    d = d - (radius[:, None] + radius[None, :])
    d[:, np.arange(n), np.arange(n)] = np.inf
    g = d.min(axis=(1, 2)) if n > 1 else np.full(len(poses), np.inf)
    if len(obstacles):
        do = np.hypot(x[:, :, None] - obstacles[:, 0], y[:, :, None] - obstacles[:, 1])
        g = np.minimum(g, (do - obstacles[:, 2] - radius[:, None]).min(axis=(1, 2)))
    return g


@pytest.mark.parametrize("offset_m", [0.0, 0.03])
@settings(max_examples=30, deadline=None, derandomize=True)
@given(st.integers(2, 12), st.integers(0, 2 ** 32 - 1), st.integers(0, 4))
def test_no_body_touches_another_or_an_obstacle_over_ten_seconds_of_random_nominal_commands(offset_m, n, seed, k):
    """Integrated with the exact arcs (4 substeps a tick, checked at each) under 2 mm tracker noise:
    bodies that start clear stay clear, whatever the nominal commands ask."""
    rng = np.random.default_rng(seed)
    radius = rng.uniform(0.03, 0.07, n)
    obstacles = np.c_[rng.uniform(-0.6, 0.6, (k, 2)), rng.uniform(0.05, 0.2, k)]
    pose = []
    while len(pose) < n:
        p = np.r_[rng.uniform(-0.6, 0.6, 2), rng.uniform(-math.pi, math.pi)]
        i = len(pose)
        ok = all(np.hypot(*(p[:2] - q[:2])) > radius[i] + radius[j] + 0.015 for j, q in enumerate(pose))
        ok = ok and all(np.hypot(*(p[:2] - o[:2])) > radius[i] + o[2] + 0.015 for o in obstacles)
        if ok:
            pose.append(p)
    pose = np.array(pose)
    dt = 1 / 30
    params = SafetyParams(margin_m=0.015, gamma_per_s=5.0, offset_m=offset_m, dt_s=dt)
    base = np.full(n, BASE)
    prev = np.zeros((n, 2))
    for tick in range(300):
        if tick % 30 == 0:
            nominal = rng.uniform(-VMAX, VMAX, (n, 2))
        noisy = pose + np.c_[rng.normal(0, 0.002, (n, 2)), rng.normal(0, 0.005, n)]
        out, _ = safety_filter(noisy, radius, nominal, wheel_base_m=base, wheel_speed_max_m_s=np.full(n, VMAX),
                               obstacles=obstacles, wheel_accel_max_m_s2=np.full(n, AMAX),
                               wheels_prev_m_s=prev, params=params)
        prev = out
        substeps = []
        for _ in range(4):
            pose = integrate_arcs(pose, out, dt / 4, base)
            substeps.append(pose)
        gaps = _gaps(np.stack(substeps), radius, obstacles)   # each substep's, at once
        assert (gaps > 0.0).all(), (tick, gaps)


def test_identical_inputs_give_identical_bits():
    rng = np.random.default_rng(5)
    pose = np.c_[rng.uniform(-0.4, 0.4, (40, 2)), rng.uniform(-3, 3, 40)]
    nominal = rng.uniform(-0.3, 0.3, (40, 2))
    a, ia = safety_filter(pose, 0.05, nominal, wheel_base_m=BASE, wheel_speed_max_m_s=VMAX)
    b, ib = safety_filter(pose.copy(), 0.05, nominal.copy(), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX)
    assert a.tobytes() == b.tobytes() and ia == ib


def test_an_empty_fleet_gives_an_empty_result():
    out, info = safety_filter(np.zeros((0, 3)), 0.05, np.zeros((0, 2)), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX)
    assert out.shape == (0, 2) and info == SafetyInfo(0, 0, 0, 0, 0)


BAD = [
    (dict(pose_world=np.zeros((2, 2))), ShapeError),
    (dict(wheels_nominal_m_s=np.zeros((3, 2))), ShapeError),
    (dict(radius_m=np.zeros(3)), ShapeError),
    (dict(obstacles=np.zeros((2, 2))), ShapeError),
    (dict(active=np.ones(3, bool)), ShapeError),
    (dict(pose_world=np.array([[0.0, math.nan, 0.0], [1, 1, 0]])), NonFiniteError),
    (dict(wheels_nominal_m_s=np.array([[math.inf, 0.0], [0, 0]])), NonFiniteError),
    (dict(pose_world=np.array([[1e300, 0.0, 0.0], [1, 1, 0]])), NonFiniteError),
    (dict(obstacles=np.array([[0.0, 0.0, math.nan]])), NonFiniteError),
    (dict(radius_m=-0.01), SafetyParamError),
    (dict(obstacles=np.array([[0.0, 0.0, -1.0]])), SafetyParamError),
    (dict(wheel_base_m=0.0), SafetyParamError),
    (dict(wheel_speed_max_m_s=-1.0), SafetyParamError),
    (dict(wheel_accel_max_m_s2=0.8), SafetyParamError),              # without wheels_prev_m_s
    (dict(wheel_accel_max_m_s2=0.0, wheels_prev_m_s=np.zeros((2, 2))), SafetyParamError),
    (dict(params="fast"), SafetyParamError),
]


@pytest.mark.parametrize("change, error", BAD)
def test_bad_input_is_refused_with_a_typed_error_by_both(change, error):
    args = dict(pose_world=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), radius_m=0.05,
                wheels_nominal_m_s=np.zeros((2, 2)), wheel_base_m=BASE, wheel_speed_max_m_s=VMAX)
    args.update(change)
    for fn in (safety_filter, safety_filter_reference):
        with pytest.raises(error):
            fn(**args)
    assert issubclass(error, VsfleetValueError)


@pytest.mark.parametrize("kw, error", [
    (dict(margin_m=-0.1), SafetyParamError), (dict(gamma_per_s=0.0), SafetyParamError),
    (dict(gamma_per_s=60.0), SafetyParamError),          # gamma dt > 1 at 30 Hz
    (dict(offset_m=-0.01), SafetyParamError), (dict(dt_s=0.0), SafetyParamError),
    (dict(margin_m=math.nan), NonFiniteError), (dict(dt_s=math.inf), NonFiniteError),
])
def test_bad_parameters_are_refused_when_made(kw, error):
    with pytest.raises(error):
        SafetyParams(**kw)


def test_the_core_refuses_what_slips_past_the_fast_path_with_the_typed_error():
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    kw = dict(wheel_base_m=np.full(2, BASE), wheel_speed_max_m_s=np.array([VMAX, -1.0]))
    with pytest.raises(SafetyParamError):
        safety_filter(pose, np.full(2, 0.05), np.zeros((2, 2)), **kw)
    kw["wheel_speed_max_m_s"] = np.array([VMAX, math.nan])
    with pytest.raises(NonFiniteError):
        safety_filter(pose, np.full(2, 0.05), np.zeros((2, 2)), **kw)
