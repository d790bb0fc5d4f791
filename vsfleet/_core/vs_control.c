/* vs_control.c - see vs_control.h.  Each formula follows the operation order of the numpy
 * reference in vsfleet/control.py (the classes' `reference` methods), row by row. */
#include "vs_control.h"
#include "vs_kin.h"
#include "vscore.h"

#include <math.h>   /* sqrt only */
#include <stdlib.h>
#include <string.h>

static double maxd(double a, double b) { return a > b ? a : b; }
static double mind(double a, double b) { return a < b ? a : b; }

/* The input's own checks (shared by every controller). */
static int check_input(const vs_control_input *in)
{
    size_t n = in->n;
    if (!vs_isfinite(in->dt_s) || !vs_isfinite(in->age_s)) return VS_ENONFINITE;
    if (!(in->dt_s > 0.0) || !(in->age_s >= 0.0)) return VS_EVALUE;
    if (!vs_all_finite(in->pose_world, 3 * n) || !vs_all_finite(in->point_now_world, 2 * n)
        || !vs_all_finite(in->point_next_world, 2 * n) || !vs_all_finite(in->wheels_prev_m_s, 2 * n)
        || !vs_all_finite(in->wheel_base_m, n) || !vs_all_finite(in->wheel_speed_max_m_s, n)
        || !vs_all_finite(in->wheel_accel_max_m_s2, n))
        return VS_ENONFINITE;
    return VS_OK;
}

/* control.py's _finish for row i: non-finite wheel -> 0, the envelope, inactive rows zero. */
static void finish_row(const vs_control_input *in, size_t i, double w0, double w1, double out[2])
{
    if (!in->active[i]) { out[0] = 0.0; out[1] = 0.0; return; }
    if (!vs_isfinite(w0)) w0 = 0.0;
    if (!vs_isfinite(w1)) w1 = 0.0;
    double p0 = in->wheels_prev_m_s[2 * i], p1 = in->wheels_prev_m_s[2 * i + 1];
    double vmax = in->wheel_speed_max_m_s[i], step = in->wheel_accel_max_m_s2[i] * in->dt_s;
    if (vs_fabs(w0) <= vmax && vs_fabs(w0 - p0) <= step && vs_fabs(w1) <= vmax && vs_fabs(w1 - p1) <= step) {
        out[0] = w0;
        out[1] = w1;
    } else {
        vs_limit_row(w0, w1, p0, p1, vmax, step, out);
    }
}

/* world point -> robot frame [m; +x ahead, +y left] (control.py's _robot_frame) */
static void robot_frame(const double *pose, double px, double py, double *dx, double *dy)
{
    double wx = px - pose[0], wy = py - pose[1], s, c;
    vs_sincos(pose[2], &s, &c);
    *dx = c * wx + s * wy;
    *dy = -s * wx + c * wy;
}

/* atan(y / x) in [-pi/2, pi/2], +-pi/2 (by y's sign) at x = 0, 0 at the origin */
static double half_plane_angle(double y, double x)
{
    if (x == 0.0) return y != 0.0 ? (y > 0.0 ? 0.5 * VS_PI : -0.5 * VS_PI) : 0.0;
    return vs_atan(y / x);
}

/* the turn wheel speed capped to brake to rest within angle (share 0.5 of the acceleration) */
static double braked_turn(double turn_m_s, double angle_rad, double base, double accel)
{
    double reach = 0.5 * base * vs_fabs(angle_rad);
    double cap = sqrt(2.0 * 0.5 * accel * reach);
    return maxd(-cap, mind(cap, turn_m_s));
}

/* Python's int(a // b) for a >= 0, b > 0, capped at `cap` */
static int floordiv_capped(double a, double b, int cap)
{
    double mod = vs_fmod(a, b);
    double div = (a - mod) / b;
    if (!(div < (double)cap + 2.0)) return cap;
    double fl = (double)(long)div;   /* floor: div >= 0 */
    if (div - fl > 0.5) fl += 1.0;
    int m = (int)fl;
    return m < cap ? m : cap;
}

/* ------------------------------------------------------------------ precision */

