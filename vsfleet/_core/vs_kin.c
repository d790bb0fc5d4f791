/* vs_kin.c - see vs_kin.h.  Each formula is written in the operation order of
 * vsfleet/kinematics.py's numpy reference (integrate_arcs, limit_wheels_v/_limit_rows). */
#include "vs_kin.h"
#include "vscore.h"

#include <math.h>   /* sqrt only (and the constant HUGE_VAL) */
#include <stdlib.h>
#include <string.h>

int vs_all_finite(const double *x, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!vs_isfinite(x[i])) return 0;
    return 1;
}

double vs_hypot_safe(double x, double y)
{
    double ax = vs_fabs(x), ay = vs_fabs(y), m = ax > ay ? ax : ay;
    if (m > 0x1p+500 && vs_isfinite(m)) {
        x *= 0x1p-600;
        y *= 0x1p-600;
        return sqrt(x * x + y * y) * 0x1p+600;
    }
    if (m < 0x1p-500 && m > 0.0) {
        x *= 0x1p+600;
        y *= 0x1p+600;
        return sqrt(x * x + y * y) * 0x1p-600;
    }
    return sqrt(x * x + y * y);
}

double vs_sinc(double x)
{
    if (vs_fabs(x) < VS_SINC_SERIES_BELOW) {
        double x2 = x * x;
        return 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0);
    }
    return vs_sin(x) / x;
}

int vs_sinc_v(const double *x, size_t n, double *out)
{
    if (!vs_all_finite(x, n)) return VS_ENONFINITE;
    for (size_t i = 0; i < n; i++) out[i] = vs_sinc(x[i]);
    return VS_OK;
}

int vs_wrap_angles(const double *th_rad, size_t n, double *out)
{
    if (!vs_all_finite(th_rad, n)) return VS_ENONFINITE;
    for (size_t i = 0; i < n; i++) out[i] = vs_wrap_angle(th_rad[i]);
    return VS_OK;
}

void vs_arc_row(const double pose[3], double vl, double vr, double dt, double base, double out[3])
{
    double v = 0.5 * (vl + vr);
    double w = (vr - vl) / base;
    double half = 0.5 * w * dt;
    double chord = v * dt * vs_sinc(half);
    double s, c;
    vs_sincos(pose[2] + half, &s, &c);
    double x = pose[0] + chord * c, y = pose[1] + chord * s, th = pose[2] + w * dt;
    out[0] = x;
    out[1] = y;
    out[2] = th;
}

int vs_integrate_arcs(const double *pose_world, const double *wheels_m_s, double dt_s, const double *wheel_base_m,
                      size_t n, double *out_pose_world)
{
    return vs_integrate_arcs_ws(pose_world, wheels_m_s, dt_s, wheel_base_m, n, out_pose_world, NULL);
}

int vs_integrate_arcs_ws(const double *pose_world, const double *wheels_m_s, double dt_s, const double *wheel_base_m,
                         size_t n, double *out_pose_world, double *work)
{
    if (!vs_isfinite(dt_s) || !vs_all_finite(pose_world, 3 * n) || !vs_all_finite(wheels_m_s, 2 * n)
        || !vs_all_finite(wheel_base_m, n))
        return VS_ENONFINITE;
    if (n == 0) return VS_OK;
    /* into scratch first: a result that overflows (or a zero wheel base) is refused before
     * anything is written */
    double *own = NULL, *r = work;
    if (r == NULL && (own = r = malloc(3 * n * sizeof *r)) == NULL) return VS_ENOMEM;
    for (size_t i = 0; i < n; i++)
        vs_arc_row(pose_world + 3 * i, wheels_m_s[2 * i], wheels_m_s[2 * i + 1], dt_s, wheel_base_m[i], r + 3 * i);
    if (!vs_all_finite(r, 3 * n)) { free(own); return VS_ENONFINITE; }
    memcpy(out_pose_world, r, 3 * n * sizeof *r);
    free(own);
    return VS_OK;
}

static double vmaxd(double a, double b) { return a > b ? a : b; }   /* np.maximum on non-NaN values */
static double vmind(double a, double b) { return a < b ? a : b; }

