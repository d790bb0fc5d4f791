"""A path for the virtual structure around round obstacles (docs/planning.md).

The structure is treated as its enclosing disc, centred on the structure origin: radius
``R = max_i (|p_i| + r_i) + margin``.  The disc does not change as the structure turns, so any
heading along a path that keeps the disc clear keeps every robot body at least ``margin`` from
every obstacle.  Each obstacle ``(x, y, r)`` becomes the disc of radius ``r + R`` (inflated) and
the structure origin, a point, looks for its shortest way among those discs on a tangent graph:

* nodes: the start, the goal, the tangent points from the start and the goal to each obstacle's
  planning circle (radius ``(1 + SLACK) (r + R)``; a point inside it gets its radial projection
  instead), the goal's radial projection on every planning circle (the nearest point to the goal:
  a candidate closest safe pose), and the bitangent points of every pair of circles;
* edges: straight segments between those points, and arcs along each circle between its nodes
  consecutive in angle, drawn as chords of at most ``ARC_STEP_RAD``; an edge exists only if every
  one of its segments stays at least ``r + R`` from every obstacle centre (checked exactly: the
  guarantee rests on this check, not on the graph's geometry);
* Dijkstra from the start; a counter-clockwise arc costs ``1 + SIDE_BIAS`` times its length, so
  between ways of nearly equal length (an obstacle right on the straight line) the one passing
  the obstacles clockwise wins by a fixed margin, and consecutive frames do not flip between them.

:func:`plan_structure` runs the compiled core (vsfleet/_core/vs_plan.c);
:func:`plan_structure_reference` is the same algorithm in readable Python, the reference it is
tested against (tests/test_core_plan.py).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

from .lazy import lazy_numpy
from . import _core
from .coreconst import (  # the core's (vs_plan.h), under the names this module has always used
    PLAN_ARC_STEP_RAD as ARC_STEP_RAD,
    PLAN_BLOCKED,
    PLAN_GOAL_TIE_M as GOAL_TIE_M,
    PLAN_MAX_ABS_M as MAX_ABS_M,
    PLAN_MAX_OBSTACLES as MAX_OBSTACLES,
    PLAN_OK,
    PLAN_SIDE_BIAS as SIDE_BIAS,
    PLAN_SLACK as SLACK,
)
from .errors import NonFiniteError, ShapeError, VsfleetValueError
from .geometry import Pose2, wrap_angle

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

_TWO_PI = 2.0 * math.pi
_CAP = 256      # waypoints room for the first core call (it says when it needs more)


@lru_cache(maxsize=1)
def _no_obstacles():
    """(0, 3) obstacles, read-only: made on first use (numpy is not loaded at import, vsfleet.lazy)."""
    a = np.zeros((0, 3))
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class StructurePlan:
    """A planned path for the structure.

    waypoints: structure poses [m, rad; world], the start position first; ready for
    ``GoalPath(plan.waypoints)``.  status: PLAN_OK (the last waypoint is the goal pose) or
    PLAN_BLOCKED (no path: the waypoints end at the reachable pose nearest the goal, all at the
    start heading).
    """

    waypoints: tuple[Pose2, ...]
    status: int

    @property
    def blocked(self) -> bool:
        return self.status == PLAN_BLOCKED

    def as_array(self) -> np.ndarray:
        """The waypoints as a (k, 3) array of (x, y, th)."""
        return np.array([w.as_tuple() for w in self.waypoints], dtype=float).reshape(-1, 3)


def _pose(p) -> np.ndarray:
    if isinstance(p, Pose2):
        return np.array((p.x, p.y, p.th))
    a = np.ascontiguousarray(p, dtype=float)
    if a.shape != (3,):
        raise ShapeError(f"a pose must be (x, y, th), got shape {a.shape}")
    return a


def _shapes(start, goal, template_xy, radius_m, obstacles):
    """Contiguous float64 arrays, or ShapeError."""
    tpl = np.ascontiguousarray(template_xy, dtype=float)
    if tpl.ndim != 2 or tpl.shape[1] != 2 or tpl.shape[0] == 0:
        raise ShapeError(f"template_xy must be (n, 2) with n >= 1, got shape {tpl.shape}")
    rad = np.ascontiguousarray(radius_m, dtype=float)
    if rad.ndim == 0:
        rad = np.full(tpl.shape[0], float(rad))
    if rad.shape != (tpl.shape[0],):
        raise ShapeError(f"radius_m must be ({tpl.shape[0]},), got shape {rad.shape}")
    obs = np.ascontiguousarray(obstacles if obstacles is not None else _no_obstacles(), dtype=float)
    if obs.size == 0:
        obs = _no_obstacles()
    if obs.ndim != 2 or obs.shape[1] != 3:
        raise ShapeError(f"obstacles must be (m, 3) rows (x, y, r), got shape {obs.shape}")
    return _pose(start), _pose(goal), tpl, rad, obs


def _validate(start, goal, template_xy, radius_m, margin_m, obstacles):
    """Arrays for the reference, or the typed error: ShapeError for shapes, NonFiniteError for
    NaN/inf, VsfleetValueError for ranges (the core checks the same)."""
    s, g, tpl, rad, obs = _shapes(start, goal, template_xy, radius_m, obstacles)
    margin = float(margin_m)
    for name, a in (("template_xy", tpl), ("radius_m", rad), ("obstacles", obs), ("start", s), ("goal", g),
                    ("margin_m", np.array([margin]))):
        if not np.all(np.isfinite(a)):
            raise NonFiniteError(f"{name} holds NaN or infinity")
    if obs.shape[0] > MAX_OBSTACLES:
        raise VsfleetValueError(f"at most {MAX_OBSTACLES} obstacles, got {obs.shape[0]}")
    if margin < 0.0 or np.any(rad < 0.0):
        raise VsfleetValueError("margin_m and radius_m must be >= 0")
    if obs.shape[0] and not np.all(obs[:, 2] > 0.0):
        raise VsfleetValueError("every obstacle radius must be > 0")
    for name, a in (("template_xy", tpl), ("radius_m", rad), ("obstacles", obs), ("start", s), ("goal", g),
                    ("margin_m", np.array([margin]))):
        if a.size and float(np.max(np.abs(a))) > MAX_ABS_M:
            raise VsfleetValueError(f"{name} holds a value beyond {MAX_ABS_M:g} m")
    return s, g, tpl, rad, margin, obs


def _plan(array: np.ndarray, status: int) -> StructurePlan:
    return StructurePlan(tuple(Pose2(float(x), float(y), float(th)) for x, y, th in array), int(status))


def plan_structure(start: Pose2 | Sequence[float], goal: Pose2 | Sequence[float], template_xy, radius_m,
                   margin_m: float, obstacles) -> StructurePlan:
    """A path for the structure from ``start`` to ``goal`` that keeps every robot body (template
    point ``template_xy[i]`` [m; structure frame] with radius ``radius_m[i]`` [m]) at least
    ``margin_m`` from every obstacle ``(x, y, r)`` [m; world] (rows of ``obstacles``, possibly
    none).  Pure and deterministic: every agent computes the same path (the compiled core)."""
    # shapes here; NaN/inf and ranges in the core, which raises the same typed errors
    s, g, tpl, rad, obs = _shapes(start, goal, template_xy, radius_m, obstacles)
    out = np.empty((_CAP, 3))
    while True:
        n, status = _core.plan_structure(tpl, rad, margin_m, obs, s, g, out)
        if status is not None:
            return StructurePlan(tuple(Pose2(x, y, th) for x, y, th in out[:n].tolist()), status)
        out = np.empty((n, 3))


# ---------------------------------------------------------------- the reference (plain Python)


def enclosing_radius(template_xy, radius_m, margin_m: float) -> float:
    """R = max_i (|p_i| + r_i) + margin [m]: the structure's disc about its origin."""
    best = 0.0
    for (px, py), r in zip(np.asarray(template_xy, dtype=float), np.asarray(radius_m, dtype=float)):
        e = math.sqrt(float(px) * float(px) + float(py) * float(py)) + float(r)
        if e > best:
            best = e
    return best + float(margin_m)


