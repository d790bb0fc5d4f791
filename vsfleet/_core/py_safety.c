/* py_safety.c - binding of the core's safety filter (vsfleet._core; see vs_safety.h). */
#include "py_util.h"
#include "vscore.h"
#include "vs_safety.h"

#define N_ARGS 14

/* safety_filter(margin_m, gamma_per_s, offset_m, dt_s, pose_world (n*3), radius_m (n),
 *               active (n bool/uint8 or None), wheel_base_m (n), wheel_speed_max_m_s (n),
 *               wheel_accel_max_m_s2 (n or None), wheels_prev_m_s (n*2 or None),
 *               obstacles (k*3), wheels_nominal_m_s (n*2), out (n*2, written))
 * -> (n_constraints, n_modified, n_softened, n_accel_relaxed, n_stopped).  n is len(radius_m). */
static PyObject *py_safety_filter(PyObject *mod, PyObject *const *args, Py_ssize_t nargs)
{
    (void)mod;
    if (nargs != N_ARGS) {
        PyErr_Format(PyExc_TypeError, "safety_filter expects %d arguments, got %zd", N_ARGS, nargs);
        return NULL;
    }
    vs_safety_params prm;
    double *fields[4] = {&prm.margin_m, &prm.gamma_per_s, &prm.offset_m, &prm.dt_s};
    for (int k = 0; k < 4; k++) {
        *fields[k] = PyFloat_AsDouble(args[k]);
        if (*fields[k] == -1.0 && PyErr_Occurred()) return NULL;
    }
    Py_buffer v[10];
    int got = 0, has_active = args[6] != Py_None, has_accel = args[9] != Py_None, has_prev = args[10] != Py_None;
    PyObject *result = NULL;
    if (has_accel != has_prev) {
        PyErr_SetString(vs_ValueError, "safety_filter: wheel_accel_max_m_s2 and wheels_prev_m_s: both or neither");
        return NULL;
    }
    if (vs_py_doubles(args[5], &v[0], -1, 0, "radius_m") < 0) return NULL;
    got = 1;
    const Py_ssize_t n = v[0].len / 8;
    /* index in v, arg, count per row (0: the obstacles, any multiple of 3), writable, name */
    static const struct { int arg, per, writable; const char *name; } spec[] = {
        {4, 3, 0, "pose_world"}, {7, 1, 0, "wheel_base_m"}, {8, 1, 0, "wheel_speed_max_m_s"},
        {11, 0, 0, "obstacles"}, {12, 2, 0, "wheels_nominal_m_s"}, {13, 2, 1, "out"},
        {9, 1, 0, "wheel_accel_max_m_s2"}, {10, 2, 0, "wheels_prev_m_s"},
    };
    const int n_spec = has_accel ? 8 : 6;
    for (int k = 0; k < n_spec; k++, got++) {
        if (vs_py_doubles(args[spec[k].arg], &v[got], spec[k].per ? n * spec[k].per : -1, spec[k].writable,
                          spec[k].name) < 0)
            goto done;
    }
    if ((v[4].len / 8) % 3 != 0) {
        PyErr_SetString(vs_ValueError, "safety_filter: obstacles must be (k, 3)");
        goto done;
    }
    Py_buffer act;
    if (has_active) {
        if (vs_py_flags(args[6], &act, n, 0, "active") < 0) goto done;
    }
    vs_safety_stats st;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = vs_safety_filter(&prm, (size_t)n, v[1].buf, v[0].buf, has_active ? act.buf : NULL, v[2].buf, v[3].buf,
                          has_accel ? v[7].buf : NULL, has_accel ? v[8].buf : NULL, (size_t)(v[4].len / 24),
                          v[4].buf, v[5].buf, v[6].buf, &st);
    Py_END_ALLOW_THREADS
    if (has_active) PyBuffer_Release(&act);
    if (rc != VS_OK) {
        vs_py_error(rc, rc == VS_ENONFINITE ? "safety_filter: inputs must be finite and below 1e150 in magnitude"
                                            : "safety_filter: an argument out of range");
        goto done;
    }
    result = Py_BuildValue("(iiiii)", st.n_constraints, st.n_modified, st.n_softened, st.n_accel_relaxed, st.n_stopped);
done:
    for (int k = 0; k < got; k++) PyBuffer_Release(&v[k]);
    return result;
}

PyMethodDef vs_py_safety_methods[] = {
    {"safety_filter", (PyCFunction)(void (*)(void))py_safety_filter, METH_FASTCALL,
     "safety_filter(margin_m, gamma_per_s, offset_m, dt_s, pose_world, radius_m, active, wheel_base_m, "
     "wheel_speed_max_m_s, wheel_accel_max_m_s2, wheels_prev_m_s, obstacles, wheels_nominal_m_s, out) -> "
     "(n_constraints, n_modified, n_accel_relaxed, n_stopped): the fleet-wide safety filter (vs_safety.h)."},
    {NULL, NULL, 0, NULL},
};
