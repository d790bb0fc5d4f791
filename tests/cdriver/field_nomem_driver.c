/* field_nomem_driver.c - a deferred field (vs_field_build_deferred) that runs out of memory while a descent resolves
 * a component stays as it was: the descent returns VS_ENOMEM, and a later descent, with memory, answers as on the
 * whole build (vs_field_build), bit for bit, and resolves to the same costs.
 *
 * Then a build (vs_field_build_deferred) whose k-th allocation fails says VS_ENOMEM, for every k it reaches.
 *
 * Built with -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=posix_memalign (tests/test_core_field_nomem.py,
 * and `make test-sanitize` under ASan): while armed, the k-th allocation fails, for k = 1, 2, ... until a resolution
 * (a build) no longer reaches its k-th allocation.  The room: a ring of obstacles around the goal (a component of its
 * own) and a pose
 * outside it, so the descent must resolve the ring's outside; its scratch grows by realloc past 256 states, so the
 * failures fall in the breadth-first listing as well as in Dial's buckets.
 * Exit 0 and "ok" when every failure left the field as it was; 1 otherwise.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vscore.h"
#include "vs_field.h"

static long armed = -1;   /* >= 1: the allocation that fails, counted down; -1: none fails */
static long aligned_failed;   /* failures given to posix_memalign (vs_field.c's cost array, on Linux) */

void *__real_malloc(size_t size);
void *__real_calloc(size_t count, size_t size);
void *__real_realloc(void *p, size_t size);
int __real_posix_memalign(void **p, size_t alignment, size_t size);
void *__wrap_malloc(size_t size);
void *__wrap_calloc(size_t count, size_t size);
void *__wrap_realloc(void *p, size_t size);
int __wrap_posix_memalign(void **p, size_t alignment, size_t size);

static int fails(void)
{
    return armed > 0 && --armed == 0;
}

void *__wrap_malloc(size_t size) { return fails() ? NULL : __real_malloc(size); }
void *__wrap_calloc(size_t count, size_t size) { return fails() ? NULL : __real_calloc(count, size); }
void *__wrap_realloc(void *p, size_t size) { return fails() ? NULL : __real_realloc(p, size); }
int __wrap_posix_memalign(void **p, size_t alignment, size_t size)
{
    if (!fails()) return __real_posix_memalign(p, alignment, size);
    aligned_failed++;
    return ENOMEM;
}

#define RING 24
#define CAP 400

/* A field armed with a finer lattice (vs_field_set_refine), where the finer lattice's build (its raster's scratch,
 * its cost array, its goal's Dijkstra: its blocked components are never resolved) runs out of memory at each of its
 * allocations in turn: the descent returns VS_ENOMEM, the finer lattice is not kept (vs_field_refined 0), and a later
 * descent, with memory, answers as a field that never ran out, bit for bit; so does the shape test, which answers 0
 * (shut) while the build fails.  The room: the ring above
 * with one obstacle left out, two robots 0.3 m apart; its lattice grown to cells of 19 cm (8,000 states) closes the
 * gap, the finer one (40,000 states, cells of 7.8 cm) opens it. */
