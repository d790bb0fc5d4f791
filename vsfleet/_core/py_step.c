/* py_step.c - bindings of the step's parts: the structure step (vs_step.h), vsfleet._core.structure_step, and
 * the assembly tie-break (vs_assembly.h), vsfleet._core.assembly_targets. */
#include <stdint.h>

#include "py_util.h"
#include "vscore.h"
#include "vs_assembly.h"
#include "vs_step.h"

const vs_field *vs_py_field(PyObject *obj);   /* py_field.c: NULL for None (or with an error set) */

/* structure_step(template, wheel_base, speed_max, accel_max, metric, goal_kind, goal, limits,
 *                pose_world, seen, excluded, judged_apart, elapsed_s, dt_s,
 *                used_out, points_now_out, points_next_out, deviations_out, radius_m, obstacles, margin_m, field,
 *                shapes_xy, shape_fields)
 * field: a capsule of field_build (the room's navigation function) or None.  shapes_xy: (k, n, 2) doubles (k = 0:
 * none), shape_fields: a tuple of k such capsules (reshape: vs_step.h).
 * -> None (no robot usable) or (fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m, shape,
 * cleared, held). */
/* A_TEMPLATE ... A_SHAPE_FIELDS, A_COUNT: py_util.h */
typedef char step_args_check[A_COUNT == VS_PY_STRUCTURE_STEP_ARGS ? 1 : -1];
/* the arguments by name (exported: STRUCTURE_STEP_ARGS); the mission's are the ones before pose_world and
 * from radius_m on, the frame's between */
const char *const vs_py_structure_step_args[VS_PY_STRUCTURE_STEP_ARGS] = {
    [A_TEMPLATE] = "template_xy", [A_BASE] = "wheel_base_m", [A_VMAX] = "wheel_speed_max_m_s",
    [A_AMAX] = "wheel_accel_max_m_s2", [A_METRIC] = "metric", [A_KIND] = "goal_kind", [A_GOAL] = "goal",
    [A_LIMITS] = "limits", [A_POSE] = "pose_world", [A_SEEN] = "seen", [A_EXCLUDED] = "excluded",
    [A_JUDGED] = "judged_apart", [A_ELAPSED] = "elapsed_s", [A_DT] = "dt_s", [A_USED] = "used_out",
    [A_NOW] = "points_now_out", [A_NEXT] = "points_next_out", [A_DEV] = "deviations_out", [A_RADIUS] = "radius_m",
    [A_OBSTACLES] = "obstacles", [A_MARGIN] = "margin_m", [A_FIELD] = "field",
    [A_SHAPES] = "shapes_xy", [A_SHAPE_FIELDS] = "shape_fields",
};

