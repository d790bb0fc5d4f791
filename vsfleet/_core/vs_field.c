/* vs_field.c - the structure's navigation function over an SE(2) lattice (vs_field.h), planned once per
 * mission, and its per-frame descent.  Integer costs, fixed neighbour order: the same bits everywhere. */
#if !defined(_POSIX_C_SOURCE) || _POSIX_C_SOURCE < 200112L
#undef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200112L   /* pthreads under -std=c99 */
#endif
#if defined(__linux__) && !defined(_DEFAULT_SOURCE)
#define _DEFAULT_SOURCE 1   /* madvise and MADV_HUGEPAGE under -std=c99 (cost_alloc) */
#endif
#include <stdlib.h>
#include <math.h>
#include <string.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif
#if !defined(VS_FIELD_NO_THREADS)
#include <pthread.h>
#endif

#include "vs_field.h"

#if defined(__SSE2__) && defined(__x86_64__)
#include <emmintrin.h>
#define VS_LOW_WORDS _MM_SHUFFLE(2, 0, 2, 0)   /* 32-bit words 0 and 2: each 64-bit lane's low word */
#endif

/* floor for |v| < 2^62 (the lattice's indices are far smaller: coordinates <= 1e6 m, cells >= 1e-3 m) */
static long long ifloor(double v)
{
    long long t = (long long)v;
    if ((double)t > v) t--;
    return t;
}

/* The cost array of `count` states, or NULL. On Linux, aligned to 2 MiB and offered to the kernel for transparent
 * huge pages (madvise: this host's default mode): an agent builds each mission's field once, into memory it has not
 * touched, and filling 8 MB of small pages took about 4,000 page faults. Memory only: the costs are the same. */
static uint32_t *cost_alloc(size_t count)
{
    if (count > SIZE_MAX / sizeof(uint32_t)) return NULL;
    size_t bytes = sizeof(uint32_t) * count;
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    const size_t huge = (size_t)1 << 21;
    if (bytes >= huge) {
        void *mem = NULL;
        if (posix_memalign(&mem, huge, bytes) != 0) return NULL;
        (void)madvise(mem, bytes, MADV_HUGEPAGE);   /* a hint: refused (EINVAL where THP is off), small pages */
        return mem;
    }
#endif
    return malloc(bytes);
}

/* a field's finer lattice (vs_field_set_refine): its inputs, and its field once built */
struct vs_field_refine {
    double *inputs;          /* one block: the template (2 n), the radii (n), the obstacles (3 m) */
    size_t n, n_obstacles, n_headings, max_states;
    double cell_m;           /* the cell asked of the fine lattice [m] (it grows as the coarse one did) */
    int built;               /* 1: fine holds the finer lattice's field (deferred, as the agents build) */
    vs_field fine;
};

/* the neighbour order, fixed: 8 moves at the same heading, then heading + 1, heading - 1 */

/* every neighbour of state s in the fixed order (8 moves at its heading, then heading + 1, heading - 1), those
 * inside the lattice only: their states in t[], base weights in w[]; returns how many */
static int neighbours_of(const vs_field *f, size_t s, size_t t[10], uint32_t w[10])
{
    /* 32-bit division: the lattice holds < 2^32 states (max_states <= 1e9), and it is several times faster */
    const uint32_t nx = (uint32_t)f->nx, ny = (uint32_t)f->ny, plane = nx * ny, nh = (uint32_t)f->n_headings;
    const uint32_t s32 = (uint32_t)s, k = s32 / plane, rem = s32 - k * plane, row = rem / nx, col = rem - row * nx;
    int e = col + 1 < nx, wst = col > 0, nth = row + 1 < ny, sth = row > 0, c = 0;
    if (e) { t[c] = s + 1; w[c++] = VS_FIELD_W_AXIS; }
    if (wst) { t[c] = s - 1; w[c++] = VS_FIELD_W_AXIS; }
    if (nth) { t[c] = s + nx; w[c++] = VS_FIELD_W_AXIS; }
    if (sth) { t[c] = s - nx; w[c++] = VS_FIELD_W_AXIS; }
    if (e && nth) { t[c] = s + nx + 1; w[c++] = VS_FIELD_W_DIAG; }
    if (wst && nth) { t[c] = s + nx - 1; w[c++] = VS_FIELD_W_DIAG; }
    if (e && sth) { t[c] = s - nx + 1; w[c++] = VS_FIELD_W_DIAG; }
    if (wst && sth) { t[c] = s - nx - 1; w[c++] = VS_FIELD_W_DIAG; }
    t[c] = (size_t)(k + 1 == nh ? 0 : k + 1) * plane + rem; w[c++] = f->w_rot;
    t[c] = (size_t)(k == 0 ? nh - 1 : k - 1) * plane + rem; w[c++] = f->w_rot;
    return c;
}

typedef struct {
    uint32_t *items;
    size_t len, cap;
} bucket;

/* grows a bucket's room (doubling, from 256); the pushes themselves are inline (bucket_push, RELAX) */
static int bucket_grow(bucket *b)
{
    size_t cap = b->cap ? 2 * b->cap : 256;
    uint32_t *p = realloc(b->items, sizeof(uint32_t) * cap);
    if (p == NULL) return VS_ENOMEM;
    b->items = p;
    b->cap = cap;
    return VS_OK;
}

static int bucket_push(bucket *b, uint32_t v)
{
    if (b->len == b->cap && bucket_grow(b) != VS_OK) return VS_ENOMEM;
    b->items[b->len++] = v;
    return VS_OK;
}

/* Dial's algorithm in the cost array itself, from the one state src: a state not reached holds, in its cost bits, a
 * value above any distance (VS_FIELD_UNRESOLVED or SEEN), walls hold VS_FIELD_WALL; a state reached gets
 * (its bits & keep) | its distance, so keep says which of the tight and blocked bits stay.  The same distances as
 * the former Dijkstra over separate distance and tight arrays (exact integers, whatever the order), with one array
 * read a neighbour instead of three.
 * A state off the lattice's border (every neighbour inside) relaxes its 10 neighbours at fixed offsets, without
 * neighbours_of's bounds; its heading, row and column come from a floating-point estimate of the quotient (exact
 * for indices < 2^32 once corrected by one), and the buckets' count is a power of two: no integer division in the
 * loop.  2026-12-07, bench/plan_cost.py's rooms 0-9, a scratch driver, best of 3: the triangle's builds from 54-65
 * to 38-51 ms, the 30 robots' from 27-60 to 27-54 ms, every cost the same bit for bit.
 * VS_ENOMEM: the states written so far keep their distances (the callers start again or fail). */
/* s + plane < 1.25 total (a plane is at most a quarter of the lattice: K >= 4) must not wrap in 32 bits */
typedef char vs_field_states_fit[VS_FIELD_MAX_STATES <= 3000000000u ? 1 : -1];

