/* vs_failure.h - the failure rule (vsfleet.failure.failure_step) over arrays of all robots.
 *
 * One call advances the rule by one frame at tracker time t [s]: the motion window (the
 * progress test), the deviation test, and hold / drop / rejoin with the recover and rejoin
 * timers.  Read vsfleet/failure.py's module docstring for the rule itself; the numpy code
 * there (failure_step_reference) is the readable reference, and this code computes the same
 * bits (no elementary function is involved: + - * / and comparisons only).
 *
 * Units and frames: lengths [m] in the world (tracker floor) frame, times [s] on the
 * tracker's clock; the motion window holds integer nanometres [nm] (int64), so its sums are
 * exact and do not depend on the order of the items in the ring (they wrap modulo 2^64 as
 * numpy's int64 does; the input bounds below keep every item far from that).  Rows are
 * robots 0..n-1 in the mission's sorted id order; (n, 2) arrays are n*2 values row-major
 * (x0, y0, x1, y1, ...); (n, W) arrays n*W, (n, W, 4) arrays n*W*4, row-major.
 * Booleans are one byte each (numpy's bool): 0 false, anything else true; written as 0 / 1.
 */
#ifndef VS_FAILURE_H
#define VS_FAILURE_H

#include <stddef.h>
#include <stdint.h>

#include "vscore.h"

/* policy modes, in the order of vsfleet.wire.ON_FAILURE */
#define VS_FAILURE_HOLD 0
#define VS_FAILURE_DROP 1
#define VS_FAILURE_REJOIN 2

/* decision kinds, in the order of vsfleet.wire.EVENT_KINDS (Decision.kind) */
#define VS_DECISION_FAIL 0
#define VS_DECISION_DROP 1
#define VS_DECISION_REJOIN 2
#define VS_DECISION_RECOVER 3

/* fresh positions and expected steps beyond this many metres are refused (VS_EVALUE): every
 * window item then stays far inside int64 nanometres */
#define VS_FAILURE_MAX_M 1e9

/* the motion window's items are held in integer nanometres: this many per metre */
#define VS_FAILURE_NM_PER_M 1e9

/* the progress test judges a robot once its window's oldest item is this share of fail_after_s old */
#define VS_FAILURE_SETTLED_RATIO 0.8

/* vsfleet.failure.FailurePolicy: every value finite and >= 0. */
typedef struct {
    int mode;                   /* VS_FAILURE_HOLD / _DROP / _REJOIN */
    double fail_deviation_m;    /* [m] farther from its point is non-compliant */
    double fail_after_s;        /* [s] non-compliant this long: failed; also the motion window */
    double rejoin_deviation_m;  /* [m] (rejoin) a dropped robot this near its point ... */
    double rejoin_after_s;      /* [s] ... for this long is taken back */
    double recover_after_s;     /* [s] (hold) a failed robot complying this long is healthy again */
    double min_progress_ratio;  /* [1] net observed / net expected displacement below this: stuck */
    double min_expected_m2;     /* [m^2] the progress test judges once the net expected step's squared
                                   length reaches this: min_expected_m squared, computed as the
                                   reference does (Python's min_expected_m ** 2, i.e. libm pow,
                                   which is not always min_expected_m * min_expected_m) */
    double min_approach_m;      /* [m] the assembly phase: a robot whose deviation shrank by more than this
                                   over a settled window is on its way (the deviation test spares it) */
} vs_failure_policy;

/* vsfleet.failure.FailureState over n robots and W ring slots per robot (W >= 1), updated in
 * place by vs_failure_step (only when it returns VS_OK). */
typedef struct {
    size_t n, slots;            /* n robots, W = slots */
    double *since_t;            /* (n) [s] non-compliant since (compliant since, once failed or
                                   dropped); NaN = not counting */
    unsigned char *failed;      /* (n) bool */
    unsigned char *dropped;     /* (n) bool */
    double *last_t;             /* (n) [s] last fresh frame; NaN = never seen fresh */
    double *last_xy;            /* (n, 2) [m; world] position at last_t */
    double *last_expected;      /* (n, 2) [m; world] the step its command should make in step_s */
    double *window_t;           /* (n, W) [s] frame time of each ring item; NaN = empty */
    int64_t *window_nm;         /* (n, W, 4) [nm] expected dx, dy, observed dx, dy of each item */
    int64_t *head;              /* (n) the next slot to write is head % W; >= 0 */
    unsigned char *in_window;   /* (n, W) bool: the item counts in sums_nm */
    int64_t *sums_nm;           /* (n, 4) [nm] the sum of the items in the window */
    double *window_dev_m;       /* (n, W) [m] the robot's deviation in each item's frame */
} vs_failure_state;

/* One frame's inputs. */
typedef struct {
    double t;                         /* [s] frame time, finite */
    const unsigned char *seen;        /* (n) bool: in the frame */
    const unsigned char *fresh;       /* (n) bool: pose of this very frame (taken & seen) */
    const double *xy_world;           /* (n, 2) [m; world]; read on fresh rows only (finite there,
                                         |x|, |y| <= VS_FAILURE_MAX_M) */
    const double *deviations_m;       /* (n) [m] distance to the point it is judged on; read on seen
                                         rows only, where NaN and -inf are refused and +inf means
                                         off (an unseen row counts as +inf) */
    const double *expected_step_m;    /* (n, 2) [m; world] the step its predicted command should
                                         make in step_s; read on fresh rows only (as xy_world) */
    double step_s;                    /* [s] > 0: a missed robot's expected step is scaled to the
                                         time that passed; 0: not scaled (Python: None) */
    double max_gap_s;                 /* [s] >= 0, +inf allowed: the cap on that time */
    const unsigned char *held;        /* (n) bool or NULL (none): the safety filter cut the robot's
                                         command in this frame (the assembly phase) */
} vs_failure_input;

/* A change of a robot's status at frame time t. */
typedef struct {
    size_t row;              /* robot row */
    int kind;                /* VS_DECISION_* */
    double t;                /* [s] the frame time */
    double deviation_m;      /* [m] its deviation in the frame (+inf when unseen) */
} vs_failure_decision;

/* Advance the failure rule by one frame: updates *state in place and writes the frame's
 * decisions to out[0 .. *count) in row order (per row: rejoin, recover, or fail then drop under
 * drop / rejoin), so at most 2n; cap < 2n is refused (VS_ENOMEM).  On any error nothing is
 * written.  Errors: VS_EVALUE (bad policy, W = 0, negative head, negative step_s or max_gap_s,
 * a fresh position or window item out of range), VS_ENONFINITE (t, step_s, a seen deviation
 * NaN or -inf, a fresh xy / expected step non-finite, a NaN policy value or max_gap_s). */
int vs_failure_step(const vs_failure_policy *policy, vs_failure_state *state, const vs_failure_input *in,
                    vs_failure_decision *out, size_t cap, size_t *count);

#endif
