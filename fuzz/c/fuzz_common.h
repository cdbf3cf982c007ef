/*
 * Shared by the libFuzzer harnesses in fuzz/c/: a CHECK that aborts (so libFuzzer and the
 * sanitizers report it), and, with -DFUZZ_STANDALONE, a main() that replays each file named
 * on the command line once (regression replay built by gcc with ASan+UBSan, no libFuzzer).
 */
#ifndef FUZZ_COMMON_H
#define FUZZ_COMMON_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#define CHECK(cond)                                                                          \
    do {                                                                                     \
        if (!(cond)) {                                                                       \
            (void)fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
            abort();                                                                         \
        }                                                                                    \
    } while (0)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Field by field: struct padding is indeterminate. */
#define CONFIG_EQ(a, b)                                                                          \
    (((a).offset_q8 == (b).offset_q8) && ((a).alpha_q8 == (b).alpha_q8) &&                       \
     ((a).spike_db == (b).spike_db) && ((a).report_mode == (b).report_mode) &&                   \
     ((a).decimation == (b).decimation))

#ifdef FUZZ_STANDALONE
int main(int argc, char **argv)
{
    static uint8_t buf[1 << 16];
    int n_files = 0;
    for (int k = 1; k < argc; k++) {
        FILE *const fp = fopen(argv[k], "rb");
        if (fp == NULL) {
            perror(argv[k]);
            return 2;
        }
        const size_t n = fread(buf, 1u, sizeof buf, fp);
        (void)fclose(fp);
        /* A copy of exactly n bytes, so ASan sees reads past the input's end. */
        uint8_t *const copy = (uint8_t *)malloc((n > 0u) ? n : 1u);
        CHECK(copy != NULL);
        for (size_t i = 0u; i < n; i++) {
            copy[i] = buf[i];
        }
        (void)LLVMFuzzerTestOneInput(copy, n);
        free(copy);
        n_files++;
    }
    (void)printf("%s: %d input(s) replayed, all checks passed\n", argv[0], n_files);
    return 0;
}
#endif

#endif /* FUZZ_COMMON_H */
