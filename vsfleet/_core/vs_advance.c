/* vs_advance.c - see vs_advance.h.  A line-by-line port of vsfleet/advance.py: the same
 * operations in the same order, so that the branches the reference takes on exact comparisons
 * (arrival, the path's closest segment and carrot, the interval searches) are taken here too. */
#include "vs_advance.h"

#include <math.h>   /* sqrt and the INFINITY macro only */
#include <stdint.h>
#include <string.h>

#define SEARCH_ITERATIONS 80   /* advance.py _SEARCH_ITERATIONS */
#if VS_ALIGN_POWER != 8 || VS_ALIGN_POWER_PLAN != 4
#error "alignment_scale computes VS_ALIGN_POWER 8 and VS_ALIGN_POWER_PLAN 4 as three and two squarings"
#endif

static uint64_t bits(double x) { uint64_t u; memcpy(&u, &x, sizeof u); return u; }
static double from_bits(uint64_t u) { double x; memcpy(&x, &u, sizeof x); return x; }

/* math.copysign */
static double copy_sign(double mag, double sgn)
{
    return from_bits((bits(mag) & 0x7fffffffffffffffULL) | (bits(sgn) & 0x8000000000000000ULL));
}

/* Python's min(a, b) / max(a, b) on floats: the first unless the second is strictly smaller / larger. */
static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* Pose2 stores th wrapped; a value already in [-pi, pi) is kept bit for bit. */
static double as_wrapped(double th) { return (th >= -VS_PI && th < VS_PI) ? th : vs_wrap_angle(th); }

/* ---- hypot, twice */

/* glibc's __hypot (sysdeps/ieee754/dbl-64/e_hypot.c, 2.35+, the kernel without FMA). */
static double hypot_kernel(double ax, double ay)
{
    double t1, t2;
    double h = sqrt(ax * ax + ay * ay);
    if (h <= 2.0 * ay) {
        double delta = h - ay;
        t1 = ax * (2.0 * delta - ax);
        t2 = (delta - 2.0 * (ax - ay)) * delta;
    } else {
        double delta = h - ax;
        t1 = 2.0 * delta * (ax - 2.0 * ay);
        t2 = (4.0 * delta - ay) * ay + delta * delta;
    }
    h -= (t1 + t2) / (2.0 * h);
    return h;
}

double vs_hypot_libm(double x, double y)
{
    const double SCALE = 0x1p-600, LARGE_VAL = 0x1p+511, TINY_VAL = 0x1p-511, EPS = 0x1p-54;
    if (!vs_isfinite(x) || !vs_isfinite(y)) {
        if ((!vs_isnan(x) && !vs_isfinite(x)) || (!vs_isnan(y) && !vs_isfinite(y))) return INFINITY;
        return x + y;
    }
    x = vs_fabs(x);
    y = vs_fabs(y);
    double ax = x < y ? y : x;
    double ay = x < y ? x : y;
    if (ax > LARGE_VAL) {
        if (ay <= ax * EPS) return ax + ay;
        return hypot_kernel(ax * SCALE, ay * SCALE) / SCALE;
    }
    if (ay < TINY_VAL) {
        if (ax >= ay / EPS) return ax + ay;
        return hypot_kernel(ax / SCALE, ay / SCALE) * SCALE;
    }
    if (ay <= ax * EPS) return ax + ay;
    return hypot_kernel(ax, ay);
}

/* Exact products and sums (Dekker, Veltkamp; exact under -ffp-contract=off). */
typedef struct { double hi, lo; } dl;

static dl dl_mul(double x, double y)
{
    const double split = 134217729.0;   /* 2^27 + 1 */
    double hi = x * y;
    double cx = split * x, xh = cx - (cx - x), xl = x - xh;
    double cy = split * y, yh = cy - (cy - y), yl = y - yh;
    dl r = {hi, ((xh * yh - hi) + xh * yl + xl * yh) + xl * yl};
    return r;
}

static dl dl_fast_sum(double a, double b)
{
    double x = a + b;
    dl r = {x, (a - x) + b};
    return r;
}

