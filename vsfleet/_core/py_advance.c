/* py_advance.c - binding of the core's advance functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"
#include "vs_advance.h"

static int get_double(PyObject *o, double *v)
{
    *v = PyFloat_AsDouble(o);
    return (*v == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* a tuple of exactly k floats into v */
static int get_tuple(PyObject *o, double *v, Py_ssize_t k, const char *name)
{
    if (!PyTuple_Check(o) || PyTuple_GET_SIZE(o) != k) {
        PyErr_Format(PyExc_TypeError, "%s must be a tuple of %zd floats", name, k);
        return -1;
    }
    for (Py_ssize_t i = 0; i < k; i++)
        if (get_double(PyTuple_GET_ITEM(o, i), &v[i]) < 0) return -1;
    return 0;
}

static const char advance_doc[] =
    "advance(x, y, th, kind, goal, dt_s, limits, template_xy, wheel_base_m, wheel_speed_max_m_s,\n"
    "        wheel_accel_max_m_s2, twist_prev, elapsed_s, headings_rad, deviations_m)\n"
    "-> (x, y, th, vx, vy, w, scale, at_goal)\n\n"
    "vs_advance (vs_advance.h). kind: 0 pose, 1 path, 2 twist; goal: float64 buffer of 3 * k doubles;\n"
    "limits: tuple of the 9 StructureLimits floats in field order; template_xy: float64 buffer of 2n;\n"
    "the wheel arrays: float64 buffers of n; twist_prev: (vx, vy, w) or None; elapsed_s: float or None;\n"
    "headings_rad, deviations_m: float64 buffers of n (NaN = unseen) or None.";

static PyObject *py_advance(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs != 15) {
        PyErr_SetString(PyExc_TypeError, "advance expects 15 arguments");
        return NULL;
    }
    double pose[3], dt_s, lim_v[9], prev[3], elapsed;
    for (int k = 0; k < 3; k++)
        if (get_double(args[k], &pose[k]) < 0) return NULL;
    long kind = PyLong_AsLong(args[3]);
    if (kind == -1 && PyErr_Occurred()) return NULL;
    if (get_double(args[5], &dt_s) < 0) return NULL;
    if (get_tuple(args[6], lim_v, 9, "limits") < 0) return NULL;
    int has_prev = args[11] != Py_None, has_elapsed = args[12] != Py_None;
    if (has_prev && get_tuple(args[11], prev, 3, "twist_prev") < 0) return NULL;
    if (has_elapsed && get_double(args[12], &elapsed) < 0) return NULL;

    Py_buffer views[7];
    int held = 0;
    PyObject *result = NULL;
    static const char *names[7] = {"goal", "template_xy", "wheel_base_m", "wheel_speed_max_m_s",
                                   "wheel_accel_max_m_s2", "headings_rad", "deviations_m"};
    PyObject *objs[7] = {args[4], args[7], args[8], args[9], args[10], args[13], args[14]};
    Py_ssize_t n = -1;
    for (int b = 0; b < 7; b++) {
        Py_ssize_t want = b >= 3 ? n : -1;   /* n is wheel_base_m's length */
        if (b >= 5 && objs[b] == Py_None) { views[b].buf = NULL; continue; }
        if (vs_py_doubles(objs[b], &views[b], want, 0, names[b]) < 0) goto done;
        held |= 1 << b;
        if (b == 2) n = views[b].len / 8;
    }
    Py_ssize_t n_goal = views[0].len / 8;
    if (n_goal % 3 != 0 || views[1].len / 8 != 2 * n) {
        PyErr_SetString(vs_ValueError, "advance: goal must hold 3 * k doubles and template_xy 2 * n");
        goto done;
    }
    vs_limits lim = {lim_v[0], lim_v[1], lim_v[2], lim_v[3], lim_v[4], lim_v[5], lim_v[6], lim_v[7], lim_v[8]};
    vs_goal goal = {(int)kind, (const double *)views[0].buf, (size_t)(n_goal / 3)};
    vs_advance_result out;
    int rc = vs_advance(pose, &goal, dt_s, &lim, views[1].buf, views[2].buf, views[3].buf, views[4].buf,
                        (size_t)n, has_prev ? prev : NULL, has_elapsed ? &elapsed : NULL,
                        views[5].buf, views[6].buf, &out);
    if (rc != VS_OK) {
        vs_py_error(rc, rc == VS_ENONFINITE
                    ? "advance: an input is NaN or infinite, or the result overflows (NaN marks an unseen "
                      "robot in headings_rad and deviations_m only)"
                    : "advance: a bad argument (goal kind or size, dt_s <= 0, limits < 0 or comply_stop_m <= "
                      "comply_full_m, envelope <= 0, n == 0)");
        goto done;
    }
    result = Py_BuildValue("(dddddddO)", out.x, out.y, out.th, out.vx_m_s, out.vy_m_s, out.w_rad_s, out.scale,
                           out.at_goal ? Py_True : Py_False);
done:
    for (int b = 0; b < 7; b++)
        if (held & (1 << b)) PyBuffer_Release(&views[b]);
    return result;
}

static PyObject *hypot2(PyObject *const *args, Py_ssize_t nargs, double (*f)(double, double))
{
    double x, y;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "expected 2 arguments"); return NULL; }
    if (get_double(args[0], &x) < 0 || get_double(args[1], &y) < 0) return NULL;
    return PyFloat_FromDouble(f(x, y));
}

static PyObject *py_hypot_libm(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return hypot2(a, n, vs_hypot_libm); }
static PyObject *py_hypot_cr(PyObject *m, PyObject *const *a, Py_ssize_t n) { (void)m; return hypot2(a, n, vs_hypot_cr); }

PyMethodDef vs_py_advance_methods[] = {
    {"advance", (PyCFunction)(void (*)(void))py_advance, METH_FASTCALL, advance_doc},
    {"hypot_libm", (PyCFunction)(void (*)(void))py_hypot_libm, METH_FASTCALL,
     "hypot_libm(x, y): as numpy's np.hypot (glibc's hypot), bit for bit."},
    {"hypot_cr", (PyCFunction)(void (*)(void))py_hypot_cr, METH_FASTCALL,
     "hypot_cr(x, y): as Python's math.hypot (correctly rounded), bit for bit."},
    {NULL, NULL, 0, NULL},
};
