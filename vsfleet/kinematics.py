"""Differential-drive kinematics over one control tick (Tan & Lewis 1996, eqs 12-18).

Conventions: SI units, world frame, headings in radians CCW from +x. A robot
pose is a :class:`~vsfleet.geometry.Pose2`; wheel speeds are ground speeds
[m/s], left then right. ``vr > vl`` turns left (CCW), which is also the sign of
the paper's eq 17 once its ``-2r`` is read as ``-(wheel base)``.

Within one tick the wheel speeds are constant, so the robot moves along a
circular arc (a straight line when ``vl == vr``). :func:`integrate_arc` is that
motion, exactly; :func:`inverse_arc` is its inverse for a target point.
"""

from __future__ import annotations

import math
from functools import lru_cache

from .lazy import lazy_numpy
from . import _core
from .coreconst import CORNER_TIE_RAD, SINC_SERIES_BELOW as _SINC_SERIES_BELOW  # vs_kin.h's
from .envelope import Envelope
from .errors import NonFiniteError, ShapeError, VsfleetValueError
from .geometry import Pose2

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

# Below this |x| the series of sin(x)/x is used; its error there is < 1e-24.


class TimeStepError(VsfleetValueError):
    """A time step is not finite and > 0."""


def _sinc(x: float) -> float:
    """sin(x)/x, smooth through x = 0 (series near 0, no division by zero)."""
    if abs(x) < _SINC_SERIES_BELOW:
        x2 = x * x
        return 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0)
    return math.sin(x) / x


def _check_dt(dt_s: float) -> float:
    dt_s = float(dt_s)
    if not math.isfinite(dt_s) or dt_s <= 0.0:
        raise TimeStepError(f"dt_s must be finite and > 0, got {dt_s!r}")
    return dt_s


