/* vs_fit_linf.c - linf: the minimum enclosing circle of the q_i at one angle, exact, with its basis
 * duals (minimax.evaluate), the n = 3 rotation guesses and basis hints (minimax.guesses, kinks), and
 * the descent to a local minimum from n = 4 (minimax.descend). */
#include "vs_fit_linf.h"

#include <math.h>   /* sqrt only (and the INFINITY / NAN macros) */
#include <string.h> /* memset */

#define WS 6

typedef struct { double cx, cy, r2, lam[3]; int mem[3]; } circle_t;

/* minimax._circle on points (X[ids[i]], Y[ids[i]]), i < k (k <= 6): the exact smallest circle. */
static void circle(const double *X, const double *Y, const size_t *ids, int k, circle_t *out)
{
    int first = 1;
    double best = 0.0;
    for (int pass = 0; pass < 2; pass++) {
        for (int i = 0; i < k; i++)
            for (int j = i + 1; j < k; j++)
                for (int l = pass == 0 ? j : j + 1; l < (pass == 0 ? j + 1 : k); l++) {
                    double x0 = X[ids[i]], y0 = Y[ids[i]];
                    double bx = X[ids[j]] - x0, by = Y[ids[j]] - y0;
                    double ex = X[ids[l]] - x0, ey = Y[ids[l]] - y0;
                    double ux, uy, lb, le;
                    if (pass == 0) {
                        ux = 0.5 * bx; uy = 0.5 * by; lb = 0.5; le = 0.0;
                    } else {
                        double det = bx * ey - by * ex;
                        double b2 = bx * bx + by * by, e2 = ex * ex + ey * ey;
                        ux = (ey * b2 - by * e2) / (2.0 * det);
                        uy = (bx * e2 - ex * b2) / (2.0 * det);
                        lb = (ux * ey - uy * ex) / det;
                        le = (bx * uy - by * ux) / det;
                    }
                    double r2 = ux * ux + uy * uy;
                    int ok = lb >= 0.0 && le >= 0.0 && lb + le <= 1.0 && vs_isfinite(r2);
                    double v = ok ? r2 : -1.0;
                    if (first || v > best) {
                        first = 0;
                        best = v;
                        out->cx = x0 + ux; out->cy = y0 + uy; out->r2 = r2;
                        out->lam[0] = 1.0 - lb - le; out->lam[1] = lb; out->lam[2] = le;
                        out->mem[0] = i; out->mem[1] = j; out->mem[2] = l;
                    }
                }
    }
    if (k == 1) {   /* (not reached: n >= 2) */
        out->cx = X[ids[0]]; out->cy = Y[ids[0]]; out->r2 = 0.0;
        out->lam[0] = 1.0; out->lam[1] = out->lam[2] = 0.0;
        out->mem[0] = out->mem[1] = out->mem[2] = 0;
    }
}

/* the k (<= WS) largest of v (n), in ascending index order (ties: the lower index); one pass */
static void largest(const double *v, size_t n, size_t k, size_t *out)
{
    size_t top[WS], cnt = 0;   /* by value descending, then index ascending */
    for (size_t i = 0; i < n; i++) {
        if (cnt == k && !(v[i] > v[top[cnt - 1]])) continue;   /* an equal value: the lower index stays */
        size_t j = cnt < k ? cnt++ : cnt - 1;
        while (j > 0 && v[i] > v[top[j - 1]]) { top[j] = top[j - 1]; j--; }
        top[j] = i;
    }
    for (size_t a = 1; a < cnt; a++) {   /* index order */
        size_t x = top[a], b = a;
        while (b > 0 && top[b - 1] > x) { top[b] = top[b - 1]; b--; }
        top[b] = x;
    }
    for (size_t a = 0; a < cnt; a++) out[a] = top[a];
}

/* max over robots of |q_i - c|^2 (NaN if any is NaN, as np.max); d2: each, or NULL */
static double d2max_of(const double *qx, const double *qy, size_t n, double cx, double cy, double *d2)
{
    double mx = 0.0;
    int nan = 0;
    for (size_t i = 0; i < n; i++) {
        double a = qx[i] - cx, b = qy[i] - cy, v = a * a + b * b;
        if (d2) d2[i] = v;
        if (v != v) nan = 1;
        else if (i == 0 || v > mx) mx = v;
    }
    return nan ? NAN : mx;
}

