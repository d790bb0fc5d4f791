/* vs_golden.c - flat entry points for the golden vectors (see vs_golden.h).
 *
 * One packing per core function, used both by the recorder (vsfleet._core.golden_call, from
 * Python) and by the plain C driver (tests/cdriver/golden_driver.c, native, aarch64 under
 * qemu, sanitizers), so the two can only agree if the core computes the same bits. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "vscore.h"
#include "vs_agent.h"
#include "vs_assembly.h"
#include "vs_golden.h"
#include "vs_step.h"
#include "vs_safety.h"

static long g_sin(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_sin(in[i]);
    return n;
}

static long g_cos(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_cos(in[i]);
    return n;
}

static long g_atan2(const double *in, long n, double *out, long cap)
{
    if (n % 2 || n / 2 > cap) return -1;
    for (long i = 0; i < n / 2; i++) out[i] = vs_atan2(in[2 * i], in[2 * i + 1]);
    return n / 2;
}

static long g_wrap(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_wrap_angle(in[i]);
    return n;
}

/* A count in a double: a whole number in [lo, hi], else -1. */
static long count_of(double v, long lo, long hi)
{
    if (!(v >= (double)lo && v <= (double)hi)) return -1;
    long k = (long)v;
    return (double)k == v ? k : -1;
}

/* structure_step: n, metric, goal kind, k goal poses, 3k goal, 9 limits, 2n template, n wheel base,
 * n speed max, n accel max, 3n poses, n seen, n excluded, n judged apart, elapsed, dt, margin,
 * cell, headings, max states (the room's field, built from these when m > 0), m obstacles, n radii, 3m obstacles
 * -> any_used, then (if any) fit 3, goal 3, twist 3, cost, at_goal, blocked, left, n used, 2n now,
 * 2n next, n deviations */
