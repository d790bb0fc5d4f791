/* py_failure.c - binding of the core's failure functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

PyMethodDef vs_py_failure_methods[] = {
    {NULL, NULL, 0, NULL},
};