/* radius of the smallest circle of three points; -inf where its rounding is not clearly small */
static double mec3(double ax, double ay, double bx, double by, double cx, double cy)
{
    double ux = bx - ax, uy = by - ay, vx = cx - ax, vy = cy - ay, zx = cx - bx, zy = cy - by;
    double a2 = zx * zx + zy * zy, b2 = vx * vx + vy * vy, c2 = ux * ux + uy * uy;   /* opposite a, b, c */
    double m2 = a2 > b2 ? (a2 > c2 ? a2 : c2) : (b2 > c2 ? b2 : c2);
    double da = ux * vx + uy * vy, db = -(ux * zx + uy * zy), dc = vx * zx + vy * zy;   /* angle cosines' signs */
    if (da <= 0.0 || db <= 0.0 || dc <= 0.0) return 0.5 * sqrt(m2);   /* right or obtuse: the longest side */
    double X = ux * vy - uy * vx;
    if (vs_fabs(X) < 1e-3 * m2) return -INFINITY;   /* thin: leave it to the pairs */
    return sqrt(a2 * b2 * c2 / (4.0 * X * X));
}

/* f(th) >= w (R_P(S) - max_i |Q_i - Q_a|) and the same with P and Q swapped, for the triple S = (a, b, c):
 * R_P(S), the radius of S's template points, does not depend on th (|q_i - t| >= |R P_i + t - Q_a| - |Q_i - Q_a|). */
static double triple_floor(const vs_prob *pr, const size_t *m, double w)
{
    const double *X[2] = {pr->Px, pr->Qx}, *Y[2] = {pr->Py, pr->Qy};
    double best = -INFINITY;
    for (int side = 0; side < 2; side++) {
        const double *x = X[side], *y = Y[side], *ox = X[1 - side], *oy = Y[1 - side];
        double R = mec3(x[m[0]], y[m[0]], x[m[1]], y[m[1]], x[m[2]], y[m[2]]);
        double dev = 0.0;
        for (int i = 1; i < 3; i++) {
            double dx = ox[m[i]] - ox[m[0]], dy = oy[m[i]] - oy[m[0]], d = sqrt(dx * dx + dy * dy);
            if (d > dev) dev = d;
        }
        double v = w * ((R - dev) - 1e-11 * R - 64.0 * VS_EPS * pr->bound);   /* X: relative error <= ~4e3 eps */
        if (v > best) best = v;
    }
    return best;
}

