/* vs_safety.c - the fleet-wide safety filter (see vs_safety.h and docs/safety.md). */
#include <stdlib.h>

#include "vscore.h"
#include "vs_safety.h"

/* magnitudes above this are refused: their squares (h = |d|^2 - D^2) would overflow */
#define BIG 1e150
/* a row a.u >= b holds at u when a.u - b >= -TOL (|a0| s + |a1| s + |b|), s the speed limit */
#define TOL 1e-10

static int ok_num(double x) { return vs_isfinite(x) && vs_fabs(x) <= BIG; }

static int all_ok(const double *a, size_t count)
{
    for (size_t k = 0; k < count; k++)
        if (!ok_num(a[k])) return 0;
    return 1;
}

/* every row k of rows (a0, a1, b) holds at (u0, u1) */
static int feasible(const double *rows, int m, double u0, double u1, double s)
{
    for (int k = 0; k < m; k++) {
        const double *r = rows + 3 * k;
        double tol = TOL * (vs_fabs(r[0]) * s + vs_fabs(r[1]) * s + vs_fabs(r[2]));
        if (r[0] * u0 + r[1] * u1 - r[2] < -tol) return 0;
    }
    return 1;
}

/* The Euclidean projection of u onto the polygon {a_k.x >= b_k}: 1 with out set, 0 if none of the
 * candidates is feasible (an empty polygon).  Candidates, in row order: the foot of every violated
 * row's line, and the vertex of every violated row k with every other row j (j > k if both are
 * violated); the first of the nearest is kept. */
static int project(const double *rows, int m, const double u[2], double s, double out[2])
{
    if (feasible(rows, m, u[0], u[1], s)) {
        out[0] = u[0];
        out[1] = u[1];
        return 1;
    }
    int found = 0;
    double best = 0.0;
    for (int k = 0; k < m; k++) {
        const double *rk = rows + 3 * k;
        double tolk = TOL * (vs_fabs(rk[0]) * s + vs_fabs(rk[1]) * s + vs_fabs(rk[2]));
        double slack = rk[0] * u[0] + rk[1] * u[1] - rk[2];
        if (!(slack < -tolk)) continue;
        double nk = rk[0] * rk[0] + rk[1] * rk[1];
        if (nk > 0.0) {
            double t = -slack / nk;
            double x0 = u[0] + t * rk[0], x1 = u[1] + t * rk[1];
            if (feasible(rows, m, x0, x1, s)) {
                double d = (x0 - u[0]) * (x0 - u[0]) + (x1 - u[1]) * (x1 - u[1]);
                if (!found || d < best) { found = 1; best = d; out[0] = x0; out[1] = x1; }
            }
        }
        for (int j = 0; j < m; j++) {
            if (j == k) continue;
            const double *rj = rows + 3 * j;
            if (j < k) {   /* a pair of violated rows is tried once, as (k, j) with j > k */
                double tolj = TOL * (vs_fabs(rj[0]) * s + vs_fabs(rj[1]) * s + vs_fabs(rj[2]));
                if (rj[0] * u[0] + rj[1] * u[1] - rj[2] < -tolj) continue;
            }
            double det = rk[0] * rj[1] - rk[1] * rj[0];
            if (det == 0.0) continue;
            double x0 = (rk[2] * rj[1] - rk[1] * rj[2]) / det;
            double x1 = (rk[0] * rj[2] - rk[2] * rj[0]) / det;
            if (!vs_isfinite(x0) || !vs_isfinite(x1)) continue;
            if (feasible(rows, m, x0, x1, s)) {
                double d = (x0 - u[0]) * (x0 - u[0]) + (x1 - u[1]) * (x1 - u[1]);
                if (!found || d < best) { found = 1; best = d; out[0] = x0; out[1] = x1; }
            }
        }
    }
    return found;
}

