"""Trajectory controllers for every robot at once: structure points -> wheel speeds.

Robots are rows of (n, ...) arrays in the mission's sorted id order. A controller is
an object with gains fixed by :func:`make_controller`::

    state = controller.initial(n)
    state, wheels_m_s = controller(state, ControlInput(...))   # wheels (n, 2): (vl, vr) [m/s]

It is a pure function of (state, input): every agent that runs it on the same frames
and commands gets bit-identical states and commands, for its own robot and for the
predictions of every other robot. Rows not ``active`` get zero wheels and keep their
state. The result has passed :func:`~vsfleet.kinematics.limit_wheels_v`.

Controllers: ``turn_then_go`` (paper eqs 9-11), ``arc`` (paper eqs 12-16),
``tracking`` (Kanayama 1990) and ``precision`` (the default: feed-forward of the point's
velocity, an own-pose filter over the commands sent, frame-age compensation and online
wheel-gain estimation; see :class:`Precision`).
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, fields
from operator import attrgetter
from typing import Callable

from .lazy import lazy_numpy
from . import _core
from .coreconst import (CONTROL_INPUT_ARGS, PRECISION_GAIN_FIELDS, PRECISION_HISTORY as _HISTORY,
                        PRECISION_STATE_ARGS, TRACKING_GAIN_FIELDS)
from .envelope import Envelopes
from .errors import ShapeError, VsfleetValueError
from .kinematics import (
    columns,
    integrate_arcs_reference as integrate_arcs,
    limit_wheels_v_reference,
    sinc_v_reference as sinc_v,
    wrap_angles_reference as wrap_angles,
)

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)


class UnknownControllerError(VsfleetValueError):
    """The controller name is not a key of :data:`CONTROLLERS`."""


class ControllerGainError(VsfleetValueError):
    """A controller gain is not a finite number in its allowed range."""


@dataclass(frozen=True)
class ControlInput:
    """What a controller needs for one frame, every robot a row (mission's sorted id order).

    pose_world (n, 3): observed poses [m, m, rad; world]; point_now_world (n, 2): each robot's
    structure point at the frame's time; point_next_world (n, 2): the same one dt_s later (the
    advance: their difference / dt_s is the feed-forward velocity); wheels_prev_m_s (n, 2): the
    last commands sent; age_s: time from the observation to when this command takes effect [s];
    active (n,): rows to command.
    """

    pose_world: np.ndarray
    point_now_world: np.ndarray
    point_next_world: np.ndarray
    wheels_prev_m_s: np.ndarray
    dt_s: float
    age_s: float
    envelopes: Envelopes
    active: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.envelopes)
        for name, cols in (("pose_world", 3), ("point_now_world", 2), ("point_next_world", 2),
                           ("wheels_prev_m_s", 2)):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n, cols):
                raise ShapeError(f"{name} must have shape ({n}, {cols}), got {a.shape}")
            object.__setattr__(self, name, a)
        act = np.asarray(self.active, dtype=bool)
        if act.shape != (n,):
            raise ShapeError(f"active must have shape ({n},), got {act.shape}")
        object.__setattr__(self, "active", act)
        if not (math.isfinite(self.dt_s) and self.dt_s > 0.0):
            raise VsfleetValueError(f"dt_s must be finite and > 0, got {self.dt_s!r}")
        if not (math.isfinite(self.age_s) and self.age_s >= 0.0):
            raise VsfleetValueError(f"age_s must be finite and >= 0, got {self.age_s!r}")


@dataclass(frozen=True)
class Stateless:
    """The state of a controller that keeps none."""


def _gain(name: str, value, *, allow_zero: bool = False, at_most: float = math.inf) -> float:
    """A gain as float, checked finite and > 0 (or >= 0 with allow_zero), and <= at_most."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ControllerGainError(f"{name} must be a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or (value == 0.0 and not allow_zero) or value > at_most:
        raise ControllerGainError(
            f"{name} must be finite, {'>=' if allow_zero else '>'} 0 and <= {at_most}, got {value!r}")
    return value


