/* vs_clear.c - the structure's clearance barrier (vs_clear.h); its reference: vsfleet.clear (plain Python). */
#include <math.h>

#include "vs_clear.h"

#define TOL 1e-12

static double dot3(const double *a, const double *t) { return a[0] * t[0] + a[1] * t[1] + a[2] * t[2]; }

static int meets(const double a[][3], const double *b, int k, const double *t)
{
    for (int r = 0; r < k; r++)
        if (!(dot3(a[r], t) >= b[r] - TOL)) return 0;
    return 1;
}

/* the nearest twist to td (metric: plain, td's third component already reach w) meeting a_r . t >= b_r for r < k,
 * by a fixed enumeration: td itself, else each row's plane, each pair's line, each triple's point (least distance,
 * the first on ties); 0 if none does */
static int nearest(const double a[][3], const double *b, int k, const double td[3], double out[3])
{
    if (meets(a, b, k, td)) { out[0] = td[0]; out[1] = td[1]; out[2] = td[2]; return 1; }
    double best_t[3] = {0.0, 0.0, 0.0}, best_d = 0.0;
    int have = 0;
    for (int p = 0; p < k; p++) {          /* each row's plane */
        double g = dot3(a[p], a[p]);
        if (!(g > TOL)) continue;
        double lam = (b[p] - dot3(a[p], td)) / g;
        double t[3] = {td[0] + lam * a[p][0], td[1] + lam * a[p][1], td[2] + lam * a[p][2]};
        if (!meets(a, b, k, t)) continue;
        double e0 = t[0] - td[0], e1 = t[1] - td[1], e2 = t[2] - td[2], d = e0 * e0 + e1 * e1 + e2 * e2;
        if (!have || d < best_d) { best_d = d; best_t[0] = t[0]; best_t[1] = t[1]; best_t[2] = t[2]; have = 1; }
    }
    for (int p = 0; p < k; p++)            /* each pair's line */
        for (int q = p + 1; q < k; q++) {
            double g00 = dot3(a[p], a[p]), g01 = dot3(a[p], a[q]), g11 = dot3(a[q], a[q]);
            double det = g00 * g11 - g01 * g01;
            if (!(det > TOL)) continue;
            double r0 = b[p] - dot3(a[p], td), r1 = b[q] - dot3(a[q], td);
            double l0 = (r0 * g11 - r1 * g01) / det, l1 = (g00 * r1 - g01 * r0) / det;
            double t[3] = {td[0] + l0 * a[p][0] + l1 * a[q][0], td[1] + l0 * a[p][1] + l1 * a[q][1],
                           td[2] + l0 * a[p][2] + l1 * a[q][2]};
            if (!meets(a, b, k, t)) continue;
            double e0 = t[0] - td[0], e1 = t[1] - td[1], e2 = t[2] - td[2], d = e0 * e0 + e1 * e1 + e2 * e2;
            if (!have || d < best_d) { best_d = d; best_t[0] = t[0]; best_t[1] = t[1]; best_t[2] = t[2]; have = 1; }
        }
    for (int p = 0; p < k; p++)            /* each triple's point: a_p.t = b_p, a_q.t = b_q, a_s.t = b_s */
        for (int q = p + 1; q < k; q++)
            for (int s = q + 1; s < k; s++) {
                const double *u = a[p], *v = a[q], *w = a[s];
                double x0 = v[1] * w[2] - v[2] * w[1], x1 = v[2] * w[0] - v[0] * w[2], x2 = v[0] * w[1] - v[1] * w[0];
                double det = u[0] * x0 + u[1] * x1 + u[2] * x2;
                if (!(det > TOL || det < -TOL)) continue;
                /* Cramer: t = (b_p (v x w) + b_q (w x u) + b_s (u x v)) / det */
                double y0 = w[1] * u[2] - w[2] * u[1], y1 = w[2] * u[0] - w[0] * u[2], y2 = w[0] * u[1] - w[1] * u[0];
                double z0 = u[1] * v[2] - u[2] * v[1], z1 = u[2] * v[0] - u[0] * v[2], z2 = u[0] * v[1] - u[1] * v[0];
                double t[3] = {(b[p] * x0 + b[q] * y0 + b[s] * z0) / det, (b[p] * x1 + b[q] * y1 + b[s] * z1) / det,
                               (b[p] * x2 + b[q] * y2 + b[s] * z2) / det};
                if (!meets(a, b, k, t)) continue;
                double e0 = t[0] - td[0], e1 = t[1] - td[1], e2 = t[2] - td[2], d = e0 * e0 + e1 * e1 + e2 * e2;
                if (!have || d < best_d) { best_d = d; best_t[0] = t[0]; best_t[1] = t[1]; best_t[2] = t[2]; have = 1; }
            }
    out[0] = best_t[0];
    out[1] = best_t[1];
    out[2] = best_t[2];
    return have;
}

