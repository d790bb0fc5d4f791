"""Advancing the virtual structure: paper step 2 (eq 7) with the cost-aware push of 3.3.3.

The structure is pushed from its fitted pose by a small twist (translation
velocity [m/s; world frame] and turn rate [rad/s]) toward the mission goal.
The twist is scaled by one factor ``s`` in [0, 1] so that no robot needs wheel
speeds or wheel accelerations outside its envelope to stay on its structure
point (the rigid-body velocity of point i is ``u_i = v + w x rho_i``; a robot
riding along it needs wheel speeds ``|u_i| -/+ w b_i / 2``).

Why the step never overshoots: before scaling, the commanded translation and
rotation per tick are capped by the remaining distance and angle, and the
scale factor is never above one.  The decelerating profile
``v <= sqrt(2 a d)`` keeps the approach smooth, so the structure stops at the
goal without oscillation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, Union

from .lazy import lazy_numpy
from . import _core
from .coreconst import (ALIGN_FLOOR, ALIGN_POWER, ALIGN_POWER_PLAN, GOAL_PATH, GOAL_PLAN, GOAL_POSE, GOAL_TWIST,
                        LIMIT_FIELDS)
from .envelope import Envelope, Envelopes
from .errors import ShapeError, VsfleetValueError
from .geometry import Pose2, angle_diff

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

# Iterations of the deterministic interval searches below: 2**-80 of the unit
# interval is far below double precision, so the result is converged and
# bit-reproducible (a fixed count, no tolerance-dependent stopping).
_SEARCH_ITERATIONS = 80


class GoalError(VsfleetValueError):
    """A mission goal is malformed (empty path, non-finite values)."""


@dataclass(frozen=True)
class Twist2:
    """Structure velocity: (vx, vy) [m/s; world frame] and turn rate w [rad/s, CCW]."""

    vx_m_s: float = 0.0
    vy_m_s: float = 0.0
    w_rad_s: float = 0.0


@dataclass(frozen=True)
class GoalPose:
    """Move the structure to a target pose and stop there."""

    pose: Pose2


@dataclass(frozen=True)
class GoalPath:
    """Follow waypoints (structure poses [m, rad; world frame]) and stop at the last one.

    synced: turn in step with the move toward the carrot (the straight way in SE(2), VS_GOAL_PLAN): a room's
    plan, whose poses keep the bodies clear only if the structure never turns ahead of them. A mission's path
    (False) turns and moves each on its own profile."""

    waypoints: tuple[Pose2, ...]
    synced: bool = False

    def __post_init__(self) -> None:
        if len(self.waypoints) == 0:
            raise GoalError("a path needs at least one waypoint")


@dataclass(frozen=True)
class GoalTwist:
    """Move at a constant twist forever: (vx, vy) [m/s; structure frame], w [rad/s]."""

    vx_m_s: float
    vy_m_s: float
    w_rad_s: float


Goal = Union[GoalPose, GoalPath, GoalTwist]


@dataclass(frozen=True)
class StructureLimits:
    """Limits on the structure's own motion and the tolerances that count as arrived.

    speed_max_m_s: largest translation speed of the structure origin [m/s].
    turn_rate_max_rad_s: largest structure turn rate [rad/s].
    position_tolerance_m / heading_tolerance_rad: within these of a pose or path goal the
    structure counts as arrived and stops being pushed; set them above the tracker's
    noise so that a fleet at rest does not chase it.
    comply_full_m / comply_stop_m: the compliance throttle (see :func:`compliance_scale`): the
    structure moves at full speed while every robot seen is within comply_full_m of its point,
    and halts once one is comply_stop_m away (linear in between). A mission's limits are
    :func:`structure_limits`: for a fleet of more than 3 robots the band moves out by what the
    largest of its robots' tracker noise adds.
    settle_s / turn_settle_s: near the goal the speed is at most (distance left) / settle_s and
    the turn rate (angle left) / turn_settle_s: a finite gain, so that robots that lag a little
    behind their points do not make the refitted structure chatter around the goal, and the
    fit's noise reaches the twist (and so every robot's feed-forward) attenuated.
    """

    speed_max_m_s: float
    turn_rate_max_rad_s: float
    position_tolerance_m: float = 3e-3
    heading_tolerance_rad: float = 0.01
    path_lookahead_m: float = 0.15
    comply_full_m: float = 0.006
    comply_stop_m: float = 0.012
    settle_s: float = 0.5
    turn_settle_s: float = 2.0

    def __post_init__(self) -> None:
        for name in LIMIT_FIELDS:   # every field (the core's order of them)
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0.0:
                raise VsfleetValueError(f"{name} must be finite and >= 0, got {v!r}")
        if self.comply_stop_m <= self.comply_full_m:
            raise VsfleetValueError("comply_stop_m must be greater than comply_full_m")


# The tracker noise the compliance band allows for in each robot's deviation [m]: the fleets we measure on
# (docs/benchmarks.md) have sigma 2 mm per axis.
COMPLY_NOISE_M = 0.002
# The fleet the band (StructureLimits' comply_full_m, comply_stop_m) was set on: the paper's triangle.
COMPLY_BASE_ROBOTS = 3
_LN_ROOTS = 24   # _ln's square roots


def _ln(x: float) -> float:
    """ln(x) for x > 0 from IEEE operations and sqrt alone, so that every host gets the same bits (a libm's log
    may differ in its last bit from one host to another; sqrt is correctly rounded everywhere). Not correctly
    rounded itself: within about 1e-8 of ln(x) (relative). 24 square roots bring x within ln(x) / 2**24 of 1,
    where ln(1 + u) is u - u**2/2 + u**3/3 to far below the rounding of u."""
    y = x
    for _ in range(_LN_ROOTS):
        y = math.sqrt(y)
    u = y - 1.0
    return (u - u * u / 2.0 + u * u * u / 3.0) * 2.0 ** _LN_ROOTS


def structure_limits(speed_max_m_s: float, turn_rate_max_rad_s: float, n_robots: int) -> StructureLimits:
    """A mission's StructureLimits: its speed and turn rate, the compliance band widened for the fleet's size.

    The compliance throttle reads the largest deviation of n robots. Tracker noise alone (sigma per axis) makes
    each robot's deviation Rayleigh-distributed, and the largest of n grows as sigma sqrt(2 ln n): for 30 robots
    under 2 mm noise it is about 5.2 mm, against 3.0 mm for the paper's 3. So the band (comply_full_m,
    comply_stop_m) is moved out by COMPLY_NOISE_M (sqrt(2 ln n) - sqrt(2 ln 3)) for n > 3 (2.25 mm for 30 robots,
    1.33 mm for 10, 0.37 mm for 4) and kept as it is for 3 robots or fewer, so that the throttle answers a robot
    that lags, not the noise of a larger fleet. n is the mission's robot count: robots dropped later keep the
    band of the mission, as every agent does. A pure function of the mission, computed with sqrt alone
    (``_ln``): every agent on every host packs the same limits.
    """
    shift_m = 0.0
    if n_robots > COMPLY_BASE_ROBOTS:
        shift_m = COMPLY_NOISE_M * (math.sqrt(2.0 * _ln(float(n_robots)))
                                    - math.sqrt(2.0 * _ln(float(COMPLY_BASE_ROBOTS))))
    base = StructureLimits(speed_max_m_s=speed_max_m_s, turn_rate_max_rad_s=turn_rate_max_rad_s)
    return StructureLimits(speed_max_m_s=speed_max_m_s, turn_rate_max_rad_s=turn_rate_max_rad_s,
                           comply_full_m=base.comply_full_m + shift_m, comply_stop_m=base.comply_stop_m + shift_m)


@dataclass(frozen=True)
class AdvanceResult:
    """The next desired structure pose and the twist that leads there.

    scale is the envelope factor in [0, 1] applied to the goal's twist (1 = not limited);
    at_goal is True once a pose or path goal is reached within the tolerances.
    """

    pose: Pose2
    twist: Twist2
    scale: float
    at_goal: bool


def structure_points(pose: Pose2, template_xy: np.ndarray) -> np.ndarray:
    """World positions (n, 2) [m] of the template points (structure frame) under ``pose``."""
    return pose.apply(template_xy)


def _profile_speed(distance: float, cap: float, accel: float, dt_s: float, settle_s: float = 0.0) -> float:
    """Speed toward a target at ``distance`` that decelerates to rest there without overshoot:
    min(cap, sqrt(2 accel d), d / max(dt_s, settle_s))."""
    if distance <= 0.0:
        return 0.0
    return min(cap, math.sqrt(2.0 * accel * distance), distance / max(dt_s, settle_s))


def _twist_toward(pose: Pose2, target: Pose2, dist_to_stop: float, limits: StructureLimits,
                  accel_m_s2: float, alpha_rad_s2: float, dt_s: float) -> Twist2:
    """World twist from ``pose`` toward ``target``; speed profiled on ``dist_to_stop``."""
    ex, ey = target.x - pose.x, target.y - pose.y
    d = math.hypot(ex, ey)
    if d > 0.0:
        # Never step past the carrot itself, nor decelerate later than the stop allows.
        speed = min(_profile_speed(dist_to_stop, limits.speed_max_m_s, accel_m_s2, dt_s, limits.settle_s), d / dt_s)
        vx, vy = speed * ex / d, speed * ey / d
    else:
        vx = vy = 0.0
    dth = angle_diff(target.th, pose.th)
    w = math.copysign(_profile_speed(abs(dth), limits.turn_rate_max_rad_s, alpha_rad_s2, dt_s, limits.turn_settle_s), dth)
    return Twist2(vx, vy, w)


def _twist_straight(pose: Pose2, target: Pose2, dist_to_stop: float, limits: StructureLimits,
                    accel_m_s2: float, alpha_rad_s2: float, dt_s: float) -> Twist2:
    """_twist_toward with the turn in step with the move: the straight way in SE(2) to ``target`` (the heading
    turns in proportion to the way moved), each no faster than its own profile (the turn's: its rate and its
    acceleration, not the settling time, as the move sets the pace); a slower turn makes the move wait."""
    t = _twist_toward(pose, target, dist_to_stop, limits, accel_m_s2, alpha_rad_s2, dt_s)
    ex, ey = target.x - pose.x, target.y - pose.y
    d, v = math.hypot(ex, ey), math.hypot(t.vx_m_s, t.vy_m_s)
    dth = angle_diff(target.th, pose.th)
    if d > 0.0 and v > 0.0:
        w_move = dth * (v / d)
        w_max = _profile_speed(abs(dth), limits.turn_rate_max_rad_s, alpha_rad_s2, dt_s, dt_s)
        if abs(w_move) > w_max:
            k = w_max / abs(w_move)
            return Twist2(k * t.vx_m_s, k * t.vy_m_s, math.copysign(w_max, dth))
        return Twist2(t.vx_m_s, t.vy_m_s, w_move)
    return t


def _path_carrot(pose: Pose2, waypoints: Sequence[Pose2], lookahead_m: float) -> tuple[Pose2, float]:
    """Carrot pose on the waypoint polyline and the remaining path length to the end [m].

    The structure position is projected on the closest segment (ties go to the
    earliest segment, so the rule is deterministic); the carrot lies lookahead_m
    further along the path, its heading interpolated between the segment's ends.
    """
    if len(waypoints) == 1:
        w0 = waypoints[0]
        return w0, math.hypot(w0.x - pose.x, w0.y - pose.y)
    pts = np.array([[w.x, w.y] for w in waypoints])
    seg = pts[1:] - pts[:-1]
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    total = float(cum[-1])
    best_i, best_d2, best_u = 0, math.inf, 0.0
    for i in range(len(seg)):
        L2 = float(seg_len[i]) ** 2
        rx, ry = pose.x - pts[i, 0], pose.y - pts[i, 1]
        u = 0.0 if L2 == 0.0 else min(1.0, max(0.0, (rx * seg[i, 0] + ry * seg[i, 1]) / L2))
        qx, qy = pts[i, 0] + u * seg[i, 0], pts[i, 1] + u * seg[i, 1]
        d2 = (pose.x - qx) ** 2 + (pose.y - qy) ** 2
        if d2 < best_d2:
            best_i, best_d2, best_u = i, d2, u
    s_proj = float(cum[best_i]) + best_u * float(seg_len[best_i])
    s_carrot = min(total, s_proj + lookahead_m)
    j = int(np.searchsorted(cum, s_carrot, side="right")) - 1
    j = min(max(j, 0), len(seg) - 1)
    frac = 0.0 if seg_len[j] == 0.0 else (s_carrot - float(cum[j])) / float(seg_len[j])
    frac = min(1.0, max(0.0, frac))
    a, b = waypoints[j], waypoints[j + 1]
    carrot = Pose2(a.x + frac * (b.x - a.x), a.y + frac * (b.y - a.y),
                   a.th + frac * angle_diff(b.th, a.th))
    if s_carrot >= total:
        carrot = waypoints[-1]
    remaining = (total - s_proj) + math.sqrt(best_d2)
    return carrot, remaining


def _wheel_demand(twist: np.ndarray, rho: np.ndarray, half_base: np.ndarray) -> np.ndarray:
    """Per robot, |u_i| + |w| b_i/2 for a world twist (vx, vy, w) and offsets rho (n, 2)."""
    ux = twist[0] - twist[2] * rho[:, 1]
    uy = twist[1] + twist[2] * rho[:, 0]
    return np.hypot(ux, uy) + abs(twist[2]) * half_base


def _as_envelopes(envelopes) -> Envelopes:
    return envelopes if isinstance(envelopes, Envelopes) else Envelopes.of(envelopes)


def envelope_scale(twist: Twist2, twist_prev: Twist2 | None, rho_world: np.ndarray,
                   envelopes: Envelopes | Sequence[Envelope], dt_s: float) -> float:
    """Largest s in [0, 1] such that every robot's wheels stay in their envelope.

    Speed: |u_i(s xi)| + |s w| b_i/2 <= v_max_i.  Acceleration: the change from
    the previous twist, |u_i(s xi - xi_prev)| + |s w - w_prev| b_i/2 <= a_i dt.
    Both sides are convex in s. When no s satisfies the acceleration bound (the
    goal asks to brake harder than the wheels can), the s that violates it least
    is returned: the structure then slows as fast as its robots can. With no
    twist_prev only the speed bound applies.
    """
    xi = np.array([twist.vx_m_s, twist.vy_m_s, twist.w_rad_s])
    env = _as_envelopes(envelopes)
    half_base = env.wheel_base_m / 2.0
    v_max = env.wheel_speed_max_m_s
    dv_max = env.wheel_accel_max_m_s2 * dt_s

    demand = _wheel_demand(xi, rho_world, half_base)
    with np.errstate(divide="ignore"):
        s_speed = float(np.min(np.where(demand > 0.0, v_max / demand, np.inf)))
    s_hi = min(1.0, s_speed)
    if twist_prev is None:
        return s_hi
    xi0 = np.array([twist_prev.vx_m_s, twist_prev.vy_m_s, twist_prev.w_rad_s])

    def excess(s: float) -> float:
        return float(np.max(_wheel_demand(s * xi - xi0, rho_world, half_base) - dv_max))

    if excess(s_hi) <= 0.0:
        return s_hi
    # Minimise the convex excess on [0, s_hi] (golden-section-free ternary search, fixed steps).
    lo, hi = 0.0, s_hi
    for _ in range(_SEARCH_ITERATIONS):
        m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
        if excess(m1) <= excess(m2):
            hi = m2
        else:
            lo = m1
    s_best = (lo + hi) / 2.0
    if excess(s_best) > 0.0:
        return s_best
    # Feasible set is [., s_edge] with s_edge < s_hi: bisect for its upper edge.
    lo, hi = s_best, s_hi
    for _ in range(_SEARCH_ITERATIONS):
        mid = (lo + hi) / 2.0
        if excess(mid) <= 0.0:
            lo = mid
        else:
            hi = mid
    return lo


def _headings(headings_rad, n: int) -> np.ndarray:
    """Headings (n,) [rad] with NaN for robots not seen (None entries of a sequence become NaN)."""
    h = np.array([math.nan if v is None else v for v in headings_rad] if not isinstance(headings_rad, np.ndarray)
                 else headings_rad, dtype=float)
    if h.shape != (n,):
        raise ShapeError(f"headings_rad must have shape ({n},), got {h.shape}")
    return h


def alignment_scale(twist: Twist2, rho_world: np.ndarray, headings_rad,
                    floor: float | None = None, power: float | None = None,
                    speed_ref_m_s: float | None = None) -> float:
    """The paper's cost-aware push (3.3.3): slow the structure while robots face across their path.

    A differential-drive robot moves only along its heading, so the part of its point's
    velocity across it becomes error. Per robot the factor is max(floor, |cos d|**power), with d
    the angle between its heading and its point's velocity (either way: robots may reverse).
    The structure moves at the smallest factor; the floor keeps it creeping so robots turn.
    headings_rad (n,) [rad], NaN (or None) for robots not seen, which are skipped. The advance passes
    power ALIGN_POWER_PLAN on a room's plan and ALIGN_POWER (the default) on every other goal (vs_advance.h).
    speed_ref_m_s (on a plan: the mission's speed): a robot whose point moves slower, at u, holds the structure
    back only by that share, 1 - (1 - factor) u / speed_ref_m_s: a robot near the structure's centre of turning,
    whose point barely moves, turns toward that motion only as fast as its point moves (offset-point tracking), so
    throttling the structure for it slowed its own turn too (vs_advance.h says where it was measured).
    """
    floor = ALIGN_FLOOR if floor is None else floor
    power = ALIGN_POWER if power is None else power
    h = _headings(headings_rad, rho_world.shape[0])
    ux = twist.vx_m_s - twist.w_rad_s * rho_world[:, 1]
    uy = twist.vy_m_s + twist.w_rad_s * rho_world[:, 0]
    u = np.hypot(ux, uy)
    use = np.isfinite(h) & (u > 0.0)
    if not np.any(use):
        return 1.0
    hs = np.where(use, h, 0.0)
    cos_d = np.abs(ux * np.cos(hs) + uy * np.sin(hs)) / np.where(use, u, 1.0)
    k = np.maximum(floor, cos_d ** power)
    if speed_ref_m_s is not None and speed_ref_m_s > 0.0:
        k = np.where(u < speed_ref_m_s, 1.0 - (1.0 - k) * (u / speed_ref_m_s), k)
    return float(min(1.0, np.min(np.where(use, k, 1.0))))


def compliance_scale(deviations_m, limits: StructureLimits) -> float:
    """Throttle in [0, 1] from how well the robots comply: 1 while the largest deviation [m] of a
    robot seen (NaN = not seen) is within comply_full_m, 0 from comply_stop_m, linear between.

    Graceful degradation (the paper's Fig. 12): a robot that halts or slows holds the structure
    back instead of being left behind, so the formation bends within comply_stop_m.
    """
    d = np.asarray(deviations_m, dtype=float)
    seen = d[np.isfinite(d)]
    if seen.size == 0:
        return 1.0
    worst = float(np.max(seen))
    span = limits.comply_stop_m - limits.comply_full_m
    return min(1.0, max(0.0, (limits.comply_stop_m - worst) / span))


def advance_structure_reference(pose_fit: Pose2, goal: Goal, dt_s: float, limits: StructureLimits,
                                template_xy: np.ndarray, envelopes: Envelopes | Sequence[Envelope],
                                twist_prev: Twist2 | None = None, elapsed_s: float | None = None,
                                headings_rad=None, deviations_m=None) -> AdvanceResult:
    """Next desired structure pose, one ``dt_s`` after the fitted pose (paper eq 7): the readable
    numpy reference of :func:`advance_structure` (which runs the compiled core, vs_advance.c).

    template_xy (n, 2) are the robots' points [m; structure frame], envelopes their limits
    (same order). Acceleration is bounded in one of two ways:
    - twist_prev (the twist returned at the previous tick): the change of every robot's
      wheel speeds from it is kept within its acceleration limit (stateful);
    - elapsed_s (time since the mission started): speed and turn rate ramp up at the
      structure's acceleration, and ramp down by the stopping profile. The result is
      then a pure function of this call's inputs, which is what duplicated agents use
      so that their copies agree bit for bit.
    headings_rad ((n,) robot headings [rad], template order, NaN if unseen) turns on the
    cost-aware push: see :func:`alignment_scale`. deviations_m ((n,) each robot's distance [m] to
    its point on the fitted structure, NaN if unseen) turns on the compliance throttle: see
    :func:`compliance_scale`. Every input is an array over all robots; the cost does not grow
    with a Python loop over them.
    """
    tpl = np.asarray(template_xy, dtype=float)
    if tpl.ndim != 2 or tpl.shape[1] != 2 or tpl.shape[0] == 0:
        raise ShapeError(f"template_xy must have shape (n, 2) with n >= 1, got {tpl.shape}")
    envelopes = _as_envelopes(envelopes)
    if len(envelopes) != tpl.shape[0]:
        raise ShapeError(f"{len(envelopes)} envelopes for {tpl.shape[0]} template points")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise VsfleetValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
    if not all(math.isfinite(v) for v in pose_fit.as_tuple()):
        raise VsfleetValueError(f"pose_fit must be finite, got {pose_fit}")

    rho = structure_points(Pose2(0.0, 0.0, pose_fit.th), tpl)  # offsets [m; world frame]
    accel = 0.5 * float(np.min(envelopes.wheel_accel_max_m_s2))
    reach = float(np.max(np.hypot(rho[:, 0], rho[:, 1]) + envelopes.wheel_base_m / 2.0))
    alpha = accel / reach

    at_goal = False
    if isinstance(goal, GoalTwist):
        c, s = math.cos(pose_fit.th), math.sin(pose_fit.th)
        desired = Twist2(c * goal.vx_m_s - s * goal.vy_m_s, s * goal.vx_m_s + c * goal.vy_m_s,
                         goal.w_rad_s)
    elif isinstance(goal, GoalPose):
        d = math.hypot(goal.pose.x - pose_fit.x, goal.pose.y - pose_fit.y)
        desired = _twist_toward(pose_fit, goal.pose, d, limits, accel, alpha, dt_s)
        at_goal = (d <= limits.position_tolerance_m
                   and abs(angle_diff(goal.pose.th, pose_fit.th)) <= limits.heading_tolerance_rad)
    elif isinstance(goal, GoalPath):
        carrot, remaining = _path_carrot(pose_fit, goal.waypoints, limits.path_lookahead_m)
        desired = (_twist_straight if goal.synced else _twist_toward)(pose_fit, carrot, remaining, limits, accel,
                                                                      alpha, dt_s)
        end = goal.waypoints[-1]
        at_goal = (carrot == end
                   and math.hypot(end.x - pose_fit.x, end.y - pose_fit.y) <= limits.position_tolerance_m
                   and abs(angle_diff(end.th, pose_fit.th)) <= limits.heading_tolerance_rad)
    else:
        raise GoalError(f"unknown goal type {type(goal).__name__}")

    if at_goal:
        desired = Twist2()
    if elapsed_s is not None:
        ramp = max(0.0, elapsed_s)
        v = math.hypot(desired.vx_m_s, desired.vy_m_s)
        k_v = min(1.0, accel * ramp / v) if v > 0.0 else 1.0
        k_w = min(1.0, alpha * ramp / abs(desired.w_rad_s)) if desired.w_rad_s != 0.0 else 1.0
        desired = Twist2(k_v * desired.vx_m_s, k_v * desired.vy_m_s, k_w * desired.w_rad_s)
    if headings_rad is not None:
        plan = isinstance(goal, GoalPath) and goal.synced    # a room's plan (VS_GOAL_PLAN): vs_advance.h says why
        k = alignment_scale(desired, rho, headings_rad, power=ALIGN_POWER_PLAN if plan else ALIGN_POWER,
                            speed_ref_m_s=limits.speed_max_m_s if plan else None)
        desired = Twist2(k * desired.vx_m_s, k * desired.vy_m_s, k * desired.w_rad_s)
    if deviations_m is not None:
        d = np.asarray(deviations_m, dtype=float)
        if d.shape != (tpl.shape[0],):
            raise ShapeError(f"deviations_m must have shape ({tpl.shape[0]},), got {d.shape}")
        k = compliance_scale(d, limits)
        desired = Twist2(k * desired.vx_m_s, k * desired.vy_m_s, k * desired.w_rad_s)
    scale = envelope_scale(desired, twist_prev, rho, envelopes, dt_s)
    twist = Twist2(scale * desired.vx_m_s, scale * desired.vy_m_s, scale * desired.w_rad_s)
    nxt = Pose2(pose_fit.x + twist.vx_m_s * dt_s, pose_fit.y + twist.vy_m_s * dt_s,
                pose_fit.th + twist.w_rad_s * dt_s)
    return AdvanceResult(pose=nxt, twist=twist, scale=scale, at_goal=at_goal)


# --- the compiled core behind advance_structure ------------------------------------------

_CACHE = "_vs_core"   # a frozen goal's / limits' packed form for the core, kept in its __dict__ (not a field)


def _core_goal(goal) -> tuple[int, np.ndarray]:
    """(VS_GOAL_* kind, float64 array of 3 * k doubles) of a goal, computed once per goal object."""
    packed = goal.__dict__.get(_CACHE) if hasattr(goal, "__dict__") else None
    if packed is not None:
        return packed
    if isinstance(goal, GoalTwist):
        packed = (GOAL_TWIST, np.array([goal.vx_m_s, goal.vy_m_s, goal.w_rad_s], dtype=float))
    elif isinstance(goal, GoalPose):
        packed = (GOAL_POSE, np.array(goal.pose.as_tuple(), dtype=float))
    elif isinstance(goal, GoalPath):
        packed = (GOAL_PLAN if goal.synced else GOAL_PATH,
                  np.array([w.as_tuple() for w in goal.waypoints], dtype=float).reshape(-1))
    else:
        raise GoalError(f"unknown goal type {type(goal).__name__}")
    packed[1].flags.writeable = False
    object.__setattr__(goal, _CACHE, packed)
    return packed


def _core_limits(limits: StructureLimits) -> tuple:
    packed = limits.__dict__.get(_CACHE)
    if packed is None:
        packed = tuple(float(getattr(limits, f)) for f in LIMIT_FIELDS)
        object.__setattr__(limits, _CACHE, packed)
    return packed


def _f64(a) -> np.ndarray:
    """a as a C-contiguous float64 array, not copied when it already is one."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=float)


_new, _set = object.__new__, object.__setattr__


def _result(r: tuple) -> AdvanceResult:
    """The AdvanceResult of the core's (x, y, th, vx, vy, w, scale, at_goal): its frozen dataclasses
    filled directly (their fields only; th is already wrapped once by the core, as Pose2 does, and
    is not wrapped again): 1.9 us through their __init__s, 1 us so."""
    pose, twist, res = _new(Pose2), _new(Twist2), _new(AdvanceResult)
    _set(pose, "__dict__", {"x": r[0], "y": r[1], "th": r[2]})
    _set(twist, "__dict__", {"vx_m_s": r[3], "vy_m_s": r[4], "w_rad_s": r[5]})
    _set(res, "__dict__", {"pose": pose, "twist": twist, "scale": r[6], "at_goal": r[7]})
    return res


def advance_structure(pose_fit: Pose2, goal: Goal, dt_s: float, limits: StructureLimits,
                      template_xy: np.ndarray, envelopes: Envelopes | Sequence[Envelope],
                      twist_prev: Twist2 | None = None, elapsed_s: float | None = None,
                      headings_rad=None, deviations_m=None) -> AdvanceResult:
    """Next desired structure pose, one ``dt_s`` after the fitted pose (paper eq 7), computed by the
    compiled core (vsfleet/_core/vs_advance.c): arguments, errors and result as
    :func:`advance_structure_reference` (within 1e-9 of it, the same at_goal), except that a
    non-finite goal, template, twist_prev or elapsed_s, or an infinite heading or deviation (NaN
    marks an unseen robot), is refused with NonFiniteError instead of spreading into the result.
    """
    tpl = template_xy if type(template_xy) is np.ndarray else np.asarray(template_xy, dtype=float)
    if tpl.ndim != 2 or tpl.shape[1] != 2 or tpl.shape[0] == 0:
        raise ShapeError(f"template_xy must have shape (n, 2) with n >= 1, got {tpl.shape}")
    n = tpl.shape[0]
    if type(envelopes) is not Envelopes:
        envelopes = _as_envelopes(envelopes)
    if envelopes.wheel_base_m.shape[0] != n:
        raise ShapeError(f"{len(envelopes)} envelopes for {n} template points")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise VsfleetValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
    x, y, th = pose_fit.x, pose_fit.y, pose_fit.th
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
        raise VsfleetValueError(f"pose_fit must be finite, got {pose_fit}")
    kind, goal_v = _core_goal(goal)
    if headings_rad is not None:
        if type(headings_rad) is not np.ndarray:
            headings_rad = _headings(headings_rad, n)
        elif headings_rad.shape != (n,):
            raise ShapeError(f"headings_rad must have shape ({n},), got {headings_rad.shape}")
    if deviations_m is not None:
        if type(deviations_m) is not np.ndarray:
            deviations_m = np.asarray(deviations_m, dtype=float)
        if deviations_m.shape != (n,):
            raise ShapeError(f"deviations_m must have shape ({n},), got {deviations_m.shape}")
    prev = None if twist_prev is None else (twist_prev.vx_m_s, twist_prev.vy_m_s, twist_prev.w_rad_s)
    elapsed = None if elapsed_s is None else float(elapsed_s)
    lim = _core_limits(limits)
    try:
        r = _core.advance(x, y, th, kind, goal_v, dt_s, lim, tpl, envelopes.wheel_base_m,
                          envelopes.wheel_speed_max_m_s, envelopes.wheel_accel_max_m_s2, prev, elapsed,
                          headings_rad, deviations_m)
    except TypeError:
        # an array that is not C-contiguous float64 (the core reads buffers as they are): convert
        # them all once, as the reference's np.asarray(..., dtype=float) does
        r = _core.advance(x, y, th, kind, goal_v, dt_s, lim, _f64(tpl), _f64(envelopes.wheel_base_m),
                          _f64(envelopes.wheel_speed_max_m_s), _f64(envelopes.wheel_accel_max_m_s2), prev, elapsed,
                          None if headings_rad is None else _f64(headings_rad),
                          None if deviations_m is None else _f64(deviations_m))
    return _result(r)
