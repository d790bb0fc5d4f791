/* vs_golden.h - the entry points the golden driver can replay: each unpacks a flat array
 * of doubles into one core call and packs its outputs (the same packing as
 * vsfleet._core.golden_call, which records them). Returns the number of outputs, -1 on error. */
#ifndef VS_GOLDEN_H
#define VS_GOLDEN_H
#include <stddef.h>
typedef struct {
    const char *name;
    long (*run)(const double *in, long n_in, double *out, long cap);
} golden_entry;
const golden_entry *golden_find(const char *name);
const golden_entry *golden_all(size_t *count);   /* every entry (the fuzz driver's list) */
#endif
