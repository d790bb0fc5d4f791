"""linf: the minimum enclosing circle of the q_i at each angle, exact, with its basis duals."""

from __future__ import annotations

import math
from functools import lru_cache
from itertools import combinations

from ..lazy import lazy_numpy
from ..coreconst import LINF_SPLIT as SPLIT  # vs_fit_linf.h's
from .certify import EPS

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

_WS = 6  # working-set size: the circle is solved exactly on these, then checked on every robot
_NEXT = [1, 2, 0]  # a basis member's successor (cross products of the radii)
# SPLIT: search end points in every uncertified cell (9 // n per end: 3 at n = 3, none from n = 10)


@lru_cache(maxsize=8)
def _subsets(k: int):
    """Members (S, 3) of every pair (i, j, j) and triple (i, j, l) of range(k), its columns, the pair count."""
    pairs = [(i, j, j) for i in range(k) for j in range(i + 1, k)]
    triples = [(i, j, l) for i in range(k) for j in range(i + 1, k) for l in range(j + 1, k)]
    mem = np.array(pairs + triples, dtype=np.intp).reshape(-1, 3)
    return mem, tuple(np.ascontiguousarray(mem[:, i]) for i in range(3)), len(pairs)


def _circle(X, Y):
    """Exact smallest circle of each row's points (m, k): centre, radius^2, basis (m, 3), weights.

    The radius is the largest over pairs (half the distance) and triples whose circumcentre
    lies in the triangle (barycentric weights >= 0: the KKT condition); that subset is the basis.
    """
    mem, (i0, i1, i2), npair = _subsets(X.shape[1])
    x0, y0 = X[:, i0], Y[:, i0]  # (m, S)
    bx, by = X[:, i1] - x0, Y[:, i1] - y0
    ex, ey = X[:, i2] - x0, Y[:, i2] - y0
    det = bx * ey - by * ex
    b2, e2 = bx * bx + by * by, ex * ex + ey * ey
    ux, uy = (ey * b2 - by * e2) / (2.0 * det), (bx * e2 - ex * b2) / (2.0 * det)
    lb, le = (ux * ey - uy * ex) / det, (bx * uy - by * ux) / det  # circumcentre = x0 + lb b + le e
    ux[:, :npair], uy[:, :npair] = 0.5 * bx[:, :npair], 0.5 * by[:, :npair]
    lb[:, :npair], le[:, :npair] = 0.5, 0.0
    r2 = ux * ux + uy * uy
    ok = (lb >= 0.0) & (le >= 0.0) & (lb + le <= 1.0) & np.isfinite(r2)
    best = np.argmax(np.where(ok, r2, -1.0), axis=1)
    rows = np.arange(len(X))
    lb, le = lb[rows, best], le[rows, best]
    lam = np.array([1.0 - lb - le, lb, le]).T
    cx, cy = x0[rows, best] + ux[rows, best], y0[rows, best] + uy[rows, best]
    return cx, cy, r2[rows, best], mem[best], lam


