/* vs_fit_l1.c - l1: the weighted geometric median of the q_i at one angle with balanced duals
 * (median.evaluate, median._duals), and the Newton start at large n (median.newton). */
#include "vs_fit_l1.h"

#include <math.h>   /* sqrt only (and the INFINITY / NAN macros) */

#define ITERS 40
#define ROUGH_ITERS 1

static int finite(double x) { return vs_isfinite(x); }

void vs_fit_eval_l1(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out)
{
    size_t n = pr->n;
    const double *w = pr->w;
    double *qx = pr->sc, *qy = qx + n, *dx = qy + n, *dy = dx + n, *d = dy + n;
    double *ndx = d + n, *ndy = ndx + n, *nd = ndy + n, *tdx = nd + n, *tdy = tdx + n, *td = tdy + n;
    double *zdx = td + n, *zdy = zdx + n, *zd = zdy + n, *kx = zd + n, *ky = kx + n, *inv = ky + n;
    double W = pr->W;
    double tx = tx0, ty = ty0;
    double gtol = 1e-12 / pr->bound;
    gtol = gtol * gtol;
    double tie = 64.0 * VS_EPS * pr->bound;
    double f = 0.0;
    for (size_t i = 0; i < n; i++) {
        qx[i] = pr->Qx[i] - (c * pr->Px[i] - s * pr->Py[i]);
        qy[i] = pr->Qy[i] - (s * pr->Px[i] + c * pr->Py[i]);
        dx[i] = qx[i] - tx;
        dy[i] = qy[i] - ty;
        d[i] = sqrt(dx[i] * dx[i] + dy[i] * dy[i]);
        f += w[i] * d[i];
    }
    for (int it = 0; it < ITERS; it++) {
        double gx = 0.0, gy = 0.0, a = 0.0, b = 0.0, cc = 0.0, sw = 0.0;
        for (size_t i = 0; i < n; i++) {
            inv[i] = d[i] > 0.0 ? 1.0 / d[i] : 0.0;
            double ux = dx[i] * inv[i], uy = dy[i] * inv[i];
            double kxi = w[i] * ux, kyi = w[i] * uy;
            gx += kxi;
            gy += kyi;
            kxi *= inv[i];
            kyi *= inv[i];
            a += kyi * uy;
            b += kxi * uy;
            cc += kxi * ux;
        }
        gx = -gx; gy = -gy; b = -b;
        int flat = gx * gx + gy * gy <= gtol;
        double det = a * cc - b * b;
        double sx = flat ? 0.0 : (cc * gx - b * gy) / det;
        double sy = flat ? 0.0 : (a * gy - b * gx) / det;
        double fn = 0.0;
        for (size_t i = 0; i < n; i++) {
            ndx[i] = dx[i] + sx;
            ndy[i] = dy[i] + sy;
            nd[i] = sqrt(ndx[i] * ndx[i] + ndy[i] * ndy[i]);
            fn += w[i] * nd[i];
        }
        int ok = fn <= f * (1.0 + 4.0 * VS_EPS);
        if (!ok) {   /* damped Newton (Weiszfeld's step if singular) */
            int fin = finite(sx) && finite(sy);
            for (size_t i = 0; i < n; i++) sw += w[i] * inv[i];
            double ux_ = fin ? sx : gx / sw, uy_ = fin ? sy : gy / sw, h = fin ? 0.5 : 1.0;
            int acc = 0;
            for (int k = 0; k < 60; k++) {
                double tf = 0.0;
                for (size_t i = 0; i < n; i++) {
                    tdx[i] = dx[i] + h * ux_;
                    tdy[i] = dy[i] + h * uy_;
                    td[i] = sqrt(tdx[i] * tdx[i] + tdy[i] * tdy[i]);
                    tf += w[i] * td[i];
                }
                if (tf <= f * (1.0 + 4.0 * VS_EPS)) {
                    sx = h * ux_; sy = h * uy_; fn = tf;
                    for (size_t i = 0; i < n; i++) { ndx[i] = tdx[i]; ndy[i] = tdy[i]; nd[i] = td[i]; }
                    acc = 1;
                    break;
                }
                h *= 0.5;
            }
            if (!acc) {
                sx = 0.0; sy = 0.0; fn = f;
                for (size_t i = 0; i < n; i++) { ndx[i] = dx[i]; ndy[i] = dy[i]; nd[i] = d[i]; }
            }
        }
        double stp = sqrt(sx * sx + sy * sy);
        tx -= sx; ty -= sy; f = fn;
        double dmin = 0.0;
        for (size_t i = 0; i < n; i++) {
            dx[i] = ndx[i]; dy[i] = ndy[i]; d[i] = nd[i];
            if (i == 0 || d[i] < dmin) dmin = d[i];
        }
        double ac = a + cc;
        int landed = ok && (stp * stp * (ac * ac) * pr->bound <= 1e-12 * W);
        int stalled = stp <= 4.0 * VS_EPS * dmin;
        int done = flat || landed || stalled || (rough && it + 1 >= ROUGH_ITERS);
        if (!ok || dmin <= stp || (done && dmin * ac <= 1e-3 * W)) {
            size_t near = 0;
            for (size_t i = 1; i < n; i++)
                if (d[i] < d[near]) near = i;
            double jx = dx[near], jy = dy[near];
            double vx = 0.0, vy = 0.0, eta = 0.0, sie = 0.0, zf = 0.0;
            for (size_t i = 0; i < n; i++) {
                double ex = dx[i] - jx, ey = dy[i] - jy, e = sqrt(ex * ex + ey * ey);
                zd[i] = e;   /* the offsets from q_j: the vertex's (lam = 0) */
                double ie = e > tie ? w[i] / e : 0.0;
                vx += ie * ex;
                vy += ie * ey;
                eta += e > tie ? 0.0 : w[i];
                sie += ie;
            }
            double vn = sqrt(vx * vx + vy * vy);
            int vertex = vn < eta;
            double lam = vertex ? 0.0 : (1.0 - eta / vn) / sie;
            for (size_t i = 0; i < n; i++) {
                double ex = dx[i] - jx, ey = dy[i] - jy;
                zdx[i] = ex - lam * vx;
                zdy[i] = ey - lam * vy;
                if (!vertex) zd[i] = sqrt(zdx[i] * zdx[i] + zdy[i] * zdy[i]);   /* else ex - 0 vx = ex */
                zf += w[i] * zd[i];
            }
            if (vertex || zf < f) {
                tx += jx + lam * vx;
                ty += jy + lam * vy;
                for (size_t i = 0; i < n; i++) { dx[i] = zdx[i]; dy[i] = zdy[i]; d[i] = zd[i]; }
                f = zf;
                done = vertex || (done && rough);
            }
        }
        if (done) break;
    }
    /* _duals: f and dual vectors balanced at the nearest q_j */
    double fd = 0.0;
    size_t j = 0;
    for (size_t i = 0; i < n; i++) {   /* d[i] is already sqrt(dx^2 + dy^2) of these offsets */
        fd += w[i] * d[i];
        if (d[i] < d[j]) j = i;
    }
    double sx = 0.0, sy = 0.0, eta = 0.0;
    for (size_t i = 0; i < n; i++) {
        double ax = dx[i] - dx[j], ay = dy[i] - dy[j];
        int on = ax * ax + ay * ay <= tie * tie;
        double iw = on ? 0.0 : w[i] / d[i];
        kx[i] = iw * dx[i];
        ky[i] = iw * dy[i];
        sx += kx[i];
        sy += ky[i];
        inv[i] = on ? w[i] : 0.0;   /* won */
        eta += inv[i];
    }
    double sn = sqrt(sx * sx + sy * sy);
    double r = eta / (sn > 0.0 ? sn : 1.0);
    double fac = (r != r ? r : (r < 1.0 ? r : 1.0)) / eta;
    for (size_t i = 0; i < n; i++) {
        double share = inv[i] * fac;
        kx[i] = kx[i] - share * sx;
        ky[i] = ky[i] - share * sy;
    }
    out->Kc = -INFINITY;
    out->f = fd;
    out->tx = tx;
    out->ty = ty;
    vs_fit_minorant(pr, kx, ky, NULL, n, &out->K, &out->A, &out->B);
}

