/* py_wire.c - binding of the frame decoder (vs_wire.h): vsfleet._core.decode_frame.
 *
 * decode_frame(payload, src=None) -> (t, seq, src, ids, poses)
 *   t float [s, tracker clock]; seq int; src str; ids a tuple of str in the order sent; poses bytes
 *   of 3 * len(ids) native float64 (x, y, th per robot) [m, m, rad; world], so
 *   memoryview(poses).cast("d") or numpy.frombuffer(poses) reads them.  src (a str): the key's last
 *   chunk, which the frame's src must equal.  A frame vsfleet.wire.decode_frame refuses raises
 *   vsfleet.wire.WireError (a ValueError) with one short reason.
 *
 * encode_cmd(t, seq, vl, vr, ttl) -> bytes
 * encode_state(t, seq, x, y, th, gx, gy, gth, cost, err, used, rejected, complete=True, mission=-1,
 *              shape=0, v=PROTOCOL_V) -> bytes
 *   The agent's messages as vsfleet.wire.encode(CmdMsg(...)) and encode(StateMsg(...)) write them, byte
 *   for byte (vs_wire.h): positional arguments in the dataclass's field order.  Only arguments whose
 *   bytes equal encode's are taken: a float field takes a float (a subclass too, numpy.float64), never
 *   an int (encode would write an integer); an integer field an int, never a bool; complete a bool;
 *   used a tuple or list of str.  Anything else raises TypeError; an integer beyond the C field's
 *   range (seq, rejected: [0, 2^64); mission, shape, v: [-2^63, 2^63)) raises ValueError.
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

/* ---------------------------------------------------------------- the encoders' arguments */

static PyObject *range_error(void)
{
    return vs_ValueError != NULL ? vs_ValueError : PyExc_ValueError;
}

/* A float argument (float or a subclass: what msgpack-python packs as float64). 0, or -1 with TypeError. */
static int arg_f64(PyObject *o, const char *fn, const char *name, double *out)
{
    if (!PyFloat_Check(o)) {
        PyErr_Format(PyExc_TypeError, "%s: %s must be a float, got %s", fn, name, Py_TYPE(o)->tp_name);
        return -1;
    }
    *out = PyFloat_AS_DOUBLE(o);
    return 0;
}

/* An int argument (not a bool: msgpack-python packs True as true, not 1). */
static int arg_int(PyObject *o, const char *fn, const char *name)
{
    if (!PyLong_Check(o) || PyBool_Check(o)) {
        PyErr_Format(PyExc_TypeError, "%s: %s must be an int, got %s", fn, name, Py_TYPE(o)->tp_name);
        return -1;
    }
    return 0;
}

static int arg_u64(PyObject *o, const char *fn, const char *name, uint64_t *out)
{
    if (arg_int(o, fn, name) < 0) return -1;
    unsigned long long v = PyLong_AsUnsignedLongLong(o);   /* OverflowError when negative or too large */
    if (v == (unsigned long long)-1 && PyErr_Occurred()) {
        if (!PyErr_ExceptionMatches(PyExc_OverflowError)) return -1;
        PyErr_Clear();
        PyErr_Format(range_error(), "%s: %s must be in [0, 2^64), got %R", fn, name, o);
        return -1;
    }
    *out = (uint64_t)v;
    return 0;
}

static int arg_i64(PyObject *o, const char *fn, const char *name, int64_t *out)
{
    if (arg_int(o, fn, name) < 0) return -1;
    int overflow = 0;
    long long v = PyLong_AsLongLongAndOverflow(o, &overflow);
    if (v == -1 && PyErr_Occurred()) return -1;
    if (overflow != 0) {
        PyErr_Format(range_error(), "%s: %s must be in [-2^63, 2^63), got %R", fn, name, o);
        return -1;
    }
    *out = (int64_t)v;
    return 0;
}

static int arg_bool(PyObject *o, const char *fn, const char *name, int *out)
{
    if (!PyBool_Check(o)) {
        PyErr_Format(PyExc_TypeError, "%s: %s must be a bool, got %s", fn, name, Py_TYPE(o)->tp_name);
        return -1;
    }
    *out = o == Py_True;
    return 0;
}

/* ---------------------------------------------------------------- the encoders */

static PyObject *py_encode_cmd(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    static const char fn[] = "encode_cmd";
    unsigned char buf[VS_WIRE_CMD_MAX_BYTES];
    double t, vl, vr, ttl;
    uint64_t seq;
    if (nargs != 5) { PyErr_SetString(PyExc_TypeError, "encode_cmd(t, seq, vl, vr, ttl) takes 5 arguments"); return NULL; }
    if (arg_f64(a[0], fn, "t", &t) < 0 || arg_u64(a[1], fn, "seq", &seq) < 0 || arg_f64(a[2], fn, "vl", &vl) < 0
            || arg_f64(a[3], fn, "vr", &vr) < 0 || arg_f64(a[4], fn, "ttl", &ttl) < 0)
        return NULL;
    size_t n = vs_wire_encode_cmd(t, seq, vl, vr, ttl, buf, sizeof buf);
    if (n == 0) return vs_py_error(VS_ENOMEM, "encode_cmd: the message does not fit its bound");
    return PyBytes_FromStringAndSize((const char *)buf, (Py_ssize_t)n);
}

