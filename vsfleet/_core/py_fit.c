/* py_fit.c - binding of the core's fit functions (vsfleet._core): fit, fit_residuals, fit_cost. */
#include "py_util.h"
#include "vscore.h"
#include "vs_fit.h"

/* template and positions: (n, 2) float64 C-contiguous, n >= 1; weights None or (n,) */
static int get_pr(PyObject *po, PyObject *ro, Py_buffer *pv, Py_buffer *rv, Py_ssize_t *n)
{
    if (vs_py_doubles(po, pv, -1, 0, "template_xy") < 0) return -1;
    Py_ssize_t k = pv->len / 8;
    if (k % 2 != 0) {
        PyBuffer_Release(pv);
        PyErr_SetString(vs_ValueError, "template_xy must hold n*2 doubles");
        return -1;
    }
    if (vs_py_doubles(ro, rv, k, 0, "positions_xy") < 0) { PyBuffer_Release(pv); return -1; }
    *n = k / 2;
    return 0;
}

static int get_w(PyObject *wo, Py_buffer *wv, Py_ssize_t n, const double **w)
{
    *w = NULL;
    if (wo == Py_None) return 0;
    if (vs_py_doubles(wo, wv, n, 0, "weights") < 0) return -1;
    *w = (const double *)wv->buf;
    return 1;
}

static int get_metric(PyObject *o, int *metric)
{
    long m = PyLong_AsLong(o);
    if (m == -1 && PyErr_Occurred()) return -1;
    if (m < VS_METRIC_L1 || m > VS_METRIC_LINF) {
        PyErr_SetString(vs_ValueError, "metric must be 0 (l1), 1 (l2) or 2 (linf)");
        return -1;
    }
    *metric = (int)m;
    return 0;
}

/* fit(template_xy, positions_xy, weights|None, metric, residuals_out|None)
 *   -> (x, y, th, cost, cost_lower_bound, rounds) */
static PyObject *py_fit(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "fit(template_xy, positions_xy, weights, metric, residuals_out)");
        return NULL;
    }
    int metric;
    if (get_metric(args[3], &metric) < 0) return NULL;
    Py_buffer pv, rv, wv, dv;
    Py_ssize_t n;
    if (get_pr(args[0], args[1], &pv, &rv, &n) < 0) return NULL;
    const double *w;
    int hw = get_w(args[2], &wv, n, &w);
    if (hw < 0) { PyBuffer_Release(&pv); PyBuffer_Release(&rv); return NULL; }
    int hd = 0;
    if (args[4] != Py_None) {
        if (vs_py_doubles(args[4], &dv, n, 1, "residuals_out") < 0) {
            PyBuffer_Release(&pv); PyBuffer_Release(&rv);
            if (hw) PyBuffer_Release(&wv);
            return NULL;
        }
        hd = 1;
    }
    vs_fit_result res;
    int rc = vs_fit((const double *)pv.buf, (const double *)rv.buf, w, (size_t)n, metric, &res);
    if (rc == VS_OK && hd)
        rc = vs_fit_residuals((const double *)pv.buf, (const double *)rv.buf, (size_t)n, res.x, res.y, res.th,
                              (double *)dv.buf);
    PyBuffer_Release(&pv); PyBuffer_Release(&rv);
    if (hw) PyBuffer_Release(&wv);
    if (hd) PyBuffer_Release(&dv);
    if (rc != VS_OK) return vs_py_error(rc, "vs_fit");
    return Py_BuildValue("(dddddi)", res.x, res.y, res.th, res.cost, res.cost_lower_bound, res.rounds);
}

/* fit_residuals(template_xy, positions_xy, x, y, th, residuals_out) -> None */
static PyObject *py_residuals(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "fit_residuals(template_xy, positions_xy, x, y, th, residuals_out)");
        return NULL;
    }
    double x = PyFloat_AsDouble(args[2]), y = PyFloat_AsDouble(args[3]), th = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred()) return NULL;
    Py_buffer pv, rv, dv;
    Py_ssize_t n;
    if (get_pr(args[0], args[1], &pv, &rv, &n) < 0) return NULL;
    if (vs_py_doubles(args[5], &dv, n, 1, "residuals_out") < 0) {
        PyBuffer_Release(&pv); PyBuffer_Release(&rv);
        return NULL;
    }
    int rc = vs_fit_residuals((const double *)pv.buf, (const double *)rv.buf, (size_t)n, x, y, th, (double *)dv.buf);
    PyBuffer_Release(&pv); PyBuffer_Release(&rv); PyBuffer_Release(&dv);
    if (rc != VS_OK) return vs_py_error(rc, "vs_fit_residuals");
    Py_RETURN_NONE;
}

/* fit_cost(template_xy, positions_xy, weights|None, metric, x, y, th) -> cost (the residuals in C) */
static PyObject *py_cost(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "fit_cost(template_xy, positions_xy, weights, metric, x, y, th)");
        return NULL;
    }
    int metric;
    if (get_metric(args[3], &metric) < 0) return NULL;
    double x = PyFloat_AsDouble(args[4]), y = PyFloat_AsDouble(args[5]), th = PyFloat_AsDouble(args[6]);
    if (PyErr_Occurred()) return NULL;
    Py_buffer pv, rv, wv;
    Py_ssize_t n;
    if (get_pr(args[0], args[1], &pv, &rv, &n) < 0) return NULL;
    const double *w;
    int hw = get_w(args[2], &wv, n, &w);
    if (hw < 0) { PyBuffer_Release(&pv); PyBuffer_Release(&rv); return NULL; }
    double cost = 0.0;
    int rc = VS_EVALUE;
    double *d = n > 0 ? PyMem_Malloc((size_t)n * sizeof(double)) : NULL;
    if (n > 0 && d == NULL) rc = VS_ENOMEM;
    else if (n > 0) {
        rc = vs_fit_residuals((const double *)pv.buf, (const double *)rv.buf, (size_t)n, x, y, th, d);
        if (rc == VS_OK) rc = vs_fit_cost(d, w, (size_t)n, metric, &cost);
    }
    PyMem_Free(d);
    PyBuffer_Release(&pv); PyBuffer_Release(&rv);
    if (hw) PyBuffer_Release(&wv);
    if (rc != VS_OK) return vs_py_error(rc, "vs_fit_cost");
    return PyFloat_FromDouble(cost);
}

PyMethodDef vs_py_fit_methods[] = {
    {"fit", (PyCFunction)(void (*)(void))py_fit, METH_FASTCALL,
     "fit(template_xy, positions_xy, weights|None, metric 0/1/2 (l1/l2/linf), residuals_out|None)"
     " -> (x, y, th, cost, cost_lower_bound, rounds): vs_fit."},
    {"fit_residuals", (PyCFunction)(void (*)(void))py_residuals, METH_FASTCALL,
     "fit_residuals(template_xy, positions_xy, x, y, th, residuals_out): d_i [m] written into residuals_out."},
    {"fit_cost", (PyCFunction)(void (*)(void))py_cost, METH_FASTCALL,
     "fit_cost(template_xy, positions_xy, weights|None, metric, x, y, th) -> the cost at the pose [weighted m]."},
    {NULL, NULL, 0, NULL},
};