#define H VS_PRECISION_HISTORY
/* per row in the scratch: pose 3, gains 2, history 10, target 2, feed 2, turn, direction, wheels 2, offset 2 */
#define ROW VS_CONTROL_PRECISION_WORK_F64(1)

int vs_control_precision(const vs_precision_gains *g, const vs_precision_state *state, const vs_control_input *in,
                         vs_precision_state *out, double *wheels_out)
{
    return vs_control_precision_ws(g, state, in, out, wheels_out, NULL);
}

int vs_control_precision_ws(const vs_precision_gains *g, const vs_precision_state *state, const vs_control_input *in,
                            vs_precision_state *out, double *wheels_out, double *work)
{
    int rc = check_input(in);
    if (rc != VS_OK) return rc;
    const double gv[17] = {g->position_gain_per_s, g->offset_m, g->pose_gain_ratio, g->heading_gain_ratio,
                           g->target_gain_ratio, g->feed_gain_ratio, g->turn_gain_ratio, g->reverse_cos_ratio,
                           g->gain_rate_ratio, g->gain_min_ratio, g->gain_max_ratio, g->moving_speed_m_s,
                           g->travel_floor_m, g->gain_boost_from_m, g->gain_boost_per_m, g->gain_boost_max_ratio,
                           g->gain_boost_mean_ratio};
    if (!vs_all_finite(gv, 17)) return VS_ENONFINITE;
    size_t n = in->n;
    if (!vs_all_finite(state->pose_world, 3 * n) || !vs_all_finite(state->gains, 2 * n)
        || !vs_all_finite(state->history_m_s, 2 * H * n) || !vs_all_finite(state->target_world, 2 * n)
        || !vs_all_finite(state->feed_m_s, 2 * n) || !vs_all_finite(state->turn_rad_s, n)
        || !vs_all_finite(state->direction, n) || !vs_all_finite(state->offset_world, 2 * n))
        return VS_ENONFINITE;
    if (n == 0) return VS_OK;
    double *own = NULL, *scratch = work;
    if (scratch == NULL && (own = scratch = malloc(n * ROW * sizeof *scratch)) == NULL) return VS_ENOMEM;

    const double dt = in->dt_s, age = in->age_s;
    const int m = floordiv_capped(age, dt, H - 1);
    double frac = 0.0;
    if (m < H - 1) {
        double x = age - m * dt;
        x = 0.0 > x ? 0.0 : x;      /* Python's max(x, 0.0) */
        frac = dt < x ? dt : x;     /* min(x, dt) */
    }
    const double floor2 = g->travel_floor_m * g->travel_floor_m;
    const double l = g->offset_m, ms = g->moving_speed_m_s;

    for (size_t i = 0; i < n; i++) {
        double *r = scratch + i * ROW;
        double *o_pose = r, *o_gains = r + 3, *o_hist = r + 5, *o_target = r + 5 + 2 * H,
               *o_feed = o_target + 2, *o_turn = o_feed + 2, *o_dir = o_turn + 1, *o_wheels = o_dir + 1,
               *o_off = o_wheels + 2;
        const double *sp = state->pose_world + 3 * i, *sg = state->gains + 2 * i;
        const double *sh = state->history_m_s + 2 * H * i;
        if (!in->active[i]) {   /* zero wheels, the state kept */
            memcpy(o_pose, sp, 3 * sizeof(double));
            memcpy(o_gains, sg, 2 * sizeof(double));
            memcpy(o_hist, sh, 2 * H * sizeof(double));
            memcpy(o_target, state->target_world + 2 * i, 2 * sizeof(double));
            memcpy(o_feed, state->feed_m_s + 2 * i, 2 * sizeof(double));
            *o_turn = state->turn_rad_s[i];
            *o_dir = state->direction[i];
            memcpy(o_off, state->offset_world + 2 * i, 2 * sizeof(double));
            o_wheels[0] = o_wheels[1] = 0.0;
            continue;
        }
        const double base = in->wheel_base_m[i];
        const double *z = in->pose_world + 3 * i;
        const int fresh = !state->ready[i];
        /* commands in effect, newest first: seq[j] was sent j + 1 frames before this one */
        const double *seq[H + 1];
        seq[0] = in->wheels_prev_m_s + 2 * i;
        for (int j = 0; j < H; j++) seq[j + 1] = sh + 2 * j;

        /* 1. filter, previous observation -> this one: seq[m + 1] for frac, then seq[m] */
        double pred[3];
        if (frac > 0.0) vs_arc_row(sp, sg[0] * seq[m + 1][0], sg[1] * seq[m + 1][1], frac, base, pred);
        else memcpy(pred, sp, sizeof pred);
        vs_arc_row(pred, sg[0] * seq[m][0], sg[1] * seq[m][1], dt - frac, base, pred);
        double travel[2];
        for (int k = 0; k < 2; k++) travel[k] = sg[k] * (seq[m][k] * (dt - frac) + seq[m + 1][k] * frac);
        double nx = z[0] - pred[0], ny = z[1] - pred[1];
        double nth = vs_wrap_angle(z[2] - pred[2]);
        double s, c;
        vs_sincos(pred[2], &s, &c);
        double along = c * nx + s * ny;
        double d_wheel[2] = {along - 0.5 * base * nth, along + 0.5 * base * nth};
        /* a robot measurably off its point (a wheel-gain change shows there first, e.g. a robot slowed or
         * back to speed) adapts its gains faster: the rate times 1 + min(max, per_m (distance - from)), the
         * distance that of the offset's running mean (the tracker's noise alone seldom moves the mean that far) */
        const double *pn = in->point_now_world + 2 * i, *so = state->offset_world + 2 * i;
        double ox = so[0] + g->gain_boost_mean_ratio * ((z[0] - pn[0]) - so[0]);
        double oy = so[1] + g->gain_boost_mean_ratio * ((z[1] - pn[1]) - so[1]);
        o_off[0] = ox;
        o_off[1] = oy;
        double off = sqrt(ox * ox + oy * oy);
        double boost = 1.0 + mind(g->gain_boost_max_ratio, g->gain_boost_per_m * maxd(off - g->gain_boost_from_m, 0.0));
        double gn[2], est[3];
        for (int k = 0; k < 2; k++) {
            double x = sg[k] + g->gain_rate_ratio * boost * d_wheel[k] * travel[k] / (travel[k] * travel[k] + floor2)
                       * sg[k];
            gn[k] = mind(maxd(x, g->gain_min_ratio), g->gain_max_ratio);
        }
        est[0] = pred[0] + g->pose_gain_ratio * nx;
        est[1] = pred[1] + g->pose_gain_ratio * ny;
        est[2] = vs_wrap_angle(pred[2] + g->heading_gain_ratio * nth);
        if (fresh) {
            memcpy(est, z, sizeof est);
            gn[0] = sg[0];
            gn[1] = sg[1];
        }

        /* 2. frame age, this observation -> the command's start: seq[m] for frac, then seq[m-1..0] */
        double p[3];
        if (frac > 0.0) vs_arc_row(est, gn[0] * seq[m][0], gn[1] * seq[m][1], frac, base, p);
        else memcpy(p, est, sizeof p);
        for (int j = m - 1; j >= 0; j--) vs_arc_row(p, gn[0] * seq[j][0], gn[1] * seq[j][1], dt, base, p);

        /* 3. target at the command's start, smoothed around its prediction; the feed-forward
         * velocity tracked as turning at a constant rate */
        const double *now = in->point_now_world + 2 * i, *nxt = in->point_next_world + 2 * i;
        const double *sf = state->feed_m_s + 2 * i, *st = state->target_world + 2 * i;
        const double turn_s = state->turn_rad_s[i];
        double f_raw[2] = {(nxt[0] - now[0]) / dt, (nxt[1] - now[1]) / dt};
        double sa, ca;
        vs_sincos(turn_s * dt, &sa, &ca);
        double fp[2] = {ca * sf[0] - sa * sf[1], sa * sf[0] + ca * sf[1]};
        double nu[2] = {f_raw[0] - fp[0], f_raw[1] - fp[1]};
        double fp2 = fp[0] * fp[0] + fp[1] * fp[1];
        int moving = fp2 > ms * ms;
        double turn;
        if (moving) {
            double turn_nu = (fp[0] * nu[1] - fp[1] * nu[0]) / fp2;
            turn = turn_s + g->turn_gain_ratio * turn_nu / dt;
        } else {
            turn = (1.0 - g->feed_gain_ratio) * turn_s;
        }
        double f[2] = {fp[0] + g->feed_gain_ratio * nu[0], fp[1] + g->feed_gain_ratio * nu[1]};
        if (fresh) {
            f[0] = f_raw[0];
            f[1] = f_raw[1];
            turn = 0.0;
        }
        o_feed[0] = f[0];
        o_feed[1] = f[1];
        double target[2];
        for (int k = 0; k < 2; k++) {
            double raw = now[k] + age * f_raw[k];
            double guess = st[k] + sf[k] * dt;
            target[k] = fresh ? raw : guess + g->target_gain_ratio * (raw - guess);
        }

        /* 4. offset-point law (the direction of motion at the middle of the command's tick) */
        vs_sincos(turn * age, &sa, &ca);
        double fa[2] = {ca * f[0] - sa * f[1], sa * f[0] + ca * f[1]};
        double w_last = (gn[1] * seq[0][1] - gn[0] * seq[0][0]) / base;
        double th_mid = p[2] + 0.5 * dt * w_last;
        double speed = vs_hypot_safe(fa[0], fa[1]);
        double lam = mind(1.0, speed / ms);
        double hc[2];
        vs_sincos(th_mid, &hc[1], &hc[0]);
        double safe = speed > 0.0 ? speed : 1.0;
        const double dir_s = state->direction[i];
        double along_f = (fa[0] * hc[0] + fa[1] * hc[1]) / safe * dir_s;
        double direction = (speed > ms && along_f < -g->reverse_cos_ratio) ? -dir_s : dir_s;
        if (fresh) direction = (speed > 0.0 && along_f < 0.0) ? -1.0 : 1.0;
        double m_dir[2] = {direction * hc[0], direction * hc[1]};
        double hr[2], hb[2];
        for (int k = 0; k < 2; k++) hr[k] = speed > 0.0 ? fa[k] / safe : m_dir[k];
        for (int k = 0; k < 2; k++) hb[k] = lam * hr[k] + (1.0 - lam) * m_dir[k];
        double hb_n = vs_hypot_safe(hb[0], hb[1]);
        for (int k = 0; k < 2; k++) hb[k] = hb_n > 1e-9 ? hb[k] / hb_n : m_dir[k];
        double nr[2] = {-hb[1], hb[0]};
        double u[2];
        for (int k = 0; k < 2; k++) {
            double feed = fa[k] + lam * l * turn * nr[k];
            double err = (target[k] - p[k]) + l * (hb[k] - m_dir[k]);
            u[k] = feed + g->position_gain_per_s * err;
        }
        double v = u[0] * hc[0] + u[1] * hc[1];
        double w = (-u[0] * hc[1] + u[1] * hc[0]) / (l * direction);
        double half = 0.5 * w * base;
        finish_row(in, i, (v - half) / gn[0], (v + half) / gn[1], o_wheels);

        memcpy(o_pose, est, sizeof est);
        o_gains[0] = gn[0];
        o_gains[1] = gn[1];
        memcpy(o_hist, seq[0], 2 * sizeof(double));
        memcpy(o_hist + 2, sh, 2 * (H - 1) * sizeof(double));
        memcpy(o_target, target, sizeof target);
        *o_turn = turn;
        *o_dir = direction;
    }
    if (!vs_all_finite(scratch, n * ROW)) { free(own); return VS_ENONFINITE; }
    for (size_t i = 0; i < n; i++) {
        const double *r = scratch + i * ROW;
        out->ready[i] = (unsigned char)(state->ready[i] || in->active[i]);
        memcpy(out->pose_world + 3 * i, r, 3 * sizeof(double));
        memcpy(out->gains + 2 * i, r + 3, 2 * sizeof(double));
        memcpy(out->history_m_s + 2 * H * i, r + 5, 2 * H * sizeof(double));
        memcpy(out->target_world + 2 * i, r + 5 + 2 * H, 2 * sizeof(double));
        memcpy(out->feed_m_s + 2 * i, r + 7 + 2 * H, 2 * sizeof(double));
        out->turn_rad_s[i] = r[9 + 2 * H];
        out->direction[i] = r[10 + 2 * H];
        memcpy(wheels_out + 2 * i, r + 11 + 2 * H, 2 * sizeof(double));
        memcpy(out->offset_world + 2 * i, r + 13 + 2 * H, 2 * sizeof(double));
    }
    free(own);
    return VS_OK;
}

