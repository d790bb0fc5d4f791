/* vs_fit.c - the fit's frame: validation, the centred problem, l2 (Procrustes), degenerate cases,
 * the certified search over the rotation (certify.search: minorants, cell bounds, refinement),
 * residuals and cost.  The evaluators are in vs_fit_l1.c and vs_fit_linf.c, the helpers they share
 * with this file in vs_fit_common.c (calls go one way: here -> evaluators -> common).  A port of
 * vsfleet/fit (numpy reference) that follows its steps in the same order; docs/fit.md. */
#include "vs_fit.h"
#include "vs_fit_l1.h"
#include "vs_fit_linf.h"

#include <math.h>   /* sqrt only (and the INFINITY / NAN macros) */
#include <stdlib.h>
#include <string.h>

static const double LOCAL[5] = {1e-6, 1e-3, 4e-3, 1.6e-2, 6.4e-2};
static const double LEAN_OFF[4] = {1e-6, 1e-4, 1e-3, 1e-2};
#define LEAN_GRID 4
#define LEAN_BIG_N 300
#define GRID 8
#define LADDER 6

static double npmax(double a, double b) { return (a != a || b != b) ? a + b : (a > b ? a : b); }

/* The metric's evaluator at one angle: VS_METRIC_L1 vs_fit_l1.c's, VS_METRIC_LINF vs_fit_linf.c's. */
static void evaluate(int metric, const vs_prob *pr, double c, double s, double tx0, double ty0, int rough,
                     vs_ang *out)
{
    if (metric == VS_METRIC_LINF) vs_fit_eval_linf(pr, c, s, tx0, ty0, rough, out);
    else vs_fit_eval_l1(pr, c, s, tx0, ty0, rough, out);
}

/* certify.cell_bounds for one cell (a -> b) */
static double cell_bound(const vs_ang *a, const vs_ang *b, double *bc, double *bs)
{
    double ca = a->c, sa = a->s, cb = b->c, sb = b->s;
    double Ka = a->K, Aa = a->A, Ba = a->B, Kb = b->K, Ab = b->A, Bb = b->B;
    double dK = Ka - Kb, dA = Aa - Ab, dB = Ba - Bb;
    double rho2 = dA * dA + dB * dB;
    double root = sqrt(npmax(rho2 - dK * dK, 0.0));
    double inv = 1.0 / rho2;
    double na = sqrt(Aa * Aa + Ba * Ba), nb = sqrt(Ab * Ab + Bb * Bb);
    double C[6], S[6];
    C[0] = ca; C[1] = cb; C[2] = Aa / na; C[3] = Ab / nb;
    S[0] = sa; S[1] = sb; S[2] = Ba / na; S[3] = Bb / nb;
    C[4] = (dA * dK - dB * root) * inv; C[5] = (dA * dK + dB * root) * inv;
    S[4] = (dB * dK + dA * root) * inv; S[5] = (dB * dK - dA * root) * inv;
    int k = -1;
    double best = 0.0;
    for (int i = 0; i < 6; i++) {
        double v = npmax(Ka - Aa * C[i] - Ba * S[i], Kb - Ab * C[i] - Bb * S[i]);
        int ok = i < 2 || ((ca * S[i] - sa * C[i] >= 0.0) && (C[i] * sb - S[i] * cb >= 0.0) && vs_isfinite(v)
                           && (i < 4 || rho2 >= dK * dK));
        if (!ok) continue;
        if (k < 0 || v < best || (v != v && best == best)) { k = i; best = v; }
    }
    *bc = C[k];
    *bs = S[k];
    double slack = 8.0 * VS_EPS * (vs_fabs(Ka) + vs_fabs(Kb) + na + nb);
    return npmax(best - slack, 0.0);
}

/* ---- the evaluated angles (certify._Angles), sorted by th */

typedef struct { double th; int rough; } ask_t;

typedef struct {
    const vs_prob *pr;
    int metric;   /* VS_METRIC_L1 or VS_METRIC_LINF: whose evaluator */
    double t0x, t0y;
    vs_ang *a;
    size_t m, cap, limit, evals;
    ask_t *ask;
    size_t ask_cap;
    vs_ang *tmp;
    size_t tmp_cap;
} angles_t;

static int cmp_ask(const void *x, const void *y)
{
    const ask_t *a = x, *b = y;
    if (a->th < b->th) return -1;
    if (a->th > b->th) return 1;
    return a->rough - b->rough;
}

/* the tables live in the workspace, sized once (search_tables): room for need, or -1 (never, by the bounds
 * there; a refusal, not an overflow, if they were wrong) */
static int grow(void **p, size_t *cap, size_t need, size_t size)
{
    (void)p;
    (void)size;
    return need <= *cap ? 0 : -1;
}