class _Graph:
    """The tangent graph, built in vs_plan.c's order (node and edge indices matter for ties)."""

    def __init__(self, obs: np.ndarray, big_r: float, start: np.ndarray):
        self.c = [(float(x), float(y)) for x, y, _ in obs]
        rk = [float(r) + big_r for r in obs[:, 2]]
        self.r2 = [r * r for r in rk]
        self.p = [r * (1.0 + SLACK) for r in rk]
        sx, sy = float(start[0]), float(start[1])
        self.s_in = [(sx - cx) * (sx - cx) + (sy - cy) * (sy - cy) < r2 for (cx, cy), r2 in zip(self.c, self.r2)]
        self.nodes: list[tuple[float, float, int, float]] = []   # x, y, circle (-1: S, G), angle
        self.edges: list[tuple[int, int, float, float, int, float, float, int]] = []  # u, v, cost u->v,
        # cost v->u, circle (-1: segment), arc start angle, arc span, chord count

    def seg_clear(self, ax: float, ay: float, bx: float, by: float, from_start: bool) -> bool:
        """Segment A-B at least r + R from every obstacle centre; from the start, a disc that holds
        the start only asks that the segment not get nearer its centre."""
        dx, dy = bx - ax, by - ay
        l2 = dx * dx + dy * dy
        for j, (cx, cy) in enumerate(self.c):
            if from_start and self.s_in[j]:
                if dx * (ax - cx) + dy * (ay - cy) < 0.0:
                    return False
                continue
            wx, wy = cx - ax, cy - ay
            t = (wx * dx + wy * dy) / l2 if l2 > 0.0 else 0.0
            t = min(1.0, max(0.0, t))
            qx, qy = ax + t * dx - cx, ay + t * dy - cy
            if qx * qx + qy * qy < self.r2[j]:
                return False
        return True

    def add_node(self, k: int, ex: float, ey: float) -> int:
        cx, cy = self.c[k]
        p = self.p[k]
        self.nodes.append((cx + p * ex, cy + p * ey, k, math.atan2(ey, ex)))
        return len(self.nodes) - 1

    def try_segment(self, u: int, v: int) -> None:
        ax, ay = self.nodes[u][:2]
        bx, by = self.nodes[v][:2]
        if self.seg_clear(ax, ay, bx, by, u == 0):
            length = math.sqrt((bx - ax) * (bx - ax) + (by - ay) * (by - ay))
            self.edges.append((u, v, length, length, -1, 0.0, 0.0, 0))

    def point_nodes(self, k: int, x: float, y: float, tangents: bool) -> list[int]:
        """Tangent points of (x, y) on circle k (if outside it and tangents), else its radial projection."""
        cx, cy = self.c[k]
        p = self.p[k]
        dx, dy = x - cx, y - cy
        d2 = dx * dx + dy * dy
        if tangents and d2 > p * p:
            d = math.sqrt(d2)
            ux, uy = dx / d, dy / d
            ca = p / d
            sa = math.sqrt(1.0 - ca * ca)
            return [self.add_node(k, ca * ux - sa * uy, ca * uy + sa * ux),
                    self.add_node(k, ca * ux + sa * uy, ca * uy - sa * ux)]
        if d2 > 0.0:
            d = math.sqrt(d2)
            return [self.add_node(k, dx / d, dy / d)]
        return [self.add_node(k, 1.0, 0.0)]

    def arc_points(self, k: int, alpha: float, span: float, nseg: int) -> list[tuple[float, float]]:
        """The arc's inner chord points, counter-clockwise."""
        cx, cy = self.c[k]
        p = self.p[k]
        step = span / nseg
        return [(cx + p * math.cos(alpha + step * i), cy + p * math.sin(alpha + step * i)) for i in range(1, nseg)]