static long structure_step_of(const double *in, long n_in, double *out, long cap, int with_shapes, int provisional)
{
    if (n_in < 4) return -1;
    long n = count_of(in[0], 1, 100000), metric = count_of(in[1], 0, 2), kind = count_of(in[2], 0, 2),
         k = count_of(in[3], 1, 100000);
    if (n < 0 || metric < 0 || kind < 0 || k < 0) return -1;
    long base = 4 + 3 * k + 9 + 2 * n + 3 * n + 3 * n + 3 * n + 2;
    if (n_in < base + 5) return -1;
    long m_obs = count_of(in[base + 4], 0, 256), heads = count_of(in[base + 2], 4, 1024),
         max_states = count_of(in[base + 3], 1024, 100000000);
    if (m_obs < 0 || heads < 0 || max_states < 0) return -1;
    long end = base + 5 + n + 3 * m_obs, n_shapes = 0;
    if (with_shapes) {   /* then: the count of shapes, and each shape's 2n points */
        if (n_in < end + 1) return -1;
        n_shapes = count_of(in[end], 0, VS_STEP_MAX_SHAPES);
        if (n_shapes < 0) return -1;
        end += 1 + 2 * n * n_shapes;
    }
    if (n_in != end || cap < 1 + 14 + 6 * n) return -1;
    const double *p = in + 4, *goal = p;
    p += 3 * k;
    const double *lim = p; p += 9;
    const double *tpl = p; p += 2 * n;
    const double *wb = p; p += n;
    const double *vmax = p; p += n;
    const double *amax = p; p += n;
    const double *pose = p; p += 3 * n;
    unsigned char flags[3][4096];
    if (n > 4096) return -1;
    for (long j = 0; j < 3; j++)
        for (long i = 0; i < n; i++) flags[j][i] = p[j * n + i] != 0.0;
    p += 3 * n;
    double elapsed = p[0], dt = p[1], margin = p[2], cell = p[3];
    const double *radii = p + 7, *obstacles = radii + n;
    vs_field field;
    int have_field = 0;
    if (m_obs > 0 && kind != VS_GOAL_TWIST) {
        if (vs_field_build(tpl, radii, (size_t)n, margin, obstacles, (size_t)m_obs, goal + 3 * (k - 1), cell,
                           (size_t)heads, (size_t)max_states, &field) != VS_OK)
            return -1;
        have_field = 1;
        if (provisional) vs_field_set_provisional(&field);
    }
    const double *shapes = obstacles + 3 * m_obs + 1;
    vs_field shape_field[VS_STEP_MAX_SHAPES];
    const vs_field *shape_ptr[VS_STEP_MAX_SHAPES];
    long built = 0;
    for (; have_field && built < n_shapes; built++) {
        if (vs_field_build(shapes + 2 * n * built, radii, (size_t)n, margin, obstacles, (size_t)m_obs,
                           goal + 3 * (k - 1), cell, (size_t)heads, (size_t)max_states, &shape_field[built]) != VS_OK)
            break;
        shape_ptr[built] = &shape_field[built];
    }
    int rc = VS_EVALUE;
    vs_structure s;
    unsigned char used[4096];
    double *now = out + 14 + n, *next = now + 2 * n, *dev = next + 2 * n;
    if (built == (have_field ? n_shapes : 0)) {
        vs_mission m = {(size_t)n, tpl, wb, vmax, amax, (int)metric, {(int)kind, goal, (size_t)k},
                        {lim[0], lim[1], lim[2], lim[3], lim[4], lim[5], lim[6], lim[7], lim[8]},
                        radii, obstacles, (size_t)m_obs, margin, have_field ? &field : NULL,
                        (size_t)built, shapes, shape_ptr};
        rc = vs_structure_step(&m, pose, flags[0], flags[1], flags[2], elapsed, dt, &s, used, now, next, dev);
    }
    for (long j = 0; j < built; j++) vs_field_free(&shape_field[j]);
    if (have_field) vs_field_free(&field);
    if (rc != VS_OK) return -1;
    out[0] = s.any_used;
    if (!s.any_used) return 1;
    double head[13] = {s.fit_x, s.fit_y, s.fit_th, s.goal_x, s.goal_y, s.goal_th, s.vx_m_s, s.vy_m_s, s.w_rad_s,
                       s.cost, (double)s.at_goal, (double)s.blocked, s.left_m};
    memcpy(out + 1, head, sizeof head);
    for (long i = 0; i < n; i++) out[14 + i] = used[i];
    if (provisional) {   /* structure_step_held: then whether the structure held */
        out[14 + 6 * n] = (double)s.held;
        return 15 + 6 * n;
    }
    if (!with_shapes) return 14 + 6 * n;
    out[14 + 6 * n] = (double)s.shape;
    return 15 + 6 * n;
}

static long g_structure_step(const double *in, long n_in, double *out, long cap)
{
    return structure_step_of(in, n_in, out, cap, 0, 0);
}

/* structure_step_held: structure_step's inputs, its field provisional (vs_field_set_provisional: a first plan, held
 * where it has no way) -> structure_step's outputs, then held */
static long g_structure_step_held(const double *in, long n_in, double *out, long cap)
{
    return structure_step_of(in, n_in, out, cap, 0, 1);
}

/* structure_step_shapes: structure_step's inputs, then the count of shapes s (<= VS_STEP_MAX_SHAPES) and their
 * 2n s points (each built into its own field as the template's is) -> structure_step's outputs, then the shape */
static long g_structure_step_shapes(const double *in, long n_in, double *out, long cap)
{
    return structure_step_of(in, n_in, out, cap, 1, 0);
}

/* safety_filter: n, k obstacles, margin, gamma, offset, dt, 3n poses, n radii, n active, n wheel base,
 * n speed max, n accel max, 2n previous wheels, 3k obstacles, 2n nominal wheels
 * -> 2n safe wheels, then constraints, modified, softened, accel relaxed, stopped */
