/* vs_step.c - see vs_step.h. */
#include <math.h>   /* sqrt only */
#include <stdlib.h>

#include "vs_step.h"
#include "vs_clear.h"

void vs_apply_pose(double x, double y, double th, const double *p, size_t n, double *out)
{
    double s, c;
    vs_sincos(th, &s, &c);
    for (size_t i = 0; i < n; i++) {
        double px = p[2 * i], py = p[2 * i + 1];
        out[2 * i] = c * px - s * py + x;
        out[2 * i + 1] = s * px + c * py + y;
    }
}

/* The fit on the rows where mask is set, gathered into scratch (4 k doubles); fit_work: vs_fit_work_f64(n). */
static int fit_rows(const vs_mission *m, const double *template_xy, const double *pose_world,
                    const unsigned char *mask, size_t k, double *scratch, double *fit_work, vs_fit_result *fit)
{
    double *tpl = scratch, *xy = scratch + 2 * k;
    size_t j = 0;
    for (size_t i = 0; i < m->n; i++) {
        if (!mask[i]) continue;
        tpl[2 * j] = template_xy[2 * i];
        tpl[2 * j + 1] = template_xy[2 * i + 1];
        xy[2 * j] = pose_world[3 * i];
        xy[2 * j + 1] = pose_world[3 * i + 1];
        j++;
    }
    return vs_fit_ws(tpl, xy, NULL, k, m->metric, fit, fit_work);
}

static void distances(const double *pose_world, const double *pts, size_t n, double *d)
{
    for (size_t i = 0; i < n; i++) {
        double dx = pose_world[3 * i] - pts[2 * i], dy = pose_world[3 * i + 1] - pts[2 * i + 1];
        d[i] = sqrt(dx * dx + dy * dy);
    }
}

size_t vs_structure_step_work_f64(size_t n, int metric)
{
    size_t fit = vs_fit_work_f64(n, metric);
    if (fit > (size_t)-1 / 2 || n > (size_t)-1 / 64) return (size_t)-1;   /* overflow: no such buffer */
    return fit + 9 * n + (n + sizeof(double) - 1) / sizeof(double);
}

/* the advance's twist through the room's clearance barrier (vs_clear.h) into t; 1 when the barrier changed it */
static int clear_twist(const vs_mission *m, const double *points_now, const vs_fit_result *fit, size_t n,
                       double reach, const vs_advance_result *adv, double t[3])
{
    const double t_in[3] = {adv->vx_m_s, adv->vy_m_s, adv->w_rad_s};
    return vs_clearance_barrier(points_now, fit->x, fit->y, m->radius_m, n, m->obstacles, m->n_obstacles, reach,
                                t_in, t);
}

/* the barrier's twist t keeps less than half the move the advance asked for (along it) */
static int held_back(const vs_advance_result *adv, const double t[3])
{
    double ask2 = adv->vx_m_s * adv->vx_m_s + adv->vy_m_s * adv->vy_m_s;
    return ask2 > 0.0 && t[0] * adv->vx_m_s + t[1] * adv->vy_m_s < VS_STEP_HELD_BACK * ask2;
}

int vs_structure_step(const vs_mission *m, const double *pose_world, const unsigned char *seen,
                      const unsigned char *excluded, const unsigned char *judged_apart, double elapsed_s,
                      double dt_s, vs_structure *out, unsigned char *used, double *points_now,
                      double *points_next, double *deviations_m)
{
    return vs_structure_step_ws(m, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s, out, used, points_now,
                                points_next, deviations_m, NULL);
}