/* ------------------------------------------------------------------ the stateless ones */

/* max(1.0, horizon / dt) as Python's max */
static double horizon_ticks(double horizon_s, double dt)
{
    double x = horizon_s / dt;
    return x > 1.0 ? x : 1.0;
}

int vs_control_turn_then_go(const vs_turn_then_go_gains *g, const vs_control_input *in, double *wheels_out)
{
    int rc = check_input(in);
    if (rc != VS_OK) return rc;
    if (!vs_isfinite(g->turn_gain_m_s_per_rad) || !vs_isfinite(g->d_max_m) || !vs_isfinite(g->horizon_s)
        || !vs_isfinite(g->turn_fade_radius_m))
        return VS_ENONFINITE;
    const double dt = in->dt_s, h = horizon_ticks(g->horizon_s, dt);
    for (size_t i = 0; i < in->n; i++) {
        const double *now = in->point_now_world + 2 * i, *nxt = in->point_next_world + 2 * i;
        double dx, dy;
        robot_frame(in->pose_world + 3 * i, now[0] + h * (nxt[0] - now[0]), now[1] + h * (nxt[1] - now[1]), &dx, &dy);
        double dist = vs_hypot_safe(dx, dy);
        double w0 = 0.0, w1 = 0.0;
        if (dist != 0.0) {
            double th_err = g->allow_reverse ? half_plane_angle(dy, dx) : vs_atan2(dy, dx);
            double v = mind(g->d_max_m, dist) / (h * dt) * (dx / dist);
            double turn = braked_turn(g->turn_gain_m_s_per_rad * th_err, th_err, in->wheel_base_m[i],
                                      in->wheel_accel_max_m_s2[i]) * mind(1.0, dist / g->turn_fade_radius_m);
            w0 = v - turn;
            w1 = v + turn;
        }
        finish_row(in, i, w0, w1, wheels_out + 2 * i);
    }
    return VS_OK;
}

