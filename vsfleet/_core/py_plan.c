/* py_plan.c - binding of the core's structure planner (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"
#include "vs_plan.h"

static int get_double(PyObject *o, double *v)
{
    *v = PyFloat_AsDouble(o);
    return (*v == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static const char plan_doc[] =
    "plan_structure(template_xy, radius_m, margin_m, obstacles, start, goal, out) -> (n_waypoints, status)\n\n"
    "vs_plan_structure (vs_plan.h). template_xy: float64 buffer of 2n; radius_m: of n; margin_m: float;\n"
    "obstacles: float64 buffer of 3m (x, y, r); start, goal: float64 buffers of 3; out: writable float64\n"
    "buffer of 3 * cap. status: 0 path to the goal, 1 blocked; status None: out is too small, nothing was\n"
    "written, n_waypoints is the count needed (call again with a larger out).";

static PyObject *py_plan_structure(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "plan_structure expects 7 arguments");
        return NULL;
    }
    double margin;
    if (get_double(args[2], &margin) < 0) return NULL;
    Py_buffer views[6];
    int held = 0;
    PyObject *result = NULL;
    static const char *names[6] = {"template_xy", "radius_m", "obstacles", "start", "goal", "out"};
    PyObject *objs[6] = {args[0], args[1], args[3], args[4], args[5], args[6]};
    static const Py_ssize_t want[6] = {-1, -1, -1, 3, 3, -1};
    for (int b = 0; b < 6; b++) {
        if (vs_py_doubles(objs[b], &views[b], want[b], b == 5, names[b]) < 0) goto done;
        held |= 1 << b;
    }
    Py_ssize_t n = views[1].len / 8, n_obs = views[2].len / 8, cap = views[5].len / 8;
    if (views[0].len / 8 != 2 * n || n_obs % 3 != 0 || cap % 3 != 0) {
        PyErr_SetString(vs_ValueError, "plan_structure: template_xy must hold 2n doubles, radius_m n, "
                        "obstacles 3m, out 3 * cap");
        goto done;
    }
    size_t n_wp = 0;
    int status = 0;
    int rc = vs_plan_structure(views[0].buf, views[1].buf, (size_t)n, margin, views[2].buf, (size_t)(n_obs / 3),
                               views[3].buf, views[4].buf, views[5].buf, (size_t)(cap / 3), &n_wp, &status);
    if (rc == VS_ENOMEM && n_wp > (size_t)(cap / 3)) {
        result = Py_BuildValue("(nO)", (Py_ssize_t)n_wp, Py_None);
    } else if (rc != VS_OK) {
        vs_py_error(rc, rc == VS_ENONFINITE
                    ? "plan_structure: an input is NaN or infinite"
                    : "plan_structure: a bad argument (n == 0, a radius or the margin < 0, an obstacle radius "
                      "<= 0, more than 256 obstacles, a value beyond 1e6 m, or an empty out)");
    } else {
        result = Py_BuildValue("(ni)", (Py_ssize_t)n_wp, status);
    }
done:
    for (int b = 0; b < 6; b++)
        if (held & (1 << b)) PyBuffer_Release(&views[b]);
    return result;
}

PyMethodDef vs_py_plan_methods[] = {
    {"plan_structure", (PyCFunction)(void (*)(void))py_plan_structure, METH_FASTCALL, plan_doc},
    {NULL, NULL, 0, NULL},
};
