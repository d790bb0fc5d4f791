/* vs_advance.h - advancing the virtual structure one tick toward its goal (paper step 2, eq 7,
 * with the cost-aware push of 3.3.3); the compiled twin of vsfleet/advance.py's
 * advance_structure_reference (see its docstrings for the why of every step).
 *
 * Units and frames as vscore.h: poses (x, y, th) [m, m, rad; world], angles as
 * vsfleet.geometry.Pose2 stores them (wrapped to [-pi, pi); an angle outside is wrapped first,
 * one inside is used as given), twists (vx, vy) [m/s; world] and w [rad/s, CCW].
 */
#ifndef VS_ADVANCE_H
#define VS_ADVANCE_H

#include <stddef.h>

#include "vscore.h"

#define VS_GOAL_POSE 0
#define VS_GOAL_PATH 1
#define VS_GOAL_TWIST 2
#define VS_GOAL_PLAN 3    /* a room's plan: a path whose carrot is followed turning in step with the move, the
                             * straight way in SE(2), so the structure never turns ahead of the plan (a path
                             * turns and moves each on its own profile) */

/* The cost-aware push's alignment throttle (paper 3.3.3; advance.py alignment_scale): per robot
 * max(VS_ALIGN_FLOOR, |cos d|**power), d the angle between its heading and its point's velocity, with power
 * VS_ALIGN_POWER_PLAN following a room's plan (VS_GOAL_PLAN) and VS_ALIGN_POWER on every other goal.
 * On a plan the structure turns in step with its move, so its points' velocities keep turning and the
 * robots lag them by a steady angle: the softer power lets a square through a thin wall's gap in time
 * instead of crawling at the floor (docs/benchmarks.md 8h). In open space the stiffer power keeps the
 * start's precision (it eases the structure into motion while the robots still turn).
 * On a plan, a robot whose point moves at u below the mission's speed (speed_max_m_s) holds the structure back
 * by that share only: its factor k becomes 1 - (1 - k) u / speed_max_m_s.  Offset-point tracking turns a robot
 * toward its point's motion only as fast as the point moves, so a robot near the structure's centre of turning,
 * its point barely moving and across its heading, held the structure at the floor and, with it, its own turn
 * (bench room 141, a square: 1-2 cm/s for 3 s, one robot 70-89 degrees off a point moving at 1-5 cm/s, every
 * deviation within 6 mm; since 2026-12-06, docs/benchmarks.md 8j).  u is the point's speed under the twist
 * desired after the ramp, so the share also eases the throttle while a plan's structure speeds up at its start
 * and slows down at its end; the compliance throttle still halts it for a robot that falls behind.
 * The powers are integers the core computes by squarings (8: three, 4: two), so no libm pow is needed. */
#define VS_ALIGN_FLOOR 0.2
#define VS_ALIGN_POWER 8
#define VS_ALIGN_POWER_PLAN 4

/* As vsfleet.advance.StructureLimits: every field finite and >= 0, comply_stop_m > comply_full_m. */
typedef struct {
    double speed_max_m_s, turn_rate_max_rad_s, position_tolerance_m, heading_tolerance_rad,
           path_lookahead_m, comply_full_m, comply_stop_m, settle_s, turn_settle_s;
} vs_limits;

typedef struct {
    int kind;                   /* VS_GOAL_* */
    const double *poses;        /* pose goal: 1 pose (x, y, th) [world]; path: n_poses waypoints (x, y, th)
                                 * [world]; twist: 1 triple (vx [m/s], vy [m/s], w [rad/s]) [structure frame] */
    size_t n_poses;             /* 1 for a pose or twist goal, >= 1 for a path */
} vs_goal;

/* The next desired structure pose (x, y, th) [world; th wrapped], the twist that leads there
 * (world), the envelope factor scale in [0, 1] applied to it, and at_goal (1 once a pose or
 * path goal is reached within the tolerances, else 0). */
typedef struct { double x, y, th; double vx_m_s, vy_m_s, w_rad_s; double scale; int at_goal; } vs_advance_result;

/* pose_fit (x, y, th) [m, rad; world]; template_xy n*2 [m; structure]; wheel_base_m,
 * wheel_speed_max_m_s, wheel_accel_max_m_s2: n each (finite, > 0); twist_prev: 3 doubles
 * (vx, vy, w; world) or NULL; elapsed_s: pointer or NULL (NULL = not given); headings_rad,
 * deviations_m: n each (NaN = unseen) or NULL (= not given).  n >= 1; dt_s > 0.
 * NaN marks an unseen robot in headings_rad and deviations_m only; every other non-finite
 * input, and an output that would overflow, is VS_ENONFINITE.  A bad shape, kind or range is
 * VS_EVALUE.  No allocation: O(n) per evaluation, O(n * 400) with twist_prev (the fixed
 * 80-step interval searches), O(n_poses) for a path. */
int vs_advance(const double pose_fit[3], const vs_goal *goal, double dt_s, const vs_limits *limits,
               const double *template_xy, const double *wheel_base_m, const double *wheel_speed_max_m_s,
               const double *wheel_accel_max_m_s2, size_t n, const double *twist_prev, const double *elapsed_s,
               const double *headings_rad, const double *deviations_m, vs_advance_result *out);

/* The two hypotenuses the reference uses, reproduced bit for bit (exposed for the tests):
 * vs_hypot_libm as numpy's np.hypot (glibc >= 2.35's hypot: Borges' correction, no FMA), and
 * vs_hypot_cr as Python's math.hypot (CPython's vector_norm: correctly rounded). */
double vs_hypot_libm(double x, double y);
double vs_hypot_cr(double x, double y);

#endif