int vs_control_arc(double horizon_s, const vs_control_input *in, double *wheels_out)
{
    int rc = check_input(in);
    if (rc != VS_OK) return rc;
    if (!vs_isfinite(horizon_s)) return VS_ENONFINITE;
    const double dt = in->dt_s, h = horizon_ticks(horizon_s, dt), t_s = h * dt;
    for (size_t i = 0; i < in->n; i++) {
        const double *now = in->point_now_world + 2 * i, *nxt = in->point_next_world + 2 * i;
        double dx, dy;
        robot_frame(in->pose_world + 3 * i, now[0] + h * (nxt[0] - now[0]), now[1] + h * (nxt[1] - now[1]), &dx, &dy);
        double dist = vs_hypot_safe(dx, dy);
        double w0 = 0.0, w1 = 0.0;
        if (dist != 0.0) {
            int forward = dx >= 0.0;
            double beta = forward ? vs_atan2(dy, dx) : vs_atan2(-dy, -dx);
            double v = (forward ? 1.0 : -1.0) * dist / (t_s * vs_sinc(beta));
            double w = 2.0 * beta / t_s;
            double half = 0.5 * w * in->wheel_base_m[i];
            w0 = v - half;
            w1 = v + half;
        }
        finish_row(in, i, w0, w1, wheels_out + 2 * i);
    }
    return VS_OK;
}

