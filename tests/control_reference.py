"""Scalar reference of the paper's controllers (the per-robot code vsfleet.control replaced); tests only.

Every controller is built by a ``make_*`` factory that fixes its gains and returns
a pure function with one signature::

    controller(pose_world, point_now_world, point_next_world, dt_s, envelope,
               wheels_prev_m_s) -> (vl_m_s, vr_m_s)

``point_now_world`` is the robot's desired structure point [m; world frame] at this
tick and ``point_next_world`` the one a tick (dt_s [s]) later, so their difference
over dt_s is the point's feed-forward velocity. The result is a pair of wheel ground
speeds [m/s] that has already passed through :func:`~vsfleet.kinematics.limit_wheels`
(the envelope's speed and acceleration limits, curvature kept).
"""

from __future__ import annotations

import math
from typing import Callable

from vsfleet.envelope import Envelope
from vsfleet.errors import VsfleetValueError
from vsfleet.geometry import Pose2
from vsfleet.kinematics import inverse_arc, limit_wheels, wheels_from_twist

Controller = Callable[
    [Pose2, tuple[float, float], tuple[float, float], float, Envelope, tuple[float, float]],
    tuple[float, float],
]


class UnknownControllerError(VsfleetValueError):
    """The controller name is not a key of :data:`CONTROLLERS`."""


class ControllerGainError(VsfleetValueError):
    """A controller gain is not a finite number in its allowed range."""


