/*
 * libFuzzer target: pfdoa_cobs_decode / pfdoa_cobs_encode on arbitrary bytes.
 * Checked beyond "no crash": decode writes at most dst_cap bytes (exact-size heap buffers,
 * so ASan sees one byte too many) and fails with CAPACITY when dst_cap is too small;
 * in-place decoding gives the same bytes; a decoded block re-encodes to a block that
 * decodes to the same bytes within the stated worst-case overhead; encode never emits a
 * zero and decode(encode(x)) == x.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_cobs.h"

static uint8_t *dup_exact(const uint8_t *src, size_t n)
{
    uint8_t *const p = (uint8_t *)malloc((n > 0u) ? n : 1u);
    CHECK(p != NULL);
    if (n > 0u) {
        memcpy(p, src, n);
    }
    return p;
}

/* Independent of cobs.c: a block is well formed iff it is non-empty, has no 0x00 and its
 * chain of code bytes ends exactly at its end. */
static int well_formed(const uint8_t *b, size_t n)
{
    if ((n == 0u) || (memchr(b, 0, n) != NULL)) {
        return 0;
    }
    size_t i = 0u;
    while (i < n) {
        i += b[i];
    }
    return i == n;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size > 4096u) {
        return 0;
    }
    /* 1. Decode the input as a block, out of place, with dst_cap == size (always enough). */
    uint8_t *const out = (uint8_t *)malloc((size > 0u) ? size : 1u);
    CHECK(out != NULL);
    const int32_t n = pfdoa_cobs_decode(data, size, out, size);
    CHECK((n >= 0) ? well_formed(data, size) : (n == PFDOA_ERR_BAD_COBS) && !well_formed(data, size));
    if (n >= 0) {
        const size_t dn = (size_t)n;
        CHECK(dn < size); /* a block is at least one byte longer than what it decodes to */
        /* In place: same result. */
        uint8_t *const inplace = dup_exact(data, size);
        CHECK(pfdoa_cobs_decode(inplace, size, inplace, size) == n);
        CHECK(memcmp(inplace, out, dn) == 0);
        free(inplace);
        /* One byte short of room: CAPACITY, never a write past dst_cap. */
        if (dn > 0u) {
            uint8_t *const small = (uint8_t *)malloc(dn - 1u + 1u);
            CHECK(small != NULL);
            CHECK(pfdoa_cobs_decode(data, size, small, dn - 1u) == PFDOA_ERR_CAPACITY);
            free(small);
        }
        /* Exact room works. */
        uint8_t *const exact = (uint8_t *)malloc((dn > 0u) ? dn : 1u);
        CHECK(exact != NULL);
        CHECK(pfdoa_cobs_decode(data, size, exact, dn) == n);
        free(exact);
        /* Re-encode: bounded, no zeros, decodes back to the same bytes. */
        const size_t cap = PFDOA_COBS_MAX_ENCODED(dn);
        uint8_t *const enc = (uint8_t *)malloc(cap);
        CHECK(enc != NULL);
        const int32_t e = pfdoa_cobs_encode(out, dn, enc, cap);
        CHECK((e >= 1) && ((size_t)e <= cap) && ((size_t)e <= size));
        CHECK(memchr(enc, 0, (size_t)e) == NULL);
        uint8_t *const back = (uint8_t *)malloc((dn > 0u) ? dn : 1u);
        CHECK(back != NULL);
        CHECK(pfdoa_cobs_decode(enc, (size_t)e, back, dn) == n);
        CHECK((dn == 0u) || (memcmp(back, out, dn) == 0));
        free(back);
        free(enc);
    } else {
        CHECK(n == PFDOA_ERR_BAD_COBS);
    }
    free(out);

    /* 2. Encode the input as data: exact worst-case buffer, then round trip. */
    const size_t cap = PFDOA_COBS_MAX_ENCODED(size);
    uint8_t *const enc = (uint8_t *)malloc(cap);
    CHECK(enc != NULL);
    const int32_t e = pfdoa_cobs_encode(data, size, enc, cap);
    CHECK((e >= 1) && ((size_t)e <= cap));
    CHECK(memchr(enc, 0, (size_t)e) == NULL);
    if ((size_t)e > 1u) {
        CHECK(pfdoa_cobs_encode(data, size, enc, (size_t)e - 1u) == PFDOA_ERR_CAPACITY);
    }
    uint8_t *const dec = (uint8_t *)malloc((size > 0u) ? size : 1u);
    CHECK(dec != NULL);
    CHECK(pfdoa_cobs_decode(enc, (size_t)e, dec, size) == (int32_t)size);
    CHECK((size == 0u) || (memcmp(dec, data, size) == 0));
    free(dec);
    free(enc);
    return 0;
}
