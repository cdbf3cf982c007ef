/* CRC-16/CCITT-FALSE unit tests. */
#include "pfdoa_crc16.h"
#include "test_support.h"

static void test_check_value(void **state)
{
    (void)state;
    const uint8_t msg[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    assert_int_equal(pfdoa_crc16_update(PFDOA_CRC_INIT, msg, sizeof msg), 0x29B1);
}

static void test_empty_and_null(void **state)
{
    (void)state;
    assert_int_equal(pfdoa_crc16_update(PFDOA_CRC_INIT, NULL, 0u), 0xFFFF);
    /* NULL with a length is treated as no data, never dereferenced. */
    assert_int_equal(pfdoa_crc16_update(0x1234u, NULL, 5u), 0x1234);
}

static void test_incremental_equals_one_shot(void **state)
{
    (void)state;
    uint8_t buf[64];
    rng_t r = {0x12345678u};
    for (size_t i = 0u; i < sizeof buf; i++) {
        buf[i] = (uint8_t)rng_next(&r);
    }
    const uint16_t whole = pfdoa_crc16_update(PFDOA_CRC_INIT, buf, sizeof buf);
    for (size_t split = 0u; split <= sizeof buf; split++) {
        uint16_t c = pfdoa_crc16_update(PFDOA_CRC_INIT, buf, split);
        c = pfdoa_crc16_update(c, &buf[split], sizeof buf - split);
        assert_int_equal(c, whole);
    }
    uint16_t c = PFDOA_CRC_INIT;
    for (size_t i = 0u; i < sizeof buf; i++) {
        c = pfdoa_crc16_byte(c, buf[i]);
    }
    assert_int_equal(c, whole);
}

static void test_crc_extra_of_definitions(void **state)
{
    (void)state;
    /* CRC_EXTRA = low ^ high of the definition string's CRC (SPEC 1.6). */
    const char *const def = "CONFIG_ACK u8 token u8 result u16 config_hash";
    const uint16_t c = pfdoa_crc16_update(PFDOA_CRC_INIT, (const uint8_t *)def, strlen(def));
    assert_int_equal((c & 0xFFu) ^ (c >> 8), PFDOA_MSG_CONFIG_ACK_CRC_EXTRA);
}

static void test_detects_single_bit_flips(void **state)
{
    (void)state;
    uint8_t buf[16] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16};
    const uint16_t ref = pfdoa_crc16_update(PFDOA_CRC_INIT, buf, sizeof buf);
    for (size_t bit = 0u; bit < (8u * sizeof buf); bit++) {
        buf[bit / 8u] ^= (uint8_t)(1u << (bit % 8u));
        assert_int_not_equal(pfdoa_crc16_update(PFDOA_CRC_INIT, buf, sizeof buf), ref);
        buf[bit / 8u] ^= (uint8_t)(1u << (bit % 8u));
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_check_value),
        cmocka_unit_test(test_empty_and_null),
        cmocka_unit_test(test_incremental_equals_one_shot),
        cmocka_unit_test(test_crc_extra_of_definitions),
        cmocka_unit_test(test_detects_single_bit_flips),
    };
    return cmocka_run_group_tests_name("crc16", tests, NULL, NULL);
}