def plan_structure_reference(start: Pose2 | Sequence[float], goal: Pose2 | Sequence[float], template_xy, radius_m,
                             margin_m: float, obstacles) -> StructurePlan:
    """The readable reference of :func:`plan_structure` (same arguments, same result within 1e-9)."""
    s, g, tpl, rad, margin, obs = _validate(start, goal, template_xy, radius_m, margin_m, obstacles)
    big_r = enclosing_radius(tpl, rad, margin)
    G = _Graph(obs, big_r, s)
    m = len(G.c)
    sx, sy, gx, gy = float(s[0]), float(s[1]), float(g[0]), float(g[1])
    G.nodes = [(sx, sy, -1, 0.0), (gx, gy, -1, 0.0)]
    G.try_segment(0, 1)
    # start and goal: tangent points (or radial projections), and the goal's projection always
    for k in range(m):
        for v in G.point_nodes(k, sx, sy, True):
            G.try_segment(0, v)
        cx, cy = G.c[k]
        if (gx - cx) * (gx - cx) + (gy - cy) * (gy - cy) > G.p[k] * G.p[k]:
            for v in G.point_nodes(k, gx, gy, True):
                G.try_segment(v, 1)
        G.try_segment(G.point_nodes(k, gx, gy, False)[0], 1)
    # bitangents: outer (+, -) then inner (+, -)
    for a in range(m):
        for b in range(a + 1, m):
            dx, dy = G.c[b][0] - G.c[a][0], G.c[b][1] - G.c[a][1]
            d = math.sqrt(dx * dx + dy * dy)
            for inner in (False, True):
                total = G.p[a] + G.p[b] if inner else G.p[a] - G.p[b]
                if not d > abs(total):
                    continue
                ux, uy = dx / d, dy / d
                cg = total / d
                sg = math.sqrt(1.0 - cg * cg)
                for sgn in (sg, -sg):
                    ex, ey = cg * ux - sgn * uy, cg * uy + sgn * ux
                    na = G.add_node(a, ex, ey)
                    nb = G.add_node(b, -ex, -ey) if inner else G.add_node(b, ex, ey)
                    G.try_segment(na, nb)
    # arcs between nodes consecutive in angle on each circle
    for k in range(m):
        on = sorted((G.nodes[v][3], v) for v in range(2, len(G.nodes)) if G.nodes[v][2] == k)
        if len(on) < 2:
            continue
        for q in range(len(on)):
            u, v = on[q][1], on[(q + 1) % len(on)][1]
            alpha = G.nodes[u][3]
            span = G.nodes[v][3] - alpha
            if q + 1 == len(on):
                span += _TWO_PI
            nseg = int(span / ARC_STEP_RAD) + 1
            chain = [G.nodes[u][:2], *G.arc_points(k, alpha, span, nseg), G.nodes[v][:2]]
            if all(G.seg_clear(*chain[i], *chain[i + 1], False) for i in range(len(chain) - 1)):
                length = G.p[k] * span
                G.edges.append((u, v, length * (1.0 + SIDE_BIAS), length, k, alpha, span, nseg))

    # Dijkstra from the start, heap ordered by (distance, node)
    nv = len(G.nodes)
    adj: list[list[tuple[int, int]]] = [[] for _ in range(nv)]
    for e, (u, v, *_rest) in enumerate(G.edges):
        adj[u].append((e, 0))
        adj[v].append((e, 1))
    dist = [math.inf] * nv
    pred: list[tuple[int, int] | None] = [None] * nv
    settled = [False] * nv
    dist[0] = 0.0
    heap = [(0.0, 0)]
    while heap:
        d, u = heapq.heappop(heap)
        if settled[u]:
            continue
        settled[u] = True
        if u == 1:
            break
        for e, back in adj[u]:
            eu, ev, cf, cb = G.edges[e][:4]
            v = eu if back else ev
            nd = d + (cb if back else cf)
            if nd < dist[v]:
                dist[v] = nd
                pred[v] = (e, back)
                heapq.heappush(heap, (nd, v))

    # the target: the goal, or the reachable node nearest it (ties: lowest index, so the start)
    status, target = PLAN_OK, 1
    if not settled[1]:
        status = PLAN_BLOCKED
        reach = [v for v in range(nv) if v != 1 and dist[v] < math.inf]
        to_goal = {v: math.sqrt((G.nodes[v][0] - gx) * (G.nodes[v][0] - gx)
                                + (G.nodes[v][1] - gy) * (G.nodes[v][1] - gy)) for v in reach}
        best = min(to_goal.values())
        target = next(v for v in reach if to_goal[v] <= best + GOAL_TIE_M)

    # the polyline
    steps = []
    v = target
    while v != 0:
        e, back = pred[v]
        steps.append((e, back))
        v = G.edges[e][1] if back else G.edges[e][0]
    pts = [(sx, sy)]
    for q, (e, back) in enumerate(reversed(steps)):
        u, v, _cf, _cb, k, alpha, span, nseg = G.edges[e]
        if k >= 0:
            inner = G.arc_points(k, alpha, span, nseg)
            for p in (reversed(inner) if back else inner):
                if p != pts[-1]:
                    pts.append(p)
        end = G.nodes[u if back else v][:2]
        if q == len(steps) - 1 or end != pts[-1]:
            pts.append(end)

    # headings: from the start's to the goal's in proportion to path length (OK); held (BLOCKED)
    th0 = wrap_angle(float(s[2]))
    dth = wrap_angle(float(g[2]) - th0)
    seg = [math.sqrt((pts[i][0] - pts[i - 1][0]) * (pts[i][0] - pts[i - 1][0])
                     + (pts[i][1] - pts[i - 1][1]) * (pts[i][1] - pts[i - 1][1])) for i in range(1, len(pts))]
    total = 0.0
    for length in seg:
        total += length
    out = np.empty((len(pts), 3))
    acc = 0.0
    for i, (x, y) in enumerate(pts):
        if i > 0:
            acc += seg[i - 1]
        th = th0
        if status == PLAN_OK:
            if i + 1 == len(pts):
                th = wrap_angle(float(g[2]))
            elif total > 0.0:
                th = wrap_angle(th0 + dth * (acc / total))
        out[i] = (x, y, th)
    return _plan(out, status)