static int dial_in_place(const vs_field *f, size_t src, uint32_t keep)
{
    uint32_t *cost = f->cost;
    const uint32_t nx = (uint32_t)f->nx, ny = (uint32_t)f->ny, plane = nx * ny;
    const uint32_t total = plane * (uint32_t)f->n_headings, w_rot = f->w_rot;
    const double inv_plane = 1.0 / (double)plane, inv_nx = 1.0 / (double)nx;
    uint32_t wmax = 2 * (w_rot > VS_FIELD_W_DIAG ? w_rot : VS_FIELD_W_DIAG);
    size_t nb = 1, pending = 0;   /* buckets: a power of two above the largest edge (a mask, not a division) */
    while (nb <= (size_t)wmax) nb *= 2;
    const uint32_t mask = (uint32_t)(nb - 1);
    bucket *bk = calloc(nb, sizeof(bucket));
    if (bk == NULL) return VS_ENOMEM;
    int rc = bucket_grow(&bk[0]);
    if (rc == VS_OK) {
        bk[0].items[bk[0].len++] = (uint32_t)src;
        cost[src] &= keep;   /* distance 0 */
        pending = 1;
    }
/* relax the neighbour t over an edge of base weight w (doubled where either end is tight) */
#define RELAX(tt, ww)                                                                                              \
    do {                                                                                                           \
        uint32_t t_ = (tt), ct_ = cost[t_];                                                                        \
        if (ct_ != VS_FIELD_WALL) {                                                                                \
            uint32_t w_ = (ww), nd_ = d + (((cs | ct_) & VS_FIELD_TIGHT_BIT) ? 2 * w_ : w_);                       \
            if (nd_ < (ct_ & VS_FIELD_COST_MASK)) {                                                                \
                bucket *b_ = &bk[nd_ & mask];                                                                      \
                cost[t_] = (ct_ & keep) | nd_;                                                                     \
                if (b_->len == b_->cap && (rc = bucket_grow(b_)) != VS_OK) goto out;                               \
                b_->items[b_->len++] = t_;                                                                         \
                pending++;                                                                                         \
            }                                                                                                      \
        }                                                                                                          \
    } while (0)
    for (uint32_t d = 0; pending > 0 && rc == VS_OK; d++) {
        bucket *b = &bk[d & mask];
        for (size_t q = 0; q < b->len; q++) {
            uint32_t s = b->items[q];
            pending--;
            uint32_t cs = cost[s];
            if ((cs & VS_FIELD_COST_MASK) != d) continue;   /* a stale entry: reached cheaper since */
            uint32_t k = (uint32_t)((double)s * inv_plane);   /* s's heading: the estimate, corrected */
            if (k * plane > s) k--;
            else if (s - k * plane >= plane) k++;
            uint32_t rem = s - k * plane, row = (uint32_t)((double)rem * inv_nx);
            if (row * nx > rem) row--;
            else if (rem - row * nx >= nx) row++;
            uint32_t col = rem - row * nx;
            if (col > 0 && col + 1 < nx && row > 0 && row + 1 < ny) {   /* in the order of neighbours_of */
                RELAX(s + 1, VS_FIELD_W_AXIS);
                RELAX(s - 1, VS_FIELD_W_AXIS);
                RELAX(s + nx, VS_FIELD_W_AXIS);
                RELAX(s - nx, VS_FIELD_W_AXIS);
                RELAX(s + nx + 1, VS_FIELD_W_DIAG);
                RELAX(s + nx - 1, VS_FIELD_W_DIAG);
                RELAX(s - nx + 1, VS_FIELD_W_DIAG);
                RELAX(s - nx - 1, VS_FIELD_W_DIAG);
                RELAX(s + plane < total ? s + plane : s + plane - total, w_rot);
                RELAX(s >= plane ? s - plane : s + (total - plane), w_rot);
            } else {
                size_t t[10];
                uint32_t w[10];
                int c = neighbours_of(f, s, t, w);
                for (int j = 0; j < c; j++) RELAX((uint32_t)t[j], w[j]);
            }
        }
        b->len = 0;
    }
#undef RELAX
out:
    for (size_t i = 0; i < nb; i++) free(bk[i].items);
    free(bk);
    return rc;
}

/* rows of this many columns or fewer (c1 - c0 < this) are tested column by column: cheaper than finding the runs'
 * ends (the 30 robots' rooms of bench/plan_cost.py, cells of 9 cm: rows of about 10 columns) */
#define VS_RASTER_SHORT_ROW 24

/* the x offset [m] of column c's body from the obstacle: ((gx + (c + ix_lo) h) + qx) - ox, as the raster's test
 * has always computed it, in this order; xs[c] = gx + (c + ix_lo) h, the column's x, computed once per build */
#define RASTER_DX(c) ((xs[c] + qx) - ox)

/* One row of one (heading, body, obstacle) raster: every column c in [c0, c1] whose body comes within the wall
 * radius (d2 = dx^2 + dy2 < w2) becomes a wall, and within the tight radius (< t2) but not the wall's, tight.
 * The same cells as testing every column: dx is non-decreasing in c (every rounding is monotone), so d2 falls,
 * then rises, and each set {d2 < w2}, {d2 < t2} is one run of columns around the column of least |dx|.  The
 * runs' ends are found by exact tests, stepping from a sqrt estimate, and the runs filled without tests. */