static long g_safety_filter(const double *in, long n_in, double *out, long cap)
{
    if (n_in < 6) return -1;
    long n = count_of(in[0], 0, 4096), k = count_of(in[1], 0, 256);
    if (n < 0 || k < 0 || n_in != 6 + 3 * n + n + n + n + n + n + 2 * n + 3 * k + 2 * n || cap < 2 * n + 5) return -1;
    vs_safety_params prm = {in[2], in[3], in[4], in[5]};
    const double *pose = in + 6, *radius = pose + 3 * n, *act = radius + n, *wb = act + n, *vmax = wb + n,
                 *amax = vmax + n, *prev = amax + n, *obs = prev + 2 * n, *nominal = obs + 3 * k;
    unsigned char active[4096];
    for (long i = 0; i < n; i++) active[i] = act[i] != 0.0;
    vs_safety_stats st;
    if (vs_safety_filter(&prm, (size_t)n, pose, radius, active, wb, vmax, amax, prev, (size_t)k, obs, nominal, out,
                         &st) != VS_OK)
        return -1;
    double counts[5] = {st.n_constraints, st.n_modified, st.n_softened, st.n_accel_relaxed, st.n_stopped};
    memcpy(out + 2 * n, counts, sizeof counts);
    return 2 * n + 5;
}

/* field_build: n, m, margin, cell, headings, max states, goal 3, 2n template, n radii, 3m obstacles
 * -> nx, ny, ix_lo, iy_lo, cell, inflation, w_rot, goal_free, then the FNV-1a hash of the cost array (64 bits,
 * as two 32-bit halves), the count of walls, of blocked and of tight states.  (vs_field_build is the deferred
 * build with every component resolved: the hash, recorded by the former whole build, holds both to its bits;
 * field_follow checks a deferred field's descents, which resolve on demand.) */
static long g_field_build(const double *in, long n_in, double *out, long cap)
{
    if (n_in < 9 || cap < 13) return -1;
    long n = count_of(in[0], 1, 4096), m = count_of(in[1], 0, 4096), heads = count_of(in[4], 4, 1024),
         max_states = count_of(in[5], 1024, 100000000);
    if (n < 0 || m < 0 || heads < 0 || max_states < 0 || n_in != 9 + 2 * n + n + 3 * m) return -1;
    const double *goal = in + 6, *tpl = in + 9, *radii = tpl + 2 * n, *obs = radii + n;
    vs_field f;
    if (vs_field_build(tpl, radii, (size_t)n, in[2], obs, (size_t)m, goal, in[3], (size_t)heads, (size_t)max_states,
                       &f) != VS_OK)
        return -1;
    uint64_t hash = 1469598103934665603ull;
    double walls = 0.0, blocked = 0.0, tight = 0.0;
    size_t total = f.nx * f.ny * f.n_headings;
    for (size_t s = 0; s < total; s++) {
        uint32_t v = f.cost[s];
        for (int b = 0; b < 4; b++) {
            hash ^= (v >> (8 * b)) & 0xFFu;
            hash *= 1099511628211ull;
        }
        if (v == VS_FIELD_WALL) walls += 1.0;
        else {
            if (v & VS_FIELD_BLOCKED_BIT) blocked += 1.0;
            if (v & VS_FIELD_TIGHT_BIT) tight += 1.0;
        }
    }
    double o[13] = {(double)f.nx, (double)f.ny, (double)f.ix_lo, (double)f.iy_lo, f.cell_m, f.inflation_m,
                    (double)f.w_rot, (double)f.goal_free, (double)(hash >> 32), (double)(hash & 0xFFFFFFFFull),
                    walls, blocked, tight};
    memcpy(out, o, sizeof o);
    vs_field_free(&f);
    return 13;
}

/* field_follow: field_build's inputs, then pose 3 and path_m -> n waypoints, blocked, left, 3n waypoints
 * (at most 64).  The same descent on the deferred build (vs_field_build_deferred), bit for bit: else refused (-1) */