int vs_control_tracking(const vs_tracking_gains *g, const vs_control_input *in, double *wheels_out)
{
    int rc = check_input(in);
    if (rc != VS_OK) return rc;
    const double gv[6] = {g->along_gain_per_s, g->lateral_gain_per_m2, g->heading_gain_per_m,
                          g->regulate_gain_per_s, g->regulate_radius_m, g->moving_speed_m_s};
    if (!vs_all_finite(gv, 6)) return VS_ENONFINITE;
    const double dt = in->dt_s, kx = g->along_gain_per_s;
    for (size_t i = 0; i < in->n; i++) {
        const double *pose = in->pose_world + 3 * i;
        const double *now = in->point_now_world + 2 * i, *nxt = in->point_next_world + 2 * i;
        const double base = in->wheel_base_m[i];
        double ex, ey, s, c;
        robot_frame(pose, now[0], now[1], &ex, &ey);
        vs_sincos(pose[2], &s, &c);
        double fw0 = (nxt[0] - now[0]) / dt, fw1 = (nxt[1] - now[1]) / dt;
        double fx = c * fw0 + s * fw1, fy = -s * fw0 + c * fw1;
        double v_ref = vs_hypot_safe(fx, fy);
        double lam = mind(1.0, v_ref / g->moving_speed_m_s);
        double v = fx + kx * ex;
        double e_th = vs_atan2(fy, fx);
        double sin_e = vs_sin(e_th);
        double lam4 = (lam * lam) * (lam * lam);
        double heading = sin_e + lam4 * (2.0 * vs_sin(0.5 * e_th) - sin_e);
        double w = lam > 0.0 ? lam * v_ref * (g->lateral_gain_per_m2 * ey + g->heading_gain_per_m * heading) : 0.0;
        double ux = v, uy = fy + kx * ey;
        double u = vs_hypot_safe(ux, uy);
        double alpha = half_plane_angle(uy, ux);
        double half_b = 0.5 * base;
        if (lam < 1.0 && u > 0.0) {
            double turn = braked_turn(g->regulate_gain_per_s * alpha * half_b, alpha, base, in->wheel_accel_max_m_s2[i])
                          / half_b * mind(1.0, u / (kx * g->regulate_radius_m));
            w = w + (1.0 - lam) * turn;
        } else {
            w = w + 0.0;
        }
        double half = 0.5 * w * base;
        finish_row(in, i, v - half, v + half, wheels_out + 2 * i);
    }
    return VS_OK;
}