def _check_finite(**values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise NonFiniteError(f"{name} must be finite, got {value!r}")


def twist_from_wheels(vl_m_s: float, vr_m_s: float, wheel_base_m: float) -> tuple[float, float]:
    """Wheel ground speeds (vl, vr) [m/s] -> body twist (v [m/s], w [rad/s, CCW]).

    v = (vl + vr) / 2, w = (vr - vl) / wheel_base_m (paper eqs 17-18 per unit time).
    """
    return (0.5 * (vl_m_s + vr_m_s), (vr_m_s - vl_m_s) / wheel_base_m)


def wheels_from_twist(v_m_s: float, w_rad_s: float, wheel_base_m: float) -> tuple[float, float]:
    """Body twist (v [m/s], w [rad/s, CCW]) -> wheel ground speeds (vl, vr) [m/s].

    The inverse of :func:`twist_from_wheels`: vl = v - w b/2, vr = v + w b/2.
    """
    half = 0.5 * w_rad_s * wheel_base_m
    return (v_m_s - half, v_m_s + half)


def integrate_arc(
    pose: Pose2, vl_m_s: float, vr_m_s: float, dt_s: float, wheel_base_m: float
) -> Pose2:
    """Pose [world frame] after driving constant wheel speeds (vl, vr) [m/s] for dt_s [s].

    Exact arc motion (paper eqs 17-18): the chord has length v dt sinc(w dt / 2) and
    points along th + w dt / 2. Smooth through w = 0 (straight line) and v = 0 (spin).
    """
    v_m_s, w_rad_s = twist_from_wheels(vl_m_s, vr_m_s, wheel_base_m)
    dth_rad = w_rad_s * dt_s
    half_rad = 0.5 * dth_rad
    chord_m = v_m_s * dt_s * _sinc(half_rad)
    chord_dir_rad = pose.th + half_rad
    return Pose2(
        pose.x + chord_m * math.cos(chord_dir_rad),
        pose.y + chord_m * math.sin(chord_dir_rad),
        pose.th + dth_rad,
    )


def inverse_arc(
    pose: Pose2, target_xy, dt_s: float, wheel_base_m: float
) -> tuple[float, float]:
    """Constant wheel speeds (vl, vr) [m/s] that drive from ``pose`` to ``target_xy`` [m; world] in dt_s.

    The arc is tangent to the heading (paper eqs 12-16; eq 14 as printed is asin of
    cos th_arc, so the exact th_arc = 2 atan(dy/dx) is used). Targets behind (dx < 0, robot
    frame) are reached in reverse on the same circle, so |th_arc| <= pi; dx == 0 is a forward
    half circle; the own position gives (0, 0).
    """
    dt_s = _check_dt(dt_s)
    tx, ty = float(target_xy[0]), float(target_xy[1])
    _check_finite(target_x=tx, target_y=ty)
    c, s = math.cos(pose.th), math.sin(pose.th)
    wx, wy = tx - pose.x, ty - pose.y
    dx, dy = c * wx + s * wy, -s * wx + c * wy  # target in the robot frame
    dist_m = math.hypot(dx, dy)
    if dist_m == 0.0:
        return (0.0, 0.0)
    if dx >= 0.0:
        # Forward: the chord leaves at half the turn angle, beta in [-pi/2, pi/2].
        beta_rad = math.atan2(dy, dx)
        direction = 1.0
    else:
        # Reverse: the chord leaves backwards; beta measured from the robot's rear.
        beta_rad = math.atan2(-dy, -dx)
        direction = -1.0
    # Chord = v dt sinc(beta), so the signed speed is dist / (dt sinc(beta)); sinc(beta) >= 2/pi.
    v_m_s = direction * dist_m / (dt_s * _sinc(beta_rad))
    # Either way the heading turns by twice the chord's angle: th_arc = 2 beta.
    w_rad_s = 2.0 * beta_rad / dt_s
    return wheels_from_twist(v_m_s, w_rad_s, wheel_base_m)


def limit_wheels(
    vl_m_s: float,
    vr_m_s: float,
    wheels_prev_m_s: tuple[float, float],
    dt_s: float,
    envelope: Envelope,
) -> tuple[float, float]:
    """Clip a wheel command (vl, vr) [m/s] to the envelope's speed and per-tick acceleration limits.

    Feasible commands come back unchanged; otherwise the command is scaled by the largest s in
    [0, 1] that fits, keeping the curvature vl : vr. When no such s exists, see the fallback in
    :func:`_reachable_toward` (keep the curvature at s > 1, else turn toward it, else brake), bounded
    so that no wheel ends farther from zero than its command asks unless one tick cannot slow it
    more, and then at the slowest speed it can reach: braking comes before the curvature, and a stop
    or a slow-down (the safety filter's) is never turned into motion. A previous command beyond the
    speed limit (its acceleration box misses the speed box) leaves the speed box alone, as in the
    safety filter.
    """
    dt_s = _check_dt(dt_s)
    u = (float(vl_m_s), float(vr_m_s))
    p = (float(wheels_prev_m_s[0]), float(wheels_prev_m_s[1]))
    _check_finite(vl_m_s=u[0], vr_m_s=u[1], vl_prev_m_s=p[0], vr_prev_m_s=p[1])
    speed_max = envelope.wheel_speed_max_m_s
    step_max = envelope.wheel_accel_max_m_s2 * dt_s

    if all(abs(u[i]) <= speed_max and abs(u[i] - p[i]) <= step_max for i in (0, 1)):
        return (vl_m_s, vr_m_s)

    # The reachable box: the speed box intersected with the acceleration box around prev. If prev
    # is so far outside the speed box that the two do not meet (for either wheel), the acceleration
    # limit yields and the speed box alone remains, as in the safety filter (n_accel_relaxed).
    box = [(max(p[i] - step_max, -speed_max), min(p[i] + step_max, speed_max)) for i in (0, 1)]
    if any(lo > hi for lo, hi in box):
        box = [(-speed_max, speed_max)] * 2

    out = _reachable_toward(u, box)
    # No wheel ends farther from zero than its command asks unless the box forces it, and then at
    # the box's speed nearest zero: keeping (s > 1) or turning toward (a corner) the curvature never
    # costs braking, so a stop or a slow-down (the safety filter's) is never turned into motion.
    # Clamping into these bounds, within the box, also makes the limits exact against rounding.
    return tuple(_clamp(out[i], *_toward_zero(u[i], *box[i])) for i in (0, 1))


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(x, lo), hi)


def _toward_zero(u: float, lo: float, hi: float) -> tuple[float, float]:
    """The part of [lo, hi] between zero and u, or (both ends) the point of [lo, hi] nearest zero."""
    a, b = max(lo, min(0.0, u)), min(hi, max(0.0, u))
    if a > b:
        a = b = min(max(0.0, lo), hi)
    return a, b