int vs_structure_step_ws(const vs_mission *m, const double *pose_world, const unsigned char *seen,
                         const unsigned char *excluded, const unsigned char *judged_apart, double elapsed_s,
                         double dt_s, vs_structure *out, unsigned char *used, double *points_now,
                         double *points_next, double *deviations_m, double *work)
{
    size_t n = m->n, n_used = 0, n_judges = 0;
    if (n == 0) return VS_EVALUE;
    if (!vs_isfinite(elapsed_s) || !vs_isfinite(dt_s)) return VS_ENONFINITE;
    if (!(dt_s > 0.0)) return VS_EVALUE;
    if (m->n_shapes > VS_STEP_MAX_SHAPES || (m->n_shapes > 0 && (m->shapes_xy == NULL || m->shape_fields == NULL)))
        return VS_EVALUE;
    for (size_t i = 0; i < n; i++) {
        if (seen[i] && !(vs_isfinite(pose_world[3 * i]) && vs_isfinite(pose_world[3 * i + 1])
                         && vs_isfinite(pose_world[3 * i + 2])))
            return VS_ENONFINITE;
        n_used += seen[i] && !excluded[i];
        n_judges += seen[i] && !excluded[i] && !judged_apart[i];
    }
    if (n_used == 0) {
        out->any_used = 0;
        return VS_OK;
    }
    /* the workspace: the fit's (vs_fit_work_f64), then scratch: gathered template and positions (4n), distances (n),
     * headings (n), deviations (n), judged points (2n); then the mask (n bytes) */
    double *own = NULL;
    if (work == NULL) {   /* vs_structure_step: allocated for this one call */
        size_t need = vs_structure_step_work_f64(n, m->metric);
        if (need > (size_t)-1 / sizeof(double) || (own = work = malloc(sizeof(double) * need)) == NULL)
            return VS_ENOMEM;
    }
    double *fit_work = work, *scratch = fit_work + vs_fit_work_f64(n, m->metric);
    unsigned char *mask = (unsigned char *)(scratch + 9 * n);
    double *dist = scratch + 4 * n, *head = dist + n, *devs = head + n, *judged = devs + n;
    for (size_t i = 0; i < n; i++) mask[i] = (unsigned char)(seen[i] && !excluded[i]);

    vs_fit_result fit;
    vs_advance_result adv;
    const double *tpl = m->template_xy;
    const vs_field *field = m->field;
    vs_goal goal = m->goal;
    int shape = 0;
    int rc = fit_rows(m, tpl, pose_world, mask, n_used, scratch, fit_work, &fit);
    if (rc != VS_OK) goto done;
    if (field != NULL && m->n_shapes > 0 && goal.kind != VS_GOAL_TWIST && goal.n_poses > 0) {
        /* reshape (vs_step.h): every shape fitted; the robots are in the shape that fits them best (the least
         * cost, ties to the first); the first open shape that is that one or stands clear of the comfort band
         * (room to change shape) is taken, else the first open one, else the template */
        vs_fit_result fits[VS_STEP_MAX_SHAPES + 1];
        int open[VS_STEP_MAX_SHAPES + 1], tight[VS_STEP_MAX_SHAPES + 1];
        size_t k_all = m->n_shapes + 1, now_in = 0, pick = 0;
        fits[0] = fit;
        for (size_t j = 0; j < k_all; j++) {
            const double *t = j == 0 ? tpl : m->shapes_xy + 2 * n * (j - 1);
            const vs_field *fj = j == 0 ? field : m->shape_fields[j - 1];
            if (j > 0) {
                rc = fit_rows(m, t, pose_world, mask, n_used, scratch, fit_work, &fits[j]);
                if (rc != VS_OK) goto done;
            }
            double p[3] = {fits[j].x, fits[j].y, fits[j].th};
            tight[j] = 0;
            open[j] = fj != NULL && vs_field_open(fj, p, &tight[j]);
            if (fits[j].cost < fits[now_in].cost) now_in = j;
        }
        int found = 0;
        for (size_t j = 0; j < k_all && !found; j++)
            if (open[j] && (j == now_in || !tight[j])) { pick = j; found = 1; }
        for (size_t j = 0; j < k_all && !found; j++)
            if (open[j]) { pick = j; found = 1; }
        if (pick > 0) {
            tpl = m->shapes_xy + 2 * n * (pick - 1);
            field = m->shape_fields[pick - 1];
            fit = fits[pick];
            shape = (int)pick;
        }
    }
    vs_apply_pose(fit.x, fit.y, fit.th, tpl, n, points_now);
    distances(pose_world, points_now, n, dist);
    const double nan = 0.0 / 0.0;
    for (size_t i = 0; i < n; i++) {
        head[i] = mask[i] ? pose_world[3 * i + 2] : nan;
        devs[i] = mask[i] ? dist[i] : nan;
    }
    double pose_fit[3] = {fit.x, fit.y, fit.th};
    int blocked = 0, held = 0;
    double left_m = 0.0;
    vs_limits limits = m->limits;
    double plan[3 * VS_STEP_PATH_CAP];
    double reach = 0.0;   /* following a field: the shape's largest |p_i| [m] (the carrot's reach, the barrier's metric) */
    if (field != NULL && goal.kind != VS_GOAL_TWIST && goal.n_poses > 0) {
        size_t n_way = 0;
        rc = vs_field_follow(field, pose_fit, VS_STEP_PATH_M, plan, VS_STEP_PATH_CAP, &n_way, &blocked, &left_m);
        if (rc != VS_OK) goto done;
        if (blocked && field->provisional) {   /* a first plan with no way from here: hold, no verdict (vs_field.h) */
            n_way = 1;
            blocked = 0;
            left_m = 0.0;
            held = 1;
        }
        goal.kind = VS_GOAL_PLAN;   /* turn in step with the move: keep to the plan in SE(2) */
        goal.poses = plan;
        goal.n_poses = n_way;
        double reach2 = 0.0;
        for (size_t i = 0; i < n; i++) {
            double r2 = tpl[2 * i] * tpl[2 * i] + tpl[2 * i + 1] * tpl[2 * i + 1];
            if (r2 > reach2) reach2 = r2;
        }
        reach = sqrt(reach2);
        double ahead = VS_STEP_LOOKAHEAD_PER_REACH * reach;
        if (ahead > limits.path_lookahead_m) limits.path_lookahead_m = ahead;
    }
    rc = vs_advance(pose_fit, &goal, dt_s, &limits, tpl, m->wheel_base_m,
                    m->wheel_speed_max_m_s, m->wheel_accel_max_m_s2, n, NULL, &elapsed_s, head, devs, &adv);
    if (rc != VS_OK) goto done;
    int cleared = 0;
    if (goal.kind == VS_GOAL_PLAN && m->n_obstacles > 0 && !adv.at_goal) {
        /* the room's clearance barrier (vs_clear.h): the points keep VS_CLEAR_M from every obstacle */
        double t[3];
        cleared = clear_twist(m, points_now, &fit, n, reach, &adv, t);
        if (cleared && limits.path_lookahead_m > m->limits.path_lookahead_m && held_back(&adv, t)) {
            /* the barrier holds a large structure's move back head on: its long carrot cut round the obstacle
             * the plan goes round; the mission's own lookahead instead (vs_step.h, VS_STEP_LOOKAHEAD_PER_REACH) */
            rc = vs_advance(pose_fit, &goal, dt_s, &m->limits, tpl, m->wheel_base_m, m->wheel_speed_max_m_s,
                            m->wheel_accel_max_m_s2, n, NULL, &elapsed_s, head, devs, &adv);
            if (rc != VS_OK) goto done;
            cleared = !adv.at_goal && clear_twist(m, points_now, &fit, n, reach, &adv, t);
        }
        if (cleared) {
            /* the pose one dt_s on, as vs_advance forms it */
            double th0 = (pose_fit[2] >= -VS_PI && pose_fit[2] < VS_PI) ? pose_fit[2] : vs_wrap_angle(pose_fit[2]);
            adv.vx_m_s = t[0];
            adv.vy_m_s = t[1];
            adv.w_rad_s = t[2];
            adv.x = pose_fit[0] + t[0] * dt_s;
            adv.y = pose_fit[1] + t[1] * dt_s;
            adv.th = vs_wrap_angle(th0 + t[2] * dt_s);
            if (!(vs_isfinite(adv.x) && vs_isfinite(adv.y) && vs_isfinite(adv.th))) { rc = VS_ENONFINITE; goto done; }
        }
    }
    if (n_judges >= 2 && n_judges < n_used) {   /* a rigid fit needs two points to fix the heading */
        for (size_t i = 0; i < n; i++) mask[i] = (unsigned char)(mask[i] && !judged_apart[i]);
        vs_fit_result jf;
        rc = fit_rows(m, tpl, pose_world, mask, n_judges, scratch, fit_work, &jf);
        if (rc != VS_OK) goto done;
        vs_apply_pose(jf.x, jf.y, jf.th, tpl, n, judged);
        distances(pose_world, judged, n, dist);
    }
    for (size_t i = 0; i < n; i++) {
        used[i] = (unsigned char)(seen[i] && !excluded[i]);
        deviations_m[i] = seen[i] ? dist[i] : 1.0 / 0.0;
    }
    vs_apply_pose(adv.x, adv.y, adv.th, tpl, n, points_next);
    out->any_used = 1;
    out->fit_x = fit.x; out->fit_y = fit.y; out->fit_th = fit.th;
    out->goal_x = adv.x; out->goal_y = adv.y; out->goal_th = adv.th;
    out->vx_m_s = adv.vx_m_s; out->vy_m_s = adv.vy_m_s; out->w_rad_s = adv.w_rad_s;
    out->cost = fit.cost;
    out->at_goal = adv.at_goal && !blocked && !held;
    out->blocked = blocked;
    out->left_m = left_m;
    out->shape = shape;
    out->cleared = cleared;
    out->held = held;
done:
    free(own);
    return rc;
}
