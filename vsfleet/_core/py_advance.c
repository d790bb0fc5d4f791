/* py_advance.c - binding of the core's advance functions (vsfleet._core). */
#include "py_util.h"
#include "vscore.h"

PyMethodDef vs_py_advance_methods[] = {
    {NULL, NULL, 0, NULL},
};