/* ask sorted by (th, rough) in place, without allocating (qsort may: glibc's merge sort mallocs from 1 KiB).  The
 * order is qsort's: two asks that compare equal are the same bits (th is never -0.0 nor NaN), so any sort gives
 * the same array. */
static int ask_less(const ask_t *a, const ask_t *b) { return cmp_ask(a, b) < 0; }

static void sift_down(ask_t *a, size_t root, size_t end)
{
    for (;;) {
        size_t c = 2 * root + 1;
        if (c >= end) return;
        if (c + 1 < end && ask_less(&a[c], &a[c + 1])) c++;
        if (!ask_less(&a[root], &a[c])) return;
        ask_t t = a[root]; a[root] = a[c]; a[c] = t;
        root = c;
    }
}

static void sort_asks(ask_t *a, size_t n)
{
    if (n < 2) return;
    for (size_t i = n / 2; i-- > 0;) sift_down(a, i, n);
    for (size_t end = n - 1; end > 0; end--) {
        ask_t t = a[0]; a[0] = a[end]; a[end] = t;
        sift_down(a, 0, end);
    }
}

/* evaluate new angles ths (exact) and rough ones; returns how many (>= 0), -1 no memory,
 * -2 the angle budget would be exceeded (nothing evaluated) */
static int angles_add(angles_t *S, const double *ths, size_t nt, const double *rough, size_t nr, int capped)
{
    size_t na = nt + nr;
    if (na == 0) return 0;
    if (grow((void **)&S->ask, &S->ask_cap, na, sizeof(ask_t))) return -1;
    ask_t *ask = S->ask;
    for (size_t i = 0; i < na; i++) {
        double t = i < nt ? ths[i] : rough[i - nt];
        ask[i].th = vs_fit_npmod(t + VS_PI, 2.0 * VS_PI) - VS_PI;
        ask[i].rough = i >= nt;
    }
    sort_asks(ask, na);
    size_t u = 0;
    for (size_t i = 0; i < na; i++)
        if (i == 0 || ask[i].th != ask[u - 1].th) ask[u++] = ask[i];
    size_t m = S->m, k = 0;
    if (m) {
        /* known angles are skipped; rough ones asked exactly are re-solved (removed from the table) */
        for (size_t i = 0; i < u; i++) {
            size_t lo = 0, hi = m;
            while (lo < hi) { size_t mid = (lo + hi) / 2; if (S->a[mid].th < ask[i].th) lo = mid + 1; else hi = mid; }
            size_t at = lo < m - 1 ? lo : m - 1;
            int known = S->a[at].th == ask[i].th;
            int redo = known && S->a[at].rough > 0.0 && !ask[i].rough;
            if (redo) S->a[at].rough = -1.0;   /* mark for removal */
            if (!known || redo) ask[k++] = ask[i];
        }
        size_t j = 0;
        for (size_t i = 0; i < m; i++)
            if (S->a[i].rough >= 0.0) S->a[j++] = S->a[i];
        S->m = m = j;
    } else {
        k = u;
    }
    if (k == 0) return 0;
    if (capped && S->evals + k > S->limit) return -2;
    if (grow((void **)&S->tmp, &S->tmp_cap, k, sizeof(vs_ang))) return -1;
    if (grow((void **)&S->a, &S->cap, m + k, sizeof(vs_ang))) return -1;
    for (size_t i = 0; i < k; i++) {
        double th = ask[i].th, tx0 = S->t0x, ty0 = S->t0y;
        if (m) {
            /* the nearest kept angle on the circle (the first index among equal gaps): the table is
             * sorted, so it is one of th's neighbours, or an end (across the wrap) */
            size_t lo = 0, hi = m;
            while (lo < hi) { size_t mid = (lo + hi) / 2; if (S->a[mid].th < th) lo = mid + 1; else hi = mid; }
            size_t cand[4] = {0, lo > 0 ? lo - 1 : 0, lo < m ? lo : m - 1, m - 1};
            size_t best = 0;
            double bg = 0.0;
            for (int q = 0; q < 4; q++) {
                size_t o = cand[q];
                double gap = vs_fabs(vs_fit_npmod(th - S->a[o].th + VS_PI, 2.0 * VS_PI) - VS_PI);
                if (q == 0 || gap < bg || (gap == bg && o < best)) { bg = gap; best = o; }
            }
            tx0 = S->a[best].tx;
            ty0 = S->a[best].ty;
        }
        vs_ang *o = &S->tmp[i];
        o->th = th;
        vs_sincos(th, &o->s, &o->c);
        o->e[0] = o->e[1] = o->e[2] = 0.0;
        evaluate(S->metric, S->pr, o->c, o->s, tx0, ty0, ask[i].rough, o);
        o->rough = ask[i].rough ? 1.0 : 0.0;
    }
    S->evals += k;
    /* merge (the new angles differ from every kept one) */
    size_t i = m, j = k, w = m + k;
    while (j > 0) {
        if (i > 0 && S->a[i - 1].th > S->tmp[j - 1].th) S->a[--w] = S->a[--i];
        else S->a[--w] = S->tmp[--j];
    }
    S->m = m + k;
    return (int)k;
}

