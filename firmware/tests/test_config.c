/* Configuration: defaults, validation ranges, packing, hash. */
#include "pfdoa_config.h"
#include "pfdoa_msg.h"
#include "test_support.h"

static void test_defaults_and_hash(void **state)
{
    (void)state;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    assert_int_equal(c.offset_q8, 0);
    assert_int_equal(c.alpha_q8, 64);
    assert_int_equal(c.spike_db, 12);
    assert_int_equal(c.report_mode, 0);
    assert_int_equal(c.decimation, 1);
    uint8_t b[PFDOA_CONFIG_LEN];
    pfdoa_config_pack(&c, b);
    const uint8_t want[PFDOA_CONFIG_LEN] = {0x00, 0x00, 0x40, 0x00, 0x0c, 0x00, 0x01};
    assert_memory_equal(b, want, sizeof want);
    assert_int_equal(pfdoa_config_hash(&c), PFDOA_CONFIG_DEFAULT_HASH); /* generator: CRC-16 in Python */
    assert_int_equal(pfdoa_config_validate(&c), PFDOA_OK);
    assert_int_equal(pfdoa_config_hash(NULL), 0);
}

static void test_validation_ranges(void **state)
{
    (void)state;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    const uint16_t alphas[] = {0u, 1u, 256u, 257u, 65535u};
    const int32_t alpha_ok[] = {PFDOA_ERR_ARG, PFDOA_OK, PFDOA_OK, PFDOA_ERR_ARG, PFDOA_ERR_ARG};
    for (size_t i = 0u; i < 5u; i++) {
        pfdoa_config_t t = c;
        t.alpha_q8 = alphas[i];
        assert_int_equal(pfdoa_config_validate(&t), alpha_ok[i]);
    }
    for (uint16_t m = 0u; m <= 255u; m++) {
        pfdoa_config_t t = c;
        t.report_mode = (uint8_t)m;
        assert_int_equal(pfdoa_config_validate(&t), (m <= 2u) ? PFDOA_OK : PFDOA_ERR_ARG);
        t = c;
        t.decimation = (uint8_t)m;
        assert_int_equal(pfdoa_config_validate(&t), (m >= 1u) ? PFDOA_OK : PFDOA_ERR_ARG);
        t = c;
        t.spike_db = (uint8_t)m; /* any */
        assert_int_equal(pfdoa_config_validate(&t), PFDOA_OK);
    }
    pfdoa_config_t t = c;
    t.offset_q8 = INT16_MIN;
    assert_int_equal(pfdoa_config_validate(&t), PFDOA_OK);
    assert_int_equal(pfdoa_config_validate(NULL), PFDOA_ERR_ARG);
}

static void test_unpack_keeps_config_on_error(void **state)
{
    (void)state;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    const pfdoa_config_t before = c;
    const uint8_t bad_alpha[PFDOA_CONFIG_LEN] = {0x80, 0xFE, 0x01, 0x01, 6, 1, 4}; /* alpha 257 */
    assert_int_equal(pfdoa_config_unpack(bad_alpha, &c), PFDOA_ERR_ARG);
    assert_memory_equal(&c, &before, sizeof c);
    const uint8_t good[PFDOA_CONFIG_LEN] = {0x80, 0xFE, 0x80, 0x00, 6, 1, 4};
    assert_int_equal(pfdoa_config_unpack(good, &c), PFDOA_OK);
    assert_int_equal(c.offset_q8, -384);
    assert_int_equal(c.alpha_q8, 128);
    assert_int_equal(c.spike_db, 6);
    assert_int_equal(c.report_mode, 1);
    assert_int_equal(c.decimation, 4);
    uint8_t back[PFDOA_CONFIG_LEN];
    pfdoa_config_pack(&c, back);
    assert_memory_equal(back, good, sizeof good);
    assert_int_equal(pfdoa_config_unpack(NULL, &c), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_config_unpack(good, NULL), PFDOA_ERR_ARG);
}

static void test_config_set_payload(void **state)
{
    (void)state;
    const uint8_t payload[PFDOA_MSG_CONFIG_SET_LEN] = {0x33, 0x00, 0x02, 0x00, 0x01, 0x00, 0x02, 0xFF};
    uint8_t token = 0u;
    pfdoa_config_t c;
    assert_int_equal(pfdoa_msg_unpack_config_set(payload, &token, &c), PFDOA_OK);
    assert_int_equal(token, 0x33);
    assert_int_equal(c.offset_q8, 512);
    assert_int_equal(c.alpha_q8, 256);
    assert_int_equal(c.report_mode, 2);
    assert_int_equal(c.decimation, 255);
    const uint8_t dec0[PFDOA_MSG_CONFIG_SET_LEN] = {0x34, 0x00, 0x00, 0x40, 0x00, 0x0c, 0x01, 0x00};
    assert_int_equal(pfdoa_msg_unpack_config_set(dec0, &token, &c), PFDOA_ERR_ARG);
    assert_int_equal(token, 0x34); /* the ack still echoes the token */
    assert_int_equal(c.decimation, 255);
}

static void test_hash_distinguishes_fields(void **state)
{
    (void)state;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    const uint16_t h0 = pfdoa_config_hash(&c);
    pfdoa_config_t t = c;
    t.offset_q8 = 1;
    assert_int_not_equal(pfdoa_config_hash(&t), h0);
    t = c;
    t.decimation = 2;
    assert_int_not_equal(pfdoa_config_hash(&t), h0);
    t = c;
    t.spike_db = 13;
    assert_int_not_equal(pfdoa_config_hash(&t), h0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_defaults_and_hash),
        cmocka_unit_test(test_validation_ranges),
        cmocka_unit_test(test_unpack_keeps_config_on_error),
        cmocka_unit_test(test_config_set_payload),
        cmocka_unit_test(test_hash_distinguishes_fields),
    };
    return cmocka_run_group_tests_name("config", tests, NULL, NULL);
}
