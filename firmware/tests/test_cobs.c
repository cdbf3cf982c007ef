/* COBS unit tests: group boundaries, errors, bounds, in-place decoding. */
#include "pfdoa_cobs.h"
#include "test_support.h"

#define BIG 1200u

/* n non-zero bytes 1, 2, ..., 255, 1, ... */
static void fill_nonzero(uint8_t *const buf, const size_t n)
{
    for (size_t i = 0u; i < n; i++) {
        buf[i] = (uint8_t)((i % 255u) + 1u);
    }
}

static void roundtrip(const uint8_t *const src, const size_t n, const int32_t want_len)
{
    static uint8_t enc[BIG + 16u], dec[BIG + 16u];
    const int32_t e = pfdoa_cobs_encode(src, n, enc, sizeof enc);
    assert_int_equal(e, want_len);
    assert_true((size_t)e <= PFDOA_COBS_MAX_ENCODED(n));
    assert_null(memchr(enc, 0, (size_t)e));
    assert_int_equal(pfdoa_cobs_decode(enc, (size_t)e, dec, sizeof dec), (int32_t)n);
    if (n > 0u) {
        assert_memory_equal(dec, src, n);
    }
}

static void test_boundaries_253_254_255(void **state)
{
    (void)state;
    static uint8_t src[BIG];
    fill_nonzero(src, sizeof src);
    static uint8_t enc[BIG + 16u];

    /* 253 non-zero bytes: one group, code 0xFE. */
    roundtrip(src, 253u, 254);
    assert_int_equal(pfdoa_cobs_encode(src, 253u, enc, sizeof enc), 254);
    assert_int_equal(enc[0], 0xFE);

    /* 254: one full group, code 0xFF, no trailing code byte. */
    roundtrip(src, 254u, 255);
    (void)pfdoa_cobs_encode(src, 254u, enc, sizeof enc);
    assert_int_equal(enc[0], 0xFF);

    /* 255: a full group, then a one-byte group (code 0x02). */
    roundtrip(src, 255u, 257);
    (void)pfdoa_cobs_encode(src, 255u, enc, sizeof enc);
    assert_int_equal(enc[0], 0xFF);
    assert_int_equal(enc[255], 0x02);
    assert_int_equal(enc[256], src[254]);

    /* 254 then a zero: a full group has no implied zero, so the zero takes an empty
     * group (0x01) and the empty tail after it another (0x01). */
    static uint8_t z[255];
    fill_nonzero(z, 254u);
    z[254] = 0u;
    roundtrip(z, 255u, 257);
    (void)pfdoa_cobs_encode(z, 255u, enc, sizeof enc);
    assert_int_equal(enc[255], 0x01);
    assert_int_equal(enc[256], 0x01);

    /* Two full groups exactly, and the worst case bound. */
    roundtrip(src, 508u, 510);
    roundtrip(src, 1000u, (int32_t)PFDOA_COBS_MAX_ENCODED(1000u));
}

static void test_zeros(void **state)
{
    (void)state;
    static const uint8_t zeros[8] = {0};
    for (size_t n = 0u; n <= sizeof zeros; n++) {
        roundtrip(zeros, n, (int32_t)n + 1);
    }
}

static void test_capacity_and_arguments(void **state)
{
    (void)state;
    uint8_t src[10] = {1, 2, 3, 0, 5, 6, 7, 8, 9, 10};
    uint8_t out[16];
    assert_int_equal(pfdoa_cobs_encode(src, sizeof src, out, 10u), PFDOA_ERR_CAPACITY);
    assert_int_equal(pfdoa_cobs_encode(NULL, 3u, out, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_cobs_encode(src, 3u, NULL, 8u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_cobs_decode(NULL, 3u, out, sizeof out), PFDOA_ERR_ARG);
    const int32_t n = pfdoa_cobs_encode(src, sizeof src, out, sizeof out);
    assert_int_equal(n, 11);
    /* Decoding into a buffer one byte short fails without writing past it. */
    uint8_t dst[10];
    uint8_t guard[4] = {0xAA, 0xAA, 0xAA, 0xAA};
    assert_int_equal(pfdoa_cobs_decode(out, (size_t)n, dst, 9u), PFDOA_ERR_CAPACITY);
    assert_int_equal(guard[0], 0xAA);
}

static void test_decode_errors(void **state)
{
    (void)state;
    uint8_t out[16];
    const uint8_t past_end[] = {0x05, 0x11, 0x22, 0x33};
    const uint8_t zero_inside[] = {0x02, 0x11, 0x00, 0x33, 0x01};
    const uint8_t zero_code[] = {0x00};
    assert_int_equal(pfdoa_cobs_decode(past_end, sizeof past_end, out, sizeof out), PFDOA_ERR_BAD_COBS);
    assert_int_equal(pfdoa_cobs_decode(zero_inside, sizeof zero_inside, out, sizeof out), PFDOA_ERR_BAD_COBS);
    assert_int_equal(pfdoa_cobs_decode(zero_code, sizeof zero_code, out, sizeof out), PFDOA_ERR_BAD_COBS);
    assert_int_equal(pfdoa_cobs_decode(out, 0u, out, sizeof out), PFDOA_ERR_BAD_COBS);
}

static void test_random_roundtrip_in_place(void **state)
{
    (void)state;
    rng_t r = {0xC0B5u};
    static uint8_t src[600], enc[700], work[700];
    for (int iter = 0; iter < 2000; iter++) {
        const size_t n = (size_t)rng_range(&r, 0, 600);
        const uint32_t zero_bias = rng_next(&r) % 4u; /* vary zero density */
        for (size_t i = 0u; i < n; i++) {
            const uint32_t x = rng_next(&r);
            src[i] = ((x >> 8) % 8u < zero_bias) ? 0u : (uint8_t)x;
        }
        const int32_t e = pfdoa_cobs_encode(src, n, enc, sizeof enc);
        assert_true(e >= 1);
        assert_true((size_t)e <= PFDOA_COBS_MAX_ENCODED(n));
        memcpy(work, enc, (size_t)e);
        assert_int_equal(pfdoa_cobs_decode(work, (size_t)e, work, (size_t)e), (int32_t)n);
        if (n > 0u) {
            assert_memory_equal(work, src, n);
        }
    }
}

static void test_random_blocks_stay_in_bounds(void **state)
{
    (void)state;
    /* Exact-size heap copies make ASan catch any read past len or write past dst_cap. */
    rng_t r = {0xB0B0u};
    for (int iter = 0; iter < 20000; iter++) {
        const size_t len = (size_t)rng_range(&r, 0, 80);
        const size_t cap = (size_t)rng_range(&r, 0, 80);
        uint8_t *const in = malloc(len + 1u);
        uint8_t *const out = malloc(cap + 1u);
        assert_non_null(in);
        assert_non_null(out);
        for (size_t i = 0u; i < len; i++) {
            in[i] = (uint8_t)(rng_next(&r) % 16u); /* small codes: many groups, some zeros */
        }
        const int32_t n = pfdoa_cobs_decode(in, len, out, cap);
        assert_true((n <= (int32_t)cap) && (n <= (int32_t)len));
        free(in);
        free(out);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_boundaries_253_254_255),
        cmocka_unit_test(test_zeros),
        cmocka_unit_test(test_capacity_and_arguments),
        cmocka_unit_test(test_decode_errors),
        cmocka_unit_test(test_random_roundtrip_in_place),
        cmocka_unit_test(test_random_blocks_stay_in_bounds),
    };
    return cmocka_run_group_tests_name("cobs", tests, NULL, NULL);
}
