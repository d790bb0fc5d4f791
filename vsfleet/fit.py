"""Fitting the virtual structure to the robots (Tan & Lewis 1996, section 3.3.1).

Given template points ``p_i`` (structure frame) and robot positions ``r_i``
(world frame), find the rigid pose ``T = (x, y, th)`` (rotation and
translation; no reflection, no scale) minimising a cost of the distances

    d_i = | r_i - T(p_i) |,     T(p) = R(th) p + (x, y).

With weights ``w_i >= 0`` (default all 1) the costs are

    l1   = sum_i w_i d_i
    l2   = sqrt(sum_i w_i d_i^2)
    linf = max_i w_i d_i

A robot with weight 0 is ignored by the fit (its residual is still reported).
Costs are in (weighted) metres.

Methods
-------
l2
    Closed form: weighted 2-D Procrustes / Umeyama without reflection.  With
    weighted centroids ``pc``, ``rc`` and ``P_i = p_i - pc``, ``Q_i = r_i - rc``,
    ``th = atan2(sum w P x Q, sum w P . Q)`` and ``t = rc - R(th) pc``.

linf and l1: a certified global search over the rotation
    For a fixed rotation ``th`` let ``q_i(th) = r_i - R(th) p_i``.  The best
    translation is the weighted minimax centre (linf: weighted minimum
    enclosing circle) or the weighted geometric median (l1) of the ``q_i``, and
    ``f(th)`` is the resulting cost; the fit is ``min_th f(th)``.  Both inner
    problems are convex and solved exactly for each angle:

    * linf: the weighted minimax centre is an LP-type problem of combinatorial
      dimension 3, so its value is the largest, over subsets ``S`` of at most 3
      robots, of the subset's optimum.  A pair's optimum is closed form; a
      triple contributes only when the point with equal weighted distances to
      its three robots (circumcentre; with weights, the intersection of
      Apollonius circles, a quadratic) lies in the triangle, which is exactly
      its KKT condition.  Up to 10 robots every pair and triple is enumerated
      (vectorised over angles); beyond, an active-set loop (basis + worst
      violators: the radius strictly increases, so it ends) works on a small
      working set and checks every robot.
    * l1: Newton steps, proximal-Newton steps that keep the nearest robot's
      cone ``w_k |t - q_k|`` exact (which also lands exactly on ``q_k`` when
      the median sits there, the Vardi-Zhang case), and a Weiszfeld /
      Vardi-Zhang safeguard, in coordinates relative to one robot's point.

    Certification (weak duality).  For any vectors ``k_i`` with ``|k_i| <= w_i``
    (l1) or ``k_i = lam_i w_i u_i`` with ``lam`` in the simplex and
    ``|u_i| <= 1`` (linf), and ``sum_i k_i = 0``::

        cost(t, th) >= sum_i k_i . (q_i(th) - t) = sum_i k_i . q_i(th)
                     = K - A cos(th) - B sin(th)         for EVERY th and t.

    The inner solver's dual multipliers at an evaluated angle ``a`` (linf: the
    basis duals; l1: unit vectors balanced through the nearest robot) give
    such a sinusoidal global minorant ``m_a``; at the exact inner optimum it
    touches ``f`` at ``a`` with the right slope, a second-order-accurate model.
    A residual imbalance ``F = sum k_i`` is paid for as ``|F| * Bnd``, where
    ``Bnd`` bounds ``|t|`` on the convex hull of the ``q_i`` (which holds the
    optimal translation), plus a rounding allowance ``64 eps Bnd sum |k_i|``;
    so a bound is valid whatever the accuracy of the inner solve.  The circle
    of rotations is cut into cells between evaluated angles; on a cell
    ``[a, b]`` the exact minimum of ``max(m_a, m_b)`` is computed in closed form
    (endpoints, each minorant's own minimum, their crossings on the unit
    circle; only sqrt is needed): a rigorous lower bound of ``f`` on the cell
    (and never below 0, the zero minorant).
    The search stops when EVERY cell's bound is within ``CERT_TOL = 1e-10``
    (weighted m) of the best cost found, so the returned cost is within
    ``CERT_TOL`` of the global optimum over all rotations and translations;
    ``FitResult.cost_lower_bound`` is the certified lower bound.  No Lipschitz
    constant is needed: every bound is a global minorant.  (If the rounding
    allowance at the optimum exceeds ``CERT_TOL / 4`` -- only for huge costs,
    e.g. weights ~1e6 or coordinates ~1e8 m -- the tolerance is that
    allowance times 4; ``cost - cost_lower_bound`` always states the gap.)

    Search order (speed only; the certificate above does not depend on it):
    a local descent from the l2 rotation (plain Python up to 400 robots for
    linf and 120 for l1, else one vectorised angle at a time; secant steps on
    the minorant slope, tangent crossings at kinks, a closed-form jump when a
    pair of robots is the basis) finds a local minimum ``th_loc``; one
    vectorised batch then evaluates a 16-point grid, a geometric stencil
    around ``th_loc`` (offsets ``(2 pi / 16) / 4^k``, k = 1..9) and the
    descent's four angles nearest ``th_loc``.  (linf with at most 10 robots
    instead runs the whole search in plain Python, one exact angle at a time:
    the descent's angles, three angles a quarter turn away -- bounded by the
    template's widest pair, re-solved exactly only if a cell next to them stays
    uncertified -- then the cutting-plane point, the middle of wide cells and
    a small geometric stencil next to the best angle for each uncertified cell,
    until all are certified; the batch search takes over if that does not end
    within 400 angles.)  That usually certifies at once;
    otherwise uncertified cells are refined (cutting-plane point, secant
    point, stencils) until all are.  In
    that first batch l1 runs only a few inner iterations and linf with more
    than 10 robots uses pair duals on the grid and the local bases' robots
    near ``th_loc`` (valid but looser bounds); refinements use exact solves,
    and first-pass points next to a cell that cannot be split further are
    re-solved exactly.

Degenerate inputs
-----------------
* n = 0 raises ShapeError.  Zero-weight robots are dropped before fitting.
* One robot (or one robot with positive weight): the rotation is
  unobservable; ``th = 0`` and the translation puts that template point exactly
  on the robot (cost 0).
* All (weighted) template points coincide, or all (weighted) robots coincide:
  the cost does not depend on the rotation, so ``th = 0``; the translation is
  the metric's optimum (weighted mean, weighted minimax centre, weighted
  geometric median).
* Two robots (for every metric): ``th`` aligns ``p_1 - p_2`` with
  ``r_1 - r_2``; the translation is the weighted mean (l2), the weighted
  minimax point ``(w_1 q_1 + w_2 q_2)/(w_1 + w_2)`` (linf), or for l1 the
  heavier robot sits exactly on its point (equal weights: the midpoint, which
  is one of a segment of optima).
* l2 when ``|(sum w P x Q, sum w P . Q)| <= 1e-13 sum w |P||Q|`` (rotation
  unobservable to rounding): ``th = 0``.
* linf / l1 with several optimal rotations: the evaluated angle with the
  smallest computed cost is returned; exact ties go to the smallest ``|th|``,
  then the smaller ``th``.  l1 with a non-unique median (collinear ``q_i``,
  balanced weights) returns the median the deterministic solver converges to.
* Robots exactly on the structure: cost 0 and the exact transform (to
  rounding); zero distances are masked, so no NaN or inf reaches a result.

Determinism
-----------
No randomness, no threads, no BLAS (no matmul): only elementwise IEEE
arithmetic, ``sqrt``, numpy reductions along a fixed axis, ``math.fsum`` for the
reported sums, and transcendental functions only from Python's ``math`` module
on scalars (numpy's vectorised sin/cos/atan2 may differ between CPUs).  The
same inputs give bit-identical outputs on every run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .errors import NonFiniteError, ShapeError, UnknownMetricError, WeightError
from .geometry import Pose2, wrap_angle

__all__ = ["METRICS", "FitResult", "fit_structure", "structure_cost"]

METRICS = ("l1", "l2", "linf")

#: Certification tolerance of the linf and l1 searches [weighted m].
CERT_TOL = 1e-10
_EPS = np.finfo(float).eps
_ENUM_MAX_N = 10  # enumerate all pairs/triples (linf) up to this many robots
_SCALAR_MAX_N = {"linf": 400, "l1": 120}  # local search in plain Python up to this many robots
_SPLIT_MIN_N = 10  # in (_SPLIT_MIN_N, _SPLIT_MAX_N] the first linf batch uses pair / basis-subset duals
_SPLIT_MAX_N = 60
_WS_EXTRA = 4  # working-set violators added per active-set step (linf, large n)
_N_GRID = 16  # initial uniform grid of rotations
_STENCIL_RATIO = 4.0
_STENCIL_LEVELS = 9
_MAX_ROUNDS = 200
_GRID = tuple(-math.pi + 2.0 * math.pi * k / _N_GRID for k in range(_N_GRID))
_LOCAL_KEEP = 4  # local-search angles nearest the optimum re-evaluated in the batch
_LS_JUMP = 0.5  # largest closed-form jump to a pair's alignment in the local search [rad]
_LS_GAIN = 1e-13  # local search stops when the predicted gain is below this [weighted m]
_FIRST_PASS_ITERS = 4  # inner l1 iterations in the first certification pass


@dataclass(frozen=True, eq=False)
class FitResult:
    """Result of :func:`fit_structure`.

    pose: the fitted structure pose (world <- structure).
    cost: the metric's cost at ``pose`` [weighted m].
    residuals_m: (n,) unweighted distances d_i = |r_i - pose(p_i)| [m], all robots.
    metric: 'l1', 'l2' or 'linf'.
    cost_lower_bound: certified lower bound of the optimal cost [weighted m]
        (equal to ``cost`` for l2 and closed-form cases).
    """

    pose: Pose2
    cost: float
    residuals_m: np.ndarray
    metric: str
    cost_lower_bound: float


# --------------------------------------------------------------------------
# validation


def _as_points(name: str, a) -> np.ndarray:
    try:
        arr = np.asarray(a)
    except Exception as exc:  # pragma: no cover - exotic array-likes
        raise ShapeError(f"{name} must be a numeric (n, 2) array: {exc}") from None
    if arr.dtype.kind == "O":
        try:
            arr = arr.astype(float)
        except (TypeError, ValueError):
            raise ShapeError(f"{name} must be a numeric (n, 2) array, got non-numeric entries") from None
    if arr.dtype.kind not in "iuf":
        raise ShapeError(f"{name} must be a real numeric (n, 2) array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ShapeError(f"{name} must have shape (n, 2), got {arr.shape}")
    arr = np.array(arr, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} holds NaN or infinity")
    return arr


def _check_metric(metric) -> str:
    if not isinstance(metric, str) or metric not in METRICS:
        raise UnknownMetricError(f"metric must be one of {METRICS}, got {metric!r}")
    return metric


def _as_weights(weights, n: int) -> np.ndarray:
    if weights is None:
        return np.ones(n)
    try:
        w = np.asarray(weights)
    except Exception as exc:  # pragma: no cover
        raise WeightError(f"weights must be a numeric (n,) array: {exc}") from None
    if w.dtype.kind == "O":
        try:
            w = w.astype(float)
        except (TypeError, ValueError):
            raise WeightError("weights must be numeric") from None
    if w.dtype.kind not in "iuf":
        raise WeightError(f"weights must be real numbers, got dtype {w.dtype}")
    if w.shape != (n,):
        raise WeightError(f"weights must have shape ({n},), got {w.shape}")
    w = np.array(w, dtype=float)
    if not np.all(np.isfinite(w)):
        raise NonFiniteError("weights hold NaN or infinity")
    if np.any(w < 0.0):
        raise WeightError("weights must be >= 0")
    if not np.any(w > 0.0):
        raise WeightError("weights are all zero")
    return w


def _validate(template_xy, positions_xy, metric, weights):
    p = _as_points("template_xy", template_xy)
    r = _as_points("positions_xy", positions_xy)
    if p.shape[0] != r.shape[0]:
        raise ShapeError(f"template_xy has {p.shape[0]} points but positions_xy has {r.shape[0]}")
    if p.shape[0] == 0:
        raise ShapeError("need at least one robot (n = 0)")
    metric = _check_metric(metric)
    w = _as_weights(weights, p.shape[0])
    return p, r, metric, w


# --------------------------------------------------------------------------
# costs


def _residuals(p: np.ndarray, r: np.ndarray, pose: Pose2) -> np.ndarray:
    if len(p) <= 32:
        # plain Python, the same operations in the same order as Pose2.apply
        c, s = math.cos(pose.th), math.sin(pose.th)
        x, y = pose.x, pose.y
        sqrt = math.sqrt
        out = []
        for (px, py), (rx, ry) in zip(p.tolist(), r.tolist()):
            dx = rx - (c * px - s * py + x)
            dy = ry - (s * px + c * py + y)
            out.append(sqrt(dx * dx + dy * dy))
        return np.array(out)
    world = pose.apply(p)
    dx = r[:, 0] - world[:, 0]
    dy = r[:, 1] - world[:, 1]
    return np.sqrt(dx * dx + dy * dy)


def _cost_of(d: np.ndarray, w: np.ndarray, metric: str) -> float:
    if metric == "l1":
        return math.fsum((w * d).tolist())
    if metric == "l2":
        return math.sqrt(math.fsum((w * (d * d)).tolist()))
    return float(np.max(w * d))


def structure_cost(template_xy, positions_xy, pose, metric: str, weights=None) -> float:
    """The fit objective at ``pose`` [weighted m].

    ``pose`` is a :class:`Pose2` or an ``(x, y, th)`` triple.  Costs:
    l1 = sum w_i d_i, l2 = sqrt(sum w_i d_i^2), linf = max w_i d_i with
    d_i = |r_i - R(th) p_i - (x, y)|.  Raises the same typed errors as
    :func:`fit_structure`.
    """
    p, r, metric, w = _validate(template_xy, positions_xy, metric, weights)
    if not isinstance(pose, Pose2):
        try:
            x, y, th = (float(v) for v in pose)
        except (TypeError, ValueError):
            raise ShapeError("pose must be a Pose2 or an (x, y, th) triple") from None
        if not all(math.isfinite(v) for v in (x, y, th)):
            raise NonFiniteError("pose holds NaN or infinity")
        pose = Pose2(x, y, th)
    return _cost_of(_residuals(p, r, pose), w, metric)


# --------------------------------------------------------------------------
# combinatorics (cached index arrays)


@lru_cache(maxsize=64)
def _combos(k: int):
    """Pairs and triples of range(k) and a members table (S, 3); a pair (i, j) is (i, j, j)."""
    i2, j2, i3, j3, k3 = [], [], [], [], []
    for a in range(k):
        for b in range(a + 1, k):
            i2.append(a)
            j2.append(b)
    for a in range(k):
        for b in range(a + 1, k):
            for c in range(b + 1, k):
                i3.append(a)
                j3.append(b)
                k3.append(c)
    mem = [(a, b, b) for a, b in zip(i2, j2)] + list(zip(i3, j3, k3))
    out = tuple(np.array(v, dtype=np.intp) for v in (i2, j2, i3, j3, k3))
    out = out + (np.array(mem, dtype=np.intp).reshape(-1, 3),)
    for v in out:
        v.flags.writeable = False
    return out


# --------------------------------------------------------------------------
# linf inner problem: weighted minimax centre (vectorised; errors silenced by caller)


def _tri_solve(v2x, v2y, v3x, v3y, w1, w2, w3, equal_w: bool):
    """Three-active weighted minimax centre of triangles (elementwise).

    The triangle is (0, v2, v3) (relative to its first point).  Returns
    (ox, oy, valid): the offset of the point with equal weighted distances to
    the three points; ``valid`` means it exists and lies in the closed
    triangle, which is exactly the KKT condition of the 3-point problem.
    Equal weights: the circumcentre, inside iff the triangle is acute.
    Weighted: the point solves a_m |x - v_m|^2 = s (a = w^2), i.e.
    x = x0 + z xd on a line with |x|^2 = z, a quadratic in z.
    """
    cr = v2x * v3y - v2y * v3x
    n2 = v2x * v2x + v2y * v2y
    n3 = v3x * v3x + v3y * v3y
    inv = 0.5 / cr
    x0x = (v3y * n2 - v2y * n3) * inv
    x0y = (v2x * n3 - v3x * n2) * inv
    if equal_w:
        dd = v2x * v3x + v2y * v3y
        return x0x, x0y, (dd > 0.0) & (dd < n2) & (dd < n3)
    a1 = w1 * w1
    a2 = w2 * w2
    a3 = w3 * w3
    b2 = a2 - a1
    b3 = a3 - a1
    den = inv / (a2 * a3)
    xdx = (a3 * b2 * v3y - a2 * b3 * v2y) * den
    xdy = (a2 * b3 * v2x - a3 * b2 * v3x) * den
    qa = xdx * xdx + xdy * xdy
    qb = 2.0 * (x0x * xdx + x0y * xdy) - 1.0
    qc = x0x * x0x + x0y * x0y
    disc = qb * qb - 4.0 * qa * qc
    sq = np.sqrt(np.maximum(disc, 0.0))
    qq = -0.5 * (qb + np.copysign(sq, qb))
    z1 = qc / qq
    z2 = qq / qa
    o1x = x0x + z1 * xdx
    o1y = x0y + z1 * xdy
    ok1 = _bary_ok(o1x, o1y, v2x, v2y, v3x, v3y, cr) & (z1 >= 0.0)
    o2x = x0x + z2 * xdx
    o2y = x0y + z2 * xdy
    ok2 = _bary_ok(o2x, o2y, v2x, v2y, v3x, v3y, cr) & (z2 >= 0.0)
    ox = np.where(ok1, o1x, o2x)
    oy = np.where(ok1, o1y, o2y)
    return ox, oy, (ok1 | ok2) & (disc >= 0.0)


def _bary(ox, oy, v2x, v2y, v3x, v3y):
    """Barycentric coordinates of o in the triangle (0, v2, v3)."""
    cr = v2x * v3y - v2y * v3x
    c2 = (ox * v3y - oy * v3x) / cr
    c3 = (v2x * oy - v2y * ox) / cr
    return 1.0 - c2 - c3, c2, c3


def _bary_ok(ox, oy, v2x, v2y, v3x, v3y, cr):
    c2 = (ox * v3y - oy * v3x) / cr
    c3 = (v2x * oy - v2y * ox) / cr
    return (c2 >= 0.0) & (c3 >= 0.0) & (1.0 - c2 - c3 >= 0.0)


def _mec_enum(X, Y, W, equal_w: bool, pairs_only: bool = False):
    """Exact weighted minimax centre of each column's points by enumeration.

    X, Y: (k, N) coordinates (robots x angles); W: (k, 1) or (k, N) weights.
    The optimum of an LP-type problem of combinatorial dimension 3 is the
    largest optimum over subsets of at most 3 points.  Returns
    ``(g, mem)``: g (9, N) rows tx, ty, rho, k1x, k2x, k3x, k1y, k2y, k3y
    (dual vectors of the basis members, which sum to zero) and mem (3, N) the
    members' local indices.
    """
    k, N = X.shape
    I2, J2, I3, J3, K3, MEM = _combos(k)
    if pairs_only:
        I3 = I3[:0]
    P = len(I2)
    dx = X[I2] - X[J2]
    dy = Y[I2] - Y[J2]
    w1, w2 = W[I2], W[J2]
    rho = (w1 * w2 / (w1 + w2)) * np.sqrt(dx * dx + dy * dy)
    ar = np.arange(N)
    if len(I3):
        Xa, Ya = X[I3], Y[I3]
        v2x = X[J3] - Xa
        v2y = Y[J3] - Ya
        v3x = X[K3] - Xa
        v3y = Y[K3] - Ya
        W1 = W[I3]
        ox, oy, ok = _tri_solve(v2x, v2y, v3x, v3y, W1, W[J3], W[K3], equal_w)
        rho3 = W1 * np.sqrt(ox * ox + oy * oy)
        rho3[~ok] = -np.inf
        best = np.argmax(np.concatenate([rho, rho3]), axis=0)
    else:
        best = np.argmax(rho, axis=0)
    mem = MEM[best].T
    i, j, l = mem
    XY = np.stack([X, Y])
    xy1 = XY[:, i, ar]
    xy2 = XY[:, j, ar]
    if equal_w and W.shape[1] == 1:
        w1 = w2 = W[0, 0]
        cw = 0.5 * w1
        txy = 0.5 * (xy1 + xy2)
    else:
        Wb = W if W.shape[1] == N else np.broadcast_to(W, (k, N))
        w1, w2 = Wb[i, ar], Wb[j, ar]
        ws = w1 + w2
        cw = w1 * w2 / ws
        txy = (w1 * xy1 + w2 * xy2) / ws
    e = xy1 - xy2
    d = np.sqrt(e[0] * e[0] + e[1] * e[1])
    kd = cw / d
    kd[d == 0.0] = 0.0
    kxy = e * kd
    g = np.empty((9, N))
    g[0:2] = txy
    g[2] = cw * d
    g[3] = kxy[0]
    g[4] = -kxy[0]
    g[5] = 0.0
    g[6] = kxy[1]
    g[7] = -kxy[1]
    g[8] = 0.0
    if len(I3):
        is_tri = best >= P
        if np.any(is_tri):
            if len(I3) == 1:
                sx, sy, ax, ay, bx, by, cx, cy, trho = (
                    v[0] for v in (ox, oy, Xa, Ya, v2x, v2y, v3x, v3y, rho3)
                )
            else:
                ts = best - P
                ts[~is_tri] = 0
                sx, sy, ax, ay, bx, by, cx, cy, trho = (
                    v[ts, ar] for v in (ox, oy, Xa, Ya, v2x, v2y, v3x, v3y, rho3)
                )
            c1, c2, c3 = _bary(sx, sy, bx, by, cx, cy)
            if equal_w and W.shape[1] == 1:
                sc = W[0, 0] * W[0, 0] / trho
            else:
                wa, wb, wc = Wb[i, ar], Wb[j, ar], Wb[l, ar]
                sc = 1.0 / (trho * (c1 / (wa * wa) + c2 / (wb * wb) + c3 / (wc * wc)))
            sc[~(np.abs(sc) < np.inf)] = 0.0
            g = np.where(is_tri, _triple_rows(ax, ay, trho, sx, sy, bx, by, cx, cy, c1, c2, c3, sc), g)
    return g, mem


def _triple_rows(x0, y0, rho, ox, oy, v2x, v2y, v3x, v3y, c1, c2, c3, sc):
    """Result rows of a triple basis: centre t = q_1 + o, radius rho, and the duals
    c_k * sc times q_k - t (that is -o, v2 - o, v3 - o for q_1, q_2, q_3)."""
    c1 = c1 * sc
    c2 = c2 * sc
    c3 = c3 * sc
    return np.stack([
        x0 + ox, y0 + oy, rho,
        -c1 * ox, c2 * (v2x - ox), c3 * (v3x - ox),
        -c1 * oy, c2 * (v2y - oy), c3 * (v3y - oy),
    ])


def _mec3(X, Y, w, equal_w: bool):
    """:func:`_mec_enum` for exactly three points per column (w: three floats)."""
    x0, x1, x2 = X
    y0, y1, y2 = Y
    w0, w1, w2 = w
    # the triangle relative to point 0; pair (1, 2) is v3 - v2
    v2x = x1 - x0
    v2y = y1 - y0
    v3x = x2 - x0
    v3y = y2 - y0
    ex = v3x - v2x
    ey = v3y - v2y
    n2 = v2x * v2x + v2y * v2y
    n3 = v3x * v3x + v3y * v3y
    n1 = ex * ex + ey * ey
    c01 = w0 * w1 / (w0 + w1)
    c02 = w0 * w2 / (w0 + w2)
    c12 = w1 * w2 / (w1 + w2)
    r01 = c01 * np.sqrt(n2)
    r02 = c02 * np.sqrt(n3)
    r12 = c12 * np.sqrt(n1)
    ox, oy, ok = _tri_solve(v2x, v2y, v3x, v3y, w0, w1, w2, equal_w)
    rt = w0 * np.sqrt(ox * ox + oy * oy)
    # best pair; the triple wins where it is valid (its value is then the optimum)
    b02 = r02 > r01
    rp = np.where(b02, r02, r01)
    b12 = r12 > rp
    rp = np.where(b12, r12, rp)
    tri = ok & (rt > rp)
    # pair basis (i, j) as offsets from point 0: i in {0, 0, 1}, j in {1, 2, 2}
    ix = np.where(b12, v2x, 0.0)
    iy = np.where(b12, v2y, 0.0)
    jx = np.where(b12 | b02, v3x, v2x)
    jy = np.where(b12 | b02, v3y, v2y)
    wi = np.where(b12, w1, w0)
    wj = np.where(b12 | b02, w2, w1)
    cw = wi * wj / (wi + wj)
    dx = ix - jx
    dy = iy - jy
    d = np.sqrt(dx * dx + dy * dy)
    kd = cw / d
    kd[d == 0.0] = 0.0
    kx = dx * kd
    ky = dy * kd
    mem = np.empty((3, len(x0)), dtype=np.intp)
    mem[0] = b12
    mem[1] = np.where(b12 | b02, 2, 1)
    mem[2] = mem[1]
    g = np.empty((9, len(x0)))
    if equal_w:
        g[0] = x0 + 0.5 * (ix + jx)
        g[1] = y0 + 0.5 * (iy + jy)
    else:
        g[0] = x0 + (wi * ix + wj * jx) / (wi + wj)
        g[1] = y0 + (wi * iy + wj * jy) / (wi + wj)
    g[2] = cw * d
    g[3] = kx
    g[4] = -kx
    g[5] = 0.0
    g[6] = ky
    g[7] = -ky
    g[8] = 0.0
    if np.any(tri):
        c1, c2, c3 = _bary(ox, oy, v2x, v2y, v3x, v3y)
        if equal_w:
            sc = w0 * w0 / rt
        else:
            sc = 1.0 / (rt * (c1 / (w0 * w0) + c2 / (w1 * w1) + c3 / (w2 * w2)))
        g = np.where(tri, _triple_rows(x0, y0, rt, ox, oy, v2x, v2y, v3x, v3y, c1, c2, c3, sc), g)
        mem[0][tri] = 0
        mem[1][tri] = 1
        mem[2][tri] = 2
    return g, mem


def _top_indices(v: np.ndarray, m: int) -> np.ndarray:
    """Row indices of the m largest entries per column (first occurrence on ties), (m, N)."""
    v = v.copy()
    cols = np.arange(v.shape[1])
    out = []
    for _ in range(m):
        j = np.argmax(v, axis=0)
        out.append(j)
        v[j, cols] = -np.inf
    return np.stack(out)


class _Problem:
    """Centred data for the rotation search: q_i(th) = Q0_i - R(th) P_i."""

    def __init__(self, p: np.ndarray, r: np.ndarray, w: np.ndarray):
        self.w = w
        self.n = n = len(w)
        fsum, sqrt = math.fsum, math.sqrt
        lw = w.tolist()
        lpx, lpy = p[:, 0].tolist(), p[:, 1].tolist()
        lrx, lry = r[:, 0].tolist(), r[:, 1].tolist()
        W = fsum(lw)
        self.wsum = W
        rng = range(n)
        self.cp = (fsum([lw[i] * lpx[i] for i in rng]) / W, fsum([lw[i] * lpy[i] for i in rng]) / W)
        self.cr = (fsum([lw[i] * lrx[i] for i in rng]) / W, fsum([lw[i] * lry[i] for i in rng]) / W)
        cpx, cpy = self.cp
        crx, cry = self.cr
        # plain Python copies for the scalar path (same IEEE arithmetic as numpy)
        self.lPx = [v - cpx for v in lpx]
        self.lPy = [v - cpy for v in lpy]
        self.lQx = [v - crx for v in lrx]
        self.lQy = [v - cry for v in lry]
        self.lw = lw
        self.lw2 = [v * v for v in lw]
        self.equal_w = all(v == lw[0] for v in lw)
        self.bound = max(sqrt(x * x + y * y) for x, y in zip(self.lQx, self.lQy)) + max(
            sqrt(x * x + y * y) for x, y in zip(self.lPx, self.lPy)
        )
        self.wmax = max(lw)

    _NP = ("Px", "Py", "Qx", "Qy", "cPx", "cPy", "cQx", "cQy", "cw", "tab")

    def __getattr__(self, name):
        # the numpy copies, built on first use (the plain-Python search needs none)
        if name not in _Problem._NP:
            raise AttributeError(name)
        self.Px = np.array(self.lPx)
        self.Py = np.array(self.lPy)
        self.Qx = np.array(self.lQx)
        self.Qy = np.array(self.lQy)
        # column views for the (robots, angles) layout
        self.cPx = self.Px[:, None]
        self.cPy = self.Py[:, None]
        self.cQx = self.Qx[:, None]
        self.cQy = self.Qy[:, None]
        self.cw = self.w[:, None]
        self.tab = np.stack([self.Qx, self.Qy, self.Px, self.Py, np.ones(self.n)])
        return getattr(self, name)

    def qT(self, c: np.ndarray, s: np.ndarray):
        """q_i(th) in the (robots, angles) layout."""
        qx = self.cQx - (self.cPx * c - self.cPy * s)
        qy = self.cQy - (self.cPx * s + self.cPy * c)
        return qx, qy

    def q(self, c: np.ndarray, s: np.ndarray):
        """q_i(th) in the (angles, robots) layout."""
        c = c[:, None]
        s = s[:, None]
        qx = self.Qx - (c * self.Px - s * self.Py)
        qy = self.Qy - (s * self.Px + c * self.Py)
        return qx, qy

    def minorant(self, members, kx, ky):
        """(K, A, B, slack, rounding part of slack) of dual vectors kx, ky on members, (N, m)."""
        Qx, Qy, Px, Py = self.Qx[members], self.Qy[members], self.Px[members], self.Py[members]
        K = np.sum(kx * Qx + ky * Qy, axis=1)
        A = np.sum(kx * Px + ky * Py, axis=1)
        B = np.sum(ky * Px - kx * Py, axis=1)
        fx = np.sum(kx, axis=1)
        fy = np.sum(ky, axis=1)
        kabs = np.sum(np.sqrt(kx * kx + ky * ky), axis=1)
        rslack = 64.0 * _EPS * kabs * self.bound
        slack = np.sqrt(fx * fx + fy * fy) * self.bound + rslack
        return K, A, B, slack, rslack


def _linf_oracle(prob: _Problem, c: np.ndarray, s: np.ndarray, warm, max_iter: int = 0,
                 subset=None, pairs_only: bool = False):
    """f, centre, minorant (K, A, B, slack) and basis at each angle (batch).

    ``subset`` / ``pairs_only`` restrict the dual to some robots or to pairs:
    the minorant stays valid (dual feasible) and ``f`` is still the true cost
    at the returned centre (an upper bound), only less tight.
    """
    qx, qy = prob.qT(c, s)
    n, N = qx.shape
    cw = prob.cw
    if subset is not None:
        sub = np.asarray(subset, dtype=np.intp)
        if len(sub) == 3:
            g, mem = _mec3(qx[sub], qy[sub], [prob.lw[i] for i in subset], prob.equal_w)
        else:
            g, mem = _mec_enum(qx[sub], qy[sub], cw[sub], prob.equal_w)
        mem = sub[mem]
    elif pairs_only:
        g, mem = _mec_enum(qx, qy, cw, prob.equal_w, pairs_only=True)
    elif n == 3:
        g, mem = _mec3(qx, qy, prob.lw, prob.equal_w)
    elif n <= _ENUM_MAX_N:
        g, mem = _mec_enum(qx, qy, cw, prob.equal_w)
    else:
        ar = np.arange(N)
        W = prob.wsum
        mx = np.sum(cw * qx, axis=0) / W
        my = np.sum(cw * qy, axis=0) / W
        dx = qx - mx
        dy = qy - my
        ws = _top_indices(cw * np.sqrt(dx * dx + dy * dy), 3 + _WS_EXTRA)
        if warm is not None:
            hot = ~np.isnan(warm[:, 0])
            ws[:3, hot] = warm[hot].T.astype(np.intp)
        g = np.empty((9, N))
        mem = np.empty((3, N), dtype=np.intp)
        act = ar
        for _ in range(10 * n + 10):
            sub_x = np.take_along_axis(qx[:, act], ws, axis=0)
            sub_y = np.take_along_axis(qy[:, act], ws, axis=0)
            g_, m_ = _mec_enum(sub_x, sub_y, prob.w[ws], prob.equal_w)
            m_ = np.take_along_axis(ws, m_, axis=0)
            dx = qx[:, act] - g_[0]
            dy = qy[:, act] - g_[1]
            wd = cw * np.sqrt(dx * dx + dy * dy)
            done = np.max(wd, axis=0) <= g_[2] * (1.0 + 8.0 * _EPS)
            g[:, act] = g_
            mem[:, act] = m_
            if np.all(done):
                break
            keep = ~done
            act = act[keep]
            ws = np.concatenate([m_[:, keep], _top_indices(wd[:, keep], _WS_EXTRA)])
    tx, ty = g[0], g[1]
    dx = qx - tx
    dy = qy - ty
    if prob.equal_w:
        f = np.sqrt(np.max(dx * dx + dy * dy, axis=0)) * prob.w[0]
    else:
        f = np.max(cw * np.sqrt(dx * dx + dy * dy), axis=0)
    kx = g[3:6]
    ky = g[6:9]
    # rows of tab: Qx, Qy, Px, Py, 1 (the last gives the imbalance sum k)
    tab = prob.tab[:, mem]
    sx = np.sum(kx * tab, axis=1)
    sy = np.sum(ky * tab, axis=1)
    K = sx[0] + sy[1]
    A = sx[2] + sy[3]
    B = sy[2] - sx[3]
    # pair duals cancel exactly; triples leave a rounding-size imbalance
    rslack = (64.0 * _EPS * prob.bound) * np.sum(np.abs(kx) + np.abs(ky), axis=0)
    slack = (np.abs(sx[4]) + np.abs(sy[4])) * prob.bound + rslack
    return f, tx, ty, K, A, B, slack, mem.T, rslack


# --------------------------------------------------------------------------
# linf, one angle at a time in plain Python (local search for small n)


def _pair_s(x1, y1, x2, y2, w1, w2):
    dx = x1 - x2
    dy = y1 - y2
    d = math.sqrt(dx * dx + dy * dy)
    ws = w1 + w2
    cw = w1 * w2 / ws
    if d > 0.0:
        kd = cw / d
        kx, ky = dx * kd, dy * kd
    else:
        kx = ky = 0.0
    return cw * d, (w1 * x1 + w2 * x2) / ws, (w1 * y1 + w2 * y2) / ws, kx, ky


def _tri_s(x1, y1, x2, y2, x3, y3, w1, w2, w3):
    """Scalar :func:`_tri_solve`; returns (rho, tx, ty, c1, c2, c3) or None."""
    v2x = x2 - x1
    v2y = y2 - y1
    v3x = x3 - x1
    v3y = y3 - y1
    cr = v2x * v3y - v2y * v3x
    if cr == 0.0:
        return None
    n2 = v2x * v2x + v2y * v2y
    n3 = v3x * v3x + v3y * v3y
    inv = 0.5 / cr
    x0x = (v3y * n2 - v2y * n3) * inv
    x0y = (v2x * n3 - v3x * n2) * inv
    if w1 == w2 == w3:
        cands = ((x0x, x0y),)
    else:
        a1, a2, a3 = w1 * w1, w2 * w2, w3 * w3
        b2 = a2 - a1
        b3 = a3 - a1
        den = inv / (a2 * a3)
        xdx = (a3 * b2 * v3y - a2 * b3 * v2y) * den
        xdy = (a2 * b3 * v2x - a3 * b2 * v3x) * den
        qa = xdx * xdx + xdy * xdy
        qb = 2.0 * (x0x * xdx + x0y * xdy) - 1.0
        qc = x0x * x0x + x0y * x0y
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:
            return None
        qq = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))
        cands = []
        for num, dnm in ((qc, qq), (qq, qa)):
            if dnm != 0.0:
                z = num / dnm
                if z >= 0.0:
                    cands.append((x0x + z * xdx, x0y + z * xdy))
    for ox, oy in cands:
        c2 = (ox * v3y - oy * v3x) / cr
        c3 = (v2x * oy - v2y * ox) / cr
        c1 = 1.0 - c2 - c3
        if c1 >= 0.0 and c2 >= 0.0 and c3 >= 0.0:
            return w1 * math.sqrt(ox * ox + oy * oy), x1 + ox, y1 + oy, c1, c2, c3
    return None


def _tri_duals_s(qx, qy, w, i, j, k, sol):
    rho, tx, ty, c1, c2, c3 = sol
    wi, wj, wk = w[i], w[j], w[k]
    den = rho * (c1 / (wi * wi) + c2 / (wj * wj) + c3 / (wk * wk))
    sc = 1.0 / den if den > 0.0 else 0.0
    c1 *= sc
    c2 *= sc
    c3 *= sc
    duals = (
        (i, c1 * (qx[i] - tx), c1 * (qy[i] - ty)),
        (j, c2 * (qx[j] - tx), c2 * (qy[j] - ty)),
        (k, c3 * (qx[k] - tx), c3 * (qy[k] - ty)),
    )
    return rho, tx, ty, (i, j, k), duals


def _mec_small_s(qx, qy, w, pts, violator: bool = False):
    """Exact weighted minimax centre of the points ``pts`` (2 to 4 indices) by enumeration.

    Returns (rho, tx, ty, basis, duals) with duals [(i, kx, ky), ...].  A
    valid three-active triple is the optimum of its three points.
    """
    m = len(pts)
    if m == 3:
        i, j, k = pts
        sol = _tri_s(qx[i], qy[i], qx[j], qy[j], qx[k], qy[k], w[i], w[j], w[k])
        if sol is not None:
            return _tri_duals_s(qx, qy, w, i, j, k, sol)
    if violator:
        # pts = an optimal basis + a point outside its circle: every basis of
        # the union holds that point (LP-type), so only subsets with it count
        h = pts[-1]
        pairs = [(i, h) if i < h else (h, i) for i in pts[:-1]]
        triples = [tuple(sorted(pts[:-1][:a] + pts[:-1][a + 1:] + (h,))) for a in range(3)] if m == 4 else ()
    else:
        pairs = [(pts[a], pts[b]) for a in range(m) for b in range(a + 1, m)]
        triples = [(pts[a], pts[b], pts[c]) for a in range(m) for b in range(a + 1, m) for c in range(b + 1, m)] if m == 4 else ()
    best = None
    for i, j in pairs:
        rho, tx, ty, kx, ky = _pair_s(qx[i], qy[i], qx[j], qy[j], w[i], w[j])
        if best is None or rho > best[0]:
            best = (rho, tx, ty, (i, j), ((i, kx, ky), (j, -kx, -ky)))
    for i, j, k in triples:
        sol = _tri_s(qx[i], qy[i], qx[j], qy[j], qx[k], qy[k], w[i], w[j], w[k])
        if sol is not None and sol[0] > best[0]:
            best = _tri_duals_s(qx, qy, w, i, j, k, sol)
    return best


def _linf_eval3(prob: _Problem, th: float, hint):
    """:func:`_linf_eval_s` for exactly three robots, inlined (the same arithmetic)."""
    c, s = math.cos(th), math.sin(th)
    sqrt = math.sqrt
    Px, Py, Qx, Qy, w = prob.lPx, prob.lPy, prob.lQx, prob.lQy, prob.lw
    p0x, p1x, p2x = Px
    p0y, p1y, p2y = Py
    x0 = Qx[0] - (p0x * c - p0y * s)
    x1 = Qx[1] - (p1x * c - p1y * s)
    x2 = Qx[2] - (p2x * c - p2y * s)
    y0 = Qy[0] - (p0x * s + p0y * c)
    y1 = Qy[1] - (p1x * s + p1y * c)
    y2 = Qy[2] - (p2x * s + p2y * c)
    w0, w1, w2 = w
    sol = _tri_s(x0, y0, x1, y1, x2, y2, w0, w1, w2)
    if sol is not None:
        rho, tx, ty, c1, c2, c3 = sol
        den = rho * (c1 / (w0 * w0) + c2 / (w1 * w1) + c3 / (w2 * w2))
        sc = 1.0 / den if den > 0.0 else 0.0
        c1 *= sc
        c2 *= sc
        c3 *= sc
        k0x, k0y = c1 * (x0 - tx), c1 * (y0 - ty)
        k1x, k1y = c2 * (x1 - tx), c2 * (y1 - ty)
        k2x, k2y = c3 * (x2 - tx), c3 * (y2 - ty)
        K = A = B = 0.0
        K += k0x * Qx[0] + k0y * Qy[0]
        A += k0x * p0x + k0y * p0y
        B += k0y * p0x - k0x * p0y
        K += k1x * Qx[1] + k1y * Qy[1]
        A += k1x * p1x + k1y * p1y
        B += k1y * p1x - k1x * p1y
        K += k2x * Qx[2] + k2y * Qy[2]
        A += k2x * p2x + k2y * p2y
        B += k2y * p2x - k2x * p2y
        fx = 0.0 + k0x + k1x + k2x
        fy = 0.0 + k0y + k1y + k2y
        kabs = 0.0 + sqrt(k0x * k0x + k0y * k0y) + sqrt(k1x * k1x + k1y * k1y) + sqrt(k2x * k2x + k2y * k2y)
        basis = (0, 1, 2)
    else:
        r01, t01x, t01y, k01x, k01y = _pair_s(x0, y0, x1, y1, w0, w1)
        r02, t02x, t02y, k02x, k02y = _pair_s(x0, y0, x2, y2, w0, w2)
        r12, t12x, t12y, k12x, k12y = _pair_s(x1, y1, x2, y2, w1, w2)
        if r02 > r01:
            if r12 > r02:
                i, j, rho, tx, ty, kx, ky = 1, 2, r12, t12x, t12y, k12x, k12y
            else:
                i, j, rho, tx, ty, kx, ky = 0, 2, r02, t02x, t02y, k02x, k02y
        elif r12 > r01:
            i, j, rho, tx, ty, kx, ky = 1, 2, r12, t12x, t12y, k12x, k12y
        else:
            i, j, rho, tx, ty, kx, ky = 0, 1, r01, t01x, t01y, k01x, k01y
        K = A = B = 0.0
        K += kx * Qx[i] + ky * Qy[i]
        A += kx * Px[i] + ky * Py[i]
        B += ky * Px[i] - kx * Py[i]
        K += -kx * Qx[j] + -ky * Qy[j]
        A += -kx * Px[j] + -ky * Py[j]
        B += -ky * Px[j] - -kx * Py[j]
        fx = fy = 0.0
        kabs = 2.0 * sqrt(kx * kx + ky * ky)
        basis = (i, j)
    a0, b0 = x0 - tx, y0 - ty
    a1, b1 = x1 - tx, y1 - ty
    a2, b2 = x2 - tx, y2 - ty
    if prob.equal_w:
        v = w0 * w0
        worst = sqrt(max(v * (a0 * a0 + b0 * b0), v * (a1 * a1 + b1 * b1), v * (a2 * a2 + b2 * b2)))
    else:
        worst = sqrt(max(w0 * w0 * (a0 * a0 + b0 * b0), w1 * w1 * (a1 * a1 + b1 * b1), w2 * w2 * (a2 * a2 + b2 * b2)))
    rslack = 64.0 * _EPS * kabs * prob.bound
    slack = (abs(fx) + abs(fy)) * prob.bound + rslack
    return worst, tx, ty, K, A, B, slack, basis, basis, A * s - B * c, rslack


def _linf_eval_s(prob: _Problem, th: float, hint):
    """One angle, plain Python: (f, tx, ty, K, A, B, slack, basis, key, slope, rounding slack)."""
    if prob.n == 3:
        return _linf_eval3(prob, th, hint)
    c, s = math.cos(th), math.sin(th)
    Px, Py, Qx, Qy, w = prob.lPx, prob.lPy, prob.lQx, prob.lQy, prob.lw
    qx = [a - (px * c - py * s) for a, px, py in zip(Qx, Px, Py)]
    qy = [a - (px * s + py * c) for a, px, py in zip(Qy, Px, Py)]
    n = prob.n
    pts = (0, 1, 2) if n == 3 else hint if hint is not None else (0, 1)
    w2 = prob.lw2
    viol = False
    for _ in range(100):
        rho, tx, ty, basis, duals = _mec_small_s(qx, qy, w, pts, viol)
        wd = [v * ((x - tx) * (x - tx) + (y - ty) * (y - ty)) for v, x, y in zip(w2, qx, qy)]
        worst = max(wd)
        jw = wd.index(worst)
        worst = math.sqrt(worst)
        if worst <= rho * (1.0 + 8.0 * _EPS) or jw in basis or len(pts) == n:
            break
        pts = basis + (jw,)
        viol = True
    K = A = B = fx = fy = 0.0
    for i, kx, ky in duals:
        K += kx * Qx[i] + ky * Qy[i]
        A += kx * Px[i] + ky * Py[i]
        B += ky * Px[i] - kx * Py[i]
        fx += kx
        fy += ky
    kabs = sum(math.sqrt(kx * kx + ky * ky) for _, kx, ky in duals)
    rslack = 64.0 * _EPS * kabs * prob.bound
    slack = (abs(fx) + abs(fy)) * prob.bound + rslack
    return worst, tx, ty, K, A, B, slack, basis, tuple(sorted(basis)), A * s - B * c, rslack


# --------------------------------------------------------------------------
# l1 inner problem: weighted geometric median


def _median_model(qx, qy, w, tx, ty, rows):
    """Quadratic model of the weighted geometric-median cost at t, split at the nearest point.

    The nearest robot point q_k (with every robot exactly on it, total weight
    eta) is kept apart; the others give gradient g and Hessian (a, b; b, c).
    Returns (kx, ky, eta, dk, gx, gy, a, b, c).
    """
    dx = qx - tx[:, None]
    dy = qy - ty[:, None]
    d = np.sqrt(dx * dx + dy * dy)
    k = np.argmin(d, axis=1)
    kx, ky = qx[rows, k], qy[rows, k]
    same = (qx == kx[:, None]) & (qy == ky[:, None])
    eta = np.sum(w * same, axis=1)
    use = ~same & (d > 0.0)
    inv = w / d
    inv[~use] = 0.0
    inv3 = inv / (d * d)
    inv3[~use] = 0.0
    gx = -np.sum(inv * dx, axis=1)
    gy = -np.sum(inv * dy, axis=1)
    a = np.sum(inv3 * dy * dy, axis=1)
    c = np.sum(inv3 * dx * dx, axis=1)
    b = -np.sum(inv3 * dx * dy, axis=1)
    return kx, ky, eta, d[rows, k], gx, gy, a, b, c


def _newton_step(tx, ty, kx, ky, eta, dk, gx, gy, a, b, c):
    """Plain Newton on every robot's quadratic model (inf when t is on q_k)."""
    ekx = (tx - kx) / dk
    eky = (ty - ky) / dk
    ik = eta / dk
    fa = a + ik * eky * eky
    fc = c + ik * ekx * ekx
    fb = b - ik * ekx * eky
    fgx = gx + eta * ekx
    fgy = gy + eta * eky
    fdet = fa * fc - fb * fb
    nx = tx - (fc * fgx - fb * fgy) / fdet
    ny = ty - (fa * fgy - fb * fgx) / fdet
    bad = ~(dk > 0.0) | ~np.isfinite(nx) | ~np.isfinite(ny)
    nx[bad] = np.inf
    ny[bad] = np.inf
    return nx, ny