def _check_gains(obj) -> None:
    """Check every float field of a controller dataclass (> 0; _allow_zero fields may be 0)."""
    allow = getattr(obj, "_allow_zero", ())
    limits = getattr(obj, "_at_most", {})
    for f in fields(obj):
        v = getattr(obj, f.name)
        if f.type in ("bool", bool):
            if not isinstance(v, bool):
                raise ControllerGainError(f"{f.name} must be a bool, got {type(v).__name__}")
            continue
        object.__setattr__(obj, f.name, _gain(f.name, v, allow_zero=f.name in allow,
                                              at_most=limits.get(f.name, math.inf)))


def _robot_frame(pose: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 2) [m] in each robot's frame [m; +x ahead, +y to the left]."""
    wx, wy = point[:, 0] - pose[:, 0], point[:, 1] - pose[:, 1]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return c * wx + s * wy, -s * wx + c * wy


def _ahead(now: np.ndarray, nxt: np.ndarray, ticks: float) -> np.ndarray:
    """Points extrapolated ``ticks`` ticks ahead: now + ticks (next - now) [m; world]."""
    return now + ticks * (nxt - now)


def _half_plane_angle(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """atan(y / x) in [-pi/2, pi/2], defined at x = 0 (then +-pi/2 by the sign of y, 0 at y = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.arctan(y / x)
    at_zero = np.where(y != 0.0, np.copysign(0.5 * math.pi, y), 0.0)
    return np.where(x == 0.0, at_zero, a)


# Share of a wheel's acceleration limit that a turn may plan to brake with.
_TURN_BRAKE_SHARE = 0.5


def _braked_turn(turn_m_s: np.ndarray, angle_rad: np.ndarray, env: Envelopes) -> np.ndarray:
    """Cap turning wheel speeds [m/s] so the wheels can still brake to rest within angle_rad.

    Each wheel has (b/2)|angle| [m] left to roll; stopping from speed u takes u^2 / (2 a).
    """
    reach_m = 0.5 * env.wheel_base_m * np.abs(angle_rad)
    cap = np.sqrt(2.0 * _TURN_BRAKE_SHARE * env.wheel_accel_max_m_s2 * reach_m)
    return np.maximum(-cap, np.minimum(cap, turn_m_s))


def _finish(wheels: np.ndarray, inp: ControlInput) -> np.ndarray:
    """Envelope-limited wheels (n, 2) [m/s]; inactive rows zero."""
    w = np.where(inp.active[:, None] & np.isfinite(wheels), wheels, 0.0)
    env = inp.envelopes
    out = limit_wheels_v_reference(w, inp.wheels_prev_m_s, inp.dt_s, env.wheel_speed_max_m_s,
                                   env.wheel_accel_max_m_s2)
    return np.where(inp.active[:, None], out, 0.0)


def _wheels(v: np.ndarray, w: np.ndarray, base: np.ndarray) -> np.ndarray:
    half = 0.5 * w * base
    return columns(v - half, v + half)


# --------------------------------------------------------------------------- the compiled core
# Each controller's __call__ runs the compiled core (vsfleet/_core/vs_control.c), which computes the
# rule of its ``reference`` method (numpy, below) within 1e-9, with the same discrete decisions. The
# core refuses what the reference carries along: NaN or infinity anywhere in the input or the state
# (NonFiniteError; the reference zeroes such a row's wheels and lets NaN into its state), and, for
# Precision, a new state that would overflow. dt_s and age_s are checked by ControlInput.


# a ControlInput's arguments in the core's order (CONTROL_INPUT_ARGS; the envelope's are its envelopes'), and
# where the flags are: active among them, Precision's ready after its gains among its state's arrays
_input_args = attrgetter(*(f"envelopes.{a}" if a in {f.name for f in fields(Envelopes)} else a
                           for a in CONTROL_INPUT_ARGS))
_ACTIVE = CONTROL_INPUT_ARGS.index("active")
_READY = 1 + PRECISION_STATE_ARGS.index("ready")


def _contiguous(a, flags: bool = False):
    """a as a C-contiguous float64 array (bool with flags); numbers as they are."""
    if isinstance(a, (float, int)):
        return a
    return np.ascontiguousarray(a, dtype=bool if flags else float)


def _core_call(fn, head: tuple, inp: ControlInput, tail: tuple, head_flags: tuple[int, ...] = ()) -> None:
    """fn(*head, *input arrays, *tail); arrays that are not C-contiguous float64 (bool: inp.active and
    head[i] for i in head_flags) are converted and the call made again (the core takes buffers as
    they are, and refuses others)."""
    args = _input_args(inp)
    try:
        fn(*head, *args, *tail)
    except TypeError:
        fn(*(_contiguous(a, i in head_flags) for i, a in enumerate(head)),
           *(_contiguous(a, i == _ACTIVE) for i, a in enumerate(args)), *tail)


def _core_gains(obj, values) -> None:
    """The gains in the core's order, as a float64 buffer (no numpy: controllers are made in the agent process)."""
    object.__setattr__(obj, "_core", array("d", map(float, values)))


# --------------------------------------------------------------------------- the paper's two


@dataclass(frozen=True)
class TurnThenGo:
    """Paper eqs 9-11, CCW: vl = v - K th_err, vr = v + K th_err [m/s], K in m/s per rad.

    Aims at the point extrapolated horizon_s [s] ahead (>= 1 tick; 0 is the paper's point_next):
    v = min(d_max_m, dist) / horizon * (Hc . Hd); th_err = atan(Hc x Hd / Hc . Hd) (reverse when
    the target is behind), or atan2 if not allow_reverse. The turn is capped to brake in time.
    """

    turn_gain_m_s_per_rad: float = 1.0
    d_max_m: float = 0.075
    horizon_s: float = 0.25
    turn_fade_radius_m: float = 0.001
    allow_reverse: bool = True
    _allow_zero = ("horizon_s",)

    def __post_init__(self) -> None:
        _check_gains(self)
        _core_gains(self, (self.turn_gain_m_s_per_rad, self.d_max_m, self.horizon_s, self.turn_fade_radius_m,
                           1.0 if self.allow_reverse else 0.0))

    def initial(self, n: int) -> Stateless:
        return Stateless()

    def __call__(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        wheels = np.empty((len(inp.active), 2))
        _core_call(_core.control_turn_then_go, (self._core,), inp, (wheels,))
        return state, wheels

    def reference(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        """:meth:`__call__` in numpy (the reference of the compiled core)."""
        h = max(1.0, self.horizon_s / inp.dt_s)
        dx, dy = _robot_frame(inp.pose_world, _ahead(inp.point_now_world, inp.point_next_world, h))
        dist = np.hypot(dx, dy)
        th_err = _half_plane_angle(dy, dx) if self.allow_reverse else np.arctan2(dy, dx)
        safe = np.where(dist == 0.0, 1.0, dist)
        v = np.minimum(self.d_max_m, dist) / (h * inp.dt_s) * (dx / safe)
        turn = (_braked_turn(self.turn_gain_m_s_per_rad * th_err, th_err, inp.envelopes)
                * np.minimum(1.0, dist / self.turn_fade_radius_m))
        wheels = np.where((dist == 0.0)[:, None], 0.0, columns(v - turn, v + turn))
        return state, _finish(wheels, inp)


@dataclass(frozen=True)
class Arc:
    """Paper eqs 12-16: wheel speeds [m/s] of the arc that reaches the point in time.

    Target: the point extrapolated horizon_s [s] ahead (>= 1 tick; 0 is the paper's point_next
    in dt_s, whose heading error flips sign every tick). See :func:`~vsfleet.kinematics.inverse_arc`.
    """

    horizon_s: float = 1.0
    _allow_zero = ("horizon_s",)

    def __post_init__(self) -> None:
        _check_gains(self)

    def initial(self, n: int) -> Stateless:
        return Stateless()

    def __call__(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        wheels = np.empty((len(inp.active), 2))
        _core_call(_core.control_arc, (self.horizon_s,), inp, (wheels,))
        return state, wheels

    def reference(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        """:meth:`__call__` in numpy (the reference of the compiled core)."""
        h = max(1.0, self.horizon_s / inp.dt_s)
        t_s = h * inp.dt_s
        dx, dy = _robot_frame(inp.pose_world, _ahead(inp.point_now_world, inp.point_next_world, h))
        dist = np.hypot(dx, dy)
        forward = dx >= 0.0
        beta = np.where(forward, np.arctan2(dy, dx), np.arctan2(-dy, -dx))
        v = np.where(forward, 1.0, -1.0) * dist / (t_s * sinc_v(beta))
        w = 2.0 * beta / t_s
        wheels = np.where((dist == 0.0)[:, None], 0.0, _wheels(v, w, inp.envelopes.wheel_base_m))
        return state, _finish(wheels, inp)


# Defaults: lateral error dynamics s^2 + v_r kth s + v_r^2 ky, so at v_r = 0.1 m/s the natural
# frequency is v_r sqrt(ky) = 5 rad/s with damping kth / (2 sqrt(ky)) = 1; kx = 2 /s along.
@dataclass(frozen=True)
class Tracking:
    """Kanayama et al. (1990) tracking with feed-forward, blended into point regulation at rest.

    Reference: point_now [m; world], heading and speed v_r of f = (next - now) / dt_s; e is the
    error in the robot frame. v = f.Hc + kx e_x; w = lam v_r (ky e_y + kth 2 sin(e_th/2)) +
    (1 - lam) w_reg, lam = min(1, v_r / moving_speed_m_s); w_reg turns either end toward f + kx e.
    """

    along_gain_per_s: float = 2.0
    lateral_gain_per_m2: float = 2500.0
    heading_gain_per_m: float = 100.0
    regulate_gain_per_s: float = 5.0
    regulate_radius_m: float = 0.005
    moving_speed_m_s: float = 0.02

    def __post_init__(self) -> None:
        _check_gains(self)
        _core_gains(self, [getattr(self, f) for f in TRACKING_GAIN_FIELDS])   # vs_tracking_gains' order

    def initial(self, n: int) -> Stateless:
        return Stateless()

    def __call__(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        wheels = np.empty((len(inp.active), 2))
        _core_call(_core.control_tracking, (self._core,), inp, (wheels,))
        return state, wheels

    def reference(self, state: Stateless, inp: ControlInput) -> tuple[Stateless, np.ndarray]:
        """:meth:`__call__` in numpy (the reference of the compiled core)."""
        pose, env = inp.pose_world, inp.envelopes
        kx = self.along_gain_per_s
        ex, ey = _robot_frame(pose, inp.point_now_world)
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        fw = (inp.point_next_world - inp.point_now_world) / inp.dt_s
        fx, fy = c * fw[:, 0] + s * fw[:, 1], -s * fw[:, 0] + c * fw[:, 1]
        v_ref = np.hypot(fx, fy)
        lam = np.minimum(1.0, v_ref / self.moving_speed_m_s)
        v = fx + kx * ex
        e_th = np.arctan2(fy, fx)
        sin_e = np.sin(e_th)
        heading = sin_e + lam**4 * (2.0 * np.sin(0.5 * e_th) - sin_e)
        w = np.where(lam > 0.0, lam * v_ref * (self.lateral_gain_per_m2 * ey
                                               + self.heading_gain_per_m * heading), 0.0)
        ux, uy = v, fy + kx * ey
        u = np.hypot(ux, uy)
        alpha = _half_plane_angle(uy, ux)
        half_b = 0.5 * env.wheel_base_m
        turn = (_braked_turn(self.regulate_gain_per_s * alpha * half_b, alpha, env) / half_b
                * np.minimum(1.0, u / (kx * self.regulate_radius_m)))
        w = w + np.where((lam < 1.0) & (u > 0.0), (1.0 - lam) * turn, 0.0)
        return state, _finish(_wheels(v, w, env.wheel_base_m), inp)


# --------------------------------------------------------------------------- precision


@dataclass(frozen=True)
class PrecisionState:
    """Per robot (rows): the filtered pose at the last observation [m, m, rad; world], the wheel
    gains estimated (actual / commanded, left and right), the commands sent before the last one
    (n, H, 2) [m/s], the filtered target point [m; world], the filtered feed-forward velocity
    [m/s; world] and the rate [rad/s] at which it turns, the driving direction (+1 ahead, -1 in
    reverse), the running mean of the robot's observed offset from its point [m; world] (the gain
    boost's trigger) and whether the row has been initialised."""

    pose_world: np.ndarray
    gains: np.ndarray
    history_m_s: np.ndarray
    target_world: np.ndarray
    feed_m_s: np.ndarray
    turn_rad_s: np.ndarray
    direction: np.ndarray
    offset_world: np.ndarray
    ready: np.ndarray


# Commands kept besides the last one sent (_HISTORY, the core's): an age of up to this many ticks is compensated.
_STATE_FIELDS = tuple(f.name for f in fields(PrecisionState))


@dataclass(frozen=True)
class Precision:
    """Offset-point tracking with feed-forward, an own-pose filter and wheel-gain estimation.

    1. Filter: the last filtered pose is driven forward over one tick by the commands that were
       in effect (the gains estimated applied), then pulled toward the observation by
       pose_gain_ratio / heading_gain_ratio. The innovation in wheel travel adapts the gains (normalised
       LMS, rate gain_rate_ratio, kept within [gain_min_ratio, gain_max_ratio]). A robot observed farther
       than gain_boost_from_m [m] from its point adapts faster: the rate times 1 + min(gain_boost_max_ratio,
       gain_boost_per_m [1/m] x the excess). The slow rate keeps the tracker's noise out of the gains; a
       wheel-gain change (a robot slowed to 50%, or back to speed) shows first as the robot falling off its
       point, and at the slow rate alone the gains caught up too late (issue 30: a robot slowed to 50%
       bent the paper triangle by up to 1.03 cm, 1.31 cm when it came back to speed). The distance is that
       of the offset's running mean, which moves gain_boost_mean_ratio of the way to each frame's offset: the
       tracker's noise alone seldom moves it past gain_boost_from_m (each frame's own offset tripped the boost
       at sigma 3-5 mm, and under l1, which piles the residual onto one robot: docs/benchmarks.md section 4).
    2. Age: the filtered pose is driven forward by age_s [s] over the commands already sent.
    3. Target: the structure point at that time (point_now + age f, f = (next - now) / dt_s),
       smoothed by target_gain_ratio around its own prediction; f is smoothed by feed_gain_ratio around its
       prediction as turning at a rate, itself tracked with turn_gain_ratio. Both
       follow the structure's twist, which every robot sees alike, so the smoothing delays the
       formation as a rigid body and does not bend it.
    4. Law: a point offset_m [m] ahead of the axle follows the target's offset point at the
       feed-forward velocity plus position_gain_per_s [1/s] times its error; wheels divided by
       the gains estimated, then the envelope (no windup: only commands sent enter the filter).
       A robot whose point moves backwards of its heading (cos below -reverse_cos_ratio) drives in reverse.
    """

    position_gain_per_s: float = 2.5
    offset_m: float = 0.025
    pose_gain_ratio: float = 0.15
    heading_gain_ratio: float = 0.1
    target_gain_ratio: float = 0.2
    feed_gain_ratio: float = 0.3
    turn_gain_ratio: float = 0.1
    reverse_cos_ratio: float = 0.2
    gain_rate_ratio: float = 0.01
    gain_min_ratio: float = 0.5
    gain_max_ratio: float = 2.0
    moving_speed_m_s: float = 0.01
    travel_floor_m: float = 0.0005
    gain_boost_from_m: float = 0.005
    gain_boost_per_m: float = 1600.0
    gain_boost_max_ratio: float = 9.0
    gain_boost_mean_ratio: float = 0.35
    _allow_zero = ("gain_rate_ratio", "gain_boost_per_m", "gain_boost_max_ratio")
    _at_most = {"pose_gain_ratio": 1.0, "heading_gain_ratio": 1.0, "target_gain_ratio": 1.0, "feed_gain_ratio": 1.0,
                "gain_boost_mean_ratio": 1.0}

    def __post_init__(self) -> None:
        _check_gains(self)
        if not self.gain_min_ratio <= 1.0 <= self.gain_max_ratio:
            raise ControllerGainError("gain_min_ratio <= 1 <= gain_max_ratio is required")
        _core_gains(self, [getattr(self, f) for f in PRECISION_GAIN_FIELDS])   # vs_precision_gains' order

    def initial(self, n: int) -> PrecisionState:
        z2 = np.zeros((n, 2))
        return PrecisionState(np.zeros((n, 3)), np.ones((n, 2)), np.zeros((n, _HISTORY, 2)),
                              z2, z2, np.zeros(n), np.ones(n), z2, np.zeros(n, dtype=bool))

    def __call__(self, state: PrecisionState, inp: ControlInput) -> tuple[PrecisionState, np.ndarray]:
        n = len(inp.active)
        new = (np.empty((n, 3)), np.empty((n, 2)), np.empty((n, _HISTORY, 2)), np.empty((n, 2)), np.empty((n, 2)),
               np.empty(n), np.empty(n), np.empty((n, 2)), np.empty(n, dtype=bool))
        wheels = np.empty((n, 2))
        old = (state.pose_world, state.gains, state.history_m_s, state.target_world, state.feed_m_s,
               state.turn_rad_s, state.direction, state.offset_world, state.ready)
        _core_call(_core.control_precision, (self._core, *old), inp, (*new, wheels), head_flags=(_READY,))
        out = object.__new__(PrecisionState)   # the dataclass without its __init__ (1 us of 5 at n = 3)
        out.__dict__.update(zip(_STATE_FIELDS, new))
        return out, wheels

    def reference(self, state: PrecisionState, inp: ControlInput) -> tuple[PrecisionState, np.ndarray]:
        """:meth:`__call__` in numpy (the reference of the compiled core)."""
        dt, env, act = inp.dt_s, inp.envelopes, inp.active
        base = env.wheel_base_m
        z = inp.pose_world
        # commands in effect, newest first: seq[j] was sent j + 1 frames before this one
        seq = np.concatenate([inp.wheels_prev_m_s[:, None, :], state.history_m_s], axis=1)
        m = min(int(inp.age_s // dt), _HISTORY - 1)
        frac = min(max(inp.age_s - m * dt, 0.0), dt) if m < _HISTORY - 1 else 0.0
        g = state.gains

        # 1. filter, previous observation -> this one: seq[m + 1] for frac, then seq[m]
        pred = integrate_arcs(state.pose_world, g * seq[:, m + 1], frac, base) if frac > 0.0 else state.pose_world
        pred = integrate_arcs(pred, g * seq[:, m], dt - frac, base)
        travel = g * (seq[:, m] * (dt - frac) + seq[:, m + 1] * frac)
        nx, ny = z[:, 0] - pred[:, 0], z[:, 1] - pred[:, 1]
        nth = wrap_angles(z[:, 2] - pred[:, 2])
        c, s = np.cos(pred[:, 2]), np.sin(pred[:, 2])
        along = c * nx + s * ny
        d_wheel = columns(along - 0.5 * base * nth, along + 0.5 * base * nth)
        # a robot measurably off its point (a wheel-gain change shows there first: a robot slowed, or back to
        # speed) adapts its gains faster: the rate times 1 + min(max, per_m (distance - from)), the distance that
        # of the offset's running mean (the tracker's noise alone seldom moves the mean that far)
        so, a = state.offset_world, self.gain_boost_mean_ratio
        offset = columns(so[:, 0] + a * ((z[:, 0] - inp.point_now_world[:, 0]) - so[:, 0]),
                         so[:, 1] + a * ((z[:, 1] - inp.point_now_world[:, 1]) - so[:, 1]))
        ox, oy = offset[:, 0], offset[:, 1]
        off = np.sqrt(ox * ox + oy * oy)
        boost = 1.0 + np.minimum(self.gain_boost_max_ratio,
                                 self.gain_boost_per_m * np.maximum(off - self.gain_boost_from_m, 0.0))
        g_new = g + self.gain_rate_ratio * boost[:, None] * d_wheel * travel / (travel * travel
                                                                                + self.travel_floor_m ** 2) * g
        g_new = np.clip(g_new, self.gain_min_ratio, self.gain_max_ratio)
        est = columns(pred[:, 0] + self.pose_gain_ratio * nx, pred[:, 1] + self.pose_gain_ratio * ny,
                        wrap_angles(pred[:, 2] + self.heading_gain_ratio * nth))
        fresh = ~state.ready
        est = np.where(fresh[:, None], z, est)
        g_new = np.where(fresh[:, None], g, g_new)

        # 2. frame age, this observation -> the command's start: seq[m] for frac, then seq[m-1..0]
        p = integrate_arcs(est, g_new * seq[:, m], frac, base) if frac > 0.0 else est
        for j in range(m - 1, -1, -1):
            p = integrate_arcs(p, g_new * seq[:, j], dt, base)

        # 3. target at the command's start, smoothed around its prediction
        f_raw = (inp.point_next_world - inp.point_now_world) / dt
        # the feed-forward velocity, tracked as turning at a constant rate (no lag in a steady turn)
        ca, sa = np.cos(state.turn_rad_s * dt), np.sin(state.turn_rad_s * dt)
        fp = columns(ca * state.feed_m_s[:, 0] - sa * state.feed_m_s[:, 1],
                       sa * state.feed_m_s[:, 0] + ca * state.feed_m_s[:, 1])
        nu = f_raw - fp
        fp2 = fp[:, 0] ** 2 + fp[:, 1] ** 2
        moving = fp2 > self.moving_speed_m_s ** 2
        turn_nu = np.where(moving, (fp[:, 0] * nu[:, 1] - fp[:, 1] * nu[:, 0]) / np.where(moving, fp2, 1.0), 0.0)
        turn = np.where(moving, state.turn_rad_s + self.turn_gain_ratio * turn_nu / dt,
                        (1.0 - self.feed_gain_ratio) * state.turn_rad_s)
        f = fp + self.feed_gain_ratio * nu
        f = np.where(fresh[:, None], f_raw, f)
        f_filtered = f
        turn = np.where(fresh, 0.0, turn)
        raw = inp.point_now_world + inp.age_s * f_raw
        guess = state.target_world + state.feed_m_s * dt
        target = np.where(fresh[:, None], raw, guess + self.target_gain_ratio * (raw - guess))

        # 4. offset-point law: the point P = c + l m, m the driving direction (the heading, or its
        # opposite in reverse), follows T + l m_ref, m_ref the point's direction of motion
        # evaluated at the middle of the command's tick: the point's velocity turned on by
        # turn * age, the heading by the last command's turn rate over dt/2
        ahead = turn * inp.age_s  # f is the chord velocity of [now, next]: its middle is dt/2 in
        ca, sa = np.cos(ahead), np.sin(ahead)
        f = columns(ca * f[:, 0] - sa * f[:, 1], sa * f[:, 0] + ca * f[:, 1])
        w_last = (g_new[:, 1] * seq[:, 0, 1] - g_new[:, 0] * seq[:, 0, 0]) / base
        th_mid = p[:, 2] + 0.5 * dt * w_last
        speed = np.hypot(f[:, 0], f[:, 1])
        lam = np.minimum(1.0, speed / self.moving_speed_m_s)
        hc = columns(np.cos(th_mid), np.sin(th_mid))
        safe = np.where(speed > 0.0, speed, 1.0)[:, None]
        # reverse while the point moves backwards of the driving direction (hysteresis: reverse_cos_ratio)
        along = (f[:, 0] * hc[:, 0] + f[:, 1] * hc[:, 1]) / safe[:, 0] * state.direction
        direction = np.where((speed > self.moving_speed_m_s) & (along < -self.reverse_cos_ratio), -state.direction,
                             state.direction)
        direction = np.where(fresh, np.where((speed > 0.0) & (along < 0.0), -1.0, 1.0), direction)
        m_dir = direction[:, None] * hc
        hr = np.where((speed > 0.0)[:, None], f / safe, m_dir)
        hb = lam[:, None] * hr + (1.0 - lam[:, None]) * m_dir
        hb_n = np.hypot(hb[:, 0], hb[:, 1])[:, None]
        hb = np.where(hb_n > 1e-9, hb / np.where(hb_n > 1e-9, hb_n, 1.0), m_dir)
        nr = columns(-hb[:, 1], hb[:, 0])
        l = self.offset_m
        feed = f + (lam * l * turn)[:, None] * nr
        err = (target - p[:, :2]) + l * (hb - m_dir)
        u = feed + self.position_gain_per_s * err
        v = u[:, 0] * hc[:, 0] + u[:, 1] * hc[:, 1]
        w = (-u[:, 0] * hc[:, 1] + u[:, 1] * hc[:, 0]) / (l * direction)
        wheels = _wheels(v, w, base) / g_new
        out = _finish(wheels, inp)

        keep = ~act[:, None]
        new = PrecisionState(
            pose_world=np.where(keep, state.pose_world, est),
            gains=np.where(keep, state.gains, g_new),
            history_m_s=np.where(keep[:, :, None], state.history_m_s, seq[:, :_HISTORY]),
            target_world=np.where(keep, state.target_world, target),
            feed_m_s=np.where(keep, state.feed_m_s, f_filtered),
            turn_rad_s=np.where(act, turn, state.turn_rad_s),
            direction=np.where(act, direction, state.direction),
            offset_world=np.where(keep, state.offset_world, offset),
            ready=state.ready | act)
        return new, out


# --------------------------------------------------------------------------- deadband, factory


@dataclass(frozen=True)
class Held:
    """A controller that holds still while the point rests and the robot is within deadband_m.

    A robot at rest on its point would otherwise chase the tracker's noise. "Rests" means the
    point moves slower than still_speed_m_s [m/s]; the command then brakes to zero within the
    envelope. The inner controller's state is updated as usual.
    """

    inner: object
    deadband_m: float = 0.004
    still_speed_m_s: float = 0.001

    def __post_init__(self) -> None:
        for name in ("deadband_m", "still_speed_m_s"):
            _gain(name, getattr(self, name), allow_zero=True)

    def initial(self, n: int):
        return self.inner.initial(n)

    def __call__(self, state, inp: ControlInput):
        state, wheels = self.inner(state, inp)
        if type(self.inner) not in _IN_CORE:   # the wheels are the core's fresh array only then
            wheels = np.array(wheels, dtype=float, order="C")
        _core_call(_core.control_hold, (self.deadband_m, self.still_speed_m_s), inp, (wheels,))
        return state, wheels

    def reference(self, state, inp: ControlInput):
        """:meth:`__call__` in numpy (the reference of the compiled core), the inner's reference too."""
        inner = getattr(self.inner, "reference", self.inner)
        state, wheels = inner(state, inp)
        step = np.hypot(*(inp.point_next_world - inp.point_now_world).T)
        dist = np.hypot(*(inp.point_now_world - inp.pose_world[:, :2]).T)
        held = (step <= self.still_speed_m_s * inp.dt_s) & (dist <= self.deadband_m)
        if np.any(held):
            env = inp.envelopes
            stop = limit_wheels_v_reference(np.zeros_like(wheels), inp.wheels_prev_m_s, inp.dt_s,
                                            env.wheel_speed_max_m_s, env.wheel_accel_max_m_s2)
            wheels = np.where((held & inp.active)[:, None], stop, wheels)
        return state, wheels


# the controllers whose __call__ returns a fresh wheels array of the core's
_IN_CORE = (TurnThenGo, Arc, Tracking, Precision)

CONTROLLERS: dict[str, Callable[..., object]] = {
    "turn_then_go": TurnThenGo,
    "arc": Arc,
    "tracking": Tracking,
    "precision": Precision,
}

# Measured in bench/precision.py and tests/test_closed_loop.py: lowest deviation and jitter.
DEFAULT_CONTROLLER = "precision"


def make_controller(name: str, deadband_m: float = 0.004, **gains: float):
    """Build the controller registered as ``name`` with keyword gains (see its class).

    The result holds still within ``deadband_m`` [m] of a resting point (see :class:`Held`);
    deadband_m = 0 gives the bare controller. Raises UnknownControllerError for an unknown
    name, TypeError for an unknown gain and ControllerGainError for a bad value.
    """
    try:
        factory = CONTROLLERS[name]
    except KeyError:
        raise UnknownControllerError(
            f"unknown controller {name!r}; known: {', '.join(sorted(CONTROLLERS))}"
        ) from None
    known = {f.name for f in fields(factory)}
    unknown = sorted(set(gains) - known)
    if unknown:
        raise TypeError(f"{name} has no gain {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    controller = factory(**gains)
    return Held(controller, deadband_m) if deadband_m > 0.0 else controller


__all__ = ["ControlInput", "Envelopes", "Stateless", "PrecisionState", "TurnThenGo", "Arc", "Tracking",
           "Precision", "Held", "CONTROLLERS", "DEFAULT_CONTROLLER", "make_controller",
           "UnknownControllerError", "ControllerGainError"]
