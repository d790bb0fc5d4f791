/* vs_fit_internal.h - shared by vs_fit.c, vs_fit_l1.c, vs_fit_linf.c (not part of the API). */
#ifndef VS_FIT_INTERNAL_H
#define VS_FIT_INTERNAL_H

#include <stddef.h>
#include "vscore.h"
#include "vs_fit.h"

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

typedef void (*vs_eval_fn)(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out);

void vs_fit_minorant(const vs_prob *pr, const double *kx, const double *ky, const size_t *rows, size_t k,
                     double *K, double *A, double *B);
void vs_fit_eval_l1(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out);
void vs_fit_eval_linf(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out);
/* median.newton: returns converged; th, tx, ty in/out */
int vs_fit_l1_newton(const vs_prob *pr, double th, double *th_out, double *tx, double *ty);
/* minimax.guesses: basis NULL (n = 3: the triangle) or a basis (i, j, j) / (i, j, l); out: up to 16 */
int vs_fit_linf_guesses(const vs_prob *pr, double th0, const int *basis, double *out);
int vs_fit_linf_kinks(const vs_prob *pr, double tha, const double *ea, double thb, const double *eb, double *out);
int vs_fit_linf_descend(const vs_prob *pr, double th0, double *th, double *tx, double *ty);
double vs_fit_remainder(double x, double y);   /* IEEE remainder (math.remainder) */
double vs_fit_npmod(double x, double y);        /* numpy remainder (sign of y) */

#define VS_LINF_SPLIT 9
#define VS_L1_NEWTON_N 20

#endif