def _prox_step(tx, ty, kx, ky, eta, gx, gy, a, b, c):
    """Proximal Newton about q_k: exact cone eta |t - q_k| + quadratic model of the rest.

    The model's minimiser is q_k itself when the model pull |b| <= eta, else
    q_k + y with y = (H + mu I)^-1 b and mu |y| = eta.  h(mu) = 1/|y(mu)| - mu/eta
    is concave (trust-region secular function), so Newton from a point right
    of the root (mu0 = 2 tr(H) eta / (|b| - eta)) converges monotonically.
    """
    y0x = tx - kx
    y0y = ty - ky
    bx = a * y0x + b * y0y - gx
    by = b * y0x + c * y0y - gy
    bn = np.sqrt(bx * bx + by * by)
    at_k = bn <= eta
    mu = 2.0 * (a + c) * eta / (bn - eta) + 1e-300
    mu[at_k] = 1.0
    yx = yy = mu
    for _ in range(30):
        ma = a + mu
        mc = c + mu
        det = ma * mc - b * b
        yx = (mc * bx - b * by) / det
        yy = (ma * by - b * bx) / det
        yn = np.sqrt(yx * yx + yy * yy)
        zx = (mc * yx - b * yy) / det
        zy = (ma * yy - b * yx) / det
        h = 1.0 / yn - mu / eta
        dh = (yx * zx + yy * zy) / (yn * yn * yn) - 1.0 / eta
        step = h / dh
        step[at_k] = 0.0
        mu = mu - step
        if not np.any(np.abs(step) > 1e-12 * np.abs(mu)):
            break
    px = kx + yx
    py = ky + yy
    px[at_k] = kx[at_k]
    py[at_k] = ky[at_k]
    return px, py


