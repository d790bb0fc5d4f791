/* vs_failure.c - the failure rule (see vs_failure.h; reference: vsfleet/failure.py). */
#include <math.h>   /* INFINITY and NAN only: no libm function is called */

#include "vs_failure.h"

#define TWO63 9223372036854775808.0     /* 2^63: |q| below it converts to int64 */

/* round half to even, as numpy's rint, without libm: |x| < 2^52 lands in [2^52, 2^53), where
 * the spacing of doubles is 1, so the addition rounds to an integer (default rounding mode) */
static double rint_even(double x)
{
    const double two52 = 4503599627370496.0;
    double a = vs_fabs(x);
    if (!(a < two52)) return x;
    double r = (a + two52) - two52;
    return x < 0.0 ? -r : r;
}

/* int64 arithmetic modulo 2^64, as numpy's (signed overflow is undefined in C) */
static int64_t wrap_i64(uint64_t u)
{
    return u <= (uint64_t)INT64_MAX ? (int64_t)u : -(int64_t)(~u) - 1;
}
static int64_t add_i64(int64_t a, int64_t b) { return wrap_i64((uint64_t)a + (uint64_t)b); }
static int64_t sub_i64(int64_t a, int64_t b) { return wrap_i64((uint64_t)a - (uint64_t)b); }

static int check_threshold(double v)
{
    if (!vs_isfinite(v)) return VS_ENONFINITE;
    return v < 0.0 ? VS_EVALUE : VS_OK;
}

/* The expected (scaled) and observed displacement of row i since its last fresh frame [m]. */
static void motion_item(const vs_failure_state *s, const vs_failure_input *in, size_t i, double item[4])
{
    double ex = s->last_expected[2 * i], ey = s->last_expected[2 * i + 1];
    if (in->step_s > 0.0) {
        double gap = in->t - s->last_t[i];
        double g = gap < in->max_gap_s ? gap : in->max_gap_s;   /* np.minimum (no NaN here) */
        double scale = g / in->step_s;
        ex = ex * scale;
        ey = ey * scale;
    }
    item[0] = ex;
    item[1] = ey;
    item[2] = in->xy_world[2 * i] - s->last_xy[2 * i];
    item[3] = in->xy_world[2 * i + 1] - s->last_xy[2 * i + 1];
}

static int validate(const vs_failure_policy *p, const vs_failure_state *s, const vs_failure_input *in,
                    size_t cap)
{
    int rc;
    if (p == NULL || s == NULL || in == NULL) return VS_EVALUE;
    if (p->mode != VS_FAILURE_HOLD && p->mode != VS_FAILURE_DROP && p->mode != VS_FAILURE_REJOIN)
        return VS_EVALUE;
    const double th[8] = {p->fail_deviation_m, p->fail_after_s, p->rejoin_deviation_m, p->rejoin_after_s,
                          p->recover_after_s, p->min_progress_ratio, p->min_expected_m2, p->min_approach_m};
    for (int k = 0; k < 8; k++)
        if ((rc = check_threshold(th[k])) != VS_OK) return rc;
    if (s->slots < 1) return VS_EVALUE;
    if (!vs_isfinite(in->t) || !vs_isfinite(in->step_s) || vs_isnan(in->max_gap_s)) return VS_ENONFINITE;
    if (in->step_s < 0.0 || in->max_gap_s < 0.0) return VS_EVALUE;
    if (cap < 2 * s->n) return VS_ENOMEM;
    for (size_t i = 0; i < s->n; i++) {
        if (s->head[i] < 0) return VS_EVALUE;
        if (!in->seen[i]) continue;
        double d = in->deviations_m[i];
        if (vs_isnan(d) || (!vs_isfinite(d) && d < 0.0)) return VS_ENONFINITE;
        if (!in->fresh[i]) continue;
        for (int k = 0; k < 2; k++) {
            double v[2] = {in->xy_world[2 * i + k], in->expected_step_m[2 * i + k]};
            for (int m = 0; m < 2; m++) {
                if (!vs_isfinite(v[m])) return VS_ENONFINITE;
                if (vs_fabs(v[m]) > VS_FAILURE_MAX_M) return VS_EVALUE;
            }
        }
        if (vs_isfinite(s->last_t[i])) {          /* an item enters the window: it must fit int64 nm */
            double item[4];
            motion_item(s, in, i, item);
            for (int k = 0; k < 4; k++) {
                double q = item[k] * VS_FAILURE_NM_PER_M;
                if (vs_isnan(q)) return VS_ENONFINITE;
                if (!(vs_fabs(q) < TWO63)) return VS_EVALUE;
            }
        }
    }
    return VS_OK;
}