static PyObject *py_structure_step(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != A_COUNT) { PyErr_SetString(PyExc_TypeError, "structure_step takes 24 arguments"); return NULL; }
    const char *const *name = vs_py_structure_step_args;
    const vs_field *field = vs_py_field(a[A_FIELD]);
    if (field == NULL && PyErr_Occurred()) return NULL;
    Py_buffer b[19];
    const vs_field *shape_fields[VS_STEP_MAX_SHAPES];
    if (!PyTuple_Check(a[A_SHAPE_FIELDS]) || PyTuple_GET_SIZE(a[A_SHAPE_FIELDS]) > VS_STEP_MAX_SHAPES) {
        PyErr_SetString(PyExc_TypeError, "shape_fields must be a tuple of at most VS_STEP_MAX_SHAPES fields");
        return NULL;
    }
    Py_ssize_t n_shapes = PyTuple_GET_SIZE(a[A_SHAPE_FIELDS]);
    for (Py_ssize_t j = 0; j < n_shapes; j++) {
        shape_fields[j] = vs_py_field(PyTuple_GET_ITEM(a[A_SHAPE_FIELDS], j));
        if (shape_fields[j] == NULL) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "shape_fields must hold fields, not None");
            return NULL;
        }
    }
    int got = 0;
    PyObject *result = NULL;
    long metric = PyLong_AsLong(a[A_METRIC]), kind = PyLong_AsLong(a[A_KIND]);
    double elapsed = PyFloat_AsDouble(a[A_ELAPSED]), dt = PyFloat_AsDouble(a[A_DT]);
    double margin = PyFloat_AsDouble(a[A_MARGIN]);
    if (PyErr_Occurred()) return NULL;
    if (vs_py_doubles(a[A_TEMPLATE], &b[got], -1, 0, name[A_TEMPLATE]) < 0) goto out;
    got++;
    Py_ssize_t n2 = b[0].len / 8;
    if (n2 % 2 || n2 == 0) { PyErr_SetString(vs_ValueError, "template_xy must be (n, 2) with n >= 1"); goto out; }
    Py_ssize_t n = n2 / 2;
    if (vs_py_doubles(a[A_BASE], &b[got], n, 0, name[A_BASE]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_VMAX], &b[got], n, 0, name[A_VMAX]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_AMAX], &b[got], n, 0, name[A_AMAX]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_GOAL], &b[got], -1, 0, name[A_GOAL]) < 0) goto out;
    got++;
    Py_ssize_t n_goal = b[4].len / 8;
    if (n_goal == 0 || n_goal % 3) { PyErr_SetString(vs_ValueError, "goal must hold 3 k doubles, k >= 1"); goto out; }
    if (vs_py_doubles(a[A_LIMITS], &b[got], 9, 0, name[A_LIMITS]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_POSE], &b[got], 3 * n, 0, name[A_POSE]) < 0) goto out;
    got++;
    if (vs_py_flags(a[A_SEEN], &b[got], n, 0, name[A_SEEN]) < 0) goto out;
    got++;
    if (vs_py_flags(a[A_EXCLUDED], &b[got], n, 0, name[A_EXCLUDED]) < 0) goto out;
    got++;
    if (vs_py_flags(a[A_JUDGED], &b[got], n, 0, name[A_JUDGED]) < 0) goto out;
    got++;
    if (vs_py_flags(a[A_USED], &b[got], n, 1, name[A_USED]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_NOW], &b[got], 2 * n, 1, name[A_NOW]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_NEXT], &b[got], 2 * n, 1, name[A_NEXT]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_DEV], &b[got], n, 1, name[A_DEV]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_RADIUS], &b[got], n, 0, name[A_RADIUS]) < 0) goto out;
    got++;
    if (vs_py_doubles(a[A_OBSTACLES], &b[got], -1, 0, name[A_OBSTACLES]) < 0) goto out;
    got++;
    if ((b[15].len / 8) % 3) { PyErr_SetString(vs_ValueError, "obstacles must hold 3 k doubles"); goto out; }
    if (vs_py_doubles(a[A_SHAPES], &b[got], 2 * n * n_shapes, 0, name[A_SHAPES]) < 0) goto out;
    got++;
    const double *lim = b[5].buf;
    vs_mission m = {(size_t)n, b[0].buf, b[1].buf, b[2].buf, b[3].buf, (int)metric,
                    {(int)kind, b[4].buf, (size_t)(n_goal / 3)},
                    {lim[0], lim[1], lim[2], lim[3], lim[4], lim[5], lim[6], lim[7], lim[8]},
                    b[14].buf, b[15].buf, (size_t)(b[15].len / 24), margin, field,
                    (size_t)n_shapes, b[16].buf, shape_fields};
    vs_structure s;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_structure_step(&m, b[6].buf, b[7].buf, b[8].buf, b[9].buf, elapsed, dt, &s, b[10].buf, b[11].buf,
                           b[12].buf, b[13].buf);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) { vs_py_error(rc, "structure_step refused its inputs"); goto out; }
    if (!s.any_used) { result = Py_NewRef(Py_None); goto out; }
    result = Py_BuildValue("(ddddddddddOOdiOO)", s.fit_x, s.fit_y, s.fit_th, s.goal_x, s.goal_y, s.goal_th, s.vx_m_s,
                           s.vy_m_s, s.w_rad_s, s.cost, s.at_goal ? Py_True : Py_False,
                           s.blocked ? Py_True : Py_False, s.left_m, s.shape,
                           s.cleared ? Py_True : Py_False, s.held ? Py_True : Py_False);
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* assembly_targets(radius_m (n), pose_world (n*3), seen (n bool/uint8), points_now (n*2), points_next (n*2),
 *                  margin_m, elapsed_s, now_out (n*2, written), next_out (n*2, written),
 *                  detoured_out (n bool/uint8, written))
 * -> the count of robots detoured.  n is len(radius_m).  The outputs must not share memory with the inputs. */