def _l1_duals(qx, qy, w, tx, ty, rows):
    """Dual vectors k_i (|k_i| <= w_i) at t, balanced through the nearest point.

    k_i = w_i (q_i - t)/|q_i - t| for robots not on the nearest point q_k; the
    robots on q_k share -sum(others), clipped to their total weight.  At the
    optimum this balances exactly (also when the median sits on q_k), and near
    it the imbalance is first order in |t - t*| without the 1/|t - q_k| blow-up.
    """
    dx = qx - tx[:, None]
    dy = qy - ty[:, None]
    d = np.sqrt(dx * dx + dy * dy)
    k = np.argmin(d, axis=1)
    kx, ky = qx[rows, k], qy[rows, k]
    same = (qx == kx[:, None]) & (qy == ky[:, None])
    use = ~same & (d > 0.0)
    dsafe = np.where(use, d, 1.0)
    kapx = np.where(use, w * dx / dsafe, 0.0)
    kapy = np.where(use, w * dy / dsafe, 0.0)
    sx = np.sum(kapx, axis=1)
    sy = np.sum(kapy, axis=1)
    sn = np.sqrt(sx * sx + sy * sy)
    eta = np.sum(np.where(same, w, 0.0), axis=1)
    clip = np.where(sn > eta, eta / np.where(sn > 0.0, sn, 1.0), 1.0)
    share = np.where(same, w / eta[:, None], 0.0) * clip[:, None]
    kapx = kapx - share * sx[:, None]
    kapy = kapy - share * sy[:, None]
    return kapx, kapy


