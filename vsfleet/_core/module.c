/* module.c - vsfleet._core: the CPython binding of the compiled core.
 *
 * Why the CPython C API (and not cffi): it adds no build or run-time dependency (the
 * interpreter's headers are all gcc needs), METH_FASTCALL calls cost well under a
 * microsecond, and numpy arrays pass through the buffer protocol without numpy's headers.
 * Each area of the core has its own binding file (py_*.c) with its own method table.
 */
#include <stddef.h>

#include "py_util.h"
#include "vscore.h"
#include "vs_advance.h"
#include "vs_agent.h"
#include "vs_assembly.h"
#include "vs_clear.h"
#include "vs_control.h"
#include "vs_failure.h"
#include "vs_field.h"
#include "vs_fit.h"
#include "vs_fit_l1.h"
#include "vs_fit_linf.h"
#include "vs_kin.h"
#include "vs_math.h"
#include "vs_step.h"
#include "vs_wire.h"

extern PyMethodDef vs_py_math_methods[];
extern PyMethodDef vs_py_fit_methods[];
extern PyMethodDef vs_py_advance_methods[];
extern PyMethodDef vs_py_control_methods[];
extern PyMethodDef vs_py_failure_methods[];
extern PyMethodDef vs_py_step_methods[];
extern PyMethodDef vs_py_golden_methods[];
extern PyMethodDef vs_py_safety_methods[];
extern PyMethodDef vs_py_field_methods[];
extern PyMethodDef vs_py_wire_methods[];
extern PyMethodDef vs_py_agent_methods[];

static PyMethodDef *tables[] = {vs_py_math_methods, vs_py_fit_methods, vs_py_advance_methods,
                                vs_py_control_methods, vs_py_failure_methods, vs_py_step_methods,
                                vs_py_golden_methods, vs_py_safety_methods,
                                vs_py_field_methods, vs_py_wire_methods, vs_py_agent_methods};

/* ------------------------------------------------------------------ the interface's constants
 * Exported as module attributes, so that Python reads them here and never writes them again
 * (vsfleet/coreconst.py is the one Python module that reads them). */

typedef struct { const char *name; long value; } int_const;
typedef struct { const char *name; double value; } double_const;
typedef struct { const char *name; int code; } coded;         /* a Python name and its VS_* code */
typedef struct { const char *name; size_t offset; } member;   /* a struct's double member and its offset */

static const int_const ints[] = {
    {"GOAL_POSE", VS_GOAL_POSE}, {"GOAL_PATH", VS_GOAL_PATH}, {"GOAL_TWIST", VS_GOAL_TWIST},
    {"GOAL_PLAN", VS_GOAL_PLAN}, {"ALIGN_POWER", VS_ALIGN_POWER},
    {"ALIGN_POWER_PLAN", VS_ALIGN_POWER_PLAN},
    {"METRIC_L1", VS_METRIC_L1}, {"METRIC_L2", VS_METRIC_L2}, {"METRIC_LINF", VS_METRIC_LINF},
    {"FAILURE_HOLD", VS_FAILURE_HOLD}, {"FAILURE_DROP", VS_FAILURE_DROP}, {"FAILURE_REJOIN", VS_FAILURE_REJOIN},
    {"DECISION_FAIL", VS_DECISION_FAIL}, {"DECISION_DROP", VS_DECISION_DROP},
    {"DECISION_REJOIN", VS_DECISION_REJOIN}, {"DECISION_RECOVER", VS_DECISION_RECOVER},
    {"PRECISION_HISTORY", VS_PRECISION_HISTORY},
    {"FIELD_WALL", VS_FIELD_WALL}, {"FIELD_BLOCKED_BIT", VS_FIELD_BLOCKED_BIT},
    {"FIELD_TIGHT_BIT", VS_FIELD_TIGHT_BIT}, {"FIELD_COST_MASK", VS_FIELD_COST_MASK},
    {"FIELD_UNRESOLVED", VS_FIELD_UNRESOLVED},
    {"FIELD_W_AXIS", VS_FIELD_W_AXIS}, {"FIELD_W_DIAG", VS_FIELD_W_DIAG}, {"FIELD_SEARCH_CELLS", VS_FIELD_SEARCH_CELLS},
    {"STEP_PATH_CAP", VS_STEP_PATH_CAP}, {"CLEAR_ROWS", VS_CLEAR_ROWS},
    {"FIT_MAX_ROUNDS", VS_FIT_MAX_ROUNDS}, {"L1_NEWTON_N", VS_L1_NEWTON_N}, {"LINF_SPLIT", VS_LINF_SPLIT},
    {"WIRE_MAX_FRAME_BYTES", VS_WIRE_MAX_FRAME_BYTES}, {"WIRE_MAX_ROBOTS", VS_WIRE_MAX_ROBOTS},
    {"WIRE_PROTOCOL_V", VS_WIRE_PROTOCOL_V}, {"WIRE_MAX_SRC", VS_WIRE_MAX_SRC},
    {"AGENT_SCRATCH_F64_PER_ROBOT", VS_AGENT_SCRATCH_F64_PER_ROBOT},
    {"AGENT_SCRATCH_U8_PER_ROBOT", VS_AGENT_SCRATCH_U8_PER_ROBOT},
};