void vs_fit_eval_linf(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out)
{
    size_t n = pr->n;
    double *qx = pr->sc, *qy = qx + n, *d2 = qy + n;
    size_t *ws = pr->si;
    size_t k = n < WS ? n : WS;
    for (size_t i = 0; i < n; i++) {
        qx[i] = pr->Qx[i] - (c * pr->Px[i] - s * pr->Py[i]);
        qy[i] = pr->Qy[i] - (s * pr->Px[i] + c * pr->Py[i]);
    }
    circle_t C;
    if (k == n) {
        for (size_t i = 0; i < n; i++) ws[i] = i;
    } else {
        for (size_t i = 0; i < n; i++) {
            double a = qx[i] - tx0, b = qy[i] - ty0;
            d2[i] = a * a + b * b;
        }
        largest(d2, n, k, ws);
    }
    circle(qx, qy, ws, (int)k, &C);
    size_t mem[3] = {ws[C.mem[0]], ws[C.mem[1]], ws[C.mem[2]]};
    double dmax = d2max_of(qx, qy, n, C.cx, C.cy, NULL);
    int act0 = dmax > C.r2 * (1.0 + 16.0 * VS_EPS) && !rough;
    if (k < n && act0) {
        for (size_t round = 0; round < n; round++) {
            double mx = d2max_of(qx, qy, n, C.cx, C.cy, d2);
            if (!(mx > C.r2 * (1.0 + 16.0 * VS_EPS))) break;
            size_t w6[6];
            w6[0] = mem[0]; w6[1] = mem[1]; w6[2] = mem[2];
            largest(d2, n, 3, w6 + 3);
            circle(qx, qy, w6, 6, &C);
            mem[0] = w6[C.mem[0]]; mem[1] = w6[C.mem[1]]; mem[2] = w6[C.mem[2]];
        }
        dmax = d2max_of(qx, qy, n, C.cx, C.cy, NULL);
    }
    double w = pr->w[0];
    double dx[3], dy[3], lam[3], kx[3], ky[3];
    for (int i = 0; i < 3; i++) { dx[i] = qx[mem[i]] - C.cx; dy[i] = qy[mem[i]] - C.cy; lam[i] = C.lam[i]; }
    if (lam[2] > 0.0) {
        double cr0 = dx[1] * dy[2] - dy[1] * dx[2];
        double cr1 = dx[2] * dy[0] - dy[2] * dx[0];
        double cr2 = dx[0] * dy[1] - dy[0] * dx[1];
        double sum = cr0 + cr1 + cr2;
        lam[0] = cr0 / sum; lam[1] = cr1 / sum; lam[2] = cr2 / sum;
    }
    double rad = sqrt(C.r2);
    double sc = rad > 0.0 ? w / rad : 0.0;
    for (int i = 0; i < 3; i++) { kx[i] = sc * lam[i] * dx[i]; ky[i] = sc * lam[i] * dy[i]; }
    double K, A, B;
    vs_fit_minorant(pr, kx, ky, mem, 3, &K, &A, &B);
    double D0 = pr->Px[mem[0]] - pr->Px[mem[1]], D1 = pr->Py[mem[0]] - pr->Py[mem[1]];
    double D2 = pr->Qx[mem[0]] - pr->Qx[mem[1]], D3 = pr->Qy[mem[0]] - pr->Qy[mem[1]];
    double dq = sqrt(D2 * D2 + D3 * D3), dp = sqrt(D0 * D0 + D1 * D1);
    double cst = 0.5 * w * (vs_fabs(dq - dp) - 16.0 * VS_EPS * pr->bound);
    if (lam[2] == 0.0 && cst >= K - A * c - B * s) { K = cst; A = 0.0; B = 0.0; }
    out->Kc = cst;   /* half a pair's distance bounds f at every angle (the search's floor) */
    if (mem[1] != mem[2]) {
        double t = triple_floor(pr, mem, w);
        if (t > out->Kc) out->Kc = t;
    }
    out->f = w * sqrt(dmax);
    out->tx = C.cx;
    out->ty = C.cy;
    out->K = K; out->A = A; out->B = B;
    out->e[0] = (double)mem[0]; out->e[1] = (double)mem[1]; out->e[2] = (double)mem[2];
}

/* ---- the basis's radius along th (minimax._r2) */

typedef struct { double px[3], py[3], qx[3], qy[3]; int pair; } basis_pq;

static void basis_load(const vs_prob *pr, const int *b, basis_pq *o)
{
    for (int i = 0; i < 3; i++) {
        o->px[i] = pr->Px[b[i]]; o->py[i] = pr->Py[b[i]]; o->qx[i] = pr->Qx[b[i]]; o->qy[i] = pr->Qy[b[i]];
    }
    o->pair = b[1] == b[2];
}

static double r2_at(const basis_pq *b, double th)
{
    double c, s;
        vs_sincos(th, &s, &c);
    double ax = b->qx[0] - (c * b->px[0] - s * b->py[0]), ay = b->qy[0] - (s * b->px[0] + c * b->py[0]);
    double bx = b->qx[1] - (c * b->px[1] - s * b->py[1]), by = b->qy[1] - (s * b->px[1] + c * b->py[1]);
    double ex = b->qx[2] - (c * b->px[2] - s * b->py[2]), ey = b->qy[2] - (s * b->px[2] + c * b->py[2]);
    double d1 = (bx - ax) * (bx - ax) + (by - ay) * (by - ay);
    if (b->pair) return 0.25 * d1;
    double X = (bx - ax) * (ey - ay) - (by - ay) * (ex - ax);
    if (X == 0.0) return INFINITY;
    return d1 * ((ex - ax) * (ex - ax) + (ey - ay) * (ey - ay)) * ((ex - bx) * (ex - bx) + (ey - by) * (ey - by))
           / (4.0 * X * X);
}