def evaluate(prob, c, s, tx0, ty0, rough):
    """Minimax centre at each angle: (f, tx, ty, K, A, B), (m,) arrays; see certify.search.

    Active set: solve exactly on a working set (the farthest robots from the warm centre),
    then add the farthest robots while any lies outside; the radius grows, so it ends.
    Duals: k_i = w lam_i (q_i - centre)/radius on the basis (lam: its barycentric weights).
    ``rough`` (the search's first-pass rows): the working set's circle only (a looser minorant).
    """
    qx, qy = prob.q(c, s)
    m, n = qx.shape
    k = min(n, _WS)
    rows = np.arange(m)[:, None]
    if k == n:  # every robot in the working set: the circle is exact at once
        cx, cy, r2, mem, lam = _circle(qx, qy)
    else:
        ws = np.argpartition((qx - tx0[:, None]) ** 2 + (qy - ty0[:, None]) ** 2, n - k, axis=1)[:, n - k:]
        cx, cy, r2, mem, lam = _circle(qx[rows, ws], qy[rows, ws])
        mem = ws[rows, mem]
    d2max = lambda: ((qx - cx[:, None]) ** 2 + (qy - cy[:, None]) ** 2).max(axis=1)  # noqa: E731
    dmax = d2max()  # rough rows keep the working set's circle: valid duals, f at its centre
    act = act0 = np.nonzero((dmax > r2 * (1.0 + 16.0 * EPS)) & ~rough)[0]
    for _ in range(n if k < n and len(act) else 0):  # each round grows every active row's radius
        ax, ay = qx[act], qy[act]
        d2 = (ax - cx[act, None]) ** 2 + (ay - cy[act, None]) ** 2
        out = d2.max(axis=1) > r2[act] * (1.0 + 16.0 * EPS)
        if not out.any():
            break
        act, d2 = act[out], d2[out]
        far = np.argpartition(d2, n - k + 3, axis=1)[:, n - k + 3:]
        ws = np.concatenate([mem[act], far], axis=1)
        sub = np.arange(len(act))[:, None]
        cx[act], cy[act], r2[act], m_, lam[act] = _circle(qx[act[:, None], ws], qy[act[:, None], ws])
        mem[act] = ws[sub, m_]
    w = prob.w[0]
    dx, dy = qx[rows, mem] - cx[:, None], qy[rows, mem] - cy[:, None]
    # a triple's multipliers from the radii themselves (lam_i ~ v_j x v_k), so that sum lam_i v_i
    # vanishes to rounding even where the circumcentre's barycentric weights are ill-conditioned
    dx1, dy1 = dx[:, _NEXT], dy[:, _NEXT]
    cr = dx1 * dy1[:, _NEXT] - dy1 * dx1[:, _NEXT]
    lam = np.where(lam[:, 2:] > 0.0, cr / np.sum(cr, axis=1)[:, None], lam)
    rad = np.sqrt(r2)
    scale = np.where(rad > 0.0, w / rad, 0.0)[:, None] * lam
    K, A, B = prob.minorant(scale * dx, scale * dy, mem)
    # a pair basis also gives the constant minorant w ||Q_i - Q_j| - |P_i - P_j|| / 2 (every th):
    # better where it touches, e.g. a pair of coincident robots, whose distance is constant
    D = prob.PQ[:, mem[:, 0]] - prob.PQ[:, mem[:, 1]]
    D *= D
    dq, dp = np.sqrt(D[2] + D[3]), np.sqrt(D[0] + D[1])
    cst = 0.5 * w * (np.abs(dq - dp) - 16.0 * EPS * prob.bound)
    flat = (lam[:, 2] == 0.0) & (cst >= K - A * c - B * s)
    K, A, B = np.where(flat, cst, K), np.where(flat, 0.0, A), np.where(flat, 0.0, B)
    f = w * np.sqrt(d2max() if k < n and len(act0) else dmax)
    return (f, cx, cy, K, A, B) + tuple(mem.T.astype(float))  # extra rows: the basis (i, j, j) or (i, j, l)


def _r2(basis, pair: bool, th: float) -> float:
    """Squared radius of a basis's circle at angle th: half the pair's distance, or the circumradius.

    basis: (Px, Py, Qx, Qy) of its 3 robots (a pair's second one repeated).
    """
    c, s = math.cos(th), math.sin(th)
    (px, py, qx, qy), (pbx, pby, qbx, qby), (pex, pey, qex, qey) = basis
    ax, ay = qx - (c * px - s * py), qy - (s * px + c * py)
    bx, by = qbx - (c * pbx - s * pby), qby - (s * pbx + c * pby)
    ex, ey = qex - (c * pex - s * pey), qey - (s * pex + c * pey)
    d1 = (bx - ax) ** 2 + (by - ay) ** 2
    if pair:
        return 0.25 * d1
    X = (bx - ax) * (ey - ay) - (by - ay) * (ex - ax)  # twice the area
    if X == 0.0:  # collinear: no circumcircle
        return math.inf
    return d1 * ((ex - ax) ** 2 + (ey - ay) ** 2) * ((ex - bx) ** 2 + (ey - by) ** 2) / (4.0 * X * X)