static long g_field_follow(const double *in, long n_in, double *out, long cap)
{
    if (n_in < 13 || cap < 3 + 3 * 64) return -1;
    long n = count_of(in[0], 1, 4096), m = count_of(in[1], 0, 4096), heads = count_of(in[4], 4, 1024),
         max_states = count_of(in[5], 1024, 100000000);
    if (n < 0 || m < 0 || heads < 0 || max_states < 0 || n_in != 9 + 2 * n + n + 3 * m + 4) return -1;
    const double *goal = in + 6, *tpl = in + 9, *radii = tpl + 2 * n, *obs = radii + n, *pose = obs + 3 * m;
    vs_field f;
    if (vs_field_build(tpl, radii, (size_t)n, in[2], obs, (size_t)m, goal, in[3], (size_t)heads, (size_t)max_states,
                       &f) != VS_OK)
        return -1;
    size_t nw = 0;
    int blocked = 0;
    double left = 0.0;
    int rc = vs_field_follow(&f, pose, pose[3], out + 3, 64, &nw, &blocked, &left);
    vs_field_free(&f);
    if (rc != VS_OK) return -1;
    vs_field d;
    if (vs_field_build_deferred(tpl, radii, (size_t)n, in[2], obs, (size_t)m, goal, in[3], (size_t)heads,
                                (size_t)max_states, &d) != VS_OK)
        return -1;
    double dw[3 * 64];
    size_t d_nw = 0;
    int d_blocked = 0;
    double d_left = 0.0;
    rc = vs_field_follow(&d, pose, pose[3], dw, 64, &d_nw, &d_blocked, &d_left);
    vs_field_free(&d);
    if (rc != VS_OK || d_nw != nw || d_blocked != blocked || memcmp(&d_left, &left, sizeof left) != 0
        || memcmp(dw, out + 3, sizeof(double) * 3 * nw) != 0)
        return -1;
    out[0] = (double)nw;
    out[1] = (double)blocked;
    out[2] = left;
    return 3 + 3 * (long)nw;
}

/* field_refine: field_build's inputs, then the finer lattice's headings and max states, then pose 3 and path_m
 * -> open, tight (vs_field_open), built (whether the finer lattice was asked), n waypoints, blocked, left, 3n
 * waypoints (at most 64) of vs_field_follow: a deferred field armed with its finer lattice (vs_field_set_refine). */
static long g_field_refine(const double *in, long n_in, double *out, long cap)
{
    if (n_in < 15 || cap < 6 + 3 * 64) return -1;
    long n = count_of(in[0], 1, 4096), m = count_of(in[1], 0, 4096), heads = count_of(in[4], 4, 1024),
         max_states = count_of(in[5], 1024, 100000000);
    if (n < 0 || m < 0 || heads < 0 || max_states < 0 || n_in != 9 + 2 * n + n + 3 * m + 6) return -1;
    const double *goal = in + 6, *tpl = in + 9, *radii = tpl + 2 * n, *obs = radii + n, *fine = obs + 3 * m;
    const double *pose = fine + 2;
    long fine_heads = count_of(fine[0], 4, 1024), fine_states = count_of(fine[1], 1024, 100000000);
    if (fine_heads < 0 || fine_states < 0) return -1;
    vs_field f;
    if (vs_field_build_deferred(tpl, radii, (size_t)n, in[2], obs, (size_t)m, goal, in[3], (size_t)heads,
                                (size_t)max_states, &f) != VS_OK)
        return -1;
    if (vs_field_set_refine(&f, tpl, radii, (size_t)n, obs, (size_t)m, in[3], (size_t)fine_heads,
                            (size_t)fine_states) != VS_OK) {
        vs_field_free(&f);
        return -1;
    }
    int tight = 0, open = vs_field_open(&f, pose, &tight);
    size_t nw = 0;
    int blocked = 0;
    double left = 0.0;
    int rc = vs_field_follow(&f, pose, pose[3], out + 6, 64, &nw, &blocked, &left);
    int built = vs_field_refined(&f);
    vs_field_free(&f);
    if (rc != VS_OK) return -1;
    out[0] = (double)open;
    out[1] = (double)tight;
    out[2] = (double)built;
    out[3] = (double)nw;
    out[4] = (double)blocked;
    out[5] = left;
    return 6 + 3 * (long)nw;
}

/* assembly_targets: n, margin, elapsed, n radii, 3n poses, n seen, 2n points now, 2n points next
 * -> 2n points now, 2n points next, n detoured, the count detoured */