static double diff_at(const basis_pq *a, const basis_pq *b, double th) { return r2_at(a, th) - r2_at(b, th); }

/* minimax._root: Illinois regula falsi for r2(a) - r2(b) on [x0, x1]; 0 without a sign change */
static int root(const basis_pq *pa, const basis_pq *pb, double a, double b, double *out)
{
    double fa = diff_at(pa, pb, a), fb = diff_at(pa, pb, b);
    double df = fa - fb;
    if (!(fa * fb < 0.0) || (vs_isnan(df) == 0 && !vs_isfinite(df))) return 0;
    int side = 0, k = 0;
    while (vs_fabs(b - a) > 1e-15 * (1.0 + vs_fabs(b)) && fb != 0.0 && k < 60) {
        double x = (a * fb - b * fa) / (fb - fa);
        k++;
        double fx = diff_at(pa, pb, x);
        if (fx * fb < 0.0) { a = b; fa = fb; side = 0; }
        else if (side) fa *= 0.5;
        else side = 1;
        b = x; fb = fx;
    }
    *out = b;
    return 1;
}

static double acos_(double x) { return vs_atan2(sqrt((1.0 - x) * (1.0 + x)), x); }

static void sort_dedupe(double *v, int *n, double gap)
{
    for (int i = 1; i < *n; i++) {
        double x = v[i];
        int j = i - 1;
        while (j >= 0 && v[j] > x) { v[j + 1] = v[j]; j--; }
        v[j + 1] = x;
    }
    int k = 0;
    for (int i = 0; i < *n; i++)
        if (i == 0 || v[i] - v[i - 1] > gap) v[k++] = v[i];
    *n = k;
}

int vs_fit_linf_guesses(const vs_prob *pr, double th0, const int *basis, double *out)
{
    if (basis == NULL && pr->n != 3) return 0;
    int rows[3] = {0, 1, 2};
    if (basis) { rows[0] = basis[0]; rows[1] = basis[1]; rows[2] = basis[2]; }
    double P[3][2], Q[3][2];
    for (int i = 0; i < 3; i++) {
        P[i][0] = pr->Px[rows[i]]; P[i][1] = pr->Py[rows[i]]; Q[i][0] = pr->Qx[rows[i]]; Q[i][1] = pr->Qy[rows[i]];
    }
    static const int AB[3][2] = {{0, 1}, {0, 2}, {1, 2}};
    double al[3], u[3], v[3], D[3][2], E[3][2], align[3];
    for (int k = 0; k < 3; k++) {
        int a = AB[k][0], b = AB[k][1];
        D[k][0] = Q[b][0] - Q[a][0]; D[k][1] = Q[b][1] - Q[a][1];
        E[k][0] = P[b][0] - P[a][0]; E[k][1] = P[b][1] - P[a][1];
        u[k] = D[k][0] * E[k][0] + D[k][1] * E[k][1];
        v[k] = E[k][0] * D[k][1] - E[k][1] * D[k][0];
        al[k] = D[k][0] * D[k][0] + D[k][1] * D[k][1] + E[k][0] * E[k][0] + E[k][1] * E[k][1];
        align[k] = vs_atan2(v[k], u[k]);
    }
    if (basis && basis[1] == basis[2]) { out[0] = align[0]; return 1; }
    double kap = D[0][0] * D[1][1] - D[0][1] * D[1][0] + E[0][0] * E[1][1] - E[0][1] * E[1][0];
    double xc = D[0][0] * E[1][1] - D[0][1] * E[1][0] + E[0][0] * D[1][1] - E[0][1] * D[1][0];
    double xs = D[0][0] * E[1][0] + D[0][1] * E[1][1] - E[0][0] * D[1][0] - E[0][1] * D[1][1];
    double starts[7];
    int ns = 0, no = 0;
    starts[ns++] = th0;
    if (!basis) {
        for (int k = 0; k < 3; k++) out[no++] = align[k];
        for (int k = 0; k < 3; k++) {
            int a = AB[k][0], b = AB[k][1];
            double du = u[a] - u[b], dv = v[a] - v[b], h = 0.5 * (al[a] - al[b]);
            double rho = vs_hypot(du, dv);
            if (rho > vs_fabs(h)) {
                double base = vs_atan2(dv, du), half = acos_(h / rho);
                starts[ns++] = base - half;
                starts[ns++] = base + half;
            }
        }
    }
    for (int q = 0; q < ns; q++) {
        double th = starts[q];
        int broke = 0;
        for (int it = 0; it < 12; it++) {
            double c, s;
        vs_sincos(th, &s, &c);
            double X = kap - c * xc - s * xs;
            if (X == 0.0) { broke = 1; break; }
            double dx = 2.0 * (s * xc - c * xs) / X;
            double d1 = -dx, d2 = 0.5 * dx * dx - 2.0 * (kap - X) / X;
            for (int k = 0; k < 3; k++) {
                double a2 = al[k] - 2.0 * (c * u[k] + s * v[k]);
                if (a2 == 0.0) { broke = 1; break; }
                double g = 2.0 * (s * u[k] - c * v[k]) / a2;
                d1 = d1 + g;
                d2 = d2 + (al[k] - a2) / a2 - g * g;
            }
            if (broke) break;
            if (!(d2 > 0.0)) break;
            double r = d1 / d2, mn = r < 0.2 ? r : 0.2, st = mn > -0.2 ? mn : -0.2;
            th -= st;
            if (vs_fabs(st) <= 1e-10) { out[no++] = th; break; }
        }
        if (broke) break;
    }
    sort_dedupe(out, &no, 1e-9);
    return no;
}