/* ---- certify._centres: guesses of the minimiser in the cell from th[b] towards side, as offsets */

static double pymax(double a, double b) { return b > a ? b : a; }

static int centres(const vs_ang *A, size_t m, const double *g, size_t b, int side, double cut, double *kept)
{
    size_t o = (b + m + side) % m, p = (b + m - side) % m;
    const double twopi = 2.0 * VS_PI;
    double xo = vs_fit_remainder(A[o].th - A[b].th, twopi);
    double xp = vs_fit_remainder(A[p].th - A[b].th, twopi);
    double d1 = (g[o] - g[b]) / xo;
    double d2 = ((g[p] - g[b]) / xp - d1) / (xp - xo);
    double t = d1 - d2 * xo;
    double disc = sqrt(pymax(t * t - 4.0 * d2 * g[b], 0.0));
    double cand[12];
    int nc = 0;
    cand[nc++] = cut;
    double roots[5];
    roots[0] = -g[b] / d1;
    roots[1] = (d2 * xo - d1 - disc) / (2.0 * d2);
    roots[2] = (d2 * xo - d1 + disc) / (2.0 * d2);
    double sec = (A[o].f - A[b].f) / xo;
    double h2 = (3.0 * sec - 2.0 * g[b] - g[o]) / xo, h3 = (g[b] + g[o] - 2.0 * sec) / (xo * xo);
    double dh = sqrt(pymax(h2 * h2 - 3.0 * h3 * g[b], 0.0));
    roots[3] = (-h2 - dh) / (3.0 * h3);
    roots[4] = (-h2 + dh) / (3.0 * h3);
    for (int i = 0; i < 5; i++) cand[nc++] = side * roots[i];
    /* arms' curvatures */
    size_t oo = (o + m + side) % m;
    double kb, ko;
    {
        double dth = vs_fit_remainder(A[p].th - A[b].th, twopi);
        kb = g[b] * g[p] > 0.0 ? (g[p] - g[b]) / dth : 0.0;
        dth = vs_fit_remainder(A[oo].th - A[o].th, twopi);
        ko = g[o] * g[oo] > 0.0 ? (g[oo] - g[o]) / dth : 0.0;
    }
    double qa = 0.5 * (kb - ko);
    double qb = g[b] - g[o] + ko * xo;
    double qc = A[b].f - A[o].f + g[o] * xo - 0.5 * ko * xo * xo;
    if (vs_fabs(qa) * xo * xo <= 1e-3 * vs_fabs(qb * xo)) {
        cand[nc++] = side * (-qc / qb);
    } else {
        double dq = sqrt(pymax(qb * qb - 4.0 * qa * qc, 0.0));
        cand[nc++] = side * ((-qb - dq) / (2.0 * qa));
        cand[nc++] = side * ((-qb + dq) / (2.0 * qa));
    }
    double width = vs_fabs(xo);
    double in[12];
    int ni = 0;
    for (int i = 0; i < nc; i++)
        if (0.0 < cand[i] && cand[i] < width) in[ni++] = cand[i];
    for (int i = 1; i < ni; i++) {   /* insertion sort (stable) */
        double x = in[i];
        int j = i - 1;
        while (j >= 0 && in[j] > x) { in[j + 1] = in[j]; j--; }
        in[j + 1] = x;
    }
    int nk = 0;
    for (int i = 0; i < ni; i++) {
        double x = in[i], mn = x < width - x ? x : width - x;
        if (nk == 0 || x - kept[nk - 1] > 1e-3 * mn) kept[nk++] = x;
    }
    return nk;
}

typedef struct { double *v; size_t n, cap; int err; } dvec;

static void push(dvec *d, double x)
{
    if (d->err) return;
    if (grow((void **)&d->v, &d->cap, d->n + 1, sizeof(double))) { d->err = 1; return; }
    d->v[d->n++] = x;
}

/* A lower bound of f at every angle (not in the reference; it only ends a search the sinusoids
 * cannot, where f is flat: near-coincident robots or template points; the search also raises it
 * to the best constant minorant an evaluation gave, linf's pair bound, which the reference uses
 * only where it beats the sinusoid at its own angle).  For any t and th,
 * |Q_i - R P_i - t| >= |R P_i + t| - |Q_i|, so f(th) >= g_P - (sum w |Q_i| (l1) or w max |Q_i| (linf))
 * with g_P the optimal cost of the template points alone, which no rotation changes; likewise with
 * P and Q swapped.  g_P is bounded below by the evaluator's own weak-duality minorant for the
 * problem (P, 0) at one angle.  -inf if neither helps.  zero: n doubles of workspace. */
