/* vs_golden.c - flat entry points for the golden vectors (see vs_golden.h).
 *
 * One packing per core function, used both by the recorder (vsfleet._core.golden_call, from
 * Python) and by the plain C driver (tests/cdriver/golden_driver.c, native, aarch64 under
 * qemu, sanitizers), so the two can only agree if the core computes the same bits. */
#include <string.h>

#include "vscore.h"
#include "vs_golden.h"

static long g_sin(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_sin(in[i]);
    return n;
}

static long g_cos(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_cos(in[i]);
    return n;
}

static long g_atan2(const double *in, long n, double *out, long cap)
{
    if (n % 2 || n / 2 > cap) return -1;
    for (long i = 0; i < n / 2; i++) out[i] = vs_atan2(in[2 * i], in[2 * i + 1]);
    return n / 2;
}

static long g_wrap(const double *in, long n, double *out, long cap)
{
    if (n > cap) return -1;
    for (long i = 0; i < n; i++) out[i] = vs_wrap_angle(in[i]);
    return n;
}

static const golden_entry entries[] = {
    {"sin", g_sin},
    {"cos", g_cos},
    {"atan2", g_atan2},
    {"wrap_angle", g_wrap},
};

const golden_entry *golden_find(const char *name)
{
    for (size_t i = 0; i < sizeof entries / sizeof entries[0]; i++)
        if (strcmp(entries[i].name, name) == 0) return &entries[i];
    return NULL;
}

const golden_entry *golden_all(size_t *count)
{
    *count = sizeof entries / sizeof entries[0];
    return entries;
}