static void sort3(int *b)
{
    for (int i = 1; i < 3; i++) {
        int x = b[i], j = i - 1;
        while (j >= 0 && b[j] > x) { b[j + 1] = b[j]; j--; }
        b[j + 1] = x;
    }
}

int vs_fit_linf_kinks(const vs_prob *pr, double tha, const double *ea, double thb, const double *eb, double *out)
{
    int ba[3] = {(int)ea[0], (int)ea[1], (int)ea[2]}, bb[3] = {(int)eb[0], (int)eb[1], (int)eb[2]};
    sort3(ba);
    sort3(bb);
    double lo = tha < thb ? tha : thb, hi = tha < thb ? thb : tha;
    double g[16];
    int ng = vs_fit_linf_guesses(pr, tha, ba, g), no = 0;
    for (int i = 0; i < ng; i++)
        if (lo < g[i] && g[i] < hi) out[no++] = g[i];
    basis_pq pa, pb;
    basis_load(pr, ba, &pa);
    basis_load(pr, bb, &pb);
    double r;
    if (root(&pa, &pb, tha, thb, &r) && lo < r && r < hi) out[no++] = r;
    return no;
}

/* ---- the descent (minimax._mec, _basis, descend) */

typedef struct { int key[3]; double cx, cy, r2; } mec_t;

static void mec(const int *ids, int k, const double *qx, const double *qy, int new_, mec_t *res)
{
    mec_t o[12];
    int no = 0;
    o[no].key[0] = o[no].key[1] = o[no].key[2] = ids[0];
    o[no].cx = qx[ids[0]]; o[no].cy = qy[ids[0]]; o[no].r2 = 0.0;
    no++;
    for (int sz = 2; sz <= 3; sz++)
        for (int a = 0; a < k; a++)
            for (int b = a + 1; b < k; b++)
                for (int c = sz == 2 ? b : b + 1; c < (sz == 2 ? b + 1 : k); c++) {
                    if (new_ >= 0 && new_ != ids[a] && new_ != ids[b] && new_ != ids[c]) continue;
                    double ax = qx[ids[a]], ay = qy[ids[a]], bx = qx[ids[b]], by = qy[ids[b]];
                    double cx, cy;
                    mec_t *m = &o[no++];
                    if (sz == 2) {
                        cx = 0.5 * (ax + bx); cy = 0.5 * (ay + by);
                        m->key[0] = ids[a]; m->key[1] = ids[b]; m->key[2] = ids[b];
                    } else {
                        bx = bx - ax; by = by - ay;
                        double ex = qx[ids[c]] - ax, ey = qy[ids[c]] - ay;
                        double det = 2.0 * (bx * ey - by * ex);
                        if (det == 0.0) det = INFINITY;
                        double b2 = bx * bx + by * by, e2 = ex * ex + ey * ey;
                        cx = ax + (ey * b2 - by * e2) / det;
                        cy = ay + (bx * e2 - ex * b2) / det;
                        m->key[0] = ids[a]; m->key[1] = ids[b]; m->key[2] = ids[c];
                    }
                    m->cx = cx; m->cy = cy;
                    m->r2 = (ax - cx) * (ax - cx) + (ay - cy) * (ay - cy);
                }
    for (int i = 1; i < no; i++) {   /* stable sort by r2 */
        mec_t x = o[i];
        int j = i - 1;
        while (j >= 0 && o[j].r2 > x.r2) { o[j + 1] = o[j]; j--; }
        o[j + 1] = x;
    }
    for (int i = 0; i < no; i++) {
        int in = 1;
        for (int p = 0; p < k && in; p++) {
            double dx = qx[ids[p]] - o[i].cx, dy = qy[ids[p]] - o[i].cy;
            if (!(dx * dx + dy * dy <= o[i].r2 * (1.0 + 1e-12))) in = 0;
        }
        if (in) { *res = o[i]; return; }
    }
    *res = o[no - 1];
}

