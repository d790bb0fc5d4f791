/* py_field.c - binding of the structure's navigation function (vs_field.h): vsfleet._core.field_build,
 * field_info, field_costs, field_follow.  A field is a capsule that owns its lattice (freed with it). */
#include <string.h>

#include "py_util.h"
#include "vscore.h"
#include "vs_field.h"
#include "vs_clear.h"

#define FIELD_CAPSULE "vsfleet._core.field"

static void field_destroy(PyObject *cap)
{
    vs_field *f = PyCapsule_GetPointer(cap, FIELD_CAPSULE);
    if (f != NULL) {
        vs_field_free(f);
        PyMem_Free(f);
    }
}

const vs_field *vs_py_field(PyObject *obj)
{
    if (obj == Py_None) return NULL;
    vs_field *f = PyCapsule_GetPointer(obj, FIELD_CAPSULE);
    if (f == NULL) return NULL;
    return f;
}

/* field_build(template_xy, radius_m, margin_m, obstacles, goal(3), cell_m, n_headings, max_states[, deferred])
 * -> capsule (deferred true: vs_field_build_deferred) */
static PyObject *py_field_build(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 8 && nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "field_build takes 8 or 9 arguments");
        return NULL;
    }
    int deferred = nargs == 9 ? PyObject_IsTrue(a[8]) : 0;
    if (deferred < 0) return NULL;
    Py_buffer b[4];
    int got = 0;
    PyObject *result = NULL;
    double margin = PyFloat_AsDouble(a[2]), cell = PyFloat_AsDouble(a[5]);
    long long heads = PyLong_AsLongLong(a[6]), max_states = PyLong_AsLongLong(a[7]);
    if (PyErr_Occurred()) return NULL;
    if (heads < 1 || max_states < 1) { PyErr_SetString(vs_ValueError, "n_headings and max_states must be >= 1"); return NULL; }
    if (vs_py_doubles(a[0], &b[got], -1, 0, "template_xy") < 0) goto out;
    got++;
    Py_ssize_t n2 = b[0].len / 8;
    if (n2 % 2 || n2 == 0) { PyErr_SetString(vs_ValueError, "template_xy must be (n, 2) with n >= 1"); goto out; }
    Py_ssize_t n = n2 / 2;
    if (vs_py_doubles(a[1], &b[got], n, 0, "radius_m") < 0) goto out;
    got++;
    if (vs_py_doubles(a[3], &b[got], -1, 0, "obstacles") < 0) goto out;
    got++;
    if ((b[2].len / 8) % 3) { PyErr_SetString(vs_ValueError, "obstacles must hold 3 k doubles"); goto out; }
    if (vs_py_doubles(a[4], &b[got], 3, 0, "goal") < 0) goto out;
    got++;
    vs_field *f = PyMem_Malloc(sizeof(vs_field));
    if (f == NULL) { PyErr_NoMemory(); goto out; }
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = (deferred ? vs_field_build_deferred : vs_field_build)(b[0].buf, b[1].buf, (size_t)n, margin, b[2].buf,
                                                              (size_t)(b[2].len / 24), b[3].buf, cell, (size_t)heads,
                                                              (size_t)max_states, f);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) { PyMem_Free(f); vs_py_error(rc, "field_build refused its inputs"); goto out; }
    result = PyCapsule_New(f, FIELD_CAPSULE, field_destroy);
    if (result == NULL) { vs_field_free(f); PyMem_Free(f); }
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* field_resolve_all(field) -> None: vs_field_resolve_all (a deferred field's components, every one) */
static PyObject *py_field_resolve_all(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_resolve_all(field)"); return NULL; }
    vs_field *f = a[0] == Py_None ? NULL : PyCapsule_GetPointer(a[0], FIELD_CAPSULE);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    int rc = vs_field_resolve_all(f);
    if (rc != VS_OK) return vs_py_error(rc, "field_resolve_all failed");
    Py_RETURN_NONE;
}

/* field_set_refine(field, template_xy, radius_m, obstacles, cell_m, n_headings, max_states) -> None:
 * vs_field_set_refine (the field's finer lattice, asked where it has no way) */
static PyObject *py_field_set_refine(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 7) { PyErr_SetString(PyExc_TypeError, "field_set_refine takes 7 arguments"); return NULL; }
    vs_field *f = a[0] == Py_None ? NULL : PyCapsule_GetPointer(a[0], FIELD_CAPSULE);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    double cell = PyFloat_AsDouble(a[4]);
    long long heads = PyLong_AsLongLong(a[5]), max_states = PyLong_AsLongLong(a[6]);
    if (PyErr_Occurred()) return NULL;
    if (heads < 1 || max_states < 1) {
        PyErr_SetString(vs_ValueError, "n_headings and max_states must be >= 1");
        return NULL;
    }
    Py_buffer b[3];
    int got = 0;
    PyObject *result = NULL;
    if (vs_py_doubles(a[1], &b[got], -1, 0, "template_xy") < 0) goto out;
    got++;
    Py_ssize_t n2 = b[0].len / 8;
    if (n2 % 2 || n2 == 0) { PyErr_SetString(vs_ValueError, "template_xy must be (n, 2) with n >= 1"); goto out; }
    if (vs_py_doubles(a[2], &b[got], n2 / 2, 0, "radius_m") < 0) goto out;
    got++;
    if (vs_py_doubles(a[3], &b[got], -1, 0, "obstacles") < 0) goto out;
    got++;
    if ((b[2].len / 8) % 3) { PyErr_SetString(vs_ValueError, "obstacles must hold 3 k doubles"); goto out; }
    int rc = vs_field_set_refine(f, b[0].buf, b[1].buf, (size_t)(n2 / 2), b[2].buf, (size_t)(b[2].len / 24), cell,
                                 (size_t)heads, (size_t)max_states);
    if (rc != VS_OK) { vs_py_error(rc, "field_set_refine refused its inputs"); goto out; }
    result = Py_None;
    Py_INCREF(result);
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* field_refine_now(field) -> bool: vs_field_refine_now (its finer lattice built now, the GIL released); whether the
 * field has a finer lattice built */
static PyObject *py_field_refine_now(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_refine_now(field)"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_field_refine_now(f);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) return vs_py_error(rc, "field_refine_now failed");
    return PyBool_FromLong(vs_field_refined(f));
}

/* field_set_provisional(field) -> None: vs_field_set_provisional (a first plan: the step holds where it has no way) */
static PyObject *py_field_set_provisional(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_set_provisional(field)"); return NULL; }
    vs_field *f = a[0] == Py_None ? NULL : PyCapsule_GetPointer(a[0], FIELD_CAPSULE);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    vs_field_set_provisional(f);
    Py_RETURN_NONE;
}

/* field_refined(field) -> bool: vs_field_refined (its finer lattice is built; asking builds nothing) */
static PyObject *py_field_refined(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_refined(field)"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    return PyBool_FromLong(vs_field_refined(f));
}

/* field_info(field) -> (gx, gy, gth, cell_m, dth_rad, inflation_m, n_headings, ix_lo, iy_lo, nx, ny, w_rot, goal_free) */
static PyObject *py_field_info(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_info(field)"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    return Py_BuildValue("(ddddddnllnnkO)", f->gx, f->gy, f->gth, f->cell_m, f->dth_rad, f->inflation_m,
                         (Py_ssize_t)f->n_headings, f->ix_lo, f->iy_lo, (Py_ssize_t)f->nx, (Py_ssize_t)f->ny,
                         (unsigned long)f->w_rot, f->goal_free ? Py_True : Py_False);
}