/* The motion test of row i (fresh & seen): updates its window and returns whether it is stuck;
 * *approach: its deviation (dev, this frame's) shrank by more than min_approach_m over a settled
 * window, from the oldest item's frame (the first slot of the earliest time, as numpy's argmin). */
static int motion_step(const vs_failure_policy *p, vs_failure_state *s, const vs_failure_input *in, size_t i,
                       int fresh, double dev, int *approach)
{
    const size_t W = s->slots;
    double *wt = s->window_t + i * W;
    int64_t *nm = s->window_nm + i * W * 4;
    unsigned char *inw = s->in_window + i * W;
    int64_t *sums = s->sums_nm + i * 4;
    double *wdev = s->window_dev_m + i * W;
    const double t = in->t;
    const double expire_before = t - p->fail_after_s;
    const int had = fresh && vs_isfinite(s->last_t[i]);
    /* one pass: items that left the window go (and, with an item to write, the slot it takes: a
     * full ring overwrites its oldest item); the earliest frame time of those that stay */
    const size_t at = had ? (size_t)((uint64_t)s->head[i] % (uint64_t)W) : W;
    double first_t = INFINITY;
    size_t first_kept = W;                         /* the first slot of the earliest time among those that stay */
    for (size_t j = 0; j < W; j++) {
        if (!inw[j]) continue;
        if (j == at || !(wt[j] > expire_before)) {
            for (int k = 0; k < 4; k++) sums[k] = sub_i64(sums[k], nm[4 * j + k]);
            inw[j] = 0;
        } else if (wt[j] < first_t) {
            first_t = wt[j];
            first_kept = j;
        }
    }
    int stuck = 0;
    *approach = 0;
    if (had) {
        double item[4];
        motion_item(s, in, i, item);
        wt[at] = t;
        wdev[at] = dev;
        for (int k = 0; k < 4; k++) {
            int64_t q = (int64_t)rint_even(item[k] * VS_FAILURE_NM_PER_M);
            nm[4 * at + k] = q;
            sums[k] = add_i64(sums[k], q);
        }
        inw[at] = 1;
        s->head[i] += 1;
        const double kept_t = first_t;
        if (t < first_t) first_t = t;
        double sx = (double)sums[0] / VS_FAILURE_NM_PER_M, sy = (double)sums[1] / VS_FAILURE_NM_PER_M;
        double ox = (double)sums[2] / VS_FAILURE_NM_PER_M, oy = (double)sums[3] / VS_FAILURE_NM_PER_M;
        double e2 = sx * sx + sy * sy;
        const int settled = t - first_t >= VS_FAILURE_SETTLED_RATIO * p->fail_after_s;
        int known = settled && (e2 >= p->min_expected_m2);
        if (known && e2 != 0.0) {                  /* e2 == 0: the ratio is not finite */
            double ratio = (ox * sx + oy * sy) / e2;
            stuck = vs_isfinite(ratio) && ratio < p->min_progress_ratio;
        }
        if (settled && vs_isfinite(dev)) {
            /* the first slot of the earliest time in the window: the earliest kept, or the item just written at
             * (time t), the lower slot on a tie (as numpy's argmin over the slots) */
            size_t first = first_kept == W || t < kept_t ? at : t == kept_t && at < first_kept ? at : first_kept;
            *approach = wdev[first] - dev > p->min_approach_m;
        }
    }
    if (fresh) {
        s->last_t[i] = t;
        s->last_xy[2 * i] = in->xy_world[2 * i];
        s->last_xy[2 * i + 1] = in->xy_world[2 * i + 1];
        s->last_expected[2 * i] = in->expected_step_m[2 * i];
        s->last_expected[2 * i + 1] = in->expected_step_m[2 * i + 1];
    }
    return stuck;
}