static int add_sorted(int *ids, int k, int v)
{
    for (int i = 0; i < k; i++)
        if (ids[i] == v) return k;
    int j = k - 1;
    while (j >= 0 && ids[j] > v) { ids[j + 1] = ids[j]; j--; }
    ids[j + 1] = v;
    return k + 1;
}

/* _basis at one angle from a warm basis (nb < 0: none) and a robot new_ outside it (-1: none) */
static void basis_at(const vs_prob *pr, double th, const int *basis, int new_, int out[3], double *cx, double *cy)
{
    size_t n = pr->n;
    double *qx = pr->sc, *qy = qx + n;
    double c, s;
        vs_sincos(th, &s, &c);
    for (size_t i = 0; i < n; i++) {
        qx[i] = pr->Qx[i] - (c * pr->Px[i] - s * pr->Py[i]);
        qy[i] = pr->Qy[i] - (s * pr->Px[i] + c * pr->Py[i]);
    }
    int ids[4], k = 0;
    if (basis) for (int i = 0; i < 3; i++) k = add_sorted(ids, k, basis[i]);
    if (new_ >= 0) k = add_sorted(ids, k, new_);
    if (k == 0) {
        size_t a = 0;
        double best = 0.0;
        for (size_t i = 0; i < n; i++) {
            double v = qx[i] * qx[i] + qy[i] * qy[i];
            if (i == 0 || v > best) { best = v; a = i; }
        }
        ids[k++] = (int)a;
    }
    int j = new_;
    double r0 = -1.0;
    mec_t m;
    memset(&m, 0, sizeof m);   /* the loop below sets it at least once (gcc -O1 -fsanitize=thread cannot tell) */
    for (size_t guard = 0; guard < 4 * n + 16; guard++) {
        mec(ids, k, qx, qy, j, &m);
        size_t a = 0;
        double best = 0.0;
        for (size_t i = 0; i < n; i++) {
            double dx = qx[i] - m.cx, dy = qy[i] - m.cy, v = dx * dx + dy * dy;
            if (i == 0 || v > best) { best = v; a = i; }
        }
        j = (int)a;
        if (best <= m.r2 * (1.0 + 1e-12) || m.r2 <= r0) break;
        k = 0;
        for (int i = 0; i < 3; i++) k = add_sorted(ids, k, m.key[i]);
        k = add_sorted(ids, k, j);
        r0 = m.r2;
    }
    out[0] = m.key[0]; out[1] = m.key[1]; out[2] = m.key[2];
    *cx = m.cx; *cy = m.cy;
}

