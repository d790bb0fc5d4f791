"""One tick of differential-drive motion: exact arcs, their inverse, and the wheel limiter."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from vsfleet.envelope import Envelope
from vsfleet.errors import NonFiniteError, VsfleetValueError
from vsfleet.geometry import Pose2, angle_diff
from vsfleet.kinematics import (
    TimeStepError,
    integrate_arc,
    inverse_arc,
    limit_wheels,
    twist_from_wheels,
    wheels_from_twist,
)

B = 0.1  # wheel base [m]
DT = 1.0 / 30.0
ENV = Envelope(B, 0.3, 1.0)

coord = st.floats(-2.0, 2.0, allow_nan=False)
heading = st.floats(-math.pi, math.pi, allow_nan=False)
wheel = st.floats(-0.5, 0.5, allow_nan=False)
poses = st.builds(Pose2, coord, coord, heading)


def rk4(pose: Pose2, vl: float, vr: float, dt: float, b: float, steps: int = 2000) -> Pose2:
    """Reference: RK4 on x' = v cos th, y' = v sin th, th' = w with constant wheel speeds."""
    v, w = (vl + vr) / 2, (vr - vl) / b
    state = np.array([pose.x, pose.y, pose.th])

    def f(s):
        return np.array([v * math.cos(s[2]), v * math.sin(s[2]), w])

    h = dt / steps
    for _ in range(steps):
        k1 = f(state)
        k2 = f(state + h / 2 * k1)
        k3 = f(state + h / 2 * k2)
        k4 = f(state + h * k3)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return Pose2(*state)


def assert_pose_close(a: Pose2, b: Pose2, tol: float) -> None:
    assert abs(a.x - b.x) <= tol and abs(a.y - b.y) <= tol
    assert abs(angle_diff(a.th, b.th)) <= tol


# --- integrate_arc ------------------------------------------------------------------


@pytest.mark.parametrize(
    "vl, vr, dt",
    [
        (0.2, 0.3, DT),
        (0.3, -0.1, 0.5),
        (-0.2, -0.25, 1.0),
        (0.1, 0.1, 2.0),
        (0.3, -0.3, 1.0),
        (0.05, 0.3, 3.0),
    ],
)
def test_integrate_arc_matches_a_fine_rk4_integration(vl, vr, dt):
    start = Pose2(0.3, -0.2, 2.5)
    assert_pose_close(integrate_arc(start, vl, vr, dt, B), rk4(start, vl, vr, dt, B), 1e-10)


@settings(max_examples=40, deadline=None)
@given(poses, wheel, wheel, st.floats(0.0, 1.0))
def test_integrate_arc_matches_rk4_for_any_wheel_speeds(pose, vl, vr, dt):
    assert_pose_close(integrate_arc(pose, vl, vr, dt, B), rk4(pose, vl, vr, dt, B, steps=400), 1e-9)


def test_integrate_arc_agrees_with_the_paper_eqs_12_13_17_18():
    # Eq 17 with r = b/2: th = (vr - vl) dt / b (CCW); eq 18: R = (vl + vr) dt / (2 th);
    # eqs 12-13 in the robot frame: dx = R sin th, dy = R (1 - cos th).
    vl, vr, dt = 0.12, 0.27, 0.4
    th = (vr - vl) * dt / B
    r = (vl + vr) * dt / (2 * th)
    end = integrate_arc(Pose2(0, 0, 0), vl, vr, dt, B)
    assert end.x == pytest.approx(r * math.sin(th), abs=1e-15)
    assert end.y == pytest.approx(r * (1 - math.cos(th)), abs=1e-15)
    assert end.th == pytest.approx(th, abs=1e-15)


def test_faster_right_wheel_turns_left():
    end = integrate_arc(Pose2(0, 0, 0), 0.1, 0.2, 0.5, B)
    assert end.th > 0 and end.y > 0


