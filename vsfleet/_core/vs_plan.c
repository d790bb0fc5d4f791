/* vs_plan.c - the structure's path around round obstacles (see vs_plan.h, docs/planning.md).
 *
 * Graph (the same construction, in the same order, as vsfleet/plan.py's
 * plan_structure_reference, so that both pick the same path):
 *   nodes: 0 = start S, 1 = goal G; then for each obstacle k in index order: S's two tangent
 *     points on the planning circle P_k (the "+" one first) or, if S is inside P_k, S's radial
 *     projection on it; then the same for G; then G's radial projection (always: the nearest point
 *     of P_k to the goal, a candidate closest safe pose); then for each pair a < b: the outer
 *     bitangents (+, -) and the inner ones (+, -) where they exist, each adding its point on P_a
 *     then its point on P_b;
 *   edges, in this order: S-G; each node's edge to S, G or its bitangent partner as the node is
 *     made; then for each circle k, arcs between its nodes consecutive in angle (ties by index),
 *     counter-clockwise from the lower angle, the last one wrapping around.
 *   An edge exists only if every one of its segments (an arc: its chords) is clear of every
 *   inflated disc: distance from the centre >= R_k, compared squared.
 * Dijkstra from S with a binary heap ordered by (distance, node index); a counter-clockwise arc
 * costs (1 + VS_PLAN_SIDE_BIAS) times its length, a clockwise one its length.
 */
#include <math.h>     /* sqrt and INFINITY only */
#include <stdlib.h>

#include "vs_plan.h"

typedef struct { double a; int i; } vs_ang_idx;
typedef struct { double d; int v; } vs_heap_item;

typedef struct {
    size_t m;
    const double *obs;          /* m*3 */
    double *r2;                 /* inflated radius squared, m */
    double *p;                  /* planning radius, m */
    unsigned char *s_in;        /* start inside the inflated disc, m */
    /* nodes */
    double *nx, *ny, *na;
    int *nc;
    size_t nv;
    /* edges */
    int *eu, *ev, *ek, *en;
    double *ecf, *ecb, *ea, *es;
    size_t ne;
} vs_plan_ctx;

static int cmp_ang_idx(const void *pa, const void *pb)
{
    const vs_ang_idx *a = (const vs_ang_idx *)pa, *b = (const vs_ang_idx *)pb;
    if (a->a < b->a) return -1;
    if (a->a > b->a) return 1;
    return (a->i > b->i) - (a->i < b->i);
}

/* segment A-B clear of every inflated disc; from_start: A is the start, and a disc that holds the
 * start only asks that the segment not get nearer its centre */
static int seg_clear(const vs_plan_ctx *c, double ax, double ay, double bx, double by, int from_start)
{
    double dx = bx - ax, dy = by - ay;
    double l2 = dx * dx + dy * dy;
    for (size_t j = 0; j < c->m; j++) {
        double cx = c->obs[3 * j], cy = c->obs[3 * j + 1];
        if (from_start && c->s_in[j]) {
            if (dx * (ax - cx) + dy * (ay - cy) < 0.0) return 0;
            continue;
        }
        double wx = cx - ax, wy = cy - ay;
        double t = l2 > 0.0 ? (wx * dx + wy * dy) / l2 : 0.0;
        if (t < 0.0) t = 0.0;
        if (t > 1.0) t = 1.0;
        double qx = ax + t * dx - cx, qy = ay + t * dy - cy;
        if (qx * qx + qy * qy < c->r2[j]) return 0;
    }
    return 1;
}

static int add_node(vs_plan_ctx *c, int k, double ex, double ey)
{
    double cx = c->obs[3 * k], cy = c->obs[3 * k + 1], p = c->p[k];
    size_t v = c->nv++;
    c->nx[v] = cx + p * ex;
    c->ny[v] = cy + p * ey;
    c->na[v] = vs_atan2(ey, ex);
    c->nc[v] = k;
    return (int)v;
}

static void add_edge(vs_plan_ctx *c, int u, int v, double cf, double cb, int k, double a, double s, int nseg)
{
    size_t e = c->ne++;
    c->eu[e] = u; c->ev[e] = v; c->ecf[e] = cf; c->ecb[e] = cb;
    c->ek[e] = k; c->ea[e] = a; c->es[e] = s; c->en[e] = nseg;
}

static double dist(double ax, double ay, double bx, double by)
{
    double dx = bx - ax, dy = by - ay;
    return sqrt(dx * dx + dy * dy);
}