static void raster_row_at(uint32_t *cost, long long c0, long long c1, const double *xs,
                          double qx, double ox, double est, double inv_h, double dy2, double w2, double t2)
{
#define D2(c) (RASTER_DX(c) * RASTER_DX(c) + dy2)
    if (c1 - c0 < VS_RASTER_SHORT_ROW) {   /* a short row: every column tested, as the runs below stand for */
        long long c = c0;
#if defined(__SSE2__) && defined(__x86_64__)
        /* four, then two columns at a time: the same operations in each lane (IEEE add, subtract, multiply and
         * compare, no fused multiply-add), so the same bits as the scalar loop below, which finishes the row */
        const __m128d vqx = _mm_set1_pd(qx), vox = _mm_set1_pd(ox), vdy2 = _mm_set1_pd(dy2);
        const __m128d vw2 = _mm_set1_pd(w2), vt2 = _mm_set1_pd(t2);
        const __m128i vtb = _mm_set1_epi32((int)VS_FIELD_TIGHT_BIT);
        for (; c + 3 <= c1; c += 4) {   /* four columns: two pairs, their words in one 16-byte or */
            __m128d dxa = _mm_sub_pd(_mm_add_pd(_mm_loadu_pd(xs + c), vqx), vox);
            __m128d dxb = _mm_sub_pd(_mm_add_pd(_mm_loadu_pd(xs + c + 2), vqx), vox);
            __m128d d2a = _mm_add_pd(_mm_mul_pd(dxa, dxa), vdy2), d2b = _mm_add_pd(_mm_mul_pd(dxb, dxb), vdy2);
            /* each lane's all-ones or zero, its low 32 bits taken (shuffle 0, 2 of each pair): columns c..c + 3 */
            __m128i wall = _mm_castps_si128(_mm_shuffle_ps(_mm_castpd_ps(_mm_cmplt_pd(d2a, vw2)),
                                                           _mm_castpd_ps(_mm_cmplt_pd(d2b, vw2)), VS_LOW_WORDS));
            __m128i tight = _mm_castps_si128(_mm_shuffle_ps(_mm_castpd_ps(_mm_cmplt_pd(d2a, vt2)),
                                                            _mm_castpd_ps(_mm_cmplt_pd(d2b, vt2)), VS_LOW_WORDS));
            __m128i four;   /* cost[c..c + 3] ORed with their bits (memcpy: no alignment asked of cost) */
            memcpy(&four, cost + c, sizeof four);
            four = _mm_or_si128(four, _mm_or_si128(wall, _mm_and_si128(tight, vtb)));
            memcpy(cost + c, &four, sizeof four);
        }
        for (; c < c1; c += 2) {
            __m128d dx = _mm_sub_pd(_mm_add_pd(_mm_loadu_pd(xs + c), vqx), vox);
            __m128d d2 = _mm_add_pd(_mm_mul_pd(dx, dx), vdy2);
            /* each lane's all-ones or zero, its low 32 bits taken (shuffle 0, 2): the two columns' words */
            __m128i wall = _mm_shuffle_epi32(_mm_castpd_si128(_mm_cmplt_pd(d2, vw2)), VS_LOW_WORDS);
            __m128i tight = _mm_shuffle_epi32(_mm_castpd_si128(_mm_cmplt_pd(d2, vt2)), VS_LOW_WORDS);
            __m128i bits = _mm_or_si128(wall, _mm_and_si128(tight, vtb));
            uint64_t two;   /* cost[c], cost[c + 1] ORed with their bits (memcpy: no alignment asked of cost) */
            memcpy(&two, cost + c, sizeof two);
            two |= (uint64_t)_mm_cvtsi128_si64(bits);
            memcpy(cost + c, &two, sizeof two);
        }
#endif
        for (; c <= c1; c++) {   /* branch-free: a wall ORs in every bit (VS_FIELD_WALL), tight */
            double d2 = D2(c);                    /* the tight bit (a wall's is never read) */
            cost[c] |= ((uint32_t)0 - (uint32_t)(d2 < w2)) | ((uint32_t)(d2 < t2) * VS_FIELD_TIGHT_BIT);
        }
        return;
    }
    /* m: the column of least d2 (the last with dx <= 0, or the one after it, or c0 / c1); est (the column where dx
     * is about 0) and inv_h = 1 / h serve estimates only, which exact tests then correct */
    long long m = c0;
    if (est > (double)c1) m = c1;
    else if (est > (double)c0) m = (long long)est;
    while (m > c0 && RASTER_DX(m) > 0.0) m--;
    while (m < c1 && RASTER_DX(m + 1) <= 0.0) m++;
    if (m < c1 && D2(m + 1) < D2(m)) m++;
    double dm = D2(m);
    if (!(dm < t2)) return;
    /* the run {d2 < lim} around m: [*lo, *hi] */
    long long lo_w = m, hi_w = m - 1;      /* empty wall run unless dm < w2 */
    long long lo_t = m, hi_t = m;
    for (int pass = 0; pass < 2; pass++) {
        double lim = pass == 0 ? t2 : w2;
        if (pass == 1 && !(dm < w2)) break;
        double half = lim - dy2 > 0.0 ? sqrt(lim - dy2) * inv_h : 0.0;
        long long a = m - (long long)half, b = m + (long long)half;
        if (a < c0) a = c0;
        if (b > c1) b = c1;
        if (D2(a) < lim) { while (a > c0 && D2(a - 1) < lim) a--; }
        else { while (!(D2(a) < lim)) a++; }           /* stops at m at the latest */
        if (D2(b) < lim) { while (b < c1 && D2(b + 1) < lim) b++; }
        else { while (!(D2(b) < lim)) b--; }
        if (pass == 0) { lo_t = a; hi_t = b; }
        else { lo_w = a; hi_w = b; }
    }
    for (long long c = lo_t; c < lo_w; c++) cost[c] |= VS_FIELD_TIGHT_BIT;
    for (long long c = lo_w; c <= hi_w; c++) cost[c] = VS_FIELD_WALL;
    for (long long c = (hi_w >= lo_w ? hi_w + 1 : lo_w); c <= hi_t; c++) cost[c] |= VS_FIELD_TIGHT_BIT;
#undef D2
}
#undef RASTER_DX

/* an angle in [-pi, pi) as it is, any other wrapped (vs_wrap_angle is not the identity inside) */
static double wrap_outside(double th)
{
    return (th >= -VS_PI && th < VS_PI) ? th : vs_wrap_angle(th);
}

static int finite3(const double *v, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!vs_isfinite(v[i])) return 0;
    return 1;
}

/* the raster's share of one thread: headings k0, k0 + k_step, ... (each heading's plane is written by its own
 * thread alone, so the planes hold the same bits however the headings are shared out) */
typedef struct {
    const vs_field *f;
    const double *template_xy;
    size_t n;
    const double *obstacles;
    size_t n_obstacles;
    const double *xs, *ys, *radii2;
    double inv_h;
    size_t k0, k_step;
    double *q;   /* 2 n: the bodies' offsets at the heading, this thread's own */
} raster_job;

