/* py_failure.c - binding of the core's failure functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"
#include "vs_failure.h"

enum { BUF_F64, BUF_BOOL, BUF_I64 };

/* A C-contiguous buffer of count items of the kind (float64, bool, int64), or -1 with an error set. */
static int get_buf(PyObject *obj, Py_buffer *view, int kind, Py_ssize_t count, int writable, const char *name)
{
    if (kind == BUF_F64) {
        if (vs_py_doubles(obj, view, -1, writable, name) < 0) return -1;
        if (view->len / 8 != count) {
            PyErr_Format(vs_ValueError, "failure_step: %s must hold %zd values, got %zd", name, count, view->len / 8);
            PyBuffer_Release(view);
            return -1;
        }
        return 0;
    }
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s %s buffer", name, writable ? " writable" : "",
                     kind == BUF_BOOL ? "bool" : "int64");
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    int ok = kind == BUF_BOOL ? (view->itemsize == 1 && f[0] == '?' && f[1] == 0)
                              : (view->itemsize == 8 && (f[0] == 'q' || f[0] == 'l') && f[1] == 0);
    if (!ok) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "%s must hold %s", name, kind == BUF_BOOL ? "bool" : "int64");
        return -1;
    }
    if (view->len / view->itemsize != count) {
        PyErr_Format(vs_ValueError, "failure_step: %s must hold %zd values, got %zd", name, count,
                     view->len / view->itemsize);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static int policy_double(PyObject *policy, const char *name, double *out)
{
    PyObject *v = PyObject_GetAttrString(policy, name);
    if (v == NULL) return -1;
    *out = PyFloat_AsDouble(v);
    Py_DECREF(v);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* vsfleet.failure.FailurePolicy -> vs_failure_policy; min_expected_m2 is Python's min_expected_m ** 2,
 * as the reference computes it. */
static int read_policy(PyObject *policy, vs_failure_policy *p)
{
    PyObject *mode = PyObject_GetAttrString(policy, "mode");
    if (mode == NULL) return -1;
    p->mode = -1;
    if (PyUnicode_Check(mode)) {
        if (PyUnicode_CompareWithASCIIString(mode, "hold") == 0) p->mode = VS_FAILURE_HOLD;
        else if (PyUnicode_CompareWithASCIIString(mode, "drop") == 0) p->mode = VS_FAILURE_DROP;
        else if (PyUnicode_CompareWithASCIIString(mode, "rejoin") == 0) p->mode = VS_FAILURE_REJOIN;
    }
    Py_DECREF(mode);
    if (p->mode < 0) { vs_py_error(VS_EVALUE, "failure_step: on_failure must be hold, drop or rejoin"); return -1; }
    if (policy_double(policy, "fail_deviation_m", &p->fail_deviation_m) < 0
        || policy_double(policy, "fail_after_s", &p->fail_after_s) < 0
        || policy_double(policy, "rejoin_deviation_m", &p->rejoin_deviation_m) < 0
        || policy_double(policy, "rejoin_after_s", &p->rejoin_after_s) < 0
        || policy_double(policy, "recover_after_s", &p->recover_after_s) < 0
        || policy_double(policy, "min_progress_ratio", &p->min_progress_ratio) < 0
        || policy_double(policy, "min_approach_m", &p->min_approach_m) < 0)
        return -1;
    PyObject *m = PyObject_GetAttrString(policy, "min_expected_m");
    if (m == NULL) return -1;
    PyObject *two = PyLong_FromLong(2);
    PyObject *sq = two ? PyNumber_Power(m, two, Py_None) : NULL;
    Py_DECREF(m);
    Py_XDECREF(two);
    if (sq == NULL) return -1;
    p->min_expected_m2 = PyFloat_AsDouble(sq);
    Py_DECREF(sq);
    return (p->min_expected_m2 == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

#define N_BUF 17
#define N_ARGS 22

/* failure_step(policy, t, seen, fresh, xy_world, deviations_m, expected_step_m, step_s, max_gap_s,
 *              since_t, failed, dropped, last_t, last_xy, last_expected, window_t, window_nm, head,
 *              in_window, sums_nm, window_dev_m, held) -> tuple of (row, kind code, deviation_m)
 * The state arrays (since_t .. window_dev_m, 12) are updated in place; step_s None = not scaled;
 * held (n) bool or None (none). */
static PyObject *py_failure_step(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != N_ARGS) {
        PyErr_Format(PyExc_TypeError, "failure_step expects %d arguments, got %zd", N_ARGS, nargs);
        return NULL;
    }
    vs_failure_policy pol;
    if (read_policy(args[0], &pol) < 0) return NULL;
    double t = PyFloat_AsDouble(args[1]);
    if (t == -1.0 && PyErr_Occurred()) return NULL;
    double step_s = 0.0;
    if (args[7] != Py_None) {
        step_s = PyFloat_AsDouble(args[7]);
        if (step_s == -1.0 && PyErr_Occurred()) return NULL;
        if (step_s == 0.0) return vs_py_error(VS_EVALUE, "failure_step: step_s must be > 0 or None");
    }
    double max_gap_s = PyFloat_AsDouble(args[8]);
    if (max_gap_s == -1.0 && PyErr_Occurred()) return NULL;

    /* the window's width from window_t's shape (n, W) */
    Py_buffer views[N_BUF];
    int got = 0;
    PyObject *result = NULL;
    vs_failure_decision *dec = NULL;
    Py_buffer wt;
    if (vs_py_doubles(args[15], &wt, -1, 1, "window_t") < 0) return NULL;
    if (wt.ndim != 2) {
        PyBuffer_Release(&wt);
        return vs_py_error(VS_EVALUE, "failure_step: window_t must be (n, W)");
    }
    const Py_ssize_t n = wt.shape[0], W = wt.shape[1];
    PyBuffer_Release(&wt);
    if (W < 1) return vs_py_error(VS_EVALUE, "failure_step: the window needs a slot");

    static const struct { int arg, kind, per_row, writable; const char *name; } spec[N_BUF] = {
        {2, BUF_BOOL, 1, 0, "seen"}, {3, BUF_BOOL, 1, 0, "fresh"}, {4, BUF_F64, 2, 0, "xy_world"},
        {5, BUF_F64, 1, 0, "deviations_m"}, {6, BUF_F64, 2, 0, "expected_step_m"},
        {9, BUF_F64, 1, 1, "since_t"}, {10, BUF_BOOL, 1, 1, "failed"}, {11, BUF_BOOL, 1, 1, "dropped"},
        {12, BUF_F64, 1, 1, "last_t"}, {13, BUF_F64, 2, 1, "last_xy"}, {14, BUF_F64, 2, 1, "last_expected"},
        {15, BUF_F64, -1, 1, "window_t"}, {16, BUF_I64, -4, 1, "window_nm"}, {17, BUF_I64, 1, 1, "head"},
        {18, BUF_BOOL, -1, 1, "in_window"}, {19, BUF_I64, 4, 1, "sums_nm"}, {20, BUF_F64, -1, 1, "window_dev_m"},
    };
    Py_buffer held;
    int has_held = 0;
    for (; got < N_BUF; got++) {
        Py_ssize_t per = spec[got].per_row < 0 ? -spec[got].per_row * W : spec[got].per_row;
        if (get_buf(args[spec[got].arg], &views[got], spec[got].kind, n * per, spec[got].writable,
                    spec[got].name) < 0)
            goto done;
    }
    if (args[21] != Py_None) {
        if (get_buf(args[21], &held, BUF_BOOL, n, 0, "held") < 0) goto done;
        has_held = 1;
    }
    vs_failure_state s = {
        (size_t)n, (size_t)W, views[5].buf, views[6].buf, views[7].buf, views[8].buf, views[9].buf,
        views[10].buf, views[11].buf, views[12].buf, views[13].buf, views[14].buf, views[15].buf,
        views[16].buf,
    };
    vs_failure_input in = {t, views[0].buf, views[1].buf, views[2].buf, views[3].buf, views[4].buf, step_s,
                           max_gap_s, has_held ? held.buf : NULL};
    size_t cap = 2 * (size_t)n, count = 0;
    dec = PyMem_Malloc((cap ? cap : 1) * sizeof *dec);
    if (dec == NULL) { PyErr_NoMemory(); goto done; }
    int rc = vs_failure_step(&pol, &s, &in, dec, cap, &count);
    if (rc != VS_OK) {
        vs_py_error(rc, rc == VS_ENONFINITE ? "failure_step: t, a seen deviation, or a fresh position or "
                                              "expected step is not finite"
                                            : "failure_step: bad argument (policy, step_s, max_gap_s, or a "
                                              "position or step beyond 1e9 m)");
        goto done;
    }
    result = PyTuple_New((Py_ssize_t)count);
    if (result == NULL) goto done;
    for (size_t k = 0; k < count; k++) {
        PyObject *item = Py_BuildValue("(nid)", (Py_ssize_t)dec[k].row, dec[k].kind, dec[k].deviation_m);
        if (item == NULL) { Py_CLEAR(result); goto done; }
        PyTuple_SET_ITEM(result, (Py_ssize_t)k, item);
    }
done:
    PyMem_Free(dec);
    for (int k = 0; k < got; k++) PyBuffer_Release(&views[k]);
    if (has_held) PyBuffer_Release(&held);
    return result;
}

PyMethodDef vs_py_failure_methods[] = {
    {"failure_step", (PyCFunction)(void (*)(void))py_failure_step, METH_FASTCALL,
     "failure_step(policy, t, seen, fresh, xy_world, deviations_m, expected_step_m, step_s, max_gap_s, "
     "since_t, failed, dropped, last_t, last_xy, last_expected, window_t, window_nm, head, in_window, "
     "sums_nm, window_dev_m, held) -> ((row, kind code, deviation_m), ...): one frame of the failure rule "
     "(vs_failure.h); the twelve state arrays are updated in place (held: bool (n) or None). Kind codes in vsfleet.wire.EVENT_KINDS order."},
    {NULL, NULL, 0, NULL},
};
