"""The certified search over the rotation: sinusoidal minorants, cell bounds, refinement.

An evaluator solves the inner (translation) problem at a batch of angles and returns, for
each angle, a global minorant m(th) = K - A cos th - B sin th of the fit cost f(th).  The
search refines the circle until every cell's bound is within CERT_TOL of the best cost.
"""

from __future__ import annotations

import math
import sys
from functools import cached_property

from ..lazy import lazy_numpy
from ..coreconst import FIT_CERT_TOL as CERT_TOL, FIT_MAX_ROUNDS as _MAX_ROUNDS  # vs_fit.h's
from ..geometry import Pose2, wrap_angle

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

#: Certification tolerance of the l1 and linf searches [weighted m].
EPS = sys.float_info.epsilon   # numpy's finfo(float).eps: the same double
_GRID = 8  # initial uniform grid of rotations
_STENCIL = tuple(4.0 ** -k for k in range(1, 9))  # offsets around a cell's centre [x distance to its ends]
_LOCAL = (1e-6, 1e-3, 4e-3, 1.6e-2, 6.4e-2)  # first batch: th0 and th0 +- these [rad]
_LEAN = (4, (1e-6, 1e-4, 1e-3, 1e-2), 300)  # the same when th0 is a converged local optimum: grid,
# offsets, and the n from which only the first and last offsets are kept (every angle costs n)
_LADDER = 6  # first batch: each guess g and g +- 1e-9 32^k, k < _LADDER (certifies a smooth minimum at once)


class Problem:
    """Centred data: q_i(th) = Q_i - R(th) P_i; the centred translation t maps to the pose."""

    def __init__(self, p: np.ndarray, r: np.ndarray, w):
        self.n = n = len(p)
        self.unit = w is None
        self.w = np.ones(n) if w is None else w
        if w is None:
            self.cp, self.cr = p.sum(axis=0) / n, r.sum(axis=0) / n
        else:
            W = float(w.sum())
            self.cp, self.cr = (w[:, None] * p).sum(axis=0) / W, (w[:, None] * r).sum(axis=0) / W
        self.P, self.Q = p - self.cp, r - self.cr
        self.PQ = np.concatenate([self.P.T, self.Q.T])  # rows Px, Py, Qx, Qy: one gather for all four
        self.Px, self.Py, self.Qx, self.Qy = self.PQ

    @cached_property
    def rigid(self) -> bool:
        """All template points or all robots coincide: f does not depend on th."""
        return bool(((self.Px == self.Px[0]) & (self.Py == self.Py[0])).all()
                    or ((self.Qx == self.Qx[0]) & (self.Qy == self.Qy[0])).all())

    @cached_property
    def bound(self) -> float:
        """|t| <= bound for every angle's optimal centred translation (it lies in the hull of q)."""
        return float(np.sqrt(self.Qx**2 + self.Qy**2).max() + np.sqrt(self.Px**2 + self.Py**2).max())

    def q(self, c: np.ndarray, s: np.ndarray):
        """q_i at each angle, (m, n) arrays, from (m,) cosines and sines."""
        c, s = c[:, None], s[:, None]
        return self.Qx - (c * self.Px - s * self.Py), self.Qy - (s * self.Px + c * self.Py)

    def minorant(self, kx, ky, rows=None):
        """(K, A, B) of dual vectors (m, k) on robots ``rows`` (m, k) (default all), K net of slack.

        m(th) = sum k_i . q_i(th) - |sum k_i| bound - 64 eps bound sum |k_i| <= f(th) when every
        |k_i| is within the metric's dual ball (weak duality; any translation).
        """
        Px, Py, Qx, Qy = self.PQ if rows is None else self.PQ[:, rows]
        add = np.add.reduce  # np.sum's own reduction, without its Python wrapper
        K, A, B = add(kx * Qx + ky * Qy, axis=1), add(kx * Px + ky * Py, axis=1), add(ky * Px - kx * Py, axis=1)
        fx, fy, kabs = add(kx, axis=1), add(ky, axis=1), add(np.sqrt(kx * kx + ky * ky), axis=1)
        return K - self.bound * (np.sqrt(fx * fx + fy * fy) + 64.0 * EPS * kabs), A, B

    def pose(self, th: float, tx: float, ty: float) -> Pose2:
        """World pose from rotation th and centred translation t."""
        th = wrap_angle(th)
        c, s = math.cos(th), math.sin(th)
        cpx, cpy = float(self.cp[0]), float(self.cp[1])
        return Pose2(tx + float(self.cr[0]) - (c * cpx - s * cpy), ty + float(self.cr[1]) - (s * cpx + c * cpy), th)


