/* vs_kin.h - differential-drive kinematics over one control tick, every robot a row
 * (Tan & Lewis 1996, eqs 17-18), as vsfleet/kinematics.py's vectorised functions.
 *
 * Units and frames: poses (x [m], y [m], th [rad, CCW from +x]) in the world frame; wheel
 * speeds (vl, vr) [m/s] are ground speeds, left then right (vr > vl turns CCW); wheel bases [m];
 * dt [s]; accelerations [m/s^2].  Arrays as vscore.h: (n, 2) / (n, 3) row-major, n rows.
 *
 * Every function returns VS_OK or a negative VS_E* code and writes its output only on VS_OK.
 * Inputs that are not finite are refused (VS_ENONFINITE), and so is a result that would not
 * be finite (an overflow, a zero wheel base).  An output may be the very array of an input of
 * the same shape (in place), never a partly overlapping one.
 */
#ifndef VS_KIN_H
#define VS_KIN_H

#include <stddef.h>

/* Below this |x| vs_sinc uses the series 1 - x^2/6 (1 - x^2/20) (error < 1e-24 there). */
#define VS_SINC_SERIES_BELOW 1e-4

/* The wheel limit's corners (vs_limit_wheels, rule 2, in its rows' vs_limit_row) whose angles to the command
 * differ by at most this [rad] tie, and the nearer to the command is taken: two corners on one ray from the
 * origin (a wheel braking to zero in one tick, its bound p - a dt a rounding away from 0) differ in angle by
 * less than an ulp of it, and a command one ulp off (the core's and the reference's, within 1e-9 of each
 * other) chose the other corner. */
#define VS_CORNER_TIE_RAD 1e-9

/* sin(x)/x, smooth through 0 (no check: x finite). */
double vs_sinc(double x);

/* out[i] = sin(x[i]) / x[i] (vs_sinc), n values. */
int vs_sinc_v(const double *x, size_t n, double *out);

/* out[i] = x[i] wrapped to [-pi, pi) [rad], as vsfleet.geometry.wrap_angle (exact fmod). */
int vs_wrap_angles(const double *th_rad, size_t n, double *out);

/* One row of vs_integrate_arcs (no checks): the pose after driving (vl, vr) for dt_s. */
void vs_arc_row(const double pose[3], double vl_m_s, double vr_m_s, double dt_s, double wheel_base_m,
                double out[3]);

/* Poses (n, 3) after driving each row's wheels (n, 2) for dt_s [s] (any finite dt, 0 included)
 * on the exact arc (paper eqs 17-18): chord v dt sinc(w dt / 2) along th + w dt / 2, heading
 * th + w dt, not wrapped.  wheel_base_m: n values. */
int vs_integrate_arcs(const double *pose_world, const double *wheels_m_s, double dt_s, const double *wheel_base_m,
                      size_t n, double *out_pose_world);

/* vs_integrate_arcs with its scratch in the caller's workspace: work holds VS_INTEGRATE_ARCS_WORK_F64(n) doubles
 * (no allocation), or is NULL (vs_integrate_arcs: allocated for the one call). */
int vs_integrate_arcs_ws(const double *pose_world, const double *wheels_m_s, double dt_s, const double *wheel_base_m,
                         size_t n, double *out_pose_world, double *work);
#define VS_INTEGRATE_ARCS_WORK_F64(n) (3 * (n))

/* One row of vs_limit_wheels (no checks): u (vl, vr) limited around the previous command p. */
void vs_limit_row(double u0, double u1, double p0, double p1, double speed_max_m_s, double step_max_m_s,
                  double out[2]);

/* Wheel commands (n, 2) [m/s] clipped to each row's speed limit wheel_speed_max_m_s [m/s] and to a
 * change of at most wheel_accel_max_m_s2 * dt_s from wheels_prev_m_s (n, 2).  Feasible rows come back
 * unchanged; otherwise the ray s u with the largest s <= 1, else the smallest s > 1 (curvature kept);
 * else the box corner nearest in angle within 90 deg; else the reachable point nearest zero; then
 * each wheel is bounded between zero and its command, or (when the box lies beyond) put at the box's
 * point nearest zero: no wheel ends faster than its command asks unless one tick cannot slow it more,
 * so a stop or a slow-down (the safety filter's) is never turned into motion.  A previous command
 * beyond the speed limit (an accel box that misses the speed box) leaves the speed box alone for
 * both wheels, as in vs_safety_filter (n_accel_relaxed).
 * dt_s must be > 0 (VS_EVALUE). */
int vs_limit_wheels(const double *wheels_m_s, const double *wheels_prev_m_s, double dt_s,
                    const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2, size_t n, double *out);

/* sqrt(x^2 + y^2) without overflow or underflow of the squares (scaled by powers of two beyond
 * 2^+-500), as numpy's hypot; equal to vs_hypot(x, y) within that range. */
double vs_hypot_safe(double x, double y);

/* 1 if all n values are finite. */
int vs_all_finite(const double *x, size_t n);

#endif