def kinks(prob, tha: float, ea, thb: float, eb) -> list:
    """Candidate minimisers in the cell (tha, thb): speed only (a search hint).

    ea, eb: the evaluator's extra rows (basis indices) at the ends.  The stationary point of
    the basis at tha (:func:`guesses`) if it is in the cell; where the two bases have equal
    radii (f's kink), if their difference changes sign over the cell (Illinois regula falsi).
    """
    ba, bb = tuple(sorted(int(v) for v in ea)), tuple(sorted(int(v) for v in eb))
    lo, hi = min(tha, thb), max(tha, thb)
    out = [g for g in guesses(prob, tha, ba) if lo < g < hi]  # the same basis: h = 0, no root
    pa, pb = (prob.PQ[:, list(bs)].T.tolist() for bs in (ba, bb))
    b = _root(lambda th: _r2(pa, ba[1] == ba[2], th) - _r2(pb, bb[1] == bb[2], th), tha, thb)
    return out + [b] if b is not None and lo < b < hi else out


def _root(h, a: float, b: float):
    """A root of h in [a, b] by Illinois regula falsi; None without a sign change."""
    fa, fb = h(a), h(b)
    if not fa * fb < 0.0 or math.isinf(fa - fb):
        return None
    side, k = 0, 0
    while abs(b - a) > 1e-15 * (1.0 + abs(b)) and fb != 0.0 and k < 60:
        x, k = (a * fb - b * fa) / (fb - fa), k + 1
        fx = h(x)
        if fx * fb < 0.0:
            a, fa, side = b, fb, 0
        elif side:
            fa *= 0.5
        else:
            side = 1
        b, fb = x, fx
    return b


def _mec(ids, qx, qy, new=None):
    """Basis (i, j, j) / (i, j, l), centre, radius^2 of the smallest circle around robots ``ids`` (sorted, <= 4);
    ``new``: a robot outside the others' smallest circle, hence on this one (Welzl)."""
    pts = list(zip(ids, qx[ids].tolist(), qy[ids].tolist()))
    out = [((ids[0],) * 3, pts[0][1], pts[0][2], 0.0)]  # one robot: itself
    for sub in (t for k in (2, 3) for t in combinations(pts, k) if new is None or new in (t[0][0], t[1][0], t[-1][0])):
        (i, ax, ay), (j, bx, by) = sub[:2]
        if len(sub) == 2:
            cx, cy, key = 0.5 * (ax + bx), 0.5 * (ay + by), (i, j, j)  # ids sorted: so is every key
        else:
            bx, by, ex, ey = bx - ax, by - ay, sub[2][1] - ax, sub[2][2] - ay
            det, b2, e2 = 2.0 * (bx * ey - by * ex) or math.inf, bx * bx + by * by, ex * ex + ey * ey  # collinear: a
            cx, cy, key = ax + (ey * b2 - by * e2) / det, ay + (bx * e2 - ex * b2) / det, (i, j, sub[2][0])
        out.append((key, cx, cy, (ax - cx) ** 2 + (ay - cy) ** 2))
    out.sort(key=lambda o: o[3])
    inside = lambda o: all((x - o[1]) ** 2 + (y - o[2]) ** 2 <= o[3] * (1.0 + 1e-12) for _, x, y in pts)  # noqa: E731
    return next((o for o in out if inside(o)), out[-1])


