/* py_step.c - binding of the core's step functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

PyMethodDef vs_py_step_methods[] = {
    {NULL, NULL, 0, NULL},
};