int vs_fit_l1_newton(const vs_prob *pr, double th, double *th_out, double *tx_out, double *ty_out)
{
    size_t n = pr->n;
    const double *w = pr->w, *Px = pr->Px, *Py = pr->Py, *Qx = pr->Qx, *Qy = pr->Qy;
    double z0 = th, z1 = 0.0, z2 = 0.0, o0 = th, o1 = 0.0, o2 = 0.0, h0 = 0.0, fold = 0.0;
    int have_old = 0;
    for (int it = 0; it < 12; it++) {
        double t = z0, tx = z1, ty = z2;
        double c, s;
        vs_sincos(t, &s, &c);
        double f = 0.0;
        double g0 = 0.0, g1 = 0.0, g2 = 0.0, a = 0.0, b = 0.0, e = 0.0, xx = 0.0, xy = 0.0, yy = 0.0;
        for (size_t i = 0; i < n; i++) {
            double rx = c * Px[i] - s * Py[i], ry = s * Px[i] + c * Py[i];
            double vx = Qx[i] - rx - tx, vy = Qy[i] - ry - ty;
            double d = sqrt(vx * vx + vy * vy);
            f += w[i] * d;
            double iw = d > 0.0 ? w[i] / d : 0.0;
            double ux = iw * vx, uy = iw * vy;
            double dd = d > 0.0 ? d : 1.0;
            double ex = vx / dd, ey = vy / dd;
            double mxx = iw * (1.0 - ex * ex), mxy = -iw * ex * ey, myy = iw * (1.0 - ey * ey);
            double mx = mxx * ry - mxy * rx, my = mxy * ry - myy * rx;
            g0 += ux * ry - uy * rx;
            g1 += ux;
            g2 += uy;
            a += mx * ry - my * rx + ux * rx + uy * ry;
            b += mx;
            e += my;
            xx += mxx;
            xy += mxy;
            yy += myy;
        }
        g1 = -g1; g2 = -g2; b = -b; e = -e;
        if (!(!have_old || f < fold)) {   /* the step raised F: back to the last point */
            *th_out = o0; *tx_out = o1; *ty_out = o2;
            return vs_fabs(h0) <= 1e-9;
        }
        double m0 = xx * yy - xy * xy, m1 = b * yy - xy * e, m2 = b * xy - xx * e;
        double det = a * m0 - b * m1 + e * m2;
        if (!(det > 0.0)) break;
        h0 = (g0 * m0 - b * (g1 * yy - xy * g2) + e * (g1 * xy - xx * g2)) / det;
        double h1 = (a * (g1 * yy - xy * g2) - g0 * m1 + e * (b * g2 - g1 * e)) / det;
        double h2 = (a * (xx * g2 - g1 * xy) - b * (b * g2 - g1 * e) + g0 * m2) / det;
        o0 = z0; o1 = z1; o2 = z2; fold = f; have_old = 1;
        z0 = t - h0; z1 = tx - h1; z2 = ty - h2;
        if (vs_fabs(h0) <= 1e-12) {
            *th_out = z0; *tx_out = z1; *ty_out = z2;
            return 1;
        }
    }
    *th_out = z0; *tx_out = z1; *ty_out = z2;
    return 0;
}
