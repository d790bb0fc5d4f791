/* vs_fit_common.h - what the fit's parts share (not part of the API): the centred problem, one
 * evaluated angle, and the helpers of vs_fit_common.c.  It depends on neither the search (vs_fit.c)
 * nor the evaluators, so the calls go one way: vs_fit.c -> vs_fit_l1.c, vs_fit_linf.c ->
 * vs_fit_common.c (tests/test_purity.py checks that no C file of the core reaches itself). */
#ifndef VS_FIT_COMMON_H
#define VS_FIT_COMMON_H

#include <stddef.h>
#include "vscore.h"

#define VS_EPS 2.220446049250313e-16

/* The centred problem (certify.Problem): q_i(th) = Q_i - R(th) P_i. */
typedef struct {
    size_t n;
    const double *w;                 /* n weights (ones when unit) */
    const double *Px, *Py, *Qx, *Qy; /* centred, n each */
    double cpx, cpy, crx, cry, W, bound;
    double *sc;                      /* scratch: VS_FIT_SCRATCH * n doubles */
    size_t *si;                      /* scratch: 8 * n indices */
} vs_prob;

#define VS_FIT_SCRATCH 24

/* One evaluated angle: the evaluator's answer (f, t, minorant K - A cos - B sin) and linf's basis. */
typedef struct { double th, c, s, f, tx, ty, K, A, B, rough, e[3], Kc; } vs_ang;
/* Kc: a constant minorant (valid at every angle; -inf if none): linf's pair bound */

/* The weak-duality minorant K - A cos th - B sin th of the dual vectors (kx, ky) on rows (NULL: 0..k-1). */
void vs_fit_minorant(const vs_prob *pr, const double *kx, const double *ky, const size_t *rows, size_t k,
                     double *K, double *A, double *B);
double vs_fit_remainder(double x, double y);   /* IEEE remainder (math.remainder) */
double vs_fit_npmod(double x, double y);        /* numpy remainder (sign of y) */

#endif