int vs_clearance_barrier(const double *points_xy, double fx, double fy, const double *radius_m, size_t n,
                         const double *obstacles, size_t m, double reach_m, const double twist_in[3],
                         double twist_out[3])
{
    double a[VS_CLEAR_ROWS][3] = {{0.0}}, b[VS_CLEAR_ROWS] = {0.0}, c[VS_CLEAR_ROWS] = {0.0};
    int k = 0;
    twist_out[0] = twist_in[0];
    twist_out[1] = twist_in[1];
    twist_out[2] = twist_in[2];
    if (!(reach_m > 0.0)) reach_m = 1.0;   /* every point at the origin: w moves none of them */
    for (size_t i = 0; i < n; i++) {
        double px = points_xy[2 * i], py = points_xy[2 * i + 1];
        double best = 0.0, bdx = 0.0, bdy = 0.0, bd = 0.0;
        int found = 0;
        for (size_t j = 0; j < m; j++) {
            const double *o = obstacles + 3 * j;
            double dx = px - o[0], dy = py - o[1];
            double d = sqrt(dx * dx + dy * dy);
            double clr = d - (radius_m[i] + o[2]);
            if (!found || clr < best) { best = clr; bdx = dx; bdy = dy; bd = d; found = 1; }
        }
        if (!found || !(best < VS_CLEAR_M + VS_CLEAR_BAND_M) || !(bd > 0.0)) continue;
        double nx = bdx / bd, ny = bdy / bd, rx = px - fx, ry = py - fy;
        /* insert by clearance, after equal ones (lower robot index first); keep VS_CLEAR_ROWS */
        int at = k;
        while (at > 0 && best < c[at - 1]) at--;
        if (at >= VS_CLEAR_ROWS) continue;
        int last = k < VS_CLEAR_ROWS ? k : VS_CLEAR_ROWS - 1;
        for (int r = last; r > at; r--) {
            a[r][0] = a[r - 1][0]; a[r][1] = a[r - 1][1]; a[r][2] = a[r - 1][2];
            b[r] = b[r - 1]; c[r] = c[r - 1];
        }
        a[at][0] = nx;
        a[at][1] = ny;
        a[at][2] = (nx * -ry + ny * rx) / reach_m;
        b[at] = -VS_CLEAR_GAMMA_PER_S * (best - VS_CLEAR_M);
        c[at] = best;
        if (k < VS_CLEAR_ROWS) k++;
    }
    const double td[3] = {twist_in[0], twist_in[1], twist_in[2] * reach_m};
    if (meets((const double (*)[3])a, b, k, td)) return 0;
    double t[3];
    if (!nearest((const double (*)[3])a, b, k, td, t)) {
        /* no twist meets every row (points inside VS_CLEAR_M on opposite sides): hold them, do not push out */
        for (int r = 0; r < k; r++)
            if (b[r] > 0.0) b[r] = 0.0;
        if (!nearest((const double (*)[3])a, b, k, td, t)) t[0] = t[1] = t[2] = 0.0;
    }
    /* never faster than the advance asked, or than the barrier's own push-out (VS_CLEAR_GAMMA_PER_S VS_CLEAR_M): a
     * smaller twist in the same direction still meets every row whose bound is <= 0 and moves out along the others */
    double n_in = sqrt(td[0] * td[0] + td[1] * td[1] + td[2] * td[2]);
    double n_out = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
    double cap = VS_CLEAR_GAMMA_PER_S * VS_CLEAR_M;
    if (n_in > cap) cap = n_in;
    if (n_out > cap) {
        double f = cap / n_out;
        t[0] = f * t[0];
        t[1] = f * t[1];
        t[2] = f * t[2];
    }
    twist_out[0] = t[0];
    twist_out[1] = t[1];
    twist_out[2] = t[2] / reach_m;
    return 1;
}