def test_equal_wheel_speeds_drive_an_exact_straight_line():
    start = Pose2(1.0, -2.0, 0.7)
    end = integrate_arc(start, 0.25, 0.25, 2.0, B)
    assert end.x == pytest.approx(1.0 + 0.5 * math.cos(0.7), abs=1e-15)
    assert end.y == pytest.approx(-2.0 + 0.5 * math.sin(0.7), abs=1e-15)
    assert end.th == start.th


def test_opposite_wheel_speeds_spin_in_place():
    start = Pose2(0.4, 0.5, -1.0)
    end = integrate_arc(start, -0.1, 0.1, 0.5, B)
    assert (end.x, end.y) == (start.x, start.y)
    assert angle_diff(end.th, start.th) == pytest.approx(0.2 / B * 0.5, abs=1e-15)


@pytest.mark.parametrize("w_rad_s", [1e-12, -1e-12, 1e-9, 3e-6])
def test_integrate_arc_is_continuous_across_zero_turn_rate(w_rad_s):
    start = Pose2(0.1, 0.2, 0.3)
    v = 0.2
    straight = integrate_arc(start, *wheels_from_twist(v, 0.0, B), 1.0, B)
    curved = integrate_arc(start, *wheels_from_twist(v, w_rad_s, B), 1.0, B)
    # First order in w: the lateral offset is v dt^2 w / 2, the heading change w dt.
    assert math.hypot(curved.x - straight.x, curved.y - straight.y) <= abs(w_rad_s) * v + 1e-16
    assert abs(angle_diff(curved.th, straight.th)) <= abs(w_rad_s) + 1e-16


def test_integrate_arc_is_smooth_where_the_series_takes_over():
    # |w dt / 2| crosses the series threshold 1e-4 at w = 2e-4: no step in x or y there.
    start = Pose2(0, 0, 0)
    ws = np.linspace(-3e-4, 3e-4, 61)
    ends = [integrate_arc(start, *wheels_from_twist(0.3, w, B), 1.0, B) for w in ws]
    for values in ([e.x for e in ends], [e.y for e in ends]):
        second_diff = np.diff(values, 2)
        assert np.ptp(second_diff) < 1e-14


# --- twist <-> wheels ---------------------------------------------------------------


@settings(max_examples=50, deadline=None)
@given(wheel, wheel, st.floats(0.05, 0.5))
def test_twist_and_wheels_round_trip(vl, vr, b):
    v, w = twist_from_wheels(vl, vr, b)
    back = wheels_from_twist(v, w, b)
    assert back == pytest.approx((vl, vr), abs=1e-15)


def test_twist_from_wheels_is_mean_speed_and_ccw_turn_rate():
    assert twist_from_wheels(0.1, 0.3, 0.1) == pytest.approx((0.2, 2.0))


# --- inverse_arc --------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(
    poses,
    st.floats(-1.0, 1.0, allow_nan=False),
    st.floats(-1.0, 1.0, allow_nan=False),
    st.sampled_from([1.0, 1e-3, 1e-6, 1e-9]),
    st.sampled_from([DT, 0.5]),
)
def test_inverse_arc_then_integrate_arc_reaches_the_target(pose, dx, dy, scale, dt):
    target = (pose.x + dx * scale, pose.y + dy * scale)
    vl, vr = inverse_arc(pose, target, dt, B)
    end = integrate_arc(pose, vl, vr, dt, B)
    assert math.hypot(end.x - target[0], end.y - target[1]) <= 1e-9


@settings(max_examples=60, deadline=None)
@given(poses, st.floats(0.01, 1.0), st.floats(-math.pi, math.pi))
def test_inverse_arc_reverses_to_targets_behind_and_turns_at_most_half_a_circle(pose, dist, bearing):
    target = pose.apply(np.array([dist * math.cos(bearing), dist * math.sin(bearing)]))
    v, w = twist_from_wheels(*inverse_arc(pose, target, DT, B), B)
    if math.cos(bearing) < -1e-9:
        assert v < 0
    elif math.cos(bearing) > 1e-9:
        assert v > 0
    assert abs(w * DT) <= math.pi + 1e-12


