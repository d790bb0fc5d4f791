/* vs_assembly.c - the assembly tie-break (see vs_assembly.h).
 *
 * The numpy reference (vsfleet/assembly.py) computes (n, n) tables of along, lateral and bars and
 * then walks the rows in order, in four passes (as below); here the same numbers are
 * computed where they are needed, with no table: robot i's row of the tables in one pass over j, and
 * bars[j][i] (head on or not) again from robot j's own way.  Every number is the reference's expression, in its order:
 *     to = point - xy, dist = sqrt(to.x to.x + to.y to.y), d = to / dist,
 *     rel = xy_j - xy_i, along = rel.x d.x + rel.y d.y, lateral = d.x rel.y - d.y rel.x,
 *     width = (r_i + r_j) + margin, gap = sqrt(rel.x rel.x + rel.y rel.y), u = rel / gap,
 *     way = (xy_i + normal clear) + u (gap - clear),
 * and the first blocker is numpy's argmin: the least along, the first (lowest row) of equal ones.  So
 * the outputs are the reference's bits for every finite input (-ffp-contract=off: no fused
 * multiply-add); finite inputs so large that a square overflows give inf or NaN in both alike, and so do
 * two robots whose offset underflows to a gap of 0 where round_blocker() divides by it (a third-pass escape
 * skips such a pair). */
#include <math.h>   /* sqrt only */
#include <stdint.h>

#include "vscore.h"
#include "vs_assembly.h"

/* detoured_out's marks while the passes run (vs_assembly_targets): the pass that sent a row round (1, 2, 3),
 * BOXED if it was boxed in, STEPS_ASIDE for a placed robot that steps aside; all 1 in the end */
#define MARK(d) ((d) & 0x0F)
#define BOXED 0x10
#define STEPS_ASIDE 4

/* The priorities' draw for a mission elapsed_s [s] old (finite): 0 for its first VS_PRIORITY_S seconds (and before
 * them), then the count of whole periods, saturated at UINT32_MAX. */
static uint32_t priority_draw(double elapsed_s)
{
    double q = elapsed_s / VS_PRIORITY_S;
    if (!(q >= 1.0)) return 0;
    return q < 4294967296.0 ? (uint32_t)q : UINT32_MAX;
}

/* Robot i's rank in draw e: i itself in draw 0, else a 32-bit mix of i and e (vs_assembly.h). */
static uint32_t rank_of(size_t i, uint32_t e)
{
    if (e == 0) return (uint32_t)i;
    uint32_t h = (uint32_t)((uint32_t)i * UINT32_C(0x9E3779B1)) ^ (uint32_t)(e * UINT32_C(0x85EBCA77));
    h ^= h >> 15;
    h = (uint32_t)(h * UINT32_C(0x2C1B3C6D));
    h ^= h >> 12;
    h = (uint32_t)(h * UINT32_C(0x297A2D39));
    h ^= h >> 15;
    return h;
}

/* Does robot a come before robot b in draw e (the lower rank; equal ranks: the lower row)? */
static int before(size_t a, size_t b, uint32_t e)
{
    uint32_t ra = rank_of(a, e), rb = rank_of(b, e);
    return ra < rb || (ra == rb && a < b);
}

/* Robot i's way to its point: 1 if it is on its way (seen, more than VS_ASSEMBLING_M from its point),
 * with its distance and direction. */
static int on_way(const double *pose_world, const unsigned char *seen, const double *points_now, size_t i,
                  double *dist, double *dx, double *dy)
{
    if (!seen[i]) return 0;
    double tx = points_now[2 * i] - pose_world[3 * i], ty = points_now[2 * i + 1] - pose_world[3 * i + 1];
    double d = sqrt(tx * tx + ty * ty);
    if (!(d > VS_ASSEMBLING_M)) return 0;
    *dist = d;
    *dx = tx / d;
    *dy = ty / d;
    return 1;
}

/* Does j (seen) bar robot i, on its way (dist, d)?  along and lateral of j on i's way are set. */
static int bars(const double *radius_m, const double *pose_world, double margin_m, size_t i, double dist, double dx,
                double dy, size_t j, double *along, double *lateral, double *width)
{
    double rx = pose_world[3 * j] - pose_world[3 * i], ry = pose_world[3 * j + 1] - pose_world[3 * i + 1];
    double a = rx * dx + ry * dy;
    double l = dx * ry - dy * rx;
    double w = (radius_m[i] + radius_m[j]) + margin_m;
    *along = a;
    *lateral = l;
    *width = w;
    return a > 0.0 && a < dist + w && vs_fabs(l) < w;
}

