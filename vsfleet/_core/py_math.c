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

#include "vs_golden.h"

/* golden_call(name, inputs) -> list of floats: one flat golden entry (vs_golden.c). */
static PyObject *py_golden_call(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs != 2 || !PyUnicode_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "golden_call(name: str, inputs: float64 buffer)");
        return NULL;
    }
    const golden_entry *e = golden_find(PyUnicode_AsUTF8(args[0]));
    if (e == NULL) return PyErr_Format(PyExc_ValueError, "no golden entry %R", args[0]);
    Py_buffer v;
    if (vs_py_doubles(args[1], &v, -1, 0, "inputs") < 0) return NULL;
    long n_in = (long)(v.len / 8), cap = n_in * 4 + 4096;
    double *out = PyMem_Malloc(sizeof(double) * (size_t)cap);
    if (out == NULL) { PyBuffer_Release(&v); return PyErr_NoMemory(); }
    long n_out = e->run((const double *)v.buf, n_in, out, cap);
    PyBuffer_Release(&v);
    if (n_out < 0) { PyMem_Free(out); return PyErr_Format(PyExc_ValueError, "golden entry %R refused its inputs", args[0]); }
    PyObject *list = PyList_New(n_out);
    for (long i = 0; list && i < n_out; i++) PyList_SET_ITEM(list, i, PyFloat_FromDouble(out[i]));
    PyMem_Free(out);
    return list;
}

PyMethodDef vs_py_golden_methods[] = {
    {"golden_call", (PyCFunction)(void (*)(void))py_golden_call, METH_FASTCALL,
     "golden_call(name, inputs) -> list: one flat entry of the golden vectors (vs_golden.c)."},
    {NULL, NULL, 0, NULL},
};
