/* py_control.c - binding of the core's kinematics (vs_kin.h) and controllers (vs_control.h)
 * (vsfleet._core).  Every function takes its outputs as writable float64 buffers (numpy arrays
 * from np.empty) and returns None; arrays are C-contiguous float64 buffers, except the flags
 * (active, ready), which are 1-byte bool/uint8 buffers.  A buffer that is not C-contiguous or
 * not of that type raises TypeError (the Python wrappers then convert and call again); a length
 * that does not fit raises ValueError; a core error the typed vsfleet error. */
#include "py_util.h"
#include "vscore.h"
#include "vs_control.h"
#include "vs_kin.h"

#define MAXBUF 32

typedef struct {
    Py_buffer v[MAXBUF];
    int k;
} bufs;

static void release(bufs *b)
{
    for (int i = 0; i < b->k; i++) PyBuffer_Release(&b->v[i]);
    b->k = 0;
}

/* n_expected doubles from obj (n_expected < 0: any); NULL with an exception set on failure */
static double *dbl(bufs *b, PyObject *obj, Py_ssize_t n_expected, int writable, const char *name)
{
    if (vs_py_doubles(obj, &b->v[b->k], n_expected, writable, name) < 0) return NULL;
    return (double *)b->v[b->k++].buf;
}

/* n bytes (bool or uint8) from obj */
static unsigned char *flags(bufs *b, PyObject *obj, Py_ssize_t n, int writable, const char *name)
{
    Py_buffer *view = &b->v[b->k];
    int fl = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, fl) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s bool buffer", name, writable ? " writable" : "");
        return NULL;
    }
    const char *f = view->format;
    if (view->itemsize != 1 || f == NULL || !(f[0] == '?' || f[0] == 'B' || ((f[0] == '<' || f[0] == '=' || f[0] == '|')
                                                                             && (f[1] == '?' || f[1] == 'B')))) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "%s must hold bool", name);
        return NULL;
    }
    if (view->len != n) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "%s must hold %zd values, got %zd", name, n, view->len);
        return NULL;
    }
    b->k++;
    return (unsigned char *)view->buf;
}