def _l1_oracle(prob: _Problem, c: np.ndarray, s: np.ndarray, warm, max_iter: int = 60):
    qx, qy = prob.q(c, s)
    N, n = qx.shape
    w = prob.w
    rows_all = np.arange(N)
    # work relative to robot 0's point (exact differences for tight clusters)
    ox = qx[:, 0].copy()
    oy = qy[:, 0].copy()
    qx = qx - ox[:, None]
    qy = qy - oy[:, None]
    tx = np.sum(w * qx, axis=1) / prob.wsum
    ty = np.sum(w * qy, axis=1) / prob.wsum
    if warm is not None:
        hot = ~np.isnan(warm[:, 0])
        tx[hot] = warm[hot, 0] - ox[hot]
        ty[hot] = warm[hot, 1] - oy[hot]
    # convergence is judged against the size of each angle's point cloud
    scale = np.sqrt(np.max(qx * qx + qy * qy, axis=1)) + 1e-300

    def cost(rx, ry, ax, ay):
        dx = rx - ax[:, None]
        dy = ry - ay[:, None]
        return np.sum(w * np.sqrt(dx * dx + dy * dy), axis=1)

    f = cost(qx, qy, tx, ty)
    act = rows_all
    ties = np.zeros(N, dtype=np.intp)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(max_iter):
            ax, ay = qx[act], qy[act]
            rows = np.arange(len(act))
            t0x, t0y, f0 = tx[act], ty[act], f[act]
            model = _median_model(ax, ay, w, t0x, t0y, rows)
            nx, ny = _newton_step(t0x, t0y, *model)
            fn = cost(ax, ay, nx, ny)
            # a tiny Newton step that does not raise the cost: in the quadratic
            # regime, so this step finishes the row (no fallbacks needed)
            kx_, ky_, eta_, dk_, gx_, gy_, a_, b_, c_ = model
            cone = eta_ >= 10.0 * dk_ * (a_ + c_)  # the nearest point's cone dominates
            conv = (
                (np.abs(nx - t0x) + np.abs(ny - t0y) <= 1e-9 * scale[act])
                & (fn <= f0 + 4.0 * _EPS * f0)
                & ~cone
            )
            # proximal Newton where Newton fails or the nearest point dominates
            pidx = np.nonzero(~conv & (~(fn < f0) | cone))[0]
            if len(pidx):
                sub = tuple(v[pidx] for v in (t0x, t0y, kx_, ky_, eta_, gx_, gy_, a_, b_, c_))
                px, py = _prox_step(*sub)
                fp = cost(ax[pidx], ay[pidx], px, py)
                fp[~(np.isfinite(px) & np.isfinite(py))] = np.inf
                usep = fp < fn[pidx]
                pi = pidx[usep]
                nx[pi] = px[usep]
                ny[pi] = py[usep]
                fn[pi] = fp[usep]
            # safeguard: Weiszfeld (Vardi-Zhang) step where the model steps fail
            bidx = np.nonzero(~conv & ~(fn < f0))[0]
            if len(bidx):
                bx_, by_ = ax[bidx], ay[bidx]
                sx, sy = t0x[bidx], t0y[bidx]
                dx = bx_ - sx[:, None]
                dy = by_ - sy[:, None]
                d = np.sqrt(dx * dx + dy * dy)
                pos = d > 0.0
                inv = w / d
                inv[~pos] = 0.0
                sinv = np.sum(inv, axis=1)
                wx = np.sum(inv * bx_, axis=1) / sinv
                wy = np.sum(inv * by_, axis=1) / sinv
                gx = np.sum(inv * dx, axis=1)
                gy = np.sum(inv * dy, axis=1)
                gn = np.sqrt(gx * gx + gy * gy)
                eta0 = np.sum(w * ~pos, axis=1)
                lam = np.minimum(1.0, eta0 / gn)
                lam[~(eta0 > 0.0)] = 0.0
                lam[(eta0 > 0.0) & ~(gn > 0.0)] = 1.0
                wx = (1.0 - lam) * wx + lam * sx
                wy = (1.0 - lam) * wy + lam * sy
                fw = cost(bx_, by_, wx, wy)
                # a real decrease by Weiszfeld beats a model step that only ties
                usew = (fw < f0[bidx]) & np.isfinite(wx) & np.isfinite(wy)
                wi = bidx[usew]
                nx[wi] = wx[usew]
                ny[wi] = wy[usew]
                fn[wi] = fw[usew]
            # accept descent; also accept a (proximal) Newton step that ties
            # within rounding, a few times: f cannot see the last digits of t
            better = fn < f0
            tie = ~better & (fn <= f0 + 4.0 * _EPS * f0) & (ties[act] < 3)
            acc = better | tie | conv
            ties[act] = np.where(better, 0, ties[act] + tie)
            step = np.sqrt((nx - t0x) ** 2 + (ny - t0y) ** 2)
            tx[act] = np.where(acc, nx, t0x)
            ty[act] = np.where(acc, ny, t0y)
            f[act] = np.where(acc, fn, f0)
            cont = acc & ~conv & (step > 2.0 * _EPS * scale[act])
            act = act[cont]
            if len(act) == 0:
                break
    kx, ky = _l1_duals(qx, qy, w, tx, ty, rows_all)
    mem = np.broadcast_to(np.arange(n), (N, n))
    K, A, B, slack, rslack = prob.minorant(mem, kx, ky)
    tx = tx + ox
    ty = ty + oy
    return f, tx, ty, K, A, B, slack, np.stack([tx, ty], axis=1), rslack


