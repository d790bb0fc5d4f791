/* vs_field.h - the structure's way through a room, planned once per mission for its bodies in SE(2):
 * a navigation function (cost to go) over a lattice of structure poses (x, y, th), and the cheap
 * per-frame descent that follows it.  The compiled twin of vsfleet/field.py's reference
 * (docs/planning.md has the method, its guarantees and its limits).
 *
 * Lattice.  States (ix, iy, k): the structure pose (gx + ix h, gy + iy h, gth + k dth), dth = 2 pi / K,
 * aligned on the goal pose (gx, gy, gth), which is the state (0, 0, 0) exactly.  The lattice covers the
 * obstacles and the goal, padded (by inflation = max(h / sqrt 2, P dth / 2), P the template's largest |p_i|,
 * how far a body moves along half an edge) so that its border band is free at every heading.  A state is FREE
 * when every robot body (its disc of radius r_i at its template point) keeps from every obstacle (radius R) the
 * exact bound of its edges: with need = r_i + R + margin_m, its centre at least
 *     sqrt(need^2 + h^2 / 2)                                   (a move: both ends so, the segment keeps need)
 *     sqrt((need + a dth^2 / 8)^2 + (a dth)^2 / 4)             (a turn: a = |p_i|, the arc's chord and bulge)
 * from the obstacle's centre, whichever is larger: so every pose on an edge between two free states keeps
 * margin_m, and the states keep only 1-2 mm more than that (margin + inflation, 2-6 cm more, until 2026-12-05).
 * A free state is TIGHT when some body is within VS_FIELD_COMFORT_M more than that.
 * Edges: the 8 neighbours at the same heading (cost 10, diagonals 14) and the two neighbouring headings in
 * the same cell (cost w_rot = round(10 P dth / h), at least 1); an edge touching a tight state costs twice.
 *
 * Cost to go.  Integer Dijkstra (Dial's buckets, run in the cost array itself) from the goal state: exact integer
 * distances, the same whatever the order of expansion, so every host and the reference agree bit for bit.  Free
 * states the goal cannot reach form components; each gets its own target, the state nearest the goal (squared
 * lattice distance, then the lowest index), and its own Dijkstra from it (the components are apart, so this is the
 * same as one from all targets at once): their costs carry VS_FIELD_BLOCKED_BIT.  Non-free states hold
 * VS_FIELD_WALL.  (Since 2026-12-06 the whole build is the deferred build with every component resolved.)
 *
 * Units and frames as vscore.h: lengths [m], poses (x, y, th) [m, m, rad; world].
 */
#ifndef VS_FIELD_H
#define VS_FIELD_H

#include <stddef.h>
#include <stdint.h>

#include "vscore.h"