static int refine_nomem(void)
{
    const double tpl[4] = {0.15, 0.0, -0.15, 0.0}, rad[2] = {0.03, 0.03};
    double obs[3 * RING], goal[3] = {0.0, 0.0, 0.0}, pose[3] = {2.0, 0.4, 1.0};
    for (int i = 1; i < RING; i++) {
        double a = 2.0 * VS_PI * (double)i / (double)RING;
        obs[3 * (i - 1)] = 0.9 * cos(a);
        obs[3 * (i - 1) + 1] = 0.9 * sin(a);
        obs[3 * (i - 1) + 2] = 0.15;
    }
    double w_ref[3 * CAP], w[3 * CAP], left_ref, left;
    size_t n_ref, n;
    int b_ref, b;
    vs_field ref;
    if (vs_field_build_deferred(tpl, rad, 2, 0.02, obs, RING - 1, goal, 0.05, 16, 8000, &ref) != VS_OK ||
        vs_field_follow(&ref, pose, 50.0, w_ref, CAP, &n_ref, &b_ref, &left_ref) != VS_OK || !b_ref ||
        vs_field_set_refine(&ref, tpl, rad, 2, obs, RING - 1, 0.05, 16, 40000) != VS_OK ||
        vs_field_follow(&ref, pose, 50.0, w_ref, CAP, &n_ref, &b_ref, &left_ref) != VS_OK || b_ref) {
        printf("refine: the room is not closed on its lattice and open on the finer one\n");
        return 1;
    }
    long failed = 0;
    for (long k = 1;; k++) {
        vs_field d;
        if (vs_field_build_deferred(tpl, rad, 2, 0.02, obs, RING - 1, goal, 0.05, 16, 8000, &d) != VS_OK ||
            vs_field_follow(&d, pose, 50.0, w, CAP, &n, &b, &left) != VS_OK ||   /* its own components resolved */
            vs_field_set_refine(&d, tpl, rad, 2, obs, RING - 1, 0.05, 16, 40000) != VS_OK) {
            printf("refine: the field failed with memory\n");
            return 1;
        }
        armed = k;
        int rc = vs_field_follow(&d, pose, 50.0, w, CAP, &n, &b, &left);
        int hit = armed == 0;
        armed = -1;
        if (hit) {
            failed++;
            if (rc != VS_ENOMEM || vs_field_refined(&d)) {
                printf("refine: allocation %ld failed: rc %d, a finer lattice %s\n", k, rc,
                       vs_field_refined(&d) ? "kept" : "not kept");
                return 1;
            }
            int tight = 0;
            armed = k;   /* the shape test, failing the same allocation: shut, nothing kept */
            int open = vs_field_open(&d, pose, &tight);
            armed = -1;
            if (open || vs_field_refined(&d)) {
                printf("refine: allocation %ld failed in the shape test: open %d\n", k, open);
                return 1;
            }
            rc = vs_field_follow(&d, pose, 50.0, w, CAP, &n, &b, &left);   /* again, with memory */
            if (rc == VS_OK && (!vs_field_open(&d, pose, &tight) || !vs_field_refined(&d))) {
                printf("refine: allocation %ld: with memory, the shape test is not open\n", k);
                return 1;
            }
        }
        if (rc != VS_OK || n != n_ref || b != b_ref || memcmp(&left, &left_ref, sizeof left) != 0 ||
            memcmp(w, w_ref, sizeof(double) * 3 * n) != 0) {
            printf("refine: allocation %ld: the descent differs from the one that never ran out\n", k);
            return 1;
        }
        vs_field_free(&d);
        if (!hit) break;
    }
    vs_field_free(&ref);
    printf("field_nomem: refine: %ld failed allocations, each VS_ENOMEM, then the same descent; ok\n", failed);
    return failed >= 3 ? 0 : 1;   /* the finer build's scratch, its cost array and its Dijkstra's buckets at least */
}