static long g_assembly_targets(const double *in, long n_in, double *out, long cap)
{
    if (n_in < 3) return -1;
    long n = count_of(in[0], 0, 4096);
    if (n < 0 || n_in != 3 + n + 3 * n + n + 2 * n + 2 * n || cap < 5 * n + 1) return -1;
    const double *radii = in + 3, *pose = radii + n, *flags = pose + 3 * n, *now = flags + n, *next = now + 2 * n;
    unsigned char seen[4096] = {0}, detoured[4096];
    for (long i = 0; i < n; i++) seen[i] = flags[i] != 0.0;
    size_t count = 0;
    if (vs_assembly_targets((size_t)n, radii, pose, seen, now, next, in[1], in[2], out, out + 2 * n, detoured, &count)
        != VS_OK)
        return -1;
    for (long i = 0; i < n; i++) out[4 * n + i] = detoured[i];
    out[5 * n] = (double)count;
    return 5 * n + 1;
}

/* a mission as structure_step packs it, without the frame's values (its poses, flags, elapsed and dt): n, metric,
 * goal kind, k goal poses, 3k goal, 9 limits, 2n template, n wheel base, n speed max, n accel max, margin, cell,
 * headings, max states, m obstacles, n radii, 3m obstacles, s shapes, 2n s points; the room's field (and each
 * shape's) built as structure_step builds them */
typedef struct {
    vs_mission m;
    vs_field field, shape_field[VS_STEP_MAX_SHAPES];
    const vs_field *shape_ptr[VS_STEP_MAX_SHAPES];
    int have_field;
    long built;
} golden_mission;

static void mission_free(golden_mission *g)
{
    for (long j = 0; j < g->built; j++) vs_field_free(&g->shape_field[j]);
    if (g->have_field) vs_field_free(&g->field);
    g->built = 0;
    g->have_field = 0;
}

/* unpacks the mission at in[0 .. n_in): the count of values it took, -1 when refused (nothing to free) */
static long mission_of(const double *in, long n_in, golden_mission *g)
{
    memset(g, 0, sizeof *g);
    if (n_in < 4) return -1;
    long n = count_of(in[0], 1, 4096), metric = count_of(in[1], 0, 2), kind = count_of(in[2], 0, 2),
         k = count_of(in[3], 1, 100000);
    if (n < 0 || metric < 0 || kind < 0 || k < 0) return -1;
    long base = 4 + 3 * k + 9 + 5 * n;   /* then margin, cell, headings, max states, m */
    if (n_in < base + 5) return -1;
    long m_obs = count_of(in[base + 4], 0, 256), heads = count_of(in[base + 2], 4, 1024),
         max_states = count_of(in[base + 3], 1024, 100000000);
    if (m_obs < 0 || heads < 0 || max_states < 0) return -1;
    long at = base + 5 + n + 3 * m_obs;
    if (n_in < at + 1) return -1;
    long n_shapes = count_of(in[at], 0, VS_STEP_MAX_SHAPES);
    if (n_shapes < 0 || n_in < at + 1 + 2 * n * n_shapes) return -1;
    const double *goal = in + 4, *lim = goal + 3 * k, *tpl = lim + 9, *wb = tpl + 2 * n, *vmax = wb + n,
                 *amax = vmax + n, *room = amax + n, *radii = room + 5, *obstacles = radii + n,
                 *shapes = obstacles + 3 * m_obs + 1;
    double margin = room[0], cell = room[1];
    if (m_obs > 0 && kind != VS_GOAL_TWIST) {
        if (vs_field_build(tpl, radii, (size_t)n, margin, obstacles, (size_t)m_obs, goal + 3 * (k - 1), cell,
                           (size_t)heads, (size_t)max_states, &g->field) != VS_OK)
            return -1;
        g->have_field = 1;
        for (; g->built < n_shapes; g->built++) {
            if (vs_field_build(shapes + 2 * n * g->built, radii, (size_t)n, margin, obstacles, (size_t)m_obs,
                               goal + 3 * (k - 1), cell, (size_t)heads, (size_t)max_states,
                               &g->shape_field[g->built]) != VS_OK) {
                mission_free(g);
                return -1;
            }
            g->shape_ptr[g->built] = &g->shape_field[g->built];
        }
    }
    vs_mission m = {(size_t)n, tpl, wb, vmax, amax, (int)metric, {(int)kind, goal, (size_t)k},
                    {lim[0], lim[1], lim[2], lim[3], lim[4], lim[5], lim[6], lim[7], lim[8]},
                    radii, obstacles, (size_t)m_obs, margin, g->have_field ? &g->field : NULL,
                    (size_t)g->built, shapes, g->shape_ptr};
    g->m = m;
    return at + 1 + 2 * n * n_shapes;
}

