/* vs_agent.c - the agent's decision at one frame (vs_agent.h), vsfleet.step.agent_step's twin. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "vs_agent.h"
#include "vs_assembly.h"
#include "vs_kin.h"

/* numpy's zeros: +0.0 */
static void zero(double *a, size_t k)
{
    for (size_t i = 0; i < k; i++) a[i] = 0.0;
}

/* vsfleet.control.Precision.initial(n) */
static void precision_initial(vs_precision_state *p, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        for (int k = 0; k < 3; k++) p->pose_world[3 * i + k] = 0.0;
        p->gains[2 * i] = 1.0;
        p->gains[2 * i + 1] = 1.0;
        for (int k = 0; k < 2 * VS_PRECISION_HISTORY; k++) p->history_m_s[2 * VS_PRECISION_HISTORY * i + k] = 0.0;
        for (int k = 0; k < 2; k++) {
            p->target_world[2 * i + k] = 0.0;
            p->feed_m_s[2 * i + k] = 0.0;
            p->offset_world[2 * i + k] = 0.0;
        }
        p->turn_rad_s[i] = 0.0;
        p->direction[i] = 1.0;
        p->ready[i] = 0;
    }
}

/* vsfleet.failure.restart_timers: keep failed and dropped, forget the timers and the motion window */
static void restart_timers(vs_failure_state *f)
{
    size_t n = f->n, w = f->slots;
    for (size_t i = 0; i < n; i++) {
        f->since_t[i] = NAN;
        f->last_t[i] = NAN;
        f->head[i] = 0;
        for (int k = 0; k < 2; k++) {
            f->last_xy[2 * i + k] = 0.0;
            f->last_expected[2 * i + k] = 0.0;
        }
        for (int k = 0; k < 4; k++) f->sums_nm[4 * i + k] = 0;
    }
    for (size_t j = 0; j < n * w; j++) {
        f->window_t[j] = NAN;
        f->in_window[j] = 0;
        f->window_dev_m[j] = 0.0;
        for (int k = 0; k < 4; k++) f->window_nm[4 * j + k] = 0;
    }
}

/* the distance [m] from a structure pose to the mission's final goal position (vsfleet.step._goal_distance) */
static double goal_distance(const vs_goal *g, double x, double y)
{
    if (g->kind != VS_GOAL_POSE && g->kind != VS_GOAL_PATH) return 0.0;
    const double *p = g->poses + 3 * (g->kind == VS_GOAL_PATH ? g->n_poses - 1 : 0);
    double dx = p[0] - x, dy = p[1] - y;
    return sqrt(dx * dx + dy * dy);
}

/* vsfleet.step.stall_state, in place on st (filtered: the safety filter changed a command in this frame, or the
 * room's clearance barrier the structure's twist) */
static void stall_state(const vs_agent_config *cfg, vs_agent_state *st, const vs_structure *s,
                        const unsigned char *used, const double *dev, int filtered, int failed_any, double t)
{
    const vs_mission *m = cfg->mission;
    if (m->field == NULL) {
        st->stall_since_t = NAN;
        st->stall_watch = 0;
        st->stalled = 0;
        return;
    }
    int any = 0;
    double worst = 0.0;
    for (size_t i = 0; i < m->n; i++) {
        if (!used[i]) continue;
        if (!any || dev[i] > worst) worst = dev[i];
        any = 1;
    }
    int watched = !s->at_goal && !s->blocked && !failed_any && any && worst < cfg->policy.fail_deviation_m;
    int moved = 1;
    if (st->stall_watch) {
        double dx = s->fit_x - st->stall_pose[0], dy = s->fit_y - st->stall_pose[1];
        moved = sqrt(dx * dx + dy * dy) > VS_AGENT_STALL_MOVE_M
                || fabs(vs_wrap_angle(s->fit_th - st->stall_pose[2])) > VS_AGENT_STALL_TURN_RAD;
    }
    if (st->stalled) {   /* going again: moved past the thresholds within VS_AGENT_STALL_S of the watch's pose */
        st->stalled = !moved;
        if (st->stalled && t - st->stall_since_t >= VS_AGENT_STALL_S) {   /* a crawl: the watch moves on with it */
            st->stall_since_t = t;
            st->stall_pose[0] = s->fit_x;
            st->stall_pose[1] = s->fit_y;
            st->stall_pose[2] = s->fit_th;
        }
        return;
    }
    if (!watched) {
        st->stall_since_t = NAN;
        st->stall_watch = 0;
        st->stalled = 0;
        return;
    }
    if (isnan(st->stall_since_t) || moved) {
        st->stall_since_t = t;
        st->stall_watch = 1;
        st->stall_pose[0] = s->fit_x;
        st->stall_pose[1] = s->fit_y;
        st->stall_pose[2] = s->fit_th;
        st->stall_filter = filtered;
        st->stalled = 0;
        return;
    }
    st->stall_filter = st->stall_filter || filtered;
    st->stalled = st->stall_filter && t - st->stall_since_t >= VS_AGENT_STALL_S;
}