def _reachable_toward(u: tuple[float, float], box) -> tuple[float, float]:
    """The point of the box that best follows the command u = (vl, vr) [m/s].

    1. On the ray {s u, s >= 0}: the largest s <= 1, else the smallest s > 1 (curvature kept).
    2. Else, if some point of the box lies within 90 deg of u: the box corner at the smallest
       angle to u (turn as far toward the commanded curvature as one tick allows); corners whose
       angles differ by at most CORNER_TIE_RAD tie, and the one nearer to u is taken.
    3. Else (u points away from everything reachable, e.g. a reversal): the point nearest zero.
    :func:`limit_wheels` then bounds each wheel between zero and its command (or, if the box lies
    beyond, at the box's point nearest zero): after 1 at s > 1 this is each wheel braking toward
    its command as far as the box allows.
    """
    s_lo, s_hi = 0.0, math.inf
    for ui, (lo, hi) in zip(u, box):
        if ui > 0.0:
            s_lo, s_hi = max(s_lo, lo / ui), min(s_hi, hi / ui)
        elif ui < 0.0:
            s_lo, s_hi = max(s_lo, hi / ui), min(s_hi, lo / ui)
        elif not lo <= 0.0 <= hi:
            s_lo, s_hi = math.inf, 0.0
    if s_lo <= s_hi:
        s = min(s_hi, 1.0) if s_lo <= 1.0 else s_lo
        return (s * u[0], s * u[1])

    corners = [(a, b) for a in box[0] for b in box[1]]

    def angle_to_u(x: tuple[float, float]) -> float:
        return abs(math.atan2(u[0] * x[1] - u[1] * x[0], u[0] * x[0] + u[1] * x[1]))

    def dist_to_u(x: tuple[float, float]) -> float:
        return math.hypot(x[0] - u[0], x[1] - u[1])

    best = corners[0]      # the smallest angle; angles within CORNER_TIE_RAD tie, and the nearer to u is taken
    for x in corners[1:]:
        if angle_to_u(x) < angle_to_u(best) - CORNER_TIE_RAD or (
                abs(angle_to_u(x) - angle_to_u(best)) <= CORNER_TIE_RAD and dist_to_u(x) < dist_to_u(best)):
            best = x
    if u != (0.0, 0.0) and angle_to_u(best) < 0.5 * math.pi:
        return best
    return (min(max(0.0, box[0][0]), box[0][1]), min(max(0.0, box[1][0]), box[1][1]))


# --- vectorised over robots: rows of (n, ...) arrays in the mission's sorted id order ---------


def columns(*cols: np.ndarray) -> np.ndarray:
    """(n,) arrays side by side as an (n, k) array (np.stack(cols, axis=1), with less overhead)."""
    return np.array(cols, dtype=float).T


def _f8(a) -> np.ndarray:
    """a as a C-contiguous float64 array (no copy when it already is one)."""
    return np.ascontiguousarray(a, dtype=float)


# The compiled core (vsfleet/_core/vs_kin.c) computes the functions below by the rule of their
# ``*_reference`` (numpy) versions, within 1e-9 (its own sin/cos/atan2: not bit-equal to numpy's).
# It refuses what the references would carry along: NaN or infinity in any input, and a result
# that would not be finite (an overflow, a zero wheel base), with NonFiniteError.


def wrap_angles(th_rad: np.ndarray) -> np.ndarray:
    """Wrap angles (any shape) to [-pi, pi), elementwise, as :func:`vsfleet.geometry.wrap_angle`."""
    th = _f8(th_rad)
    out = np.empty(th.shape)
    _core.wrap_angles(th, out)
    return out if out.ndim else out[()]


def sinc_v(x: np.ndarray) -> np.ndarray:
    """sin(x)/x elementwise, smooth through 0 (the series of :func:`_sinc` below 1e-4)."""
    x = _f8(x)
    out = np.empty(x.shape)
    _core.sinc_v(x, out)
    return out if out.ndim else out[()]


def integrate_arcs(pose_world: np.ndarray, wheels_m_s: np.ndarray, dt_s: float | np.ndarray,
                   wheel_base_m: np.ndarray) -> np.ndarray:
    """Poses (n, 3) [m, m, rad; world] after driving wheels (n, 2) (vl, vr) [m/s] for dt_s [s].

    The exact arc of :func:`integrate_arc` for every row (heading not wrapped). dt_s may be any
    finite number (0 gives the poses back); an array dt_s runs the numpy reference.
    """
    out = np.empty((len(pose_world), 3))
    try:
        _core.integrate_arcs(pose_world, wheels_m_s, dt_s, wheel_base_m, out)
    except TypeError:   # not C-contiguous float64 arrays (a list, a scalar wheel base, an array dt_s)
        if np.ndim(dt_s) != 0:
            return integrate_arcs_reference(pose_world, wheels_m_s, dt_s, wheel_base_m)
        p, u = _f8(pose_world), _f8(wheels_m_s)
        n = len(p)
        if p.shape != (n, 3) or u.shape != (n, 2):
            raise ShapeError(f"integrate_arcs: pose_world (n, 3) and wheels_m_s (n, 2), got {p.shape}, {u.shape}")
        base = np.broadcast_to(_f8(wheel_base_m), (n,)).copy()
        _core.integrate_arcs(p, u, float(dt_s), base, out)
    return out


