"""l1: the weighted geometric median of the q_i at each angle, with duals balanced at the end."""

from __future__ import annotations

import math

from ..lazy import lazy_numpy
from ..coreconst import L1_NEWTON_N as NEWTON_N  # vs_fit_l1.h's: from this n the search starts at newton()'s rotation
from .certify import EPS

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

_ITERS = 40  # inner iterations (Newton converges in a handful from a warm start)
_ROUGH_ITERS = 1  # a first-pass solve: a valid but looser minorant
# NEWTON_N: from this n the search starts at newton()'s rotation (smaller fits often sit on a robot)


def _duals(dx, dy, w, tie: float):
    """f and dual vectors k_i (|k_i| <= w_i) from the offsets q_i - t, balanced at the nearest q_j.

    k_i = w_i (q_i - t)/|q_i - t| for robots off the nearest point q_j; the robots on q_j (within
    ``tie`` [m] of it: rounding makes coincident robots differ) share -sum(others), clipped to
    their total weight.  At the optimum this balances exactly, also when the median sits on q_j
    (the Vardi-Zhang case); a robot within ``tie`` costs at most 2 w tie of the bound.
    """
    d = np.sqrt(dx * dx + dy * dy)
    f = np.sum(w * d, axis=1)
    rows = np.arange(len(d))
    j = np.argmin(d, axis=1)
    on = (dx - dx[rows, j][:, None]) ** 2 + (dy - dy[rows, j][:, None]) ** 2 <= tie * tie
    iw = np.where(on, 0.0, w / d)  # d > 0 off q_j
    kx, ky = iw * dx, iw * dy
    sx, sy = np.sum(kx, axis=1), np.sum(ky, axis=1)
    won = np.where(on, w, 0.0)
    eta = np.sum(won, axis=1)
    sn = np.sqrt(sx * sx + sy * sy)
    share = won * (np.minimum(1.0, eta / np.where(sn > 0.0, sn, 1.0)) / eta)[:, None]
    return f, kx - share * sx[:, None], ky - share * sy[:, None]