def _basis(prob, ths, basis, last: bool = False, new: int = -1):
    """The enclosing circle's basis and centre at ths[0] [rad] from a warm basis or () (and a robot ``new`` outside
    it): add the farthest robot until none is outside.  ``last``: the first index of ``ths`` where ``basis`` is
    not the basis (or len) and the farthest robot there if it is outside (else -1)."""
    if last:  # the basis's circle at every angle; a triple must stay acute (its centre inside)
        qx, qy = prob.q(np.array([math.cos(x) for x in ths]), np.array([math.sin(x) for x in ths]))
        (ax, bx, ex), (ay, by, ey) = qx[:, list(basis)].T, qy[:, list(basis)].T
        bx, by, ex, ey = bx - ax, by - ay, ex - ax, ey - ay
        det, b2, e2, be = 2.0 * (bx * ey - by * ex), bx * bx + by * by, ex * ex + ey * ey, bx * ex + by * ey
        pair = basis[1] == basis[2]
        ux, uy = (0.5 * bx, 0.5 * by) if pair else ((ey * b2 - by * e2) / det, (bx * e2 - ex * b2) / det)
        d2 = (qx - (ax + ux)[:, None]) ** 2 + (qy - (ay + uy)[:, None]) ** 2
        out = d2.max(axis=1) > (ux * ux + uy * uy) * (1.0 + 1e-12)
        bad = out | ((not pair) & ((be <= 0.0) | (b2 <= be) | (e2 <= be)))
        k = int(np.argmax(bad)) if bad.any() else len(ths)
        return k, int(d2[k].argmax()) if k < len(ths) and out[k] else -1
    c, s = math.cos(ths[0]), math.sin(ths[0])
    qx, qy = prob.Qx - (c * prob.Px - s * prob.Py), prob.Qy - (s * prob.Px + c * prob.Py)
    ids, j, r0 = sorted(set(basis) | ({new} - {-1})) or [int((qx * qx + qy * qy).argmax())], new, -1.0
    while True:  # the radius grows, so it ends
        basis, cx, cy, r2 = _mec(ids, qx, qy, None if j < 0 else j)
        d2 = (qx - cx) ** 2 + (qy - cy) ** 2
        if d2[j := int(d2.argmax())] <= r2 * (1.0 + 1e-12) or r2 <= r0:
            return basis, cx, cy
        ids, r0 = sorted(set(basis) | {j}), r2


def descend(prob, th0: float, steps: int = 12, samples: int = 16):
    """A local minimum of f near th0 [rad] (speed only): (th, its centre (tx, ty), found); (th0, 0, False) if
    none.  Walk downhill on f's pieces: towards the stationary point of the current basis (pair alignment or
    triple Newton), to the first sampled angle where the basis changes, to the kink there (equal radii).  A
    stationary point, or a kink where the new basis rises, is a minimum if that basis holds just past it."""
    rad = lambda b: lambda x, pq=prob.PQ[:, list(b)].T.tolist(): _r2(pq, b[1] == b[2], x)  # noqa: E731
    th, basis = th0, _basis(prob, [th0], ())[0]  # from the robot farthest from the centroid
    for _ in range(steps):
        down = -1.0 if (r := rad(basis))(th + 1e-7) > r(th - 1e-7) else 1.0
        st = [th + math.remainder(g - th, 2.0 * math.pi) for g in guesses(prob, th, basis)]
        st = [g for g in st if 0.0 < (g - th) * down < 0.5]
        target = min(st, key=lambda g: abs(g - th)) if st else th + 0.1 * down
        xs = [th + (target - th) * (k + 1) / samples for k in range(samples)]
        k, j = _basis(prob, xs, basis, last=True)
        rn = rad(nb := basis if k == samples else _basis(prob, [xs[k]], basis, new=j)[0])
        kink = None if k == samples else _root(lambda x: r(x) - rn(x), xs[k - 1] if k else th, xs[min(k, samples - 1)])
        x, b2 = (target if kink is None else kink), (nb,)
        if (k == samples and st) or (kink is not None and rn(kink + 1e-7 * down) >= rn(kink)):
            if (b2 := _basis(prob, [x + 1e-9 * down], nb))[0] == nb:  # nb really is the basis past x
                return x, b2[1:], True
        th, basis = (xs[min(k, samples - 1)] if kink is None else kink), b2[0]
    return th0, (0.0, 0.0), False


