/* vs_control.h - the trajectory controllers of vsfleet/control.py, every robot a row:
 * structure points -> wheel speeds.
 *
 * Units and frames (vscore.h): poses (x [m], y [m], th [rad, CCW from +x]) and points [m] in
 * the world frame (the tracker's floor); wheel speeds (vl, vr) [m/s], left then right; times
 * [s]; rows in the mission's sorted id order; (n, k) arrays row-major.
 *
 * Every controller: rows whose active[i] is 0 get zero wheels and keep their state; the
 * wheels have passed vs_limit_wheels (the envelope); a row whose law gives a non-finite wheel
 * speed (an overflow) commands 0 on that wheel before the limiter, as the reference.  Each row
 * depends on that row's inputs only, so one robot's command is the same bits whatever the
 * other rows hold.  Returns VS_OK or VS_E*; outputs (state and wheels) are written only on
 * VS_OK.  Refused: any input (state included) not finite (VS_ENONFINITE), dt_s <= 0 or
 * age_s < 0 (VS_EVALUE), and a new state that would not be finite (VS_ENONFINITE; the
 * numpy reference lets inf/NaN into its state there).  Scratch: one malloc per call
 * (vs_control_precision), freed before it returns (VS_ENOMEM if it fails).
 */
#ifndef VS_CONTROL_H
#define VS_CONTROL_H

#include <stddef.h>

/* What a controller needs for one frame (vsfleet.control.ControlInput). */
typedef struct {
    size_t n;                            /* robots (rows) */
    const double *pose_world;            /* n*3: observed poses [m, m, rad; world] */
    const double *point_now_world;       /* n*2: each robot's structure point at the frame's time [m; world] */
    const double *point_next_world;      /* n*2: the same point dt_s later [m; world] */
    const double *wheels_prev_m_s;       /* n*2: the last commands sent (vl, vr) [m/s] */
    double dt_s;                         /* control tick [s], > 0 */
    double age_s;                        /* observation -> the command taking effect [s], >= 0 */
    const double *wheel_base_m;          /* n: [m] */
    const double *wheel_speed_max_m_s;   /* n: [m/s] */
    const double *wheel_accel_max_m_s2;  /* n: [m/s^2] */
    const unsigned char *active;         /* n: 1 = command this row, 0 = zero wheels, state kept */
} vs_control_input;

/* ------------------------------------------------------------------ precision (the default) */

/* vsfleet.control.Precision's gains, in its field order (see its docstring for the meaning). */
typedef struct {
    double position_gain_per_s;   /* [1/s] */
    double offset_m;              /* [m], the point ahead of the axle that is steered */
    double pose_gain_ratio;       /* own-pose filter, position share of the innovation */
    double heading_gain_ratio;    /* own-pose filter, heading share */
    double target_gain_ratio;     /* target smoothing */
    double feed_gain_ratio;       /* feed-forward velocity smoothing */
    double turn_gain_ratio;       /* the feed-forward turn-rate tracker */
    double reverse_cos_ratio;     /* reverse hysteresis: cos below -this drives in reverse */
    double gain_rate_ratio;       /* wheel-gain estimator rate (NLMS), >= 0 */
    double gain_min_ratio;        /* wheel gains kept within [min, max] */
    double gain_max_ratio;
    double moving_speed_m_s;      /* [m/s] below which the point counts as resting */
    double travel_floor_m;        /* [m] regulariser of the estimator */
    double gain_boost_from_m;     /* [m] a robot farther than this from its point adapts its gains faster: */
    double gain_boost_per_m;      /* [1/m] rate x (1 + min(max_ratio, per_m (distance - from_m))), >= 0 */
    double gain_boost_max_ratio;  /* the most extra rate, >= 0 */
    double gain_boost_mean_ratio; /* the distance is that of the offset's running mean: each frame it moves this
                                   * share of the way to the offset observed, in (0, 1] (1: this frame's alone) */
} vs_precision_gains;

