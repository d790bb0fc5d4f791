/* vscore.h - the compiled core of vsfleet's agent step (C99, no allocation on the hot path
 * beyond what the caller passes in, no global state, no I/O).
 *
 * Conventions, for every function of the core:
 *   - lengths in metres [m], angles in radians [rad] counter-clockwise from +x, times in
 *     seconds [s] on the tracker's clock, wheel speeds in [m/s], accelerations in [m/s^2];
 *   - robots are rows 0..n-1 in the mission's sorted id order; an (n, 2) array is n*2
 *     doubles, row-major (x0, y0, x1, y1, ...); a pose is (x, y, th);
 *   - "world" is the tracker's floor frame; "structure" is the template's own frame; a
 *     structure pose T = (x, y, th) maps a template point p to the world as R(th) p + (x, y);
 *   - every function returns VS_OK or a negative VS_E* code and writes its outputs only on
 *     VS_OK; inputs that are not finite are refused (VS_ENONFINITE), never propagated.
 *
 * Determinism: compiled with -O2 -ffp-contract=off, never -ffast-math; elementary functions
 * are the core's own (vs_math.h, + - * / sqrt only); every sum runs in a fixed order (index
 * order, unless a function's comment says otherwise).  So every host (x86-64 with or without
 * AVX-512, aarch64) computes the same bits: tests/data/golden-core.json holds them.
 */
#ifndef VSCORE_H
#define VSCORE_H

#include <stddef.h>

#define VS_OK 0
#define VS_EVALUE (-1)      /* a bad argument (shape, range, unknown name) */
#define VS_ENONFINITE (-2)  /* NaN or infinity in an input */
#define VS_ENOMEM (-3)      /* scratch space too small / allocation failed */

#include "vs_math.h"

#endif
