/* py_math.c - the core's own elementary functions, exposed for tests (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

typedef double (*fn1)(double);

static PyObject *call1(PyObject *const *args, Py_ssize_t nargs, fn1 f)
{
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "expected 1 argument"); return NULL; }
    double x = PyFloat_AsDouble(args[0]);
    if (x == -1.0 && PyErr_Occurred()) return NULL;
    return PyFloat_FromDouble(f(x));
}

static PyObject *py_sin(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return call1(a, n, vs_sin); }
static PyObject *py_cos(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return call1(a, n, vs_cos); }
static PyObject *py_atan(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return call1(a, n, vs_atan); }
static PyObject *py_wrap(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return call1(a, n, vs_wrap_angle); }

static PyObject *py_atan2(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "atan2(y, x)"); return NULL; }
    double y = PyFloat_AsDouble(args[0]), x = PyFloat_AsDouble(args[1]);
    if (PyErr_Occurred()) return NULL;
    return PyFloat_FromDouble(vs_atan2(y, x));
}

static PyObject *py_fmod(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "fmod(x, y)"); return NULL; }
    double x = PyFloat_AsDouble(args[0]), y = PyFloat_AsDouble(args[1]);
    if (PyErr_Occurred()) return NULL;
    return PyFloat_FromDouble(vs_fmod(x, y));
}

PyMethodDef vs_py_math_methods[] = {
    {"sin", (PyCFunction)(void (*)(void))py_sin, METH_FASTCALL, "sin(x): the core's own sine."},
    {"cos", (PyCFunction)(void (*)(void))py_cos, METH_FASTCALL, "cos(x): the core's own cosine."},
    {"atan", (PyCFunction)(void (*)(void))py_atan, METH_FASTCALL, "atan(x): the core's own arctangent."},
    {"atan2", (PyCFunction)(void (*)(void))py_atan2, METH_FASTCALL, "atan2(y, x) [rad]: the core's own."},
    {"fmod", (PyCFunction)(void (*)(void))py_fmod, METH_FASTCALL, "fmod(x, y): exact, integer-only."},
    {"wrap_angle", (PyCFunction)(void (*)(void))py_wrap, METH_FASTCALL, "wrap_angle(th) -> [-pi, pi)."},
    {NULL, NULL, 0, NULL},
};