static size_t max_size(size_t a, size_t b) { return a > b ? a : b; }

size_t vs_agent_work_f64(const vs_mission *m)
{
    size_t n = m->n;
    if (n == 0) return 0;
    if (n > ((size_t)1 << 24) || m->n_obstacles > ((size_t)1 << 24)) return (size_t)-1;   /* the filter refuses them */
    /* the kernels run one after another: each has the whole workspace */
    size_t w = vs_structure_step_work_f64(n, m->metric);
    w = max_size(w, VS_CONTROL_PRECISION_WORK_F64(n));
    w = max_size(w, VS_SAFETY_WORK_F64(n, m->n_obstacles));
    return max_size(w, VS_INTEGRATE_ARCS_WORK_F64(n));
}

double vs_agent_command_ttl(const vs_agent_config *cfg, double frame_t, double now_s)
{
    if (!cfg->room) return cfg->ttl_s;
    double left = frame_t + 1.0 / cfg->safety.gamma_per_s - now_s;
    return left < cfg->ttl_s ? left : cfg->ttl_s;
}

int vs_agent_step(const vs_agent_config *cfg, vs_agent_state *st, const double *pose_world,
                  const unsigned char *seen, const unsigned char *fresh, double t, vs_agent_out *out,
                  unsigned char *used, vs_failure_decision *decisions, double *scratch_f64,
                  unsigned char *scratch_u8)
{
    size_t need = vs_agent_work_f64(cfg->mission);
    double *work = NULL;
    if (need > 0 && (need > (size_t)-1 / sizeof(double) || (work = malloc(need * sizeof(double))) == NULL))
        return VS_ENOMEM;
    int rc = vs_agent_step_ws(cfg, st, pose_world, seen, fresh, t, out, used, decisions, scratch_f64, scratch_u8,
                              work);
    free(work);
    return rc;
}