#define VS_FIELD_WALL 0xFFFFFFFFu          /* a state that is not free */
#define VS_FIELD_BLOCKED_BIT 0x80000000u   /* a state the goal cannot reach: its cost leads to its target */
#define VS_FIELD_TIGHT_BIT 0x40000000u     /* a free state within the comfort band of an obstacle */
#define VS_FIELD_COST_MASK 0x3FFFFFFFu     /* the cost to go itself */
#define VS_FIELD_UNRESOLVED 0x3FFFFFFEu    /* deferred build: a blocked state whose component is not resolved yet.
                                              Costs must stay below it (and below 2^30 for the whole build's flags):
                                              a way of k lattice edges costs at most 2 k max(14, w_rot), far below
                                              in any room the agents plan (bench rooms: under 10^5) */
#define VS_FIELD_COMFORT_M 0.10            /* [m] beyond the margin: closer costs twice (the filter stays idle) */
#define VS_FIELD_MAX_ABS_M 1e6             /* larger coordinates or radii are refused (VS_EVALUE) */
#define VS_FIELD_MAX_OBSTACLES 4096
#define VS_FIELD_MAX_STATES 1000000000u      /* max_states at most (uint32 indices) */
#define VS_FIELD_GROW 1.25                 /* the cell grows by this factor until the lattice fits max_states */
#define VS_FIELD_W_AXIS 10u
#define VS_FIELD_W_DIAG 14u
#define VS_FIELD_SEARCH_CELLS 4            /* a descent's start is looked for this many cells around the pose */

struct vs_field_refine;   /* vs_field_set_refine: a finer lattice of the same room (vs_field.c) */

typedef struct {
    double gx, gy, gth;        /* the goal pose [m, rad; world], gth wrapped to [-pi, pi) */
    double cell_m;             /* h [m] (may be larger than asked: max_states) */
    double dth_rad;            /* 2 pi / K */
    double margin_m;           /* the clearance kept on every edge [m] */
    double inflation_m;        /* how far a body moves along half an edge [m]: the lattice's padding */
    size_t n_headings;         /* K */
    long ix_lo, iy_lo;         /* lattice index of column / row 0 (ix = ix_lo + column) */
    size_t nx, ny;
    uint32_t w_rot;
    int goal_free;             /* 0: the goal pose itself is not free: every state is blocked */
    uint32_t *cost;            /* (K, ny, nx) row-major: index (k * ny + row) * nx + column */
    struct vs_field_refine *refine;   /* NULL, or the finer lattice to ask where this one has no way (set_refine) */
    int provisional;           /* 1: a first plan that holds where it has no way (vs_field_set_provisional) */
} vs_field;

/* Build the field for a mission.  template_xy (n, 2) [m; structure frame]; radius_m (n) >= 0 [m];
 * margin_m >= 0 [m]; obstacles (n_obstacles, 3) (x, y, r > 0) [m; world], n_obstacles <= VS_FIELD_MAX_OBSTACLES;
 * goal (x, y, th); cell_m > 0 [m] (at least 1e-3), n_headings in [4, 1024], max_states in [1024,
 * VS_FIELD_MAX_STATES] and >= 9 n_headings (a lattice of 3 x 3 cells at least).
 * VS_ENONFINITE / VS_EVALUE on bad inputs, VS_ENOMEM if allocation fails; on VS_OK *out owns its cost
 * array: release it with vs_field_free.  Cost: O(K n m (r / h)^2 + K nx ny) (once per mission); scratch memory
 * while it builds: 8 (2 n + nx + ny + 3 n m) bytes (each body and obstacle's radii, computed once). */
int vs_field_build(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                   const double *obstacles, size_t n_obstacles, const double goal[3], double cell_m,
                   size_t n_headings, size_t max_states, vs_field *out);

/* The same field, built faster: the components the goal cannot reach are left for later (their states hold
 * VS_FIELD_BLOCKED_BIT | VS_FIELD_UNRESOLVED, with their tight bit), and each one is resolved (its target, its
 * costs) the first time vs_field_follow or vs_field_open needs it: only when no state within the descent's search
 * can reach the goal.  Every answer of vs_field_follow and vs_field_open is the same as on vs_field_build's field,
 * bit for bit, and a resolved component's costs are the same; so is the whole cost array after
 * vs_field_resolve_all.  Those resolutions write into the field's cost array (one caller at a time) and allocate a
 * component's scratch, freed before they return (VS_ENOMEM: the component stays unresolved).  Why: in bench/room.py's
 * rooms those components (the room's outside, pockets between obstacles) held 75-95 % of the free states, and a
 * build spent 60-80 % of its time on them (docs/planning.md, "Cost of a build"). */
int vs_field_build_deferred(const double *template_xy, const double *radius_m, size_t n, double margin_m,
                            const double *obstacles, size_t n_obstacles, const double goal[3], double cell_m,
                            size_t n_headings, size_t max_states, vs_field *out);

/* Resolve every component a deferred build left (a no-op on vs_field_build's field). */
int vs_field_resolve_all(vs_field *f);

void vs_field_free(vs_field *f);

/* The state nearest a pose (clamped into the lattice): its column, row and heading index. */
void vs_field_nearest(const vs_field *f, const double pose[3], size_t *col, size_t *row, size_t *k);

/* Follow the field from a pose (the fitted structure pose): waypoints[0] = the pose, then the nearest
 * usable state and its descent, until the goal state (then the last waypoint is the goal pose exactly),
 * the component's target, or path_m [m] of lattice steps, or cap waypoints.  The descent starts on a free
 * state within VS_FIELD_SEARCH_CELLS cells (and two headings) of the pose (its own cell is ring 0, at 5 headings):
 * the cheapest of the nearest ring that has one the goal can be reached from, else the cheapest of the nearest
 * ring that has any (ties: the first found); if none, the waypoints are the pose alone and *blocked = 1.
 * *blocked: the goal cannot be reached from here (the
 * descent ends at the closest safe pose); *left_m [m]: then, how far that pose is from the goal (0 when not
 * blocked).  cap >= 2.  No allocation; O(path_m / h) per call (plus the target's descent when blocked); on a
 * deferred field, the first call that needs a component resolves it (vs_field_build_deferred), and on a field armed
 * with a finer lattice, the first call with no way on f builds that lattice (vs_field_set_refine). */
/* 1 when the descent from the pose (vs_field_follow) starts on a free state from which the goal can be reached,
 * else 0 (no free state near, or a component the goal cannot reach): whether a shape can take its way from
 * this pose (vs_step.c chooses among a mission's shapes).  *tight: that start state lies in the comfort band
 * (VS_FIELD_TIGHT_BIT; 0 when there is none).  pose finite; no allocation (on a deferred field, or one armed with
 * a finer lattice: as vs_field_follow; a resolution or a build that fails leaves 0, not open). */
int vs_field_open(const vs_field *f, const double pose[3], int *tight);

int vs_field_follow(const vs_field *f, const double pose[3], double path_m, double *waypoints, size_t cap,
                    size_t *n_waypoints, int *blocked, double *left_m);

/* Refinement (since 2026-12-07).  A lattice coarse enough for a large room (its cell grown to fit max_states, or a
 * long structure's turns) can close a passage the bodies clear by a few centimetres: the field then has no way where
 * a finer lattice of the same room has one (bench/room.py rooms 70 and 130: a line of 10 robots, cells of 7.3 cm,
 * sealed from the goal; at 128 headings and 6 million states, cells of 4.7 cm, open).  vs_field_set_refine arms f
 * with that finer lattice: the same room (template_xy, radius_m, obstacles: the inputs f was built from; f's margin
 * and goal) at cell_m, n_headings and max_states (as vs_field_build takes them; the inputs are copied).  From then
 * on, where f itself has no way from a pose (vs_field_follow's *blocked, vs_field_open's 0), the finer lattice is
 * asked, and its answer is taken when it has a way from that pose; otherwise f's answer stands.  So the answers are a
 * function of the room and the pose alone, as before: every agent gets the same, whenever it builds the finer field.
 * The finer field is built (vs_field_build_deferred) by the first call that needs it, or by vs_field_refine_now,
 * into memory that f owns and vs_field_free releases.  Not thread-safe: one caller at a time on f, as for the
 * components a deferred build resolves (vs_field_refine_now included: never beside a frame that follows f).  A build
 * that fails (VS_ENOMEM) keeps nothing and is tried again by the next call that needs it: vs_field_follow returns its
 * error, vs_field_open answers 0.  VS_EVALUE: f not built, already armed, sizes out of range, or inputs vs_field_build
 * would refuse (VS_ENONFINITE: not finite). */
int vs_field_set_refine(vs_field *f, const double *template_xy, const double *radius_m, size_t n,
                        const double *obstacles, size_t n_obstacles, double cell_m, size_t n_headings,
                        size_t max_states);

/* Mark f provisional (since 2026-12-07): a first plan whose "no way" is not a verdict.  vs_structure_step (vs_step.h)
 * holds the structure where f has no way from its pose (no move, not blocked, not at the goal) instead of heading
 * for the closest safe pose: the verdict is the room's own field's, which every agent follows from the mission's
 * FIRST_PLAN_S on (vsfleet.field.first_lattice: a coarse lattice, or a large structure's own lattice without the
 * finer one it asks).  vs_field_follow and vs_field_open answer as before. */
void vs_field_set_provisional(vs_field *f);

/* Build f's finer lattice now, if f has one and it is not built yet (VS_OK otherwise); one caller at a time on f. */
int vs_field_refine_now(const vs_field *f);

/* 1 when f's finer lattice is built. */
int vs_field_refined(const vs_field *f);

#endif