/* the four rows of the box [lo0, hi0] x [lo1, hi1] at rows[0..11] */
static void box_rows(double *rows, double lo0, double lo1, double hi0, double hi1)
{
    rows[0] = 1.0; rows[1] = 0.0; rows[2] = lo0;
    rows[3] = 0.0; rows[4] = 1.0; rows[5] = lo1;
    rows[6] = -1.0; rows[7] = 0.0; rows[8] = -hi0;
    rows[9] = 0.0; rows[10] = -1.0; rows[11] = -hi1;
}

/* the barrier row of robot i (centre (cx, cy), control point (px, py), heading cos/sin c, s, wheel
 * base b) against another body: its control point (qx, qy) with the disk sum D (control points), its
 * centre (ox, oy) with the disk sum E (centres), taking share of the constraint.  The control
 * points' barrier while it holds (h >= 0), else (bodies closer than the offset allows: a crowded
 * start) the centres' barrier, which constrains v alone.  1 if the row can bind in the speed box. */
static int barrier_row(double *row, double cx, double cy, double px, double py, double c, double s, double b,
                       double l, double qx, double qy, double D, double ox, double oy, double E, double share,
                       double gamma, double vmax)
{
    double dx = px - qx, dy = py - qy;
    double h = (dx * dx + dy * dy) - D * D;
    if (!(h >= 0.0) || l == 0.0) {
        dx = cx - ox;
        dy = cy - oy;
        h = (dx * dx + dy * dy) - E * E;
        l = 0.0;
    }
    /* far pairs: |a0| + |a1| <= 2 |d| (1 + 2 l / b), so the exact test below drops the row when
     * gamma h share >= 2 |d| (1 + 2 l / b) vmax; dropped here with 1% to spare for rounding
     * (the same rows as the exact test alone, cheaper) */
    double gh = (gamma * h) * share;
    if (gh > 0.0) {
        double lim = 2.0 * (1.0 + 2.0 * l / b) * vmax;
        if (gh * gh > 1.0201 * (lim * lim) * (dx * dx + dy * dy)) return 0;
    }
    double g = 2.0 * (dx * c + dy * s);
    double q = 2.0 * l * (dy * c - dx * s);
    double a0 = 0.5 * g - q / b, a1 = 0.5 * g + q / b;
    double bnd = -(gamma * h) * share;
    if (bnd <= -(vs_fabs(a0) + vs_fabs(a1)) * vmax) return 0;
    row[0] = a0;
    row[1] = a1;
    row[2] = bnd;
    return 1;
}

int vs_safety_filter(const vs_safety_params *p, size_t n, const double *pose_world,
                     const double *radius_m, const unsigned char *active, const double *wheel_base_m,
                     const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2,
                     const double *wheels_prev_m_s, size_t n_obstacles, const double *obstacles,
                     const double *wheels_nominal_m_s, double *wheels_safe_m_s,
                     vs_safety_stats *stats)
{
    return vs_safety_filter_ws(p, n, pose_world, radius_m, active, wheel_base_m, wheel_speed_max_m_s,
                               wheel_accel_max_m_s2, wheels_prev_m_s, n_obstacles, obstacles, wheels_nominal_m_s,
                               wheels_safe_m_s, stats, NULL);
}