static int get_double(PyObject *obj, double *x)
{
    *x = PyFloat_AsDouble(obj);
    return (*x == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static int nargs_is(Py_ssize_t nargs, Py_ssize_t want, const char *sig)
{
    if (nargs == want) return 0;
    PyErr_Format(PyExc_TypeError, "expected %zd arguments: %s", want, sig);
    return -1;
}

static PyObject *done(bufs *b, int rc, const char *what)
{
    release(b);
    if (rc != VS_OK) return vs_py_error(rc, what);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ kinematics */

typedef int (*elementwise)(const double *, size_t, double *);

static PyObject *call_elementwise(PyObject *const *args, Py_ssize_t nargs, elementwise f, const char *what)
{
    if (nargs_is(nargs, 2, "(x, out)") < 0) return NULL;
    bufs b = {.k = 0};
    double *out = dbl(&b, args[1], -1, 1, "out");
    if (out == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 8;
    double *x = dbl(&b, args[0], n, 0, "x");
    if (x == NULL) { release(&b); return NULL; }
    return done(&b, f(x, (size_t)n, out), what);
}

static PyObject *py_sinc_v(PyObject *m, PyObject *const *a, Py_ssize_t n)
{ (void)m; return call_elementwise(a, n, vs_sinc_v, "sinc_v: x must be finite"); }
static PyObject *py_wrap_angles(PyObject *m, PyObject *const *a, Py_ssize_t n)
{ (void)m; return call_elementwise(a, n, vs_wrap_angles, "wrap_angles: angles must be finite"); }

static PyObject *py_integrate_arcs(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 5, "(pose_world, wheels_m_s, dt_s, wheel_base_m, out)") < 0) return NULL;
    double dt;
    if (get_double(args[2], &dt) < 0) return NULL;
    bufs b = {.k = 0};
    double *out = dbl(&b, args[4], -1, 1, "out");
    if (out == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 24;
    const double *pose = dbl(&b, args[0], 3 * n, 0, "pose_world");
    const double *wheels = pose ? dbl(&b, args[1], 2 * n, 0, "wheels_m_s") : NULL;
    const double *base = wheels ? dbl(&b, args[3], n, 0, "wheel_base_m") : NULL;
    if (base == NULL) { release(&b); return NULL; }
    return done(&b, vs_integrate_arcs(pose, wheels, dt, base, (size_t)n, out),
                "integrate_arcs: poses, wheels, dt and wheel bases must be finite (and so the result)");
}

static PyObject *py_limit_wheels(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 6, "(wheels_m_s, wheels_prev_m_s, dt_s, speed_max_m_s, accel_max_m_s2, out)") < 0) return NULL;
    double dt;
    if (get_double(args[2], &dt) < 0) return NULL;
    bufs b = {.k = 0};
    double *out = dbl(&b, args[5], -1, 1, "out");
    if (out == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    const double *u = dbl(&b, args[0], 2 * n, 0, "wheels_m_s");
    const double *p = u ? dbl(&b, args[1], 2 * n, 0, "wheels_prev_m_s") : NULL;
    const double *vmax = p ? dbl(&b, args[3], n, 0, "speed_max_m_s") : NULL;
    const double *amax = vmax ? dbl(&b, args[4], n, 0, "accel_max_m_s2") : NULL;
    if (amax == NULL) { release(&b); return NULL; }
    return done(&b, vs_limit_wheels(u, p, dt, vmax, amax, (size_t)n, out), "wheel commands must be finite");
}

/* ------------------------------------------------------------------ controllers */

/* The arguments of a ControlInput, in the order every controller takes them (exported by name) */
enum { IN_POSE, IN_NOW, IN_NEXT, IN_PREV, IN_DT, IN_AGE, IN_BASE, IN_VMAX, IN_AMAX, IN_ACTIVE, IN_COUNT };
typedef char in_count_check[IN_COUNT == VS_PY_CONTROL_INPUTS ? 1 : -1];
const char *const vs_py_control_input_args[VS_PY_CONTROL_INPUTS] = {
    [IN_POSE] = "pose_world", [IN_NOW] = "point_now_world", [IN_NEXT] = "point_next_world",
    [IN_PREV] = "wheels_prev_m_s", [IN_DT] = "dt_s", [IN_AGE] = "age_s", [IN_BASE] = "wheel_base_m",
    [IN_VMAX] = "wheel_speed_max_m_s", [IN_AMAX] = "wheel_accel_max_m_s2", [IN_ACTIVE] = "active",
};

/* The arguments of a ControlInput from args (in that order); n rows.  0 on success. */
static int read_input(bufs *b, PyObject *const *args, Py_ssize_t n, vs_control_input *in)
{
    const char *const *name = vs_py_control_input_args;
    in->n = (size_t)n;
    if (get_double(args[IN_DT], &in->dt_s) < 0 || get_double(args[IN_AGE], &in->age_s) < 0) return -1;
    if ((in->pose_world = dbl(b, args[IN_POSE], 3 * n, 0, name[IN_POSE])) == NULL) return -1;
    if ((in->point_now_world = dbl(b, args[IN_NOW], 2 * n, 0, name[IN_NOW])) == NULL) return -1;
    if ((in->point_next_world = dbl(b, args[IN_NEXT], 2 * n, 0, name[IN_NEXT])) == NULL) return -1;
    if ((in->wheels_prev_m_s = dbl(b, args[IN_PREV], 2 * n, 0, name[IN_PREV])) == NULL) return -1;
    if ((in->wheel_base_m = dbl(b, args[IN_BASE], n, 0, name[IN_BASE])) == NULL) return -1;
    if ((in->wheel_speed_max_m_s = dbl(b, args[IN_VMAX], n, 0, name[IN_VMAX])) == NULL) return -1;
    if ((in->wheel_accel_max_m_s2 = dbl(b, args[IN_AMAX], n, 0, name[IN_AMAX])) == NULL) return -1;
    if ((in->active = flags(b, args[IN_ACTIVE], n, 0, name[IN_ACTIVE])) == NULL) return -1;
    return 0;
}

/* Precision's state arrays, in the order control_precision takes them (exported by name) */
enum { ST_POSE, ST_GAINS, ST_HISTORY, ST_TARGET, ST_FEED, ST_TURN, ST_DIRECTION, ST_OFFSET, ST_READY, ST_COUNT };
typedef char st_count_check[ST_COUNT == VS_PY_PRECISION_STATES ? 1 : -1];
const char *const vs_py_precision_state_args[VS_PY_PRECISION_STATES] = {
    [ST_POSE] = "pose_world", [ST_GAINS] = "gains", [ST_HISTORY] = "history_m_s", [ST_TARGET] = "target_world",
    [ST_FEED] = "feed_m_s", [ST_TURN] = "turn_rad_s", [ST_DIRECTION] = "direction", [ST_OFFSET] = "offset_world",
    [ST_READY] = "ready",
};

#define INPUT_SIG "pose, now, next, prev, dt_s, age_s, wheel_base, speed_max, accel_max, active"
static const char *const CONTROL_ERR = "control input: every array must be finite, dt_s > 0 and age_s >= 0";

/* control_precision(gains (17,), state: pose, gains, history, target, feed, turn, direction, offset, ready,
 *                   <the 10 input arguments>, out state: the same 9, wheels_out) (28 buffers of MAXBUF) */
static PyObject *py_control_precision(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    enum { STATE = 1, INPUT = STATE + ST_COUNT, OUT = INPUT + IN_COUNT, WHEELS = OUT + ST_COUNT };
    if (nargs_is(nargs, WHEELS + 1, "(gains, state..., " INPUT_SIG ", out_state..., wheels_out)") < 0)
        return NULL;
    bufs b = {.k = 0};
    double *wheels = dbl(&b, args[WHEELS], -1, 1, "wheels_out");
    if (wheels == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    const double *gv = dbl(&b, args[0], 17, 0, "gains");
    if (gv == NULL) goto fail;
    vs_precision_gains g = {gv[0], gv[1], gv[2], gv[3], gv[4], gv[5], gv[6], gv[7], gv[8], gv[9], gv[10], gv[11], gv[12],
                            gv[13], gv[14], gv[15], gv[16]};
    vs_precision_state st, out;
    PyObject *const *s = args + STATE, *const *o = args + OUT;
    const char *const *names = vs_py_precision_state_args;
    const Py_ssize_t sizes[ST_READY] = {[ST_POSE] = 3 * n, [ST_GAINS] = 2 * n,
                                        [ST_HISTORY] = 2 * VS_PRECISION_HISTORY * n, [ST_TARGET] = 2 * n,
                                        [ST_FEED] = 2 * n, [ST_TURN] = n, [ST_DIRECTION] = n, [ST_OFFSET] = 2 * n};
    double **sp[ST_READY] = {[ST_POSE] = &st.pose_world, [ST_GAINS] = &st.gains, [ST_HISTORY] = &st.history_m_s,
                             [ST_TARGET] = &st.target_world, [ST_FEED] = &st.feed_m_s, [ST_TURN] = &st.turn_rad_s,
                             [ST_DIRECTION] = &st.direction, [ST_OFFSET] = &st.offset_world};
    double **op[ST_READY] = {[ST_POSE] = &out.pose_world, [ST_GAINS] = &out.gains,
                             [ST_HISTORY] = &out.history_m_s,
                             [ST_TARGET] = &out.target_world, [ST_FEED] = &out.feed_m_s, [ST_TURN] = &out.turn_rad_s,
                             [ST_DIRECTION] = &out.direction, [ST_OFFSET] = &out.offset_world};
    for (int k = 0; k < ST_READY; k++) {
        if ((*sp[k] = dbl(&b, s[k], sizes[k], 0, names[k])) == NULL) goto fail;
        if ((*op[k] = dbl(&b, o[k], sizes[k], 1, names[k])) == NULL) goto fail;
    }
    if ((st.ready = flags(&b, s[ST_READY], n, 0, names[ST_READY])) == NULL) goto fail;
    if ((out.ready = flags(&b, o[ST_READY], n, 1, names[ST_READY])) == NULL) goto fail;
    vs_control_input in;
    if (read_input(&b, args + INPUT, n, &in) < 0) goto fail;
    return done(&b, vs_control_precision(&g, &st, &in, &out, wheels),
                "precision: input and state must be finite (and so the new state), dt_s > 0, age_s >= 0");
fail:
    release(&b);
    return NULL;
}

/* control_turn_then_go(gains (5,): K, d_max, horizon, fade, allow_reverse (0/1), <input>, wheels_out) */
static PyObject *py_control_turn_then_go(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 12, "(gains, " INPUT_SIG ", wheels_out)") < 0) return NULL;
    bufs b = {.k = 0};
    double *wheels = dbl(&b, args[11], -1, 1, "wheels_out");
    if (wheels == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    const double *gv = dbl(&b, args[0], 5, 0, "gains");
    vs_control_input in;
    if (gv == NULL || read_input(&b, args + 1, n, &in) < 0) { release(&b); return NULL; }
    vs_turn_then_go_gains g = {gv[0], gv[1], gv[2], gv[3], gv[4] != 0.0};
    return done(&b, vs_control_turn_then_go(&g, &in, wheels), CONTROL_ERR);
}

/* control_arc(horizon_s, <input>, wheels_out) */
static PyObject *py_control_arc(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 12, "(horizon_s, " INPUT_SIG ", wheels_out)") < 0) return NULL;
    double horizon;
    if (get_double(args[0], &horizon) < 0) return NULL;
    bufs b = {.k = 0};
    double *wheels = dbl(&b, args[11], -1, 1, "wheels_out");
    if (wheels == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    vs_control_input in;
    if (read_input(&b, args + 1, n, &in) < 0) { release(&b); return NULL; }
    return done(&b, vs_control_arc(horizon, &in, wheels), CONTROL_ERR);
}

/* control_tracking(gains (6,), <input>, wheels_out) */
static PyObject *py_control_tracking(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 12, "(gains, " INPUT_SIG ", wheels_out)") < 0) return NULL;
    bufs b = {.k = 0};
    double *wheels = dbl(&b, args[11], -1, 1, "wheels_out");
    if (wheels == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    const double *gv = dbl(&b, args[0], 6, 0, "gains");
    vs_control_input in;
    if (gv == NULL || read_input(&b, args + 1, n, &in) < 0) { release(&b); return NULL; }
    vs_tracking_gains g = {gv[0], gv[1], gv[2], gv[3], gv[4], gv[5]};
    return done(&b, vs_control_tracking(&g, &in, wheels), CONTROL_ERR);
}