/* Is robot i's straight way to (wx, wy) barred (as bars() says) by a seen robot other than i and skip (n: none)?
 * A way of length 0 is not barred. */
static int way_barred(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                      double margin_m, size_t i, size_t skip, double wx, double wy)
{
    double tx = wx - pose_world[3 * i], ty = wy - pose_world[3 * i + 1];
    double wd = sqrt(tx * tx + ty * ty);
    if (!(wd > 0.0)) return 0;
    double dx = tx / wd, dy = ty / wd;
    for (size_t k = 0; k < n; k++) {
        double along, lateral, width;
        if (k == i || k == skip || !seen[k]) continue;
        if (bars(radius_m, pose_world, margin_m, i, wd, dx, dy, k, &along, &lateral, &width)) return 1;
    }
    return 0;
}

/* Robot i's first blocker on its way (dist, d): the least along among the seen robots that bar it, the
 * first (lowest row) of equal ones; n if none.  Its lateral and width are set. */
static size_t first_blocker(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                            double margin_m, size_t i, double dist, double dx, double dy, double *lat_j,
                            double *width_j)
{
    size_t j = n;
    double best = 0.0;
    for (size_t k = 0; k < n; k++) {
        double along, lateral, width;
        if (k == i || !seen[k]) continue;
        if (!bars(radius_m, pose_world, margin_m, i, dist, dx, dy, k, &along, &lateral, &width)) continue;
        if (j == n || along < best) {
            j = k;
            best = along;
            *lat_j = lateral;
            *width_j = width;
        }
    }
    return j;
}

/* A robot i that gives way to j (its centre at gap [m] along (ux, uy) from i's; (nx, ny) the unit normal to the side
 * i passes on) and cannot go round: VS_ESCAPE_M straight back from j, else out of the crowd (away from (cx, cy)),
 * else 45 degrees off back towards the passing side, then the other, then 90 degrees off back towards the passing
 * side, then the other, the first way no robot bars; else its own position (it waits). */
static void escape(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                   double margin_m, size_t i, double ux, double uy, double nx, double ny, double cx, double cy,
                   double *wx_out, double *wy_out)
{
    double x = pose_world[3 * i], y = pose_world[3 * i + 1];
    double ox = x - cx, oy = y - cy;
    double od = sqrt(ox * ox + oy * oy);
    double ex = x - ux * VS_ESCAPE_M, ey = y - uy * VS_ESCAPE_M;
    int found = !way_barred(n, radius_m, pose_world, seen, margin_m, i, n, ex, ey);
    if (!found && od > 0.0) {
        ex = x + (ox / od) * VS_ESCAPE_M;
        ey = y + (oy / od) * VS_ESCAPE_M;
        found = !way_barred(n, radius_m, pose_world, seen, margin_m, i, n, ex, ey);
    }
    double h = sqrt(0.5);
    double fan[4][2] = {{h * (nx - ux), h * (ny - uy)}, {h * (-nx - ux), h * (-ny - uy)}, {nx, ny}, {-nx, -ny}};
    for (int k = 0; k < 4 && !found; k++) {
        ex = x + fan[k][0] * VS_ESCAPE_M;
        ey = y + fan[k][1] * VS_ESCAPE_M;
        found = !way_barred(n, radius_m, pose_world, seen, margin_m, i, n, ex, ey);
    }
    if (!found) {
        ex = x;
        ey = y;
    }
    *wx_out = ex;
    *wy_out = ey;
}

/* Robot i's target round its blocker j, on the side left (1: j on i's right, pass on its left; -1: on its
 * right), width_j = r_i + r_j + margin: the detour's waypoint, or, boxed in, escape() (then 1 is returned and
 * the waypoint it could not take is in (*way_x, *way_y); else 0). */