static double flat_bound(const vs_prob *pr, int metric, double *zero)
{
    size_t n = pr->n;
    for (size_t i = 0; i < n; i++) zero[i] = 0.0;
    double best = -INFINITY, sp = 0.0, sq = 0.0, mp = 0.0, mq = 0.0;
    int linf = metric == VS_METRIC_LINF;
    for (size_t i = 0; i < n; i++) {
        double a = sqrt(pr->Px[i] * pr->Px[i] + pr->Py[i] * pr->Py[i]);
        double b = sqrt(pr->Qx[i] * pr->Qx[i] + pr->Qy[i] * pr->Qy[i]);
        sp += pr->w[i] * a; sq += pr->w[i] * b;
        if (a > mp) mp = a;
        if (b > mq) mq = b;
    }
    for (int side = 0; side < 2; side++) {
        vs_prob sub = *pr;
        double rest;
        if (side == 0) { sub.Qx = zero; sub.Qy = zero; rest = linf ? pr->w[0] * mq : sq; }
        else { sub.Px = zero; sub.Py = zero; rest = linf ? pr->w[0] * mp : sp; }
        vs_ang a;
        a.e[0] = a.e[1] = a.e[2] = 0.0;
        /* (P, 0) at th = pi: q_i = P_i; (0, Q) at th = 0: q_i = Q_i */
        double c = side == 0 ? -1.0 : 1.0;
        evaluate(metric, &sub, c, 0.0, 0.0, 0.0, 0, &a);
        double g = a.K - a.A * c;
        double v = g - rest - 64.0 * VS_EPS * (pr->bound * pr->W + rest);
        if (v > best) best = v;
    }
    return best;
}

/* ---- the workspace (vs_fit_work_f64): the fit's arrays, then the search's tables, each sized once from the
 * number of points k and the metric */

#define SLOTS(bytes) (((bytes) + sizeof(double) - 1) / sizeof(double))   /* doubles that hold `bytes` */

/* the angles a search may evaluate (its work cap; S.limit) */
static size_t search_limit(size_t k)
{
    return VS_FIT_WORK / k > VS_FIT_MIN_ANGLES ? VS_FIT_WORK / k : VS_FIT_MIN_ANGLES;
}

/* The angles one batch may ask, at most.  The table never holds more than limit angles (m <= evals <= limit: the
 * first batch, <= 3 * 5 + 16 * 3 * LADDER + GRID angles, is below any limit, and later batches stop at it), so a
 * round has at most limit bad cells, each asking its split point, itself and its successor (when rough) and 2 nlv
 * splits; each side of the best angle adds at most 24 hints or 12 centres, each 3 LADDER or 2 (nlev + 1 <= 9)
 * angles. */
static size_t search_nw_cap(size_t k, int metric)
{
    size_t nlv = metric == VS_METRIC_LINF ? (size_t)VS_LINF_SPLIT / k : 0;
    return search_limit(k) * (3 + 2 * nlv) + 2 * 24 * 3 * LADDER;
}

/* the search's tables for k points (without zero, k doubles): never more as k grows */
static size_t search_tables(size_t k, int metric)
{
    size_t L = search_limit(k), nw = search_nw_cap(k, metric);
    return 2 * SLOTS(L * sizeof(vs_ang)) + SLOTS((nw + GRID) * sizeof(ask_t)) + nw + 4 * L + SLOTS(L * sizeof(size_t));
}

/* the workspace of one fit of exactly k kept points (the search's tables only where a search can run) */
static size_t fit_need(size_t k, int metric)
{
    size_t w = 9 * k + (size_t)VS_FIT_SCRATCH * k + SLOTS(8 * k * sizeof(size_t));
    if (metric != VS_METRIC_L2 && k >= 3) w += k + search_tables(k, metric);
    return w;
}

size_t vs_fit_work_f64(size_t n, int metric)
{
    if (n == 0 || metric < VS_METRIC_L1 || metric > VS_METRIC_LINF) return 0;
    if (n > ((size_t)-1 / sizeof(double) - search_tables(3, VS_METRIC_LINF)) / 64) return (size_t)-1;   /* overflow */
    size_t w = 9 * n + (size_t)VS_FIT_SCRATCH * n + SLOTS(8 * n * sizeof(size_t));
    if (metric != VS_METRIC_L2 && n >= 3) w += n + search_tables(3, metric);   /* any k in 3..n: k = 3's tables */
    return w;
}

/* the search's tables, carved from the workspace */
typedef struct {
    double *zero;
    vs_ang *a, *tmp;
    ask_t *ask;
    double *nw, *lb, *bc, *bs, *g;
    size_t *bad;
    size_t limit, nw_cap;
} search_ws;

