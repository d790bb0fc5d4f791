#include "py_util.h"
#include "vscore.h"

PyObject *vs_NonFiniteError = NULL;
PyObject *vs_ValueError = NULL;

int vs_py_doubles(PyObject *obj, Py_buffer *view, Py_ssize_t n_expected, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s float64 buffer", name,
                     writable ? " writable" : "");
        return -1;
    }
    if (view->itemsize != 8 || view->format == NULL || (view->format[0] != 'd' && !(view->format[0] == '<'
            && view->format[1] == 'd') && !(view->format[0] == '=' && view->format[1] == 'd'))) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "%s must hold float64", name);
        return -1;
    }
    Py_ssize_t n = view->len / 8;
    if (n_expected >= 0 && n != n_expected) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "%s must hold %zd doubles, got %zd", name, n_expected, n);
        return -1;
    }
    return 0;
}

PyObject *vs_py_error(int code, const char *what)
{
    PyObject *type = code == VS_ENONFINITE ? vs_NonFiniteError
                   : code == VS_ENOMEM ? PyExc_MemoryError : vs_ValueError;
    if (type == NULL) type = PyExc_ValueError;
    PyErr_Format(type, "%s (core error %d)", what, code);
    return NULL;
}

int vs_py_flags(PyObject *obj, Py_buffer *view, Py_ssize_t n_expected, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s bool/uint8 buffer", name,
                     writable ? " writable" : "");
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (view->itemsize != 1 || !(f[0] == '?' || f[0] == 'B' || f[0] == 'b')) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "%s must hold bool or uint8", name);
        return -1;
    }
    if (n_expected >= 0 && view->len != n_expected) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "%s must hold %zd flags, got %zd", name, n_expected, view->len);
        return -1;
    }
    return 0;
}