static void raster_headings(const raster_job *J)
{
    const vs_field *f = J->f;
    const double *template_xy = J->template_xy, *obstacles = J->obstacles, *xs = J->xs, *ys = J->ys;
    const double *radii2 = J->radii2, inv_h = J->inv_h, h = f->cell_m;
    const size_t n = J->n, n_obstacles = J->n_obstacles, plane = f->nx * f->ny;
    double *q = J->q;
    for (size_t k = J->k0; k < f->n_headings; k += J->k_step) {
        double th = f->gth + (double)k * f->dth_rad;
        double sn = vs_sin(th), cs = vs_cos(th);
        for (size_t i = 0; i < n; i++) {
            double px = template_xy[2 * i], py = template_xy[2 * i + 1];
            q[2 * i] = cs * px - sn * py;
            q[2 * i + 1] = sn * px + cs * py;
        }
        uint32_t *plane_cost = f->cost + k * plane;
        for (size_t i = 0; i < n; i++) {
            double qx = q[2 * i], qy = q[2 * i + 1];
            for (size_t j = 0; j < n_obstacles; j++) {
                const double *o = obstacles + 3 * j;
                const double *b = radii2 + 3 * (i * n_obstacles + j);
                double w2 = b[0], t2 = b[1], rho_tight = b[2];
                /* the body centre is (gx + ix h + qx, ...): within rho_tight of the obstacle only for ix in
                 * ((cx - rho_tight) / h, (cx + rho_tight) / h), cx = ox - qx - gx; the floor of the low end and the
                 * floor of the high end + 1 hold that range and a column more (rounding moves the ends by about
                 * 1e-5 of a cell at most: coordinates <= 1e6 m, cells >= 1e-3 m).  Likewise the rows. */
                double cx = (o[0] - qx) - f->gx, cy = (o[1] - qy) - f->gy;
                long long c0 = ifloor((cx - rho_tight) / h) - f->ix_lo;
                long long c1 = ifloor((cx + rho_tight) / h) + 1 - f->ix_lo;
                long long r0 = ifloor((cy - rho_tight) / h) - f->iy_lo;
                long long r1 = ifloor((cy + rho_tight) / h) + 1 - f->iy_lo;
                if (c0 < 0) c0 = 0;
                if (r0 < 0) r0 = 0;
                if (c1 > (long long)f->nx - 1) c1 = (long long)f->nx - 1;
                if (r1 > (long long)f->ny - 1) r1 = (long long)f->ny - 1;
                double est = (o[0] - (f->gx + qx)) * inv_h - (double)f->ix_lo;   /* the column nearest: an estimate */
                for (long long r = r0; r <= r1; r++) {
                    double by = ys[r] + qy;   /* (gy + (r + iy_lo) h) + qy, as the raster has always computed it */
                    double dy = by - o[1];
                    double dy2 = dy * dy;
                    if (!(dy2 < t2)) continue;   /* no column of this row: dx * dx + dy2 >= dy2 (monotone rounding) */
                    raster_row_at(plane_cost + (size_t)r * f->nx, c0, c1, xs, qx, o[0], est, inv_h, dy2, w2, t2);
                }
            }
        }
    }
}

#if !defined(VS_FIELD_NO_THREADS)
static void *raster_thread(void *job)
{
    raster_headings((const raster_job *)job);
    return NULL;
}
#endif

/* The raster over every heading: the odd headings on a second thread where one can be started (else on this one),
 * the even ones here.  The same planes, bit for bit, either way (raster_headings).  Built with VS_FIELD_NO_THREADS,
 * all on this thread.  Why (2026-12-07, bench/plan_cost.py): the raster was about 60 % of a 30 robots' build. */
static void raster_all(raster_job jobs[2])
{
#if !defined(VS_FIELD_NO_THREADS)
    pthread_t other;
    if (jobs[0].f->n_headings > 1 && pthread_create(&other, NULL, raster_thread, &jobs[1]) == 0) {
        jobs[0].k_step = 2;
        raster_headings(&jobs[0]);
        pthread_join(other, NULL);
        return;
    }
#endif
    jobs[0].k0 = 0;
    jobs[0].k_step = 1;
    raster_headings(&jobs[0]);
}

/* 1 when the room's finite values are in range: |coordinates| and radii <= VS_FIELD_MAX_ABS_M, body radii >= 0,
 * obstacle radii > 0 */
static int room_in_range(const double *template_xy, const double *radius_m, size_t n, const double *obstacles,
                         size_t n_obstacles)
{
    for (size_t i = 0; i < 2 * n; i++)
        if (vs_fabs(template_xy[i]) > VS_FIELD_MAX_ABS_M) return 0;
    for (size_t i = 0; i < n; i++)
        if (!(radius_m[i] >= 0.0) || radius_m[i] > VS_FIELD_MAX_ABS_M) return 0;
    for (size_t j = 0; j < n_obstacles; j++) {
        const double *o = obstacles + 3 * j;
        if (vs_fabs(o[0]) > VS_FIELD_MAX_ABS_M || vs_fabs(o[1]) > VS_FIELD_MAX_ABS_M || !(o[2] > 0.0) ||
            o[2] > VS_FIELD_MAX_ABS_M)
            return 0;
    }
    return 1;
}

