"""The fleet-wide safety filter: control barrier functions for robot bodies and round obstacles.

Every agent sees every pose and computes every robot's wheel command (rows = robots, the
mission's sorted id order), so every agent filters the whole fleet's nominal commands the same
way and takes its own row. :func:`safety_filter` runs the compiled core
(vsfleet/_core/vs_safety.c); :func:`safety_filter_reference` is the same rule in numpy, the
readable reference it is tested against (within 1e-9, equal counts). The method, its guarantees
and its limits: docs/safety.md and vsfleet/_core/vs_safety.h.

In short: robot i's control point p_i = (x, y) + offset (cos th, sin th) keeps
h = |p_i - p_j|^2 - (r_i + r_j + 2 offset + margin)^2 >= 0 by dh/dt >= -gamma h, each robot of a
pair taking half (where that h < 0, bodies closer than the offset allows, the same barrier on the
centres without the offset); an obstacle (or an inactive robot, a fixed disk with command zero) is taken
whole by the active robot. Each robot's command is then the exact Euclidean projection of its
nominal command onto its polygon of barrier rows and wheel box (speed limit, and the accel limit
from its previous command when given); an empty polygon softens the rows of bodies already inside
the margin from "separate" to "do not close", then relaxes the accel box, then (never, but for
rounding) stops the robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from .lazy import lazy_numpy
from . import _core
from .errors import NonFiniteError, ShapeError, VsfleetValueError

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

# magnitudes above this are refused (NonFiniteError): their squares would overflow
_BIG = 1e150
# a row a.u >= b holds at u when a.u - b >= -_TOL (|a0| vmax + |a1| vmax + |b|)
_TOL = 1e-10


class SafetyParamError(VsfleetValueError):
    """A safety filter parameter or per-robot limit is out of its range."""


@dataclass(frozen=True)
class SafetyParams:
    """The filter's parameters.

    margin_m [m] >= 0: added to every sum of radii: tracker noise and the tick's lookahead. Noise of
    sigma 2 mm per axis on each robot is 2.8 mm on a distance between two; 3 sigma (8.5 mm) held for
    seconds but a closed loop samples thousands of ticks, and 10 mm gave a 0.9 mm contact in one
    of the bench's runs, so 15 mm (5 sigma); an arc departs from its chord by <= vmax^2 dt^2 / b
    per robot (0.8 mm at 0.3 m/s, 30 Hz, b = 0.12 m). gamma_per_s [1/s] > 0 with gamma_per_s * dt_s
    <= 1: how fast a barrier may close (h(t + dt) >= (1 - gamma dt) h(t) on straight motion).
    offset_m [m] >= 0: the control point ahead of the centre (0: the centre itself, the barrier
    constrains v only; > 0: Robotarium's offset point, which also steers, bodies inflated by it;
    pairs closer than the offset allows fall back to the centres' barrier).
    dt_s [s] > 0: the control tick.
    """

    margin_m: float = 0.015
    gamma_per_s: float = 5.0
    offset_m: float = 0.0
    dt_s: float = 1.0 / 30.0

    def __post_init__(self) -> None:
        for name in ("margin_m", "gamma_per_s", "offset_m", "dt_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise SafetyParamError(f"{name} must be a number, got {v!r}")
            if not (math.isfinite(v) and abs(v) <= _BIG):
                raise NonFiniteError(f"{name} must be finite, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.margin_m < 0.0 or self.offset_m < 0.0:
            raise SafetyParamError(f"margin_m and offset_m must be >= 0, got {self.margin_m}, {self.offset_m}")
        if self.gamma_per_s <= 0.0 or self.dt_s <= 0.0:
            raise SafetyParamError(f"gamma_per_s and dt_s must be > 0, got {self.gamma_per_s}, {self.dt_s}")
        if not self.gamma_per_s * self.dt_s <= 1.0:
            raise SafetyParamError(f"gamma_per_s * dt_s must be <= 1, got {self.gamma_per_s * self.dt_s}")


@dataclass(frozen=True)
class SafetyInfo:
    """What the filter did: barrier rows kept (could bind within the speed box, over all robots),
    active robots whose nominal command was not feasible, robots whose polygon was empty (bodies
    inside the margin asked to separate in conflicting ways: those rows softened to "do not
    close"), robots solved without their accel box (empty even softened, or their previous
    command beyond the speed box), robots stopped (no command met their constraints: rounding
    only, as (0, 0) meets softened rows)."""

    n_constraints: int
    n_modified: int
    n_softened: int
    n_accel_relaxed: int
    n_stopped: int


def _f8(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


def _per_robot(name: str, value, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        return np.full(n, float(a))
    a = _f8(a)
    if a.shape != (n,):
        raise ShapeError(f"{name} must be a number or have shape ({n},), got {a.shape}")
    return a


def _finite(name: str, a: np.ndarray) -> None:
    if a.size and not (np.all(np.isfinite(a)) and float(np.max(np.abs(a))) <= _BIG):
        raise NonFiniteError(f"{name} must be finite (and below 1e150 in magnitude)")


def _checked(pose_world, radius_m, wheels_nominal_m_s, wheel_base_m, wheel_speed_max_m_s, obstacles, active,
             wheel_accel_max_m_s2, wheels_prev_m_s, params):
    """The validated, C-contiguous float64 inputs (shared by the core path and the reference)."""
    if not isinstance(params, SafetyParams):
        raise SafetyParamError(f"params must be a SafetyParams, got {type(params).__name__}")
    pose = _f8(pose_world)
    if pose.ndim != 2 or pose.shape[1] != 3:
        raise ShapeError(f"pose_world must have shape (n, 3), got {pose.shape}")
    n = pose.shape[0]
    nominal = _f8(wheels_nominal_m_s)
    if nominal.shape != (n, 2):
        raise ShapeError(f"wheels_nominal_m_s must have shape ({n}, 2), got {nominal.shape}")
    radius = _per_robot("radius_m", radius_m, n)
    base = _per_robot("wheel_base_m", wheel_base_m, n)
    vmax = _per_robot("wheel_speed_max_m_s", wheel_speed_max_m_s, n)
    obs = np.zeros((0, 3)) if obstacles is None else _f8(obstacles)
    if obs.size == 0:
        obs = np.zeros((0, 3))
    if obs.ndim != 2 or obs.shape[1] != 3:
        raise ShapeError(f"obstacles must have shape (k, 3) (x, y, r), got {obs.shape}")
    act = None
    if active is not None:
        act = np.ascontiguousarray(active, dtype=bool)
        if act.shape != (n,):
            raise ShapeError(f"active must have shape ({n},), got {act.shape}")
    if (wheel_accel_max_m_s2 is None) != (wheels_prev_m_s is None):
        raise SafetyParamError("wheel_accel_max_m_s2 and wheels_prev_m_s: give both or neither")
    amax = prev = None
    if wheel_accel_max_m_s2 is not None:
        amax = _per_robot("wheel_accel_max_m_s2", wheel_accel_max_m_s2, n)
        prev = _f8(wheels_prev_m_s)
        if prev.shape != (n, 2):
            raise ShapeError(f"wheels_prev_m_s must have shape ({n}, 2), got {prev.shape}")
    for name, a in (("pose_world", pose), ("wheels_nominal_m_s", nominal), ("radius_m", radius),
                    ("wheel_base_m", base), ("wheel_speed_max_m_s", vmax), ("obstacles", obs),
                    ("wheel_accel_max_m_s2", amax), ("wheels_prev_m_s", prev)):
        if a is not None:
            _finite(name, a)
    if np.any(radius < 0.0) or np.any(obs[:, 2] < 0.0):
        raise SafetyParamError("radii (robots' and obstacles') must be >= 0")
    if np.any(base <= 0.0) or np.any(vmax <= 0.0) or (amax is not None and np.any(amax <= 0.0)):
        raise SafetyParamError("wheel_base_m, wheel_speed_max_m_s and wheel_accel_max_m_s2 must be > 0")
    return pose, radius, nominal, base, vmax, obs, act, amax, prev


def safety_filter(pose_world, radius_m, wheels_nominal_m_s, *, wheel_base_m, wheel_speed_max_m_s,
                  obstacles=None, active=None, wheel_accel_max_m_s2=None, wheels_prev_m_s=None,
                  params: SafetyParams = SafetyParams()) -> tuple[np.ndarray, SafetyInfo]:
    """Safe wheel commands (n, 2) [m/s] for every robot, and what the filter did.

    pose_world (n, 3) [m, m, rad; world]: observed poses (an inactive robot's last seen one);
    radius_m: body radii [m] >= 0, a number or (n,); wheels_nominal_m_s (n, 2) (vl, vr): the
    commands asked for; wheel_base_m, wheel_speed_max_m_s: numbers or (n,) > 0; obstacles (k, 3)
    (x, y, r) [m] or None; active (n,) bool or None (all active): inactive robots are fixed disks
    and get (0, 0); wheel_accel_max_m_s2 (number or (n,)) with wheels_prev_m_s (n, 2): also keep
    each command within accel * dt of the previous one where safety allows, and add each moving
    robot's stopping distance (vl_prev^2 + vr_prev^2) / (4 accel) to its radius.
    Raises ShapeError, NonFiniteError (NaN, infinity, magnitudes above 1e150), SafetyParamError.
    """
    args = (pose_world, radius_m, wheels_nominal_m_s, wheel_base_m, wheel_speed_max_m_s, obstacles, active,
            wheel_accel_max_m_s2, wheels_prev_m_s, params)
    fast = _as_given(*args)
    if fast is not None:   # arrays as the core takes them: the core checks the values itself
        try:
            return _call_core(params, *fast)
        except (ValueError, TypeError):
            pass   # the checks below raise the typed error
    return _call_core(params, *_checked(*args))


def _call_core(params, pose, radius, nominal, base, vmax, obs, act, amax, prev):
    out = np.empty((len(pose), 2))
    counts = _core.safety_filter(params.margin_m, params.gamma_per_s, params.offset_m, params.dt_s, pose, radius,
                                 act, base, vmax, amax, prev, obs, nominal, out)
    return out, SafetyInfo(*counts)


def _is_f8(a, shape) -> bool:
    return (type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape
            and a.flags.c_contiguous)


def _as_given(pose, radius, nominal, base, vmax, obs, act, amax, prev, params):
    """The arguments as they are when every array already has the core's dtype, layout and shape
    (no copies, no scans: the core refuses bad values), else None."""
    if type(params) is not SafetyParams or type(pose) is not np.ndarray or pose.ndim != 2:
        return None
    n = pose.shape[0]
    if obs is None:
        obs = _no_obstacles()
    ok = (_is_f8(pose, (n, 3)) and _is_f8(nominal, (n, 2)) and _is_f8(radius, (n,)) and _is_f8(base, (n,))
          and _is_f8(vmax, (n,)) and type(obs) is np.ndarray and obs.ndim == 2 and _is_f8(obs, (len(obs), 3))
          and (act is None or (type(act) is np.ndarray and act.dtype == np.bool_ and act.shape == (n,)
                               and act.flags.c_contiguous))
          and ((amax is None and prev is None) or (_is_f8(amax, (n,)) and _is_f8(prev, (n, 2)))))
    return (pose, radius, nominal, base, vmax, obs, act, amax, prev) if ok else None


@lru_cache(maxsize=1)
def _no_obstacles():
    """(0, 3) obstacles, read-only: made on first use (numpy is not loaded at import, vsfleet.lazy)."""
    a = np.zeros((0, 3))
    a.flags.writeable = False
    return a


# --- the numpy reference of the compiled filter ---------------------------------------------------


def _feasible(rows: np.ndarray, u0: float, u1: float, s: float) -> bool:
    tol = _TOL * (np.abs(rows[:, 0]) * s + np.abs(rows[:, 1]) * s + np.abs(rows[:, 2]))
    return bool(np.all(rows[:, 0] * u0 + rows[:, 1] * u1 - rows[:, 2] >= -tol))


def _project(rows: np.ndarray, u: tuple[float, float], s: float):
    """The Euclidean projection of u onto {a_k.x >= b_k}, or None (empty): the nominal if feasible,
    else the nearest feasible foot of a violated row's line or vertex of a violated row with another
    (rows in order, the first of the nearest kept), as vs_safety.c."""
    if _feasible(rows, u[0], u[1], s):
        return u
    tol = _TOL * (np.abs(rows[:, 0]) * s + np.abs(rows[:, 1]) * s + np.abs(rows[:, 2]))
    slack = rows[:, 0] * u[0] + rows[:, 1] * u[1] - rows[:, 2]
    violated = slack < -tol
    best = None
    best_d = 0.0

    def consider(x0: float, x1: float) -> None:
        nonlocal best, best_d
        if _feasible(rows, x0, x1, s):
            d = (x0 - u[0]) * (x0 - u[0]) + (x1 - u[1]) * (x1 - u[1])
            if best is None or d < best_d:
                best, best_d = (x0, x1), d

    m = len(rows)
    for k in range(m):
        if not violated[k]:
            continue
        a0, a1, b = (float(v) for v in rows[k])
        nk = a0 * a0 + a1 * a1
        if nk > 0.0:
            t = -float(slack[k]) / nk
            consider(u[0] + t * a0, u[1] + t * a1)
        for j in range(m):
            if j == k or (j < k and violated[j]):
                continue
            c0, c1, e = (float(v) for v in rows[j])
            det = a0 * c1 - a1 * c0
            if det == 0.0:
                continue
            x0 = (b * c1 - a1 * e) / det
            x1 = (a0 * e - b * c0) / det
            if math.isfinite(x0) and math.isfinite(x1):
                consider(x0, x1)
    return best


def _box(lo0: float, lo1: float, hi0: float, hi1: float) -> np.ndarray:
    return np.array([[1.0, 0.0, lo0], [0.0, 1.0, lo1], [-1.0, 0.0, -hi0], [0.0, -1.0, -hi1]])


def safety_filter_reference(pose_world, radius_m, wheels_nominal_m_s, *, wheel_base_m, wheel_speed_max_m_s,
                            obstacles=None, active=None, wheel_accel_max_m_s2=None, wheels_prev_m_s=None,
                            params: SafetyParams = SafetyParams()) -> tuple[np.ndarray, SafetyInfo]:
    """:func:`safety_filter` in numpy (the reference of the compiled core): same arguments, result, errors."""
    pose, radius, nominal, base, vmax, obs, act, amax, prev = _checked(
        pose_world, radius_m, wheels_nominal_m_s, wheel_base_m, wheel_speed_max_m_s, obstacles, active,
        wheel_accel_max_m_s2, wheels_prev_m_s, params)
    n = len(pose)
    act = np.ones(n, dtype=bool) if act is None else act
    l, margin, gamma, dt = params.offset_m, params.margin_m, params.gamma_per_s, params.dt_s
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    px, py = pose[:, 0] + l * c, pose[:, 1] + l * s
    brake = np.zeros(n)   # (vl^2 + vr^2) / (4 amax): a bound on each robot's stopping distance
    if amax is not None:
        brake = np.where(act, (prev[:, 0] * prev[:, 0] + prev[:, 1] * prev[:, 1]) / (4.0 * amax), 0.0)
    out = np.zeros((n, 2))
    n_rows = n_modified = n_softened = n_relaxed = n_stopped = 0
    for i in range(n):
        if not act[i]:
            continue
        # every other robot, then every obstacle: its control point and disk sum, its centre and
        # disk sum, the share
        others = np.arange(n) != i
        act_o = act[others]
        qx = np.concatenate([np.where(act_o, px[others], pose[others, 0]), obs[:, 0]])
        qy = np.concatenate([np.where(act_o, py[others], pose[others, 1]), obs[:, 1]])
        esum = np.concatenate([(((radius[i] + radius[others]) + margin) + brake[i]) + brake[others],
                               ((radius[i] + obs[:, 2]) + margin) + brake[i]])
        dsum = esum + np.concatenate([np.where(act_o, 2.0 * l, l), np.full(len(obs), l)])
        ox = np.concatenate([pose[others, 0], obs[:, 0]])
        oy = np.concatenate([pose[others, 1], obs[:, 1]])
        share = np.concatenate([np.where(act_o, 0.5, 1.0), np.ones(len(obs))])
        dx, dy = px[i] - qx, py[i] - qy
        h = (dx * dx + dy * dy) - dsum * dsum
        # the control points' barrier while it holds, else the centres' (v alone)
        centre = ~(h >= 0.0) | (l == 0.0)
        cdx, cdy = pose[i, 0] - ox, pose[i, 1] - oy
        dx, dy = np.where(centre, cdx, dx), np.where(centre, cdy, dy)
        h = np.where(centre, (cdx * cdx + cdy * cdy) - esum * esum, h)
        li = np.where(centre, 0.0, l)
        g = 2.0 * (dx * c[i] + dy * s[i])
        q = 2.0 * li * (dy * c[i] - dx * s[i])
        a0, a1 = 0.5 * g - q / base[i], 0.5 * g + q / base[i]
        bnd = -(gamma * h) * share
        keep = ~(bnd <= -(np.abs(a0) + np.abs(a1)) * vmax[i])
        rows = np.stack([a0[keep], a1[keep], bnd[keep]], axis=1).reshape(-1, 3)
        n_rows += len(rows)
        u = (float(nominal[i, 0]), float(nominal[i, 1]))
        v = float(vmax[i])
        lo0 = lo1 = -v
        hi0 = hi1 = v
        accel = False
        if amax is not None:
            step = float(amax[i]) * dt
            lo0, lo1 = max(lo0, prev[i, 0] - step), max(lo1, prev[i, 1] - step)
            hi0, hi1 = min(hi0, prev[i, 0] + step), min(hi1, prev[i, 1] + step)
            accel = True
            if lo0 > hi0 or lo1 > hi1:
                lo0 = lo1 = -v
                hi0 = hi1 = v
                accel = False
                n_relaxed += 1
        full = np.concatenate([rows, _box(lo0, lo1, hi0, hi1)])
        if not _feasible(full, u[0], u[1], v):
            n_modified += 1
        x = _project(full, u, v)
        if x is None:
            rows = rows.copy()
            rows[rows[:, 2] > 0.0, 2] = 0.0
            n_softened += 1
            x = _project(np.concatenate([rows, _box(lo0, lo1, hi0, hi1)]), u, v)
        if x is None and accel:
            n_relaxed += 1
            x = _project(np.concatenate([rows, _box(-v, -v, v, v)]), u, v)
        if x is None:
            x = (0.0, 0.0)
            n_stopped += 1
        out[i] = x
    if not np.all(np.isfinite(out)):
        raise NonFiniteError("safety_filter: a safe command is not finite")
    return out, SafetyInfo(n_rows, n_modified, n_softened, n_relaxed, n_stopped)


__all__ = ["SafetyParams", "SafetyInfo", "SafetyParamError", "safety_filter", "safety_filter_reference"]