static PyObject *py_encode_state(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    static const char fn[] = "encode_state";
    static const char *const names[] = {"t", "seq", "x", "y", "th", "gx", "gy", "gth", "cost", "err", "used",
                                        "rejected", "complete", "mission", "shape", "v"};
    enum { STACK_IDS = 1000, STACK_BYTES = 4096 };   /* most states: no allocation here either */
    vs_wire_str ids_stack[STACK_IDS];
    unsigned char buf_stack[STACK_BYTES];
    vs_wire_state s;
    double *floats[] = {&s.t, NULL, &s.x, &s.y, &s.th, &s.gx, &s.gy, &s.gth, &s.cost, &s.err};
    if (nargs < 12 || nargs > 16) {
        PyErr_SetString(PyExc_TypeError, "encode_state(t, seq, x, y, th, gx, gy, gth, cost, err, used, rejected, "
                                         "complete=True, mission=-1, shape=0, v=PROTOCOL_V) takes 12 to 16 arguments");
        return NULL;
    }
    for (int k = 0; k < 10; k++)
        if (k != 1 && arg_f64(a[k], fn, names[k], floats[k]) < 0) return NULL;
    s.complete = 1;
    s.mission = -1;
    s.shape = 0;
    s.v = VS_WIRE_PROTOCOL_V;
    if (arg_u64(a[1], fn, "seq", &s.seq) < 0 || arg_u64(a[11], fn, "rejected", &s.rejected) < 0
            || (nargs > 12 && arg_bool(a[12], fn, "complete", &s.complete) < 0)
            || (nargs > 13 && arg_i64(a[13], fn, "mission", &s.mission) < 0)
            || (nargs > 14 && arg_i64(a[14], fn, "shape", &s.shape) < 0)
            || (nargs > 15 && arg_i64(a[15], fn, "v", &s.v) < 0))
        return NULL;
    if (!PyTuple_Check(a[10]) && !PyList_Check(a[10])) {
        PyErr_Format(PyExc_TypeError, "%s: used must be a tuple or list of str, got %s", fn, Py_TYPE(a[10])->tp_name);
        return NULL;
    }
    PyObject *used = PySequence_Fast(a[10], "used");   /* the same object, held: no Python code runs below */
    if (used == NULL) return NULL;
    Py_ssize_t n_used = PySequence_Fast_GET_SIZE(used);
    PyObject **items = PySequence_Fast_ITEMS(used);
    vs_wire_str *ids = n_used <= STACK_IDS ? ids_stack : PyMem_Malloc((size_t)n_used * sizeof *ids);
    unsigned char *buf = NULL;
    PyObject *out = NULL;
    size_t id_bytes = 0, cap, n;
    if (ids == NULL) { PyErr_NoMemory(); goto done; }
    for (Py_ssize_t j = 0; j < n_used; j++) {
        if (!PyUnicode_Check(items[j])) {
            PyErr_Format(PyExc_TypeError, "%s: used[%zd] must be a str, got %s", fn, j, Py_TYPE(items[j])->tp_name);
            goto done;
        }
        Py_ssize_t len;
        const char *utf8 = PyUnicode_AsUTF8AndSize(items[j], &len);   /* kept by the str: no copy to free */
        if (utf8 == NULL) goto done;
        ids[j].s = (const unsigned char *)utf8;
        ids[j].len = (size_t)len;
        id_bytes += (size_t)len;
    }
    s.used = ids;
    s.n_used = (size_t)n_used;
    cap = VS_WIRE_STATE_MAX_BYTES((size_t)n_used, id_bytes);
    buf = cap <= STACK_BYTES ? buf_stack : PyMem_Malloc(cap);
    if (buf == NULL) { PyErr_NoMemory(); goto done; }
    n = vs_wire_encode_state(&s, buf, cap);
    if (n == 0) vs_py_error(VS_ENOMEM, "encode_state: the message does not fit its bound (an id over 2^32 - 1 bytes?)");
    else out = PyBytes_FromStringAndSize((const char *)buf, (Py_ssize_t)n);
done:
    if (buf != NULL && buf != buf_stack) PyMem_Free(buf);
    if (ids != NULL && ids != ids_stack) PyMem_Free(ids);
    Py_DECREF(used);
    return out;
}

PyMethodDef vs_py_wire_methods[] = {
    {"decode_frame", (PyCFunction)(void (*)(void))py_decode_frame, METH_FASTCALL,
     "decode_frame(payload, src=None) -> (t, seq, src, ids, poses): a tracker frame checked as "
     "vsfleet.wire.decode_frame checks it; poses: bytes of 3 float64 per robot. WireError if refused."},
    {"encode_cmd", (PyCFunction)(void (*)(void))py_encode_cmd, METH_FASTCALL,
     "encode_cmd(t, seq, vl, vr, ttl) -> bytes: vsfleet.wire.encode(CmdMsg(t, seq, vl, vr, ttl)), byte for byte "
     "(positional, CmdMsg's field order). t, vl, vr, ttl floats [s, m/s, m/s, s]; seq an int in [0, 2^64). "
     "TypeError for another type (an int for a float too), ValueError out of range."},
    {"encode_state", (PyCFunction)(void (*)(void))py_encode_state, METH_FASTCALL,
     "encode_state(t, seq, x, y, th, gx, gy, gth, cost, err, used, rejected, complete=True, mission=-1, shape=0, "
     "v=PROTOCOL_V) -> bytes: vsfleet.wire.encode(StateMsg(...)) with the same values, byte for byte (positional, "
     "StateMsg's field order). Floats: t [s], x, y, th, gx, gy, gth [m, m, rad; world], cost, err [m]; used a tuple "
     "or list of str; seq, rejected ints in [0, 2^64); complete a bool; mission, shape, v ints in [-2^63, 2^63). "
     "TypeError for another type (an int for a float too), ValueError out of range."},
    {NULL, NULL, 0, NULL}};