static const double_const doubles[] = {
    {"ALIGN_FLOOR", VS_ALIGN_FLOOR},
    {"FAILURE_NM_PER_M", VS_FAILURE_NM_PER_M}, {"FAILURE_SETTLED_RATIO", VS_FAILURE_SETTLED_RATIO},
    {"FIELD_COMFORT_M", VS_FIELD_COMFORT_M}, {"FIELD_GROW", VS_FIELD_GROW}, {"STEP_PATH_M", VS_STEP_PATH_M},
    {"STEP_LOOKAHEAD_PER_REACH", VS_STEP_LOOKAHEAD_PER_REACH},
    {"STEP_HELD_BACK", VS_STEP_HELD_BACK},
    {"CLEAR_M", VS_CLEAR_M}, {"CLEAR_BAND_M", VS_CLEAR_BAND_M}, {"CLEAR_GAMMA_PER_S", VS_CLEAR_GAMMA_PER_S},
    {"ASSEMBLING_M", VS_ASSEMBLING_M}, {"DETOUR_CLEAR_M", VS_DETOUR_CLEAR_M},
    {"ESCAPE_M", VS_ESCAPE_M}, {"PRESSED_M", VS_PRESSED_M}, {"PRIORITY_S", VS_PRIORITY_S},
    {"FIT_CERT_TOL", VS_FIT_CERT_TOL}, {"FIT_MAX_ABS", VS_FIT_MAX_ABS}, {"SINC_SERIES_BELOW", VS_SINC_SERIES_BELOW},
    {"CORNER_TIE_RAD", VS_CORNER_TIE_RAD},
    {"WIRE_MAX_ABS", VS_WIRE_MAX_ABS}, {"WIRE_MAX_ABS_T", VS_WIRE_MAX_ABS_T},
    {"AGENT_STALL_S", VS_AGENT_STALL_S}, {"AGENT_STALL_MOVE_M", VS_AGENT_STALL_MOVE_M},
    {"AGENT_STALL_TURN_RAD", VS_AGENT_STALL_TURN_RAD},
};

/* the names Python gives the codes: a tuple indexed by code */
static const coded metrics[] = {{"l1", VS_METRIC_L1}, {"l2", VS_METRIC_L2}, {"linf", VS_METRIC_LINF}};
/* the controllers the agent step runs (vs_agent.h VS_AGENT_*), by vsfleet.control.CONTROLLERS' names */
static const coded agent_controllers[] = {{"precision", VS_AGENT_PRECISION}, {"turn_then_go", VS_AGENT_TURN_THEN_GO},
                                          {"arc", VS_AGENT_ARC}, {"tracking", VS_AGENT_TRACKING}};
static const coded decisions[] = {{"fail", VS_DECISION_FAIL}, {"drop", VS_DECISION_DROP},
                                  {"rejoin", VS_DECISION_REJOIN}, {"recover", VS_DECISION_RECOVER}};
static const coded modes[] = {{"hold", VS_FAILURE_HOLD}, {"drop", VS_FAILURE_DROP}, {"rejoin", VS_FAILURE_REJOIN}};