int vs_agent_step_ws(const vs_agent_config *cfg, vs_agent_state *st, const double *pose_world,
                     const unsigned char *seen, const unsigned char *fresh, double t, vs_agent_out *out,
                     unsigned char *used, vs_failure_decision *decisions, double *scratch_f64,
                     unsigned char *scratch_u8, double *work)
{
    const vs_mission *m = cfg->mission;
    const size_t n = m->n;
    vs_failure_state *f = &st->failure;
    if (!vs_isfinite(t) || n == 0 || cfg->own >= n || f->n != n || work == NULL) return VS_EVALUE;
    memset(out, 0, sizeof *out);
    out->shape_before = st->shape;

    /* the scratch, carved once (VS_AGENT_SCRATCH_*) */
    double *pose_seen = scratch_f64, *now = pose_seen + 3 * n, *next = now + 2 * n, *dev = next + 2 * n;
    double *tgt_now = dev + n, *tgt_next = tgt_now + 2 * n, *prev = tgt_next + 2 * n, *wheels = prev + 2 * n;
    double *nominal = wheels + 2 * n, *arcs = nominal + 2 * n, *expected = arcs + 3 * n;
    double *c_pose = expected + 2 * n, *c_radius = c_pose + 3 * n, *c_base = c_radius + n, *c_vmax = c_base + n;
    double *c_amax = c_vmax + n, *c_prev = c_amax + n, *c_wheels = c_prev + 2 * n;   /* ends at 39 n */
    unsigned char *judged = scratch_u8, *active = judged + n, *detoured = active + n, *held = detoured + n;
    unsigned char *moved = held + n, *c_active = moved + n, *seen_active = c_active + n;

    /* a gap longer than ttl: every robot has halted since the last commands */
    int fresh_start = t - st->last_cmd_t > cfg->ttl_s || !st->ctrl_ready;
    /* a gap longer than resync_gap_s: restart the failure timers and the motion window */
    if (t - st->last_frame_t > cfg->resync_gap_s && st->last_frame_t > -INFINITY) {
        restart_timers(f);
        if (!st->stalled) {   /* and the stall watch: a gap is no time the structure stood (glue.py) */
            st->stall_since_t = NAN;
            st->stall_watch = 0;
        }
        out->resynced = 1;
    }
    st->last_frame_t = t;

    int hold = cfg->policy.mode == VS_FAILURE_HOLD;
    for (size_t i = 0; i < n; i++) judged[i] = hold ? (f->failed[i] && !f->dropped[i]) : 0;
    vs_structure s;
    int rc = vs_structure_step_ws(m, pose_world, seen, f->dropped, judged, t - cfg->effective_t, cfg->dt_s, &s,
                                  used, now, next, dev, work);
    if (rc != VS_OK) return rc;
    if (!s.any_used) return VS_OK;
    s.fit_th = vs_wrap_angle(s.fit_th);    /* as the reference's Pose2 of the structure (wrap_angle once more) */
    s.goal_th = vs_wrap_angle(s.goal_th);
    out->ran = 1;
    out->s = s;
    if (fresh_start) {   /* (the reference starts a local controller afresh: kept only when the frame runs) */
        zero(prev, 2 * n);
        if (cfg->controller == VS_AGENT_PRECISION) precision_initial(&st->precision, n);
        st->ctrl_ready = 1;
    } else {
        memcpy(prev, st->wheels_m_s, sizeof(double) * 2 * n);
    }

    int rejoin = cfg->policy.mode == VS_FAILURE_REJOIN;
    for (size_t i = 0; i < n; i++) {
        active[i] = seen[i] && (rejoin || !f->dropped[i]);
        for (int k = 0; k < 3; k++) pose_seen[3 * i + k] = seen[i] ? pose_world[3 * i + k] : 0.0;
    }
    const double *point_now = now, *point_next = next;
    if (cfg->bodies) {   /* the assembly tie-break: robots barred on their way go round */
        for (size_t i = 0; i < n; i++) seen_active[i] = seen[i] && active[i];
        rc = vs_assembly_targets(n, m->radius_m, pose_seen, seen_active, now, next, cfg->safety.margin_m,
                                 t - cfg->effective_t, tgt_now, tgt_next, detoured, NULL);
        if (rc != VS_OK) return rc;
        point_now = tgt_now;
        point_next = tgt_next;
    }
    vs_control_input in = {n, pose_seen, point_now, point_next, prev, cfg->dt_s, cfg->age_s, m->wheel_base_m,
                           m->wheel_speed_max_m_s, m->wheel_accel_max_m_s2, active};
    switch (cfg->controller) {
    case VS_AGENT_PRECISION:
        rc = vs_control_precision_ws(&cfg->precision, &st->precision, &in, &st->precision, wheels, work);
        break;
    case VS_AGENT_TURN_THEN_GO:
        rc = vs_control_turn_then_go(&cfg->turn_then_go, &in, wheels);
        break;
    case VS_AGENT_ARC:
        rc = vs_control_arc(cfg->arc_horizon_s, &in, wheels);
        break;
    case VS_AGENT_TRACKING:
        rc = vs_control_tracking(&cfg->tracking, &in, wheels);
        break;
    default:
        return VS_EVALUE;
    }
    if (rc != VS_OK) return rc;
    if (cfg->deadband_m > 0.0 && (rc = vs_control_hold(cfg->deadband_m, cfg->still_speed_m_s, &in, wheels)) != VS_OK)
        return rc;
    for (size_t i = 0; i < n; i++)
        if (!active[i]) wheels[2 * i] = wheels[2 * i + 1] = 0.0;

    int filtered = 0;
    if (cfg->room) {   /* every robot's command through the fleet-wide safety filter: the seen robots are its rows */
        memcpy(nominal, wheels, sizeof(double) * 2 * n);
        size_t k = 0;
        for (size_t i = 0; i < n; i++) {
            if (!seen[i]) continue;
            for (int c = 0; c < 3; c++) c_pose[3 * k + c] = pose_world[3 * i + c];
            c_radius[k] = m->radius_m[i];
            c_base[k] = m->wheel_base_m[i];
            c_vmax[k] = m->wheel_speed_max_m_s[i];
            c_amax[k] = m->wheel_accel_max_m_s2[i];
            c_active[k] = active[i];
            for (int c = 0; c < 2; c++) {
                c_prev[2 * k + c] = prev[2 * i + c];
                c_wheels[2 * k + c] = wheels[2 * i + c];
            }
            k++;
        }
        if (k > 0) {
            rc = vs_safety_filter_ws(&cfg->safety, k, c_pose, c_radius, c_active, c_base, c_vmax, c_amax, c_prev,
                                     m->n_obstacles, m->obstacles, c_wheels, c_wheels, NULL, work);
            if (rc != VS_OK) return rc;
            k = 0;
            for (size_t i = 0; i < n; i++) {
                if (!seen[i]) continue;
                wheels[2 * i] = c_wheels[2 * k];
                wheels[2 * i + 1] = c_wheels[2 * k + 1];
                k++;
            }
        }
        for (size_t i = 0; i < n; i++) {
            held[i] = wheels[2 * i] != nominal[2 * i] || wheels[2 * i + 1] != nominal[2 * i + 1];
            filtered = filtered || held[i];
            if (cfg->bodies) held[i] = held[i] || detoured[i];
        }
    }
    out->vl_m_s = wheels[2 * cfg->own];
    out->vr_m_s = wheels[2 * cfg->own + 1];
    if (seen[cfg->own]) {
        double dx = pose_world[3 * cfg->own] - now[2 * cfg->own], dy = pose_world[3 * cfg->own + 1] - now[2 * cfg->own + 1];
        out->own_seen = 1;
        out->err_m = sqrt(dx * dx + dy * dy);
    }
    /* the motion test takes only poses of this very frame (vsfleet.step.agent_step says why) */
    for (size_t i = 0; i < n; i++) moved[i] = fresh[i] && active[i];
    if ((rc = vs_integrate_arcs_ws(pose_seen, wheels, cfg->dt_s, m->wheel_base_m, n, arcs, work)) != VS_OK) return rc;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 2; c++)
            expected[2 * i + c] = moved[i] ? arcs[3 * i + c] - pose_seen[3 * i + c] : 0.0;
    for (size_t i = 0; i < n; i++) {   /* the failure rule reads xy (n, 2): the seen poses' columns 0, 1 */
        c_pose[2 * i] = pose_seen[3 * i];
        c_pose[2 * i + 1] = pose_seen[3 * i + 1];
    }
    vs_failure_input fin = {t, seen, fresh, c_pose, dev, expected, cfg->dt_s, cfg->ttl_s, cfg->room ? held : NULL};
    if ((rc = vs_failure_step(&cfg->policy, f, &fin, decisions, 2 * n, &out->n_decisions)) != VS_OK) return rc;

    int failed_any = 0;
    if (m->field != NULL)
        for (size_t i = 0; i < n; i++) failed_any = failed_any || f->failed[i];
    int was = st->blocked || st->stalled;
    /* a held frame (a provisional first plan with no way: vs_step.h) gives no verdict: the blocked flag and the stall
     * watch stay as they were, and no event is sent (a mission that follows a blocked one stays blocked through it) */
    if (!s.held) stall_state(cfg, st, &s, used, dev, filtered || s.cleared, failed_any, t);
    int blocked = s.held ? st->blocked : s.blocked;
    int is = blocked || st->stalled;
    if (is != was) {
        out->event = is ? 1 : 2;
        out->event_dev_m = s.blocked ? s.left_m : goal_distance(&m->goal, s.fit_x, s.fit_y);
    }
    memcpy(st->wheels_m_s, wheels, sizeof(double) * 2 * n);
    st->blocked = blocked;
    st->shape = s.shape;
    st->last_cmd_t = t;
    return VS_OK;
}