/* field_costs(field) -> bytes: the (K, ny, nx) uint32 cost array, native byte order (tests, golden vectors) */
static PyObject *py_field_costs(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 1) { PyErr_SetString(PyExc_TypeError, "field_costs(field)"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    return PyBytes_FromStringAndSize((const char *)f->cost,
                                     (Py_ssize_t)(sizeof(uint32_t) * f->nx * f->ny * f->n_headings));
}

/* field_follow(field, pose(3), path_m, waypoints_out (cap, 3)) -> (n_waypoints, blocked, left_m) */
static PyObject *py_field_follow(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 4) { PyErr_SetString(PyExc_TypeError, "field_follow takes 4 arguments"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    double path_m = PyFloat_AsDouble(a[2]);
    if (PyErr_Occurred()) return NULL;
    Py_buffer b[2];
    int got = 0;
    PyObject *result = NULL;
    if (vs_py_doubles(a[1], &b[got], 3, 0, "pose") < 0) goto out;
    got++;
    if (vs_py_doubles(a[3], &b[got], -1, 1, "waypoints_out") < 0) goto out;
    got++;
    size_t cap = (size_t)(b[1].len / 24), nw = 0;
    int blocked = 0;
    double left = 0.0;
    int rc = vs_field_follow(f, b[0].buf, path_m, b[1].buf, cap, &nw, &blocked, &left);
    if (rc != VS_OK) { vs_py_error(rc, "field_follow refused its inputs"); goto out; }
    result = Py_BuildValue("(nOd)", (Py_ssize_t)nw, blocked ? Py_True : Py_False, left);
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* field_open(field, pose(3)) -> (open, tight): vs_field_open (whether a shape can take its way from the pose) */
static PyObject *py_field_open(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 2) { PyErr_SetString(PyExc_TypeError, "field_open(field, pose)"); return NULL; }
    const vs_field *f = vs_py_field(a[0]);
    if (f == NULL) { if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "not a field"); return NULL; }
    Py_buffer b;
    if (vs_py_doubles(a[1], &b, 3, 0, "pose") < 0) return NULL;
    const double *p = b.buf;
    PyObject *result = NULL;
    if (!(vs_isfinite(p[0]) && vs_isfinite(p[1]) && vs_isfinite(p[2]))) vs_py_error(VS_ENONFINITE, "field_open: pose");
    else {
        int tight = 0, open = vs_field_open(f, p, &tight);
        result = Py_BuildValue("(OO)", open ? Py_True : Py_False, tight ? Py_True : Py_False);
    }
    PyBuffer_Release(&b);
    return result;
}

/* clearance_barrier(points_xy (n, 2), fx, fy, radius_m (n), obstacles (m, 3), reach_m, vx, vy, w)
 * -> (vx, vy, w, changed): vs_clearance_barrier (vs_clear.h) */
static PyObject *py_clearance_barrier(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 9) { PyErr_SetString(PyExc_TypeError, "clearance_barrier takes 9 arguments"); return NULL; }
    double fx = PyFloat_AsDouble(a[1]), fy = PyFloat_AsDouble(a[2]), reach = PyFloat_AsDouble(a[5]);
    double t_in[3] = {PyFloat_AsDouble(a[6]), PyFloat_AsDouble(a[7]), PyFloat_AsDouble(a[8])}, t[3];
    if (PyErr_Occurred()) return NULL;
    Py_buffer b[3];
    int got = 0;
    PyObject *result = NULL;
    if (vs_py_doubles(a[0], &b[got], -1, 0, "points_xy") < 0) goto out;
    got++;
    Py_ssize_t n2 = b[0].len / 8;
    if (n2 % 2) { PyErr_SetString(vs_ValueError, "points_xy must be (n, 2)"); goto out; }
    if (vs_py_doubles(a[3], &b[got], n2 / 2, 0, "radius_m") < 0) goto out;
    got++;
    if (vs_py_doubles(a[4], &b[got], -1, 0, "obstacles") < 0) goto out;
    got++;
    if ((b[2].len / 8) % 3) { PyErr_SetString(vs_ValueError, "obstacles must hold 3 k doubles"); goto out; }
    int changed = vs_clearance_barrier(b[0].buf, fx, fy, b[1].buf, (size_t)(n2 / 2), b[2].buf,
                                       (size_t)(b[2].len / 24), reach, t_in, t);
    result = Py_BuildValue("dddN", t[0], t[1], t[2], PyBool_FromLong(changed));
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

PyMethodDef vs_py_field_methods[] = {
    {"field_build", (PyCFunction)(void (*)(void))py_field_build, METH_FASTCALL,
     "field_build(template_xy, radius_m, margin_m, obstacles, goal, cell_m, n_headings, max_states[, deferred]) "
     "-> field."},
    {"field_resolve_all", (PyCFunction)(void (*)(void))py_field_resolve_all, METH_FASTCALL,
     "field_resolve_all(field): resolve every component a deferred build left."},
    {"field_set_refine", (PyCFunction)(void (*)(void))py_field_set_refine, METH_FASTCALL,
     "field_set_refine(field, template_xy, radius_m, obstacles, cell_m, n_headings, max_states): its finer lattice."},
    {"field_refine_now", (PyCFunction)(void (*)(void))py_field_refine_now, METH_FASTCALL,
     "field_refine_now(field) -> bool: build its finer lattice now; whether it has one built."},
    {"field_set_provisional", (PyCFunction)(void (*)(void))py_field_set_provisional, METH_FASTCALL,
     "field_set_provisional(field): a first plan, held where it has no way (vs_step)."},
    {"field_refined", (PyCFunction)(void (*)(void))py_field_refined, METH_FASTCALL,
     "field_refined(field) -> bool: whether its finer lattice is built."},
    {"field_info", (PyCFunction)(void (*)(void))py_field_info, METH_FASTCALL, "field_info(field) -> lattice tuple."},
    {"field_costs", (PyCFunction)(void (*)(void))py_field_costs, METH_FASTCALL, "field_costs(field) -> bytes."},
    {"field_open", (PyCFunction)(void (*)(void))py_field_open, METH_FASTCALL,
     "field_open(field, pose) -> (open, tight)."},
    {"field_follow", (PyCFunction)(void (*)(void))py_field_follow, METH_FASTCALL,
     "field_follow(field, pose, path_m, waypoints_out) -> (n, blocked, left_m)."},
    {"clearance_barrier", (PyCFunction)(void (*)(void))py_clearance_barrier, METH_FASTCALL,
     "clearance_barrier(points_xy, fx, fy, radius_m, obstacles, reach_m, vx, vy, w) -> (vx, vy, w, changed)."},
    {NULL, NULL, 0, NULL}};
