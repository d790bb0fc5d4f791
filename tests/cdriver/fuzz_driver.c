/* fuzz_driver.c - every entry point of the core with hostile inputs, under ASan/UBSan
 * (make test-sanitize).
 *
 * For each flat entry (vs_golden.c: one per core function, with the same argument
 * unpacking the golden vectors use), ITER calls with random lengths 0..300 and values drawn
 * from NaN, +-inf, +-1e300, +-0, denormals, duplicates and ordinary numbers.  A call must
 * either refuse (-1) or return outputs; the sanitizers abort on any out-of-bounds access,
 * use of uninitialised memory they can see, overflow or leak.  Deterministic (own PRNG).
 */
#include <stdio.h>
#include <stdlib.h>
#include <stdint.h>
#include <string.h>

#include "vscore.h"
#include "vs_golden.h"

static uint64_t state = 0x9e3779b97f4a7c15ULL;
static uint64_t next(void)
{
    state ^= state << 13; state ^= state >> 7; state ^= state << 17;
    return state;
}
static double uniform(void) { return (double)(next() >> 11) / 9007199254740992.0; }

static double hostile(const double *pool, long n_pool, const double *sofar, long k)
{
    uint64_t r = next() % 16;
    static const double odd[] = {0.0, -0.0, 1e300, -1e300, 1e-310, -1e-310, 5e-324, 1.0, -1.0, 2.0, 0.5, 3.0};
    if (r == 0) { double nan; uint64_t b = 0x7ff8000000000001ULL; memcpy(&nan, &b, 8); return nan; }
    if (r == 1) return (next() & 1) ? 1.0 / 0.0 : -1.0 / 0.0;
    if (r <= 3) return odd[next() % (sizeof odd / sizeof odd[0])];
    if (r == 4 && k > 0) return sofar[next() % (uint64_t)k];          /* duplicates */
    if (r == 5 && n_pool > 0) return pool[next() % (uint64_t)n_pool];
    if (r <= 9) return (double)(int)(next() % 7) - 3.0;                  /* small integers: ties, collinear */
    return (uniform() - 0.5) * ((next() & 1) ? 2.0 : 200.0);
}

/* structure_step (vs_golden.c's packing) with a valid header and hostile contents: n robots,
 * k goal poses, the metric and goal kind; flags mostly 0/1 (sometimes hostile too). */
static long structure_step_input(double *in)
{
    long n = (long)(next() % 41), k = 1 + (long)(next() % 3);
    if (n == 0 && (next() & 1)) n = 1;
    long len = 0;
    double v;   /* each value is drawn before in[len++] stores it: len is read once, sequenced */
    in[len++] = (double)n;
    in[len++] = (double)(next() % 3);
    in[len++] = (double)(next() % 3);
    in[len++] = (double)k;
    for (long i = 0; i < 3 * k; i++, len++) in[len] = hostile(in, len, in, len);
    for (long i = 0; i < 9; i++, len++) in[len] = (next() % 8) ? uniform() * 0.1 + 1e-3 : hostile(in, len, in, len);
    for (long i = 0; i < 2 * n; i++, len++) in[len] = hostile(in, len, in, len);       /* template */
    for (long i = 0; i < 3 * n; i++, len++) in[len] = (next() % 8) ? 0.05 + uniform() : hostile(in, len, in, len);
    for (long i = 0; i < 3 * n; i++, len++) in[len] = hostile(in, len, in, len);       /* poses */
    for (long i = 0; i < 3 * n; i++, len++) in[len] = (next() % 16) ? (double)(next() & 1) : hostile(in, len, in, len);
    v = (next() % 8) ? uniform() * 10.0 : hostile(in, len, in, len); /* elapsed */
    in[len++] = v;
    v = (next() % 8) ? 1.0 / 30.0 : hostile(in, len, in, len); /* dt */
    in[len++] = v;
    long m = (next() % 3) ? (long)(next() % 7) : 0;
    v = (next() % 8) ? 0.01 : hostile(in, len, in, len); /* margin */
    in[len++] = v;
    v = (next() % 8) ? 0.05 + 0.1 * uniform() : hostile(in, len, in, len); /* the field's cell */
    in[len++] = v;
    v = (next() % 8) ? (double)(4 + next() % 13) : hostile(in, len, in, len);      /* headings */
    in[len++] = v;
    v = (next() % 8) ? (double)(1024 + next() % 30000) : hostile(in, len, in, len); /* max states */
    in[len++] = v;
    in[len++] = (double)m;
    for (long i = 0; i < n; i++, len++) in[len] = (next() % 8) ? 0.05 * uniform() : hostile(in, len, in, len);
    for (long i = 0; i < 3 * m; i++, len++) in[len] = (i % 3 == 2 && next() % 8) ? 0.05 + uniform() : hostile(in, len, in, len);
    return len;
}