def evaluate(prob, c, s, tx0, ty0, rough, iters: int = _ITERS):
    """Geometric median at each angle: (f, tx, ty, K, A, B), (m,) arrays; see certify.search.

    The state is the offsets q_i - t (exact near t, where the Hessian is large).  Each
    iteration: gradient g and Hessian H at t (robots on t left out) and a Newton step, halved
    until it does not raise f (Weiszfeld's step where H is singular).  The nearest robot point
    q_j is tested exactly when it is within a step, Newton failed or the row is finishing:
    |sum_{i != j} w_i u_i| < w_j there means t = q_j is optimal, else the Vardi-Zhang step from
    q_j is taken if it lowers f (Weiszfeld stalls next to such a point).  Rows marked
    ``rough`` (m,) stop after a few iterations: their minorant is valid, only looser.
    """
    qx, qy = prob.q(c, s)
    w = prob.w
    W = float(np.sum(w))
    tx, ty = tx0.astype(float), ty0.astype(float)
    gtol = (1e-12 / prob.bound) ** 2  # |gradient|^2: the imbalance costs |g| bound <= 1e-12
    tie = 64.0 * EPS * prob.bound  # robots closer than this to a robot point are taken as on it [m]
    act = np.arange(len(tx))
    dx, dy = qx - tx[:, None], qy - ty[:, None]
    DX, DY = dx.copy(), dy.copy()  # each row's final offsets
    d = np.sqrt(dx * dx + dy * dy)
    f = np.sum(w * d, axis=1)
    for it in range(iters):
        inv = np.divide(1.0, d, out=np.zeros_like(d), where=d > 0.0)  # robots on t left out
        ux, uy = dx * inv, dy * inv
        kx, ky = (ux, uy) if prob.unit else (w * ux, w * uy)
        gx, gy = -np.sum(kx, axis=1), -np.sum(ky, axis=1)
        flat = gx * gx + gy * gy <= gtol  # the duals balance to well within the tolerance
        kx, ky = kx * inv, ky * inv  # Hessian: sum w/d (I - u u^T)
        a, b, cc = np.sum(ky * uy, axis=1), -np.sum(kx * uy, axis=1), np.sum(kx * ux, axis=1)
        det = a * cc - b * b
        sx = np.where(flat, 0.0, (cc * gx - b * gy) / det)  # Newton: t - (sx, sy)
        sy = np.where(flat, 0.0, (a * gy - b * gx) / det)
        ndx, ndy = dx + sx[:, None], dy + sy[:, None]
        nd = np.sqrt(ndx * ndx + ndy * ndy)
        fn = np.sum(nd if prob.unit else w * nd, axis=1)
        ok = fn <= f * (1.0 + 4.0 * EPS)  # a tie within rounding is a landing; False for NaN
        if not ok.all():  # damped Newton where the full step raises f (Weiszfeld's step if singular)
            bad = np.nonzero(~ok)[0]
            fin = np.isfinite(sx[bad]) & np.isfinite(sy[bad])
            sw = np.sum(w * inv[bad], axis=1)
            ux_, uy_ = np.where(fin, sx[bad], gx[bad] / sw), np.where(fin, sy[bad], gy[bad] / sw)
            h = np.where(fin, 0.5, 1.0)
            for _ in range(60):
                tdx, tdy = dx[bad] + (h * ux_)[:, None], dy[bad] + (h * uy_)[:, None]
                td = np.sqrt(tdx * tdx + tdy * tdy)
                tf = np.sum(w * td, axis=1)
                acc = tf <= f[bad] * (1.0 + 4.0 * EPS)
                rows = bad[acc]
                sx[rows], sy[rows], ndx[rows], ndy[rows], nd[rows], fn[rows] = (
                    h[acc] * ux_[acc], h[acc] * uy_[acc], tdx[acc], tdy[acc], td[acc], tf[acc])
                bad, ux_, uy_, h = bad[~acc], ux_[~acc], uy_[~acc], 0.5 * h[~acc]
                if not len(bad):
                    break
            sx[bad], sy[bad], ndx[bad], ndy[bad], nd[bad], fn[bad] = 0.0, 0.0, dx[bad], dy[bad], d[bad], f[bad]
        step = np.sqrt(sx * sx + sy * sy)
        tx[act], ty[act], dx, dy, d, f = tx[act] - sx, ty[act] - sy, ndx, ndy, nd, fn
        # after a Newton step the gradient is ~ |H| step^2 / d, d ~ W / sum(w/d) (quadratic convergence)
        landed = ok & (step * step * (a + cc) ** 2 * prob.bound <= 1e-12 * W)  # a + cc = sum w/d
        dmin = d.min(axis=1)
        stalled = step <= 4.0 * EPS * dmin  # below the resolution of the nearest offset
        done = flat | landed | stalled | (rough[act] & (it + 1 >= _ROUGH_ITERS))
        # q_j is near: within a step, or (a row finishing) close next to the others
        test = np.nonzero(~ok | (dmin <= step) | (done & (dmin * (a + cc) <= 1e-3 * W)))[0]
        if len(test):
            near = np.argmin(d[test], axis=1)
            jx, jy = dx[test, near], dy[test, near]  # offsets of q_j; q_i - q_j = dx_i - jx
            ex, ey = dx[test] - jx[:, None], dy[test] - jy[:, None]
            e = np.sqrt(ex * ex + ey * ey)
            ie = np.where(e > tie, w / e, 0.0)  # robots within rounding of q_j are on it
            vx, vy = np.sum(ie * ex, axis=1), np.sum(ie * ey, axis=1)
            eta = np.sum(np.where(e > tie, 0.0, w), axis=1)
            vn = np.sqrt(vx * vx + vy * vy)
            vertex = vn < eta
            # else the Vardi-Zhang step from q_j: Weiszfeld stalls next to a point that is not optimal
            lam = np.where(vertex, 0.0, (1.0 - eta / vn) / np.sum(ie, axis=1))
            zdx, zdy = ex - (lam * vx)[:, None], ey - (lam * vy)[:, None]
            zd = np.sqrt(zdx * zdx + zdy * zdy)
            zf = np.sum(w * zd, axis=1)
            move = vertex | (zf < f[test])
            rows = test[move]
            tx[act[rows]] += (jx + lam * vx)[move]
            ty[act[rows]] += (jy + lam * vy)[move]
            dx[rows], dy[rows], d[rows], f[rows] = zdx[move], zdy[move], zd[move], zf[move]
            done[rows] = vertex[move] | (done[rows] & rough[act[rows]])
        fin = act[done]
        DX[fin], DY[fin] = dx[done], dy[done]
        if done.all():
            break
        keep = ~done
        act, dx, dy, d, f = act[keep], dx[keep], dy[keep], d[keep], f[keep]
    else:
        DX[act], DY[act] = dx, dy
    f, kx, ky = _duals(DX, DY, w, tie)
    K, A, B = prob.minorant(kx, ky)
    return f, tx, ty, K, A, B