/* CPython's math.hypot (Modules/mathmodule.c vector_norm, two coordinates). */
double vs_hypot_cr(double x, double y)
{
    if (!vs_isfinite(x) || !vs_isfinite(y)) return vs_hypot_libm(x, y);
    x = vs_fabs(x);
    y = vs_fabs(y);
    double mx = x > y ? x : y;
    if (mx == 0.0) return mx;
    uint64_t biased = (bits(mx) >> 52) & 0x7ff;
    if (biased == 0) return vs_hypot_libm(x, y);        /* subnormal: far below the physical range */
    int e = (int)biased - 1022;                         /* frexp's exponent of a normal mx */
    if (e > 1000) return vs_hypot_libm(x, y);           /* far out of the physical range */
    double scale = from_bits((uint64_t)(1023 - e) << 52);   /* ldexp(1.0, -e), exact */
    double csum = 1.0, frac1 = 0.0, frac2 = 0.0, v[2] = {x, y};
    dl pr, sm;
    for (int i = 0; i < 2; i++) {
        double t = v[i] * scale;
        pr = dl_mul(t, t);
        sm = dl_fast_sum(csum, pr.hi);
        csum = sm.hi;
        frac1 += pr.lo;
        frac2 += sm.lo;
    }
    double h = sqrt(csum - 1.0 + (frac1 + frac2));
    pr = dl_mul(-h, h);
    sm = dl_fast_sum(csum, pr.hi);
    csum = sm.hi;
    frac1 += pr.lo;
    frac2 += sm.lo;
    double r = csum - 1.0 + (frac1 + frac2);
    h += r / (2.0 * h);
    return h / scale;
}

/* ---- the pieces of advance.py */

typedef struct { double vx, vy, w; } twist3;

/* _profile_speed */
static double profile_speed(double distance, double cap, double accel, double dt_s, double settle_s)
{
    if (distance <= 0.0) return 0.0;
    double a = cap, b = sqrt(2.0 * accel * distance), c = distance / py_max(dt_s, settle_s);
    return py_min(py_min(a, b), c);
}

/* _twist_toward: world twist from pose toward target; speed profiled on dist_to_stop. */
static twist3 twist_toward(const double pose[3], const double target[3], double dist_to_stop,
                           const vs_limits *lim, double accel, double alpha, double dt_s)
{
    twist3 t;
    double ex = target[0] - pose[0], ey = target[1] - pose[1];
    double d = vs_hypot_cr(ex, ey);
    if (d > 0.0) {
        double speed = py_min(profile_speed(dist_to_stop, lim->speed_max_m_s, accel, dt_s, lim->settle_s), d / dt_s);
        t.vx = speed * ex / d;
        t.vy = speed * ey / d;
    } else {
        t.vx = t.vy = 0.0;
    }
    double dth = vs_wrap_angle(target[2] - pose[2]);
    t.w = copy_sign(profile_speed(vs_fabs(dth), lim->turn_rate_max_rad_s, alpha, dt_s, lim->turn_settle_s), dth);
    return t;
}

/* twist_toward, the turn and the move in step: the structure goes the straight way in SE(2) to the target
 * (its heading turns in proportion to the way it moves), each no faster than its own profile */
static twist3 twist_straight(const double pose[3], const double target[3], double dist_to_stop,
                             const vs_limits *lim, double accel, double alpha, double dt_s)
{
    twist3 t = twist_toward(pose, target, dist_to_stop, lim, accel, alpha, dt_s);
    double ex = target[0] - pose[0], ey = target[1] - pose[1];
    double d = vs_hypot_cr(ex, ey), v = vs_hypot_cr(t.vx, t.vy);
    double dth = vs_wrap_angle(target[2] - pose[2]);
    if (d > 0.0 && v > 0.0) {
        double w_move = dth * (v / d);           /* the turn rate that ends the turn with the move */
        /* the turn's own bound: its rate and its acceleration (not the settling time: the move sets the pace) */
        double w_max = profile_speed(vs_fabs(dth), lim->turn_rate_max_rad_s, alpha, dt_s, dt_s);
        if (vs_fabs(w_move) > w_max) {           /* the turn is the slower: the move waits for it */
            double k = w_max / vs_fabs(w_move);
            t.w = copy_sign(w_max, dth);
            t.vx = k * t.vx;
            t.vy = k * t.vy;
        } else {
            t.w = w_move;
        }
    }
    return t;
}