/* a whole number of at most 2^62 in magnitude in a double (an int64 of the failure rule's state), else -1 */
static int int64_of(double v, int64_t *out)
{
    if (!(v >= -4611686018427387904.0 && v <= 4611686018427387904.0) || v != floor(v)) return -1;
    *out = (int64_t)v;
    return 0;
}

/* NaN as one bit pattern (+NaN: what C99 hex floats and Python's float.hex write back) */
static double canon(double v) { return isnan(v) ? NAN : v; }

/* agent_step: the mission (mission_of), then the agent: own, controller (VS_AGENT_*), 17 gains (the controller's
 * struct's values first: precision 17, turn_then_go 5, arc 1, tracking 6), deadband, still speed, 9 policy (mode,
 * then vs_failure_policy's numbers), 4 safety, dt, ttl, age, resync gap, effective_t, room, bodies; then the state:
 * W, then py_agent.c's 22 arrays in order (2n wheels; the precision state: 3n pose, 2n gains, 10n history, 2n
 * target, 2n feed, n turn, n direction, 2n offset, n ready; the failure state: n since, n failed, n dropped, n last_t, 2n
 * last_xy, 2n last_expected, nW window_t, 4nW window_nm, n head, nW in_window, 4n sums, nW window_dev) and its 12
 * scalars (last_frame_t, last_cmd_t, ctrl_ready, blocked, stall_since_t, stall_watch, stall x, y, th,
 * stall_filter, stalled, shape); then F frames, each t, 3n poses, n seen, n fresh
 * -> per frame: ran, resynced, then (if ran) fit 3, goal 3, twist 3, cost, at_goal, blocked, left, shape, vl, vr,
 *    own_seen, err, event, event_dev, shape_before, n used, n deviations, the count of decisions d and d times
 *    (row, kind, t, deviation); then the final state as packed (the 22 arrays, the 12 scalars).  NaN comes out as
 *    +NaN. */