int main(void)
{
    const double tpl[6] = {0.2, 0.0, -0.1, 0.17, -0.1, -0.17}, rad[3] = {0.05, 0.05, 0.05};
    double obs[3 * RING], goal[3] = {0.0, 0.0, 0.0}, pose[3] = {2.0, 0.4, 1.0};
    for (int i = 0; i < RING; i++) {
        double a = 2.0 * VS_PI * (double)i / (double)RING;
        obs[3 * i] = 0.9 * cos(a);
        obs[3 * i + 1] = 0.9 * sin(a);
        obs[3 * i + 2] = 0.15;
    }
    vs_field whole;
    if (vs_field_build(tpl, rad, 3, 0.02, obs, RING, goal, 0.05, 16, 200000, &whole) != VS_OK) {
        printf("whole build failed\n");
        return 1;
    }
    double w_ref[3 * CAP], w[3 * CAP], left_ref, left;
    size_t n_ref, n;
    int b_ref, b;
    if (vs_field_follow(&whole, pose, 50.0, w_ref, CAP, &n_ref, &b_ref, &left_ref) != VS_OK || !b_ref) {
        printf("the whole build's descent is not blocked\n");
        return 1;
    }
    size_t total = whole.nx * whole.ny * whole.n_headings;
    long failed = 0;
    for (long k = 1;; k++) {
        vs_field d;
        if (vs_field_build_deferred(tpl, rad, 3, 0.02, obs, RING, goal, 0.05, 16, 200000, &d) != VS_OK) {
            printf("deferred build failed\n");
            return 1;
        }
        uint32_t *before = malloc(sizeof(uint32_t) * total);
        if (before == NULL) return 1;
        memcpy(before, d.cost, sizeof(uint32_t) * total);
        armed = k;
        int rc = vs_field_follow(&d, pose, 50.0, w, CAP, &n, &b, &left);
        int hit = armed == 0;   /* the k-th allocation was reached, and failed */
        armed = -1;
        if (hit) {
            failed++;
            if (rc != VS_ENOMEM || memcmp(before, d.cost, sizeof(uint32_t) * total) != 0) {
                printf("allocation %ld failed: rc %d, the field %s\n", k, rc,
                       memcmp(before, d.cost, sizeof(uint32_t) * total) ? "changed" : "as it was");
                return 1;
            }
            rc = vs_field_follow(&d, pose, 50.0, w, CAP, &n, &b, &left);   /* again, with memory */
        }
        if (rc != VS_OK || n != n_ref || b != b_ref || memcmp(&left, &left_ref, sizeof left) != 0 ||
            memcmp(w, w_ref, sizeof(double) * 3 * n) != 0) {
            printf("allocation %ld: the descent differs from the whole build's\n", k);
            return 1;
        }
        if (vs_field_resolve_all(&d) != VS_OK || memcmp(d.cost, whole.cost, sizeof(uint32_t) * total) != 0) {
            printf("allocation %ld: resolved costs differ from the whole build's\n", k);
            return 1;
        }
        free(before);
        vs_field_free(&d);
        if (!hit) break;   /* this resolution needs fewer than k allocations: every one has failed once */
    }
    vs_field_free(&whole);
    printf("field_nomem: %ld failed allocations, each left the field as it was; ok\n", failed);
    if (failed <= 2) return 1;   /* the listing and Dial's buckets both allocate */

    /* A build whose k-th allocation fails says VS_ENOMEM (and, under ASan, leaks nothing), for every k it reaches;
     * the lattice (about 630,000 states, 2.5 MB) is large enough for the cost array's huge-page path on Linux. */
    long build_failed = 0;
    for (long k = 1;; k++) {
        vs_field d;
        armed = k;
        int rc = vs_field_build_deferred(tpl, rad, 3, 0.02, obs, RING, goal, 0.02, 32, 1000000, &d);
        int hit = armed == 0;
        armed = -1;
        if (!hit) {
            if (rc != VS_OK || d.nx * d.ny * d.n_headings * sizeof(uint32_t) < ((size_t)1 << 21)) {
                printf("build: rc %d with memory, or a lattice under 2 MiB\n", rc);
                return 1;
            }
            vs_field_free(&d);
            break;
        }
        build_failed++;
        if (rc != VS_ENOMEM) {
            printf("build: allocation %ld failed, rc %d\n", k, rc);
            return 1;
        }
    }
#if defined(__linux__)
    if (aligned_failed < 1) {
        printf("build: the cost array did not come from posix_memalign\n");
        return 1;
    }
#endif
    printf("field_nomem: build: %ld failed allocations (%ld aligned), each VS_ENOMEM; ok\n", build_failed,
           aligned_failed);
    if (build_failed < 2) return 1;   /* the scratch and the cost array at least */
    return refine_nomem();
}