/* _path_carrot: carrot (x, y, th) on the polyline wp (m waypoints, th already as stored), the
 * remaining length [m], and whether the carrot equals the last waypoint (Pose2 ==). */
static void path_carrot(const double pose[3], const double *wp, size_t m, double lookahead,
                        double carrot[3], double *remaining, int *is_end)
{
    const double *end = wp + 3 * (m - 1);
    if (m == 1) {
        carrot[0] = end[0]; carrot[1] = end[1]; carrot[2] = as_wrapped(end[2]);
        *remaining = vs_hypot_cr(end[0] - pose[0], end[1] - pose[1]);
        *is_end = 1;
        return;
    }
    size_t nseg = m - 1, best_i = 0;
    double total = 0.0, best_d2 = INFINITY, best_u = 0.0, cum_best = 0.0;
    for (size_t i = 0; i < nseg; i++) {      /* cum[i] = total before segment i (np.cumsum order) */
        double sx = wp[3 * (i + 1)] - wp[3 * i], sy = wp[3 * (i + 1) + 1] - wp[3 * i + 1];
        double len = vs_hypot_libm(sx, sy);
        double L2 = len * len;
        double rx = pose[0] - wp[3 * i], ry = pose[1] - wp[3 * i + 1];
        double u = L2 == 0.0 ? 0.0 : py_min(1.0, py_max(0.0, (rx * sx + ry * sy) / L2));
        double qx = wp[3 * i] + u * sx, qy = wp[3 * i + 1] + u * sy;
        double dx = pose[0] - qx, dy = pose[1] - qy;
        double d2 = dx * dx + dy * dy;
        if (d2 < best_d2) { best_i = i; best_d2 = d2; best_u = u; cum_best = total; }
        total = total + len;
    }
    double len_best = vs_hypot_libm(wp[3 * (best_i + 1)] - wp[3 * best_i], wp[3 * (best_i + 1) + 1] - wp[3 * best_i + 1]);
    double s_proj = cum_best + best_u * len_best;
    double s_carrot = py_min(total, s_proj + lookahead);
    /* j = searchsorted(cum, s_carrot, 'right') - 1, clamped to a segment: the last cum[j] <= s_carrot */
    size_t j = 0;
    double cum_j = 0.0, cum = 0.0, len_j = vs_hypot_libm(wp[3] - wp[0], wp[4] - wp[1]);
    for (size_t k = 0; k < nseg; k++) {
        double len = vs_hypot_libm(wp[3 * (k + 1)] - wp[3 * k], wp[3 * (k + 1) + 1] - wp[3 * k + 1]);
        if (cum <= s_carrot) { j = k; cum_j = cum; len_j = len; }
        cum = cum + len;
    }
    double frac = len_j == 0.0 ? 0.0 : (s_carrot - cum_j) / len_j;
    frac = py_min(1.0, py_max(0.0, frac));
    const double *a = wp + 3 * j, *b = wp + 3 * (j + 1);
    double ath = as_wrapped(a[2]), bth = as_wrapped(b[2]);
    double endth = as_wrapped(end[2]);
    carrot[0] = a[0] + frac * (b[0] - a[0]);
    carrot[1] = a[1] + frac * (b[1] - a[1]);
    carrot[2] = vs_wrap_angle(ath + frac * vs_wrap_angle(bth - ath));
    if (s_carrot >= total) { carrot[0] = end[0]; carrot[1] = end[1]; carrot[2] = endth; }
    *is_end = carrot[0] == end[0] && carrot[1] == end[1] && carrot[2] == endth;
    *remaining = (total - s_proj) + sqrt(best_d2);
}

/* Structure offsets rho_i = R(th) p_i + 0 [m; world] (Pose2(0, 0, th).apply). */
static void rho_of(const double *tpl, size_t i, double c, double s, double *rx, double *ry)
{
    double px = tpl[2 * i], py = tpl[2 * i + 1];
    *rx = c * px - s * py + 0.0;
    *ry = s * px + c * py + 0.0;
}

