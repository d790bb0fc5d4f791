/* vs_fit_l1.h - l1's evaluator at one angle and its Newton start (vs_fit_l1.c), for the search in
 * vs_fit.c (not part of the API). */
#ifndef VS_FIT_L1_H
#define VS_FIT_L1_H

#include "vs_fit_common.h"

#define VS_L1_NEWTON_N 20

void vs_fit_eval_l1(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out);
/* median.newton: returns converged; th, tx, ty in/out */
int vs_fit_l1_newton(const vs_prob *pr, double th, double *th_out, double *tx, double *ty);

#endif