static int build(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                 const double *obstacles, size_t n_obstacles, const double goal[3], double cell_m,
                 size_t n_headings, size_t max_states, int defer, vs_field *out)
{
    if (n == 0 || n_obstacles > VS_FIELD_MAX_OBSTACLES || n_headings < 4 || n_headings > 1024 ||
        max_states < 1024 || max_states > VS_FIELD_MAX_STATES || 9 * n_headings > max_states)
        return VS_EVALUE;
    if (!finite3(template_xy, 2 * n) || !finite3(radius_m, n) || !finite3(obstacles, 3 * n_obstacles) ||
        !finite3(goal, 3) || !vs_isfinite(margin_m) || !vs_isfinite(cell_m))
        return VS_ENONFINITE;
    if (!(cell_m >= 1e-3) || cell_m > VS_FIELD_MAX_ABS_M || !(margin_m >= 0.0) || margin_m > VS_FIELD_MAX_ABS_M)
        return VS_EVALUE;
    if (!room_in_range(template_xy, radius_m, n, obstacles, n_obstacles)) return VS_EVALUE;
    for (int i = 0; i < 2; i++)
        if (vs_fabs(goal[i]) > VS_FIELD_MAX_ABS_M) return VS_EVALUE;
    if (vs_fabs(goal[2]) > VS_FIELD_MAX_ABS_M) return VS_EVALUE;

    vs_field f;
    memset(&f, 0, sizeof f);
    f.gx = goal[0];
    f.gy = goal[1];
    f.gth = wrap_outside(goal[2]);
    f.n_headings = n_headings;
    f.dth_rad = VS_TWO_PI / (double)n_headings;
    f.margin_m = margin_m;
    double pmax = 0.0, reach = 0.0;   /* largest |p_i|, largest |p_i| + r_i */
    for (size_t i = 0; i < n; i++) {
        double px = template_xy[2 * i], py = template_xy[2 * i + 1];
        double p = sqrt(px * px + py * py);
        if (p > pmax) pmax = p;
        if (p + radius_m[i] > reach) reach = p + radius_m[i];
    }
    /* the lattice's extent [m, relative to the goal], then the cell that keeps it within max_states */
    double lo_x = 0.0, hi_x = 0.0, lo_y = 0.0, hi_y = 0.0;
    for (size_t j = 0; j < n_obstacles; j++) {
        const double *o = obstacles + 3 * j;
        double ax = (o[0] - o[2]) - f.gx, bx = (o[0] + o[2]) - f.gx;
        double ay = (o[1] - o[2]) - f.gy, by = (o[1] + o[2]) - f.gy;
        if (ax < lo_x) lo_x = ax;
        if (bx > hi_x) hi_x = bx;
        if (ay < lo_y) lo_y = ay;
        if (by > hi_y) hi_y = by;
    }
    double h = cell_m;
    for (;;) {
        double infl = h * sqrt(0.5), rot = pmax * (VS_PI / (double)n_headings);
        f.inflation_m = infl > rot ? infl : rot;
        double pad = ((reach + margin_m) + f.inflation_m) + VS_FIELD_COMFORT_M + 2.0 * h;
        long long ix0 = ifloor((lo_x - pad) / h), ix1 = -ifloor(-(hi_x + pad) / h);
        long long iy0 = ifloor((lo_y - pad) / h), iy1 = -ifloor(-(hi_y + pad) / h);
        double states = (double)(ix1 - ix0 + 1) * (double)(iy1 - iy0 + 1) * (double)n_headings;
        if (states <= (double)max_states && states < 4.0e9) {
            f.ix_lo = (long)ix0;
            f.iy_lo = (long)iy0;
            f.nx = (size_t)(ix1 - ix0 + 1);
            f.ny = (size_t)(iy1 - iy0 + 1);
            break;
        }
        h *= VS_FIELD_GROW;
        if (h > VS_FIELD_MAX_ABS_M) return VS_EVALUE;   /* unreachable: 9 K <= max_states fits at h ~ the room */
    }
    f.cell_m = h;
    {
        double wr = (double)VS_FIELD_W_AXIS * (pmax * f.dth_rad) / h;
        long long w = ifloor(wr + 0.5);
        f.w_rot = w < 1 ? 1u : (uint32_t)w;
    }
    size_t plane = f.nx * f.ny, total = plane * n_headings;
    /* the bodies' offsets, then the columns' x (xs), the rows' y (ys), and each (body i, obstacle j)'s squared wall
     * and tight radii and tight radius (radii2[3 (i m + j) ...]: the same at every heading, computed once) */
    double *q = NULL;
    if (n <= (SIZE_MAX / sizeof(double) - f.nx - f.ny) / (4 + 3 * (size_t)n_obstacles))   /* + a thread's 2 n */
        q = malloc(sizeof(double) * (4 * n + f.nx + f.ny + 3 * n * n_obstacles));
    f.cost = cost_alloc(total);
    int rc = VS_OK;
    if (q == NULL || f.cost == NULL) { rc = VS_ENOMEM; goto fail; }
    for (size_t s = 0; s < total; s++) f.cost[s] = 0u;   /* 0: free (the raster ORs in walls, tight bits) */

    /* the raster: for each heading, each body and each obstacle, the lattice points within reach */
    const double inv_h = 1.0 / h;
    double *xs = q + 2 * n, *ys = xs + f.nx, *radii2 = ys + f.ny;
    for (size_t c = 0; c < f.nx; c++) xs[c] = f.gx + (double)((long long)c + (long long)f.ix_lo) * h;
    for (size_t r = 0; r < f.ny; r++) ys[r] = f.gy + (double)((long long)r + (long long)f.iy_lo) * h;
    for (size_t i = 0; i < n; i++) {
        double px = template_xy[2 * i], py = template_xy[2 * i + 1];
        double arm = sqrt(px * px + py * py);          /* |p_i|: the body's arc radius when the structure turns */
        double chord = arm * f.dth_rad;                /* >= the chord of a turn edge */
        double sagitta = (arm * (f.dth_rad * f.dth_rad)) / 8.0;   /* >= the arc's bulge beyond that chord */
        for (size_t j = 0; j < n_obstacles; j++) {
            /* the exact bound of the edges (vs_field.h): a move keeps need where both ends keep
             * sqrt(need^2 + h^2 / 2), a turn where both keep sqrt((need + sagitta)^2 + chord^2 / 4) */
            double need = (radius_m[i] + obstacles[3 * j + 2]) + margin_m;
            double move2 = need * need + (h * h) / 2.0;
            double bulge = need + sagitta;
            double turn2 = bulge * bulge + (chord * chord) / 4.0;
            double w2 = turn2 > move2 ? turn2 : move2;
            double rho_tight = sqrt(w2) + VS_FIELD_COMFORT_M;
            double *b = radii2 + 3 * (i * n_obstacles + j);
            b[0] = w2;
            b[1] = rho_tight * rho_tight;
            b[2] = rho_tight;
        }
    }
    raster_job jobs[2] = {{&f, template_xy, n, obstacles, n_obstacles, xs, ys, radii2, inv_h, 0, 1, q},
                          {&f, template_xy, n, obstacles, n_obstacles, xs, ys, radii2, inv_h, 1, 2,
                           q + 2 * n + f.nx + f.ny + 3 * n * n_obstacles}};
    raster_all(jobs);

    /* pass 1, from the goal state, in the cost array: every free state unresolved and blocked (its tight bit kept)
     * until the goal's Dijkstra reaches it */
    size_t goal_state = (size_t)(-f.iy_lo) * f.nx + (size_t)(-f.ix_lo);
    f.goal_free = f.cost[goal_state] != VS_FIELD_WALL;
    for (size_t s = 0; s < total; s++)
        if (f.cost[s] != VS_FIELD_WALL)
            f.cost[s] = VS_FIELD_UNRESOLVED | VS_FIELD_BLOCKED_BIT | (f.cost[s] & VS_FIELD_TIGHT_BIT);
    if (f.goal_free && (rc = dial_in_place(&f, goal_state, VS_FIELD_TIGHT_BIT)) != VS_OK) goto fail;
    free(q);
    q = NULL;
    /* the components the goal cannot reach, each from its target (resolve_component): now, or (deferred) when a
     * descent first needs one */
    if (!defer && (rc = vs_field_resolve_all(&f)) != VS_OK) goto fail;
    *out = f;
    return VS_OK;
fail:
    free(q);
    free(f.cost);
    return rc;
}

int vs_field_build(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                   const double *obstacles, size_t n_obstacles, const double goal[3], double cell_m,
                   size_t n_headings, size_t max_states, vs_field *out)
{
    return build(template_xy, radius_m, n, margin_m, obstacles, n_obstacles, goal, cell_m, n_headings, max_states, 0,
                 out);
}

int vs_field_build_deferred(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                            const double *obstacles, size_t n_obstacles, const double goal[3], double cell_m,
                            size_t n_headings, size_t max_states, vs_field *out)
{
    return build(template_xy, radius_m, n, margin_m, obstacles, n_obstacles, goal, cell_m, n_headings, max_states, 1,
                 out);
}

/* a free state the goal cannot reach whose cost a deferred build left for later */
static int unresolved(uint32_t v)
{
    return v != VS_FIELD_WALL && (v & VS_FIELD_BLOCKED_BIT) && (v & VS_FIELD_COST_MASK) == VS_FIELD_UNRESOLVED;
}

/* The component of the unresolved state s0, as vs_field_build's second pass leaves it: its target is its state
 * nearest the goal (squared lattice distance, then the lowest index), and every state's cost is its exact integer
 * distance to that target (Dial's buckets).  The component's states are found breadth first and marked SEEN (a
 * cost beyond any distance, so Dial takes it for "not reached"); no state outside the component is touched (its
 * free neighbours are all in it: the goal's component and the others are apart from it).  Writes through f->cost
 * only: the lattice is f's, the same for every caller. */