/* _wheel_demand of robot i: |u_i| + |w| b_i / 2 */
static double wheel_demand(double vx, double vy, double w, double rx, double ry, double half_base)
{
    double ux = vx - w * ry, uy = vy + w * rx;
    return vs_hypot_libm(ux, uy) + vs_fabs(w) * half_base;
}

typedef struct {
    const double *tpl, *wb, *vmax, *amax;
    size_t n;
    double c, s, dt_s;
} robots;

/* the envelope_scale's excess(s): the worst acceleration overrun of s xi - xi0 */
static double excess(const robots *r, twist3 xi, const double xi0[3], double s)
{
    double vx = s * xi.vx - xi0[0], vy = s * xi.vy - xi0[1], w = s * xi.w - xi0[2];
    double worst = 0.0;
    for (size_t i = 0; i < r->n; i++) {
        double rx, ry;
        rho_of(r->tpl, i, r->c, r->s, &rx, &ry);
        double e = wheel_demand(vx, vy, w, rx, ry, r->wb[i] / 2.0) - r->amax[i] * r->dt_s;
        if (i == 0 || e > worst) worst = e;
    }
    return worst;
}

/* envelope_scale */
static double envelope_scale(const robots *r, twist3 xi, const double *xi0)
{
    double s_speed = INFINITY;
    for (size_t i = 0; i < r->n; i++) {
        double rx, ry;
        rho_of(r->tpl, i, r->c, r->s, &rx, &ry);
        double demand = wheel_demand(xi.vx, xi.vy, xi.w, rx, ry, r->wb[i] / 2.0);
        if (demand > 0.0) {
            double q = r->vmax[i] / demand;
            if (q < s_speed) s_speed = q;
        }
    }
    double s_hi = py_min(1.0, s_speed);
    if (xi0 == NULL) return s_hi;
    if (excess(r, xi, xi0, s_hi) <= 0.0) return s_hi;
    double lo = 0.0, hi = s_hi;
    for (int k = 0; k < SEARCH_ITERATIONS; k++) {
        double m1 = lo + (hi - lo) / 3.0, m2 = hi - (hi - lo) / 3.0;
        if (excess(r, xi, xi0, m1) <= excess(r, xi, xi0, m2)) hi = m2;
        else lo = m1;
    }
    double s_best = (lo + hi) / 2.0;
    if (excess(r, xi, xi0, s_best) > 0.0) return s_best;
    lo = s_best;
    hi = s_hi;
    for (int k = 0; k < SEARCH_ITERATIONS; k++) {
        double mid = (lo + hi) / 2.0;
        if (excess(r, xi, xi0, mid) <= 0.0) lo = mid;
        else hi = mid;
    }
    return lo;
}

/* alignment_scale (floor VS_ALIGN_FLOOR; power VS_ALIGN_POWER_PLAN on a plan, else VS_ALIGN_POWER) */
static double alignment_scale(const robots *r, twist3 t, const double *headings, int plan, double speed_ref)
{
    int any = 0;
    double k_min = 1.0;
    for (size_t i = 0; i < r->n; i++) {
        double h = headings[i];
        if (vs_isnan(h)) continue;
        double rx, ry;
        rho_of(r->tpl, i, r->c, r->s, &rx, &ry);
        double ux = t.vx - t.w * ry, uy = t.vy + t.w * rx;
        double u = vs_hypot_libm(ux, uy);
        if (!(u > 0.0)) continue;
        double sh, ch;
        vs_sincos(h, &sh, &ch);
        double cos_d = vs_fabs(ux * ch + uy * sh) / u;
        double p2 = cos_d * cos_d, p4 = p2 * p2, p8 = p4 * p4;
        double k = py_max(VS_ALIGN_FLOOR, plan ? p4 : p8);
        if (plan && speed_ref > 0.0 && u < speed_ref) k = 1.0 - (1.0 - k) * (u / speed_ref);
        if (!any || k < k_min) k_min = k;
        any = 1;
    }
    if (!any) return 1.0;
    return py_min(1.0, k_min);
}

