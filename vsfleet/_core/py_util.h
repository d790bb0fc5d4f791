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
 * PRECISION_STATE_ARGS, STRUCTURE_STEP_ARGS; Python finds its positions there). */
#define VS_PY_CONTROL_INPUTS 10
#define VS_PY_PRECISION_STATES 8
#define VS_PY_STRUCTURE_STEP_ARGS 24
extern const char *const vs_py_control_input_args[VS_PY_CONTROL_INPUTS];
extern const char *const vs_py_precision_state_args[VS_PY_PRECISION_STATES];
extern const char *const vs_py_structure_step_args[VS_PY_STRUCTURE_STEP_ARGS];
extern PyObject *vs_NonFiniteError;   /* vsfleet.errors.NonFiniteError */
extern PyObject *vs_ValueError;       /* vsfleet.errors.VsfleetValueError */
#endif