def _l1_eval_s(prob: _Problem, th: float, hint):
    """One angle, plain Python: weighted geometric median and its duals.

    Same method as :func:`_l1_oracle`: Newton and proximal-Newton candidates
    with a Weiszfeld (Vardi-Zhang) safeguard, then duals balanced through the
    nearest robot point.  Returns (f, tx, ty, K, A, B, slack, (tx, ty)).
    """
    c, s = math.cos(th), math.sin(th)
    Px, Py, Qx, Qy, w = prob.lPx, prob.lPy, prob.lQx, prob.lQy, prob.lw
    n = prob.n
    rng = range(n)
    qx = [Qx[i] - (Px[i] * c - Py[i] * s) for i in rng]
    qy = [Qy[i] - (Px[i] * s + Py[i] * c) for i in rng]
    # work relative to robot 0's point (exact differences for tight clusters)
    ox, oy = qx[0], qy[0]
    qx = [v - ox for v in qx]
    qy = [v - oy for v in qy]
    sqrt = math.sqrt

    def cost(ax, ay):
        return math.fsum([w[i] * sqrt((qx[i] - ax) * (qx[i] - ax) + (qy[i] - ay) * (qy[i] - ay)) for i in rng])

    if hint is None:
        tx = math.fsum([w[i] * qx[i] for i in rng]) / prob.wsum
        ty = math.fsum([w[i] * qy[i] for i in rng]) / prob.wsum
    else:
        tx, ty = hint[0] - ox, hint[1] - oy
    f = cost(tx, ty)
    scale = max(sqrt(qx[i] * qx[i] + qy[i] * qy[i]) for i in rng)
    ties = 0
    for _ in range(60):
        d = [sqrt((qx[i] - tx) * (qx[i] - tx) + (qy[i] - ty) * (qy[i] - ty)) for i in rng]
        k = min(rng, key=d.__getitem__)
        kx, ky = qx[k], qy[k]
        eta = 0.0
        gx = gy = ha = hb = hc = 0.0
        for i in rng:
            if qx[i] == kx and qy[i] == ky:
                eta += w[i]
            elif d[i] > 0.0:
                dx = qx[i] - tx
                dy = qy[i] - ty
                iv = w[i] / d[i]
                i3 = iv / (d[i] * d[i])
                gx -= iv * dx
                gy -= iv * dy
                ha += i3 * dy * dy
                hc += i3 * dx * dx
                hb -= i3 * dx * dy
        best = None
        dk = d[k]
        if dk > 0.0:
            # plain Newton on every robot's quadratic model
            ex = (tx - kx) / dk
            ey = (ty - ky) / dk
            ik = eta / dk
            fa = ha + ik * ey * ey
            fc = hc + ik * ex * ex
            fb = hb - ik * ex * ey
            fgx = gx + eta * ex
            fgy = gy + eta * ey
            det = fa * fc - fb * fb
            if det > 0.0:
                nx = tx - (fc * fgx - fb * fgy) / det
                ny = ty - (fa * fgy - fb * fgx) / det
                if math.isfinite(nx) and math.isfinite(ny):
                    best = (cost(nx, ny), nx, ny)
                    if (
                        best[0] <= f + 4.0 * _EPS * f
                        and abs(nx - tx) + abs(ny - ty) <= 1e-9 * scale
                        and eta < 10.0 * dk * (ha + hc)
                    ):
                        tx, ty, f = nx, ny, best[0]
                        break
        if best is None or not best[0] < f or eta >= 10.0 * dk * (ha + hc):
            # proximal Newton about q_k (see _prox_step)
            y0x = tx - kx
            y0y = ty - ky
            bx = ha * y0x + hb * y0y - gx
            by = hb * y0x + hc * y0y - gy
            bn = sqrt(bx * bx + by * by)
            px = py = math.inf
            if bn <= eta:
                px, py = kx, ky
            else:
                mu = 2.0 * (ha + hc) * eta / (bn - eta) + 1e-300
                try:
                    for _ in range(30):
                        ma = ha + mu
                        mc = hc + mu
                        det = ma * mc - hb * hb
                        yx = (mc * bx - hb * by) / det
                        yy = (ma * by - hb * bx) / det
                        yn = sqrt(yx * yx + yy * yy)
                        zx = (mc * yx - hb * yy) / det
                        zy = (ma * yy - hb * yx) / det
                        dh = (yx * zx + yy * zy) / (yn * yn * yn) - 1.0 / eta
                        if not dh < 0.0:
                            break
                        step = (1.0 / yn - mu / eta) / dh
                        mu -= step
                        if abs(step) <= 1e-12 * abs(mu):
                            break
                    px, py = kx + yx, ky + yy
                except (ZeroDivisionError, OverflowError):
                    pass  # degenerate model: no proximal candidate this step
            if math.isfinite(px) and math.isfinite(py):
                fp = cost(px, py)
                if best is None or fp < best[0]:
                    best = (fp, px, py)
        if best is None or not best[0] < f:
            # Weiszfeld with the Vardi-Zhang step
            sw = sx = sy = 0.0
            e0 = 0.0
            for i in rng:
                if d[i] > 0.0:
                    iv = w[i] / d[i]
                    sw += iv
                    sx += iv * qx[i]
                    sy += iv * qy[i]
                else:
                    e0 += w[i]
            if sw > 0.0:
                wx, wy = sx / sw, sy / sw
                if e0 > 0.0:
                    rx = sum(w[i] * (qx[i] - tx) / d[i] for i in rng if d[i] > 0.0)
                    ry = sum(w[i] * (qy[i] - ty) / d[i] for i in rng if d[i] > 0.0)
                    rr = sqrt(rx * rx + ry * ry)
                    lam = min(1.0, e0 / rr) if rr > 0.0 else 1.0
                    wx = (1.0 - lam) * wx + lam * tx
                    wy = (1.0 - lam) * wy + lam * ty
                fw = cost(wx, wy)
                if fw < f:
                    best = (fw, wx, wy)
                    ties = -1
        if best is None:
            break
        fn, nx, ny = best
        if fn < f:
            ties = 0
        elif fn <= f + 4.0 * _EPS * f and ties < 3:
            ties += 1
        else:
            break
        step = sqrt((nx - tx) * (nx - tx) + (ny - ty) * (ny - ty))
        tx, ty, f = nx, ny, fn
        if step <= 2.0 * _EPS * scale:
            break
    # duals balanced through the nearest point
    d = [sqrt((qx[i] - tx) * (qx[i] - tx) + (qy[i] - ty) * (qy[i] - ty)) for i in rng]
    k = min(rng, key=d.__getitem__)
    kx, ky = qx[k], qy[k]
    kap = []
    same = []
    sx = sy = eta = 0.0
    for i in rng:
        if qx[i] == kx and qy[i] == ky:
            same.append(i)
            eta += w[i]
        elif d[i] > 0.0:
            ax = w[i] * (qx[i] - tx) / d[i]
            ay = w[i] * (qy[i] - ty) / d[i]
            kap.append((i, ax, ay))
            sx += ax
            sy += ay
    sn = sqrt(sx * sx + sy * sy)
    clip = eta / sn if sn > eta else 1.0
    for i in same:
        sh = w[i] / eta * clip
        kap.append((i, -sh * sx, -sh * sy))
    K = A = B = fx = fy = kabs = 0.0
    for i, ax, ay in kap:
        K += ax * Qx[i] + ay * Qy[i]
        A += ax * Px[i] + ay * Py[i]
        B += ay * Px[i] - ax * Py[i]
        fx += ax
        fy += ay
        kabs += sqrt(ax * ax + ay * ay)
    slack = sqrt(fx * fx + fy * fy) * prob.bound + 64.0 * _EPS * kabs * prob.bound
    tx += ox
    ty += oy
    return f, tx, ty, K, A, B, slack, (tx, ty), 0, A * s - B * c


