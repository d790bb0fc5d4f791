/* vs_fit_linf.h - linf's evaluator at one angle, its rotation guesses, basis hints and descent
 * (vs_fit_linf.c), for the search in vs_fit.c (not part of the API). */
#ifndef VS_FIT_LINF_H
#define VS_FIT_LINF_H

#include "vs_fit_common.h"

#define VS_LINF_SPLIT 9

void vs_fit_eval_linf(const vs_prob *pr, double c, double s, double tx0, double ty0, int rough, vs_ang *out);
/* minimax.guesses: basis NULL (n = 3: the triangle) or a basis (i, j, j) / (i, j, l); out: up to 16 */
int vs_fit_linf_guesses(const vs_prob *pr, double th0, const int *basis, double *out);
int vs_fit_linf_kinks(const vs_prob *pr, double tha, const double *ea, double thb, const double *eb, double *out);
int vs_fit_linf_descend(const vs_prob *pr, double th0, double *th, double *tx, double *ty);

#endif
