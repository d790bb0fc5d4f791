/* vs_step.h - the structure part of the agent step: fit, advance, judged fit (one call a frame).
 *
 * As vsfleet.step.structure_step: the structure is fitted to the robots seen and not
 * excluded, advanced one dt_s toward the goal (robots absent or excluded still bound the
 * advance), and each robot's deviation is measured on the structure fitted without the
 * judged_apart robots when two or more others remain (under hold, a failed robot bends the
 * structure the robots follow, and the healthy robots it bends must not look non-compliant).
 * Everything duplicated agents must agree on bit for bit comes out of this one function.
 */
#ifndef VS_STEP_H
#define VS_STEP_H

#include <stddef.h>

#include "vscore.h"
#include "vs_advance.h"
#include "vs_fit.h"
#include "vs_field.h"

/* What a mission fixes for every frame (rows in its sorted robot order). */
typedef struct {
    size_t n;
    const double *template_xy;          /* (n, 2) [m; structure frame] */
    const double *wheel_base_m;         /* (n) [m] */
    const double *wheel_speed_max_m_s;  /* (n) [m/s] */
    const double *wheel_accel_max_m_s2; /* (n) [m/s^2] */
    int metric;                         /* VS_METRIC_* */
    vs_goal goal;
    vs_limits limits;
    /* the room (issue 22); n_obstacles == 0: none, and the structure goes straight for its goal */
    const double *radius_m;             /* (n) robot body radii [m], >= 0 (0: a point) */
    const double *obstacles;            /* (n_obstacles, 3) round obstacles (x, y, r) [m; world] */
    size_t n_obstacles;
    double margin_m;                    /* [m] clearance kept beyond the bodies (tracker noise, the carrot) */
    const vs_field *field;              /* the room's navigation function (vs_field_build, once per mission);
                                           NULL: none, and the structure goes straight for its goal */
    /* reshape (issue 28): shapes the structure may take where the template cannot pass, tried in order after
     * the template (the mission's smaller scales, then its alternative templates); n_shapes == 0: none */
    size_t n_shapes;                    /* <= VS_STEP_MAX_SHAPES */
    const double *shapes_xy;            /* (n_shapes, n, 2) [m; structure frame]: row k's point of robot i */
    const vs_field *const *shape_fields; /* (n_shapes) each shape's field, built once per mission as field */
} vs_mission;

#define VS_STEP_MAX_SHAPES 8            /* a mission's shapes beyond its template, at most */

#define VS_STEP_PATH_M 2.0              /* [m] of the field's descent handed to the advance each frame */
#define VS_STEP_PATH_CAP 160            /* waypoints at most (2 m of 3 cm cells, and rotations) */
#define VS_STEP_HELD_BACK 0.5          /* that share of the move (VS_STEP_LOOKAHEAD_PER_REACH) */
#define VS_STEP_LOOKAHEAD_PER_REACH 0.3 /* following a field: the carrot runs at least this times the shape's
                                           reach (its largest |p_i|) ahead, never less than limits.path_lookahead_m:
                                           a large structure's turn spread over more of its move; but where the
                                           clearance barrier keeps less than half the move asked for (along it),
                                           the advance runs again with limits' own, and that goes through the
                                           barrier instead (a long carrot cut round the obstacle the plan goes
                                           round, and the barrier held a point head on against it) */

typedef struct {
    int any_used;                       /* 0: no robot usable, nothing else written */
    double fit_x, fit_y, fit_th;        /* fitted pose [m, rad; world] (th wrapped to [-pi, pi)) */
    double goal_x, goal_y, goal_th;     /* advanced pose, one dt_s later [m, rad; world] */
    double vx_m_s, vy_m_s, w_rad_s;     /* the twist between them [m/s; world], [rad/s] */
    double cost;                        /* the fit's cost [weighted m] */
    int at_goal;
    int blocked;                        /* obstacles: no path to the goal; the structure heads for the
                                           closest safe pose (the plan's last waypoint) and stops there */
    double left_m;                      /* obstacles: distance [m] from the plan's end to the goal */
    int shape;                          /* the shape taken: 0 the template, k >= 1 shapes_xy's row k - 1 */
    int cleared;                        /* the room's clearance barrier changed the advance's twist (vs_clear.h) */
    int held;                           /* a provisional field with no way from here: the structure holds, and
                                           this frame gives no verdict (blocked 0; vs_field_set_provisional) */
} vs_structure;

/* With a field (a room) and a pose or path goal, the advance follows the field's descent from the fitted
 * pose (vs_field_follow, VS_STEP_PATH_M of it): the same pure function of the frame on every agent.  Its twist
 * then passes the room's clearance barrier (vs_clear.h; not at the goal): the points on the structure keep
 * VS_CLEAR_M from every obstacle, and a point already closer is moved out, held or not.
 * Shapes (n_shapes > 0, with a field): every shape (the template, then shapes_xy's rows in order) is fitted
 * to the robots; the robots are taken to be in the shape whose fit costs least (ties: the first).  The
 * structure takes the first shape whose field is open (vs_field_open) at its own fit and that is either the
 * shape the robots are in or clear of the comfort band (room to change shape); else the first open shape;
 * none open: the template (blocked).  Points, advance and deviations are then that shape's; out->shape says
 * which.  No state is kept: the shape is a function of the frame, so every agent switches at the same frame.
 * A provisional field (vs_field_set_provisional: a first plan) with no way from the fitted pose is no verdict: the
 * structure holds (the advance to the fitted pose itself), and neither blocked nor at_goal is set.
 * pose_world (n, 3) [m, m, rad; world], read on seen rows only; seen, excluded, judged_apart
 * (n) 0/1; elapsed_s [s] since the mission took effect; dt_s [s] > 0.  Outputs (n each, or
 * (n, 2)): used (seen & !excluded), points_now / points_next [m; world] (every robot's point
 * on the fitted / advanced structure), deviations_m [m] (+inf for unseen robots). */
int vs_structure_step(const vs_mission *m, const double *pose_world, const unsigned char *seen,
                      const unsigned char *excluded, const unsigned char *judged_apart, double elapsed_s,
                      double dt_s, vs_structure *out, unsigned char *used, double *points_now,
                      double *points_next, double *deviations_m);

/* vs_structure_step in the caller's workspace: work holds vs_structure_step_work_f64(m->n, m->metric) doubles (no
 * allocation), or is NULL (vs_structure_step: allocated for the one call).  Same results, bit for bit. */
int vs_structure_step_ws(const vs_mission *m, const double *pose_world, const unsigned char *seen,
                         const unsigned char *excluded, const unsigned char *judged_apart, double elapsed_s,
                         double dt_s, vs_structure *out, unsigned char *used, double *points_now,
                         double *points_next, double *deviations_m, double *work);

/* Doubles of workspace vs_structure_step_ws needs for n robots under metric (its fits' and its own). */
size_t vs_structure_step_work_f64(size_t n, int metric);

/* R(th) p + (x, y) for n points (n, 2) -> out (n, 2) [m; world]. */
void vs_apply_pose(double x, double y, double th, const double *points_xy, size_t n, double *out);

#endif
