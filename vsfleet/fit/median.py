"""l1: the weighted geometric median of the q_i at each angle, with duals balanced at the end."""

from __future__ import annotations

import numpy as np

from .certify import EPS

_ITERS = 40  # inner iterations (Newton converges in a handful from a warm start)
_ROUGH_ITERS = 2  # a first-pass solve: a valid but looser minorant


def _duals(qx, qy, w, tx, ty):
    """f and dual vectors k_i (|k_i| <= w_i) at t, balanced through the nearest robot point.

    k_i = w_i (q_i - t)/|q_i - t| for robots off the nearest point q_j; the robots on q_j
    share -sum(others), clipped to their total weight.  At the optimum this balances exactly,
    also when the median sits on q_j (the Vardi-Zhang case).
    """
    dx, dy = qx - tx[:, None], qy - ty[:, None]
    d = np.sqrt(dx * dx + dy * dy)
    f = np.sum(w * d, axis=1)
    rows = np.arange(len(d))
    j = np.argmin(d, axis=1)
    on = (qx == qx[rows, j][:, None]) & (qy == qy[rows, j][:, None])
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

    Each iteration: the cost's gradient g and Hessian H at t (robots on t left out) and a
    Newton step, kept if it does not raise f, else a Weiszfeld step t - g / sum(w/d).  When the
    nearest robot point q_j is closer than the step, it is tested exactly:
    |sum_{i != j} w_i u_i| < w_j there means t = q_j is optimal (Vardi-Zhang).  Rows marked
    ``rough`` (m,) stop after a few iterations: their minorant is valid, only looser.
    """
    qx, qy = prob.q(c, s)
    w = prob.w
    W = float(np.sum(w))
    tx, ty = tx0.astype(float), ty0.astype(float)
    stop = prob.bound * 1e-15  # step [m] at rounding level
    gtol = (1e-12 / prob.bound) ** 2  # |gradient|^2: the imbalance costs |g| bound <= 1e-12
    act = np.arange(len(tx))
    x, y = qx, qy
    dx, dy = x - tx[:, None], y - ty[:, None]
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
        sx, sy = (cc * gx - b * gy) / det, (a * gy - b * gx) / det  # Newton: t - (sx, sy)
        t0x, t0y = tx[act], ty[act]
        ndx, ndy = dx + sx[:, None], dy + sy[:, None]
        nd = np.sqrt(ndx * ndx + ndy * ndy)
        fn = np.sum(nd if prob.unit else w * nd, axis=1)
        ok = fn <= f * (1.0 + 4.0 * EPS)  # a tie within rounding is a landing; False for NaN
        step = np.sqrt(sx * sx + sy * sy)
        if not ok.all():  # Weiszfeld where Newton fails (never raises f)
            bad = ~ok
            sw = np.sum(w * inv[bad], axis=1)
            wsx, wsy = np.where(sw > 0.0, gx[bad] / sw, 0.0), np.where(sw > 0.0, gy[bad] / sw, 0.0)
            sx[bad], sy[bad] = wsx, wsy
            ndx[bad], ndy[bad] = dx[bad] + wsx[:, None], dy[bad] + wsy[:, None]
            nd[bad] = np.sqrt(ndx[bad] ** 2 + ndy[bad] ** 2)
            fn[bad] = np.sum(w * nd[bad], axis=1)
            step[bad] = np.sqrt(wsx * wsx + wsy * wsy)
        sx, sy, step = np.where(flat, 0.0, sx), np.where(flat, 0.0, sy), np.where(flat, 0.0, step)
        tx[act], ty[act], dx, dy, d, f = t0x - sx, t0y - sy, ndx, ndy, nd, fn
        # after a Newton step the gradient is ~ |H| step^2 / d, d ~ W / sum(w/d) (quadratic convergence)
        sw = a + cc  # trace of H = sum w/d
        landed = ok & (step * step * sw * sw * prob.bound <= 1e-12 * W)
        done = flat | landed | (step <= stop) | (rough[act] & (it + 1 >= _ROUGH_ITERS))
        test = np.nonzero(~ok | (d.min(axis=1) <= step))[0]  # Newton failed, or q_j is within a step
        if len(test):
            near = np.argmin(d[test], axis=1)
            jx, jy = x[test, near], y[test, near]
            ex, ey = x[test] - jx[:, None], y[test] - jy[:, None]
            e = np.sqrt(ex * ex + ey * ey)
            ie = np.where(e > 0.0, w / e, 0.0)
            vx, vy = np.sum(ie * ex, axis=1), np.sum(ie * ey, axis=1)
            vertex = vx * vx + vy * vy < np.sum(np.where(e > 0.0, 0.0, w), axis=1) ** 2
            hit = test[vertex]
            tx[act[hit]], ty[act[hit]] = jx[vertex], jy[vertex]
            done[hit] = True
        if done.all():
            break
        keep = ~done
        act, x, y, dx, dy, d, f = act[keep], x[keep], y[keep], dx[keep], dy[keep], d[keep], f[keep]
    f, kx, ky = _duals(qx, qy, w, tx, ty)
    K, A, B = prob.minorant(kx, ky)
    return f, tx, ty, K, A, B