def cell_bounds(ca, sa, cb, sb, Ka, Aa, Ba, Kb, Ab, Bb):
    """min of max(m_a, m_b) over each arc from angle a to b (< pi), with the argmin (cos, sin).

    The minimum is at an endpoint, a crossing m_a = m_b or an unconstrained minimum of one
    minorant; all are found with sqrt only.  Never below 0 (f >= 0).
    """
    dK, dA, dB = Ka - Kb, Aa - Ab, Ba - Bb  # crossings: dA c + dB s = dK
    rho2 = dA * dA + dB * dB
    root = np.sqrt(np.maximum(rho2 - dK * dK, 0.0))
    inv = 1.0 / rho2
    na, nb = np.sqrt(Aa * Aa + Ba * Ba), np.sqrt(Ab * Ab + Bb * Bb)
    C, S = np.empty((6, len(ca))), np.empty((6, len(ca)))  # the candidates' cos and sin
    C[0], C[1], C[2], C[3] = ca, cb, Aa / na, Ab / nb
    S[0], S[1], S[2], S[3] = sa, sb, Ba / na, Bb / nb
    C[4], C[5] = (dA * dK - dB * root) * inv, (dA * dK + dB * root) * inv
    S[4], S[5] = (dB * dK + dA * root) * inv, (dB * dK - dA * root) * inv
    v = np.maximum(Ka - Aa * C - Ba * S, Kb - Ab * C - Bb * S)
    ok = (ca * S - sa * C >= 0.0) & (C * sb - S * cb >= 0.0) & np.isfinite(v)  # inside the arc, real
    ok[:2] = True
    ok[4:] &= rho2 >= dK * dK
    k, cols = np.argmin(np.where(ok, v, np.inf), axis=0), np.arange(len(ca))
    best, bc, bs = v[k, cols], C[k, cols], S[k, cols]
    slack = 8.0 * EPS * (np.abs(Ka) + np.abs(Kb) + na + nb)
    return np.maximum(best - slack, 0.0), bc, bs


def translation_at(prob: Problem, evaluate, th: float):
    """Optimal centred translation at a fixed rotation and the minorant's value there."""
    c, s = np.array([math.cos(th)]), np.array([math.sin(th)])
    f, tx, ty, K, A, B = evaluate(prob, c, s, np.zeros(1), np.zeros(1), np.zeros(1, bool))[:6]
    return float(tx[0]), float(ty[0]), float(K[0] - A[0] * c[0] - B[0] * s[0])


class _Angles:
    """Evaluated angles, kept sorted: rows th, c, s, f, tx, ty, K, A, B, rough, extras of ``self.a``."""

    def __init__(self, prob: Problem, evaluate, t0=(0.0, 0.0)):
        self.prob, self.evaluate, self.t0 = prob, evaluate, t0
        self.a = np.empty((10, 0))

    def add(self, ths, rough=()) -> int:
        """Evaluate new angles (``rough``: first-pass ones); rough angles asked again are re-solved.

        Returns how many angles were evaluated.
        """
        ask = np.remainder(np.array(list(ths) + list(rough), dtype=float) + math.pi, 2.0 * math.pi) - math.pi
        flag = np.arange(len(ask)) >= len(ask) - len(rough)
        order = np.lexsort((flag, ask))  # exact before rough at equal angles: keep the first
        ask, flag = ask[order], flag[order]
        first = np.concatenate([[True], ask[1:] != ask[:-1]])
        th, flag = ask[first], flag[first]
        old = self.a
        if old.shape[1]:
            at = np.minimum(np.searchsorted(old[0], th), old.shape[1] - 1)
            known = old[0, at] == th
            redo = known & (old[9, at] > 0) & ~flag  # first-pass angles re-solved exactly
            th, flag = th[~known | redo], flag[~known | redo]
            if redo.any():
                keep = np.ones(old.shape[1], bool)
                keep[at[redo]] = False
                old = old[:, keep]
        if not len(th):
            return 0
        if old.shape[1]:
            gap = np.abs(np.remainder(th[:, None] - old[0] + math.pi, 2.0 * math.pi) - math.pi)
            t0 = old[4:6, np.argmin(gap, axis=1)]  # warm start: the nearest evaluated angle's t
        else:
            t0 = np.array(self.t0, dtype=float)[:, None].repeat(len(th), axis=1)  # the caller's start
        lt = th.tolist()
        c = np.array([math.cos(t) for t in lt])  # math, not numpy: the same bits on every CPU
        s = np.array([math.sin(t) for t in lt])
        out = self.evaluate(self.prob, c, s, t0[0], t0[1], flag)
        a = np.array((th, c, s) + tuple(out[:6]) + (flag,) + tuple(out[6:]), dtype=float)  # extra rows: the evaluator's
        a = np.concatenate([old, a], axis=1) if old.shape[1] else a
        self.a = a[:, np.argsort(a[0], kind="stable")]
        return len(th)