/* field_build (vs_golden.c's packing): n robots, m obstacles, margin, cell, headings, max states, goal,
 * template, radii, obstacles; small lattices, hostile values */
static long field_build_input(double *in)
{
    long n = 1 + (long)(next() % 12), m = (long)(next() % 9), len = 0;
    double v;
    in[len++] = (double)n;
    in[len++] = (double)m;
    v = (next() % 8) ? 0.02 : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? 0.05 + 0.2 * uniform() : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? (double)(4 + next() % 29) : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? (double)(1024 + next() % 40000) : hostile(in, len, in, len);
    in[len++] = v;
    for (long i = 0; i < 3; i++, len++) in[len] = (next() % 4) ? 4.0 * (uniform() - 0.5) : hostile(in, len, in, len);
    for (long i = 0; i < 2 * n; i++, len++) in[len] = (next() % 4) ? uniform() - 0.5 : hostile(in, len, in, len);
    for (long i = 0; i < n; i++, len++) in[len] = (next() % 8) ? 0.1 * uniform() : hostile(in, len, in, len);
    for (long i = 0; i < 3 * m; i++, len++) in[len] = (i % 3 == 2) ? ((next() % 8) ? 0.05 + 0.3 * uniform() : hostile(in, len, in, len))
                                                         : ((next() % 4) ? 4.0 * (uniform() - 0.5) : hostile(in, len, in, len));
    return len;
}

/* safety_filter (vs_golden.c's packing) with a valid header and hostile contents. */
static long safety_filter_input(double *in)
{
    long n = (long)(next() % 25), k = (long)(next() % 5), len = 0;
    double v;   /* as above: draw, then store and increment */
    in[len++] = (double)n;
    in[len++] = (double)k;
    v = (next() % 8) ? 0.015 : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? 5.0 : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? 0.03 * (double)(next() & 1) : hostile(in, len, in, len);
    in[len++] = v;
    v = (next() % 8) ? 1.0 / 30.0 : hostile(in, len, in, len);
    in[len++] = v;
    for (long i = 0; i < 3 * n; i++, len++) in[len] = hostile(in, len, in, len);                       /* poses */
    for (long i = 0; i < n; i++, len++) in[len] = (next() % 8) ? 0.05 : hostile(in, len, in, len);     /* radii */
    for (long i = 0; i < n; i++, len++) in[len] = (double)(next() & 1);                               /* active */
    for (long i = 0; i < 3 * n; i++, len++) in[len] = (next() % 8) ? 0.1 + uniform() : hostile(in, len, in, len);
    for (long i = 0; i < 2 * n; i++, len++) in[len] = (next() % 4) ? uniform() - 0.5 : hostile(in, len, in, len);
    for (long i = 0; i < 3 * k; i++, len++) in[len] = (i % 3 == 2 && next() % 8) ? 0.05 + uniform() : hostile(in, len, in, len);
    for (long i = 0; i < 2 * n; i++, len++) in[len] = (next() % 4) ? uniform() - 0.5 : hostile(in, len, in, len);
    return len;
}

int main(int argc, char **argv)
{
    long iters = argc > 1 ? atol(argv[1]) : 2000;
    size_t count;
    const golden_entry *all = golden_all(&count);
    enum { CAP = 1 << 16 };
    double *in = malloc(sizeof(double) * CAP), *out = malloc(sizeof(double) * CAP);
    if (!in || !out) return 2;
    for (size_t e = 0; e < count; e++) {
        long refused = 0, ran = 0;
        for (long it = 0; it < iters; it++) {
            long n = (long)(next() % 301);
            if (it % 50 == 0) n = 0;
            for (long i = 0; i < n; i++) in[i] = hostile(in, i, in, i);
            if (strcmp(all[e].name, "structure_step") == 0 && it % 10) n = structure_step_input(in);
            if (strcmp(all[e].name, "safety_filter") == 0 && it % 10) n = safety_filter_input(in);
            if (strcmp(all[e].name, "field_build") == 0 && it % 10) n = field_build_input(in);
            if (strcmp(all[e].name, "field_follow") == 0 && it % 10) {   /* a room, then a pose and a length */
                n = field_build_input(in);
                for (int j = 0; j < 4; j++, n++) {
                    double v = (next() % 4) ? (j == 3 ? 3.0 * uniform() : 8.0 * (uniform() - 0.5)) : hostile(in, n, in, n);
                    in[n] = v;
                }
            }
            long got = all[e].run(in, n, out, CAP);
            if (got < 0) refused++; else ran++;
        }
        printf("fuzz %-14s %ld calls: %ld ran, %ld refused\n", all[e].name, iters, ran, refused);
    }
    free(in); free(out);
    return 0;
}