static void carve_search(double *p, size_t k, int metric, search_ws *W)
{
    size_t L = search_limit(k), nw = search_nw_cap(k, metric);
    W->limit = L;
    W->nw_cap = nw;
    W->zero = p; p += k;
    W->a = (vs_ang *)(void *)p; p += SLOTS(L * sizeof(vs_ang));
    W->tmp = (vs_ang *)(void *)p; p += SLOTS(L * sizeof(vs_ang));
    W->ask = (ask_t *)(void *)p; p += SLOTS((nw + GRID) * sizeof(ask_t));
    W->nw = p; p += nw;
    W->lb = p; p += L;
    W->bc = p; p += L;
    W->bs = p; p += L;
    W->g = p; p += L;
    W->bad = (size_t *)(void *)p;
}

/* certify.search: (th, centred tx, ty, lower bound); rounds out.  Its tables are W's (carve_search). */
static int search(const vs_prob *pr, int metric, double th0, const double *guess, int ng, int split,
                  double t0x, double t0y, int lean, int refine, const search_ws *W, double *th_out, double *tx_out,
                  double *ty_out, double *lower_out, int *rounds_out)
{
    size_t n = pr->n;
    angles_t S;
    memset(&S, 0, sizeof S);
    S.pr = pr; S.metric = metric; S.t0x = t0x; S.t0y = t0y;
    S.limit = search_limit(n);
    S.a = W->a; S.cap = W->limit;
    S.tmp = W->tmp; S.tmp_cap = W->limit;
    S.ask = W->ask; S.ask_cap = W->nw_cap + GRID;
    dvec nw = {W->nw, 0, W->nw_cap, 0};
    double *lb = W->lb, *bc = W->bc, *bs = W->bs, *g = W->g;
    size_t *bad = W->bad;
    size_t wcap = W->limit;
    int rc = VS_OK, rounds = 0;
    /* the first batch */
    const double *offs;
    int noff, grid;
    double few1[4];
    int nfew;
    if (ng > 0) { few1[0] = LEAN_OFF[3]; nfew = 1; }
    else if (n < LEAN_BIG_N) { memcpy(few1, LEAN_OFF, sizeof LEAN_OFF); nfew = 4; }
    else { few1[0] = LEAN_OFF[0]; few1[1] = LEAN_OFF[3]; nfew = 2; }
    if (lean) { grid = LEAN_GRID; offs = few1; noff = nfew; }
    else { grid = GRID; offs = LOCAL; noff = 5; }
    double step = 2.0 * VS_PI / grid;
    static const double E3[3] = {-1.0, 0.0, 1.0};
    for (int e = 0; e < 3; e++)
        for (int h = 0; h < noff; h++) push(&nw, th0 + E3[e] * offs[h]);
    for (int gi = 0; gi < ng; gi++)
        for (int e = 0; e < 3; e++) {
            double p32 = 1.0;
            for (int k = 0; k < LADDER - lean; k++, p32 *= 32.0) push(&nw, guess[gi] + E3[e] * 1e-9 * p32);
        }
    double rgh[GRID];
    for (int k = 0; k < grid; k++) rgh[k] = -VS_PI + step * k;
    if (nw.err) { rc = VS_ENOMEM; goto done; }
    if (angles_add(&S, nw.v, nw.n, rgh, (size_t)grid, 0) < 0) { rc = VS_ENOMEM; goto done; }
    int nlev = (int)(400 / n);
    if (nlev > 8) nlev = 8;
    if (nlev < 1) nlev = 1;
    int nlv = split / (int)n;
    double frac[16];
    for (int k = 0; k < nlv && k < 8; k++) {
        double v = 1.0;
        for (int j = 0; j <= k; j++) v *= 0.25;
        frac[k] = v;
        frac[nlv + k] = 1.0 - v;
    }
    double flat = flat_bound(pr, metric, W->zero);
    double lower = 0.0;
    for (int round = 0; round < VS_FIT_MAX_ROUNDS; round++) {
        size_t m = S.m;
        const vs_ang *A = S.a;
        if (m > wcap) { rc = VS_ENOMEM; goto done; }   /* never: m <= limit (search_nw_cap) */
        rounds = round + 1;
        size_t b = 0;
        double lbmin = 0.0, kmax = 0.0;
        for (size_t i = 0; i < m; i++)
            if (A[i].Kc > flat) flat = A[i].Kc;
        for (size_t i = 0; i < m; i++) {
            lb[i] = cell_bound(&A[i], &A[(i + 1) % m], &bc[i], &bs[i]);
            if (flat > lb[i]) lb[i] = flat;   /* never moves a cut: it certifies every cell or none */
            if (A[i].f < A[b].f) b = i;
            if (i == 0 || lb[i] < lbmin) lbmin = lb[i];
            double ak = vs_fabs(A[i].K);
            if (i == 0 || ak > kmax) kmax = ak;
        }
        double fbest = A[b].f;
        lower = fbest < lbmin ? fbest : lbmin;
        double tl = 4.0 * 64.0 * VS_EPS * pr->bound * (kmax + 1.0);
        double tol_eff = 0.5 * (tl > VS_FIT_CERT_TOL ? tl : VS_FIT_CERT_TOL);
        double thr = fbest - tol_eff;
        size_t nb = 0;
        for (size_t i = 0; i < m; i++)
            if (lb[i] < thr) bad[nb++] = i;
        if (nb == 0) break;
        nw.n = 0;
        for (size_t i = 0; i < nb; i++) push(&nw, vs_atan2(bs[bad[i]], bc[bad[i]]));
        for (size_t i = 0; i < nb; i++)
            if (A[bad[i]].rough > 0.0) push(&nw, A[bad[i]].th);
        for (size_t i = 0; i < nb; i++) {
            size_t j = (bad[i] + 1) % m;
            if (A[j].rough > 0.0) push(&nw, A[j].th);
        }
        for (size_t i = 0; i < nb; i++) {
            double t = A[bad[i]].th, arc = vs_fit_npmod(A[(bad[i] + 1) % m].th - t, 2.0 * VS_PI);
            for (int k = 0; k < 2 * nlv; k++) push(&nw, t + arc * frac[k]);
        }
        for (size_t i = 0; i < m; i++) g[i] = A[i].A * A[i].s - A[i].B * A[i].c;
        for (int sd = 0; sd < 2; sd++) {
            int side = sd == 0 ? 1 : -1;
            size_t j = sd == 0 ? b : (b + m - 1) % m;
            if (lb[j] >= thr) continue;
            size_t o = (b + m + side) % m;
            double width = vs_fabs(vs_fit_remainder(A[o].th - A[b].th, 2.0 * VS_PI));
            size_t jj = 0;
            while (bad[jj] < j) jj++;
            double cut = vs_fabs(vs_fit_remainder(nw.v[jj] - A[b].th, 2.0 * VS_PI));
            double tb = A[b].th;
            double hints[24];
            int nh = refine ? vs_fit_linf_kinks(pr, tb, A[b].e, tb + side * width, A[o].e, hints) : 0;
            for (int h = 0; h < nh; h++)
                for (int e = 0; e < 3; e++) {
                    double p32 = 1.0;
                    for (int k = 0; k < LADDER; k++, p32 *= 32.0) push(&nw, hints[h] + E3[e] * 1e-9 * p32);
                }
            if (nh == 0) {
                double xs[12];
                int nx = centres(A, m, g, b, side, cut, xs);
                for (int q = 0; q < nx; q++) {
                    double x = xs[q], d = width - x < x ? width - x : x;
                    double lvl = 1.0;
                    for (int h = 0; h <= nlev; h++) {
                        for (int e = -1; e <= 1; e += 2) push(&nw, tb + side * (x + e * d * (h ? lvl : 0.0)));
                        if (h) lvl *= 0.25;
                        else lvl = 0.25;
                    }
                }
            }
        }
        if (nw.err) { rc = VS_ENOMEM; goto done; }
        int added = angles_add(&S, nw.v, nw.n, NULL, 0, 1);
        if (added == -1) { rc = VS_ENOMEM; goto done; }
        if (added <= 0) break;   /* nothing new (cells cannot be split) or the angle budget is spent */
    }
    {
        size_t b = 0;
        for (size_t i = 1; i < S.m; i++)
            if (S.a[i].f < S.a[b].f) b = i;
        *th_out = S.a[b].th; *tx_out = S.a[b].tx; *ty_out = S.a[b].ty;
        *lower_out = lower;
        *rounds_out = rounds;
    }
done:
    return rc;
}