int vs_failure_step(const vs_failure_policy *policy, vs_failure_state *state, const vs_failure_input *in,
                    vs_failure_decision *out, size_t cap, size_t *count)
{
    int rc = validate(policy, state, in, cap);
    if (rc != VS_OK) return rc;
    const vs_failure_policy *p = policy;
    vs_failure_state *s = state;
    const size_t n = s->n;
    const double t = in->t;
    const double inf = INFINITY, nan = NAN;
    /* the structure is off (not one robot) when every robot in the fit, two or more, is off */
    size_t in_fit = 0;
    double min_dev = inf;
    for (size_t i = 0; i < n; i++) {
        if (in->seen[i] && !s->dropped[i]) {
            in_fit++;
            if (in->deviations_m[i] < min_dev) min_dev = in->deviations_m[i];
        }
    }
    const int structure_off = in_fit >= 2 && min_dev > p->fail_deviation_m;
    const int drops = p->mode == VS_FAILURE_DROP || p->mode == VS_FAILURE_REJOIN;
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        const int seen = in->seen[i] != 0;
        const double dev = seen ? in->deviations_m[i] : inf;
        int approach;
        const int stuck = motion_step(p, s, in, i, seen && in->fresh[i], dev, &approach);
        /* the assembly phase: a seen robot that approaches its point, or that the safety filter holds
         * back, is on its way: the deviation test does not judge it (the progress test still does) */
        const int held = seen && in->held != NULL && in->held[i];
        const int on_way = vs_isfinite(dev) && (approach || held);
        const int off = dev > p->fail_deviation_m && !(structure_off && vs_isfinite(dev)) && !on_way;
        const int complies = !(off || stuck);
        double since = s->since_t[i];
        int back = 0, recover = 0, fail = 0;
        if (s->dropped[i]) {                       /* dropped: rejoin only (since counts compliant time) */
            if (p->mode == VS_FAILURE_REJOIN) {
                /* near its point and moving as commanded: a robot taken back while its window says stuck
                 * would fail again on the next frame, and its peers, whose windows differ, flap with it */
                if (dev <= p->rejoin_deviation_m && !stuck) {
                    double start = vs_isnan(since) ? t : since;
                    back = t - start >= p->rejoin_after_s;
                    since = back ? nan : start;
                } else {
                    since = nan;
                }
            }
        } else if (s->failed[i]) {                 /* failed (hold): recover after recover_after_s */
            if (complies) {
                double start = vs_isnan(since) ? t : since;
                recover = t - start >= p->recover_after_s;
                since = recover ? nan : start;
            } else {
                since = nan;
            }
        } else {                                   /* healthy: stuck counts from a whole window back */
            if (!complies) {
                double start = vs_isnan(since) ? t - (stuck ? p->fail_after_s : 0.0) : since;
                fail = t - start >= p->fail_after_s;
                since = fail ? nan : start;
            } else {
                since = nan;
            }
        }
        s->since_t[i] = since;
        if (back) {
            out[m++] = (vs_failure_decision){i, VS_DECISION_REJOIN, t, dev};
            s->failed[i] = 0;
            s->dropped[i] = 0;
        } else if (recover) {
            out[m++] = (vs_failure_decision){i, VS_DECISION_RECOVER, t, dev};
            s->failed[i] = 0;
        } else if (fail) {
            out[m++] = (vs_failure_decision){i, VS_DECISION_FAIL, t, dev};
            s->failed[i] = 1;
            if (drops) {
                out[m++] = (vs_failure_decision){i, VS_DECISION_DROP, t, dev};
                s->dropped[i] = 1;
            }
        }
    }
    *count = m;
    return VS_OK;
}