@pytest.mark.parametrize(
    "target, expected",
    [
        ((0.1, 0.0), (3.0, 3.0)),  # straight ahead
        ((-0.1, 0.0), (-3.0, -3.0)),  # straight behind: reverse
        ((0.0, 0.0), (0.0, 0.0)),  # already there
    ],
)
def test_inverse_arc_special_targets(target, expected):
    assert inverse_arc(Pose2(0, 0, 0), target, DT, B) == pytest.approx(expected, abs=1e-12)


def test_inverse_arc_to_a_point_abeam_drives_a_forward_half_circle():
    vl, vr = inverse_arc(Pose2(0, 0, 0), (0.0, 0.2), 1.0, B)
    v, w = twist_from_wheels(vl, vr, B)
    assert v == pytest.approx(0.1 * math.pi)  # half of a circle of radius 0.1 m
    assert w == pytest.approx(math.pi)


def test_inverse_arc_is_continuous_through_straight_ahead():
    a = inverse_arc(Pose2(0, 0, 0), (0.1, 1e-13), DT, B)
    b = inverse_arc(Pose2(0, 0, 0), (0.1, 0.0), DT, B)
    assert a == pytest.approx(b, abs=1e-9)


@pytest.mark.parametrize("dt", [0.0, -0.1, math.inf, math.nan])
def test_inverse_arc_rejects_a_bad_time_step(dt):
    with pytest.raises(TimeStepError):
        inverse_arc(Pose2(0, 0, 0), (1.0, 0.0), dt, B)


def test_inverse_arc_rejects_a_non_finite_target():
    with pytest.raises(NonFiniteError):
        inverse_arc(Pose2(0, 0, 0), (math.nan, 0.0), DT, B)


# --- limit_wheels -------------------------------------------------------------------

SPEED_MAX, STEP_MAX = ENV.wheel_speed_max_m_s, ENV.wheel_accel_max_m_s2 * DT
SLACK = 1e-12


def within_limits(out, prev) -> bool:
    return all(
        abs(o) <= SPEED_MAX * (1 + SLACK) and abs(o - p) <= STEP_MAX * (1 + SLACK) for o, p in zip(out, prev)
    )


def feasible_scales(cmd, prev, n: int = 2001) -> np.ndarray:
    """Independent check: the scales s on a fine grid of [0, 1] where s * cmd is feasible."""
    s = np.linspace(0.0, 1.0, n)
    ok = np.ones_like(s, dtype=bool)
    for c, p in zip(cmd, prev):
        ok &= (np.abs(s * c) <= SPEED_MAX) & (np.abs(s * c - p) <= STEP_MAX)
    return s[ok]


commands = st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
prevs = st.tuples(st.floats(-SPEED_MAX, SPEED_MAX), st.floats(-SPEED_MAX, SPEED_MAX))


@settings(max_examples=300, deadline=None)
@given(commands, prevs)
def test_limit_wheels_never_exceeds_speed_or_acceleration_limits(cmd, prev):
    out = limit_wheels(*cmd, prev, DT, ENV)
    assert within_limits(out, prev)


@settings(max_examples=200, deadline=None)
@given(commands, prevs)
def test_limit_wheels_keeps_the_curvature_whenever_a_feasible_scaling_exists(cmd, prev):
    scales = feasible_scales(cmd, prev)
    assume(scales.size > 0)
    out = limit_wheels(*cmd, prev, DT, ENV)
    norm = math.hypot(*cmd)
    if norm == 0.0:
        assert out == (0.0, 0.0)
        return
    cross = cmd[0] * out[1] - cmd[1] * out[0]
    assert abs(cross) <= 1e-12 * max(norm, 1.0)  # parallel: vl : vr kept
    assert cmd[0] * out[0] + cmd[1] * out[1] >= -1e-15  # same direction, not reversed
    s_out = math.hypot(*out) / norm
    assert s_out >= scales.max() - 1e-12  # and the largest such scale


