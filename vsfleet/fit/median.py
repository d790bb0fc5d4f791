"""l1: the weighted geometric median of the q_i at each angle, with duals balanced at the end."""

from __future__ import annotations

import numpy as np

_ITERS = 40  # inner iterations (Newton converges in a handful from a warm start)


def _duals(qx, qy, w, tx, ty):
    """f and dual vectors k_i (|k_i| <= w_i) at t, balanced through the nearest robot point.

    k_i = w_i (q_i - t)/|q_i - t| for robots off the nearest point q_j; the robots on q_j
    share -sum(others), clipped to their total weight.  At the optimum this balances exactly,
    also when the median sits on q_j (the Vardi-Zhang case).
    """
    dx, dy = qx - tx[:, None], qy - ty[:, None]
    d = np.sqrt(dx * dx + dy * dy)
    f = np.sum(w * d, axis=1)
    j = np.argmin(d, axis=1)[:, None]
    on = (qx == np.take_along_axis(qx, j, 1)) & (qy == np.take_along_axis(qy, j, 1))
    iw = np.where(on | (d == 0.0), 0.0, w / np.where(d > 0.0, d, 1.0))
    kx, ky = iw * dx, iw * dy
    sx, sy = np.sum(kx, axis=1), np.sum(ky, axis=1)
    eta = np.sum(np.where(on, w, 0.0), axis=1)
    sn = np.sqrt(sx * sx + sy * sy)
    share = np.where(on, w, 0.0) * (np.minimum(1.0, eta / np.where(sn > 0.0, sn, 1.0)) / eta)[:, None]
    return f, kx - share * sx[:, None], ky - share * sy[:, None]


def evaluate(prob, c, s, tx0, ty0, iters: int = _ITERS):
    """Geometric median at each angle: (f, tx, ty, K, A, B), (m,) arrays; see certify.search.

    Each iteration: the cost's gradient g and Hessian H at t (robots on t left out), a Newton
    step, and the nearest robot point q_j tested exactly (|sum_{i != j} w_i u_i| < w_j there
    means t = q_j is optimal); a Newton step that does not lower f falls back to Weiszfeld.
    """
    qx, qy = prob.q(c, s)
    w = prob.w
    tx, ty = tx0.astype(float), ty0.astype(float)
    scale = prob.bound * 1e-13
    act = np.arange(len(tx))
    for _ in range(iters):
        x, y = qx[act], qy[act]
        dx, dy = x - tx[act, None], y - ty[act, None]
        d = np.sqrt(dx * dx + dy * dy)
        f0 = np.sum(w * d, axis=1)
        pos = d > 0.0
        iw = np.where(pos, w / np.where(pos, d, 1.0), 0.0)
        i3 = iw / np.where(pos, d * d, 1.0)
        gx, gy = -np.sum(iw * dx, axis=1), -np.sum(iw * dy, axis=1)
        a, b, cc = np.sum(i3 * dy * dy, axis=1), -np.sum(i3 * dx * dy, axis=1), np.sum(i3 * dx * dx, axis=1)
        det = a * cc - b * b
        nx, ny = tx[act] - (cc * gx - b * gy) / det, ty[act] - (a * gy - b * gx) / det
        sw = np.sum(iw, axis=1)  # Weiszfeld step t - g / sum(w/d)
        wx, wy = tx[act] - gx / sw, ty[act] - gy / sw
        # the nearest robot point, tested exactly
        j = np.argmin(d, axis=1)[:, None]
        jx, jy = np.take_along_axis(x, j, 1)[:, 0], np.take_along_axis(y, j, 1)[:, 0]
        ex, ey = x - jx[:, None], y - jy[:, None]
        e = np.sqrt(ex * ex + ey * ey)
        on = e > 0.0
        ie = np.where(on, w / np.where(on, e, 1.0), 0.0)
        vx, vy = np.sum(ie * ex, axis=1), np.sum(ie * ey, axis=1)
        vertex = vx * vx + vy * vy < np.sum(np.where(on, 0.0, w), axis=1) ** 2
        ndx, ndy = x - nx[:, None], y - ny[:, None]
        fn = np.sum(w * np.sqrt(ndx * ndx + ndy * ndy), axis=1)
        newton = np.isfinite(fn) & (fn <= f0)
        ux = np.where(vertex, jx, np.where(newton, nx, np.where(sw > 0.0, wx, tx[act])))
        uy = np.where(vertex, jy, np.where(newton, ny, np.where(sw > 0.0, wy, ty[act])))
        moved = np.abs(ux - tx[act]) + np.abs(uy - ty[act])
        tx[act], ty[act] = ux, uy
        act = act[~vertex & (moved > scale)]
        if not len(act):
            break
    f, kx, ky = _duals(qx, qy, w, tx, ty)
    K, A, B = prob.minorant(kx, ky)
    return f, tx, ty, K, A, B
