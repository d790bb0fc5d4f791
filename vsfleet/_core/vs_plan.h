/* vs_plan.h - a path for the virtual structure around round obstacles; the compiled twin of
 * vsfleet/plan.py's plan_structure_reference (docs/planning.md has the method and its limits).
 *
 * The structure is treated as its enclosing disc, centred on the structure origin (the pose's
 * (x, y)): radius R = max_i (|p_i| + r_i) + margin.  The disc does not depend on the heading, so
 * any heading along a path that keeps the disc clear keeps every robot body at least margin from
 * every obstacle.  Each obstacle (x, y, r) becomes the disc of radius r + R ("inflated"); the
 * planner finds the shortest path of the centre point among the inflated discs on a tangent graph
 * (tangent segments between discs planned at (1 + VS_PLAN_SLACK) times the inflated radius, and
 * arcs along them drawn as chords of at most VS_PLAN_ARC_STEP_RAD), Dijkstra with fixed tie-breaks.
 * Every segment of the returned polyline is checked exactly (segment-to-centre distance >= the
 * inflated radius), so the guarantee does not rest on the graph's geometry.
 *
 * Units and frames as vscore.h: lengths [m], poses (x, y, th) [m, m, rad; world].
 */
#ifndef VS_PLAN_H
#define VS_PLAN_H

#include <stddef.h>

#include "vscore.h"

#define VS_PLAN_OK 0              /* the waypoints end at the goal pose */
#define VS_PLAN_BLOCKED 1         /* no path: the waypoints end at the closest safe pose */

#define VS_PLAN_MAX_OBSTACLES 256
#define VS_PLAN_MAX_ABS_M 1e6     /* larger coordinates or radii are refused (VS_EVALUE) */
#define VS_PLAN_SLACK 0.01        /* arcs are planned on (1 + slack) * inflated radius */
#define VS_PLAN_ARC_STEP_RAD (VS_PI / 12.0)   /* an arc's chords span at most this angle */
#define VS_PLAN_SIDE_BIAS 0.05    /* counter-clockwise arcs cost (1 + bias) * their length */
#define VS_PLAN_GOAL_TIE_M 1e-9   /* blocked: nodes this close to the best distance tie */

/* The enclosing radius R [m] of the structure: max_i (sqrt(px^2 + py^2) + r_i) + margin_m.
 * VS_EVALUE if n == 0 or a radius or the margin is < 0 or above VS_PLAN_MAX_ABS_M. */
int vs_plan_radius(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                   double *radius_out_m);

/* template_xy: n*2 [m; structure frame]; radius_m: n body radii [m] (>= 0); margin_m >= 0 [m];
 * obstacles: n_obstacles*3 (x, y, r) [m; world], r > 0, n_obstacles <= VS_PLAN_MAX_OBSTACLES;
 * start, goal: (x, y, th) [m, rad; world].  Every value finite (else VS_ENONFINITE) and of
 * magnitude <= VS_PLAN_MAX_ABS_M (else VS_EVALUE); n >= 1 and cap >= 1 (else VS_EVALUE).
 *
 * On VS_OK: waypoints holds *n_waypoints poses (x, y, th) (row-major, *n_waypoints <= cap) and
 * *status is VS_PLAN_OK or VS_PLAN_BLOCKED.  Waypoint 0 is always the start position.
 *   VS_PLAN_OK: the last waypoint is the goal pose (th wrapped); headings turn from the start's to
 *     the goal's (shortest way, angle_diff) linearly in path length.  >= 2 waypoints.
 *   VS_PLAN_BLOCKED: the goal cannot be reached (its disc overlaps an obstacle's, or every way is
 *     shut): the waypoints lead to the reachable graph node nearest the goal (the start itself,
 *     one waypoint, when no node is nearer), all at the start heading (a blocked structure does
 *     not turn).
 * A start whose disc already overlaps an obstacle's may still leave: a segment from the start is
 * allowed if it never gets nearer that obstacle's centre than the start is.
 * VS_ENOMEM: malloc failed, or cap < the waypoints needed; in the latter case (only) *n_waypoints
 * is set to the number needed and nothing else is written: call again with that cap.
 * Cost: O(m^3) segment tests for m obstacles (tens of microseconds at m = 6). */
int vs_plan_structure(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                      const double *obstacles, size_t n_obstacles, const double start[3],
                      const double goal[3], double *waypoints, size_t cap, size_t *n_waypoints,
                      int *status);

#endif