/* control_hold(deadband_m, still_speed_m_s, <input>, wheels (in/out)) */
static PyObject *py_control_hold(PyObject *m, PyObject *const *args, Py_ssize_t nargs)
{
    (void)m;
    if (nargs_is(nargs, 13, "(deadband_m, still_speed_m_s, " INPUT_SIG ", wheels)") < 0) return NULL;
    double deadband, still;
    if (get_double(args[0], &deadband) < 0 || get_double(args[1], &still) < 0) return NULL;
    bufs b = {.k = 0};
    double *wheels = dbl(&b, args[12], -1, 1, "wheels");
    if (wheels == NULL) return NULL;
    Py_ssize_t n = b.v[0].len / 16;
    vs_control_input in;
    if (read_input(&b, args + 2, n, &in) < 0) { release(&b); return NULL; }
    return done(&b, vs_control_hold(deadband, still, &in, wheels), CONTROL_ERR);
}

#define FC(f) (PyCFunction)(void (*)(void))(f), METH_FASTCALL
PyMethodDef vs_py_control_methods[] = {
    {"sinc_v", FC(py_sinc_v), "sinc_v(x, out): sin(x)/x elementwise (series below 1e-4)."},
    {"wrap_angles", FC(py_wrap_angles), "wrap_angles(th, out): [-pi, pi) elementwise [rad]."},
    {"integrate_arcs", FC(py_integrate_arcs),
     "integrate_arcs(pose (n,3), wheels (n,2), dt_s, wheel_base (n,), out (n,3)): exact arcs (eqs 17-18)."},
    {"limit_wheels", FC(py_limit_wheels),
     "limit_wheels(u (n,2), prev (n,2), dt_s, speed_max (n,), accel_max (n,), out (n,2)): the envelope."},
    {"control_precision", FC(py_control_precision),
     "control_precision(gains (17,), 9 state arrays, " INPUT_SIG ", 9 out state arrays, wheels_out (n,2))."},
    {"control_turn_then_go", FC(py_control_turn_then_go), "control_turn_then_go(gains (5,), " INPUT_SIG ", wheels_out)."},
    {"control_arc", FC(py_control_arc), "control_arc(horizon_s, " INPUT_SIG ", wheels_out)."},
    {"control_tracking", FC(py_control_tracking), "control_tracking(gains (6,), " INPUT_SIG ", wheels_out)."},
    {"control_hold", FC(py_control_hold), "control_hold(deadband_m, still_speed_m_s, " INPUT_SIG ", wheels in/out)."},
    {NULL, NULL, 0, NULL},
};
