/* vs_safety.h - the fleet-wide safety filter: control barrier functions for every pair of robot
 * bodies and every round obstacle, within each robot's wheel envelope (issue 22; docs/safety.md).
 *
 * Every agent sees every pose and computes every robot's command (rows = robots), so every agent
 * runs this filter on the whole fleet and gets the same bits: no iteration that stops on a
 * tolerance, fixed row order, the core's own trig (vs_math.h), sums in index order.
 *
 * Model.  Robot i is a unicycle driven by its wheels u_i = (vl, vr) [m/s]: v = (vl + vr) / 2,
 * w = (vr - vl) / b_i.  Its control point p_i = (x, y) + l (cos th, sin th) (l = offset_m >= 0;
 * l > 0 is Robotarium's single-integrator-at-an-offset-point reduction) moves with
 *     dp_i/dt = J_i u_i = v e_i + l w e_i_perp,  e_i = (cos th, sin th).
 * The body (a disk of radius r_i about (x, y)) lies inside the disk of radius r_i + l about p_i.
 *
 * Barriers.  Pair (i, j), both active: h = |p_i - p_j|^2 - (r_i + r_j + 2 l + margin)^2, kept by
 *     dh/dt = 2 d.(J_i u_i - J_j u_j) >= -gamma h        (d = p_i - p_j; linear class-K),
 * shared in halves (Wang, Ames, Egerstedt 2017): robot i takes 2 d.J_i u_i >= -gamma h / 2, robot
 * j the mirror.  An inactive robot j is a fixed disk of radius r_j about its centre (command
 * zero); a round obstacle (x, y, R) likewise; the active robot takes the whole constraint:
 *     2 d.J_i u_i >= -gamma h,  h = |p_i - c|^2 - (r_i + l + R + margin)^2.
 * Where the control points' h < 0 (bodies closer than the offset allows, as in a crowded start:
 * the offset barrier does not hold there and would not protect the bodies), the row is the same
 * barrier on the centres (l = 0, disk sums without the offset), which constrains v alone.  Either
 * barrier, while >= 0, keeps the bodies margin apart; the choice depends on |p_i - p_j| only, so
 * both robots of a pair choose alike.
 * With an accel limit (wheel_accel_max_m_s2 and wheels_prev_m_s given), each active robot's
 * stopping distance (vl_prev^2 + vr_prev^2) / (4 amax) (a bound on how far its centre goes while
 * both wheels brake at amax from the previous command) joins its radius in every sum: a first-order barrier does not know that a robot needs room to brake,
 * and a robot that turns toward a body while moving would otherwise be asked to stop at once.
 * A constraint that no wheel command within |vl|, |vr| <= vmax can violate is left out.
 *
 * Solve.  With the constraints split this way, min sum_i |u_i - u_i_nominal|^2 separates into
 * one 2-variable problem per robot: the Euclidean projection of its nominal command onto the
 * convex polygon {a_k.u >= b_k} intersected with its wheel box [lo, hi]^2, where
 *     lo = max(-vmax, prev - amax dt), hi = min(vmax, prev + amax dt)
 * (the speed box alone when accel_max or wheels_prev is NULL).  It is solved exactly, by a fixed
 * enumeration: the nominal itself if feasible, else the best feasible point among the feet of
 * the violated constraints' lines and the vertices on them (the optimum lies on a line that the
 * nominal violates).  Degrading safely: if the polygon is empty (only rows with h < 0, bodies
 * inside the margin, can empty it), those rows are softened from "separate at rate -gamma h" to
 * "do not close" (b = 0); if it is still empty (the accel box excludes every such command), the
 * speed box replaces the accel box (the accel limit yields to safety); (0, 0) then meets every
 * row, so the last resort, stopping, is reached only by rounding.
 *
 * Guarantees (continuous time): an active robot's half keeps dh/dt >= -gamma h / 2 whatever its
 * neighbour does within its own half or when it stops, so h >= 0 is invariant and h < 0 (a start
 * inside the margin, or noise) does not decrease (it increases unless softened).  Over a tick dt the control points move on arcs: with
 * gamma dt <= 1 (enforced) and straight motion, h(t + dt) >= (1 - gamma dt) h(t) >= 0 exactly;
 * the arc's departure from a straight line (<= vmax^2 dt^2 / b per robot) and the tracker's noise
 * are what margin_m covers.
 */
#ifndef VS_SAFETY_H
#define VS_SAFETY_H

#include <stddef.h>

typedef struct {
    double margin_m;      /* >= 0: added to every sum of radii [m] (tracker noise, arc lookahead) */
    double gamma_per_s;   /* > 0, gamma_per_s * dt_s <= 1: the linear class-K gain [1/s] */
    double offset_m;      /* >= 0: the control point ahead of each robot's centre [m] */
    double dt_s;          /* > 0: the control tick [s] (accel box, the discrete-time bound) */
} vs_safety_params;

typedef struct {
    int n_constraints;    /* barrier rows kept (could bind within the speed box), over all robots */
    int n_modified;       /* active robots whose nominal command was not feasible */
    int n_softened;       /* active robots whose polygon was empty: rows with b > 0 set to b = 0 */
    int n_accel_relaxed;  /* active robots solved without their accel box (empty with it) */
    int n_stopped;        /* active robots stopped: no command met their constraints */
} vs_safety_stats;

/* Filter every robot's nominal wheel command (n, 2) [m/s] into a safe one (n, 2).
 *   pose_world (n*3) [m, m, rad]; radius_m (n) >= 0; active (n) 0/1, NULL = all active (inactive
 *   rows are fixed disks, their output rows are 0); wheel_base_m (n) > 0; wheel_speed_max_m_s (n)
 *   > 0; wheel_accel_max_m_s2 (n) > 0 and wheels_prev_m_s (n*2), both or neither (NULL);
 *   obstacles (n_obstacles*3: x, y, r >= 0) [m]; stats: optional (NULL).
 * Errors: VS_EVALUE (NULL arrays with n > 0, a parameter out of range), VS_ENONFINITE (NaN or
 * infinity anywhere, or a magnitude above 1e150 whose square would overflow), VS_ENOMEM.
 * Outputs are written only on VS_OK; wheels_safe_m_s may alias wheels_nominal_m_s. */
int vs_safety_filter(const vs_safety_params *p, size_t n, const double *pose_world,
                     const double *radius_m, const unsigned char *active, const double *wheel_base_m,
                     const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2,
                     const double *wheels_prev_m_s, size_t n_obstacles, const double *obstacles,
                     const double *wheels_nominal_m_s, double *wheels_safe_m_s,
                     vs_safety_stats *stats);

/* vs_safety_filter with its scratch in the caller's workspace: work holds VS_SAFETY_WORK_F64(n, n_obstacles)
 * doubles (no allocation), or is NULL (vs_safety_filter: allocated for the one call). */
int vs_safety_filter_ws(const vs_safety_params *p, size_t n, const double *pose_world,
                        const double *radius_m, const unsigned char *active, const double *wheel_base_m,
                        const double *wheel_speed_max_m_s, const double *wheel_accel_max_m_s2,
                        const double *wheels_prev_m_s, size_t n_obstacles, const double *obstacles,
                        const double *wheels_nominal_m_s, double *wheels_safe_m_s,
                        vs_safety_stats *stats, double *work);
/* points 5 n, barrier rows 3 ((n - 1) + n_obstacles + 4), commands 2 n */
#define VS_SAFETY_WORK_F64(n, n_obstacles) (10 * (n) + 3 * (n_obstacles) + 9)

#endif