def newton(prob, th: float, iters: int = 12):
    """A local l1 optimum: (th [rad], centred (tx, ty), converged), Newton on (th, t) from (th, 0).

    F = sum w |q_i(th) - t| with its gradient and 3x3 Hessian in closed form (robots on t left
    out).  Converged: a th step <= 1e-12, or a th step <= 1e-9 that raised F (rounding).
    Speed only (the search's start).
    """
    w, Px, Py, Qx, Qy = prob.w, prob.Px, prob.Py, prob.Qx, prob.Qy
    z, fold = (th, 0.0, 0.0), math.inf
    for _ in range(iters):
        th, tx, ty = z
        c, s = math.cos(th), math.sin(th)
        rx, ry = c * Px - s * Py, s * Px + c * Py  # R P: dq/dth = (ry, -rx), d2q/dth2 = R P
        vx, vy = Qx - rx - tx, Qy - ry - ty
        d = np.sqrt(vx * vx + vy * vy)
        f = float(np.sum(w * d))
        if not f < fold:  # the step raised F (only rounding, if it was tiny): back to the last point
            return zold[0], zold[1:], abs(h0) <= 1e-9
        iw = np.divide(w, d, out=np.zeros_like(d), where=d > 0.0)
        ux, uy = iw * vx, iw * vy  # w u_i
        ex, ey = vx / np.where(d > 0.0, d, 1.0), vy / np.where(d > 0.0, d, 1.0)
        mxx, mxy, myy = iw * (1.0 - ex * ex), -iw * ex * ey, iw * (1.0 - ey * ey)  # w/d (I - u u^T)
        mx, my = mxx * ry - mxy * rx, mxy * ry - myy * rx  # w M dq/dth
        g = (float(np.sum(ux * ry - uy * rx)), -float(np.sum(ux)), -float(np.sum(uy)))
        a, b, e = float(np.sum(mx * ry - my * rx + ux * rx + uy * ry)), -float(np.sum(mx)), -float(np.sum(my))
        xx, xy, yy = float(np.sum(mxx)), float(np.sum(mxy)), float(np.sum(myy))
        # solve [[a, b, e], [b, xx, xy], [e, xy, yy]] h = g (Cramer)
        m0, m1, m2 = xx * yy - xy * xy, b * yy - xy * e, b * xy - xx * e
        det = a * m0 - b * m1 + e * m2
        if not det > 0.0:  # not a minimum's basin (or singular): keep the best point
            break
        h0 = (g[0] * m0 - b * (g[1] * yy - xy * g[2]) + e * (g[1] * xy - xx * g[2])) / det
        h1 = (a * (g[1] * yy - xy * g[2]) - g[0] * m1 + e * (b * g[2] - g[1] * e)) / det
        h2 = (a * (xx * g[2] - g[1] * xy) - b * (b * g[2] - g[1] * e) + g[0] * m2) / det
        zold, fold = z, f
        z = (th - h0, tx - h1, ty - h2)
        if abs(h0) <= 1e-12:
            return z[0], z[1:], True
    return z[0], z[1:], False