def _centres(f, g, th, b: int, side: int, cut: float) -> list:
    """Distinct guesses of the minimiser in the cell from th[b] towards ``side``, as offsets.

    The cut point; the slope's root interpolated through b and the cell's other end o (a line)
    and through b's other neighbour too (a parabola: a smooth minimum); where quadratic models
    of f's two arms cross (a kink: the basis changes).  Numpy scalars: a zero divisor gives
    inf / nan, dropped with every guess outside the cell.
    """
    m = len(th)
    o, p = (b + side) % m, (b - side) % m
    xo = math.remainder(float(th[o] - th[b]), 2.0 * math.pi)
    xp = math.remainder(float(th[p] - th[b]), 2.0 * math.pi)
    d1 = (g[o] - g[b]) / xo
    d2 = ((g[p] - g[b]) / xp - d1) / (xp - xo)
    disc = np.sqrt(max((d1 - d2 * xo) ** 2 - 4.0 * d2 * g[b], 0.0))
    roots = (-g[b] / d1, (d2 * xo - d1 - disc) / (2.0 * d2), (d2 * xo - d1 + disc) / (2.0 * d2))
    # the slope's roots of the cubic Hermite model of f on the cell (f and f' at both ends)
    sec = (f[o] - f[b]) / xo
    h2, h3 = (3.0 * sec - 2.0 * g[b] - g[o]) / xo, (g[b] + g[o] - 2.0 * sec) / (xo * xo)
    dh = np.sqrt(max(h2 * h2 - 3.0 * h3 * g[b], 0.0))
    roots += ((-h2 - dh) / (3.0 * h3), (-h2 + dh) / (3.0 * h3))

    def curv(i, j):  # an arm's curvature from two of its slopes (straight if they differ in sign)
        dth = math.remainder(float(th[j] - th[i]), 2.0 * math.pi)
        return float((g[j] - g[i]) / dth) if g[i] * g[j] > 0.0 else 0.0

    kb, ko = curv(b, p), curv(o, (o + side) % m)  # arms: b + g_b x + kb x^2/2 and the same at o
    qa = np.float64(0.5 * (kb - ko))
    qb = g[b] - g[o] + ko * xo
    qc = f[b] - f[o] + g[o] * xo - 0.5 * ko * xo * xo
    if abs(qa) * xo * xo <= 1e-3 * abs(qb * xo):  # nearly straight arms: the tangent lines' crossing
        kinks = (-qc / qb,)
    else:
        dq = np.sqrt(max(qb * qb - 4.0 * qa * qc, 0.0))
        kinks = ((-qb - dq) / (2.0 * qa), (-qb + dq) / (2.0 * qa))
    width = abs(xo)
    kept = []
    for x in sorted(x for x in [cut] + [float(side * r) for r in roots] + [float(side * k) for k in kinks]
                    if 0.0 < x < width):
        if not kept or x - kept[-1] > 1e-3 * min(x, width - x):
            kept.append(x)
    return kept


