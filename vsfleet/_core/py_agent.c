/* py_agent.c - binding of the agent's per-frame step (vs_agent.h): vsfleet._core.agent_config, agent_step. */
#include <string.h>

#include "py_util.h"
#include "vscore.h"
#include "vs_agent.h"
#include "vs_wire.h"

const vs_field *vs_py_field(PyObject *obj);   /* py_field.c: NULL for None (or with an error set) */

#define AGENT_CAPSULE "vsfleet._core.agent_config"
#define N_MISSION_BUFS 10

/* a mission and an agent's constants, with the buffers it points into held until the capsule goes */
typedef struct {
    vs_agent_config cfg;
    vs_mission m;
    Py_buffer views[N_MISSION_BUFS];
    int got;
    const vs_field *shape_fields[VS_STEP_MAX_SHAPES];
    PyObject *keep;          /* the mission tuple (its fields' capsules) */
    /* the frame path (agent_frame): the mission's robot ids in its sorted order (UTF-8 bytes, kept in ids_blob),
     * and buffers sized for n robots */
    PyObject *ids_blob;      /* bytes: every id, one after the other */
    vs_wire_str *ids;        /* (n) slices of ids_blob */
    vs_wire_str *used_ids;   /* (n) the ids of the robots a fit used */
    vs_wire_slice *slices;   /* (n) the frame's ids, as the decoder gives them */
    double *frame_poses;     /* (n, 3) the frame's poses in the order sent */
    double *row_poses;       /* (n, 3) the same, in rows */
    unsigned char *seen;     /* (n) */
    unsigned char *used;     /* (n) */
    vs_failure_decision *decisions;   /* (2n) the failure rule's decisions of a frame */
    unsigned char *state_buf;
    size_t state_cap;
    double *work;            /* the kernels' workspace, vs_agent_work_f64(m) doubles: no frame allocates */
} agent_config;

static void agent_config_free(PyObject *cap)
{
    agent_config *a = PyCapsule_GetPointer(cap, AGENT_CAPSULE);
    if (a == NULL) return;
    for (int i = 0; i < a->got; i++) PyBuffer_Release(&a->views[i]);
    Py_XDECREF(a->keep);
    Py_XDECREF(a->ids_blob);
    PyMem_Free(a->ids);
    PyMem_Free(a->used_ids);
    PyMem_Free(a->slices);
    PyMem_Free(a->frame_poses);
    PyMem_Free(a->row_poses);
    PyMem_Free(a->seen);
    PyMem_Free(a->used);
    PyMem_Free(a->decisions);
    PyMem_Free(a->state_buf);
    PyMem_Free(a->work);
    PyMem_Free(a);
}

static int doubles_of(PyObject *seq, double *out, Py_ssize_t k, const char *name)
{
    PyObject *fast = PySequence_Fast(seq, name);
    if (fast == NULL) return -1;
    if (PySequence_Fast_GET_SIZE(fast) != k) {
        Py_DECREF(fast);
        PyErr_Format(vs_ValueError, "agent_config: %s must hold %zd numbers", name, k);
        return -1;
    }
    for (Py_ssize_t i = 0; i < k; i++) {
        out[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(fast, i));
        if (out[i] == -1.0 && PyErr_Occurred()) { Py_DECREF(fast); return -1; }
    }
    Py_DECREF(fast);
    return 0;
}

/* agent_config's policy, safety and times, by place; their names are exported (AGENT_POLICY, AGENT_SAFETY,
 * AGENT_TIMES) and vsfleet.agentcore builds the tuples by name */
enum { P_MODE, P_FAIL_DEV, P_FAIL_AFTER, P_REJOIN_DEV, P_REJOIN_AFTER, P_RECOVER_AFTER, P_MIN_PROGRESS, P_MIN_EXPECTED2,
       P_MIN_APPROACH, P_COUNT };
enum { S_MARGIN, S_GAMMA, S_OFFSET, S_DT, S_COUNT };
enum { T_DT, T_TTL, T_AGE, T_RESYNC_GAP, T_EFFECTIVE, T_COUNT };
typedef char policy_check[P_COUNT == VS_PY_AGENT_POLICY && S_COUNT == VS_PY_AGENT_SAFETY
                          && T_COUNT == VS_PY_AGENT_TIMES ? 1 : -1];
const char *const vs_py_agent_policy[VS_PY_AGENT_POLICY] = {
    [P_MODE] = "mode", [P_FAIL_DEV] = "fail_deviation_m", [P_FAIL_AFTER] = "fail_after_s",
    [P_REJOIN_DEV] = "rejoin_deviation_m", [P_REJOIN_AFTER] = "rejoin_after_s", [P_RECOVER_AFTER] = "recover_after_s",
    [P_MIN_PROGRESS] = "min_progress_ratio", [P_MIN_EXPECTED2] = "min_expected_m2", [P_MIN_APPROACH] = "min_approach_m",
};
const char *const vs_py_agent_safety[VS_PY_AGENT_SAFETY] = {
    [S_MARGIN] = "margin_m", [S_GAMMA] = "gamma_per_s", [S_OFFSET] = "offset_m", [S_DT] = "dt_s",
};
const char *const vs_py_agent_times[VS_PY_AGENT_TIMES] = {
    [T_DT] = "dt_s", [T_TTL] = "ttl_s", [T_AGE] = "age_s", [T_RESYNC_GAP] = "resync_gap_s",
    [T_EFFECTIVE] = "effective_t",
};

