/* vs_assembly.h - the assembly tie-break of the agent step (issue 28, crowded starts; issue 29: in the core).
 *
 * As vsfleet.assembly.assembly_targets_reference, bit for bit (the same operations in the same order,
 * + - * / and sqrt only, and 32-bit unsigned integer arithmetic for the priorities).  Robot i, seen and more
 * than VS_ASSEMBLING_M from its point, is barred by robot j (seen, j != i) when j's centre lies ahead on i's
 * straight way to its point, 0 < along < dist + width, within width = (r_i + r_j) + margin_m of that line;
 * its first blocker is the nearest such j (the least along; ties: the lowest row).
 *
 * Priorities.  Which of two robots comes first is drawn afresh every VS_PRIORITY_S seconds of the mission
 * (elapsed_s, from the mission's effective time): in draw e = floor(elapsed_s / VS_PRIORITY_S) (0 before
 * the first period ends; saturated at UINT32_MAX) robot i has rank i when e = 0, else the 32-bit mix
 * h = (i * 0x9E3779B1) ^ (e * 0x85EBCA77); h ^= h >> 15; h *= 0x2C1B3C6D; h ^= h >> 12; h *= 0x297A2D39;
 * h ^= h >> 15 (arithmetic modulo 2^32); the lower rank comes first, equal ranks by the lower row.  So
 * for the mission's first period the rows' own order decides, and a tie that holds two robots for good
 * in one order is decided the other way, with odds of one half, in each later period.
 *
 * Two robots that bar each other (head on): the one that comes later gives way and passes the other on its
 * right; the other keeps its way, unless a robot that comes before it bars it head on too (then it also
 * passes its first blocker on its right: of two robots that bar each other, the later never keeps its way).
 * A robot barred by one that does not bar it passes it on the side it is already on (on the right when
 * dead ahead).  Passing j means heading for the waypoint c = width + VS_DETOUR_CLEAR_M to that side of the
 * line from i to j and c short of j along it.  A robot sent round its first blocker j (either way above)
 * that is boxed in (pressed against j, gap - width < VS_PRESSED_M with gap its centre's distance from
 * j's, and its way to that waypoint barred by a third robot) escapes instead: it heads VS_ESCAPE_M
 * straight back from j, if no robot bars that way; else VS_ESCAPE_M straight out of the crowd (away from
 * the centroid of the seen robots, summed in row order); else VS_ESCAPE_M 45 degrees off straight back
 * towards its passing side, then towards the other side, then 90 degrees off towards its passing side,
 * then the other (the first of these ways no robot bars); else it waits where it stands (its target is
 * its own position).  Then, in a second pass that reads these targets, a robot that kept its way head on
 * into a first blocker that waits goes round that blocker on its right in turn, boxed in or not as above.
 * Then, in a third pass that reads the second's targets, a robot on its way whose first robot on its way
 * to its target (as a first blocker, on that way) is k, pressed against k (at a gap above 0), k coming
 * first, and barring k's way to k's target in turn (their targets cross), escapes from k as above,
 * passing on its right.
 * Last, a placed robot k (seen, not on its way) that bars the way of a robot i boxed in by the first or second
 * pass (and not sent off by the third) to the waypoint i could not take steps aside (of such robots i, the
 * lowest row): its target is VS_ESCAPE_M straight away from i, else 45 degrees off that to k's left, then its
 * right, then 90 degrees off it the same, the first of these ways no robot bars; else it keeps its point.
 * As k leaves its point by more than VS_ASSEMBLING_M it is on its way again, so a step aside is a few
 * centimetres: enough to open a channel between placed robots for two robots to pass each other.
 * Every agent computes the same targets from the same frame.
 */
#ifndef VS_ASSEMBLY_H
#define VS_ASSEMBLY_H

#include <stddef.h>

#define VS_ASSEMBLING_M 0.05   /* [m] a seen robot farther than this from its point is on its way to it */
#define VS_DETOUR_CLEAR_M 0.03 /* [m] a detour's waypoint lies this far beyond touching + margin_m, beside
                                  the line to the blocker and as far short of it */
#define VS_ESCAPE_M 0.15       /* [m] a boxed-in robot's way back from its blocker, or out of the crowd; a
                                  placed robot's way aside */
#define VS_PRIORITY_S 10.0     /* [s] the priorities are drawn afresh every this long of the mission */
#define VS_PRESSED_M 0.03      /* [m] a robot whose centre is less than this beyond width from its blocker's
                                  (gap - width < VS_PRESSED_M) is pressed against it */

/* Every robot's targets after the tie-break, and which robots it sent round another.
 *   radius_m (n) [m] >= 0; pose_world (n, 3) [m, m, rad; world] (x and y read, the heading never);
 *   seen (n) 0/1 (nonzero: seen); points_now, points_next (n, 2) [m; world], every robot's point on
 *   the fitted and on the advanced structure; margin_m [m] >= 0, the clearance beyond the bodies;
 *   elapsed_s [s], finite: the frame's time less the mission's effective time (the priorities' draw).
 *   Only seen rows enter the tie-break: there radius_m, pose_world's x and y, points_now and points_next
 *   must be finite (VS_ENONFINITE) and radius_m >= 0 (VS_EVALUE); an unseen row's values, whatever they
 *   are (NaN included), are neither checked nor used, and its points are copied through as they are.
 *   Outputs: now_out, next_out (n, 2): points_now / points_next, with a detoured robot's rows both
 *   set to its waypoint; detoured_out (n) 0/1.  With n < 2 or no robot on its way the outputs are
 *   the inputs and no robot is detoured.  *n_detoured (optional, NULL): the count of detoured robots.
 * O(n^2) time, no allocation.  The outputs must not overlap the inputs.  Errors: VS_EVALUE (NULL
 * arrays with n > 0, a negative radius or margin), VS_ENONFINITE; outputs are written only on VS_OK. */
int vs_assembly_targets(size_t n, const double *radius_m, const double *pose_world, const unsigned char *seen,
                        const double *points_now, const double *points_next, double margin_m, double elapsed_s,
                        double *now_out, double *next_out, unsigned char *detoured_out, size_t *n_detoured);

#endif
