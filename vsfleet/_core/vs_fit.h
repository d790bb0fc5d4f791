/* vs_fit.h - fitting the virtual structure to the robots (Tan & Lewis 1996, 3.3.1), the compiled
 * port of vsfleet/fit (the numpy code stays as the reference; method: docs/fit.md).
 *
 * The pose T = (x, y, th) (world <- structure) minimising l1 = sum w_i d_i, l2 = sqrt(sum w_i d_i^2)
 * or linf = max w_i d_i, d_i = |r_i - R(th) p_i - (x, y)| [m].  l2 is closed form; l1 and linf are
 * certified global optima: cost - cost_lower_bound <= VS_FIT_CERT_TOL [weighted m] unless the work
 * cap was hit (then rounds == VS_FIT_MAX_ROUNDS or the angle budget ran out; the lower bound is
 * still a proven one).
 */
#ifndef VS_FIT_H
#define VS_FIT_H

#include <stddef.h>

#define VS_METRIC_L1 0
#define VS_METRIC_L2 1
#define VS_METRIC_LINF 2

#define VS_FIT_CERT_TOL 1e-10   /* [weighted m] the certified gap of l1 and linf */
#define VS_FIT_MAX_ROUNDS 60    /* search rounds per fit (as the reference) */
/* angles evaluated per fit: at most max(VS_FIT_MIN_ANGLES, VS_FIT_WORK / n) (a hard cap on work;
 * the reference has none: normal fits evaluate tens to a few hundred angles) */
#define VS_FIT_MIN_ANGLES 512
#define VS_FIT_WORK 60000

/* |coordinate| [m], |pose| and weights above this are refused (VS_ENONFINITE): their squares overflow */
#define VS_FIT_MAX_ABS 1e150

typedef struct { double x, y, th; double cost; double cost_lower_bound; int rounds; } vs_fit_result;

/* template_xy, positions_xy: n*2 [m; structure / world]; weights: n >= 0 or NULL (unit);
 * the pose world<-structure minimising the metric; cost [weighted m] at it; certified lower bound.
 * rounds: the certified search's rounds (0: closed form; 1: certified by its first batch).
 * VS_EVALUE: n = 0, unknown metric, negative or all-zero weights, unequal positive weights with
 * linf; VS_ENONFINITE: NaN, infinity or a magnitude over VS_FIT_MAX_ABS; VS_ENOMEM. */
int vs_fit(const double *template_xy, const double *positions_xy, const double *weights, size_t n,
           int metric, vs_fit_result *out);

/* vs_fit in the caller's workspace: work holds vs_fit_work_f64(n, metric) doubles (any fit of at most n points
 * fits in it; no allocation), or is NULL (vs_fit: allocated for the one call).  Same results, bit for bit. */
int vs_fit_ws(const double *template_xy, const double *positions_xy, const double *weights, size_t n,
              int metric, vs_fit_result *out, double *work);

/* Doubles of workspace any fit of at most n points under metric needs (0: n = 0 or an unknown metric): O(n) for
 * l2; l1 and linf add their search's angle tables, sized by its work cap (VS_FIT_WORK / 3 angles at 3 points,
 * whatever n: about 1.2e6 doubles for linf, 0.8e6 for l1; a fit touches only the part it uses). */
size_t vs_fit_work_f64(size_t n, int metric);

/* d_out[i] = |r_i - R(th) p_i - (x, y)| [m], i < n (d_out may not alias the inputs). */
int vs_fit_residuals(const double *template_xy, const double *positions_xy, size_t n,
                     double x, double y, double th, double *d_out);

/* The metric's cost [weighted m] of residuals d (n >= 1): sum w d, sqrt(sum w d^2) in index order,
 * or max w d; weights NULL = unit (not checked beyond finiteness). */
int vs_fit_cost(const double *d, const double *weights, size_t n, int metric, double *cost_out);

#endif