static long g_agent_step(const double *in, long n_in, double *out, long cap)
{
    golden_mission g;
    long at = mission_of(in, n_in, &g);
    if (at < 0) return -1;
    const long n = (long)g.m.n;
    long result = -1;
    double *buf = NULL;
    unsigned char *bytes = NULL;
    int64_t *ints = NULL;
    vs_failure_decision *dec = NULL;
    double *work = NULL;
    const long n_cfg = 2 + 17 + 2 + 9 + 4 + 5 + 2;
    if (n_in < at + n_cfg + 1) goto done;
    const double *c = in + at, *gains = c + 2;
    long own = count_of(c[0], 0, n - 1), W = count_of(c[n_cfg], 1, 100000);
    if (own < 0 || W < 1) goto done;
    vs_agent_config cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.mission = &g.m;
    cfg.own = (size_t)own;
    cfg.controller = (int)count_of(c[1], 0, 3);
    if (cfg.controller == VS_AGENT_PRECISION)
        cfg.precision = (vs_precision_gains){gains[0], gains[1], gains[2], gains[3], gains[4], gains[5], gains[6],
                                             gains[7], gains[8], gains[9], gains[10], gains[11], gains[12],
                                             gains[13], gains[14], gains[15], gains[16]};
    cfg.turn_then_go = (vs_turn_then_go_gains){gains[0], gains[1], gains[2], gains[3], gains[4] != 0.0};
    cfg.arc_horizon_s = gains[0];
    cfg.tracking = (vs_tracking_gains){gains[0], gains[1], gains[2], gains[3], gains[4], gains[5]};
    const double *p = gains + 17;
    cfg.deadband_m = p[0];
    cfg.still_speed_m_s = p[1];
    p += 2;
    cfg.policy = (vs_failure_policy){(int)count_of(p[0], 0, 1000), p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]};
    p += 9;
    cfg.safety = (vs_safety_params){p[0], p[1], p[2], p[3]};
    p += 4;
    cfg.dt_s = p[0];
    cfg.ttl_s = p[1];
    cfg.age_s = p[2];
    cfg.resync_gap_s = p[3];
    cfg.effective_t = p[4];
    cfg.room = p[5] != 0.0;
    cfg.bodies = p[6] != 0.0;
    p += 8;   /* past W */
    /* the state: 22 arrays, then 12 scalars */
    const long per[22] = {2, 3, 2, 2 * VS_PRECISION_HISTORY, 2, 2, 1, 1, 2, 1, 1, 1, 1, 1, 2, 2, W, 4 * W, 1, W, 4, W};
    long n_state = 12;
    for (int k = 0; k < 22; k++) n_state += n * per[k];
    at += n_cfg + 1;
    if (n_in < at + n_state) goto done;
    long per_frame = 1 + 5 * n, frames = (n_in - at - n_state) / per_frame;
    if ((n_in - at - n_state) % per_frame != 0) goto done;
    buf = malloc(sizeof(double) * (size_t)(n_state + VS_AGENT_SCRATCH_F64(n)));
    bytes = malloc((size_t)(n * (3 + 2 * W + 3) + VS_AGENT_SCRATCH_U8(n)));
    ints = malloc(sizeof(int64_t) * (size_t)(n * (4 * W + 1 + 4)));
    dec = malloc(sizeof *dec * (size_t)(2 * n));
    size_t n_work = vs_agent_work_f64(&g.m);   /* the kernels' workspace, once for the run (as an agent's mission) */
    if (n_work < (size_t)-1 / sizeof(double)) work = malloc(sizeof(double) * (n_work ? n_work : 1));
    if (buf == NULL || bytes == NULL || ints == NULL || dec == NULL || work == NULL) goto done;
    /* doubles: the arrays' values as given (booleans and ints too, for the output); their typed copies below */
    memcpy(buf, p, sizeof(double) * (size_t)n_state);
    double *arr[22];
    long off = 0;
    for (int k = 0; k < 22; k++) {
        arr[k] = buf + off;
        off += n * per[k];
    }
    double *sc = buf + off;
    unsigned char *ready = bytes, *failed = ready + n, *dropped = failed + n, *in_window = dropped + n;
    unsigned char *seen = in_window + n * W, *fresh = seen + n, *used = fresh + n, *scratch_u8 = used + n;
    int64_t *window_nm = ints, *head = window_nm + 4 * n * W, *sums = head + n;
    for (long i = 0; i < n; i++) {
        ready[i] = arr[9][i] != 0.0;
        failed[i] = arr[11][i] != 0.0;
        dropped[i] = arr[12][i] != 0.0;
        if (int64_of(arr[18][i], &head[i]) < 0) goto done;
    }
    for (long j = 0; j < n * W; j++) in_window[j] = arr[19][j] != 0.0;
    for (long j = 0; j < 4 * n * W; j++)
        if (int64_of(arr[17][j], &window_nm[j]) < 0) goto done;
    for (long j = 0; j < 4 * n; j++)
        if (int64_of(arr[20][j], &sums[j]) < 0) goto done;
    vs_agent_state st = {
        arr[0], sc[2] != 0.0,
        {arr[1], arr[2], arr[3], arr[4], arr[5], arr[6], arr[7], arr[8], ready},
        {(size_t)n, (size_t)W, arr[10], failed, dropped, arr[13], arr[14], arr[15], arr[16], window_nm, head,
         in_window, sums, arr[21]},
        sc[0], sc[1], sc[3] != 0.0, sc[4], sc[5] != 0.0, {sc[6], sc[7], sc[8]}, sc[9] != 0.0, sc[10] != 0.0,
        (int)count_of(sc[11], 0, VS_STEP_MAX_SHAPES),
    };
    double *scratch_f64 = buf + n_state, *o = out;
    const double *fr = in + at + n_state;
    for (long f = 0; f < frames; f++, fr += per_frame) {
        for (long i = 0; i < n; i++) {
            seen[i] = fr[1 + 3 * n + i] != 0.0;
            fresh[i] = fr[1 + 4 * n + i] != 0.0;
        }
        vs_agent_out r;
        if (vs_agent_step_ws(&cfg, &st, fr + 1, seen, fresh, fr[0], &r, used, dec, scratch_f64, scratch_u8, work)
            != VS_OK)
            goto done;
        long need = r.ran ? 24 + 2 * n + 4 * (long)r.n_decisions : 2;
        if (cap - (o - out) < need + n_state) goto done;
        *o++ = r.ran;
        *o++ = r.resynced;
        if (!r.ran) continue;
        const vs_structure *s = &r.s;
        double head_out[21] = {s->fit_x, s->fit_y, s->fit_th, s->goal_x, s->goal_y, s->goal_th, s->vx_m_s,
                               s->vy_m_s, s->w_rad_s, s->cost, (double)s->at_goal, (double)s->blocked, s->left_m,
                               (double)s->shape, r.vl_m_s, r.vr_m_s, (double)r.own_seen, r.err_m, (double)r.event,
                               r.event_dev_m, (double)r.shape_before};
        for (int k = 0; k < 21; k++) *o++ = canon(head_out[k]);
        for (long i = 0; i < n; i++) *o++ = used[i];
        for (long i = 0; i < n; i++) *o++ = canon(scratch_f64[7 * n + i]);   /* the deviations (vs_agent.c) */
        *o++ = (double)r.n_decisions;
        for (size_t k = 0; k < r.n_decisions; k++) {
            *o++ = (double)dec[k].row;
            *o++ = (double)dec[k].kind;
            *o++ = canon(dec[k].t);
            *o++ = canon(dec[k].deviation_m);
        }
    }
    if (cap - (o - out) < n_state) goto done;
    /* the final state, packed as it came in */
    for (long i = 0; i < n; i++) {
        arr[9][i] = ready[i];
        arr[11][i] = failed[i];
        arr[12][i] = dropped[i];
        arr[18][i] = (double)head[i];
    }
    for (long j = 0; j < n * W; j++) arr[19][j] = in_window[j];
    for (long j = 0; j < 4 * n * W; j++) arr[17][j] = (double)window_nm[j];
    for (long j = 0; j < 4 * n; j++) arr[20][j] = (double)sums[j];
    double tail[12] = {st.last_frame_t, st.last_cmd_t, st.ctrl_ready, st.blocked, st.stall_since_t, st.stall_watch,
                       st.stall_pose[0], st.stall_pose[1], st.stall_pose[2], st.stall_filter, st.stalled, st.shape};
    memcpy(sc, tail, sizeof tail);
    for (long j = 0; j < n_state; j++) *o++ = canon(buf[j]);
    result = (long)(o - out);
done:
    free(buf);
    free(bytes);
    free(ints);
    free(dec);
    free(work);
    mission_free(&g);
    return result;
}

static const golden_entry entries[] = {
    {"field_build", g_field_build},
    {"field_follow", g_field_follow},
    {"field_refine", g_field_refine},
    {"safety_filter", g_safety_filter},
    {"structure_step", g_structure_step},
    {"structure_step_shapes", g_structure_step_shapes},
    {"structure_step_held", g_structure_step_held},
    {"sin", g_sin},
    {"cos", g_cos},
    {"atan2", g_atan2},
    {"wrap_angle", g_wrap},
    {"assembly_targets", g_assembly_targets},
    {"agent_step", g_agent_step},
};

const golden_entry *golden_find(const char *name)
{
    for (size_t i = 0; i < sizeof entries / sizeof entries[0]; i++)
        if (strcmp(entries[i].name, name) == 0) return &entries[i];
    return NULL;
}

const golden_entry *golden_all(size_t *count)
{
    *count = sizeof entries / sizeof entries[0];
    return entries;
}