# --------------------------------------------------------------------------
# certified search over the rotation


def _cell_bounds(ca, sa, cb, sb, K1, A1, B1, K2, A2, B2):
    """min over the arc [a, b] (< pi) of max(m1, m2), m = K - A c - B s.

    The minimum is at an endpoint, at a minorant's own minimum ((c, s) along
    (A, B)) or where the two cross on the unit circle; only sqrt is needed.
    Returns (lb, argmin_c, argmin_s).
    """
    cx = np.empty((6, len(ca)))
    cy = np.empty((6, len(ca)))
    cx[0] = ca
    cy[0] = sa
    cx[1] = cb
    cy[1] = sb
    r1 = np.sqrt(A1 * A1 + B1 * B1)
    r2 = np.sqrt(A2 * A2 + B2 * B2)
    cx[2] = A1 / r1
    cy[2] = B1 / r1
    cx[3] = A2 / r2
    cy[3] = B2 / r2
    dA = A1 - A2
    dB = B1 - B2
    R = np.sqrt(dA * dA + dB * dB)
    u = (K1 - K2) / R
    h = np.sqrt(1.0 - u * u) / R
    u = u / R
    bx = u * dA
    by = u * dB
    px = h * dB
    py = h * dA
    cx[4] = bx - px
    cy[4] = by + py
    cx[5] = bx + px
    cy[5] = by - py
    # inside the arc (NaN candidates fail the test); endpoints always count
    ok = ((ca * cy - sa * cx) >= -1e-15) & ((cx * sb - cy * cb) >= -1e-15)
    ok[:2] = True
    v = np.maximum(K1 - A1 * cx - B1 * cy, K2 - A2 * cx - B2 * cy)
    v[~ok] = np.inf
    j = np.argmin(v, axis=0)
    cols = np.arange(len(ca))
    return v[j, cols], cx[j, cols], cy[j, cols]


def _stencil(x: float, h: float, levels: int, out: list) -> None:
    out.append(x)
    step = h
    for _ in range(levels):
        step /= _STENCIL_RATIO
        out.append(x - step)
        out.append(x + step)


def _slope(th: float, A: float, B: float) -> float:
    """d/dth of the minorant K - A cos th - B sin th (= f'(th) where f is smooth)."""
    return A * math.sin(th) - B * math.cos(th)


def _local_search(prob: _Problem, evalf, th0: float, max_evals: int = 30) -> list:
    """Plain descent to a local minimum of f near th0 (proposes angles only).

    Every evaluation is exact and the certified search re-checks the result,
    so this needs no guarantee.  A tiny probe gives a curvature estimate, then
    Newton/secant steps on the minorant slope until the minimum is bracketed;
    inside the bracket: secant on the slope when both ends share a basis
    (smooth piece), else the crossing of the two tangents (a kink), else
    bisection.
    """
    recs: list = []
    try:
        _descend(prob, evalf, th0, max_evals, recs)
    except (ArithmeticError, ValueError):
        pass  # plain-float trouble in a degenerate model: keep what was found
    return recs


def _descend(prob: _Problem, evalf, th0: float, max_evals: int, recs: list) -> None:
    two_pi = 2.0 * math.pi

    def ev(th, hint):
        r = evalf(prob, wrap_angle(th), hint)
        rec = (th, r, r[9])
        recs.append(rec)
        return rec

    prev = ev(th0, None)
    if prev[2] == 0.0:
        return
    d = -1.0 if prev[2] > 0.0 else 1.0
    x = th0 + d * 1e-4
    lo = hi = None
    last = None
    widths: list[float] = []
    fbest = prev[1][0]
    while len(recs) < max_evals:
        r = ev(x, prev[1][7] if lo is None else (lo if abs(x - lo[0]) < abs(x - hi[0]) else hi)[1][7])
        if lo is None:
            if r[2] * d >= 0.0 or r[1][0] > prev[1][0]:
                lo, hi = (prev, r) if prev[0] < r[0] else (r, prev)
                last = (prev, r)
            else:
                dth = r[0] - prev[0]
                curv = (r[2] - prev[2]) / dth
                step = -1.2 * r[2] / curv if curv > 0.0 else d * max(2.0 * abs(dth), 0.02)
                if step * d <= 0.0 or abs(step) > 4.0 * abs(dth) + 0.05:
                    step = d * max(2.0 * abs(dth), 0.02)
                key = r[1][8]
                if isinstance(key, tuple) and len(key) == 2:
                    # a two-robot basis: its optimum aligns the pair, in closed form
                    i, j = key
                    px, py = prob.lPx[i] - prob.lPx[j], prob.lPy[i] - prob.lPy[j]
                    qx, qy = prob.lQx[i] - prob.lQx[j], prob.lQy[i] - prob.lQy[j]
                    ta = math.atan2(px * qy - py * qx, px * qx + py * qy)
                    ta += two_pi * round((r[0] - ta) / two_pi)
                    if 0.0 < (ta - r[0]) * d <= _LS_JUMP:
                        step = 1.000001 * (ta - r[0])
                if abs(r[0] + step - th0) > math.pi:
                    return
                prev = r
                x = r[0] + step
                continue
        else:
            last = (last[1], r)
            if r[2] == 0.0:
                break
            if r[2] < 0.0 and r[1][0] <= lo[1][0]:
                lo = r
            else:
                hi = r
        # propose inside the bracket
        x = None
        p0, p1 = last
        if p0[1][8] == p1[1][8] and p1[2] != p0[2]:
            # secant on the slope through the two latest points (one smooth piece)
            x = p1[0] - p1[2] * (p1[0] - p0[0]) / (p1[2] - p0[2])
        if not (x is not None and lo[0] < x < hi[0]) and lo[2] < 0.0 < hi[2]:
            # crossing of the tangents at the bracket ends (a kink)
            x = (hi[1][0] - lo[1][0] + lo[2] * lo[0] - hi[2] * hi[0]) / (lo[2] - hi[2])
        widths.append(hi[0] - lo[0])
        if x is None or not (lo[0] < x < hi[0]) or (len(widths) > 2 and widths[-1] > 0.5 * widths[-3]):
            x = lo[0] + 0.5 * (hi[0] - lo[0])
            widths.clear()
        # stop when the step or its predicted gain is negligible
        if abs(x - p1[0]) <= 1e-13 * max(1.0, abs(x)) or hi[0] - lo[0] <= 1e-13:
            break
        if abs(p1[2] * (x - p1[0])) <= _LS_GAIN * max(1.0, fbest):
            break
        fbest = min(fbest, r[1][0])


