/* py_wire.c - binding of the frame decoder (vs_wire.h): vsfleet._core.decode_frame.
 *
 * decode_frame(payload, src=None) -> (t, seq, src, ids, poses)
 *   t float [s, tracker clock]; seq int; src str; ids a tuple of str in the order sent; poses bytes
 *   of 3 * len(ids) native float64 (x, y, th per robot) [m, m, rad; world], so
 *   memoryview(poses).cast("d") or numpy.frombuffer(poses) reads them.  src (a str): the key's last
 *   chunk, which the frame's src must equal.  A frame vsfleet.wire.decode_frame refuses raises
 *   vsfleet.wire.WireError (a ValueError) with one short reason.
 */
#include <string.h>

#include "py_util.h"
#include "vscore.h"
#include "vs_wire.h"

/* vsfleet.wire.WireError, looked up on the first refusal (vsfleet.wire imports this module's
 * package, so not at import time); VsfleetValueError, its base class, if that fails. */
static PyObject *wire_error(void)
{
    static PyObject *cls = NULL;
    if (cls == NULL) {
        PyObject *wire = PyImport_ImportModule("vsfleet.wire");
        if (wire != NULL) {
            cls = PyObject_GetAttrString(wire, "WireError");
            Py_DECREF(wire);
        }
        if (cls == NULL) {
            PyErr_Clear();
            return vs_ValueError != NULL ? vs_ValueError : PyExc_ValueError;
        }
    }
    return cls;
}

static PyObject *refused(const unsigned char *payload, const vs_wire_slice *ids, const vs_wire_error *err)
{
    PyObject *cls = wire_error();
    if (err->robot >= 0) {
        const vs_wire_slice *id = &ids[err->robot];
        PyObject *name = PyUnicode_DecodeASCII((const char *)payload + id->off, id->len, "strict");
        if (name == NULL) return NULL;
        PyErr_Format(cls, "frame: field '%s', robot %R: %s", err->field, name, err->why);
        Py_DECREF(name);
    } else if (strcmp(err->field, "payload") == 0) {
        PyErr_Format(cls, "frame: %s (byte %zu)", err->why, err->at);
    } else {
        PyErr_Format(cls, "frame: field '%s': %s", err->field, err->why);
    }
    return NULL;
}

static PyObject *py_decode_frame(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    vs_wire_slice ids[VS_WIRE_MAX_ROBOTS];
    double poses[3 * VS_WIRE_MAX_ROBOTS];
    if (nargs < 1 || nargs > 2) { PyErr_SetString(PyExc_TypeError, "decode_frame(payload, src=None)"); return NULL; }
    PyObject *obj = a[0];
    if (!PyBytes_Check(obj) && !PyByteArray_Check(obj) && !PyMemoryView_Check(obj)) {
        PyErr_Format(wire_error(), "frame: payload must be bytes, got %s", Py_TYPE(obj)->tp_name);
        return NULL;
    }
    const char *want = NULL;
    Py_ssize_t want_len = 0;
    if (nargs == 2 && a[1] != Py_None) {
        want = PyUnicode_AsUTF8AndSize(a[1], &want_len);
        if (want == NULL) return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_SIMPLE) < 0) return NULL;
    const unsigned char *payload = view.buf;
    vs_frame frame;
    vs_wire_error err;
    int rc = vs_wire_decode_frame(payload, (size_t)view.len, (const unsigned char *)want, (size_t)want_len,
                                  ids, poses, VS_WIRE_MAX_ROBOTS, &frame, &err);
    PyObject *out = NULL, *t = NULL, *seq = NULL, *src = NULL, *names = NULL, *xyth = NULL;
    if (rc != VS_OK) {
        refused(payload, ids, &err);
        goto done;
    }
    t = PyFloat_FromDouble(frame.t);
    seq = PyLong_FromUnsignedLongLong((unsigned long long)frame.seq);
    src = PyUnicode_DecodeASCII((const char *)payload + frame.src.off, frame.src.len, "strict");
    names = PyTuple_New((Py_ssize_t)frame.n);
    xyth = PyBytes_FromStringAndSize((const char *)poses, (Py_ssize_t)(3 * frame.n * sizeof(double)));
    if (t == NULL || seq == NULL || src == NULL || names == NULL || xyth == NULL) goto done;
    for (size_t j = 0; j < frame.n; j++) {
        PyObject *name = PyUnicode_DecodeASCII((const char *)payload + ids[j].off, ids[j].len, "strict");
        if (name == NULL) goto done;
        PyTuple_SET_ITEM(names, (Py_ssize_t)j, name);
    }
    out = PyTuple_Pack(5, t, seq, src, names, xyth);
done:
    Py_XDECREF(t);
    Py_XDECREF(seq);
    Py_XDECREF(src);
    Py_XDECREF(names);
    Py_XDECREF(xyth);
    PyBuffer_Release(&view);
    return out;
}

PyMethodDef vs_py_wire_methods[] = {
    {"decode_frame", (PyCFunction)(void (*)(void))py_decode_frame, METH_FASTCALL,
     "decode_frame(payload, src=None) -> (t, seq, src, ids, poses): a tracker frame checked as "
     "vsfleet.wire.decode_frame checks it; poses: bytes of 3 float64 per robot. WireError if refused."},
    {NULL, NULL, 0, NULL}};