def guesses(prob, th0: float, basis=None) -> list:
    """Candidate optimal rotations [rad]: speed only.  Without ``basis``: the paper triangle (n = 3, else none).

    With 3 robots f is the half longest side or the circumradius (C1 where they meet), so
    its minimum is a pair's alignment (closed form) or a stationary point of the triple's
    circumradius R = abc / 2X (Newton on ln R^2 from th0 and where two sides are equal;
    sides^2 and X = 2 area are affine in cos th, sin th).  docs/fit.md.  ``basis`` (i, j, j)
    or (i, j, l): only that pair's alignment, or Newton from th0 on that triple's R.
    """
    if basis is None and prob.n != 3:  # the search runs from n = 3 (larger n: descend)
        return []
    rows = [0, 1, 2] if basis is None else list(basis)  # a pair (i, j, j): its second point repeated
    P, Q = prob.P[rows].tolist(), prob.Q[rows].tolist()
    sides, out = [], []
    for a, b in ((0, 1), (0, 2), (1, 2)):
        D, E = (Q[b][0] - Q[a][0], Q[b][1] - Q[a][1]), (P[b][0] - P[a][0], P[b][1] - P[a][1])
        u, v = D[0] * E[0] + D[1] * E[1], E[0] * D[1] - E[1] * D[0]  # |D - R E|^2 = al - 2(c u + s v)
        sides.append((D[0] ** 2 + D[1] ** 2 + E[0] ** 2 + E[1] ** 2, u, v, D, E))
        out.append(math.atan2(v, u))  # R(th) E along D
    if basis is not None and basis[1] == basis[2]:
        return out[:1]
    (_, _, _, D1, E1), (_, _, _, D2, E2) = sides[0], sides[1]
    kap = D1[0] * D2[1] - D1[1] * D2[0] + E1[0] * E2[1] - E1[1] * E2[0]
    xc = D1[0] * E2[1] - D1[1] * E2[0] + E1[0] * D2[1] - E1[1] * D2[0]
    xs = D1[0] * E2[0] + D1[1] * E2[1] - E1[0] * D2[0] - E1[1] * D2[1]  # X = kap - c xc - s xs
    starts, out = [th0], (out if basis is None else [])
    equal = () if basis is not None else ((sides[0], sides[1]), (sides[0], sides[2]), (sides[1], sides[2]))
    for (a1, u1, v1, _, _), (a2, u2, v2, _, _) in equal:
        du, dv, h = u1 - u2, v1 - v2, 0.5 * (a1 - a2)  # two sides equal: c du + s dv = h
        rho = math.hypot(du, dv)
        if rho > abs(h):
            base, half = math.atan2(dv, du), math.acos(h / rho)
            starts += [base - half, base + half]
    for th in starts:  # Newton from th0 and where two sides are equal (the triple's circle is near)
        try:
            for _ in range(12):
                c, s = math.cos(th), math.sin(th)
                X = kap - c * xc - s * xs
                dx = 2.0 * (s * xc - c * xs) / X  # ln R^2 = sum ln a^2 - ln X^2 + const: d/dth, d2/dth2
                d1, d2 = -dx, 0.5 * dx * dx - 2.0 * (kap - X) / X
                for al, u, v, _, _ in sides:
                    a2 = al - 2.0 * (c * u + s * v)
                    g = 2.0 * (s * u - c * v) / a2
                    d1, d2 = d1 + g, d2 + (al - a2) / a2 - g * g
                if not d2 > 0.0:  # concave here: no minimum of R nearby
                    break
                step = max(-0.2, min(0.2, d1 / d2))
                th -= step
                if abs(step) <= 1e-10:  # quadratic convergence: th is exact to rounding
                    out.append(th)
                    break
        except ZeroDivisionError:  # a degenerate triple (coincident or collinear points)
            break
    out.sort()
    return [x for i, x in enumerate(out) if i == 0 or x - out[i - 1] > 1e-9]