#define SEEN (VS_FIELD_UNRESOLVED - 1u)
static int resolve_component(const vs_field *f, size_t s0)
{
    if (!unresolved(f->cost[s0])) return VS_OK;
    const size_t plane = f->nx * f->ny;
    uint32_t *cost = f->cost;
    bucket comp = {NULL, 0, 0};
    int rc = VS_OK;
    size_t best = s0;
    long long best_d2 = -1;
    /* listed, then marked: a state marked SEEN is always in comp, so a failure restores every one of them */
    if ((rc = bucket_push(&comp, (uint32_t)s0)) != VS_OK) goto done;
    cost[s0] = (cost[s0] & ~VS_FIELD_COST_MASK) | SEEN;
    for (size_t head = 0; head < comp.len; head++) {
        size_t u = comp.items[head];
        size_t rem = u % plane;
        long long c = (long long)(rem % f->nx) + f->ix_lo, r = (long long)(rem / f->nx) + f->iy_lo;
        long long d2 = c * c + r * r;
        if (best_d2 < 0 || d2 < best_d2 || (d2 == best_d2 && u < best)) { best_d2 = d2; best = u; }
        size_t nbr[10];
        uint32_t wts[10];
        int cnt = neighbours_of(f, u, nbr, wts);
        for (int j = 0; j < cnt; j++) {
            if (!unresolved(cost[nbr[j]])) continue;
            if ((rc = bucket_push(&comp, (uint32_t)nbr[j])) != VS_OK) goto done;
            cost[nbr[j]] = (cost[nbr[j]] & ~VS_FIELD_COST_MASK) | SEEN;
        }
    }
    /* Dial from the target, over the component (costs SEEN: not reached; the blocked and tight bits kept) */
    rc = dial_in_place(f, best, VS_FIELD_TIGHT_BIT | VS_FIELD_BLOCKED_BIT);
done:
    if (rc != VS_OK)   /* leave the component unresolved, as it was: a later call starts again */
        for (size_t i = 0; i < comp.len; i++)
            cost[comp.items[i]] = (cost[comp.items[i]] & ~VS_FIELD_COST_MASK) | VS_FIELD_UNRESOLVED;
    free(comp.items);
    return rc;
}
#undef SEEN

int vs_field_resolve_all(vs_field *f)
{
    if (f == NULL || f->cost == NULL) return VS_EVALUE;
    size_t total = f->nx * f->ny * f->n_headings;
    for (size_t s = 0; s < total; s++) {
        int rc = resolve_component(f, s);
        if (rc != VS_OK) return rc;
    }
    return VS_OK;
}

void vs_field_free(vs_field *f)
{
    if (f == NULL) return;
    free(f->cost);
    f->cost = NULL;
    if (f->refine != NULL) {
        vs_field_free(&f->refine->fine);
        free(f->refine->inputs);
        free(f->refine);
        f->refine = NULL;
    }
}

/* the column (row) of u = coordinate / h + 0.5 on an axis of `count` from `lo`, clamped; *out set if clamped.
 * Compared in double first, so that a pose far away (or at 1e300) never overflows the integer conversion. */
static size_t axis_index(double u, long lo, size_t count, int *out)
{
    if (!(u >= (double)lo)) { *out = 1; return 0; }
    if (u >= (double)(lo + (long)count)) { *out = 1; return count - 1; }
    return (size_t)(ifloor(u) - lo);
}

static void nearest(const vs_field *f, const double pose[3], size_t *col, size_t *row, size_t *k, int *outside)
{
    int out = 0;
    *col = axis_index((pose[0] - f->gx) / f->cell_m + 0.5, f->ix_lo, f->nx, &out);
    *row = axis_index((pose[1] - f->gy) / f->cell_m + 0.5, f->iy_lo, f->ny, &out);
    long long kk = ifloor(vs_wrap_angle(pose[2] - f->gth) / f->dth_rad + 0.5);
    long long nh = (long long)f->n_headings;
    *k = (size_t)(((kk % nh) + nh) % nh);
    *outside = out;
}

void vs_field_nearest(const vs_field *f, const double pose[3], size_t *col, size_t *row, size_t *k)
{
    int outside;
    nearest(f, pose, col, row, k, &outside);
}

static void state_pose(const vs_field *f, size_t s, double *out)
{
    size_t plane = f->nx * f->ny, k = s / plane, rem = s % plane;
    out[0] = f->gx + (double)((long)(rem % f->nx) + f->ix_lo) * f->cell_m;
    out[1] = f->gy + (double)((long)(rem / f->nx) + f->iy_lo) * f->cell_m;
    out[2] = wrap_outside(f->gth + (double)k * f->dth_rad);
}

/* the next state of the descent from s (the neighbour of least cost + edge weight, strictly cheaper than s;
 * ties: the first in neighbour order), or -1 at a target */
static long descend(const vs_field *f, size_t s, uint32_t *w_out)
{
    uint32_t cs = f->cost[s] & VS_FIELD_COST_MASK;
    if (cs == 0) return -1;
    long best = -1;
    uint32_t best_v = 0, best_w = 0;
    size_t nbr[10];
    uint32_t wts[10];
    int cnt = neighbours_of(f, s, nbr, wts);
    for (int j = 0; j < cnt; j++) {
        size_t t = nbr[j];
        uint32_t w = wts[j];
        if (f->cost[t] == VS_FIELD_WALL) continue;
        uint32_t ct = f->cost[t] & VS_FIELD_COST_MASK;
        if (ct >= cs) continue;
        if ((f->cost[s] | f->cost[t]) & VS_FIELD_TIGHT_BIT) w *= 2;
        uint32_t v = ct + w;
        if (best < 0 || v < best_v) { best = (long)t; best_v = v; best_w = w; }
    }
    *w_out = best_w;
    return best;
}

/* every pose on the straight way from a to b (heading the short way), sampled at most h/2 and dth/2 apart,
 * rounds to a free state outside the comfort band with the blocked bit `want`: the comfort band (far wider
 * than the rounding) keeps the clearance between samples */
static int segment_clear(const vs_field *f, const double *a, const double *b, uint32_t want)
{
    double dx = b[0] - a[0], dy = b[1] - a[1], dth = vs_wrap_angle(b[2] - a[2]);
    double steps_xy = sqrt(dx * dx + dy * dy) / (0.5 * f->cell_m), steps_th = vs_fabs(dth) / (0.5 * f->dth_rad);
    long long m = ifloor(steps_xy > steps_th ? steps_xy : steps_th) + 1;
    size_t plane = f->nx * f->ny;
    for (long long i = 0; i <= m; i++) {
        double t = (double)i / (double)m, p[3] = {a[0] + dx * t, a[1] + dy * t, a[2] + dth * t};
        size_t c, r, k;
        vs_field_nearest(f, p, &c, &r, &k);
        uint32_t v = f->cost[k * plane + r * f->nx + c];
        if (v == VS_FIELD_WALL || (v & VS_FIELD_TIGHT_BIT) || (v & VS_FIELD_BLOCKED_BIT) != want) return 0;
    }
    return 1;
}