int vs_control_hold(double deadband_m, double still_speed_m_s, const vs_control_input *in, double *wheels)
{
    int rc = check_input(in);
    if (rc != VS_OK) return rc;
    if (!vs_isfinite(deadband_m) || !vs_isfinite(still_speed_m_s)) return VS_ENONFINITE;
    if (!vs_all_finite(wheels, 2 * in->n)) return VS_ENONFINITE;
    const double still = still_speed_m_s * in->dt_s;
    for (size_t i = 0; i < in->n; i++) {
        const double *pose = in->pose_world + 3 * i;
        const double *now = in->point_now_world + 2 * i, *nxt = in->point_next_world + 2 * i;
        double step = vs_hypot_safe(nxt[0] - now[0], nxt[1] - now[1]);
        double dist = vs_hypot_safe(now[0] - pose[0], now[1] - pose[1]);
        if (in->active[i] && step <= still && dist <= deadband_m) {
            double stop[2];
            double p0 = in->wheels_prev_m_s[2 * i], p1 = in->wheels_prev_m_s[2 * i + 1];
            double vmax = in->wheel_speed_max_m_s[i], st = in->wheel_accel_max_m_s2[i] * in->dt_s;
            if (0.0 <= vmax && vs_fabs(0.0 - p0) <= st && vs_fabs(0.0 - p1) <= st) {
                stop[0] = 0.0;
                stop[1] = 0.0;
            } else {
                vs_limit_row(0.0, 0.0, p0, p1, vmax, st, stop);
            }
            wheels[2 * i] = stop[0];
            wheels[2 * i + 1] = stop[1];
        }
    }
    return VS_OK;
}