void vs_limit_row(double u0, double u1, double p0, double p1, double vmax, double step, double out[2])
{
    double u[2] = {u0, u1}, p[2] = {p0, p1}, lo[2], hi[2], slo_w[2], shi_w[2];
    for (int k = 0; k < 2; k++) {
        lo[k] = vmaxd(p[k] - step, -vmax);
        hi[k] = vmind(p[k] + step, vmax);
    }
    /* the previous command beyond the speed box (its accel box misses it): the accel limit yields and
     * the speed box alone limits the command, as in the safety filter (vs_safety.c, n_accel_relaxed) */
    if (lo[0] > hi[0] || lo[1] > hi[1])
        for (int k = 0; k < 2; k++) { lo[k] = -vmax; hi[k] = vmax; }
    for (int k = 0; k < 2; k++) {
        int zero_in = lo[k] <= 0.0 && 0.0 <= hi[k];
        if (u[k] > 0.0) { slo_w[k] = lo[k] / u[k]; shi_w[k] = hi[k] / u[k]; }
        else if (u[k] < 0.0) { slo_w[k] = hi[k] / u[k]; shi_w[k] = lo[k] / u[k]; }
        else { slo_w[k] = zero_in ? 0.0 : HUGE_VAL; shi_w[k] = zero_in ? HUGE_VAL : 0.0; }
    }
    /* 1. the ray {s u} */
    double s_lo = vmaxd(0.0, vmaxd(slo_w[0], slo_w[1]));
    double s_hi = vmind(shi_w[0], shi_w[1]);
    double r[2];
    if (s_lo <= s_hi) {
        double s = s_lo <= 1.0 ? vmind(s_hi, 1.0) : s_lo;
        if (!vs_isfinite(s)) s = 0.0;
        r[0] = s * u[0];
        r[1] = s * u[1];
    } else {
        /* 2. the corner at the smallest angle to u (ties, within VS_CORNER_TIE_RAD: nearest to u), if within
         * 90 deg */
        double cx[4] = {lo[0], lo[0], hi[0], hi[0]}, cy[4] = {lo[1], hi[1], lo[1], hi[1]};
        double ang[4], dist[4];
        for (int j = 0; j < 4; j++) {
            ang[j] = vs_fabs(vs_atan2(u[0] * cy[j] - u[1] * cx[j], u[0] * cx[j] + u[1] * cy[j]));
            dist[j] = vs_hypot_safe(cx[j] - u[0], cy[j] - u[1]);
        }
        int best = 0;
        for (int j = 1; j < 4; j++)
            if (ang[j] < ang[best] - VS_CORNER_TIE_RAD
                || (vs_fabs(ang[j] - ang[best]) <= VS_CORNER_TIE_RAD && dist[j] < dist[best]))
                best = j;
        if ((u[0] != 0.0 || u[1] != 0.0) && ang[best] < 0.5 * VS_PI) {
            r[0] = cx[best];
            r[1] = cy[best];
        } else {
            /* 3. the point nearest zero */
            r[0] = vmind(vmaxd(0.0, lo[0]), hi[0]);
            r[1] = vmind(vmaxd(0.0, lo[1]), hi[1]);
        }
    }
    /* 4. no wheel farther from zero than its command asks, unless the box forces it (then at the
     * box's point nearest zero): the curvature kept (s > 1) or turned toward (a corner) never costs
     * braking, and a stop or a slow-down (the safety filter's) is never turned into motion.  Clamping
     * into [a, b], within the box, also makes the limits exact against rounding. */
    for (int k = 0; k < 2; k++) {
        double a = vmaxd(lo[k], vmind(0.0, u[k])), b = vmind(hi[k], vmaxd(0.0, u[k]));
        if (a > b) a = b = vmind(vmaxd(0.0, lo[k]), hi[k]);
        out[k] = vmind(vmaxd(r[k], a), b);
    }
}

int vs_limit_wheels(const double *wheels_m_s, const double *wheels_prev_m_s, double dt_s,
                    const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2, size_t n, double *out)
{
    if (!vs_isfinite(dt_s)) return VS_ENONFINITE;
    if (!(dt_s > 0.0)) return VS_EVALUE;
    if (!vs_all_finite(wheels_m_s, 2 * n) || !vs_all_finite(wheels_prev_m_s, 2 * n)
        || !vs_all_finite(wheel_speed_max_m_s, n) || !vs_all_finite(wheel_accel_max_m_s2, n))
        return VS_ENONFINITE;
    for (size_t i = 0; i < n; i++) {
        double u0 = wheels_m_s[2 * i], u1 = wheels_m_s[2 * i + 1];
        double p0 = wheels_prev_m_s[2 * i], p1 = wheels_prev_m_s[2 * i + 1];
        double vmax = wheel_speed_max_m_s[i], step = wheel_accel_max_m_s2[i] * dt_s;
        if (vs_fabs(u0) <= vmax && vs_fabs(u0 - p0) <= step && vs_fabs(u1) <= vmax && vs_fabs(u1 - p1) <= step) {
            out[2 * i] = u0;
            out[2 * i + 1] = u1;
        } else {
            double r[2];
            vs_limit_row(u0, u1, p0, p1, vmax, step, r);
            out[2 * i] = r[0];
            out[2 * i + 1] = r[1];
        }
    }
    return VS_OK;
}