/* procrustes.rotation */
static double l2_rotation(const vs_prob *pr)
{
    double dot = 0.0, cross = 0.0, pp = 0.0, qq = 0.0;
    for (size_t i = 0; i < pr->n; i++) {
        double w = pr->w[i], wpx = w * pr->Px[i], wpy = w * pr->Py[i];
        dot += wpx * pr->Qx[i];
        dot += wpy * pr->Qy[i];
        cross += wpx * pr->Qy[i] - wpy * pr->Qx[i];
        pp += wpx * pr->Px[i];
        pp += wpy * pr->Py[i];
        qq += w * pr->Qx[i] * pr->Qx[i];
        qq += w * pr->Qy[i] * pr->Qy[i];
    }
    double mag = sqrt(pp * qq);
    if (vs_hypot(cross, dot) <= 1e-13 * mag) return 0.0;
    return vs_atan2(cross, dot);
}

/* finite and within VS_FIT_MAX_ABS (NaN fails the comparison) */
static int check_finite(const double *a, size_t k)
{
    for (size_t i = 0; i < k; i++)
        if (!(vs_fabs(a[i]) <= VS_FIT_MAX_ABS)) return 0;
    return 1;
}

int vs_fit_residuals(const double *p, const double *r, size_t n, double x, double y, double th, double *d)
{
    double pose[3] = {x, y, th};
    if (!check_finite(pose, 3) || !check_finite(p, 2 * n) || !check_finite(r, 2 * n))
        return VS_ENONFINITE;
    double c, s;
        vs_sincos(th, &s, &c);
    for (size_t i = 0; i < n; i++) {
        double px = p[2 * i], py = p[2 * i + 1];
        double dx = r[2 * i] - (c * px - s * py + x);
        double dy = r[2 * i + 1] - (s * px + c * py + y);
        d[i] = sqrt(dx * dx + dy * dy);
    }
    return VS_OK;
}