static PyObject *py_assembly_targets(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 10) {
        PyErr_Format(PyExc_TypeError, "assembly_targets expects 10 arguments, got %zd", nargs);
        return NULL;
    }
    double margin = PyFloat_AsDouble(a[5]);
    if (margin == -1.0 && PyErr_Occurred()) return NULL;
    double elapsed = PyFloat_AsDouble(a[6]);
    if (elapsed == -1.0 && PyErr_Occurred()) return NULL;
    Py_buffer b[8];
    int got = 0;
    PyObject *result = NULL;
    if (vs_py_doubles(a[0], &b[got], -1, 0, "radius_m") < 0) return NULL;
    got = 1;
    const Py_ssize_t n = b[0].len / 8;
    /* arg, count per row, flags (1) or doubles (0), writable, name */
    static const struct { int arg, per, flags, writable; const char *name; } spec[] = {
        {1, 3, 0, 0, "pose_world"}, {2, 1, 1, 0, "seen"}, {3, 2, 0, 0, "points_now"}, {4, 2, 0, 0, "points_next"},
        {7, 2, 0, 1, "now_out"}, {8, 2, 0, 1, "next_out"}, {9, 1, 1, 1, "detoured_out"},
    };
    for (int k = 0; k < 7; k++, got++) {
        int (*take)(PyObject *, Py_buffer *, Py_ssize_t, int, const char *) = spec[k].flags ? vs_py_flags
                                                                                             : vs_py_doubles;
        if (take(a[spec[k].arg], &b[got], n * spec[k].per, spec[k].writable, spec[k].name) < 0) goto out;
    }
    for (int k = 5; k < 8; k++) {   /* no output may share memory with an input or another output */
        uintptr_t lo = (uintptr_t)b[k].buf, hi = lo + (uintptr_t)b[k].len;
        for (int j = 0; j < k; j++) {
            uintptr_t jlo = (uintptr_t)b[j].buf, jhi = jlo + (uintptr_t)b[j].len;
            if (b[k].len > 0 && b[j].len > 0 && lo < jhi && jlo < hi) {
                PyErr_Format(vs_ValueError, "assembly_targets: %s shares memory with an input", spec[k - 1].name);
                goto out;
            }
        }
    }
    size_t count = 0;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_assembly_targets((size_t)n, b[0].buf, b[1].buf, b[2].buf, b[3].buf, b[4].buf, margin, elapsed,
                             b[5].buf, b[6].buf, b[7].buf, &count);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) {
        vs_py_error(rc, rc == VS_ENONFINITE ? "assembly_targets: a seen robot's radius, position or points, the "
                                              "margin or elapsed_s, is not finite"
                                            : "assembly_targets: a negative radius or margin");
        goto out;
    }
    result = PyLong_FromSize_t(count);
out:
    for (int k = 0; k < got; k++) PyBuffer_Release(&b[k]);
    return result;
}

PyMethodDef vs_py_step_methods[] = {
    {"structure_step", (PyCFunction)(void (*)(void))py_structure_step, METH_FASTCALL,
     "structure_step(...): fit, advance and judged fit of one frame (vsfleet/_core/vs_step.h)."},
    {"assembly_targets", (PyCFunction)(void (*)(void))py_assembly_targets, METH_FASTCALL,
     "assembly_targets(radius_m, pose_world, seen, points_now, points_next, margin_m, elapsed_s, now_out, "
     "next_out, detoured_out) -> the count detoured: the assembly tie-break (vsfleet/_core/vs_assembly.h)."},
    {NULL, NULL, 0, NULL},
};