/* a straight edge u-v if clear (u == 0: from the start) */
static void try_segment(vs_plan_ctx *c, int u, int v)
{
    if (seg_clear(c, c->nx[u], c->ny[u], c->nx[v], c->ny[v], u == 0)) {
        double l = dist(c->nx[u], c->ny[u], c->nx[v], c->ny[v]);
        add_edge(c, u, v, l, l, -1, 0.0, 0.0, 0);
    }
}

/* the point (x, y) seen from circle k: its tangent points (d > P_k) or its radial projection;
 * returns the number of nodes made, their indices in out */
static int point_nodes(vs_plan_ctx *c, int k, double x, double y, int tangents_only_outside, int out[2])
{
    double cx = c->obs[3 * k], cy = c->obs[3 * k + 1], p = c->p[k];
    double dx = x - cx, dy = y - cy, d2 = dx * dx + dy * dy;
    if (tangents_only_outside && d2 > p * p) {
        double d = sqrt(d2), ux = dx / d, uy = dy / d;
        double ca = p / d, sa = sqrt(1.0 - ca * ca);
        out[0] = add_node(c, k, ca * ux - sa * uy, ca * uy + sa * ux);
        out[1] = add_node(c, k, ca * ux + sa * uy, ca * uy - sa * ux);
        return 2;
    }
    if (d2 > 0.0) {
        double d = sqrt(d2);
        out[0] = add_node(c, k, dx / d, dy / d);
    } else {
        out[0] = add_node(c, k, 1.0, 0.0);
    }
    return 1;
}

static void heap_push(vs_heap_item *h, size_t *n, double d, int v)
{
    size_t i = (*n)++;
    while (i > 0) {
        size_t parent = (i - 1) / 2;
        vs_heap_item q = h[parent];
        if (q.d < d || (q.d == d && q.v < v)) break;
        h[i] = q;
        i = parent;
    }
    h[i].d = d;
    h[i].v = v;
}

static vs_heap_item heap_pop(vs_heap_item *h, size_t *n)
{
    vs_heap_item top = h[0], last = h[--(*n)];
    size_t i = 0;
    for (;;) {
        size_t l = 2 * i + 1, r = l + 1, s = l;
        if (l >= *n) break;
        if (r < *n && (h[r].d < h[l].d || (h[r].d == h[l].d && h[r].v < h[l].v))) s = r;
        if (last.d < h[s].d || (last.d == h[s].d && last.v < h[s].v)) break;
        h[i] = h[s];
        i = s;
    }
    if (*n > 0) h[i] = last;
    return top;
}

int vs_plan_radius(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                   double *radius_out_m)
{
    if (n == 0) return VS_EVALUE;
    if (!vs_isfinite(margin_m)) return VS_ENONFINITE;
    for (size_t i = 0; i < n; i++)
        if (!vs_isfinite(template_xy[2 * i]) || !vs_isfinite(template_xy[2 * i + 1]) || !vs_isfinite(radius_m[i]))
            return VS_ENONFINITE;
    if (margin_m < 0.0 || margin_m > VS_PLAN_MAX_ABS_M) return VS_EVALUE;
    double best = 0.0;
    for (size_t i = 0; i < n; i++) {
        double px = template_xy[2 * i], py = template_xy[2 * i + 1], r = radius_m[i];
        if (r < 0.0 || r > VS_PLAN_MAX_ABS_M || vs_fabs(px) > VS_PLAN_MAX_ABS_M || vs_fabs(py) > VS_PLAN_MAX_ABS_M)
            return VS_EVALUE;
        double e = sqrt(px * px + py * py) + r;
        if (e > best) best = e;
    }
    *radius_out_m = best + margin_m;
    return VS_OK;
}