#define VS_PRECISION_HISTORY 5   /* commands kept besides the last one sent */

/* vsfleet.control.PrecisionState, rows = robots. */
typedef struct {
    double *pose_world;      /* n*3: filtered pose at the last observation [m, m, rad; world] */
    double *gains;           /* n*2: wheel gains estimated (actual / commanded), left, right */
    double *history_m_s;     /* n*5*2: the commands sent before the last one, newest first [m/s] */
    double *target_world;    /* n*2: filtered target point [m; world] */
    double *feed_m_s;        /* n*2: filtered feed-forward velocity [m/s; world] */
    double *turn_rad_s;      /* n: rate at which the feed-forward velocity turns [rad/s] */
    double *direction;       /* n: +1 ahead, -1 in reverse */
    double *offset_world;    /* n*2: running mean of the observed pose minus the point [m; world] (the gain boost) */
    unsigned char *ready;    /* n: 1 once the row has been initialised */
} vs_precision_state;

/* One frame of Precision for every row: reads `state`, writes the new state to `out` (which may
 * be `state` itself, in place: everything is computed into scratch first) and wheels_out (n*2)
 * [m/s].  The state's arrays are read as const. */
int vs_control_precision(const vs_precision_gains *g, const vs_precision_state *state, const vs_control_input *in,
                         vs_precision_state *out, double *wheels_out);

/* vs_control_precision with its scratch in the caller's workspace: work holds VS_CONTROL_PRECISION_WORK_F64(n)
 * doubles (no allocation), or is NULL (vs_control_precision: allocated for the one call). */
int vs_control_precision_ws(const vs_precision_gains *g, const vs_precision_state *state, const vs_control_input *in,
                            vs_precision_state *out, double *wheels_out, double *work);
#define VS_CONTROL_PRECISION_WORK_F64(n) ((n) * (3 + 2 + 2 * VS_PRECISION_HISTORY + 2 + 2 + 1 + 1 + 2 + 2))

/* ------------------------------------------------------------------ the stateless ones */

typedef struct {
    double turn_gain_m_s_per_rad;  /* K [m/s per rad] */
    double d_max_m;                /* [m] */
    double horizon_s;              /* [s], >= 0 (at least one tick is used) */
    double turn_fade_radius_m;     /* [m], > 0 */
    int allow_reverse;             /* 1: atan of the half plane (reverse onto a point behind) */
} vs_turn_then_go_gains;

/* Paper eqs 9-11 (vsfleet.control.TurnThenGo): wheels_out n*2 [m/s]. */
int vs_control_turn_then_go(const vs_turn_then_go_gains *g, const vs_control_input *in, double *wheels_out);

/* Paper eqs 12-16 (vsfleet.control.Arc), horizon_s [s] >= 0: wheels_out n*2 [m/s]. */
int vs_control_arc(double horizon_s, const vs_control_input *in, double *wheels_out);

typedef struct {
    double along_gain_per_s;       /* kx [1/s] */
    double lateral_gain_per_m2;    /* ky [1/m^2] */
    double heading_gain_per_m;     /* kth [1/m] */
    double regulate_gain_per_s;    /* [1/s] */
    double regulate_radius_m;      /* [m] */
    double moving_speed_m_s;       /* [m/s] */
} vs_tracking_gains;

/* Kanayama et al. (1990) with feed-forward (vsfleet.control.Tracking): wheels_out n*2 [m/s]. */
int vs_control_tracking(const vs_tracking_gains *g, const vs_control_input *in, double *wheels_out);

/* vsfleet.control.Held's deadband, after the inner controller: a row whose point moves at most
 * still_speed_m_s * dt_s in the tick and lies within deadband_m [m] of the robot brakes toward
 * zero within the envelope (active rows only).  wheels (n*2) [m/s] are read and rewritten in
 * place, only on VS_OK. */
int vs_control_hold(double deadband_m, double still_speed_m_s, const vs_control_input *in, double *wheels);

#endif