int vs_fit_cost(const double *d, const double *w, size_t n, int metric, double *cost)
{
    if (n == 0 || metric < VS_METRIC_L1 || metric > VS_METRIC_LINF) return VS_EVALUE;
    for (size_t i = 0; i < n; i++)
        if (!vs_isfinite(d[i])) return VS_ENONFINITE;
    if (w && !check_finite(w, n)) return VS_ENONFINITE;
    double acc = 0.0;
    for (size_t i = 0; i < n; i++) {
        double wd = w ? w[i] * d[i] : d[i];
        if (metric == VS_METRIC_L1) acc += wd;
        else if (metric == VS_METRIC_L2) acc += wd * d[i];
        else if (i == 0 || wd > acc) acc = wd;
    }
    *cost = metric == VS_METRIC_L2 ? sqrt(acc) : acc;
    return VS_OK;
}

int vs_fit(const double *tpl, const double *pos, const double *weights, size_t n, int metric, vs_fit_result *out)
{
    return vs_fit_ws(tpl, pos, weights, n, metric, out, NULL);
}

int vs_fit_ws(const double *tpl, const double *pos, const double *weights, size_t n, int metric, vs_fit_result *out,
              double *work)
{
    if (n == 0 || metric < VS_METRIC_L1 || metric > VS_METRIC_LINF || tpl == NULL || pos == NULL || out == NULL)
        return VS_EVALUE;
    if (!check_finite(tpl, 2 * n) || !check_finite(pos, 2 * n) || (weights && !check_finite(weights, n)))
        return VS_ENONFINITE;
    size_t kept = n;
    if (weights) {
        double w0 = 0.0;
        int any = 0;
        kept = 0;
        for (size_t i = 0; i < n; i++) {
            if (weights[i] < 0.0) return VS_EVALUE;
            if (weights[i] > 0.0) {
                if (metric == VS_METRIC_LINF && any && weights[i] != w0) return VS_EVALUE;
                if (!any) w0 = weights[i];
                any = 1;
                kept++;
            }
        }
        if (!any) return VS_EVALUE;
    }
    size_t nd = 9 * kept + (size_t)VS_FIT_SCRATCH * kept;
    double *own = NULL;
    if (work == NULL) {   /* vs_fit: the workspace of this one fit, once */
        size_t need = fit_need(kept, metric);
        if (need > (size_t)-1 / sizeof(double) || (own = work = malloc(need * sizeof(double))) == NULL)
            return VS_ENOMEM;
    }
    double *buf = work;
    size_t *ibuf = (size_t *)(void *)(work + nd);
    double *w = buf, *Px = w + kept, *Py = Px + kept, *Qx = Py + kept, *Qy = Qx + kept;
    double *px = Qy + kept, *py = px + kept, *rx = py + kept, *ry = rx + kept;
    double *sc = ry + kept;
    {
        size_t k = 0;
        for (size_t i = 0; i < n; i++) {
            if (weights && !(weights[i] > 0.0)) continue;
            w[k] = weights ? weights[i] : 1.0;
            px[k] = tpl[2 * i]; py[k] = tpl[2 * i + 1];
            rx[k] = pos[2 * i]; ry[k] = pos[2 * i + 1];
            k++;
        }
    }
    vs_prob pr;
    pr.n = kept; pr.w = w; pr.Px = Px; pr.Py = Py; pr.Qx = Qx; pr.Qy = Qy; pr.sc = sc; pr.si = ibuf;
    {
        double sx = 0.0, sy = 0.0, tx = 0.0, ty = 0.0, W = 0.0;
        for (size_t i = 0; i < kept; i++) {
            if (weights) {
                W += w[i];
                sx += w[i] * px[i]; sy += w[i] * py[i]; tx += w[i] * rx[i]; ty += w[i] * ry[i];
            } else {
                sx += px[i]; sy += py[i]; tx += rx[i]; ty += ry[i];
            }
        }
        if (!weights) W = (double)kept;
        pr.W = W;
        pr.cpx = sx / W; pr.cpy = sy / W; pr.crx = tx / W; pr.cry = ty / W;
        double mp = 0.0, mq = 0.0;
        for (size_t i = 0; i < kept; i++) {
            Px[i] = px[i] - pr.cpx; Py[i] = py[i] - pr.cpy; Qx[i] = rx[i] - pr.crx; Qy[i] = ry[i] - pr.cry;
            double a = sqrt(Qx[i] * Qx[i] + Qy[i] * Qy[i]), b = sqrt(Px[i] * Px[i] + Py[i] * Py[i]);
            if (i == 0 || a > mq) mq = a;
            if (i == 0 || b > mp) mp = b;
        }
        pr.bound = mq + mp;
    }
    int rigid = 1, rigid_q = 1;
    for (size_t i = 1; i < kept; i++) {
        if (Px[i] != Px[0] || Py[i] != Py[0]) rigid = 0;
        if (Qx[i] != Qx[0] || Qy[i] != Qy[0]) rigid_q = 0;
    }
    rigid = rigid || rigid_q;
    double th = 0.0, tx = 0.0, ty = 0.0, lower = 0.0;
    int have_lower = 0, rounds = 0, rc = VS_OK;
    if (kept == 1) {
        th = 0.0;
    } else if (metric == VS_METRIC_L2 || kept == 2 || rigid) {
        th = (metric != VS_METRIC_L2 && rigid) ? 0.0 : l2_rotation(&pr);
        if (metric != VS_METRIC_L2) {
            vs_ang a;
            double c, s;
        vs_sincos(th, &s, &c);
            a.e[0] = a.e[1] = a.e[2] = 0.0;
            evaluate(metric, &pr, c, s, 0.0, 0.0, 0, &a);
            tx = a.tx; ty = a.ty;
            lower = a.K - a.A * c - a.B * s;
            have_lower = 1;
        }
    } else {
        double th0 = l2_rotation(&pr), t0x = 0.0, t0y = 0.0;
        int lean = 0;
        if (metric == VS_METRIC_L1 && kept >= VS_L1_NEWTON_N)
            lean = vs_fit_l1_newton(&pr, th0, &th0, &t0x, &t0y);
        else if (metric == VS_METRIC_LINF && kept > 3)
            lean = vs_fit_linf_descend(&pr, th0, &th0, &t0x, &t0y);
        double guess[16];
        int ng = 0, split = 0;
        if (metric == VS_METRIC_LINF) {
            ng = vs_fit_linf_guesses(&pr, th0, NULL, guess);
            if (ng == 0 && lean) { guess[0] = th0; ng = 1; }
            split = VS_LINF_SPLIT;
        }
        search_ws W;
        carve_search(work + nd + SLOTS(8 * kept * sizeof(size_t)), kept, metric, &W);
        rc = search(&pr, metric, th0, guess, ng, split, t0x, t0y, lean, metric == VS_METRIC_LINF, &W,
                    &th, &tx, &ty, &lower, &rounds);
        have_lower = 1;
    }
    if (rc == VS_OK) {
        /* wrapped until wrapping keeps it (Pose2 wraps again: the cost is at the angle it keeps) */
        double thw = vs_wrap_angle(th);
        for (int k = 0; k < 4 && vs_wrap_angle(thw) != thw; k++) thw = vs_wrap_angle(thw);
        double c, s;
        vs_sincos(thw, &s, &c);
        double x = tx + pr.crx - (c * pr.cpx - s * pr.cpy);
        double y = ty + pr.cry - (s * pr.cpx + c * pr.cpy);
        /* the cost at the world pose, over every robot (zero weights add nothing) */
        double cost = 0.0;
        double c2 = c, s2 = s;
        for (size_t i = 0; i < n; i++) {
            double qx = tpl[2 * i], qy = tpl[2 * i + 1];
            double dx = pos[2 * i] - (c2 * qx - s2 * qy + x);
            double dy = pos[2 * i + 1] - (s2 * qx + c2 * qy + y);
            double d = sqrt(dx * dx + dy * dy), wd = weights ? weights[i] * d : d;
            if (metric == VS_METRIC_L1) cost += wd;
            else if (metric == VS_METRIC_L2) cost += wd * d;
            else if (i == 0 || wd > cost) cost = wd;
        }
        if (metric == VS_METRIC_L2) cost = sqrt(cost);
        out->x = x; out->y = y; out->th = thw;
        out->cost = cost;
        out->cost_lower_bound = have_lower && lower < cost ? lower : cost;
        out->rounds = rounds;
    }
    free(own);
    return rc;
}
