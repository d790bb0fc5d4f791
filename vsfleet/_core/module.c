/* module.c - vsfleet._core: the CPython binding of the compiled core.
 *
 * Why the CPython C API (and not cffi): it adds no build or run-time dependency (the
 * interpreter's headers are all gcc needs), METH_FASTCALL calls cost well under a
 * microsecond, and numpy arrays pass through the buffer protocol without numpy's headers.
 * Each area of the core has its own binding file (py_*.c) with its own method table.
 */
#include "py_util.h"
#include "vscore.h"

extern PyMethodDef vs_py_math_methods[];
extern PyMethodDef vs_py_fit_methods[];
extern PyMethodDef vs_py_advance_methods[];
extern PyMethodDef vs_py_control_methods[];
extern PyMethodDef vs_py_failure_methods[];
extern PyMethodDef vs_py_step_methods[];
extern PyMethodDef vs_py_golden_methods[];
extern PyMethodDef vs_py_safety_methods[];
extern PyMethodDef vs_py_plan_methods[];
extern PyMethodDef vs_py_field_methods[];
extern PyMethodDef vs_py_wire_methods[];

static PyMethodDef *tables[] = {vs_py_math_methods, vs_py_fit_methods, vs_py_advance_methods,
                                vs_py_control_methods, vs_py_failure_methods, vs_py_step_methods,
                                vs_py_golden_methods, vs_py_safety_methods, vs_py_plan_methods,
                                vs_py_field_methods, vs_py_wire_methods};

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
    return m;
}