/* agent_config(mission, own, controller, gains, deadband_m, still_speed_m_s, policy, safety, times, room, bodies,
 *              ids)
 * mission: the mission packed for the core in MISSION_ARGS order (vsfleet.step.core_mission); own: the agent's row;
 * controller: VS_AGENT_* code; gains: the controller's numbers in its C struct's order (precision 17, turn_then_go
 * 5, arc 1, tracking 6); policy: (mode code, fail_deviation_m, fail_after_s, rejoin_deviation_m, rejoin_after_s,
 * recover_after_s, min_progress_ratio, min_expected_m2, min_approach_m); safety: (margin_m, gamma_per_s, offset_m,
 * dt_s); times: (dt_s, ttl_s, age_s, resync_gap_s, effective_t); ids: the mission's robot ids in its sorted
 * order (str) -> a capsule */
static PyObject *py_agent_config(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 12) { PyErr_SetString(PyExc_TypeError, "agent_config takes 12 arguments"); return NULL; }
    PyObject *mt = a[0];
    if (!PyTuple_Check(mt) || PyTuple_GET_SIZE(mt) != VS_PY_MISSION_ARGS) {
        PyErr_SetString(PyExc_TypeError, "agent_config: the mission must be the core's tuple (MISSION_ARGS)");
        return NULL;
    }
    agent_config *c = PyMem_Calloc(1, sizeof *c);
    if (c == NULL) return PyErr_NoMemory();
    PyObject *cap = PyCapsule_New(c, AGENT_CAPSULE, agent_config_free);
    if (cap == NULL) { PyMem_Free(c); return NULL; }
    c->keep = Py_NewRef(mt);
    /* the mission's arrays, by their places in MISSION_ARGS (py_util.h) */
    static const int dbl[N_MISSION_BUFS] = {
        VS_PY_MISSION_AT(A_TEMPLATE), VS_PY_MISSION_AT(A_BASE), VS_PY_MISSION_AT(A_VMAX), VS_PY_MISSION_AT(A_AMAX),
        VS_PY_MISSION_AT(A_GOAL), VS_PY_MISSION_AT(A_LIMITS), VS_PY_MISSION_AT(A_RADIUS),
        VS_PY_MISSION_AT(A_OBSTACLES), VS_PY_MISSION_AT(A_SHAPES), -1};
    static const char *names[N_MISSION_BUFS] = {"template_xy", "wheel_base_m", "wheel_speed_max_m_s",
                                                "wheel_accel_max_m_s2", "goal", "limits", "radius_m", "obstacles",
                                                "shapes_xy", ""};
    for (; c->got < N_MISSION_BUFS - 1; c->got++)
        if (vs_py_doubles(PyTuple_GET_ITEM(mt, dbl[c->got]), &c->views[c->got], -1, 0, names[c->got]) < 0) goto fail;
    Py_ssize_t n = c->views[0].len / 16;
    if (n < 1 || c->views[0].len % 16 || c->views[1].len != 8 * n || c->views[2].len != 8 * n
        || c->views[3].len != 8 * n || c->views[6].len != 8 * n || c->views[4].len == 0 || c->views[4].len % 24
        || c->views[5].len != 72 || c->views[7].len % 24) {
        PyErr_SetString(vs_ValueError, "agent_config: the mission's arrays do not fit n robots");
        goto fail;
    }
    PyObject *sf = PyTuple_GET_ITEM(mt, VS_PY_MISSION_AT(A_SHAPE_FIELDS));
    if (!PyTuple_Check(sf) || PyTuple_GET_SIZE(sf) > VS_STEP_MAX_SHAPES
        || c->views[8].len != 16 * n * PyTuple_GET_SIZE(sf)) {
        PyErr_SetString(vs_ValueError, "agent_config: shapes_xy and shape_fields do not agree");
        goto fail;
    }
    for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(sf); j++)
        if ((c->shape_fields[j] = vs_py_field(PyTuple_GET_ITEM(sf, j))) == NULL) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "agent_config: a shape without its field");
            goto fail;
        }
    const vs_field *field = vs_py_field(PyTuple_GET_ITEM(mt, VS_PY_MISSION_AT(A_FIELD)));
    if (field == NULL && PyErr_Occurred()) goto fail;
    long metric = PyLong_AsLong(PyTuple_GET_ITEM(mt, VS_PY_MISSION_AT(A_METRIC)));
    long kind = PyLong_AsLong(PyTuple_GET_ITEM(mt, VS_PY_MISSION_AT(A_KIND)));
    double margin = PyFloat_AsDouble(PyTuple_GET_ITEM(mt, VS_PY_MISSION_AT(A_MARGIN)));
    if (PyErr_Occurred()) goto fail;
    const double *lim = c->views[5].buf;
    vs_mission m = {(size_t)n, c->views[0].buf, c->views[1].buf, c->views[2].buf, c->views[3].buf, (int)metric,
                    {(int)kind, c->views[4].buf, (size_t)(c->views[4].len / 24)},
                    {lim[0], lim[1], lim[2], lim[3], lim[4], lim[5], lim[6], lim[7], lim[8]},
                    c->views[6].buf, c->views[7].buf, (size_t)(c->views[7].len / 24), margin, field,
                    (size_t)PyTuple_GET_SIZE(sf), c->views[8].buf, c->shape_fields};
    c->m = m;
    vs_agent_config *g = &c->cfg;
    g->mission = &c->m;
    Py_ssize_t own = PyLong_AsSsize_t(a[1]);
    long ctrl = PyLong_AsLong(a[2]);
    g->deadband_m = PyFloat_AsDouble(a[4]);
    g->still_speed_m_s = PyFloat_AsDouble(a[5]);
    int room = PyObject_IsTrue(a[9]), bodies = PyObject_IsTrue(a[10]);
    if (PyErr_Occurred() || room < 0 || bodies < 0) goto fail;
    if (own < 0 || own >= n) { PyErr_SetString(vs_ValueError, "agent_config: own must be a row"); goto fail; }
    g->own = (size_t)own;
    g->controller = (int)ctrl;
    g->room = room;
    g->bodies = bodies;
    double gains[17];
    switch (ctrl) {
    case VS_AGENT_PRECISION:
        if (doubles_of(a[3], gains, 17, "gains") < 0) goto fail;
        g->precision = (vs_precision_gains){gains[0], gains[1], gains[2], gains[3], gains[4], gains[5], gains[6],
                                            gains[7], gains[8], gains[9], gains[10], gains[11], gains[12], gains[13],
                                            gains[14], gains[15], gains[16]};
        break;
    case VS_AGENT_TURN_THEN_GO:
        if (doubles_of(a[3], gains, 5, "gains") < 0) goto fail;
        g->turn_then_go = (vs_turn_then_go_gains){gains[0], gains[1], gains[2], gains[3], gains[4] != 0.0};
        break;
    case VS_AGENT_ARC:
        if (doubles_of(a[3], gains, 1, "gains") < 0) goto fail;
        g->arc_horizon_s = gains[0];
        break;
    case VS_AGENT_TRACKING:
        if (doubles_of(a[3], gains, 6, "gains") < 0) goto fail;
        g->tracking = (vs_tracking_gains){gains[0], gains[1], gains[2], gains[3], gains[4], gains[5]};
        break;
    default:
        PyErr_SetString(vs_ValueError, "agent_config: unknown controller code");
        goto fail;
    }
    double pol[P_COUNT], saf[S_COUNT], times[T_COUNT];
    if (doubles_of(a[6], pol, P_COUNT, "policy") < 0 || doubles_of(a[7], saf, S_COUNT, "safety") < 0
        || doubles_of(a[8], times, T_COUNT, "times") < 0)
        goto fail;
    if (!(pol[P_MODE] == 0.0 || pol[P_MODE] == 1.0 || pol[P_MODE] == 2.0)) {   /* a mode code, before any cast */
        PyErr_SetString(vs_ValueError, "agent_config: the policy's mode must be a code of FAILURE_MODES");
        goto fail;
    }
    g->policy = (vs_failure_policy){(int)pol[P_MODE], pol[P_FAIL_DEV], pol[P_FAIL_AFTER], pol[P_REJOIN_DEV],
                                    pol[P_REJOIN_AFTER], pol[P_RECOVER_AFTER], pol[P_MIN_PROGRESS],
                                    pol[P_MIN_EXPECTED2], pol[P_MIN_APPROACH]};
    g->safety = (vs_safety_params){saf[S_MARGIN], saf[S_GAMMA], saf[S_OFFSET], saf[S_DT]};
    g->dt_s = times[T_DT];
    g->ttl_s = times[T_TTL];
    g->age_s = times[T_AGE];
    g->resync_gap_s = times[T_RESYNC_GAP];
    g->effective_t = times[T_EFFECTIVE];
    /* the ids, for agent_frame */
    if (!PyTuple_Check(a[11]) || PyTuple_GET_SIZE(a[11]) != n) {
        PyErr_SetString(PyExc_TypeError, "agent_config: ids must be a tuple of the mission's n robot ids");
        goto fail;
    }
    PyObject *parts = PyList_New(n);
    if (parts == NULL) goto fail;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *b = PyUnicode_AsUTF8String(PyTuple_GET_ITEM(a[11], i));
        if (b == NULL) { Py_DECREF(parts); goto fail; }
        PyList_SET_ITEM(parts, i, b);
    }
    PyObject *empty = PyBytes_FromStringAndSize("", 0);
    c->ids_blob = empty ? PyObject_CallMethod(empty, "join", "O", parts) : NULL;
    Py_XDECREF(empty);
    c->ids = PyMem_Calloc((size_t)n, sizeof *c->ids);
    c->used_ids = PyMem_Calloc((size_t)n, sizeof *c->used_ids);
    c->slices = PyMem_Calloc((size_t)n, sizeof *c->slices);
    c->frame_poses = PyMem_Calloc(3 * (size_t)n, sizeof(double));
    c->row_poses = PyMem_Calloc(3 * (size_t)n, sizeof(double));
    c->seen = PyMem_Calloc((size_t)n, 1);
    c->used = PyMem_Calloc((size_t)n, 1);
    c->decisions = PyMem_Calloc(2 * (size_t)n, sizeof *c->decisions);
    if (c->ids_blob == NULL || c->ids == NULL || c->used_ids == NULL || c->slices == NULL || c->frame_poses == NULL || c->row_poses == NULL
        || c->seen == NULL || c->used == NULL || c->decisions == NULL) {
        Py_DECREF(parts);
        if (!PyErr_Occurred()) PyErr_NoMemory();
        goto fail;
    }
    const unsigned char *blob = (const unsigned char *)PyBytes_AS_STRING(c->ids_blob);
    size_t at = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        size_t len = (size_t)PyBytes_GET_SIZE(PyList_GET_ITEM(parts, i));
        c->ids[i] = (vs_wire_str){blob + at, len};
        at += len;
    }
    Py_DECREF(parts);
    c->state_cap = VS_WIRE_STATE_MAX_BYTES((size_t)n, at);
    c->state_buf = PyMem_Malloc(c->state_cap);
    if (c->state_buf == NULL) { PyErr_NoMemory(); goto fail; }
    /* the kernels' workspace, sized with the mission (up to ~10 MB for l1 and linf: the search's tables, untouched
     * beyond what a fit uses; not zeroed, so never touched here) */
    size_t work = vs_agent_work_f64(&c->m);
    if (work > ((size_t)-1 / 2) / sizeof(double)) {
        PyErr_SetString(vs_ValueError, "agent_config: too many robots or obstacles for the safety filter");
        goto fail;
    }
    c->work = PyMem_Malloc(work * sizeof(double));
    if (c->work == NULL) { PyErr_NoMemory(); goto fail; }
    return cap;