int vs_plan_structure(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                      const double *obstacles, size_t n_obstacles, const double start[3],
                      const double goal[3], double *waypoints, size_t cap, size_t *n_waypoints,
                      int *status)
{
    if (cap == 0 || n == 0 || n_obstacles > VS_PLAN_MAX_OBSTACLES) return VS_EVALUE;
    /* every value finite first (VS_ENONFINITE), then the ranges (VS_EVALUE) */
    for (int k = 0; k < 3; k++)
        if (!vs_isfinite(start[k]) || !vs_isfinite(goal[k])) return VS_ENONFINITE;
    for (size_t j = 0; j < 3 * n_obstacles; j++)
        if (!vs_isfinite(obstacles[j])) return VS_ENONFINITE;
    double big_r;
    int rc = vs_plan_radius(template_xy, radius_m, n, margin_m, &big_r);
    if (rc != VS_OK) return rc;
    for (int k = 0; k < 3; k++)
        if (vs_fabs(start[k]) > VS_PLAN_MAX_ABS_M || vs_fabs(goal[k]) > VS_PLAN_MAX_ABS_M) return VS_EVALUE;
    for (size_t j = 0; j < n_obstacles; j++) {
        const double *o = obstacles + 3 * j;
        if (vs_fabs(o[0]) > VS_PLAN_MAX_ABS_M || vs_fabs(o[1]) > VS_PLAN_MAX_ABS_M || !(o[2] > 0.0)
            || o[2] > VS_PLAN_MAX_ABS_M)
            return VS_EVALUE;
    }

    size_t m = n_obstacles;
    size_t vmax = 2 + 5 * m + 4 * m * (m > 0 ? m - 1 : 0);
    size_t emax = 1 + 5 * m + 2 * m * (m > 0 ? m - 1 : 0) + (vmax - 2);
    vs_plan_ctx c;
    c.m = m; c.obs = obstacles; c.nv = 0; c.ne = 0;
    c.r2 = malloc((m + 1) * sizeof *c.r2);
    c.p = malloc((m + 1) * sizeof *c.p);
    c.s_in = malloc(m + 1);
    c.nx = malloc(vmax * sizeof *c.nx);
    c.ny = malloc(vmax * sizeof *c.ny);
    c.na = malloc(vmax * sizeof *c.na);
    c.nc = malloc(vmax * sizeof *c.nc);
    c.eu = malloc(emax * sizeof *c.eu);
    c.ev = malloc(emax * sizeof *c.ev);
    c.ek = malloc(emax * sizeof *c.ek);
    c.en = malloc(emax * sizeof *c.en);
    c.ecf = malloc(emax * sizeof *c.ecf);
    c.ecb = malloc(emax * sizeof *c.ecb);
    c.ea = malloc(emax * sizeof *c.ea);
    c.es = malloc(emax * sizeof *c.es);
    vs_ang_idx *sorted = malloc(vmax * sizeof *sorted);
    size_t *coff = malloc((m + 2) * sizeof *coff);
    size_t *aoff = malloc((vmax + 1) * sizeof *aoff);
    int *adj = malloc(2 * emax * sizeof *adj);
    double *dist_v = malloc(vmax * sizeof *dist_v);
    int *pred = malloc(vmax * sizeof *pred);
    unsigned char *settled = malloc(vmax);
    vs_heap_item *heap = malloc((2 * emax + 1) * sizeof *heap);
    int *chain = malloc(vmax * sizeof *chain);
    double *pts = NULL;
    rc = VS_ENOMEM;
    if (!c.r2 || !c.p || !c.s_in || !c.nx || !c.ny || !c.na || !c.nc || !c.eu || !c.ev || !c.ek || !c.en
        || !c.ecf || !c.ecb || !c.ea || !c.es || !sorted || !coff || !aoff || !adj || !dist_v || !pred
        || !settled || !heap || !chain)
        goto done;

    for (size_t k = 0; k < m; k++) {
        double rk = obstacles[3 * k + 2] + big_r;
        double dx = start[0] - obstacles[3 * k], dy = start[1] - obstacles[3 * k + 1];
        c.r2[k] = rk * rk;
        c.p[k] = rk * (1.0 + VS_PLAN_SLACK);
        c.s_in[k] = (unsigned char)(dx * dx + dy * dy < c.r2[k]);
    }

    /* nodes and straight edges */
    c.nx[0] = start[0]; c.ny[0] = start[1]; c.na[0] = 0.0; c.nc[0] = -1;
    c.nx[1] = goal[0]; c.ny[1] = goal[1]; c.na[1] = 0.0; c.nc[1] = -1;
    c.nv = 2;
    try_segment(&c, 0, 1);
    for (size_t k = 0; k < m; k++) {
        int made[2], cnt;
        cnt = point_nodes(&c, (int)k, start[0], start[1], 1, made);
        for (int q = 0; q < cnt; q++) try_segment(&c, 0, made[q]);
        double gdx = goal[0] - obstacles[3 * k], gdy = goal[1] - obstacles[3 * k + 1];
        if (gdx * gdx + gdy * gdy > c.p[k] * c.p[k]) {
            cnt = point_nodes(&c, (int)k, goal[0], goal[1], 1, made);
            for (int q = 0; q < cnt; q++) try_segment(&c, made[q], 1);
        }
        (void)point_nodes(&c, (int)k, goal[0], goal[1], 0, made);
        try_segment(&c, made[0], 1);
    }
    for (size_t a = 0; a < m; a++) {
        for (size_t b = a + 1; b < m; b++) {
            double dx = obstacles[3 * b] - obstacles[3 * a], dy = obstacles[3 * b + 1] - obstacles[3 * a + 1];
            double d = sqrt(dx * dx + dy * dy), pa = c.p[a], pb = c.p[b];
            for (int inner = 0; inner < 2; inner++) {
                double sum = inner ? pa + pb : pa - pb;
                if (!(d > vs_fabs(sum))) continue;
                double ux = dx / d, uy = dy / d, cg = sum / d, sg = sqrt(1.0 - cg * cg);
                for (int sgn = 0; sgn < 2; sgn++) {
                    double s = sgn ? -sg : sg;
                    double ex = cg * ux - s * uy, ey = cg * uy + s * ux;
                    int na = add_node(&c, (int)a, ex, ey);
                    int nb = inner ? add_node(&c, (int)b, -ex, -ey) : add_node(&c, (int)b, ex, ey);
                    try_segment(&c, na, nb);
                }
            }
        }
    }

    /* arcs: nodes of each circle in angle order (ties by index) */
    for (size_t k = 0; k <= m; k++) coff[k] = 0;
    for (size_t v = 2; v < c.nv; v++) coff[c.nc[v] + 1]++;
    for (size_t k = 0; k < m; k++) coff[k + 1] += coff[k];
    {
        size_t *fill = aoff;   /* borrowed as a cursor, rebuilt below */
        for (size_t k = 0; k < m; k++) fill[k] = coff[k];
        for (size_t v = 2; v < c.nv; v++) {
            size_t at = fill[c.nc[v]]++;
            sorted[at].a = c.na[v];
            sorted[at].i = (int)v;
        }
    }
    for (size_t k = 0; k < m; k++) {
        size_t lo = coff[k], cnt = coff[k + 1] - coff[k];
        if (cnt < 2) continue;
        qsort(sorted + lo, cnt, sizeof *sorted, cmp_ang_idx);
        double cx = obstacles[3 * k], cy = obstacles[3 * k + 1], p = c.p[k];
        for (size_t q = 0; q < cnt; q++) {
            int u = sorted[lo + q].i, v = sorted[lo + (q + 1) % cnt].i;
            double alpha = c.na[u];
            double span = c.na[v] - alpha;
            if (q + 1 == cnt) span += VS_TWO_PI;
            int nseg = (int)(span / VS_PLAN_ARC_STEP_RAD) + 1;
            double step = span / nseg;
            double px = c.nx[u], py = c.ny[u];
            int clear = 1;
            for (int i = 1; i < nseg && clear; i++) {
                double s, co;
                vs_sincos(alpha + step * i, &s, &co);
                double qx = cx + p * co, qy = cy + p * s;
                clear = seg_clear(&c, px, py, qx, qy, 0);
                px = qx; py = qy;
            }
            if (clear && seg_clear(&c, px, py, c.nx[v], c.ny[v], 0)) {
                double len = p * span;
                add_edge(&c, u, v, len * (1.0 + VS_PLAN_SIDE_BIAS), len, (int)k, alpha, span, nseg);
            }
        }
    }

    /* adjacency (each node's edges in edge order) and Dijkstra from the start */
    size_t nv = c.nv;
    for (size_t v = 0; v <= nv; v++) aoff[v] = 0;
    for (size_t e = 0; e < c.ne; e++) { aoff[c.eu[e] + 1]++; aoff[c.ev[e] + 1]++; }
    for (size_t v = 0; v < nv; v++) aoff[v + 1] += aoff[v];
    {
        size_t *cur = (size_t *)malloc((nv + 1) * sizeof *cur);
        if (cur == NULL) goto done;
        for (size_t v = 0; v < nv; v++) cur[v] = aoff[v];
        for (size_t e = 0; e < c.ne; e++) {
            adj[cur[c.eu[e]]++] = (int)(2 * e);          /* forward: u -> v */
            adj[cur[c.ev[e]]++] = (int)(2 * e + 1);      /* backward: v -> u */
        }
        free(cur);
    }
    for (size_t v = 0; v < nv; v++) { dist_v[v] = INFINITY; pred[v] = -1; settled[v] = 0; }
    size_t hn = 0;
    dist_v[0] = 0.0;
    heap_push(heap, &hn, 0.0, 0);
    while (hn > 0) {
        vs_heap_item it = heap_pop(heap, &hn);
        int u = it.v;
        if (settled[u]) continue;
        settled[u] = 1;
        if (u == 1) break;
        for (size_t q = aoff[u]; q < aoff[u + 1]; q++) {
            int de = adj[q], e = de / 2, back = de % 2;
            int v = back ? c.eu[e] : c.ev[e];
            double nd = it.d + (back ? c.ecb[e] : c.ecf[e]);
            if (nd < dist_v[v]) {
                dist_v[v] = nd;
                pred[v] = de;
                heap_push(heap, &hn, nd, v);
            }
        }
    }

    /* the target: the goal, or the reachable node nearest it */
    int target = 1, st = VS_PLAN_OK;
    if (!settled[1]) {
        st = VS_PLAN_BLOCKED;
        double best = INFINITY;
        for (size_t v = 0; v < nv; v++)
            if (v != 1 && dist_v[v] < INFINITY) {
                double g = dist(c.nx[v], c.ny[v], goal[0], goal[1]);
                if (g < best) best = g;
            }
        for (size_t v = 0; v < nv; v++)
            if (v != 1 && dist_v[v] < INFINITY
                && dist(c.nx[v], c.ny[v], goal[0], goal[1]) <= best + VS_PLAN_GOAL_TIE_M) {
                target = (int)v;
                break;
            }
    }

    /* the polyline: the chain of edges from the start to the target, arcs drawn as chords */
    size_t nchain = 0, npts_max = 1;
    for (int v = target; v != 0; ) {
        int de = pred[v], e = de / 2;
        chain[nchain++] = de;
        npts_max += c.ek[e] >= 0 ? (size_t)c.en[e] : 1;
        v = (de % 2) ? c.ev[e] : c.eu[e];
    }
    pts = malloc(2 * npts_max * sizeof *pts);
    if (pts == NULL) goto done;
    size_t np = 0;
    pts[0] = start[0]; pts[1] = start[1]; np = 1;
    for (size_t q = nchain; q-- > 0; ) {
        int de = chain[q], e = de / 2, back = de % 2;
        int k = c.ek[e];
        if (k >= 0) {
            int nseg = c.en[e];
            double step = c.es[e] / nseg, cx = obstacles[3 * k], cy = obstacles[3 * k + 1], p = c.p[k];
            for (int j = 1; j < nseg; j++) {
                int i = back ? nseg - j : j;
                double s, co;
                vs_sincos(c.ea[e] + step * i, &s, &co);
                double qx = cx + p * co, qy = cy + p * s;
                if (qx != pts[2 * np - 2] || qy != pts[2 * np - 1]) { pts[2 * np] = qx; pts[2 * np + 1] = qy; np++; }
            }
        }
        int v = back ? c.eu[e] : c.ev[e];
        if (q == 0 || c.nx[v] != pts[2 * np - 2] || c.ny[v] != pts[2 * np - 1]) {
            pts[2 * np] = c.nx[v]; pts[2 * np + 1] = c.ny[v]; np++;
        }
    }
    if (np > cap) {
        *n_waypoints = np;
        rc = VS_ENOMEM;
        goto done;
    }

    /* headings */
    double th0 = vs_wrap_angle(start[2]);
    double dth = vs_wrap_angle(goal[2] - th0);
    double total = 0.0;
    for (size_t i = 1; i < np; i++) total += dist(pts[2 * i - 2], pts[2 * i - 1], pts[2 * i], pts[2 * i + 1]);
    double s_acc = 0.0;
    for (size_t i = 0; i < np; i++) {
        if (i > 0) s_acc += dist(pts[2 * i - 2], pts[2 * i - 1], pts[2 * i], pts[2 * i + 1]);
        double th = th0;
        if (st == VS_PLAN_OK) {
            if (i + 1 == np) th = vs_wrap_angle(goal[2]);
            else if (total > 0.0) th = vs_wrap_angle(th0 + dth * (s_acc / total));
        }
        waypoints[3 * i] = pts[2 * i];
        waypoints[3 * i + 1] = pts[2 * i + 1];
        waypoints[3 * i + 2] = th;
    }
    *n_waypoints = np;
    *status = st;
    rc = VS_OK;

done:
    free(c.r2); free(c.p); free(c.s_in); free(c.nx); free(c.ny); free(c.na); free(c.nc);
    free(c.eu); free(c.ev); free(c.ek); free(c.en); free(c.ecf); free(c.ecb); free(c.ea); free(c.es);
    free(sorted); free(coff); free(aoff); free(adj); free(dist_v); free(pred); free(settled); free(heap);
    free(chain); free(pts);
    return rc;
}