def _gain(name: str, value: float, *, allow_zero: bool = False) -> float:
    """A gain as float, checked finite and > 0 (or >= 0 with allow_zero)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ControllerGainError(f"{name} must be a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or (value == 0.0 and not allow_zero):
        raise ControllerGainError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")
    return value


def _robot_frame(pose: Pose2, point_world) -> tuple[float, float]:
    """A world point [m] in the robot frame [m; +x ahead, +y to the left]."""
    wx, wy = float(point_world[0]) - pose.x, float(point_world[1]) - pose.y
    c, s = math.cos(pose.th), math.sin(pose.th)
    return (c * wx + s * wy, -s * wx + c * wy)


def _ahead(point_now_world, point_next_world, ticks: float) -> tuple[float, float]:
    """The point extrapolated ``ticks`` ticks ahead: now + ticks (next - now) [m; world]."""
    nx, ny = float(point_now_world[0]), float(point_now_world[1])
    return (nx + ticks * (float(point_next_world[0]) - nx), ny + ticks * (float(point_next_world[1]) - ny))


def _horizon_ticks(horizon_s: float, dt_s: float) -> float:
    """A look-ahead time [s] in ticks of dt_s [s], never less than one tick."""
    return max(1.0, horizon_s / dt_s)


# Share of a wheel's acceleration limit that a turn may plan to brake with.
_TURN_BRAKE_SHARE = 0.5


def _braked_turn(turn_m_s: float, angle_rad: float, envelope: Envelope) -> float:
    """Cap a turning wheel speed [m/s] so the wheels can still brake to rest within angle_rad.

    Each wheel has (b/2)|angle| [m] left to roll; stopping from speed u takes u^2 / (2 a).
    Without the cap a rate-limited turn overshoots and can cycle around the target direction.
    """
    reach_m = 0.5 * envelope.wheel_base_m * abs(angle_rad)
    cap_m_s = math.sqrt(2.0 * _TURN_BRAKE_SHARE * envelope.wheel_accel_max_m_s2 * reach_m)
    return max(-cap_m_s, min(cap_m_s, turn_m_s))


def _half_plane_angle(y: float, x: float) -> float:
    """atan(y / x) in [-pi/2, pi/2], defined at x = 0 (then +-pi/2 by the sign of y)."""
    if x == 0.0:
        return math.copysign(0.5 * math.pi, y) if y != 0.0 else 0.0
    return math.atan(y / x)


# Defaults: d_max_m / horizon_s = 0.3 m/s, the speed cap; a 0.25 s look-ahead damps the
# heading loop (horizon 0, the paper's, oscillates around the path; see tests/test_control.py).
def make_turn_then_go(
    turn_gain_m_s_per_rad: float = 1.0,
    d_max_m: float = 0.075,
    horizon_s: float = 0.25,
    turn_fade_radius_m: float = 0.001,
    allow_reverse: bool = True,
) -> Controller:
    """Paper eqs 9-11, CCW: vl = v - K th_err, vr = v + K th_err [m/s], K in m/s per rad.

    Aims at the point extrapolated horizon_s [s] ahead (>= 1 tick; 0 is the paper's point_next):
    v = min(d_max_m, dist) / horizon * (Hc . Hd); th_err = atan(Hc x Hd / Hc . Hd) (reverse when
    the target is behind), or atan2 if not allow_reverse. The turn is capped to brake in time.
    """
    turn_gain = _gain("turn_gain_m_s_per_rad", turn_gain_m_s_per_rad)
    d_max = _gain("d_max_m", d_max_m)
    horizon = _gain("horizon_s", horizon_s, allow_zero=True)
    fade = _gain("turn_fade_radius_m", turn_fade_radius_m)

    def turn_then_go(pose_world, point_now_world, point_next_world, dt_s, envelope, wheels_prev_m_s):
        h = _horizon_ticks(horizon, dt_s)
        dx, dy = _robot_frame(pose_world, _ahead(point_now_world, point_next_world, h))
        dist_m = math.hypot(dx, dy)
        if dist_m == 0.0:
            vl, vr = 0.0, 0.0
        else:
            # In the robot frame Hc = (1, 0), so Hc x Hd = dy / dist and Hc . Hd = dx / dist.
            th_err = _half_plane_angle(dy, dx) if allow_reverse else math.atan2(dy, dx)
            v = min(d_max, dist_m) / (h * dt_s) * (dx / dist_m)
            # Within turn_fade_radius_m of the target its direction is noise: fade the turn out.
            turn = _braked_turn(turn_gain * th_err, th_err, envelope) * min(1.0, dist_m / fade)
            vl, vr = v - turn, v + turn
        return limit_wheels(vl, vr, wheels_prev_m_s, dt_s, envelope)

    return turn_then_go


def make_arc(horizon_s: float = 1.0) -> Controller:
    """Paper eqs 12-16: wheel speeds [m/s] of the arc that reaches the point in time.

    Target: the point extrapolated horizon_s [s] ahead (>= 1 tick; 0 is the paper's point_next
    in dt_s, whose heading error flips sign every tick). See :func:`~vsfleet.kinematics.inverse_arc`.
    """
    horizon = _gain("horizon_s", horizon_s, allow_zero=True)

    def arc(pose_world, point_now_world, point_next_world, dt_s, envelope, wheels_prev_m_s):
        h = _horizon_ticks(horizon, dt_s)
        target = _ahead(point_now_world, point_next_world, h)
        vl, vr = inverse_arc(pose_world, target, h * dt_s, envelope.wheel_base_m)
        return limit_wheels(vl, vr, wheels_prev_m_s, dt_s, envelope)

    return arc


# Defaults: lateral error dynamics s^2 + v_r kth s + v_r^2 ky, so at v_r = 0.1 m/s the natural
# frequency is v_r sqrt(ky) = 5 rad/s with damping kth / (2 sqrt(ky)) = 1; kx = 2 /s along.
def make_tracking(
    along_gain_per_s: float = 2.0,
    lateral_gain_per_m2: float = 2500.0,
    heading_gain_per_m: float = 100.0,
    regulate_gain_per_s: float = 5.0,
    regulate_radius_m: float = 0.005,
    moving_speed_m_s: float = 0.02,
) -> Controller:
    """Kanayama et al. (1990) tracking with feed-forward, blended into point regulation at rest.

    Reference: point_now [m; world], heading and speed v_r of f = (next - now) / dt_s; e is the
    error in the robot frame. v = f.Hc + kx e_x; w = lam v_r (ky e_y + kth 2 sin(e_th/2)) +
    (1 - lam) w_reg, lam = min(1, v_r / moving_speed_m_s); w_reg turns either end toward f + kx e.
    """
    kx = _gain("along_gain_per_s", along_gain_per_s)
    ky = _gain("lateral_gain_per_m2", lateral_gain_per_m2)
    kth = _gain("heading_gain_per_m", heading_gain_per_m)
    k_reg = _gain("regulate_gain_per_s", regulate_gain_per_s)
    u_fade = kx * _gain("regulate_radius_m", regulate_radius_m)
    v_moving = _gain("moving_speed_m_s", moving_speed_m_s)

    def tracking(pose_world, point_now_world, point_next_world, dt_s, envelope, wheels_prev_m_s):
        ex, ey = _robot_frame(pose_world, point_now_world)
        c, s = math.cos(pose_world.th), math.sin(pose_world.th)
        fwx = (float(point_next_world[0]) - float(point_now_world[0])) / dt_s
        fwy = (float(point_next_world[1]) - float(point_now_world[1])) / dt_s
        fx, fy = c * fwx + s * fwy, -s * fwx + c * fwy  # feed-forward velocity, robot frame
        v_ref = math.hypot(fx, fy)
        lam = min(1.0, v_ref / v_moving)
        # Identical in both laws: Kanayama's v_r cos(e_th) is the feed-forward along the heading.
        v = fx + kx * ex
        w = 0.0
        if lam > 0.0:
            e_th = math.atan2(fy, fx)  # reference heading minus robot heading
            # 2 sin(e_th / 2) for Kanayama's sin(e_th): the same near 0, but a robot facing
            # backwards turns round instead of resting at sin(pi) = 0. At low speed it is blended
            # back toward sin(e_th), which is continuous at pi, so that the regulation term
            # (which may drive in reverse) and this one do not fight across the +-pi jump.
            sin_e = math.sin(e_th)
            heading = sin_e + lam**4 * (2.0 * math.sin(0.5 * e_th) - sin_e)
            w += lam * v_ref * (ky * ey + kth * heading)
        if lam < 1.0:
            ux, uy = v, fy + kx * ey  # the velocity a holonomic robot would command
            u = math.hypot(ux, uy)
            if u > 0.0:
                alpha = _half_plane_angle(uy, ux)
                half_b = 0.5 * envelope.wheel_base_m
                turn = _braked_turn(k_reg * alpha * half_b, alpha, envelope) / half_b
                w += (1.0 - lam) * turn * min(1.0, u / u_fade)
        vl, vr = wheels_from_twist(v, w, envelope.wheel_base_m)
        return limit_wheels(vl, vr, wheels_prev_m_s, dt_s, envelope)

    return tracking


CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "turn_then_go": make_turn_then_go,
    "arc": make_arc,
    "tracking": make_tracking,
}

# Measured in tests/test_control.py (see test_default_controller_converges_fastest):
# fastest worst-case convergence over the start grid, sub-millimetre steady error.
DEFAULT_CONTROLLER = "arc"


def with_deadband(controller: Controller, deadband_m: float = 0.004,
                  still_speed_m_s: float = 0.003) -> Controller:
    """Hold still while the point rests and the robot is within deadband_m [m] of it.

    A robot at rest on its point would otherwise chase the tracker's noise (a few mm
    sideways means a turn on the spot). "Rests" means the point moves slower than
    still_speed_m_s [m/s]. The command then brakes to zero within the envelope.
    """
    deadband = float(deadband_m)
    still = float(still_speed_m_s)
    if not (math.isfinite(deadband) and deadband >= 0.0 and math.isfinite(still) and still >= 0.0):
        raise ControllerGainError("deadband_m and still_speed_m_s must be finite and >= 0")

    def held(pose_world, point_now_world, point_next_world, dt_s, envelope, wheels_prev_m_s):
        step_m = math.hypot(float(point_next_world[0]) - float(point_now_world[0]),
                            float(point_next_world[1]) - float(point_now_world[1]))
        dist_m = math.hypot(float(point_now_world[0]) - pose_world.x, float(point_now_world[1]) - pose_world.y)
        if step_m <= still * dt_s and dist_m <= deadband:
            return limit_wheels(0.0, 0.0, wheels_prev_m_s, dt_s, envelope)
        return controller(pose_world, point_now_world, point_next_world, dt_s, envelope, wheels_prev_m_s)

    return held


def make_controller(name: str, deadband_m: float = 0.004, **gains: float) -> Controller:
    """Build the controller registered as ``name`` with keyword gains (see its factory).

    The result holds still within ``deadband_m`` [m] of a resting point (see with_deadband);
    deadband_m = 0 gives the bare controller. Raises UnknownControllerError for an unknown
    name and TypeError for an unknown gain.
    """
    try:
        factory = CONTROLLERS[name]
    except KeyError:
        raise UnknownControllerError(
            f"unknown controller {name!r}; known: {', '.join(sorted(CONTROLLERS))}"
        ) from None
    controller = factory(**gains)
    return with_deadband(controller, deadband_m) if deadband_m > 0.0 else controller