def limit_wheels_v(wheels_m_s: np.ndarray, wheels_prev_m_s: np.ndarray, dt_s: float,
                   speed_max_m_s: np.ndarray, accel_max_m_s2: np.ndarray) -> np.ndarray:
    """:func:`limit_wheels` for every row: commands (n, 2) [m/s] clipped to each robot's envelope.

    Same rule (the ray s u with the largest s <= 1, else the smallest s > 1; else the box corner
    nearest in angle within 90 deg; else the point nearest zero; then no wheel farther from zero
    than its command asks unless the box forces it), checked equal in the tests.
    """
    dt_s = _check_dt(dt_s)
    out = np.empty((len(wheels_m_s), 2))
    try:
        _core.limit_wheels(wheels_m_s, wheels_prev_m_s, dt_s, speed_max_m_s, accel_max_m_s2, out)
    except TypeError:   # not C-contiguous float64 arrays
        u, p = _f8(wheels_m_s), _f8(wheels_prev_m_s)
        n = len(u)
        if u.shape != (n, 2) or p.shape != (n, 2):
            raise ShapeError(f"limit_wheels_v: commands (n, 2), got {u.shape}, {p.shape}") from None
        vmax = np.broadcast_to(_f8(speed_max_m_s), (n,)).copy()
        amax = np.broadcast_to(_f8(accel_max_m_s2), (n,)).copy()
        _core.limit_wheels(u, p, dt_s, vmax, amax, out)
    return out


# --- the numpy references of the compiled functions above -------------------------------------


def wrap_angles_reference(th_rad: np.ndarray) -> np.ndarray:
    """:func:`wrap_angles` in numpy (the reference of the compiled core)."""
    w = np.fmod(np.asarray(th_rad, dtype=float) + math.pi, 2.0 * math.pi)
    w = np.where(w < 0.0, w + 2.0 * math.pi, w)
    return w - math.pi


def sinc_v_reference(x: np.ndarray) -> np.ndarray:
    """:func:`sinc_v` in numpy (the reference of the compiled core)."""
    x = np.asarray(x, dtype=float)
    x2 = x * x
    series = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        direct = np.sin(x) / x
    return np.where(np.abs(x) < _SINC_SERIES_BELOW, series, direct)


def integrate_arcs_reference(pose_world: np.ndarray, wheels_m_s: np.ndarray, dt_s: float | np.ndarray,
                   wheel_base_m: np.ndarray) -> np.ndarray:
    """Poses (n, 3) [m, m, rad; world] after driving wheels (n, 2) (vl, vr) [m/s] for dt_s [s].

    The exact arc of :func:`integrate_arc` for every row (heading not wrapped); numpy, the
    reference of the compiled core behind :func:`integrate_arcs`.
    """
    p = np.asarray(pose_world, dtype=float)
    u = np.asarray(wheels_m_s, dtype=float)
    v = 0.5 * (u[:, 0] + u[:, 1])
    w = (u[:, 1] - u[:, 0]) / wheel_base_m
    half = 0.5 * w * dt_s
    chord = v * dt_s * sinc_v(half)
    direction = p[:, 2] + half
    return columns(p[:, 0] + chord * np.cos(direction), p[:, 1] + chord * np.sin(direction),
                     p[:, 2] + w * dt_s)


@lru_cache(maxsize=1)
def _atan2_ufunc():
    """The core's atan2, element by element (the reference's tie-breaks): a numpy ufunc, made on first use."""
    return np.frompyfunc(_core.atan2, 2, 1)