@settings(max_examples=100, deadline=None)
@given(prevs, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_limit_wheels_returns_a_feasible_command_unchanged(prev, a, b):
    cmd = (
        max(-SPEED_MAX, min(SPEED_MAX, prev[0] + a * STEP_MAX)),
        max(-SPEED_MAX, min(SPEED_MAX, prev[1] + b * STEP_MAX)),
    )
    assert limit_wheels(*cmd, prev, DT, ENV) == cmd


def slowest_reachable(p: float) -> float:
    """The wheel speed nearest zero within one tick of p (prev within the speed box)."""
    return min(max(0.0, max(p - STEP_MAX, -SPEED_MAX)), min(p + STEP_MAX, SPEED_MAX))


@settings(max_examples=400, deadline=None)
@given(commands, prevs)
def test_limit_wheels_never_drives_a_wheel_beyond_its_command_unless_it_cannot_brake_harder(cmd, prev):
    """Each wheel ends between zero and its command, or (when one tick cannot get it there) at the
    slowest speed it can reach: a stop or a slow-down (the safety filter's) is never undone."""
    out = limit_wheels(*cmd, prev, DT, ENV)
    for o, c, p in zip(out, cmd, prev):
        between = min(0.0, c) - 1e-15 <= o <= max(0.0, c) + 1e-15
        assert between or o == pytest.approx(slowest_reachable(p), abs=1e-15), (o, c, p)


def test_limit_wheels_does_not_turn_a_command_in_place_into_motion_ahead():
    # from 0.2 m/s straight ahead, asked to turn in place (v = 0): the corner rule kept the left wheel
    # at speed, even sped it up (0.2267, 0.1733: v = 0.2, no braking); now both wheels brake at amax
    out = limit_wheels(0.05, -0.05, (0.2, 0.2), DT, ENV)
    assert out == pytest.approx((0.2 - STEP_MAX, 0.2 - STEP_MAX), abs=1e-15)
    out = limit_wheels(0.01, 0.0, (0.2, 0.2), DT, ENV)   # nearly a stop: was (0.2 + STEP_MAX, 0.2 - STEP_MAX)
    assert out == pytest.approx((0.2 - STEP_MAX, 0.2 - STEP_MAX), abs=1e-15)


def test_limit_wheels_lets_a_stop_through_when_the_previous_command_lies_beyond_the_speed_limit():
    # the accel box and the speed box do not meet: the accel limit yields (as in the safety filter,
    # n_accel_relaxed) and the speed box alone limits the command; the wheel was pinned at +vmax
    assert limit_wheels(0.0, 0.0, (0.5, 0.5), DT, ENV) == (0.0, 0.0)
    assert limit_wheels(0.1, -0.1, (0.5, 0.2), DT, ENV) == (0.1, -0.1)


def test_limit_wheels_scales_a_too_fast_command_down_along_its_ray():
    prev = (0.29, 0.145)
    out = limit_wheels(0.6, 0.3, prev, DT, ENV)
    assert out == pytest.approx((0.3, 0.15), abs=1e-15)


def test_limit_wheels_brakes_every_wheel_when_it_cannot_slow_down_enough():
    # the ray is reachable only at s > 1 (2.67 u): keeping the curvature there held the right wheel at
    # 0.1333 (braking 0.0167 where it could brake 0.0333); both wheels now brake at their limit
    prev = (0.3, 0.15)
    out = limit_wheels(0.1, 0.05, prev, DT, ENV)
    assert out == pytest.approx((0.3 - STEP_MAX, 0.15 - STEP_MAX), abs=1e-15)
    # and a wheel whose command the box reaches gets it, however the other one brakes
    assert limit_wheels(0.1, 0.14, prev, DT, ENV) == pytest.approx((0.3 - STEP_MAX, 0.14), abs=1e-15)


def test_limit_wheels_turns_as_far_toward_an_unreachable_curvature_as_one_tick_allows():
    # Spinning left from full speed straight ahead: no scaling of (-0.3, 0.3) is reachable
    # in one tick, so the left wheel brakes fully and the right one keeps its speed.
    prev = (0.3, 0.3)
    out = limit_wheels(-0.3, 0.3, prev, DT, ENV)
    assert out == pytest.approx((0.3 - STEP_MAX, 0.3), abs=1e-15)
    assert within_limits(out, prev)


def test_limit_wheels_brakes_hardest_when_the_ray_points_away_from_the_current_motion():
    prev = (0.3, 0.3)
    out = limit_wheels(-0.2, -0.2, prev, DT, ENV)
    assert out == pytest.approx((0.3 - STEP_MAX, 0.3 - STEP_MAX), abs=1e-15)


def test_limit_wheels_accepts_a_zero_command_and_brakes_toward_it():
    assert limit_wheels(0.0, 0.0, (0.2, -0.2), DT, ENV) == pytest.approx(
        (0.2 - STEP_MAX, -0.2 + STEP_MAX), abs=1e-15
    )


def test_limit_wheels_prefers_the_speed_limit_when_prev_is_far_outside_it():
    out = limit_wheels(1.0, 1.0, (0.5, 0.5), DT, ENV)
    assert out == pytest.approx((SPEED_MAX, SPEED_MAX))


@pytest.mark.parametrize("bad", [(math.nan, 0.0), (0.0, math.inf)])
def test_limit_wheels_rejects_non_finite_commands(bad):
    with pytest.raises(NonFiniteError):
        limit_wheels(*bad, (0.0, 0.0), DT, ENV)


def test_kinematics_errors_are_value_errors():
    assert issubclass(TimeStepError, VsfleetValueError) and issubclass(TimeStepError, ValueError)


# --- vectorised over robots -----------------------------------------------------------------


def test_limit_wheels_v_gives_the_scalar_rule_for_every_row():
    from vsfleet.kinematics import limit_wheels_v

    rng = np.random.default_rng(2)
    n = 4000
    u = rng.uniform(-1.0, 1.0, (n, 2)) * rng.choice([0.0, 0.1, 1.0], (n, 2))
    p = rng.uniform(-0.6, 0.6, (n, 2)) * rng.choice([0.0, 0.1, 1.0], (n, 2))
    u[::7] = 0.0
    u[1::11, 1] = 0.0
    out = limit_wheels_v(u, p, DT, np.full(n, ENV.wheel_speed_max_m_s), np.full(n, ENV.wheel_accel_max_m_s2))
    expected = np.array([limit_wheels(u[i, 0], u[i, 1], tuple(p[i]), DT, ENV) for i in range(n)])
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)


def test_integrate_arcs_is_integrate_arc_for_every_row():
    from vsfleet.kinematics import integrate_arcs

    rng = np.random.default_rng(3)
    pose = np.column_stack([rng.normal(0, 1, (50, 2)), rng.uniform(-3, 3, 50)])
    wheels = rng.uniform(-0.3, 0.3, (50, 2))
    wheels[::5, 1] = wheels[::5, 0]                        # straight lines too
    out = integrate_arcs(pose, wheels, DT, np.full(50, 0.1))
    for i in range(50):
        e = integrate_arc(Pose2(*pose[i]), wheels[i, 0], wheels[i, 1], DT, 0.1)
        assert out[i, :2] == pytest.approx((e.x, e.y), abs=1e-15)
        assert math.isclose(math.remainder(out[i, 2] - e.th, 2 * math.pi), 0.0, abs_tol=1e-12)