def _search(prob: _Problem, oracle, evalf, seed: float, tol: float):
    """Certified global minimisation of f(th) over the circle.

    Returns (th, tx, ty, best cost, certified lower bound).
    """
    two_pi = 2.0 * math.pi
    recs = _local_search(prob, evalf, seed)
    if recs:
        best = min(recs, key=lambda r: r[1][0])
        th_loc = wrap_angle(best[0])
    else:
        best = None
        th_loc = wrap_angle(seed)
    h0 = two_pi / _N_GRID
    new = list(_GRID)
    cand: list[float] = []
    _stencil(th_loc, h0, _STENCIL_LEVELS, cand)
    # re-evaluate the local search's angles in the batch (finely spaced near the optimum)
    near = sorted(recs, key=lambda r: abs(math.remainder(r[0] - th_loc, 2.0 * math.pi)))
    cand.extend(r[0] for r in near[:_LOCAL_KEEP])
    pi = math.pi
    new.extend(x if -pi <= x < pi else wrap_angle(x) for x in cand)
    st_loc = _state_vec(best[1][7]) if best is not None else None
    uses_warm = oracle is _l1_oracle or prob.n > _ENUM_MAX_N
    TH = None
    lb_all = -np.inf
    exact_first = oracle is _linf_oracle and not (_SPLIT_MIN_N < prob.n <= _SPLIT_MAX_N)
    for _ in range(_MAX_ROUNDS):
        if TH is None:
            uniq = sorted(set(new))
        else:
            have = set(TH.tolist())
            uniq = sorted(set(x for x in new if x not in have))
        if not uniq and TH is not None:
            # nothing left to split: re-solve the inexact first-pass points that
            # bound uncertified cells (exactly), else stop
            redo = sorted(set(j for i in unc.tolist() for j in (i, int(nxt[i])) if not EX[j]))
            if not redo:
                break
            ridx = np.array(redo, dtype=np.intp)
            f, tx, ty, K, A, B, slack, state, rslack = oracle(prob, C[ridx], S[ridx], STATE[ridx])
            F[ridx], TX[ridx], TY[ridx], KK[ridx], AA[ridx], BB[ridx] = f, tx, ty, K - slack, A, B
            STATE[ridx], SL[ridx], EX[ridx] = state, rslack, True
            uniq = []
        if not uniq and TH is None:
            break
        th_new = np.array(uniq)
        c_new = np.array([math.cos(x) for x in uniq])
        s_new = np.array([math.sin(x) for x in uniq])
        if not uniq:
            pass
        elif not uses_warm or (TH is None and st_loc is None):
            warm = None
        elif TH is None:
            # warm start near the local optimum, cold (NaN) elsewhere
            warm = np.full((len(uniq), len(st_loc)), np.nan)
            dd = np.abs(th_new - th_loc)
            warm[np.minimum(dd, two_pi - dd) < h0] = st_loc
        else:
            dd = np.abs(th_new[:, None] - TH[None, :])
            dd = np.minimum(dd, two_pi - dd)
            warm = STATE[np.argmin(dd, axis=1)]
        if TH is None:
            f, tx, ty, K, A, B, slack, state, rslack = _first_pass(
                prob, oracle, uniq, c_new, s_new, warm, recs, th_loc, h0
            )
            TH, C, S, F, KK, AA, BB, TX, TY, STATE, SL = (
                th_new, c_new, s_new, f, K - slack, A, B, tx, ty, state, rslack
            )
            EX = np.full(len(uniq), exact_first)
        elif uniq:
            f, tx, ty, K, A, B, slack, state, rslack = oracle(prob, c_new, s_new, warm)
            TH, C, S, F, KK, AA, BB, TX, TY, STATE, SL, EX = (
                np.concatenate([u, v]) for u, v in (
                    (TH, th_new), (C, c_new), (S, s_new), (F, f), (KK, K - slack), (AA, A), (BB, B),
                    (TX, tx), (TY, ty), (STATE, state), (SL, rslack), (EX, np.ones(len(uniq), dtype=bool)),
                )
            )
            order = np.argsort(TH, kind="stable")
            TH, C, S, F, KK, AA, BB, TX, TY, STATE, SL, EX = (
                v[order] for v in (TH, C, S, F, KK, AA, BB, TX, TY, STATE, SL, EX)
            )
        U = float(np.min(F))
        m = len(TH)
        nxt = np.arange(1, m + 1)
        nxt[-1] = 0
        M = np.stack([C, S, KK, AA, BB])
        Mn = M[:, nxt]
        lb, lc, ls = _cell_bounds(M[0], M[1], Mn[0], Mn[1], M[2], M[3], M[4], Mn[2], Mn[3], Mn[4])
        lb = np.maximum(lb, 0.0)  # every cost is >= 0 (the zero minorant)
        lb_all = float(np.min(lb))
        # the tolerance cannot be finer than the rounding of the bounds at the optimum
        tol_eff = max(tol, 4.0 * float(SL[int(np.argmin(F))]))
        if lb_all >= U - tol_eff:
            break
        unc = np.nonzero(lb < U - tol_eff)[0]
        new = []
        for i in unc.tolist():
            a = float(TH[i])
            b = float(TH[nxt[i]])
            if b <= a:
                b += two_pi
            h = b - a
            cand = []
            xk = math.atan2(float(ls[i]), float(lc[i]))
            while xk < a:
                xk += two_pi
            while xk > b:
                xk -= two_pi
            if a < xk < b:
                _stencil(xk, h, _STENCIL_LEVELS, cand)
            # secant on the minorant slopes (derivatives of f where smooth)
            da = _slope(a, float(AA[i]), float(BB[i]))
            db = _slope(b, float(AA[nxt[i]]), float(BB[nxt[i]]))
            if da < 0.0 < db:
                xs = a + h * (-da / (db - da))
                if a < xs < b:
                    _stencil(xs, h, _STENCIL_LEVELS, cand)
            cand.append(a + 0.5 * h)
            for x in cand:
                if a < x < b:
                    new.append(x - two_pi if x >= math.pi else x)
    best_f = float(np.min(F))
    ties = np.nonzero(F == best_f)[0]
    j = min(ties.tolist(), key=lambda i: (abs(float(TH[i])), float(TH[i])))
    return float(TH[j]), float(TX[j]), float(TY[j]), best_f, min(lb_all, best_f)


def _cell_bound_s(ca, sa, cb, sb, K1, A1, B1, K2, A2, B2):
    """Scalar :func:`_cell_bounds` (same candidates, same arithmetic): (lb, argmin_c, argmin_s)."""
    sqrt = math.sqrt
    best = max(K1 - A1 * ca - B1 * sa, K2 - A2 * ca - B2 * sa)
    bc, bs = ca, sa
    v = max(K1 - A1 * cb - B1 * sb, K2 - A2 * cb - B2 * sb)
    if v < best:
        best, bc, bs = v, cb, sb
    cands = []
    r1 = sqrt(A1 * A1 + B1 * B1)
    if r1 > 0.0:
        cands.append((A1 / r1, B1 / r1))
    r2 = sqrt(A2 * A2 + B2 * B2)
    if r2 > 0.0:
        cands.append((A2 / r2, B2 / r2))
    dA = A1 - A2
    dB = B1 - B2
    R = sqrt(dA * dA + dB * dB)
    if R > 0.0:
        u = (K1 - K2) / R
        e = 1.0 - u * u
        if e >= 0.0:
            h = sqrt(e) / R
            u = u / R
            bx = u * dA
            by = u * dB
            px = h * dB
            py = h * dA
            cands.append((bx - px, by + py))
            cands.append((bx + px, by - py))
    for cx, cy in cands:
        if (ca * cy - sa * cx) >= -1e-15 and (cx * sb - cy * cb) >= -1e-15:
            v = max(K1 - A1 * cx - B1 * cy, K2 - A2 * cx - B2 * cy)
            if v < best:
                best, bc, bs = v, cx, cy
    return best, bc, bs


_SMALL_MAX_N = 10  # linf: the whole certified search in plain Python up to this many robots
_SMALL_STENCIL = 1  # stencil points added next to the best angle per round
_SMALL_RATIO = 16.0
_SMALL_MAX_EVALS = 400  # evaluation budget of the plain-Python search (then the batch search)


def _search_small(prob: _Problem, seed: float, tol: float):
    """:func:`_search` for linf and few robots, in plain Python (no numpy calls).

    Same certificate (sinusoidal minorants, closed-form cell bounds, the same
    tolerance rule); only the choice of angles differs: the local descent's
    angles plus three angles a quarter turn apart (so every cell is shorter
    than pi), then uncertified cells are split at the minimiser of their bound
    (cutting plane) and, when wide, also at the middle, until every cell is
    certified.  Returns None when the evaluation budget runs out (the caller
    then runs the batch search).
    """
    two_pi = 2.0 * math.pi
    pi = math.pi
    cos, sin = math.cos, math.sin
    recs = _local_search(prob, _linf_eval_s, seed)
    pts = {}  # wrapped angle -> (c, s, f, tx, ty, K - slack, A, B, rslack, basis)

    def put(th, r):
        pts[th] = (cos(th), sin(th), r[0], r[1], r[2], r[3] - r[6], r[4], r[5], r[10], r[7])

    for th, r, _ in recs:
        th = wrap_angle(th)
        if th not in pts:
            put(th, r)
    if pts:
        th_loc = min(pts, key=lambda a: pts[a][2])
        hint = pts[th_loc][9]
    else:
        th_loc = wrap_angle(seed)
        hint = None
    # three angles a quarter turn apart; with robots enough, far from the
    # optimum a pair dual (the template's widest pair) is bound enough: the
    # point is re-solved exactly only if a cell next to it stays uncertified
    n = prob.n
    Px, Py, Qx, Qy, w = prob.lPx, prob.lPy, prob.lQx, prob.lQy, prob.lw
    pi_ = max(range(n), key=lambda k: Px[k] * Px[k] + Py[k] * Py[k])
    pj_ = max(range(n), key=lambda k: (Px[k] - Px[pi_]) ** 2 + (Py[k] - Py[pi_]) ** 2)
    cheap = bool(pts) and pi_ != pj_
    for k in (1, 2, 3):
        x = wrap_angle(th_loc + 0.5 * pi * k)
        if x in pts:
            continue
        if cheap:
            c, s = cos(x), sin(x)
            i, j = (pi_, pj_) if pi_ < pj_ else (pj_, pi_)
            rho, tx, ty, kx, ky = _pair_s(
                Qx[i] - (Px[i] * c - Py[i] * s), Qy[i] - (Px[i] * s + Py[i] * c),
                Qx[j] - (Px[j] * c - Py[j] * s), Qy[j] - (Px[j] * s + Py[j] * c), w[i], w[j],
            )
            K = A = B = 0.0
            K += kx * Qx[i] + ky * Qy[i]
            A += kx * Px[i] + ky * Py[i]
            B += ky * Px[i] - kx * Py[i]
            K += -kx * Qx[j] + -ky * Qy[j]
            A += -kx * Px[j] + -ky * Py[j]
            B += -ky * Px[j] - -kx * Py[j]
            rslack = 64.0 * _EPS * (2.0 * math.sqrt(kx * kx + ky * ky)) * prob.bound
            # f = inf: not a candidate optimum until solved exactly
            pts[x] = (c, s, math.inf, tx, ty, K - rslack, A, B, rslack, (i, j))
        else:
            put(x, _linf_eval_s(prob, x, hint))
    cells = {}  # (a, b) -> cell bound, kept across rounds
    while True:
        TH = sorted(pts)
        m = len(TH)
        if m > _SMALL_MAX_EVALS:
            return None
        P = [pts[a] for a in TH]
        ib = min(range(m), key=lambda i: P[i][2])
        U = P[ib][2]
        tol_eff = max(tol, 4.0 * P[ib][8])
        lb_all = math.inf
        new = []
        for i in range(m):
            j = i + 1 if i + 1 < m else 0
            a = TH[i]
            b = TH[j] if j else TH[0] + two_pi
            h = b - a
            pa, pb = P[i], P[j]
            key = (a, b, pa[2] == math.inf, pb[2] == math.inf)
            cb = cells.get(key)
            if cb is not None:
                lb, lc, ls = cb
            elif h >= 3.0:
                lb, lc, ls = -math.inf, 0.0, 0.0
            else:
                lb, lc, ls = _cell_bound_s(pa[0], pa[1], pb[0], pb[1], pa[5], pa[6], pa[7], pb[5], pb[6], pb[7])
                if lb < 0.0:
                    lb = 0.0  # every cost is >= 0 (the zero minorant)
                cells[key] = (lb, lc, ls)
            if lb < lb_all:
                lb_all = lb
            if lb >= U - tol_eff:
                continue
            if pa[2] == math.inf or pb[2] == math.inf:
                # an endpoint with a pair bound only: solve it exactly first
                for x, pr in ((a, pa), (TH[j], pb)):
                    if pr[2] == math.inf:
                        new.append((x, pr[9]))
                continue
            cand = []
            if h < 3.0:
                xk = math.atan2(ls, lc)
                while xk < a:
                    xk += two_pi
                while xk > b:
                    xk -= two_pi
                inner = a + 1e-3 * h < xk < b - 1e-3 * h
                if a < xk < b:
                    cand.append(xk)
                if h > 0.1 or not inner:
                    cand.append(a + 0.5 * h)
                elif i == ib or j == ib:
                    # next to the best angle the minorants' curvature, not their
                    # slope, limits the bound: a geometric stencil towards it
                    x0, sg = (a, 1.0) if i == ib else (b, -1.0)
                    e = h
                    for _ in range(_SMALL_STENCIL):
                        e /= _SMALL_RATIO
                        cand.append(x0 + sg * e)
            else:
                cand.append(a + 0.5 * h)
            for x in cand:
                if a < x < b:
                    x = x - two_pi if x >= pi else x
                    new.append((x, pa[9] if x - a < b - x else pb[9]))
        if lb_all >= U - tol_eff:
            break
        added = False
        for x, hb in new:
            if x not in pts or pts[x][2] == math.inf:
                put(x, _linf_eval_s(prob, x, hb))
                added = True
        if not added:
            return None
    TH = sorted(pts)
    best_f = min(v[2] for v in pts.values())
    j = min((a for a in TH if pts[a][2] == best_f), key=lambda a: (abs(a), a))
    return j, pts[j][3], pts[j][4], best_f, min(lb_all, best_f)


