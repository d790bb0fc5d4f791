/* vs_fit_common.c - the helpers the fit's search (vs_fit.c) and its evaluators (vs_fit_l1.c,
 * vs_fit_linf.c) share: the weak-duality minorant and two remainders.  Moved here unchanged from
 * vs_fit.c, so that the evaluators no longer call back into the search; see vs_fit_common.h. */
#include "vs_fit_common.h"

#include <math.h>   /* sqrt only */

double vs_fit_remainder(double x, double y)
{
    double r = vs_fmod(x, y);
    if (2.0 * vs_fabs(r) > y) r = r > 0.0 ? r - y : r + y;
    return r;
}

double vs_fit_npmod(double x, double y)
{
    double m = vs_fmod(x, y);
    if (m != 0.0) {
        if ((y < 0.0) != (m < 0.0)) m += y;
    } else {
        m = y < 0.0 ? -0.0 : 0.0;
    }
    return m;
}

void vs_fit_minorant(const vs_prob *pr, const double *kx, const double *ky, const size_t *rows, size_t k,
                     double *K, double *A, double *B)
{
    double sk = 0.0, sa = 0.0, sb = 0.0, fx = 0.0, fy = 0.0, ka = 0.0;
    for (size_t i = 0; i < k; i++) {
        size_t r = rows ? rows[i] : i;
        double px = pr->Px[r], py = pr->Py[r], qx = pr->Qx[r], qy = pr->Qy[r];
        sk += kx[i] * qx + ky[i] * qy;
        sa += kx[i] * px + ky[i] * py;
        sb += ky[i] * px - kx[i] * py;
        fx += kx[i];
        fy += ky[i];
        ka += sqrt(kx[i] * kx[i] + ky[i] * ky[i]);
    }
    *K = sk - pr->bound * (sqrt(fx * fx + fy * fy) + 64.0 * VS_EPS * ka);
    *A = sa;
    *B = sb;
}