static int round_blocker(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                         double margin_m, size_t i, size_t j, double left, double width_j, double cx, double cy,
                         double *wx_out, double *wy_out, double *way_x, double *way_y)
{
    double rx = pose_world[3 * j] - pose_world[3 * i], ry = pose_world[3 * j + 1] - pose_world[3 * i + 1];
    double gap = sqrt(rx * rx + ry * ry);
    double ux = rx / gap, uy = ry / gap;                   /* towards j */
    double nx = -uy * left, ny = ux * left;
    double clear = width_j + VS_DETOUR_CLEAR_M;   /* round j: as far beside the line to j, that much short */
    double wx = (pose_world[3 * i] + nx * clear) + ux * (gap - clear);
    double wy = (pose_world[3 * i + 1] + ny * clear) + uy * (gap - clear);
    *way_x = wx;
    *way_y = wy;
    int boxed = gap - width_j < VS_PRESSED_M && way_barred(n, radius_m, pose_world, seen, margin_m, i, j, wx, wy);
    if (boxed) escape(n, radius_m, pose_world, seen, margin_m, i, ux, uy, nx, ny, cx, cy, &wx, &wy);
    *wx_out = wx;
    *wy_out = wy;
    return boxed;
}

/* Robot i (sent round, its target in now_out): the same in next_out, marked detoured (mark: the pass's mark);
 * boxed in (boxed): marked BOXED too, with the waypoint it could not take, (way_x, way_y), kept in next_out
 * until the last pass (placed robots step aside) has read it. */
static void send_round_boxed(size_t i, const double *now_out, double *next_out, unsigned char *detoured_out,
                             unsigned char mark, int boxed, double way_x, double way_y)
{
    next_out[2 * i] = boxed ? way_x : now_out[2 * i];
    next_out[2 * i + 1] = boxed ? way_y : now_out[2 * i + 1];
    detoured_out[i] = (unsigned char)(boxed ? mark | BOXED : mark);
}

/* Robot i, its waypoint already in now_out: the same in next_out, marked detoured (mark: the pass's mark). */
static void send_round(size_t i, const double *now_out, double *next_out, unsigned char *detoured_out,
                       unsigned char mark)
{
    next_out[2 * i] = now_out[2 * i];
    next_out[2 * i + 1] = now_out[2 * i + 1];
    detoured_out[i] = mark;
}

/* The first robot (as first_blocker) on robot i's way to its target now_out[i]; n if none or the target is its
 * own position.  Its lateral and width are set. */
static size_t first_on_target(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                              double margin_m, const double *now_out, size_t i, double *lat_k, double *width_k)
{
    double tx = now_out[2 * i] - pose_world[3 * i], ty = now_out[2 * i + 1] - pose_world[3 * i + 1];
    double t = sqrt(tx * tx + ty * ty);
    if (!(t > 0.0)) return n;
    return first_blocker(n, radius_m, pose_world, seen, margin_m, i, t, tx / t, ty / t, lat_k, width_k);
}