/* a struct of doubles' members: a tuple of their names in the struct's order (by offset) */
#define MEMBER(s, f) {#f, offsetof(s, f)}
static const member limits[] = {
    MEMBER(vs_limits, speed_max_m_s), MEMBER(vs_limits, turn_rate_max_rad_s), MEMBER(vs_limits, position_tolerance_m),
    MEMBER(vs_limits, heading_tolerance_rad), MEMBER(vs_limits, path_lookahead_m), MEMBER(vs_limits, comply_full_m),
    MEMBER(vs_limits, comply_stop_m), MEMBER(vs_limits, settle_s), MEMBER(vs_limits, turn_settle_s),
};
static const member precision[] = {
    MEMBER(vs_precision_gains, position_gain_per_s), MEMBER(vs_precision_gains, offset_m),
    MEMBER(vs_precision_gains, pose_gain_ratio), MEMBER(vs_precision_gains, heading_gain_ratio),
    MEMBER(vs_precision_gains, target_gain_ratio), MEMBER(vs_precision_gains, feed_gain_ratio),
    MEMBER(vs_precision_gains, turn_gain_ratio), MEMBER(vs_precision_gains, reverse_cos_ratio),
    MEMBER(vs_precision_gains, gain_rate_ratio), MEMBER(vs_precision_gains, gain_min_ratio),
    MEMBER(vs_precision_gains, gain_max_ratio), MEMBER(vs_precision_gains, moving_speed_m_s),
    MEMBER(vs_precision_gains, travel_floor_m), MEMBER(vs_precision_gains, gain_boost_from_m),
    MEMBER(vs_precision_gains, gain_boost_per_m), MEMBER(vs_precision_gains, gain_boost_max_ratio),
    MEMBER(vs_precision_gains, gain_boost_mean_ratio),
};
static const member tracking[] = {
    MEMBER(vs_tracking_gains, along_gain_per_s), MEMBER(vs_tracking_gains, lateral_gain_per_m2),
    MEMBER(vs_tracking_gains, heading_gain_per_m), MEMBER(vs_tracking_gains, regulate_gain_per_s),
    MEMBER(vs_tracking_gains, regulate_radius_m), MEMBER(vs_tracking_gains, moving_speed_m_s),
};
#undef MEMBER

#define COUNT(a) (sizeof (a) / sizeof (a)[0])

/* m.<attr> = the tuple of the k names, each at its code (codes 0 .. k-1, each once) */
static int add_coded(PyObject *m, const char *attr, const coded *c, size_t k)
{
    PyObject *t = PyTuple_New((Py_ssize_t)k);
    if (t == NULL) return -1;
    for (size_t i = 0; i < k; i++) {
        if (c[i].code < 0 || (size_t)c[i].code >= k || PyTuple_GET_ITEM(t, c[i].code) != NULL) {
            PyErr_Format(PyExc_SystemError, "vsfleet._core: the codes of %s are not 0 .. %zu", attr, k - 1);
            Py_DECREF(t);
            return -1;
        }
        PyObject *s = PyUnicode_FromString(c[i].name);
        if (s == NULL) { Py_DECREF(t); return -1; }
        PyTuple_SET_ITEM(t, c[i].code, s);
    }
    return PyModule_AddObject(m, attr, t) < 0 ? (Py_DECREF(t), -1) : 0;
}

/* m.<attr> = the tuple of the members' names in their struct's order; the k members of doubles
 * must fill the struct of size bytes, each once */
static int add_members(PyObject *m, const char *attr, const member *f, size_t k, size_t size)
{
    if (k * sizeof(double) != size) {
        PyErr_Format(PyExc_SystemError, "vsfleet._core: %s does not name every member of its struct", attr);
        return -1;
    }
    coded c[32];
    if (k > COUNT(c)) {
        PyErr_Format(PyExc_SystemError, "vsfleet._core: %s has more members than add_members holds", attr);
        return -1;
    }
    for (size_t i = 0; i < k; i++) c[i] = (coded){f[i].name, (int)(f[i].offset / sizeof(double))};
    return add_coded(m, attr, c, k);
}

