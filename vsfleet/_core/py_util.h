/* py_util.h - buffer helpers shared by the binding files (py_*.c); not part of the pure core. */
#ifndef VS_PY_UTIL_H
#define VS_PY_UTIL_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>

/* A C-contiguous buffer of doubles from obj (numpy float64 array, array('d'), memoryview):
 * 0 on success (release with PyBuffer_Release), -1 with TypeError/ValueError set.
 * n_expected < 0: any length. writable: the caller writes its outputs into it. */
int vs_py_doubles(PyObject *obj, Py_buffer *view, Py_ssize_t n_expected, int writable, const char *name);
/* A C-contiguous buffer of n one-byte booleans (numpy bool or uint8): as vs_py_doubles. */
int vs_py_flags(PyObject *obj, Py_buffer *view, Py_ssize_t n_expected, int writable, const char *name);
/* Raise the typed vsfleet error for a negative VS_E* code (ValueError subclasses). */
PyObject *vs_py_error(int code, const char *what);
/* The argument layouts the bindings read, by name (module.c exports them: CONTROL_INPUT_ARGS,
 * PRECISION_STATE_ARGS, STRUCTURE_STEP_ARGS, and the agent's AGENT_*; Python finds its positions there). */
#define VS_PY_CONTROL_INPUTS 10
#define VS_PY_PRECISION_STATES 9
#define VS_PY_STRUCTURE_STEP_ARGS 24
extern const char *const vs_py_control_input_args[VS_PY_CONTROL_INPUTS];
extern const char *const vs_py_precision_state_args[VS_PY_PRECISION_STATES];
extern const char *const vs_py_structure_step_args[VS_PY_STRUCTURE_STEP_ARGS];
/* structure_step's arguments (py_step.c); a mission packed for the core (vsfleet.structure.MISSION_ARGS) is those
 * before A_POSE and from A_RADIUS on, in this order: VS_PY_MISSION_AT(a) is argument a's place in it */
enum { A_TEMPLATE, A_BASE, A_VMAX, A_AMAX, A_METRIC, A_KIND, A_GOAL, A_LIMITS, A_POSE, A_SEEN, A_EXCLUDED, A_JUDGED,
       A_ELAPSED, A_DT, A_USED, A_NOW, A_NEXT, A_DEV, A_RADIUS, A_OBSTACLES, A_MARGIN, A_FIELD, A_SHAPES,
       A_SHAPE_FIELDS, A_COUNT };
#define VS_PY_MISSION_AT(a) ((a) < A_POSE ? (a) : (a) - (A_RADIUS - A_POSE))
#define VS_PY_MISSION_ARGS VS_PY_MISSION_AT(A_COUNT)
/* the agent binding's tuples and buffers (py_agent.c), by name: agent_config's policy, safety and times, the
 * state's arrays and numbers (scalars), and agent_step's answer */
#define VS_PY_AGENT_POLICY 9
#define VS_PY_AGENT_SAFETY 4
#define VS_PY_AGENT_TIMES 5
#define VS_PY_AGENT_STATE 22
#define VS_PY_AGENT_SCALARS 12
#define VS_PY_AGENT_RESULT 23
extern const char *const vs_py_agent_policy[VS_PY_AGENT_POLICY];
extern const char *const vs_py_agent_safety[VS_PY_AGENT_SAFETY];
extern const char *const vs_py_agent_times[VS_PY_AGENT_TIMES];
extern const char *const vs_py_agent_state[VS_PY_AGENT_STATE];
extern const char *const vs_py_agent_scalars[VS_PY_AGENT_SCALARS];
extern const char *const vs_py_agent_result[VS_PY_AGENT_RESULT];
extern PyObject *vs_NonFiniteError;   /* vsfleet.errors.NonFiniteError */
extern PyObject *vs_ValueError;       /* vsfleet.errors.VsfleetValueError */
#endif
