"""An independent reference for bench/room.py: OMPL plans the structure's rigid footprint in SE(2).

The footprint is the template's bodies (discs of radius r_i at the template points, structure frame);
a pose (x, y, th) is valid when every body keeps at least ``margin_m`` from every round obstacle
(x, y, r) (the field's own test, vsfleet.field, without its lattice inflation). The state space is
OMPL's SE2StateSpace with the heading weighted by the footprint's reach rho = max_i |p_i| + r_i, so
that its distance |dxy| + rho |dth| bounds how far any body moves; motions are checked every
``resolution_m`` of that distance (0.5 cm: no body jumps more than 5 mm between two checked poses).
The planner (RRTConnect by default; RRT* or BIT* on request) runs with a fixed seed and a budget of
state validity checks (300 000, about 4-8 s on the bench machine; a budget, not a time, so that a busy
machine gives the same answer; a 30 s time limit guards it); its path is then simplified (OMPL's
PathSimplifier, to its end) and every motion of it checked again here.

    from bench.ompl_ref import plan_ompl
    res = plan_ompl(template_xy, radii, obstacles, start=(x, y, th), goal=(x, y, th))
    res.success, res.length_m, res.time_s, res.path   # path (k, 3) [m, m, rad]

OMPL 2.0's Python bindings (nanobind): ``from ompl import base as ob, geometric as og, util as ou``;
a validity checker may be a plain callable taking an SE2StateType (getX/getY/getYaw).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

MARGIN_M = 0.02          # vsfleet.step.PLAN_MARGIN_M: the same clearance as our planner's
RESOLUTION_M = 0.005     # motion checks: no body moves more than this between two checked poses
MAX_CHECKS = 300_000     # the planner's budget: state validity checks (~5 s here); deterministic, unlike a time
TIME_LIMIT_S = 30.0      # a guard only: the budget ends a search first unless the machine is very slow
SEED = 1
PLANNERS = ("rrtconnect", "rrtstar", "bitstar")


def available() -> bool:
    """OMPL's Python bindings import (pip install ompl>=2.0; the bench extra)."""
    try:
        from ompl import base, geometric, util  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class OmplResult:
    success: bool            # an exact solution, valid again after simplification
    length_m: float          # translational length of the structure origin's path [m] (nan: none)
    time_s: float            # planning + simplification, wall clock [s]
    checks: int              # state validity checks made (planning and simplification)
    path: np.ndarray         # (k, 3) poses [m, m, rad]; empty without a solution
    status: str              # OMPL's PlannerStatus, as text


def footprint(template_xy, radii) -> tuple[np.ndarray, np.ndarray, float]:
    """(template (n, 2), radii (n,), reach rho = max |p_i| + r_i)."""
    tpl = np.asarray(template_xy, dtype=float).reshape(-1, 2)
    rad = np.broadcast_to(np.asarray(radii, dtype=float), (len(tpl),)).copy()
    return tpl, rad, float((np.hypot(tpl[:, 0], tpl[:, 1]) + rad).max())


def clearance_m(template_xy, radii, obstacles, pose) -> float:
    """The smallest distance [m] between a body of the footprint at ``pose`` and an obstacle's edge
    (+inf without obstacles)."""
    tpl, rad, _ = footprint(template_xy, radii)
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    if not len(obs):
        return math.inf
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    bx = x + c * tpl[:, 0] - s * tpl[:, 1]
    by = y + s * tpl[:, 0] + c * tpl[:, 1]
    d = np.hypot(bx[:, None] - obs[None, :, 0], by[:, None] - obs[None, :, 1]) - rad[:, None] - obs[None, :, 2]
    return float(d.min())


def validity_fn(template_xy, radii, obstacles, margin_m: float = MARGIN_M):
    """valid(x, y, th): every body at least margin_m from every obstacle (squared distances, no sqrt)."""
    tpl, rad, _ = footprint(template_xy, radii)
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    if not len(obs):
        return lambda x, y, th: True
    px, py = tpl[:, 0].copy(), tpl[:, 1].copy()
    ox, oy = obs[:, 0][None, :], obs[:, 1][None, :]
    need2 = (rad[:, None] + obs[None, :, 2] + margin_m) ** 2
    cos, sin = math.cos, math.sin

    def valid(x: float, y: float, th: float) -> bool:
        c, s = cos(th), sin(th)
        dx = (x + c * px - s * py)[:, None] - ox
        dy = (y + s * px + c * py)[:, None] - oy
        return not bool(((dx * dx + dy * dy) < need2).any())

    return valid


def default_bounds(template_xy, radii, obstacles, start, goal, pad_m: float = 0.3) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi): the box around the obstacles, the start and the goal, widened by the
    footprint's reach + pad_m, so that an open room can be gone around."""
    _, _, rho = footprint(template_xy, radii)
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    xs = [start[0], goal[0]] + list(obs[:, 0] - obs[:, 2]) + list(obs[:, 0] + obs[:, 2])
    ys = [start[1], goal[1]] + list(obs[:, 1] - obs[:, 2]) + list(obs[:, 1] + obs[:, 2])
    w = rho + pad_m
    return min(xs) - w, max(xs) + w, min(ys) - w, max(ys) + w


