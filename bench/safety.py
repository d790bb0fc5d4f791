"""Offline evaluation of the safety filter (vsfleet.safety) against Robotarium's barrier certificate.

Randomised scenarios (N 3..30, random templates, random crowded starts, 0-6 round obstacles,
tracker noise sigma 2 mm on the observed poses), each run twice in the same closed loop:

    observe (truth + noise) -> nominal go-to-point on each robot's moving template point
    -> safety layer (vsfleet.safety.safety_filter, or Robotarium's unicycle barrier certificate)
    -> plant: the wheel envelope (vsfleet.kinematics.limit_wheels_v: speed and accel) and the exact
       arcs of vsfleet.kinematics.integrate_arcs, in 4 substeps per tick (contacts are checked on
       the true poses at every substep).

The structure (template at a pose) moves on a straight line from the start to the goal at
0.1 m/s, turning to the goal heading; it does not plan around obstacles (that is part 1 of issue
22), so robots whose points cross an obstacle are held off by the safety layer. A robot's point
is its control point 0.05 m ahead of its centre (Robotarium's projection distance), for both.

Robotarium: robotarium-python-simulator from PyPI (rps.utilities.barrier_certificates,
create_unicycle_barrier_certificate, barrier_gain 100, projection 0.05 m, magnitude 0.2 m/s,
safety_radius 2 r + margin + projection so that bodies are kept margin apart). Its unicycle
certificate has no obstacles; with obstacles the same single-integrator QP (cvxopt, its options)
gets one row per robot and obstacle in the same form (gain h^3), written here.

    .venv/bin/python bench/safety.py            # 200 scenarios
    .venv/bin/python bench/safety.py --quick    # 20 scenarios
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))

from vsfleet.kinematics import integrate_arcs, limit_wheels_v  # noqa: E402
from vsfleet.safety import SafetyParams, safety_filter  # noqa: E402

DT = 1.0 / 30.0
SUBSTEPS = 4
RADIUS = 0.05          # body radius [m] (a GRITSbot is 0.11 m across)
BASE = 0.12            # wheel base [m]
VMAX = 0.3             # wheel speed limit [m/s]
AMAX = 0.8             # wheel accel limit [m/s^2]
NOISE_XY = 0.002       # tracker noise sigma [m]
NOISE_TH = 0.005       # [rad]
MARGIN = 0.015         # both layers keep bodies this far apart (observed): 5 sigma of the 2.8 mm noise of a distance
L = 0.05               # control point ahead of the centre [m]
GAMMA = 5.0            # vsfleet: dh/dt >= -GAMMA h [1/s]
STRUCT_SPEED = 0.1     # [m/s]
SI_LIMIT = 0.2         # nominal point speed limit [m/s] (Robotarium's magnitude_limit)
K_P = 1.0              # nominal point gain [1/s]
AT_GOAL = 0.02         # every point within this of its final place [m]
HELD_TICKS = 15        # deadlock breaking: held back this long ...
DETOUR_TICKS = 30      # ... turns the nominal wish for this long ...
DETOUR_RAD = 1.2       # ... by this angle (left)
CROWD_RANGE = 0.25     # the nominal's crowd term: neighbours closer than this [m] ...
CROWD_GAIN = 0.05      # ... push at most this fast [m/s]
AROUND_RANGE = 0.05    # the nominal steers around bodies within this of its edge [m]
WAIT_DEV = 0.08        # the structure starts when every point is this close to its place [m] ...
ASSEMBLE_MAX_S = 30.0  # ... or after this long [s]; then it moves on the clock


@dataclass
class Scenario:
    seed: int
    n: int
    template: np.ndarray       # (n, 2) structure frame
    start: np.ndarray          # (n, 3)
    goal: tuple[float, float, float]
    obstacles: np.ndarray      # (k, 3)
    kind: str


def _template(rng, n: int) -> tuple[np.ndarray, str]:
    kind = rng.choice(["grid", "ring", "line", "wedge", "random"])
    s = 2 * RADIUS + rng.uniform(0.15, 0.30)   # gaps a body can pass through with its margins
    if kind == "grid":
        c = int(math.ceil(math.sqrt(n)))
        pts = np.array([[(k % c) * s, (k // c) * s] for k in range(n)], float)
    elif kind == "ring":
        rad = max(s / (2 * math.sin(math.pi / n)), s)
        a = 2 * math.pi * np.arange(n) / n
        pts = rad * np.c_[np.cos(a), np.sin(a)]
    elif kind == "line":
        pts = np.c_[np.zeros(n), np.arange(n) * s]
    elif kind == "wedge":
        pts = np.array([[-(k + 1) // 2 * s * 0.8, ((-1) ** k) * ((k + 1) // 2) * s * 0.8] for k in range(n)], float)
        pts[:, 1] *= 1.25
    else:
        pts = []
        while len(pts) < n:
            p = rng.uniform(-1, 1, 2) * s * math.sqrt(n) * 0.8
            if all(np.hypot(*(p - q)) >= s for q in pts):
                pts.append(p)
        pts = np.array(pts)
    return pts - pts.mean(axis=0), str(kind)


def _crowded(rng, n: int) -> np.ndarray:
    """n bodies packed at random in a small disk, 1.5-4 cm apart (gaps between bodies)."""
    rad = 2 * RADIUS * math.sqrt(n) * 0.75
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform(-rad, rad, 2)
        if np.hypot(*p) > rad:
            continue
        gap = rng.uniform(0.015, 0.04)
        if all(np.hypot(*(p - q)) >= 2 * RADIUS + gap for q in pts):
            pts.append(p)
        else:
            rad *= 1.0005
    xy = np.array(pts)
    return np.c_[xy, rng.uniform(-math.pi, math.pi, n)]


def _place(T, pts):
    c, s = math.cos(T[2]), math.sin(T[2])
    return np.c_[T[0] + c * pts[:, 0] - s * pts[:, 1], T[1] + s * pts[:, 0] + c * pts[:, 1]]


def make_scenario(seed: int) -> Scenario:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 31))
    template, kind = _template(rng, n)
    start = _crowded(rng, n)
    dist = rng.uniform(1.5, 3.0)
    ang = rng.uniform(-0.6, 0.6)
    goal = (dist * math.cos(ang), dist * math.sin(ang), float(rng.uniform(-math.pi, math.pi)))
    final = _place(goal, template)
    obs: list[np.ndarray] = []
    want = int(rng.integers(0, 7))
    tries = 0
    while len(obs) < want and tries < 2000:
        tries += 1
        f = rng.uniform(0.25, 0.75)
        c = np.array(goal[:2]) * f + rng.normal(0, 0.3, 2)
        R = rng.uniform(0.05, 0.25)
        clear = RADIUS + R + 0.08
        if np.min(np.hypot(*(start[:, :2] - c).T)) < clear + 0.2 or np.min(np.hypot(*(final - c).T)) < clear:
            continue
        if any(np.hypot(*(c - o[:2])) < R + o[2] + 2 * RADIUS + 0.1 for o in obs):   # passable gaps
            continue
        obs.append(np.array([c[0], c[1], R]))
    return Scenario(seed, n, template, start, goal, np.array(obs).reshape(-1, 3), kind)


def structure_at(sc: Scenario, t: float):
    """The structure pose at t: straight to the goal at STRUCT_SPEED, turning with it."""
    dist = math.hypot(sc.goal[0], sc.goal[1])
    T_move = dist / STRUCT_SPEED
    f = min(1.0, t / T_move)
    th = math.remainder(sc.goal[2], 2 * math.pi) * f
    return (sc.goal[0] * f, sc.goal[1] * f, th), T_move


def nominal_si(points: np.ndarray, targets: np.ndarray, targets_next: np.ndarray) -> np.ndarray:
    """Single-integrator nominal at the control points: feed-forward + K_P error, capped at SI_LIMIT."""
    dxi = (targets_next - targets) / DT + K_P * (targets - points)
    norm = np.hypot(dxi[:, 0], dxi[:, 1])
    scale = np.where(norm > SI_LIMIT, SI_LIMIT / np.maximum(norm, 1e-300), 1.0)
    return dxi * scale[:, None]


def crowd_term(centres: np.ndarray, points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The nominal's own way through a crowd (the same for both layers): a robot still away from its
    place is pushed off its close neighbours and around them (to the right), so that robots sitting
    on one another's places give way; the safety layer, not this, keeps bodies apart."""
    d = centres[:, None, :] - centres[None, :, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    np.fill_diagonal(dist, np.inf)
    w = np.where(dist < CROWD_RANGE, (CROWD_RANGE - dist) / CROWD_RANGE, 0.0)
    away = (d / np.maximum(dist, 1e-9)[..., None] * w[..., None]).sum(axis=1)
    err = targets - points
    en = np.hypot(err[:, 0], err[:, 1])
    right = np.c_[err[:, 1], -err[:, 0]] / np.maximum(en, 1e-9)[:, None]
    crowded = np.minimum(1.0, w.sum(axis=1))
    moving = np.minimum(1.0, en / 0.1)[:, None]
    return CROWD_GAIN * (away + moving * crowded[:, None] * right)


def around(centres: np.ndarray, points: np.ndarray, targets: np.ndarray, dxi: np.ndarray,
           obstacles: np.ndarray) -> np.ndarray:
    """The nominal goes around what blocks its way (the same for both layers): when the nearest body
    or obstacle within AROUND_RANGE of its edge lies within 60 deg of its wish, the wish turns to the
    tangent of that body on the side of the wish (the right when straight on), keeping its speed."""
    n = len(points)
    cen = np.r_[centres, obstacles[:, :2]] if len(obstacles) else centres
    rad = np.r_[np.full(n, RADIUS), obstacles[:, 2]] if len(obstacles) else np.full(n, RADIUS)
    d = centres[:, None, :] - cen[None, :, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    edge = dist - rad[None, :] - RADIUS
    edge[np.arange(n), np.arange(n)] = np.inf
    speed = np.hypot(dxi[:, 0], dxi[:, 1])
    out = dxi.copy()
    for i in range(n):
        j = int(np.argmin(edge[i]))
        if edge[i, j] > AROUND_RANGE or speed[i] < 1e-6 or np.hypot(*(targets[i] - points[i])) < 0.03:
            continue
        to = -d[i, j] / max(dist[i, j], 1e-12)           # towards the body
        wish = dxi[i] / speed[i]
        if wish @ to < 0.5:                               # not within 60 deg
            continue
        right = np.array([to[1], -to[0]])
        side = right if wish @ right >= -1e-9 else -right
        out[i] = speed[i] * side
    return out


def si_to_uni(dxi: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(v, w) of Robotarium's si_to_uni_dyn (projection L, angular limit pi), rows = robots."""
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    v = c * dxi[:, 0] + s * dxi[:, 1]
    w = np.clip((-s * dxi[:, 0] + c * dxi[:, 1]) / L, -math.pi, math.pi)
    return np.c_[v, w]


def uni_to_wheels(vw: np.ndarray) -> np.ndarray:
    return np.c_[vw[:, 0] - 0.5 * BASE * vw[:, 1], vw[:, 0] + 0.5 * BASE * vw[:, 1]]


def wheels_to_uni(u: np.ndarray) -> np.ndarray:
    return np.c_[0.5 * (u[:, 0] + u[:, 1]), (u[:, 1] - u[:, 0]) / BASE]


class Ours:
    name = "vsfleet"

    def __init__(self, sc: Scenario, offset: float):
        n = sc.n
        self.kw = dict(wheel_base_m=np.full(n, BASE), wheel_speed_max_m_s=np.full(n, VMAX),
                       obstacles=np.ascontiguousarray(sc.obstacles, dtype=float).reshape(-1, 3),
                       wheel_accel_max_m_s2=np.full(n, AMAX),
                       params=SafetyParams(margin_m=MARGIN, gamma_per_s=GAMMA, offset_m=offset, dt_s=DT))
        self.radius = np.full(n, RADIUS)
        self.stops = 0
        self.calls = 0

    def __call__(self, pose_obs, wheels_nom, wheels_prev):
        out, info = safety_filter(pose_obs, self.radius, wheels_nom, wheels_prev_m_s=wheels_prev, **self.kw)
        self.stops += info.n_stopped
        return out


class Unfiltered:
    """No safety layer: what the nominal reaches when bodies may pass through one another."""

    name = "none"

    def __init__(self, sc: Scenario):
        self.stops = 0

    def __call__(self, pose_obs, wheels_nom, wheels_prev):
        return wheels_nom


class Robotarium:
    name = "robotarium"

    def __init__(self, sc: Scenario):
        from cvxopt import matrix
        from cvxopt.solvers import qp
        from rps.utilities.barrier_certificates import create_unicycle_barrier_certificate
        from rps.utilities.transformations import create_si_to_uni_mapping, create_uni_to_si_dynamics

        self.gain = 100.0
        self.safety_radius = 2 * RADIUS + MARGIN + L
        self.cert = create_unicycle_barrier_certificate(barrier_gain=self.gain, safety_radius=self.safety_radius,
                                                        projection_distance=L, magnitude_limit=SI_LIMIT)
        self.si_to_uni, self.uni_to_si_states = create_si_to_uni_mapping(projection_distance=L)
        self.uni_to_si = create_uni_to_si_dynamics(projection_distance=L)
        self.obstacles = sc.obstacles
        self.matrix, self.qp = matrix, qp
        self.stops = 0
        self.calls = 0

    def _with_obstacles(self, dxu, x):
        """rps's unicycle certificate (create_single_integrator_barrier_certificate's QP, the same rows
        and cvxopt options) with one more row per robot and obstacle in the same form."""
        x_si = self.uni_to_si_states(x)
        dxi = self.uni_to_si(dxu, x)
        n = dxi.shape[1]
        r_si = self.safety_radius + L
        rows, rhs = [], []
        for i in range(n - 1):
            for j in range(i + 1, n):
                e = x_si[:, i] - x_si[:, j]
                h = e @ e - r_si ** 2
                a = np.zeros(2 * n)
                a[2 * i:2 * i + 2] = -2 * e
                a[2 * j:2 * j + 2] = 2 * e
                rows.append(a)
                rhs.append(self.gain * h ** 3)
        for i in range(n):
            for o in self.obstacles:
                e = x_si[:, i] - o[:2]
                h = e @ e - (RADIUS + L + o[2] + MARGIN) ** 2
                a = np.zeros(2 * n)
                a[2 * i:2 * i + 2] = -2 * e
                rows.append(a)
                rhs.append(self.gain * h ** 3)
        norms = np.linalg.norm(dxi, 2, 0)
        big = norms > SI_LIMIT
        dxi[:, big] *= SI_LIMIT / norms[big]
        H = self.matrix(2 * np.identity(2 * n))
        f = self.matrix(-2 * np.reshape(dxi, 2 * n, order="F"))
        res = self.qp(H, f, self.matrix(np.array(rows)), self.matrix(np.array(rhs, float)))["x"]
        return self.si_to_uni(np.reshape(res, (2, -1), order="F"), x)

    def __call__(self, pose_obs, wheels_nom, wheels_prev):
        dxu = wheels_to_uni(wheels_nom).T.copy()
        x = pose_obs.T.copy()
        if len(self.obstacles):
            safe = self._with_obstacles(dxu, x)
        else:
            safe = self.cert(dxu, x)
        return uni_to_wheels(np.asarray(safe).T)


@dataclass
class Result:
    contacts: int = 0
    min_gap: float = math.inf
    reached: bool = False
    t_goal: float = math.nan
    dev_moving: list = field(default_factory=list)
    dev_obstacle: list = field(default_factory=list)
    filter_s: float = 0.0
    ticks: int = 0
    stops: int = 0


def gaps(pose: np.ndarray, obstacles: np.ndarray) -> float:
    """The smallest gap between bodies, or a body and an obstacle [m] (negative: contact)."""
    xy = pose[:, :2]
    d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    np.fill_diagonal(d, np.inf)
    g = float(np.min(d)) - 2 * RADIUS
    if len(obstacles):
        do = np.hypot(xy[:, None, 0] - obstacles[None, :, 0], xy[:, None, 1] - obstacles[None, :, 1])
        g = min(g, float(np.min(do - obstacles[None, :, 2])) - RADIUS)
    return g


def run(sc: Scenario, layer, seed: int) -> Result:
    rng = np.random.default_rng(10_000 + seed)
    n = sc.n
    base = np.full(n, BASE)
    vmax, amax = np.full(n, VMAX), np.full(n, AMAX)
    pose = sc.start.copy()
    prev = np.zeros((n, 2))
    dist = math.hypot(sc.goal[0], sc.goal[1])
    T_end = dist / STRUCT_SPEED + 60.0
    sp = 0.0   # the structure's progress [s of motion]: it waits for the formation to assemble first
    started = False
    final = _place(sc.goal, sc.template)
    near_obstacle = np.zeros(n, bool)
    res = Result()
    res.min_gap = gaps(pose, sc.obstacles)
    held = np.zeros(n, int)
    detour = np.zeros(n, int)
    t = 0.0
    while t < T_end:
        obs = pose + np.c_[rng.normal(0, NOISE_XY, (n, 2)), rng.normal(0, NOISE_TH, n)]
        T_now, T_move = structure_at(sc, sp)
        c, s = np.cos(obs[:, 2]), np.sin(obs[:, 2])
        points_obs = obs[:, :2] + L * np.c_[c, s]
        assembled = np.max(np.hypot(*(points_obs - _place(T_now, sc.template)).T)) < WAIT_DEV
        started = started or assembled or t >= ASSEMBLE_MAX_S
        sp_next = sp + DT if started else sp
        T_next, _ = structure_at(sc, sp_next)
        targets, targets_next = _place(T_now, sc.template), _place(T_next, sc.template)
        dxi = nominal_si(points_obs, targets, targets_next) + crowd_term(obs[:, :2], points_obs, targets)
        dxi = around(obs[:, :2], points_obs, targets, dxi, sc.obstacles)
        # deadlock breaking (the nominal's, the same for both layers): a robot held back for 0.5 s
        # turns its wish 70 deg to the left for the next second (a right-of-way rule)
        ang = np.where(detour > 0, DETOUR_RAD, 0.0)
        ca, sa = np.cos(ang), np.sin(ang)
        dxi = np.c_[ca * dxi[:, 0] - sa * dxi[:, 1], sa * dxi[:, 0] + ca * dxi[:, 1]]
        wheels_nom = uni_to_wheels(si_to_uni(dxi, obs))
        t0 = time.perf_counter()
        wheels = layer(obs, np.ascontiguousarray(wheels_nom), prev)
        res.filter_s += time.perf_counter() - t0
        res.ticks += 1
        far = np.hypot(*(points_obs - targets).T) > 0.05
        v_nom = np.abs(wheels_nom.sum(axis=1)) + 1e-9
        held_back = far & (np.abs(wheels.sum(axis=1)) < 0.3 * v_nom)
        held = np.where(held_back, held + 1, np.maximum(held - 1, 0))
        detour = np.where(held > HELD_TICKS, DETOUR_TICKS, np.maximum(detour - 1, 0))
        held = np.where(held > HELD_TICKS, 0, held)
        wheels = limit_wheels_v(wheels, prev, DT, vmax, amax)   # the plant's envelope
        prev = wheels
        for _ in range(SUBSTEPS):
            pose = integrate_arcs(pose, wheels, DT / SUBSTEPS, base)
            g = gaps(pose, sc.obstacles)
            res.min_gap = min(res.min_gap, g)
            if g < 0.0:
                res.contacts += 1
        t += DT
        sp = sp_next
        points = pose[:, :2] + L * np.c_[np.cos(pose[:, 2]), np.sin(pose[:, 2])]
        dev = np.hypot(*(points - _place(structure_at(sc, sp)[0], sc.template)).T)
        if 0.0 < sp < T_move:
            res.dev_moving.append(float(np.mean(dev)))
            if len(sc.obstacles):
                tg = _place(structure_at(sc, sp)[0], sc.template)
                dto = np.hypot(tg[:, None, 0] - sc.obstacles[None, :, 0], tg[:, None, 1] - sc.obstacles[None, :, 1])
                near_obstacle = np.any(dto < sc.obstacles[None, :, 2] + RADIUS + 0.3, axis=1)
                if near_obstacle.any():
                    res.dev_obstacle.append(float(np.mean(dev)))
        if sp >= T_move and np.all(np.hypot(*(points - final).T) < AT_GOAL):
            res.reached, res.t_goal = True, t
            break
    res.stops = layer.stops
    res.final_err = np.hypot(*(points - _place(structure_at(sc, sp)[0], sc.template)).T)
    return res


def summary(name: str, rs: list[Result], scs: list[Scenario]) -> dict:
    reached = [r for r in rs if r.reached]
    with_obs = [r for r, sc in zip(rs, scs) if len(sc.obstacles)]
    return {
        "layer": name,
        "contacts (substeps)": sum(r.contacts for r in rs),
        "runs with contact": sum(r.contacts > 0 for r in rs),
        "min gap [mm]": 1e3 * min(r.min_gap for r in rs),
        "median min gap [mm]": 1e3 * float(np.median([r.min_gap for r in rs])),
        "reached": f"{len(reached)}/{len(rs)}",
        "reached, no obstacles": f"{sum(r.reached for r, sc in zip(rs, scs) if not len(sc.obstacles))}/"
                                 f"{sum(1 for sc in scs if not len(sc.obstacles))}",
        "median t_goal [s]": float(np.median([r.t_goal for r in reached])) if reached else math.nan,
        "mean deviation moving [mm]": 1e3 * float(np.mean([np.mean(r.dev_moving) for r in rs if r.dev_moving])),
        "mean deviation near obstacles [mm]": 1e3 * float(np.mean(
            [np.mean(r.dev_obstacle) for r in with_obs if r.dev_obstacle])) if with_obs else math.nan,
        "filter per tick [ms]": 1e3 * sum(r.filter_s for r in rs) / max(1, sum(r.ticks for r in rs)),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 scenarios instead of 200")
    ap.add_argument("--scenarios", type=int, default=None)
    ap.add_argument("--offset", type=float, default=0.03, help="vsfleet's offset_m [m]")
    ap.add_argument("--no-baseline", action="store_true", help="skip Robotarium and the unfiltered run")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    count = args.scenarios or (20 if args.quick else 200)
    layers = ["vsfleet"] + ([] if args.no_baseline else ["robotarium", "none"])
    results: dict[str, list[Result]] = {k: [] for k in layers}
    scs = []
    t_start = time.perf_counter()
    for k in range(count):
        sc = make_scenario(args.seed + k)
        scs.append(sc)
        line = [f"[{k + 1}/{count}] seed {sc.seed} N={sc.n} {sc.kind} obstacles={len(sc.obstacles)}"]
        for name in layers:
            layer = {"vsfleet": lambda: Ours(sc, args.offset), "robotarium": lambda: Robotarium(sc),
                     "none": lambda: Unfiltered(sc)}[name]()
            r = run(sc, layer, sc.seed)
            results[name].append(r)
            line.append(f"{name}: contacts={r.contacts} gap={1e3 * r.min_gap:.1f}mm "
                        f"{'goal %.0fs' % r.t_goal if r.reached else 'no goal'}")
        print("  ".join(line), f"({time.perf_counter() - t_start:.0f} s)", flush=True)
    rows = [summary(name, results[name], scs) for name in layers]
    keys = list(rows[0])
    print()
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(f"{v:.1f}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