def limit_wheels_v_reference(wheels_m_s: np.ndarray, wheels_prev_m_s: np.ndarray, dt_s: float,
                   speed_max_m_s: np.ndarray, accel_max_m_s2: np.ndarray) -> np.ndarray:
    """:func:`limit_wheels` for every row: commands (n, 2) [m/s] clipped to each robot's envelope.

    Same rule (the ray s u with the largest s <= 1, else the smallest s > 1; else the box corner
    nearest in angle within 90 deg; else the point nearest zero; then no wheel farther from zero
    than its command asks unless the box forces it), checked equal in the tests;
    numpy, the reference of the compiled core behind :func:`limit_wheels_v`.
    """
    dt_s = _check_dt(dt_s)
    u = np.asarray(wheels_m_s, dtype=float)
    p = np.asarray(wheels_prev_m_s, dtype=float)
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(p))):
        raise NonFiniteError("wheel commands must be finite")
    vmax = np.asarray(speed_max_m_s, dtype=float)[:, None]
    step = (np.asarray(accel_max_m_s2, dtype=float) * dt_s)[:, None]
    feasible = np.all((np.abs(u) <= vmax) & (np.abs(u - p) <= step), axis=1)
    if feasible.all():
        return u.copy()
    bad = np.flatnonzero(~feasible)
    out = u.copy()
    out[bad] = _limit_rows(u[bad], p[bad], vmax[bad], step[bad])
    return out


def _limit_rows(u: np.ndarray, p: np.ndarray, vmax: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The clipping rule of :func:`limit_wheels_v_reference` for rows that need it (all infeasible)."""
    lo = np.maximum(p - step, -vmax)
    hi = np.minimum(p + step, vmax)
    # the previous command beyond the speed box: the accel limit yields, the speed box alone (the filter's rule)
    relaxed = np.any(lo > hi, axis=1, keepdims=True)
    speed = np.broadcast_to(vmax, u.shape)
    lo = np.where(relaxed, -speed, lo)
    hi = np.where(relaxed, speed, hi)
    # 1. the ray {s u}: per wheel the interval of s that lands in [lo, hi]
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = lo / u, hi / u
    s_lo_w = np.where(u > 0.0, a, np.where(u < 0.0, b, np.where((lo <= 0.0) & (0.0 <= hi), 0.0, np.inf)))
    s_hi_w = np.where(u > 0.0, b, np.where(u < 0.0, a, np.where((lo <= 0.0) & (0.0 <= hi), np.inf, 0.0)))
    s_lo = np.maximum(0.0, np.max(s_lo_w, axis=1))
    s_hi = np.min(s_hi_w, axis=1)
    on_ray = s_lo <= s_hi
    s = np.where(s_lo <= 1.0, np.minimum(s_hi, 1.0), s_lo)
    with np.errstate(invalid="ignore"):
        ray = np.where(on_ray[:, None], np.where(np.isfinite(s), s, 0.0)[:, None] * u, 0.0)
    # 2. the corner at the smallest angle to u (ties, angles within CORNER_TIE_RAD: nearest to u), if within 90 deg
    cx = columns(lo[:, 0], lo[:, 0], hi[:, 0], hi[:, 0])
    cy = columns(lo[:, 1], hi[:, 1], lo[:, 1], hi[:, 1])
    # the angles with the core's own atan2, not numpy's: two corners on one ray from the origin tie exactly,
    # and numpy's arctan2 and the core's differ by an ulp there, which chose the other corner (1 closed loop
    # in about 1000 of tests/test_core_control.py's hypothesis cases)
    ang = np.abs(_atan2_ufunc()(u[:, :1] * cy - u[:, 1:] * cx, u[:, :1] * cx + u[:, 1:] * cy).astype(float))
    dist = np.hypot(cx - u[:, :1], cy - u[:, 1:])
    best = np.zeros(len(u), dtype=int)
    for j in range(1, 4):  # in corner order: a smaller angle, or a tie within CORNER_TIE_RAD and nearer to u
        held = ang[np.arange(len(u)), best]
        better = (ang[:, j] < held - CORNER_TIE_RAD) | (
            (np.abs(ang[:, j] - held) <= CORNER_TIE_RAD) & (dist[:, j] < dist[np.arange(len(u)), best]))
        best = np.where(better, j, best)
    rows = np.arange(len(u))
    corner = columns(cx[rows, best], cy[rows, best])
    corner_ok = np.any(u != 0.0, axis=1) & (ang[rows, best] < 0.5 * math.pi)
    # 3. the point nearest zero
    zero = np.minimum(np.maximum(0.0, lo), hi)
    out = np.where(on_ray[:, None], ray, np.where(corner_ok[:, None], corner, zero))
    # 4. no wheel farther from zero than its command asks, unless the box forces it (then nearest zero)
    a = np.maximum(lo, np.minimum(0.0, u))
    b = np.minimum(hi, np.maximum(0.0, u))
    forced = a > b
    a = np.where(forced, zero, a)
    b = np.where(forced, zero, b)
    return np.minimum(np.maximum(out, a), b)