int vs_assembly_targets(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                        const double *points_now, const double *points_next, double margin_m, double elapsed_s,
                        double *now_out, double *next_out, unsigned char *detoured_out, size_t *n_detoured)
{
    if (n > 0 && (radius_m == NULL || pose_world == NULL || seen == NULL || points_now == NULL
                  || points_next == NULL || now_out == NULL || next_out == NULL || detoured_out == NULL))
        return VS_EVALUE;
    if (!vs_isfinite(margin_m) || !vs_isfinite(elapsed_s)) return VS_ENONFINITE;
    if (!(margin_m >= 0.0)) return VS_EVALUE;
    for (size_t i = 0; i < n; i++) {
        if (!seen[i]) continue;
        if (!(vs_isfinite(radius_m[i]) && vs_isfinite(pose_world[3 * i]) && vs_isfinite(pose_world[3 * i + 1])
              && vs_isfinite(points_now[2 * i]) && vs_isfinite(points_now[2 * i + 1])
              && vs_isfinite(points_next[2 * i]) && vs_isfinite(points_next[2 * i + 1])))
            return VS_ENONFINITE;
        if (!(radius_m[i] >= 0.0)) return VS_EVALUE;
    }
    for (size_t i = 0; i < 2 * n; i++) {
        now_out[i] = points_now[i];
        next_out[i] = points_next[i];
    }
    const uint32_t e = priority_draw(elapsed_s);
    for (size_t i = 0; i < n; i++) detoured_out[i] = 0;
    /* the centroid of the seen robots, summed in row order: a boxed-in robot heads away from it */
    double cx = 0.0, cy = 0.0, cn = 0.0;
    for (size_t i = 0; i < n; i++) {
        if (!seen[i]) continue;
        cx = cx + pose_world[3 * i];
        cy = cy + pose_world[3 * i + 1];
        cn = cn + 1.0;
    }
    if (cn > 0.0) {
        cx = cx / cn;
        cy = cy / cn;
    }
    for (size_t i = 0; i < n && n >= 2; i++) {
        double dist, dx, dy, lat_j = 0.0, width_j = 0.0;
        if (!on_way(pose_world, seen, points_now, i, &dist, &dx, &dy)) continue;
        size_t j = first_blocker(n, radius_m, pose_world, seen, margin_m, i, dist, dx, dy, &lat_j, &width_j);
        if (j == n) continue;
        /* head on: j bars i too (j on its way, i ahead on it) */
        double dist_j, dx_j, dy_j, along_ji, lat_ji, width_ji;
        int mutual = on_way(pose_world, seen, points_now, j, &dist_j, &dx_j, &dy_j)
                     && bars(radius_m, pose_world, margin_m, j, dist_j, dx_j, dy_j, i, &along_ji, &lat_ji, &width_ji);
        if (mutual && before(i, j, e)) {
            /* head on, and i comes first: i keeps its way, unless a robot k before i bars i head on too */
            int yields = 0;
            for (size_t k = 0; k < n && !yields; k++) {
                double along_ik, lat_ik, width_ik, dist_k, dx_k, dy_k, along_ki, lat_ki, width_ki;
                if (k == i || !seen[k] || !before(k, i, e)) continue;
                yields = bars(radius_m, pose_world, margin_m, i, dist, dx, dy, k, &along_ik, &lat_ik, &width_ik)
                         && on_way(pose_world, seen, points_now, k, &dist_k, &dx_k, &dy_k)
                         && bars(radius_m, pose_world, margin_m, k, dist_k, dx_k, dy_k, i, &along_ki, &lat_ki,
                                 &width_ki);
            }
            if (!yields) continue;
        }
        double left = (!mutual && lat_j < 0.0) ? 1.0 : -1.0;   /* j on i's right: pass on its left */
        double way_x, way_y;
        int boxed = round_blocker(n, radius_m, pose_world, seen, margin_m, i, j, left, width_j, cx, cy,
                                  &now_out[2 * i], &now_out[2 * i + 1], &way_x, &way_y);
        send_round_boxed(i, now_out, next_out, detoured_out, 1, boxed, way_x, way_y);
    }
    /* a robot that kept its way (barred, not sent round: head on, coming first) into a first blocker that waits
     * (sent round, its target its own position) gives way in turn: round it on its right.  Each row reads the
     * first pass's targets: the rows this pass sends round are marked 2, and a first blocker counts only if
     * marked 1 (MARK: BOXED or not); a row's own outputs are written only at that row. */
    for (size_t i = 0; i < n && n >= 2; i++) {
        double dist, dx, dy, lat_j = 0.0, width_j = 0.0;
        if (detoured_out[i] || !on_way(pose_world, seen, points_now, i, &dist, &dx, &dy)) continue;
        size_t j = first_blocker(n, radius_m, pose_world, seen, margin_m, i, dist, dx, dy, &lat_j, &width_j);
        if (j == n || MARK(detoured_out[j]) != 1 || now_out[2 * j] != pose_world[3 * j]
            || now_out[2 * j + 1] != pose_world[3 * j + 1])
            continue;
        double way_x, way_y;
        int boxed = round_blocker(n, radius_m, pose_world, seen, margin_m, i, j, -1.0, width_j, cx, cy,
                                  &now_out[2 * i], &now_out[2 * i + 1], &way_x, &way_y);
        send_round_boxed(i, now_out, next_out, detoured_out, 2, boxed, way_x, way_y);
    }
    /* a robot on its way pressed against the first robot k on its way to its target, k before it, and barring k's
     * way to k's target in turn (their targets cross): it escapes from k, as if boxed in, passing on its right.
     * Decided on the second pass's targets (rows marked 3), then written. */
    for (size_t i = 0; i < n && n >= 2; i++) {
        double dist, dx, dy, lat_k = 0.0, width_k = 0.0;
        if (!on_way(pose_world, seen, points_now, i, &dist, &dx, &dy)) continue;
        size_t k = first_on_target(n, radius_m, pose_world, seen, margin_m, now_out, i, &lat_k, &width_k);
        if (k == n || !before(k, i, e)) continue;
        double rx = pose_world[3 * k] - pose_world[3 * i], ry = pose_world[3 * k + 1] - pose_world[3 * i + 1];
        double gap = sqrt(rx * rx + ry * ry);
        if (!(gap > 0.0) || !(gap - width_k < VS_PRESSED_M)) continue;
        double tx = now_out[2 * k] - pose_world[3 * k], ty = now_out[2 * k + 1] - pose_world[3 * k + 1];
        double tk = sqrt(tx * tx + ty * ty), along_ki, lat_ki, width_ki;
        if (!(tk > 0.0)
            || !bars(radius_m, pose_world, margin_m, k, tk, tx / tk, ty / tk, i, &along_ki, &lat_ki, &width_ki))
            continue;
        detoured_out[i] = 3;
    }
    for (size_t i = 0; i < n; i++) {
        double lat_k = 0.0, width_k = 0.0;
        if (detoured_out[i] != 3) continue;
        size_t k = first_on_target(n, radius_m, pose_world, seen, margin_m, now_out, i, &lat_k, &width_k);
        if (k == n) continue;   /* (never: the same k as decided, row i's target unchanged since) */
        double rx = pose_world[3 * k] - pose_world[3 * i], ry = pose_world[3 * k + 1] - pose_world[3 * i + 1];
        double gap = sqrt(rx * rx + ry * ry);
        double ux = rx / gap, uy = ry / gap;
        escape(n, radius_m, pose_world, seen, margin_m, i, ux, uy, uy, -ux, cx, cy, &now_out[2 * i],
               &now_out[2 * i + 1]);
        send_round(i, now_out, next_out, detoured_out, 1);
    }
    /* a placed robot (seen, not on its way) that bars the way of a boxed-in robot i (the lowest such row whose
     * target is still its escape) to the waypoint it could not take steps aside: VS_ESCAPE_M straight away from i,
     * else 45 then 90 degrees off that (left first), the first way no robot bars.  It reads the marks and waypoints
     * of the passes above, and writes only its own row, marked STEPS_ASIDE (never BOXED). */
    int any_boxed = 0;
    for (size_t i = 0; i < n; i++) any_boxed |= detoured_out[i] & BOXED;
    for (size_t k = 0; k < n && any_boxed; k++) {
        double dist_k, dx_k, dy_k;
        if (!seen[k] || detoured_out[k] || on_way(pose_world, seen, points_now, k, &dist_k, &dx_k, &dy_k)) continue;
        for (size_t i = 0; i < n; i++) {
            double along, lateral, width;
            if (!(detoured_out[i] & BOXED)) continue;
            double tx = next_out[2 * i] - pose_world[3 * i], ty = next_out[2 * i + 1] - pose_world[3 * i + 1];
            double wd = sqrt(tx * tx + ty * ty);
            if (!(wd > 0.0)
                || !bars(radius_m, pose_world, margin_m, i, wd, tx / wd, ty / wd, k, &along, &lateral, &width))
                continue;
            double rx = pose_world[3 * k] - pose_world[3 * i], ry = pose_world[3 * k + 1] - pose_world[3 * i + 1];
            double g = sqrt(rx * rx + ry * ry);
            if (g > 0.0) {   /* away from i, then 45 degrees off it to the left and the right, then 90 */
                double ux = rx / g, uy = ry / g, h = sqrt(0.5);
                double fan[5][2] = {{ux, uy}, {h * (ux - uy), h * (uy + ux)}, {h * (ux + uy), h * (uy - ux)},
                                    {-uy, ux}, {uy, -ux}};
                for (int q = 0; q < 5; q++) {
                    double ax = pose_world[3 * k] + fan[q][0] * VS_ESCAPE_M;
                    double ay = pose_world[3 * k + 1] + fan[q][1] * VS_ESCAPE_M;
                    if (way_barred(n, radius_m, pose_world, seen, margin_m, k, n, ax, ay)) continue;
                    now_out[2 * k] = ax;
                    now_out[2 * k + 1] = ay;
                    send_round(k, now_out, next_out, detoured_out, STEPS_ASIDE);
                    break;
                }
            }
            break;
        }
    }
    size_t count = 0;
    for (size_t i = 0; i < n; i++) {
        if (detoured_out[i] & BOXED) {   /* its waypoint read: its target in next_out too */
            next_out[2 * i] = now_out[2 * i];
            next_out[2 * i + 1] = now_out[2 * i + 1];
        }
        if (detoured_out[i]) detoured_out[i] = 1;
        count += detoured_out[i];
    }
    if (n_detoured != NULL) *n_detoured = count;
    return VS_OK;
}
