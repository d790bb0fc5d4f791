/* py_fit.c - binding of the core's fit functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

PyMethodDef vs_py_fit_methods[] = {
    {NULL, NULL, 0, NULL},
};
