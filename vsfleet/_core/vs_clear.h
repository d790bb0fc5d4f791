/* vs_clear.h - the structure keeps its bodies' clearance: a barrier on the structure's twist in a room.
 *
 * The field (vs_field.h) plans a way whose edges keep every body margin_m from every obstacle, but the advance
 * follows it with a carrot that cuts the lattice's corners, and the robots lag their points while the structure
 * turns: in a tight gap the structure's points came within 9-11 mm of a wall (docs/planning.md), inside the
 * safety filter's 15 mm, where the robot held by the filter can never reach its point and the fleet stalls.
 * This barrier keeps the points themselves clear: for each robot, the obstacle its point (at the fitted pose)
 * is nearest to, clearance c = |p - o| - (r_i + R_o) [m], gives the row
 *     d c / dt = n . (v + w x rho_i) >= -VS_CLEAR_GAMMA_PER_S (c - VS_CLEAR_M)
 * (n: the unit vector from the obstacle to the point, rho_i: the point from the structure's origin), kept only
 * where c < VS_CLEAR_M + VS_CLEAR_BAND_M, the VS_CLEAR_ROWS of least clearance (ties: the lower robot index).
 * So a point closes on an obstacle no faster than the gamma rate of its spare clearance, and a point already
 * inside VS_CLEAR_M is moved out at that rate, even while the advance holds the structure still.
 *
 * The twist (vx, vy, w) is replaced by its nearest twist that meets every row, in the metric
 * |dv|^2 + (reach dw)^2 (reach [m]: the shape's largest |p_i|; 1 when it is 0), found exactly by a fixed
 * enumeration: the twist itself when it meets every row, else the best (least distance, the first in order on
 * ties) of the projections onto each row's plane, each pair's line and each triple's point that meets every row
 * (within 1e-12).  None (points inside VS_CLEAR_M on opposite sides, as in a passage the field threads at its
 * margin): the rows' positive bounds become 0 (hold, do not push out) and the enumeration runs again; none
 * still: the zero twist.  Then, if that twist is longer (in the metric) than the one given and than the push-out
 * VS_CLEAR_GAMMA_PER_S VS_CLEAR_M, it is scaled down to the larger of the two (the advance's envelope; a shorter
 * twist in the same direction still meets every row of bound <= 0 and moves out along the others).
 * + - * / and sqrt only, fixed order: the same bits everywhere.
 * Units and frames as vscore.h: [m], [rad], [s]; world frame. */
#ifndef VS_CLEAR_H
#define VS_CLEAR_H
#include <stddef.h>

#define VS_CLEAR_M 0.022              /* [m] the clearance the structure's points keep from obstacles */
#define VS_CLEAR_BAND_M 0.10          /* [m] rows only for points within VS_CLEAR_M + this of an obstacle */
#define VS_CLEAR_GAMMA_PER_S 2.0      /* [1/s] the barrier's rate */
#define VS_CLEAR_ROWS 6               /* rows kept at most (the least clearances) */

/* points_xy (n, 2) [m; world]: the robots' points at the fitted pose (fx, fy) [m]; radius_m (n) [m];
 * obstacles (m, 3) (x, y, R) [m; world]; reach_m > 0 [m]; twist_in (vx, vy, w) [m/s, m/s, rad/s; world].
 * twist_out: the barrier's twist.  Returns 0 when twist_in meets every row (twist_out = twist_in), else 1.
 * No allocation; O(n m) plus a fixed enumeration of at most 2 x 42 candidates. */
int vs_clearance_barrier(const double *points_xy, double fx, double fy, const double *radius_m, size_t n,
                         const double *obstacles, size_t m, double reach_m, const double twist_in[3],
                         double twist_out[3]);
#endif