fail:
    Py_DECREF(cap);
    return NULL;
}

enum { BUF_F64, BUF_BOOL, BUF_I64 };

static int get_buf(PyObject *obj, Py_buffer *view, int kind, Py_ssize_t count, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "agent_step: %s must be a C-contiguous%s buffer", name, writable ? " writable" : "");
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    int ok = kind == BUF_F64 ? (view->itemsize == 8 && f[0] == 'd' && f[1] == 0)
           : kind == BUF_BOOL ? (view->itemsize == 1 && (f[0] == '?' || f[0] == 'B') && f[1] == 0)
                              : (view->itemsize == 8 && (f[0] == 'q' || f[0] == 'l') && f[1] == 0);
    if (!ok || view->len / view->itemsize != count) {
        PyErr_Format(vs_ValueError, "agent_step: %s must hold %zd %s", name, count,
                     kind == BUF_F64 ? "float64" : kind == BUF_BOOL ? "bool" : "int64");
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* the state's arrays, by place (their names exported: AGENT_STATE; vsfleet.agentcore checks its order against it) */
enum { ST_WHEELS, ST_POSE, ST_GAINS, ST_HISTORY, ST_TARGET, ST_FEED, ST_TURN, ST_DIRECTION, ST_OFFSET, ST_READY,
       ST_SINCE, ST_FAILED, ST_DROPPED, ST_LAST_T, ST_LAST_XY, ST_LAST_EXPECTED, ST_WINDOW_T, ST_WINDOW_NM, ST_HEAD,
       ST_IN_WINDOW, ST_SUMS_NM, ST_WINDOW_DEV, N_STATE };
const char *const vs_py_agent_state[VS_PY_AGENT_STATE] = {
    [ST_WHEELS] = "wheels_m_s", [ST_POSE] = "pose_world", [ST_GAINS] = "gains", [ST_HISTORY] = "history_m_s",
    [ST_TARGET] = "target_world", [ST_FEED] = "feed_m_s", [ST_TURN] = "turn_rad_s", [ST_DIRECTION] = "direction",
    [ST_OFFSET] = "offset_world", [ST_READY] = "ready", [ST_SINCE] = "since_t", [ST_FAILED] = "failed",
    [ST_DROPPED] = "dropped",
    [ST_LAST_T] = "last_t", [ST_LAST_XY] = "last_xy", [ST_LAST_EXPECTED] = "last_expected", [ST_WINDOW_T] = "window_t",
    [ST_WINDOW_NM] = "window_nm", [ST_HEAD] = "head", [ST_IN_WINDOW] = "in_window", [ST_SUMS_NM] = "sums_nm",
    [ST_WINDOW_DEV] = "window_dev_m",
};
/* the state's numbers (a float64 buffer), by place (exported: AGENT_SCALARS) */
enum { SC_LAST_FRAME_T, SC_LAST_CMD_T, SC_CTRL_READY, SC_BLOCKED, SC_STALL_SINCE_T, SC_STALL_WATCH, SC_STALL_X,
       SC_STALL_Y, SC_STALL_TH, SC_STALL_FILTER, SC_STALLED, SC_SHAPE, N_SCALARS };
const char *const vs_py_agent_scalars[VS_PY_AGENT_SCALARS] = {
    [SC_LAST_FRAME_T] = "last_frame_t", [SC_LAST_CMD_T] = "last_cmd_t", [SC_CTRL_READY] = "ctrl_ready",
    [SC_BLOCKED] = "blocked", [SC_STALL_SINCE_T] = "stall_since_t", [SC_STALL_WATCH] = "stall_watch",
    [SC_STALL_X] = "stall_x", [SC_STALL_Y] = "stall_y", [SC_STALL_TH] = "stall_th", [SC_STALL_FILTER] = "stall_filter",
    [SC_STALLED] = "stalled", [SC_SHAPE] = "shape",
};
/* agent_step's answer, by place (exported: AGENT_RESULT); (resynced,) alone when no robot was usable */
enum { R_RESYNCED, R_FIT_X, R_FIT_Y, R_FIT_TH, R_GOAL_X, R_GOAL_Y, R_GOAL_TH, R_VX, R_VY, R_W, R_COST, R_AT_GOAL,
       R_BLOCKED, R_LEFT, R_SHAPE, R_VL, R_VR, R_OWN_SEEN, R_ERR, R_EVENT, R_EVENT_DEV, R_SHAPE_BEFORE, R_DECISIONS,
       N_RESULT };
const char *const vs_py_agent_result[VS_PY_AGENT_RESULT] = {
    [R_RESYNCED] = "resynced", [R_FIT_X] = "fit_x", [R_FIT_Y] = "fit_y", [R_FIT_TH] = "fit_th",
    [R_GOAL_X] = "goal_x", [R_GOAL_Y] = "goal_y", [R_GOAL_TH] = "goal_th", [R_VX] = "vx_m_s", [R_VY] = "vy_m_s",
    [R_W] = "w_rad_s", [R_COST] = "cost", [R_AT_GOAL] = "at_goal", [R_BLOCKED] = "blocked", [R_LEFT] = "left_m",
    [R_SHAPE] = "shape", [R_VL] = "vl_m_s", [R_VR] = "vr_m_s", [R_OWN_SEEN] = "own_seen", [R_ERR] = "err_m",
    [R_EVENT] = "event", [R_EVENT_DEV] = "event_dev_m", [R_SHAPE_BEFORE] = "shape_before",
    [R_DECISIONS] = "decisions",
};
typedef char state_check[N_STATE == VS_PY_AGENT_STATE && N_SCALARS == VS_PY_AGENT_SCALARS
                         && N_RESULT == VS_PY_AGENT_RESULT ? 1 : -1];
#define N_STEP_ARGS 10

/* the state's buffers, held for one call */
typedef struct {
    Py_buffer v[N_STATE + 3];
    int got;
    vs_agent_state st;
    double *sc;
    double *scratch_f64;
    unsigned char *scratch_u8;
} state_views;

static void release_state(state_views *sv)
{
    for (int k = 0; k < sv->got; k++) PyBuffer_Release(&sv->v[k]);
    sv->got = 0;
}

/* state: the N_STATE arrays (ST_*); scalars: the N_SCALARS numbers (SC_*) */
static int get_state(const agent_config *c, PyObject *tuple, PyObject *scalars, PyObject *f64, PyObject *u8,
                     state_views *sv)
{
    sv->got = 0;
    const Py_ssize_t n = (Py_ssize_t)c->m.n;
    if (!PyTuple_Check(tuple) || PyTuple_GET_SIZE(tuple) != N_STATE) {
        PyErr_Format(PyExc_TypeError, "agent_step: the state must be a tuple of %d arrays", (int)N_STATE);
        return -1;
    }
    /* the window's width from window_t ((n, W)) */
    Py_buffer wt;
    if (PyObject_GetBuffer(PyTuple_GET_ITEM(tuple, ST_WINDOW_T), &wt, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return -1;
    Py_ssize_t W = (wt.ndim == 2 && wt.shape[0] == n) ? wt.shape[1] : 0;
    PyBuffer_Release(&wt);
    if (W < 1) { PyErr_SetString(vs_ValueError, "agent_step: window_t must be (n, W), W >= 1"); return -1; }
    static const struct { int kind; Py_ssize_t per_row; } spec[N_STATE] = {   /* per_row < 0: times W */
        [ST_WHEELS] = {BUF_F64, 2},
        [ST_POSE] = {BUF_F64, 3}, [ST_GAINS] = {BUF_F64, 2}, [ST_HISTORY] = {BUF_F64, 2 * VS_PRECISION_HISTORY},
        [ST_TARGET] = {BUF_F64, 2}, [ST_FEED] = {BUF_F64, 2}, [ST_TURN] = {BUF_F64, 1},
        [ST_DIRECTION] = {BUF_F64, 1}, [ST_OFFSET] = {BUF_F64, 2}, [ST_READY] = {BUF_BOOL, 1},
        [ST_SINCE] = {BUF_F64, 1}, [ST_FAILED] = {BUF_BOOL, 1}, [ST_DROPPED] = {BUF_BOOL, 1},
        [ST_LAST_T] = {BUF_F64, 1}, [ST_LAST_XY] = {BUF_F64, 2}, [ST_LAST_EXPECTED] = {BUF_F64, 2},
        [ST_WINDOW_T] = {BUF_F64, -1}, [ST_WINDOW_NM] = {BUF_I64, -4}, [ST_HEAD] = {BUF_I64, 1},
        [ST_IN_WINDOW] = {BUF_BOOL, -1}, [ST_SUMS_NM] = {BUF_I64, 4}, [ST_WINDOW_DEV] = {BUF_F64, -1},
    };
    for (; sv->got < N_STATE; sv->got++) {
        Py_ssize_t per = spec[sv->got].per_row < 0 ? -spec[sv->got].per_row * W : spec[sv->got].per_row;
        if (get_buf(PyTuple_GET_ITEM(tuple, sv->got), &sv->v[sv->got], spec[sv->got].kind, n * per, 1,
                    vs_py_agent_state[sv->got]) < 0)
            goto fail;
    }
    if (get_buf(scalars, &sv->v[sv->got], BUF_F64, N_SCALARS, 1, "scalars") < 0) goto fail;
    sv->got++;
    if (get_buf(f64, &sv->v[sv->got], BUF_F64, VS_AGENT_SCRATCH_F64(n), 1, "scratch_f64") < 0) goto fail;
    sv->got++;
    if (get_buf(u8, &sv->v[sv->got], BUF_BOOL, VS_AGENT_SCRATCH_U8(n), 1, "scratch_u8") < 0) goto fail;
    sv->got++;
    Py_buffer *v = sv->v;
    double *sc = v[N_STATE].buf;
    if (!(sc[SC_SHAPE] >= 0.0 && sc[SC_SHAPE] <= (double)VS_STEP_MAX_SHAPES)) {   /* before any cast to int */
        PyErr_SetString(vs_ValueError, "agent_step: the state's shape must be in [0, VS_STEP_MAX_SHAPES]");
        goto fail;
    }
    sv->sc = sc;
    sv->scratch_f64 = v[N_STATE + 1].buf;
    sv->scratch_u8 = v[N_STATE + 2].buf;
    vs_agent_state st = {
        v[ST_WHEELS].buf, sc[SC_CTRL_READY] != 0.0,
        {v[ST_POSE].buf, v[ST_GAINS].buf, v[ST_HISTORY].buf, v[ST_TARGET].buf, v[ST_FEED].buf, v[ST_TURN].buf,
         v[ST_DIRECTION].buf, v[ST_OFFSET].buf, v[ST_READY].buf},
        {(size_t)n, (size_t)W, v[ST_SINCE].buf, v[ST_FAILED].buf, v[ST_DROPPED].buf, v[ST_LAST_T].buf,
         v[ST_LAST_XY].buf, v[ST_LAST_EXPECTED].buf, v[ST_WINDOW_T].buf, v[ST_WINDOW_NM].buf, v[ST_HEAD].buf,
         v[ST_IN_WINDOW].buf, v[ST_SUMS_NM].buf, v[ST_WINDOW_DEV].buf},
        sc[SC_LAST_FRAME_T], sc[SC_LAST_CMD_T], sc[SC_BLOCKED] != 0.0, sc[SC_STALL_SINCE_T], sc[SC_STALL_WATCH] != 0.0,
        {sc[SC_STALL_X], sc[SC_STALL_Y], sc[SC_STALL_TH]}, sc[SC_STALL_FILTER] != 0.0, sc[SC_STALLED] != 0.0,
        (int)sc[SC_SHAPE],
    };
    sv->st = st;
    return 0;
fail:
    release_state(sv);
    return -1;
}

static void put_scalars(state_views *sv)
{
    double *sc = sv->sc;
    const vs_agent_state *st = &sv->st;
    sc[SC_LAST_FRAME_T] = st->last_frame_t;
    sc[SC_LAST_CMD_T] = st->last_cmd_t;
    sc[SC_CTRL_READY] = st->ctrl_ready;
    sc[SC_BLOCKED] = st->blocked;
    sc[SC_STALL_SINCE_T] = st->stall_since_t;
    sc[SC_STALL_WATCH] = st->stall_watch;
    sc[SC_STALL_X] = st->stall_pose[0];
    sc[SC_STALL_Y] = st->stall_pose[1];
    sc[SC_STALL_TH] = st->stall_pose[2];
    sc[SC_STALL_FILTER] = st->stall_filter;
    sc[SC_STALLED] = st->stalled;
    sc[SC_SHAPE] = st->shape;
}

/* (resynced,), or agent_step's answer in R_* order (its names: AGENT_RESULT), the decisions last:
 * ((row, kind code, t, deviation_m), ...) */
static PyObject *result_of(const vs_agent_out *out, const vs_failure_decision *dec)
{
    if (!out->ran) return Py_BuildValue("(O)", out->resynced ? Py_True : Py_False);
    PyObject *r = PyTuple_New(N_RESULT);
    if (r == NULL) return NULL;
    PyObject *decs = PyTuple_New((Py_ssize_t)out->n_decisions);
    if (decs == NULL) { Py_DECREF(r); return NULL; }
    PyTuple_SET_ITEM(r, R_DECISIONS, decs);
    for (size_t k = 0; k < out->n_decisions; k++) {
        PyObject *item = Py_BuildValue("(nidd)", (Py_ssize_t)dec[k].row, dec[k].kind, dec[k].t, dec[k].deviation_m);
        if (item == NULL) { Py_DECREF(r); return NULL; }
        PyTuple_SET_ITEM(decs, (Py_ssize_t)k, item);
    }
    const vs_structure *s = &out->s;
    const struct { int at; double v; } num[] = {
        {R_FIT_X, s->fit_x}, {R_FIT_Y, s->fit_y}, {R_FIT_TH, s->fit_th}, {R_GOAL_X, s->goal_x},
        {R_GOAL_Y, s->goal_y}, {R_GOAL_TH, s->goal_th}, {R_VX, s->vx_m_s}, {R_VY, s->vy_m_s}, {R_W, s->w_rad_s},
        {R_COST, s->cost}, {R_LEFT, s->left_m}, {R_VL, out->vl_m_s}, {R_VR, out->vr_m_s}, {R_ERR, out->err_m},
        {R_EVENT_DEV, out->event_dev_m},
    };
    const struct { int at; long v; } ints[] = {
        {R_SHAPE, s->shape}, {R_EVENT, out->event}, {R_SHAPE_BEFORE, out->shape_before},
    };
    const struct { int at; int v; } flags[] = {
        {R_RESYNCED, out->resynced}, {R_AT_GOAL, s->at_goal}, {R_BLOCKED, s->blocked}, {R_OWN_SEEN, out->own_seen},
    };
    (void)sizeof(char[sizeof num / sizeof num[0] + sizeof ints / sizeof ints[0] + sizeof flags / sizeof flags[0] + 1
                      == N_RESULT ? 1 : -1]);   /* every place set once (and R_DECISIONS above) */
    for (size_t k = 0; k < sizeof num / sizeof num[0]; k++) {
        PyObject *v = PyFloat_FromDouble(num[k].v);
        if (v == NULL) { Py_DECREF(r); return NULL; }
        PyTuple_SET_ITEM(r, num[k].at, v);
    }
    for (size_t k = 0; k < sizeof ints / sizeof ints[0]; k++) {
        PyObject *v = PyLong_FromLong(ints[k].v);
        if (v == NULL) { Py_DECREF(r); return NULL; }
        PyTuple_SET_ITEM(r, ints[k].at, v);
    }
    for (size_t k = 0; k < sizeof flags / sizeof flags[0]; k++)
        PyTuple_SET_ITEM(r, flags[k].at, PyBool_FromLong(flags[k].v));
    return r;
}

/* agent_step(config, state_arrays (21), scalars (12 float64), pose_world (n, 3), seen (n), fresh (n), t, used_out (n),
 *            scratch_f64, scratch_u8) -> result_of's tuple.  The state (arrays and scalars) is updated in place. */
static PyObject *py_agent_step(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != N_STEP_ARGS) { PyErr_SetString(PyExc_TypeError, "agent_step takes 10 arguments"); return NULL; }
    agent_config *c = PyCapsule_GetPointer(a[0], AGENT_CAPSULE);
    if (c == NULL) return NULL;
    double t = PyFloat_AsDouble(a[6]);
    if (t == -1.0 && PyErr_Occurred()) return NULL;
    const Py_ssize_t n = (Py_ssize_t)c->m.n;
    state_views sv;
    if (get_state(c, a[1], a[2], a[8], a[9], &sv) < 0) return NULL;
    Py_buffer v[4];
    int got = 0;
    PyObject *result = NULL;
    vs_failure_decision *dec = c->decisions;   /* sized with the mission, as the kernels' work */
    if (get_buf(a[3], &v[got], BUF_F64, 3 * n, 0, "pose_world") < 0) goto done;
    got++;
    if (get_buf(a[4], &v[got], BUF_BOOL, n, 0, "seen") < 0) goto done;
    got++;
    if (get_buf(a[5], &v[got], BUF_BOOL, n, 0, "fresh") < 0) goto done;
    got++;
    if (get_buf(a[7], &v[got], BUF_BOOL, n, 1, "used_out") < 0) goto done;
    got++;
    vs_agent_out out;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_agent_step_ws(&c->cfg, &sv.st, v[0].buf, v[1].buf, v[2].buf, t, &out, v[3].buf, dec, sv.scratch_f64,
                          sv.scratch_u8, c->work);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) { vs_py_error(rc, "agent_step refused its inputs"); goto done; }
    put_scalars(&sv);
    result = result_of(&out, dec);
done:
    for (int k = 0; k < got; k++) PyBuffer_Release(&v[k]);
    release_state(&sv);
    return result;
}

/* the row of a robot id (bytes) among the mission's sorted ids, or -1 (UTF-8's byte order is the code points')*/
static Py_ssize_t row_of(const agent_config *c, const unsigned char *id, size_t len)
{
    Py_ssize_t lo = 0, hi = (Py_ssize_t)c->m.n - 1;
    while (lo <= hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        const vs_wire_str *r = &c->ids[mid];
        size_t k = r->len < len ? r->len : len;
        int cmp = memcmp(r->s, id, k);
        if (cmp == 0) cmp = r->len < len ? -1 : r->len > len ? 1 : 0;
        if (cmp == 0) return mid;
        if (cmp < 0) lo = mid + 1;
        else hi = mid - 1;
    }
    return -1;
}

/* agent_frame(config, state_arrays, scalars, scratch_f64, scratch_u8, payload, src, now_s, max_future_s, max_stale_s,
 *             done_t, done_seq, mission_version, rejected, max_age_s, others_t)
 * One pass from a frame's payload to the command's and the state's payloads, for the agent's common case: one
 * source, whose frame lists exactly the mission's robots, newer than the last frame run (done_t, done_seq), neither
 * stale nor from the future against now_s, of the mission in force (t >= its effective_t), and no other source
 * heard within max_age_s of it (others_t: the newest frame time of every other source, -inf for none), and young
 * enough to move on (vs_agent_command_ttl > 0).
 * -> None when the frame is not that case (nothing is changed: the agent's merger and step take it), else
 *    (cmd payload, state payload, t, seq, result_of's tuple).  The state is updated in place. */
static PyObject *py_agent_frame(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 16) { PyErr_SetString(PyExc_TypeError, "agent_frame takes 16 arguments"); return NULL; }
    agent_config *c = PyCapsule_GetPointer(a[0], AGENT_CAPSULE);
    if (c == NULL) return NULL;
    if (!PyBytes_Check(a[5]) || !PyUnicode_Check(a[6])) {
        PyErr_SetString(PyExc_TypeError, "agent_frame: payload must be bytes and src a str");
        return NULL;
    }
    Py_ssize_t src_len;
    const char *src = PyUnicode_AsUTF8AndSize(a[6], &src_len);
    if (src == NULL) { PyErr_Clear(); Py_RETURN_NONE; }   /* not UTF-8: the agent's own path rejects it */
    double now = PyFloat_AsDouble(a[7]), max_future = PyFloat_AsDouble(a[8]), max_stale = PyFloat_AsDouble(a[9]);
    double done_t = PyFloat_AsDouble(a[10]);
    long long done_seq = PyLong_AsLongLong(a[11]), version = PyLong_AsLongLong(a[12]);
    unsigned long long rejected = PyLong_AsUnsignedLongLong(a[13]);
    double max_age = PyFloat_AsDouble(a[14]), others_t = PyFloat_AsDouble(a[15]);
    if (PyErr_Occurred()) return NULL;
    const size_t n = c->m.n;
    vs_frame fr;
    vs_wire_error err;
    int rc = vs_wire_decode_frame((const unsigned char *)PyBytes_AS_STRING(a[5]), (size_t)PyBytes_GET_SIZE(a[5]),
                                  (const unsigned char *)src, (size_t)src_len, c->slices, c->frame_poses, n, &fr,
                                  &err);
    if (rc != VS_OK || fr.n != n) Py_RETURN_NONE;   /* refused, or not every robot: the agent's own path */
    if (fr.t > now + max_future || fr.t < now - max_stale || fr.t < c->cfg.effective_t) Py_RETURN_NONE;
    const double ttl = vs_agent_command_ttl(&c->cfg, fr.t, now);
    if (!(ttl > 0.0)) Py_RETURN_NONE;   /* too old for the safety filter's horizon: the long way skips it */
    if (fr.t < done_t || (fr.t == done_t && (long long)fr.seq <= done_seq)) Py_RETURN_NONE;
    if (!(others_t < fr.t - max_age)) Py_RETURN_NONE;   /* another source heard lately could shadow or hold robots */
    memset(c->seen, 0, n);
    const unsigned char *payload = (const unsigned char *)PyBytes_AS_STRING(a[5]);
    for (size_t k = 0; k < n; k++) {
        Py_ssize_t row = row_of(c, payload + c->slices[k].off, c->slices[k].len);
        if (row < 0) Py_RETURN_NONE;   /* a robot the mission does not name (the decoder refuses duplicates) */
        c->seen[row] = 1;
        for (int j = 0; j < 3; j++) c->row_poses[3 * row + j] = c->frame_poses[3 * k + j];
    }
    state_views sv;
    if (get_state(c, a[1], a[2], a[3], a[4], &sv) < 0) return NULL;
    PyObject *result = NULL;
    vs_failure_decision *dec = c->decisions;   /* sized with the mission, as the kernels' work */
    vs_agent_out out;
    unsigned char cmd[VS_WIRE_CMD_MAX_BYTES];
    size_t cmd_len = 0, state_len = 0;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_agent_step_ws(&c->cfg, &sv.st, c->row_poses, c->seen, c->seen, fr.t, &out, c->used, dec,
                          sv.scratch_f64, sv.scratch_u8, c->work);
    if (rc == VS_OK && out.ran) {
        /* the ttl ends where the safety filter's guarantee ends (vsfleet.step.command_ttl_s) */
        cmd_len = vs_wire_encode_cmd(fr.t, fr.seq, out.vl_m_s, out.vr_m_s, ttl, cmd, sizeof cmd);
        size_t k = 0;
        for (size_t i = 0; i < n; i++)
            if (c->used[i]) c->used_ids[k++] = c->ids[i];
        const vs_structure *s = &out.s;
        vs_wire_state msg = {fr.t, fr.seq, s->fit_x, s->fit_y, s->fit_th, s->goal_x, s->goal_y, s->goal_th, s->cost,
                             out.err_m, c->used_ids, k, rejected, 1, version, s->shape, VS_WIRE_PROTOCOL_V};
        state_len = vs_wire_encode_state(&msg, c->state_buf, c->state_cap);
    }
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) { vs_py_error(rc, "agent_frame refused its inputs"); goto done; }
    put_scalars(&sv);
    PyObject *r = result_of(&out, dec);
    if (r == NULL) goto done;
    if (!out.ran) {   /* no robot usable (every one dropped): no command, no state */
        result = Py_BuildValue("(OOdLN)", Py_None, Py_None, fr.t, (long long)fr.seq, r);
        goto done;
    }
    if (cmd_len == 0 || state_len == 0) { Py_DECREF(r); PyErr_NoMemory(); goto done; }
    result = Py_BuildValue("(y#y#dLN)", (const char *)cmd, (Py_ssize_t)cmd_len, (const char *)c->state_buf,
                           (Py_ssize_t)state_len, fr.t, (long long)fr.seq, r);