/* compliance_scale */
static double compliance_scale(const double *dev, size_t n, const vs_limits *lim)
{
    int any = 0;
    double worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        if (vs_isnan(dev[i])) continue;
        if (!any || dev[i] > worst) worst = dev[i];
        any = 1;
    }
    if (!any) return 1.0;
    double span = lim->comply_stop_m - lim->comply_full_m;
    return py_min(1.0, py_max(0.0, (lim->comply_stop_m - worst) / span));
}

static int all_finite(const double *v, size_t k)
{
    for (size_t i = 0; i < k; i++) if (!vs_isfinite(v[i])) return 0;
    return 1;
}

/* finite or NaN (unseen) */
static int finite_or_nan(const double *v, size_t k)
{
    for (size_t i = 0; i < k; i++) if (!vs_isfinite(v[i]) && !vs_isnan(v[i])) return 0;
    return 1;
}

static int positive(const double *v, size_t k)
{
    for (size_t i = 0; i < k; i++) if (!(v[i] > 0.0)) return 0;
    return 1;
}

int vs_advance(const double pose_fit[3], const vs_goal *goal, double dt_s, const vs_limits *limits,
               const double *template_xy, const double *wheel_base_m, const double *wheel_speed_max_m_s,
               const double *wheel_accel_max_m_s2, size_t n, const double *twist_prev, const double *elapsed_s,
               const double *headings_rad, const double *deviations_m, vs_advance_result *out)
{
    if (pose_fit == NULL || goal == NULL || limits == NULL || template_xy == NULL || wheel_base_m == NULL
            || wheel_speed_max_m_s == NULL || wheel_accel_max_m_s2 == NULL || out == NULL || n == 0)
        return VS_EVALUE;
    if (goal->poses == NULL || goal->n_poses == 0 || goal->n_poses > ((size_t)-1) / 3
            || (goal->kind != VS_GOAL_PATH && goal->kind != VS_GOAL_PLAN && goal->n_poses != 1)
            || (goal->kind != VS_GOAL_POSE && goal->kind != VS_GOAL_PATH && goal->kind != VS_GOAL_TWIST
                && goal->kind != VS_GOAL_PLAN))
        return VS_EVALUE;
    if (n > ((size_t)-1) / 2) return VS_EVALUE;
    if (!vs_isfinite(dt_s)) return VS_ENONFINITE;
    if (!(dt_s > 0.0)) return VS_EVALUE;
    if (!all_finite(pose_fit, 3)) return VS_ENONFINITE;
    const double lim_v[9] = {limits->speed_max_m_s, limits->turn_rate_max_rad_s, limits->position_tolerance_m,
                             limits->heading_tolerance_rad, limits->path_lookahead_m, limits->comply_full_m,
                             limits->comply_stop_m, limits->settle_s, limits->turn_settle_s};
    if (!all_finite(lim_v, 9)) return VS_ENONFINITE;
    for (int k = 0; k < 9; k++) if (lim_v[k] < 0.0) return VS_EVALUE;
    if (!(limits->comply_stop_m > limits->comply_full_m)) return VS_EVALUE;
    if (!all_finite(goal->poses, 3 * goal->n_poses)) return VS_ENONFINITE;
    if (!all_finite(template_xy, 2 * n) || !all_finite(wheel_base_m, n) || !all_finite(wheel_speed_max_m_s, n)
            || !all_finite(wheel_accel_max_m_s2, n))
        return VS_ENONFINITE;
    if (!positive(wheel_base_m, n) || !positive(wheel_speed_max_m_s, n) || !positive(wheel_accel_max_m_s2, n))
        return VS_EVALUE;
    if (twist_prev != NULL && !all_finite(twist_prev, 3)) return VS_ENONFINITE;
    if (elapsed_s != NULL && !vs_isfinite(*elapsed_s)) return VS_ENONFINITE;
    if (headings_rad != NULL && !finite_or_nan(headings_rad, n)) return VS_ENONFINITE;
    if (deviations_m != NULL && !finite_or_nan(deviations_m, n)) return VS_ENONFINITE;

    const double pose[3] = {pose_fit[0], pose_fit[1], as_wrapped(pose_fit[2])};
    robots r = {template_xy, wheel_base_m, wheel_speed_max_m_s, wheel_accel_max_m_s2, n, 0.0, 0.0, dt_s};
    vs_sincos(pose[2], &r.s, &r.c);

    double amin = wheel_accel_max_m_s2[0], reach = 0.0;
    for (size_t i = 0; i < n; i++) {
        if (wheel_accel_max_m_s2[i] < amin) amin = wheel_accel_max_m_s2[i];
        double rx, ry;
        rho_of(template_xy, i, r.c, r.s, &rx, &ry);
        double v = vs_hypot_libm(rx, ry) + wheel_base_m[i] / 2.0;
        if (i == 0 || v > reach) reach = v;
    }
    double accel = 0.5 * amin;
    double alpha = accel / reach;

    int at_goal = 0;
    twist3 desired;
    if (goal->kind == VS_GOAL_TWIST) {
        const double *g = goal->poses;
        desired.vx = r.c * g[0] - r.s * g[1];
        desired.vy = r.s * g[0] + r.c * g[1];
        desired.w = g[2];
    } else if (goal->kind == VS_GOAL_POSE) {
        const double g[3] = {goal->poses[0], goal->poses[1], as_wrapped(goal->poses[2])};
        double d = vs_hypot_cr(g[0] - pose[0], g[1] - pose[1]);
        desired = twist_toward(pose, g, d, limits, accel, alpha, dt_s);
        at_goal = d <= limits->position_tolerance_m
                  && vs_fabs(vs_wrap_angle(g[2] - pose[2])) <= limits->heading_tolerance_rad;
    } else {
        double carrot[3], remaining;
        int is_end;
        path_carrot(pose, goal->poses, goal->n_poses, limits->path_lookahead_m, carrot, &remaining, &is_end);
        desired = goal->kind == VS_GOAL_PLAN ? twist_straight(pose, carrot, remaining, limits, accel, alpha, dt_s)
                               : twist_toward(pose, carrot, remaining, limits, accel, alpha, dt_s);
        const double *e = goal->poses + 3 * (goal->n_poses - 1);
        at_goal = is_end && vs_hypot_cr(e[0] - pose[0], e[1] - pose[1]) <= limits->position_tolerance_m
                  && vs_fabs(vs_wrap_angle(as_wrapped(e[2]) - pose[2])) <= limits->heading_tolerance_rad;
    }

    if (at_goal) desired.vx = desired.vy = desired.w = 0.0;
    if (elapsed_s != NULL) {
        double ramp = py_max(0.0, *elapsed_s);
        double v = vs_hypot_cr(desired.vx, desired.vy);
        double k_v = v > 0.0 ? py_min(1.0, accel * ramp / v) : 1.0;
        double k_w = desired.w != 0.0 ? py_min(1.0, alpha * ramp / vs_fabs(desired.w)) : 1.0;
        desired.vx = k_v * desired.vx;
        desired.vy = k_v * desired.vy;
        desired.w = k_w * desired.w;
    }
    if (headings_rad != NULL) {
        double k = alignment_scale(&r, desired, headings_rad, goal->kind == VS_GOAL_PLAN, limits->speed_max_m_s);
        desired.vx = k * desired.vx;
        desired.vy = k * desired.vy;
        desired.w = k * desired.w;
    }
    if (deviations_m != NULL) {
        double k = compliance_scale(deviations_m, n, limits);
        desired.vx = k * desired.vx;
        desired.vy = k * desired.vy;
        desired.w = k * desired.w;
    }
    double scale = envelope_scale(&r, desired, twist_prev);
    twist3 t = {scale * desired.vx, scale * desired.vy, scale * desired.w};
    vs_advance_result res;
    res.x = pose[0] + t.vx * dt_s;
    res.y = pose[1] + t.vy * dt_s;
    res.th = pose[2] + t.w * dt_s;
    res.vx_m_s = t.vx;
    res.vy_m_s = t.vy;
    res.w_rad_s = t.w;
    res.scale = scale;
    res.at_goal = at_goal;
    const double check[7] = {res.x, res.y, res.th, res.vx_m_s, res.vy_m_s, res.w_rad_s, res.scale};
    if (!all_finite(check, 7)) return VS_ENONFINITE;   /* an overflow on inputs near DBL_MAX */
    res.th = vs_wrap_angle(res.th);
    *out = res;
    return VS_OK;
}