/* m.<attr> = the tuple of the k names, in their order */
static int add_names(PyObject *m, const char *attr, const char *const *names, size_t k)
{
    coded c[32];
    if (k > COUNT(c)) {
        PyErr_Format(PyExc_SystemError, "vsfleet._core: %s has more names than add_names holds", attr);
        return -1;
    }
    for (size_t i = 0; i < k; i++) c[i] = (coded){names[i], (int)i};
    return add_coded(m, attr, c, k);
}

static int add_constants(PyObject *m)
{
    for (size_t i = 0; i < COUNT(ints); i++)
        if (PyModule_AddIntConstant(m, ints[i].name, ints[i].value) < 0) return -1;
    for (size_t i = 0; i < COUNT(doubles); i++) {
        PyObject *v = PyFloat_FromDouble(doubles[i].value);
        if (v == NULL) return -1;
        if (PyModule_AddObject(m, doubles[i].name, v) < 0) { Py_DECREF(v); return -1; }
    }
    if (add_coded(m, "METRICS", metrics, COUNT(metrics)) < 0) return -1;
    if (add_coded(m, "DECISION_KINDS", decisions, COUNT(decisions)) < 0) return -1;
    if (add_coded(m, "FAILURE_MODES", modes, COUNT(modes)) < 0) return -1;
    if (add_coded(m, "AGENT_CONTROLLERS", agent_controllers, COUNT(agent_controllers)) < 0) return -1;
    if (add_members(m, "LIMIT_FIELDS", limits, COUNT(limits), sizeof(vs_limits)) < 0) return -1;
    if (add_members(m, "PRECISION_GAIN_FIELDS", precision, COUNT(precision), sizeof(vs_precision_gains)) < 0)
        return -1;
    if (add_members(m, "TRACKING_GAIN_FIELDS", tracking, COUNT(tracking), sizeof(vs_tracking_gains)) < 0)
        return -1;
    /* the bindings' argument layouts (py_control.c, py_step.c) */
    if (add_names(m, "CONTROL_INPUT_ARGS", vs_py_control_input_args, VS_PY_CONTROL_INPUTS) < 0) return -1;
    if (add_names(m, "PRECISION_STATE_ARGS", vs_py_precision_state_args, VS_PY_PRECISION_STATES) < 0) return -1;
    if (add_names(m, "STRUCTURE_STEP_ARGS", vs_py_structure_step_args, VS_PY_STRUCTURE_STEP_ARGS) < 0) return -1;
    if (add_names(m, "AGENT_POLICY", vs_py_agent_policy, VS_PY_AGENT_POLICY) < 0) return -1;
    if (add_names(m, "AGENT_SAFETY", vs_py_agent_safety, VS_PY_AGENT_SAFETY) < 0) return -1;
    if (add_names(m, "AGENT_TIMES", vs_py_agent_times, VS_PY_AGENT_TIMES) < 0) return -1;
    if (add_names(m, "AGENT_STATE", vs_py_agent_state, VS_PY_AGENT_STATE) < 0) return -1;
    if (add_names(m, "AGENT_SCALARS", vs_py_agent_scalars, VS_PY_AGENT_SCALARS) < 0) return -1;
    if (add_names(m, "AGENT_RESULT", vs_py_agent_result, VS_PY_AGENT_RESULT) < 0) return -1;
    return 0;
}

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "vsfleet._core",
    "The compiled core of the agent step (C99; see vsfleet/_core/vscore.h).", -1, NULL};

PyMODINIT_FUNC PyInit__core(void)
{
    PyObject *errors = PyImport_ImportModule("vsfleet.errors");
    if (errors == NULL) return NULL;
    vs_NonFiniteError = PyObject_GetAttrString(errors, "NonFiniteError");
    vs_ValueError = PyObject_GetAttrString(errors, "VsfleetValueError");
    Py_DECREF(errors);
    if (vs_NonFiniteError == NULL || vs_ValueError == NULL) return NULL;
    PyObject *m = PyModule_Create(&moddef);
    if (m == NULL) return NULL;
    for (size_t t = 0; t < sizeof tables / sizeof tables[0]; t++) {
        if (PyModule_AddFunctions(m, tables[t]) < 0) { Py_DECREF(m); return NULL; }
    }
    if (add_constants(m) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