done:
    release_state(&sv);
    return result;
}

PyMethodDef vs_py_agent_methods[] = {
    {"agent_config", (PyCFunction)(void (*)(void))py_agent_config, METH_FASTCALL,
     "agent_config(mission, own, controller, gains, deadband_m, still_speed_m_s, policy, safety, times, room, "
     "bodies) -> capsule: a mission and an agent's constants for agent_step (vsfleet/_core/vs_agent.h)."},
    {"agent_step", (PyCFunction)(void (*)(void))py_agent_step, METH_FASTCALL,
     "agent_step(config, state, scalars, pose_world, seen, fresh, t, used_out, scratch_f64, scratch_u8): one "
     "frame of the agent past its poses (vsfleet/_core/vs_agent.h); the state is updated in place."},
    {"agent_frame", (PyCFunction)(void (*)(void))py_agent_frame, METH_FASTCALL,
     "agent_frame(config, state, scalars, scratch_f64, scratch_u8, payload, src, now_s, max_future_s, max_stale_s, "
     "done_t, done_seq, mission_version, rejected, max_age_s, others_t) -> None or (cmd payload, state payload, t, seq, step result): one "
     "pass from a frame's payload to the command's and the state's (vsfleet/_core/py_agent.c)."},
    {NULL, NULL, 0, NULL},
};