/* _basis(last=True): the first of xs[0..ns) where basis is not the basis, and the robot outside */
static int basis_last(const vs_prob *pr, const double *xs, int ns, const int *basis, int *far)
{
    size_t n = pr->n;
    int pair = basis[1] == basis[2];
    for (int q = 0; q < ns; q++) {
        double c, s;
        vs_sincos(xs[q], &s, &c);
        double qa[3][2];
        for (int i = 0; i < 3; i++) {
            int r = basis[i];
            qa[i][0] = pr->Qx[r] - (c * pr->Px[r] - s * pr->Py[r]);
            qa[i][1] = pr->Qy[r] - (s * pr->Px[r] + c * pr->Py[r]);
        }
        double ax = qa[0][0], ay = qa[0][1];
        double bx = qa[1][0] - ax, by = qa[1][1] - ay, ex = qa[2][0] - ax, ey = qa[2][1] - ay;
        double det = 2.0 * (bx * ey - by * ex), b2 = bx * bx + by * by, e2 = ex * ex + ey * ey, be = bx * ex + by * ey;
        double ux, uy;
        if (pair) { ux = 0.5 * bx; uy = 0.5 * by; }
        else { ux = (ey * b2 - by * e2) / det; uy = (bx * e2 - ex * b2) / det; }
        double cx = ax + ux, cy = ay + uy;
        double mx = 0.0;
        size_t am = 0;
        int nan = 0;
        for (size_t i = 0; i < n; i++) {
            double qx = pr->Qx[i] - (c * pr->Px[i] - s * pr->Py[i]);
            double qy = pr->Qy[i] - (s * pr->Px[i] + c * pr->Py[i]);
            double dx = qx - cx, dy = qy - cy, v = dx * dx + dy * dy;
            if (v != v) { if (!nan) { nan = 1; am = i; } continue; }
            if (!nan && (i == 0 || v > mx)) { mx = v; am = i; }
        }
        int out = !nan && mx > (ux * ux + uy * uy) * (1.0 + 1e-12);
        int bad = out || (!pair && (be <= 0.0 || b2 <= be || e2 <= be));
        if (bad) {
            *far = out ? (int)am : -1;
            return q;
        }
    }
    *far = -1;
    return ns;
}

int vs_fit_linf_descend(const vs_prob *pr, double th0, double *th_out, double *tx_out, double *ty_out)
{
    const int samples = 16;
    int basis[3];
    double cx, cy;
    double th = th0;
    basis_at(pr, th0, NULL, -1, basis, &cx, &cy);
    for (int step = 0; step < 12; step++) {
        basis_pq r, rn;
        basis_load(pr, basis, &r);
        double down = r2_at(&r, th + 1e-7) > r2_at(&r, th - 1e-7) ? -1.0 : 1.0;
        double g[16], st[16];
        int ng = vs_fit_linf_guesses(pr, th, basis, g), nst = 0;
        for (int i = 0; i < ng; i++) {
            double x = th + vs_fit_remainder(g[i] - th, 2.0 * VS_PI);
            double t = (x - th) * down;
            if (0.0 < t && t < 0.5) st[nst++] = x;
        }
        double target = th + 0.1 * down;
        if (nst) {
            target = st[0];
            for (int i = 1; i < nst; i++)
                if (vs_fabs(st[i] - th) < vs_fabs(target - th)) target = st[i];
        }
        double xs[16];
        for (int k = 0; k < samples; k++) xs[k] = th + (target - th) * (k + 1) / samples;
        int j;
        int k = basis_last(pr, xs, samples, basis, &j);
        int nb[3] = {basis[0], basis[1], basis[2]};
        if (k < samples) basis_at(pr, xs[k], basis, j, nb, &cx, &cy);
        basis_load(pr, nb, &rn);
        double kink = 0.0;
        int have_kink = 0;
        if (k < samples) have_kink = root(&r, &rn, k ? xs[k - 1] : th, xs[k < samples - 1 ? k : samples - 1], &kink);
        double x = have_kink ? kink : target;
        int b2[3] = {nb[0], nb[1], nb[2]};
        if ((k == samples && nst) || (have_kink && r2_at(&rn, kink + 1e-7 * down) >= r2_at(&rn, kink))) {
            basis_at(pr, x + 1e-9 * down, nb, -1, b2, &cx, &cy);
            if (b2[0] == nb[0] && b2[1] == nb[1] && b2[2] == nb[2]) {
                *th_out = x; *tx_out = cx; *ty_out = cy;
                return 1;
            }
        }
        th = have_kink ? kink : xs[k < samples - 1 ? k : samples - 1];
        basis[0] = b2[0]; basis[1] = b2[1]; basis[2] = b2[2];
    }
    *th_out = th0; *tx_out = 0.0; *ty_out = 0.0;
    return 0;
}
