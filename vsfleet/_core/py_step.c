/* py_step.c - binding of the structure step (vs_step.h): vsfleet._core.structure_step. */
#include "py_util.h"
#include "vscore.h"
#include "vs_step.h"

const vs_field *vs_py_field(PyObject *obj);   /* py_field.c: NULL for None (or with an error set) */

/* structure_step(template, wheel_base, speed_max, accel_max, metric, goal_kind, goal, limits,
 *                pose_world, seen, excluded, judged_apart, elapsed_s, dt_s,
 *                used_out, points_now_out, points_next_out, deviations_out, radius_m, obstacles, margin_m, field)
 * field: a capsule of field_build (the room's navigation function) or None.
 * -> None (no robot usable) or (fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m). */
static PyObject *py_structure_step(PyObject *mod, PyObject *const *a, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != 22) { PyErr_SetString(PyExc_TypeError, "structure_step takes 22 arguments"); return NULL; }
    const vs_field *field = vs_py_field(a[21]);
    if (field == NULL && PyErr_Occurred()) return NULL;
    Py_buffer b[18];
    int got = 0;
    PyObject *result = NULL;
    long metric = PyLong_AsLong(a[4]), kind = PyLong_AsLong(a[5]);
    double elapsed = PyFloat_AsDouble(a[12]), dt = PyFloat_AsDouble(a[13]), margin = PyFloat_AsDouble(a[20]);
    if (PyErr_Occurred()) return NULL;
    if (vs_py_doubles(a[0], &b[got], -1, 0, "template_xy") < 0) goto out;
    got++;
    Py_ssize_t n2 = b[0].len / 8;
    if (n2 % 2 || n2 == 0) { PyErr_SetString(vs_ValueError, "template_xy must be (n, 2) with n >= 1"); goto out; }
    Py_ssize_t n = n2 / 2;
    if (vs_py_doubles(a[1], &b[got], n, 0, "wheel_base_m") < 0) goto out;
    got++;
    if (vs_py_doubles(a[2], &b[got], n, 0, "wheel_speed_max_m_s") < 0) goto out;
    got++;
    if (vs_py_doubles(a[3], &b[got], n, 0, "wheel_accel_max_m_s2") < 0) goto out;
    got++;
    if (vs_py_doubles(a[6], &b[got], -1, 0, "goal") < 0) goto out;
    got++;
    Py_ssize_t n_goal = b[4].len / 8;
    if (n_goal == 0 || n_goal % 3) { PyErr_SetString(vs_ValueError, "goal must hold 3 k doubles, k >= 1"); goto out; }
    if (vs_py_doubles(a[7], &b[got], 9, 0, "limits") < 0) goto out;
    got++;
    if (vs_py_doubles(a[8], &b[got], 3 * n, 0, "pose_world") < 0) goto out;
    got++;
    if (vs_py_flags(a[9], &b[got], n, 0, "seen") < 0) goto out;
    got++;
    if (vs_py_flags(a[10], &b[got], n, 0, "excluded") < 0) goto out;
    got++;
    if (vs_py_flags(a[11], &b[got], n, 0, "judged_apart") < 0) goto out;
    got++;
    if (vs_py_flags(a[14], &b[got], n, 1, "used_out") < 0) goto out;
    got++;
    if (vs_py_doubles(a[15], &b[got], 2 * n, 1, "points_now_out") < 0) goto out;
    got++;
    if (vs_py_doubles(a[16], &b[got], 2 * n, 1, "points_next_out") < 0) goto out;
    got++;
    if (vs_py_doubles(a[17], &b[got], n, 1, "deviations_out") < 0) goto out;
    got++;
    if (vs_py_doubles(a[18], &b[got], n, 0, "radius_m") < 0) goto out;
    got++;
    if (vs_py_doubles(a[19], &b[got], -1, 0, "obstacles") < 0) goto out;
    got++;
    if ((b[15].len / 8) % 3) { PyErr_SetString(vs_ValueError, "obstacles must hold 3 k doubles"); goto out; }
    const double *lim = b[5].buf;
    vs_mission m = {(size_t)n, b[0].buf, b[1].buf, b[2].buf, b[3].buf, (int)metric,
                    {(int)kind, b[4].buf, (size_t)(n_goal / 3)},
                    {lim[0], lim[1], lim[2], lim[3], lim[4], lim[5], lim[6], lim[7], lim[8]},
                    b[14].buf, b[15].buf, (size_t)(b[15].len / 24), margin, field};
    vs_structure s;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_structure_step(&m, b[6].buf, b[7].buf, b[8].buf, b[9].buf, elapsed, dt, &s, b[10].buf, b[11].buf,
                           b[12].buf, b[13].buf);
    Py_END_ALLOW_THREADS
    if (rc != VS_OK) { vs_py_error(rc, "structure_step refused its inputs"); goto out; }
    if (!s.any_used) { result = Py_NewRef(Py_None); goto out; }
    result = Py_BuildValue("(ddddddddddOOd)", s.fit_x, s.fit_y, s.fit_th, s.goal_x, s.goal_y, s.goal_th, s.vx_m_s,
                           s.vy_m_s, s.w_rad_s, s.cost, s.at_goal ? Py_True : Py_False,
                           s.blocked ? Py_True : Py_False, s.left_m);
out:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

PyMethodDef vs_py_step_methods[] = {
    {"structure_step", (PyCFunction)(void (*)(void))py_structure_step, METH_FASTCALL,
     "structure_step(...): fit, advance and judged fit of one frame (vsfleet/_core/vs_step.h)."},
    {NULL, NULL, 0, NULL},
};