/* the state a descent from pose starts at, among the free states within VS_FIELD_SEARCH_CELLS cells of it (ring 0:
 * the pose's own cell), at the nearest heading and two either side: of the nearest ring that has one the goal can be
 * reached from, the cheapest such; else of the nearest ring that has any free state, the cheapest; then the first
 * found; -1 if none.  *outside: the pose lies outside the lattice. */
static long start_state(const vs_field *f, const double pose[3], int *outside)
{
    size_t plane = f->nx * f->ny;
    size_t c0, r0, k0;
    nearest(f, pose, &c0, &r0, &k0, outside);
    long start = -1;
    uint32_t start_v = 0, start_b = 0;
    int start_d = 0;
    static const int DK[5] = {0, 1, -1, 2, -2};
    for (int d = 0; d <= VS_FIELD_SEARCH_CELLS && (start < 0 || start_b); d++) {
        for (int a = 0; a < 5; a++) {
            size_t k = (size_t)((long)k0 + (long)f->n_headings + DK[a]) % f->n_headings;
            for (int dr = -d; dr <= d; dr++) {
                for (int dc = -d; dc <= d; dc++) {
                    if (dr != -d && dr != d && dc != -d && dc != d) continue;   /* the ring only */
                    long c = (long)c0 + dc, r = (long)r0 + dr;
                    if (c < 0 || r < 0 || c >= (long)f->nx || r >= (long)f->ny) continue;
                    size_t s = k * plane + (size_t)r * f->nx + (size_t)c;
                    if (f->cost[s] == VS_FIELD_WALL) continue;
                    /* a state the goal can be reached from before any the goal cannot (whose cost is to its own
                     * component's end, often smaller), in a farther ring too, then the cheaper: a pose between states
                     * beside a wall starts on the way to the goal, not in a sliver of the lattice that leads nowhere
                     * (bench room 4: a sliver in the pose's own ring; room 174: a sliver of one state in ring 0, at
                     * two headings off, the way one cell away) */
                    uint32_t v = f->cost[s] & VS_FIELD_COST_MASK;
                    uint32_t b = (f->cost[s] & VS_FIELD_BLOCKED_BIT) != 0;
                    /* a reachable one, or a blocked one of a nearer ring, stands */
                    if (start >= 0 && b && (start_b == 0 || start_d < d)) continue;
                    if (start < 0 || b < start_b || (b == start_b && v < start_v)) {
                        start_d = d;
                        start = (long)s; start_v = v; start_b = b;
                    }
                }
            }
        }
    }
    return start;
}

/* A deferred field (vs_field_build_deferred): the components the start's choice compares costs in are resolved.
 * That is only when no state within the search can be reached from the goal: then the start is the cheapest
 * free state of the nearest ring that has one, and its component's descent follows (start_state). */
static int prepare_start(const vs_field *f, const double pose[3])
{
    size_t plane = f->nx * f->ny;
    size_t c0, r0, k0;
    int outside;
    nearest(f, pose, &c0, &r0, &k0, &outside);
    static const int DK[5] = {0, 1, -1, 2, -2};
    int ring = -1;   /* the nearest ring with a free state */
    for (int pass = 0; pass < 2; pass++) {   /* pass 0: look; pass 1: resolve that ring's components */
        for (int d = 0; d <= VS_FIELD_SEARCH_CELLS; d++) {
            if (pass == 1 && d != ring) continue;
            for (int a = 0; a < 5; a++) {
                size_t k = (size_t)((long)k0 + (long)f->n_headings + DK[a]) % f->n_headings;
                for (int dr = -d; dr <= d; dr++) {
                    for (int dc = -d; dc <= d; dc++) {
                        if (dr != -d && dr != d && dc != -d && dc != d) continue;
                        long c = (long)c0 + dc, r = (long)r0 + dr;
                        if (c < 0 || r < 0 || c >= (long)f->nx || r >= (long)f->ny) continue;
                        size_t s = k * plane + (size_t)r * f->nx + (size_t)c;
                        uint32_t v = f->cost[s];
                        if (v == VS_FIELD_WALL) continue;
                        if (pass == 0 && !(v & VS_FIELD_BLOCKED_BIT)) return VS_OK;   /* the start can reach the goal */
                        if (pass == 0 && ring < 0) ring = d;
                        if (pass == 1) {
                            int rc = resolve_component(f, s);
                            if (rc != VS_OK) return rc;
                        }
                    }
                }
            }
        }
        if (ring < 0) return VS_OK;   /* no free state near: the start is none */
    }
    return VS_OK;
}

static int open_one(const vs_field *f, const double pose[3], int *tight)
{
    int outside;
    if (prepare_start(f, pose) != VS_OK) { *tight = 0; return 0; }   /* a resolution that fails: not open */
    long start = start_state(f, pose, &outside);
    *tight = start >= 0 && (f->cost[start] & VS_FIELD_TIGHT_BIT) != 0;
    return start >= 0 && !(f->cost[start] & VS_FIELD_BLOCKED_BIT);
}

/* Whether a free state the goal can reach lies within the descent's search of the pose (VS_FIELD_SEARCH_CELLS
 * cells, 5 headings): then the descent starts on one (start_state), and open_one answers 1.  Reads only: a deferred
 * field's unresolved states are blocked whatever their costs, so nothing needs resolving to know. */
static int reachable_near(const vs_field *f, const double pose[3])
{
    size_t plane = f->nx * f->ny;
    size_t c0, r0, k0;
    int outside;
    nearest(f, pose, &c0, &r0, &k0, &outside);
    static const int DK[5] = {0, 1, -1, 2, -2};
    for (int d = 0; d <= VS_FIELD_SEARCH_CELLS; d++)
        for (int a = 0; a < 5; a++) {
            size_t k = (size_t)((long)k0 + (long)f->n_headings + DK[a]) % f->n_headings;
            for (int dr = -d; dr <= d; dr++)
                for (int dc = -d; dc <= d; dc++) {
                    if (dr != -d && dr != d && dc != -d && dc != d) continue;
                    long c = (long)c0 + dc, r = (long)r0 + dr;
                    if (c < 0 || r < 0 || c >= (long)f->nx || r >= (long)f->ny) continue;
                    uint32_t v = f->cost[k * plane + (size_t)r * f->nx + (size_t)c];
                    if (v != VS_FIELD_WALL && !(v & VS_FIELD_BLOCKED_BIT)) return 1;
                }
        }
    return 0;
}