def _first_pass(prob: _Problem, oracle, uniq, c, s, warm, recs, th_loc: float, h0: float):
    """The first certification batch, made cheap; any shortfall is refined later.

    l1: a few inner iterations (any iterate gives valid bounds).  linf with
    4..40 robots: pair duals on the coarse grid (far from the optimum, where
    the margin is large) and, near the optimum, the exact minimax centre of
    the robots that form the local search's bases.
    """
    if oracle is _l1_oracle:
        return oracle(prob, c, s, warm, _FIRST_PASS_ITERS)
    n = prob.n
    if not (_SPLIT_MIN_N < n <= _SPLIT_MAX_N):
        return oracle(prob, c, s, warm)
    zone = 0.26 * h0
    members = set()
    for r in recs:
        dd = abs(math.remainder(r[0] - th_loc, 2.0 * math.pi))
        if dd <= zone:
            members.update(r[1][8])
    if not 2 <= len(members) <= 8:
        return oracle(prob, c, s, warm)
    subset = sorted(members)
    grid = set(_GRID)
    gi = np.array([k for k, x in enumerate(uniq) if x in grid], dtype=np.intp)
    zi = np.array([k for k, x in enumerate(uniq) if x not in grid], dtype=np.intp)
    outs = []
    if len(gi):
        outs.append((gi, oracle(prob, c[gi], s[gi], None, pairs_only=True)))
    if len(zi):
        outs.append((zi, oracle(prob, c[zi], s[zi], None, subset=subset)))
    if len(outs) == 1:
        return outs[0][1]
    (i1, o1), (i2, o2) = outs
    res = []
    for a, b in zip(o1, o2):
        v = np.empty((len(uniq),) + a.shape[1:], dtype=a.dtype)
        v[i1] = a
        v[i2] = b
        res.append(v)
    return tuple(res)


def _state_vec(state) -> list:
    """Warm-start state as a float vector: a basis (padded to 3) or a point."""
    if len(state) == 2 and isinstance(state[0], float):
        return [state[0], state[1]]
    if len(state) == 2:
        return [float(state[0]), float(state[1]), float(state[1])]
    return [float(v) for v in state]


def _batch_eval(oracle, keyed: bool):
    """One angle through a batch oracle (large n); keyed: the state is a basis."""

    def evalf(prob, th, hint):
        c = np.array([math.cos(th)])
        s = np.array([math.sin(th)])
        warm = None if hint is None else np.array([hint], dtype=float)
        f, tx, ty, K, A, B, slack, state, _ = oracle(prob, c, s, warm)
        st = tuple(state[0].tolist())
        a_, b_ = float(A[0]), float(B[0])
        return (float(f[0]), float(tx[0]), float(ty[0]), float(K[0]), a_, b_,
                float(slack[0]), st, tuple(sorted(set(int(v) for v in st))) if keyed else 0,
                a_ * s[0] - b_ * c[0])

    return evalf


# --------------------------------------------------------------------------
# fit


def _pose_from_centred(prob: _Problem, th: float, tx: float, ty: float) -> Pose2:
    """World pose from a centred translation t' at rotation th."""
    th = wrap_angle(th)
    c, s = math.cos(th), math.sin(th)
    x = tx + prob.cr[0] - (c * prob.cp[0] - s * prob.cp[1])
    y = ty + prob.cr[1] - (s * prob.cp[0] + c * prob.cp[1])
    return Pose2(x, y, th)


def _fit_l2(prob: _Problem) -> float:
    """Weighted Procrustes rotation without reflection (0 when unobservable)."""
    Px, Py, Qx, Qy, w = prob.lPx, prob.lPy, prob.lQx, prob.lQy, prob.lw
    rng = range(prob.n)
    dot = math.fsum([w[i] * (Px[i] * Qx[i] + Py[i] * Qy[i]) for i in rng])
    cross = math.fsum([w[i] * (Px[i] * Qy[i] - Py[i] * Qx[i]) for i in rng])
    mag = math.fsum(
        [w[i] * math.sqrt((Px[i] * Px[i] + Py[i] * Py[i]) * (Qx[i] * Qx[i] + Qy[i] * Qy[i])) for i in rng]
    )
    if math.hypot(cross, dot) <= 1e-13 * mag:
        return 0.0
    return math.atan2(cross, dot)


def _translation_at(prob: _Problem, metric: str, th: float):
    """Optimal centred translation at a fixed rotation, with a certified lower bound."""
    c = np.array([math.cos(th)])
    s = np.array([math.sin(th)])
    oracle = _linf_oracle if metric == "linf" else _l1_oracle
    f, tx, ty, K, A, B, slack, _, _ = oracle(prob, c, s, None)
    lb = float(K[0] - A[0] * c[0] - B[0] * s[0] - slack[0])
    return float(tx[0]), float(ty[0]), lb


def fit_structure(template_xy, positions_xy, metric: str = "l2", weights=None) -> FitResult:
    """Fit the virtual structure: the rigid pose minimising the metric's cost.

    template_xy: (n, 2) structure-frame points p_i [m].
    positions_xy: (n, 2) world positions r_i of the robots [m].
    metric: 'l1' (sum w_i d_i), 'l2' (sqrt(sum w_i d_i^2)) or 'linf'
        (max w_i d_i), with d_i = |r_i - R(th) p_i - (x, y)|.
    weights: optional (n,) non-negative weights (default all 1); a robot with
        weight 0 is ignored by the fit.

    l2 is closed form; linf and l1 are certified global optima (cost within
    1e-10 of optimal; see the module docstring for the method, the
    certificate and the degenerate cases: n = 1 and coincident points give
    th = 0, n = 2 is closed form).

    Raises ShapeError (shapes, n = 0, non-numeric), NonFiniteError,
    UnknownMetricError, WeightError.
    """
    p, r, metric, w = _validate(template_xy, positions_xy, metric, weights)
    with np.errstate(all="ignore"):
        return _fit(p, r, metric, w)


def _fit(p: np.ndarray, r: np.ndarray, metric: str, w: np.ndarray) -> FitResult:
    if w.min() > 0.0:
        pk, rk, wk = p, r, w
    else:
        keep = w > 0.0
        pk, rk, wk = p[keep], r[keep], w[keep]
    prob = _Problem(pk, rk, wk)
    m = len(wk)
    lower = None
    tmpl_same = all(x == prob.lPx[0] for x in prob.lPx) and all(y == prob.lPy[0] for y in prob.lPy)
    robots_same = all(x == prob.lQx[0] for x in prob.lQx) and all(y == prob.lQy[0] for y in prob.lQy)
    if m == 1:
        pose = Pose2(rk[0, 0] - pk[0, 0], rk[0, 1] - pk[0, 1], 0.0)
    elif metric == "l2":
        th = 0.0 if (tmpl_same or robots_same) else _fit_l2(prob)
        pose = _pose_from_centred(prob, th, 0.0, 0.0)
    elif tmpl_same or robots_same:
        th = 0.0
        tx, ty, lower = _translation_at(prob, metric, th)
        pose = _pose_from_centred(prob, th, tx, ty)
    elif m == 2:
        th = _fit_l2(prob)
        thw = wrap_angle(th)
        c, s = math.cos(thw), math.sin(thw)
        qx = prob.Qx - (c * prob.Px - s * prob.Py)
        qy = prob.Qy - (s * prob.Px + c * prob.Py)
        w1, w2 = float(wk[0]), float(wk[1])
        if metric == "linf" or w1 == w2:
            tx = (w1 * qx[0] + w2 * qx[1]) / (w1 + w2) if metric == "linf" else 0.5 * (qx[0] + qx[1])
            ty = (w1 * qy[0] + w2 * qy[1]) / (w1 + w2) if metric == "linf" else 0.5 * (qy[0] + qy[1])
        else:
            j = 0 if w1 > w2 else 1
            tx, ty = qx[j], qy[j]
        pose = _pose_from_centred(prob, thw, float(tx), float(ty))
    else:
        oracle = _linf_oracle if metric == "linf" else _l1_oracle
        if prob.n <= _SCALAR_MAX_N[metric]:
            evalf = _linf_eval_s if metric == "linf" else _l1_eval_s
        else:
            evalf = _batch_eval(oracle, metric == "linf")
        seed = _fit_l2(prob)
        out = None
        if metric == "linf" and prob.n <= _SMALL_MAX_N:
            out = _search_small(prob, seed, CERT_TOL)
        if out is None:
            out = _search(prob, oracle, evalf, seed, CERT_TOL)
        th, tx, ty, best, lower = out
        pose = _pose_from_centred(prob, th, tx, ty)
    d = _residuals(p, r, pose)
    cost = _cost_of(d, w, metric)
    if lower is None:
        lower = cost
    d.flags.writeable = False
    return FitResult(pose=pose, cost=cost, residuals_m=d, metric=metric, cost_lower_bound=min(float(lower), cost))