int vs_safety_filter_ws(const vs_safety_params *p, size_t n, const double *pose_world,
                        const double *radius_m, const unsigned char *active, const double *wheel_base_m,
                        const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2,
                        const double *wheels_prev_m_s, size_t n_obstacles, const double *obstacles,
                        const double *wheels_nominal_m_s, double *wheels_safe_m_s,
                        vs_safety_stats *stats, double *work)
{
    if (p == NULL) return VS_EVALUE;
    if (!ok_num(p->margin_m) || !ok_num(p->gamma_per_s) || !ok_num(p->offset_m) || !ok_num(p->dt_s))
        return VS_ENONFINITE;
    if (!(p->margin_m >= 0.0) || !(p->gamma_per_s > 0.0) || !(p->offset_m >= 0.0) || !(p->dt_s > 0.0)
        || !(p->gamma_per_s * p->dt_s <= 1.0))
        return VS_EVALUE;
    if ((wheel_accel_max_m_s2 == NULL) != (wheels_prev_m_s == NULL)) return VS_EVALUE;
    if (n_obstacles > 0 && obstacles == NULL) return VS_EVALUE;
    if (n > 0 && (pose_world == NULL || radius_m == NULL || wheel_base_m == NULL
                  || wheel_speed_max_m_s == NULL || wheels_nominal_m_s == NULL || wheels_safe_m_s == NULL))
        return VS_EVALUE;
    if (n > ((size_t)1 << 24) || n_obstacles > ((size_t)1 << 24)) return VS_EVALUE;
    if (!all_ok(pose_world, 3 * n) || !all_ok(radius_m, n) || !all_ok(wheel_base_m, n)
        || !all_ok(wheel_speed_max_m_s, n) || !all_ok(wheels_nominal_m_s, 2 * n)
        || !all_ok(obstacles, 3 * n_obstacles))
        return VS_ENONFINITE;
    if (wheel_accel_max_m_s2 != NULL && (!all_ok(wheel_accel_max_m_s2, n) || !all_ok(wheels_prev_m_s, 2 * n)))
        return VS_ENONFINITE;
    for (size_t i = 0; i < n; i++) {
        if (!(radius_m[i] >= 0.0) || !(wheel_base_m[i] > 0.0) || !(wheel_speed_max_m_s[i] > 0.0)) return VS_EVALUE;
        if (wheel_accel_max_m_s2 != NULL && !(wheel_accel_max_m_s2[i] > 0.0)) return VS_EVALUE;
    }
    for (size_t k = 0; k < n_obstacles; k++)
        if (!(obstacles[3 * k + 2] >= 0.0)) return VS_EVALUE;

    vs_safety_stats st = {0, 0, 0, 0, 0};
    if (n == 0) {
        if (stats != NULL) *stats = st;
        return VS_OK;
    }
    const double l = p->offset_m, margin = p->margin_m, gamma = p->gamma_per_s, dt = p->dt_s;
    size_t max_rows = (n - 1) + n_obstacles + 4;
    double *own = NULL;
    if (work == NULL && (own = work = malloc(VS_SAFETY_WORK_F64(n, n_obstacles) * sizeof *work)) == NULL)
        return VS_ENOMEM;
    double *pts = work;                                  /* px, py, cos, sin, braking distance */
    double *rows = pts + 5 * n;
    double *out = rows + 3 * max_rows;
    for (size_t i = 0; i < n; i++) {
        double s, c;
        vs_sincos(pose_world[3 * i + 2], &s, &c);
        pts[5 * i] = pose_world[3 * i] + l * c;
        pts[5 * i + 1] = pose_world[3 * i + 1] + l * s;
        pts[5 * i + 2] = c;
        pts[5 * i + 3] = s;
        /* (vl^2 + vr^2) / (4 amax): a bound on the distance the centre travels while both wheels
         * brake at amax (|v| <= (|vl| + |vr|) / 2, each wheel stopping in |v_w| / amax) */
        double brake = 0.0;
        if (wheel_accel_max_m_s2 != NULL && (active == NULL || active[i])) {
            double vl = wheels_prev_m_s[2 * i], vr = wheels_prev_m_s[2 * i + 1];
            brake = (vl * vl + vr * vr) / (4.0 * wheel_accel_max_m_s2[i]);
        }
        pts[5 * i + 4] = brake;
    }
    int rc = VS_OK;
    for (size_t i = 0; i < n; i++) {
        if (active != NULL && !active[i]) {
            out[2 * i] = 0.0;
            out[2 * i + 1] = 0.0;
            continue;
        }
        const double px = pts[5 * i], py = pts[5 * i + 1], c = pts[5 * i + 2], s = pts[5 * i + 3];
        const double bi = pts[5 * i + 4];
        const double b = wheel_base_m[i], vmax = wheel_speed_max_m_s[i], ri = radius_m[i];
        int m = 0;
        const double cx = pose_world[3 * i], cy = pose_world[3 * i + 1];
        for (size_t j = 0; j < n; j++) {
            if (j == i) continue;
            int act_j = active == NULL || active[j];
            const double ox = pose_world[3 * j], oy = pose_world[3 * j + 1];
            const double E = (((ri + radius_m[j]) + margin) + bi) + pts[5 * j + 4];
            if (act_j)
                m += barrier_row(rows + 3 * m, cx, cy, px, py, c, s, b, l, pts[5 * j], pts[5 * j + 1], E + 2.0 * l,
                                 ox, oy, E, 0.5, gamma, vmax);
            else
                m += barrier_row(rows + 3 * m, cx, cy, px, py, c, s, b, l, ox, oy, E + l, ox, oy, E, 1.0, gamma, vmax);
        }
        for (size_t k = 0; k < n_obstacles; k++) {
            const double ox = obstacles[3 * k], oy = obstacles[3 * k + 1], R = obstacles[3 * k + 2];
            const double E = ((ri + R) + margin) + bi;
            m += barrier_row(rows + 3 * m, cx, cy, px, py, c, s, b, l, ox, oy, E + l, ox, oy, E, 1.0, gamma, vmax);
        }
        st.n_constraints += m;
        const double u[2] = {wheels_nominal_m_s[2 * i], wheels_nominal_m_s[2 * i + 1]};
        double lo0 = -vmax, lo1 = -vmax, hi0 = vmax, hi1 = vmax;
        int accel = 0;
        if (wheel_accel_max_m_s2 != NULL) {
            double step = wheel_accel_max_m_s2[i] * dt;
            double p0 = wheels_prev_m_s[2 * i], p1 = wheels_prev_m_s[2 * i + 1];
            double a_lo0 = p0 - step, a_lo1 = p1 - step, a_hi0 = p0 + step, a_hi1 = p1 + step;
            if (a_lo0 > lo0) lo0 = a_lo0;
            if (a_lo1 > lo1) lo1 = a_lo1;
            if (a_hi0 < hi0) hi0 = a_hi0;
            if (a_hi1 < hi1) hi1 = a_hi1;
            accel = 1;
            if (lo0 > hi0 || lo1 > hi1) {   /* the previous command is beyond the speed box */
                lo0 = -vmax; lo1 = -vmax; hi0 = vmax; hi1 = vmax;
                accel = 0;
                st.n_accel_relaxed++;
            }
        }
        box_rows(rows + 3 * m, lo0, lo1, hi0, hi1);
        if (!feasible(rows, m + 4, u[0], u[1], vmax)) st.n_modified++;
        /* an empty polygon: soften (rows asking to separate, b > 0, only ask not to close: b = 0),
         * then drop the accel box; (0, 0) meets softened rows in the speed box */
        double x[2];
        int got = project(rows, m + 4, u, vmax, x);
        if (!got) {
            for (int k = 0; k < m; k++)
                if (rows[3 * k + 2] > 0.0) rows[3 * k + 2] = 0.0;
            st.n_softened++;
            got = project(rows, m + 4, u, vmax, x);
        }
        if (!got && accel) {
            box_rows(rows + 3 * m, -vmax, -vmax, vmax, vmax);
            st.n_accel_relaxed++;
            got = project(rows, m + 4, u, vmax, x);
        }
        if (!got) {
            x[0] = 0.0;
            x[1] = 0.0;
            st.n_stopped++;
        }
        if (!vs_isfinite(x[0]) || !vs_isfinite(x[1])) { rc = VS_ENONFINITE; break; }
        out[2 * i] = x[0];
        out[2 * i + 1] = x[1];
    }
    if (rc == VS_OK) {
        for (size_t k = 0; k < 2 * n; k++) wheels_safe_m_s[k] = out[k];
        if (stats != NULL) *stats = st;
    }
    free(own);
    return rc;
}