static int follow_one(const vs_field *f, const double pose[3], double path_m, double *waypoints, size_t cap,
                      size_t *n_waypoints, int *blocked, double *left_m)
{
    size_t plane = f->nx * f->ny;
    int outside, rc = prepare_start(f, pose);
    if (rc != VS_OK) return rc;
    long start = start_state(f, pose, &outside);
    waypoints[0] = pose[0];
    waypoints[1] = pose[1];
    waypoints[2] = pose[2];
    size_t nw = 1;
    if (start < 0) {   /* on no free state, none near: stay */
        double dx = f->gx - pose[0], dy = f->gy - pose[1];
        *n_waypoints = 1;
        *blocked = 1;
        *left_m = sqrt(dx * dx + dy * dy);
        return VS_OK;
    }
    int is_blocked = (f->cost[start] & VS_FIELD_BLOCKED_BIT) != 0;
    size_t s = (size_t)start;
    state_pose(f, s, waypoints + 3 * nw);
    nw++;
    double run = 0.0;
    while (nw < cap && run < path_m) {
        uint32_t w;
        long t = descend(f, s, &w);
        if (t < 0) break;
        s = (size_t)t;
        state_pose(f, s, waypoints + 3 * nw);
        nw++;
        run += (double)(w > VS_FIELD_W_DIAG * 2 ? VS_FIELD_W_DIAG * 2 : w) / (double)VS_FIELD_W_AXIS * f->cell_m;
    }
    /* any angle: from the pose, straight to the farthest waypoint it sees through open space (a pose
     * outside the lattice goes to its border state first: nothing is out there) */
    for (size_t j = nw - 1; j >= 2 && !outside; j--) {
        if (segment_clear(f, waypoints, waypoints + 3 * j, is_blocked ? VS_FIELD_BLOCKED_BIT : 0u)) {
            memmove(waypoints + 3, waypoints + 3 * j, sizeof(double) * 3 * (nw - j));
            nw = 1 + (nw - j);
            break;
        }
    }
    double lx = 0.0, ly = 0.0;
    if (is_blocked) {   /* how far the component's target is from the goal */
        size_t u = s;
        for (size_t step = 0; step < f->n_headings * plane; step++) {
            uint32_t w;
            long t = descend(f, u, &w);
            if (t < 0) break;
            u = (size_t)t;
        }
        double end[3];
        state_pose(f, u, end);
        lx = f->gx - end[0];
        ly = f->gy - end[1];
    }
    *n_waypoints = nw;
    *blocked = is_blocked;
    *left_m = is_blocked ? sqrt(lx * lx + ly * ly) : 0.0;
    return VS_OK;
}

/* ------------------------------------------------------------------------------------------------ refinement */

int vs_field_set_refine(vs_field *f, const double *template_xy, const double *radius_m, size_t n,
                        const double *obstacles, size_t n_obstacles, double cell_m, size_t n_headings,
                        size_t max_states)
{
    if (f == NULL || f->cost == NULL || f->refine != NULL || n == 0 || n_obstacles > VS_FIELD_MAX_OBSTACLES ||
        n_headings < 4 || n_headings > 1024 || max_states < 1024 || max_states > VS_FIELD_MAX_STATES ||
        9 * n_headings > max_states)
        return VS_EVALUE;
    if (!finite3(template_xy, 2 * n) || !finite3(radius_m, n) || !finite3(obstacles, 3 * n_obstacles) ||
        !vs_isfinite(cell_m))
        return VS_ENONFINITE;
    if (!(cell_m >= 1e-3) || cell_m > VS_FIELD_MAX_ABS_M) return VS_EVALUE;
    /* the build's own checks: refused now, not by every descent that would ask the finer lattice */
    if (!room_in_range(template_xy, radius_m, n, obstacles, n_obstacles)) return VS_EVALUE;
    if (n > (SIZE_MAX / sizeof(double) - 3 * n_obstacles) / 3) return VS_ENOMEM;
    struct vs_field_refine *r = malloc(sizeof *r);
    double *in = malloc(sizeof(double) * (3 * n + 3 * n_obstacles + 1));   /* + 1: never malloc(0) */
    if (r == NULL || in == NULL) {
        free(r);
        free(in);
        return VS_ENOMEM;
    }
    memcpy(in, template_xy, sizeof(double) * 2 * n);
    memcpy(in + 2 * n, radius_m, sizeof(double) * n);
    if (n_obstacles > 0) memcpy(in + 3 * n, obstacles, sizeof(double) * 3 * n_obstacles);
    memset(r, 0, sizeof *r);
    r->inputs = in;
    r->n = n;
    r->n_obstacles = n_obstacles;
    r->n_headings = n_headings;
    r->max_states = max_states;
    r->cell_m = cell_m;
    f->refine = r;
    return VS_OK;
}

/* f's finer lattice, built the first time it is asked for (*g NULL: f has none) */
static int refined(const vs_field *f, const vs_field **g)
{
    struct vs_field_refine *r = f->refine;
    *g = NULL;
    if (r == NULL) return VS_OK;
    if (!r->built) {
        const double goal[3] = {f->gx, f->gy, f->gth};
        const double *in = r->inputs;
        int rc = vs_field_build_deferred(in, in + 2 * r->n, r->n, f->margin_m, in + 3 * r->n, r->n_obstacles, goal,
                                         r->cell_m, r->n_headings, r->max_states, &r->fine);
        if (rc != VS_OK) return rc;
        r->built = 1;
    }
    *g = &r->fine;
    return VS_OK;
}

int vs_field_refine_now(const vs_field *f)
{
    if (f == NULL || f->cost == NULL) return VS_EVALUE;
    const vs_field *g;
    return refined(f, &g);
}

void vs_field_set_provisional(vs_field *f)
{
    if (f != NULL) f->provisional = 1;
}

int vs_field_refined(const vs_field *f)
{
    return f != NULL && f->refine != NULL && f->refine->built;
}

int vs_field_open(const vs_field *f, const double pose[3], int *tight)
{
    if (open_one(f, pose, tight)) return 1;
    const vs_field *g;
    /* the finer lattice's answer where it is open (a build that fails: not open, as a resolution that fails); its
     * components the goal cannot reach are never resolved: its answer is taken only where it has a way */
    if (f->refine == NULL || refined(f, &g) != VS_OK || !reachable_near(g, pose)) return 0;
    return open_one(g, pose, tight);
}

int vs_field_follow(const vs_field *f, const double pose[3], double path_m, double *waypoints, size_t cap,
                    size_t *n_waypoints, int *blocked, double *left_m)
{
    if (f == NULL || f->cost == NULL || cap < 2) return VS_EVALUE;
    if (!finite3(pose, 3) || !vs_isfinite(path_m)) return VS_ENONFINITE;
    if (f->refine != NULL && !reachable_near(f, pose)) {
        /* no way on this lattice (its descent would say blocked): the finer one's, if it has one from here; else
         * this one's answer stands */
        const vs_field *g;
        int rc = refined(f, &g);
        if (rc != VS_OK) return rc;
        if (reachable_near(g, pose)) return follow_one(g, pose, path_m, waypoints, cap, n_waypoints, blocked, left_m);
    }
    return follow_one(f, pose, path_m, waypoints, cap, n_waypoints, blocked, left_m);
}