def path_length_m(path) -> float:
    """Translational length of a path of poses (k, 3): the origin's polyline [m]."""
    p = np.asarray(path, dtype=float).reshape(-1, 3)
    if len(p) < 2:
        return 0.0
    return float(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])).sum())


def motion_valid(valid, a, b, resolution_m: float, rho: float) -> bool:
    """The straight SE(2) motion a -> b (heading the short way) checked every resolution_m of body travel."""
    dth = math.remainder(b[2] - a[2], 2 * math.pi)
    d = math.hypot(b[0] - a[0], b[1] - a[1]) + rho * abs(dth)
    m = max(1, math.ceil(d / resolution_m))
    return all(valid(a[0] + (b[0] - a[0]) * i / m, a[1] + (b[1] - a[1]) * i / m, a[2] + dth * i / m)
               for i in range(m + 1))


def plan_ompl(template_xy, radii, obstacles, start, goal, margin_m: float = MARGIN_M,
              max_checks: int = MAX_CHECKS, time_limit_s: float = TIME_LIMIT_S, seed: int = SEED,
              planner: str = "rrtconnect", resolution_m: float = RESOLUTION_M, bounds=None,
              simplify: bool = True) -> OmplResult:
    """Plan the footprint from ``start`` to ``goal`` (x, y, th) among ``obstacles`` (m, 3) with OMPL.

    The search stops at its first exact solution (RRTConnect; RRT* and BIT* keep improving theirs), after
    ``max_checks`` state validity checks, or after ``time_limit_s`` seconds, whichever comes first: with the
    seed fixed, the check budget makes the answer the same on any machine (the time limit is a guard)."""
    from ompl import base as ob  # noqa: PLC0415
    from ompl import geometric as og  # noqa: PLC0415
    from ompl import util as ou  # noqa: PLC0415

    if planner not in PLANNERS:
        raise ValueError(f"planner {planner!r}: one of {PLANNERS}")
    ou.setLogLevel(ou.LOG_NONE)
    # the seed generator restarts for every plan (OMPL complains, silenced above, but every room then
    # plans the same way whatever ran before it)
    ou.RNG.setSeed(max(1, int(seed)))
    _, _, rho = footprint(template_xy, radii)
    check = validity_fn(template_xy, radii, obstacles, margin_m)
    calls = [0]

    def valid(x: float, y: float, th: float) -> bool:
        calls[0] += 1
        return check(x, y, th)

    t0 = time.perf_counter()
    if not (valid(*start) and valid(*goal)):
        return OmplResult(False, math.nan, time.perf_counter() - t0, calls[0], np.empty((0, 3)), "invalid start or goal")

    space = ob.SE2StateSpace()
    space.setSubspaceWeight(1, rho)          # distance = |dxy| + rho |dth| >= the farthest body's travel
    x_lo, x_hi, y_lo, y_hi = default_bounds(template_xy, radii, obstacles, start, goal) if bounds is None else bounds
    b = ob.RealVectorBounds(2)
    b.setLow(0, x_lo)
    b.setHigh(0, x_hi)
    b.setLow(1, y_lo)
    b.setHigh(1, y_hi)
    space.setBounds(b)
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda s: valid(s.getX(), s.getY(), s.getYaw()))
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(resolution_m / space.getMaximumExtent())

    def state(p):
        s = space.allocState()
        s.setX(float(p[0]))
        s.setY(float(p[1]))
        s.setYaw(float(math.remainder(p[2], 2 * math.pi)))
        return s

    ss.setStartAndGoalStates(state(start), state(goal), 1e-6)
    if planner == "rrtconnect":
        ss.setPlanner(og.RRTConnect(si))
    elif planner == "rrtstar":
        ss.setPlanner(og.RRTstar(si))
    else:
        ss.setPlanner(og.BITstar(si))
    budget = ob.PlannerTerminationCondition(lambda: calls[0] >= max_checks)
    status = ss.solve(ob.plannerOrTerminationCondition(budget, ob.timedPlannerTerminationCondition(float(time_limit_s))))
    exact = ss.haveExactSolutionPath()
    path = np.empty((0, 3))
    ok = False
    if exact:
        if simplify:
            ss.simplifySolution()
        p = ss.getSolutionPath()
        path = np.array([[p.getState(i).getX(), p.getState(i).getY(), p.getState(i).getYaw()]
                         for i in range(p.getStateCount())])
        # checked again here, independently of OMPL's motion validator
        ok = all(motion_valid(valid, path[i], path[i + 1], resolution_m, rho) for i in range(len(path) - 1))
    elapsed = time.perf_counter() - t0
    return OmplResult(ok, path_length_m(path) if ok else math.nan, elapsed, calls[0],
                      path if ok else np.empty((0, 3)), str(status))
