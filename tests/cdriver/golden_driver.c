/* golden_driver.c - replays tests/data/golden-core.txt through the core, no Python involved.
 *
 * Built natively at -O0/-O2/-O3 (tests/test_core_golden.py), cross-compiled for aarch64 and
 * run under qemu-aarch64 (make test-cross), and under AddressSanitizer/UBSan (make
 * test-sanitize).  Each line of the file is one call:
 *     <entry> <n_in> <inputs as C99 hex floats> <n_out> <expected outputs as hex floats>
 * and every output must come back bit for bit.  Exit status: 0 if all matched, 1 otherwise.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>

#include "vscore.h"
#include "vs_golden.h"

#define MAX_LINE (1 << 22)

static int same_bits(double a, double b) { return memcmp(&a, &b, sizeof a) == 0; }

int main(int argc, char **argv)
{
    if (argc != 2) { fprintf(stderr, "usage: %s golden-core.txt\n", argv[0]); return 2; }
    FILE *fp = fopen(argv[1], "r");
    if (!fp) { perror(argv[1]); return 2; }
    char *line = malloc(MAX_LINE);
    double *in = malloc(sizeof(double) * (MAX_LINE / 8)), *want = malloc(sizeof(double) * (MAX_LINE / 8)),
           *got = malloc(sizeof(double) * (MAX_LINE / 8));
    if (!line || !in || !want || !got) return 2;
    long records = 0, bad = 0, lineno = 0;
    while (fgets(line, MAX_LINE, fp)) {
        lineno++;
        if (line[0] == '#' || line[0] == '\n') continue;
        char *p = line, *end;
        char name[64];
        int used = 0;
        if (sscanf(p, "%63s%n", name, &used) != 1) continue;
        p += used;
        long n_in = strtol(p, &end, 10); p = end;
        for (long i = 0; i < n_in; i++) { in[i] = strtod(p, &end); p = end; }
        long n_out = strtol(p, &end, 10); p = end;
        for (long i = 0; i < n_out; i++) { want[i] = strtod(p, &end); p = end; }
        const golden_entry *e = golden_find(name);
        if (e == NULL) { fprintf(stderr, "line %ld: unknown entry %s\n", lineno, name); bad++; continue; }
        long n_got = e->run(in, n_in, got, MAX_LINE / 8);
        records++;
        if (n_got != n_out) {
            fprintf(stderr, "line %ld (%s): %ld outputs, want %ld\n", lineno, name, n_got, n_out);
            bad++;
            continue;
        }
        for (long i = 0; i < n_out; i++) {
            if (!same_bits(got[i], want[i])) {
                fprintf(stderr, "line %ld (%s): output %ld is %a, want %a\n", lineno, name, i, got[i], want[i]);
                bad++;
                break;
            }
        }
    }
    fclose(fp);
    free(line); free(in); free(want); free(got);
    printf("golden-core: %ld records, %ld mismatched\n", records, bad);
    return bad ? 1 : 0;
}