def search(prob: Problem, evaluate, th0: float, guesses=(), split: int = 0, tol: float = CERT_TOL,
           max_rounds: int = _MAX_ROUNDS, t0=(0.0, 0.0), lean: bool = False, refine=None):
    """Certified min over th of f(th): (th, centred tx, ty, lower bound of min f).

    Rounds: evaluate new angles; bound every cell between neighbours; in each cell whose
    bound is below best - tol/2 add its cut point (the bound's argmin) and re-solve its ends
    exactly if they came from the rough first pass; next to the best angle add stencils around
    the cell's guesses of the minimiser (:func:`_centres`); until every cell is certified.
    ``guesses``: candidate minimisers [rad] for the first batch; ``split``: every uncertified
    cell also gets 2 (split // n) points at 4^-k of its width from its ends.  ``t0``: the
    first batch's warm start (centred translation); ``lean``: th0 is a converged local
    optimum (and t0 its translation), so the first batch is smaller (_LEAN).  ``refine(prob,
    th_b, extras_b, th_o, extras_o)``: candidate minimisers [rad] in the uncertified cell from
    the best angle b to its neighbour o (from the evaluator's extra rows); each gets a ladder.
    """
    S = _Angles(prob, evaluate, t0)
    few = _LEAN[1][-1:] if guesses else _LEAN[1][:: 1 if prob.n < _LEAN[2] else 3]  # with a guess: its ladder
    grid, offsets = (_LEAN[0], few) if lean else (_GRID, _LOCAL)
    step = 2.0 * math.pi / grid
    local = [th0 + e * h for e in (-1.0, 0.0, 1.0) for h in offsets]
    local += [g + e * 1e-9 * 32.0 ** k for g in guesses for e in (-1.0, 0.0, 1.0) for k in range(_LADDER - lean)]
    S.add(local, rough=[-math.pi + step * k for k in range(grid)])
    levels = _STENCIL[: max(1, min(len(_STENCIL), 400 // prob.n))]
    lv = 4.0 ** -np.arange(1, split // prob.n + 1)  # resolves a cell whose end touches f
    frac = np.concatenate([lv, 1.0 - lv])
    lower = 0.0
    for _ in range(max_rounds):
        th, c, s, f, tx, ty, K, A, B, rough = S.a[:10]
        nxt = np.arange(1, len(th) + 1) % len(th)
        lb, bc, bs = cell_bounds(c, s, c[nxt], s[nxt], K, A, B, K[nxt], A[nxt], B[nxt])
        b = int(np.argmin(f))
        fbest = float(f[b])
        lower = min(fbest, float(lb.min()))
        # half the tolerance: the reported cost is recomputed from the world pose
        tol_eff = 0.5 * max(tol, 4.0 * 64.0 * EPS * prob.bound * float(np.abs(K).max() + 1.0))
        bad = np.nonzero(lb < fbest - tol_eff)[0]
        if len(bad) == 0:
            break
        new = [math.atan2(y, x) for y, x in zip(bs[bad].tolist(), bc[bad].tolist())]
        ends = np.concatenate([bad, nxt[bad]])
        new += th[ends[rough[ends] > 0]].tolist()
        arc = np.remainder(th[nxt[bad]] - th[bad], 2.0 * math.pi)
        new += (th[bad][:, None] + arc[:, None] * frac).ravel().tolist()
        g = A * s - B * c  # slopes f'(th) of the minorants (exact at smooth inner optima)
        m = len(th)
        for side, j in ((1, b), (-1, (b - 1) % m)):  # the cells right and left of the best
            if lb[j] >= fbest - tol_eff:
                continue
            width = abs(math.remainder(float(th[(b + side) % m] - th[b]), 2.0 * math.pi))
            cut = abs(math.remainder(new[int(np.searchsorted(bad, j))] - float(th[b]), 2.0 * math.pi))
            tb = float(th[b])
            hints = [] if refine is None else refine(prob, tb, S.a[10:, b], tb + side * width, S.a[10:, (b + side) % m])
            for r in hints:
                new += [r + e * 1e-9 * 32.0 ** k for e in (-1.0, 0.0, 1.0) for k in range(_LADDER)]
            for x in [] if hints else _centres(f, g, th, b, side, cut):  # a stencil on both sides of each
                d = min(x, width - x)
                new += [tb + side * (x + e * d * h) for h in (0.0,) + levels for e in (-1.0, 1.0)]
        if not S.add(new):  # the uncertified cells cannot be split in floating point
            break
    b = int(np.argmin(S.a[3]))
    return float(S.a[0, b]), float(S.a[4, b]), float(S.a[5, b]), lower
