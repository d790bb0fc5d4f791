/* py_control.c - binding of the core's control functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

PyMethodDef vs_py_control_methods[] = {
    {NULL, NULL, 0, NULL},
};
