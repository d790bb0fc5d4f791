"""The structure keeps its bodies' clearance in a room: a barrier on the structure's twist.

The readable reference of ``vs_clearance_barrier`` (vsfleet/_core/vs_clear.{h,c}; the header has the why), in
plain Python floats, operation for operation as the core, so the two agree bit for bit
(tests/test_core_clear.py). The structure step applies it after the advance whenever it follows a room's
field (docs/planning.md, "Keeping the points clear").

For each robot, the obstacle its point (at the fitted pose) is nearest to gives one row,
``n . (v + w x rho) >= -GAMMA_PER_S (c - CLEAR_M)`` (c: the point's clearance [m]), kept where
c < CLEAR_M + BAND_M, the ROWS of least clearance. The twist becomes the nearest twist meeting every row, in the
metric |dv|^2 + (reach dw)^2, by a fixed enumeration of the rows' planes, pairs' lines and triples' points; where
none meets them all (points inside CLEAR_M on opposite sides), the rows only hold (no push-out); and it is never
longer (in that metric) than the twist given or the push-out GAMMA_PER_S CLEAR_M.
"""

from __future__ import annotations

import math

from . import _core
from .coreconst import CLEAR_BAND_M, CLEAR_GAMMA_PER_S, CLEAR_M, CLEAR_ROWS

_TOL = 1e-12


def _dot(a, t) -> float:
    return a[0] * t[0] + a[1] * t[1] + a[2] * t[2]


def _meets(rows, t) -> bool:
    return all(_dot(a, t) >= b - _TOL for a, b, _c in rows)


def clearance_barrier_reference(points_xy, fx: float, fy: float, radius_m, obstacles, reach_m: float,
                                twist) -> tuple[tuple[float, float, float], bool]:
    """points_xy (n, 2) [m; world]: the robots' points at the fitted pose (fx, fy); radius_m (n) [m];
    obstacles (m, 3) (x, y, R) [m; world]; reach_m [m]; twist (vx, vy, w) [m/s, rad/s; world].
    Returns (the barrier's twist, whether it differs from the one given)."""
    vx, vy, w = (float(v) for v in twist)
    if not reach_m > 0.0:
        reach_m = 1.0   # every point at the origin: w moves none of them
    obs = [(float(o[0]), float(o[1]), float(o[2])) for o in obstacles]
    rows: list[tuple[tuple[float, float, float], float, float]] = []   # (a, b, clearance), by clearance
    for i, p in enumerate(points_xy):
        px, py, ri = float(p[0]), float(p[1]), float(radius_m[i])
        found, best, bdx, bdy, bd = False, 0.0, 0.0, 0.0, 0.0
        for ox, oy, orad in obs:
            dx, dy = px - ox, py - oy
            d = math.sqrt(dx * dx + dy * dy)
            clr = d - (ri + orad)
            if not found or clr < best:
                found, best, bdx, bdy, bd = True, clr, dx, dy, d
        if not found or not best < CLEAR_M + CLEAR_BAND_M or not bd > 0.0:
            continue
        nx, ny, rx, ry = bdx / bd, bdy / bd, px - fx, py - fy
        at = len(rows)
        while at > 0 and best < rows[at - 1][2]:
            at -= 1
        if at >= CLEAR_ROWS:
            continue
        rows.insert(at, ((nx, ny, (nx * -ry + ny * rx) / reach_m), -CLEAR_GAMMA_PER_S * (best - CLEAR_M), best))
        del rows[CLEAR_ROWS:]
    td = (vx, vy, w * reach_m)
    if _meets(rows, td):
        return (vx, vy, w), False
    t = _nearest(rows, td)
    if t is None:   # no twist meets every row (points inside CLEAR_M on opposite sides): hold them, do not push out
        rows = [(a, b if not b > 0.0 else 0.0, c) for a, b, c in rows]
        t = _nearest(rows, td)
        if t is None:
            t = (0.0, 0.0, 0.0)
    # never faster than the advance asked, or than the barrier's own push-out (CLEAR_GAMMA_PER_S CLEAR_M)
    n_in = math.sqrt(td[0] * td[0] + td[1] * td[1] + td[2] * td[2])
    n_out = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    cap = CLEAR_GAMMA_PER_S * CLEAR_M
    if n_in > cap:
        cap = n_in
    if n_out > cap:
        f = cap / n_out
        t = (f * t[0], f * t[1], f * t[2])
    return (t[0], t[1], t[2] / reach_m), True


def _nearest(rows, td):
    """The nearest twist to td meeting every row (td itself, else each row's plane, each pair's line, each triple's
    point: the least distance, the first on ties); None if none does."""
    if _meets(rows, td):
        return td
    best_t, best_d = None, None

    def consider(t) -> None:
        nonlocal best_t, best_d
        if not _meets(rows, t):
            return
        e0, e1, e2 = t[0] - td[0], t[1] - td[1], t[2] - td[2]
        d = e0 * e0 + e1 * e1 + e2 * e2
        if best_d is None or d < best_d:
            best_t, best_d = t, d

    k = len(rows)
    for p in range(k):                       # each row's plane
        a, b = rows[p][0], rows[p][1]
        g = _dot(a, a)
        if not g > _TOL:
            continue
        lam = (b - _dot(a, td)) / g
        consider((td[0] + lam * a[0], td[1] + lam * a[1], td[2] + lam * a[2]))
    for p in range(k):                       # each pair's line
        for q in range(p + 1, k):
            ap, aq = rows[p][0], rows[q][0]
            g00, g01, g11 = _dot(ap, ap), _dot(ap, aq), _dot(aq, aq)
            det = g00 * g11 - g01 * g01
            if not det > _TOL:
                continue
            r0, r1 = rows[p][1] - _dot(ap, td), rows[q][1] - _dot(aq, td)
            l0, l1 = (r0 * g11 - r1 * g01) / det, (g00 * r1 - g01 * r0) / det
            consider((td[0] + l0 * ap[0] + l1 * aq[0], td[1] + l0 * ap[1] + l1 * aq[1],
                      td[2] + l0 * ap[2] + l1 * aq[2]))
    for p in range(k):                       # each triple's point (Cramer)
        for q in range(p + 1, k):
            for s in range(q + 1, k):
                u, v, w3 = rows[p][0], rows[q][0], rows[s][0]
                x0, x1, x2 = v[1] * w3[2] - v[2] * w3[1], v[2] * w3[0] - v[0] * w3[2], v[0] * w3[1] - v[1] * w3[0]
                det = u[0] * x0 + u[1] * x1 + u[2] * x2
                if not (det > _TOL or det < -_TOL):
                    continue
                y0, y1, y2 = w3[1] * u[2] - w3[2] * u[1], w3[2] * u[0] - w3[0] * u[2], w3[0] * u[1] - w3[1] * u[0]
                z0, z1, z2 = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
                bp, bq, bs = rows[p][1], rows[q][1], rows[s][1]
                consider(((bp * x0 + bq * y0 + bs * z0) / det, (bp * x1 + bq * y1 + bs * z1) / det,
                          (bp * x2 + bq * y2 + bs * z2) / det))
    return best_t


def clearance_barrier(points_xy, fx: float, fy: float, radius_m, obstacles, reach_m: float,
                      twist) -> tuple[tuple[float, float, float], bool]:
    """The compiled core's vs_clearance_barrier: the same arguments and result as the reference."""
    vx, vy, w, changed = _core.clearance_barrier(points_xy, float(fx), float(fy), radius_m, obstacles,
                                                 float(reach_m), float(twist[0]), float(twist[1]), float(twist[2]))
    return (vx, vy, w), bool(changed)
