/* Host tooling: the event-script interpreter and the batch-mode `init` parser. */
#include "script.h"
#include "test_support.h"

static void test_parse_init(void **state)
{
    (void)state;
    script_init_t in;
    char err[96];
    assert_int_equal(script_parse_init(" {\"anchor_id\": 5}", &in, err, sizeof err), 0);
    assert_int_equal(in.anchor_id, 5);
    assert_int_equal(in.transports, PFDOA_TRANSPORT_UART);
    assert_int_equal(in.store_ok, 1);
    assert_int_equal(in.has_config, 0);
    assert_int_equal(script_parse_init("{\"anchor_id\":126,\"transport\":\"both\",\"boot_tick_ms\":4294967295,"
                                       "\"fw_major\":1,\"fw_minor\":0,\"store_ok\":false,\"sil_inject\":true,"
                                       "\"config\":{\"offset_q8\":-32768,\"alpha_q8\":256,\"spike_db\":0,"
                                       "\"report_mode\":2,\"decimation\":255}}",
                                       &in, err, sizeof err),
                     0);
    assert_int_equal(in.transports, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN);
    assert_int_equal(in.boot_tick, UINT32_MAX);
    assert_int_equal(in.store_ok, 0);
    assert_int_equal(in.sil_inject, 1);
    assert_int_equal(in.has_config, 1);
    assert_int_equal(in.config.offset_q8, INT16_MIN);
    assert_int_equal(in.config.decimation, 255);
    static const char *const bad[] = {
        "",
        "{}",                                   /* anchor_id required */
        "{\"anchor_id\":127}",                  /* broadcast is not an anchor */
        "{\"anchor_id\":-1}",
        "{\"anchor_id\":1.5}",
        "{\"anchor_id\":1,}",
        "{\"anchor_id\":1} x",
        "{\"anchor_id\":1,\"transport\":\"spi\"}",
        "{\"anchor_id\":1,\"boot_tick_ms\":4294967296}",
        "{\"anchor_id\":1,\"store_ok\":1}",
        "{\"anchor_id\":1,\"config\":{\"alpha_q8\":257}}",
        "{\"anchor_id\":1,\"config\":{\"speed\":1}}",
        "{\"anchor_id\":1,\"extra\":0}",
        "{\"anchor_id\":1,\"transport\":\"u\\\"art\"}",
        "{\"anchor_id\"",
    };
    for (size_t i = 0u; i < sizeof bad / sizeof bad[0]; i++) {
        err[0] = '\0';
        if (script_parse_init(bad[i], &in, err, sizeof err) == 0) {
            fail_msg("accepted bad init %s", bad[i]);
        }
        assert_true(err[0] != '\0');
    }
}

static size_t emitted;

static void count_line(void *const user, const char *const line)
{
    (void)user;
    assert_true((line[0] == 'U') || (line[0] == 'C'));
    emitted++;
}

static void test_run_lines(void **state)
{
    (void)state;
    script_env_t env;
    memset(&env, 0, sizeof env);
    env.emit = count_line;
    pfdoa_hal_t hal;
    script_hal(&env, &hal);
    pfdoa_anchor_t a;
    assert_int_equal(pfdoa_anchor_init(&a, &hal, 5u, PFDOA_TRANSPORT_UART), PFDOA_OK);
    uint8_t scratch[64];
    static const char *const good[] = {
        "P 0", "", "   # comment", "R 10 1 -60 37 0 0", "R 11 1 -61 38 0 0 # trailing comment",
        "U 20 00ff00", "C 30 185 0000400", /* odd hex: rejected below, so not here */
    };
    emitted = 0u;
    for (size_t i = 0u; i < 6u; i++) {
        char line[64];
        strcpy(line, good[i]);
        assert_int_equal(script_run_line(&a, line, scratch, sizeof scratch), 0);
    }
    assert_int_equal(emitted, 1u); /* the first STATUS */
    static const char *const bad[] = {
        "X 1", "P", "P -1", "P 4294967296", "R 1 2 3", "R 1 65536 -60 37 0 0", "R 1 1 -129 37 0 0",
        "R 1 1 -60 256 0 0", "U 1 0", "U 1 zz", "C 1 85 00", "C 1 800 00", "C 1 185 000000000000000000",
        "C 30 185 0000400",
    };
    for (size_t i = 0u; i < sizeof bad / sizeof bad[0]; i++) {
        char line[64];
        strcpy(line, bad[i]);
        if (script_run_line(&a, line, scratch, sizeof scratch) == 0) {
            fail_msg("accepted bad line %s", bad[i]);
        }
    }
    /* Stored configuration strings. */
    assert_int_equal(script_set_stored_config(&env, "512,128,6,1,4"), 0);
    assert_int_equal(env.have_stored, 1);
    assert_int_equal(script_set_stored_config(&env, "0,0,6,1,4"), -1);
    assert_int_equal(script_set_stored_config(&env, "0,64,12,0"), -1);
    assert_int_equal(script_set_stored_config(&env, "0,64,12,0,1,1"), -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_parse_init),
        cmocka_unit_test(test_run_lines),
    };
    return cmocka_run_group_tests_name("script (host tooling)", tests, NULL, NULL);
}
