/*
 * The beacon image (beacon_app.c, radio_tx.c: the robot's authenticated rolling beacon,
 * protocol/SPEC.md 9) with the real beacon module and core, on the register fake: it sends
 * nothing until it has a key and the time; provisioning lines on the UART; each
 * advertisement goes out on 37, 38 and 39 with the channel's frequency and whitening, the
 * bytes the beacon's builders make (golden-vector checked in firmware/tests), its address
 * rolling with the period; what it sends, an anchor core with the key verifies; the key
 * survives a power cycle in flash, the time does not; bad lines get ERR; a stuck radio is
 * an error, not a hang.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "beacon_app.h"
#include "fake_nrf.h"
#include "nrf_test_support.h"
#include "pfdoa_anchor.h"

static const char KEY_HEX[] = "000102030405060708090a0b0c0d0e0f";
static const uint8_t KEY[PFDOA_AUTH_KEY_LEN] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};
#define C0 432900000u

static uint32_t rx_filled;

static int setup(void **state)
{
    (void)state;
    nrf_fake_reset();
    rx_filled = 0u;
    return 0;
}

static void at_ms(uint64_t ms)
{
    nrf_fake_rtc_advance_to(test_rtc_ticks_of_ms(ms), RTC1_IRQHandler);
}

/* A line from the host, then main-loop passes until the reply is out; the reply text. */
static const char *say(const char *line, char *reply, size_t cap)
{
    char buf[96];
    const int n = snprintf(buf, sizeof buf, "%s\n", line);
    assert_true(n > 0 && (size_t)n < sizeof buf);
    (void)test_uarte_rx((const uint8_t *)buf, (size_t)n, &rx_filled, UARTE0_UART0_IRQHandler);
    test_uarte_stop_flush(&rx_filled, NULL, 0u, UARTE0_UART0_IRQHandler);
    size_t got = 0u;
    for (int pass = 0; pass < 4; ++pass) {
        beacon_app_step();
        got += test_uarte_drain_tx((uint8_t *)&reply[got], cap - 1u - got, UARTE0_UART0_IRQHandler);
    }
    reply[got] = '\0';
    return reply;
}

static void provision(uint32_t counter, uint32_t phase)
{
    char reply[64];
    char line[64];
    assert_string_equal(say("K 000102030405060708090a0b0c0d0e0f", reply, sizeof reply), "OK K ec5ad48c\n");
    (void)snprintf(line, sizeof line, "T %u %u", (unsigned)counter, (unsigned)phase);
    char want[32];
    (void)snprintf(want, sizeof want, "OK T %u\n", (unsigned)counter);
    assert_string_equal(say(line, reply, sizeof reply), want);
}

static void test_silent_without_key_and_time(void **state)
{
    (void)state;
    assert_int_equal(beacon_app_init(), BEACON_OK);
    for (uint64_t t = 0u; t < 1000u; t += 10u) {
        at_ms(t);
        beacon_app_step();
    }
    assert_int_equal(nrf_fake.tx_count, 0u);
    char reply[64];
    assert_string_equal(say("S", reply, sizeof reply), "S - - 0 0\n");
    assert_string_equal(say("T 5 0", reply, sizeof reply), "ERR no key\n");
    assert_string_equal(say("K 00", reply, sizeof reply), "ERR unknown command (K, T, S)\n");
    assert_string_equal(say("K 000102030405060708090a0b0c0d0e0g", reply, sizeof reply), "ERR key: 32 hex digits\n");
    assert_string_equal(say("K 000102030405060708090a0b0c0d0e0f00000000000000000000", reply, sizeof reply),
                        "ERR line too long\n");
    /* A key but no time: still nothing on the air. */
    assert_string_equal(say("K 000102030405060708090a0b0c0d0e0f", reply, sizeof reply), "OK K ec5ad48c\n");
    assert_string_equal(say("T 5 4096", reply, sizeof reply), "ERR time: T <counter> <phase_ms 0..4095>\n");
    assert_string_equal(say("T 4294967296 0", reply, sizeof reply), "ERR time: T <counter> <phase_ms 0..4095>\n");
    for (uint64_t t = 1000u; t < 1500u; t += 10u) {
        at_ms(t);
        beacon_app_step();
    }
    assert_int_equal(nrf_fake.tx_count, 0u);
    assert_int_equal(beacon_app_get()->refused, 6u);
    assert_int_equal(beacon_app_get()->commands, 2u);
}

static void test_advertising_events_on_three_channels_that_an_anchor_verifies(void **state)
{
    (void)state;
    assert_int_equal(beacon_app_init(), BEACON_OK);
    provision(C0, 3950u); /* the next period begins 146 ms from now */
    const uint32_t start = beacon_app_get()->beacon.seq;
    for (uint64_t t = 0u; t <= 300u; t += 5u) {
        at_ms(t);
        beacon_app_step();
    }
    /* 100 ms interval from the first poll (at the key, before the time): advertisements at
     * 100 (period C0), 200 and 300 ms (C0 + 1); each an event of three PDUs. */
    assert_int_equal(nrf_fake.tx_count, 9u);
    static const uint32_t freq[3] = {2u, 26u, 80u};
    for (uint32_t i = 0u; i < nrf_fake.tx_count; ++i) {
        const nrf_fake_tx_t *const t = &nrf_fake.tx[i];
        assert_int_equal(t->frequency, freq[i % 3u]);
        assert_int_equal(t->whiteiv, 37u + i % 3u);
        assert_int_equal(t->txpower, 0u);
        assert_int_equal(t->len, PFDOA_BEACON_AUTH_PDU_LEN);
        assert_memory_equal(t->data, nrf_fake.tx[i - i % 3u].data, t->len); /* the same PDU in one event */
    }
    /* The first advertisement is the beacon's builder's for (C0, seq); the next ones are of
     * the next period: its address. */
    pfdoa_hmac_key_t k;
    pfdoa_hmac_init(&k, KEY, sizeof KEY);
    pfdoa_auth_ids_t ids;
    pfdoa_auth_derive(&k, C0, &ids);
    uint8_t want[PFDOA_BEACON_AUTH_PDU_LEN];
    assert_int_equal(pfdoa_beacon_auth_adv_pdu(&k, &ids, C0, (uint16_t)start, want, sizeof want),
                     (int32_t)sizeof want);
    assert_memory_equal(nrf_fake.tx[0].data, want, sizeof want);
    assert_memory_not_equal(&nrf_fake.tx[3].data[2], ids.adv_a, 6u);
    pfdoa_auth_derive(&k, C0 + 1u, &ids);
    assert_memory_equal(&nrf_fake.tx[3].data[2], ids.adv_a, 6u);
    assert_memory_equal(&nrf_fake.tx[6].data[2], ids.adv_a, 6u);
    /* An anchor holding the key reports the three events; the replay of the first is rejected. */
    pfdoa_anchor_t a;
    assert_int_equal(pfdoa_anchor_init(&a, NULL, 2u, PFDOA_TRANSPORT_UART), PFDOA_OK);
    pfdoa_beacon_filter_t f;
    memset(&f, 0, sizeof f);
    f.kind = PFDOA_FILTER_PFDOA_AUTH;
    memcpy(f.match, KEY, sizeof KEY);
    (void)pfdoa_anchor_set_filter(&a, 0u, &f);
    for (uint32_t i = 0u; i < nrf_fake.tx_count; ++i) {
        const pfdoa_rx_t rx = {100u + 100u * (i / 3u) + i % 3u, -60, (uint8_t)(37u + i % 3u), 0u};
        assert_int_equal(pfdoa_anchor_on_ble_pdu(&a, &rx, nrf_fake.tx[i].data, nrf_fake.tx[i].len), 1);
    }
    const pfdoa_rx_t late = {500u, -40, 37u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&a, &late, nrf_fake.tx[0].data, nrf_fake.tx[0].len), 0);
    assert_int_equal(pfdoa_anchor_auth_rejected(&a, PFDOA_AUTH_REPLAYED), 1u);
    char reply[64];
    char want_s[64];
    (void)snprintf(want_s, sizeof want_s, "S ec5ad48c %u 3 0\n", (unsigned)(C0 + 1u));
    assert_string_equal(say("S", reply, sizeof reply), want_s);
}

static void test_key_survives_a_power_cycle_the_time_does_not(void **state)
{
    (void)state;
    assert_int_equal(beacon_app_init(), BEACON_OK);
    provision(C0, 0u);
    at_ms(100u);
    beacon_app_step();
    assert_int_equal(nrf_fake.tx_count, 3u);
    assert_true(nrf_fake.flash_writes > 0u);
    uint32_t pages[NRF_STORE_PAGES][NRF_FLASH_PAGE_SIZE / 4u];
    memcpy(pages, nrf_fake_store_pages, sizeof pages);
    nrf_fake_reset();
    rx_filled = 0u;
    memcpy(nrf_fake_store_pages, pages, sizeof pages);
    assert_int_equal(beacon_app_init(), BEACON_OK);
    char reply[64];
    assert_string_equal(say("S", reply, sizeof reply), "S ec5ad48c - 0 0\n"); /* the key, no time */
    for (uint64_t t = 0u; t < 500u; t += 10u) {
        at_ms(t);
        beacon_app_step();
    }
    assert_int_equal(nrf_fake.tx_count, 0u);
    assert_string_equal(say("T 432900100 17", reply, sizeof reply), "OK T 432900100\n");
    at_ms(600u);
    beacon_app_step();
    assert_int_equal(nrf_fake.tx_count, 3u);
    /* The stored record holds the key, nothing else; the UART never echoed it. */
    assert_int_equal(nrf_fake.flash_violations, 0u);
    (void)KEY_HEX;
}

static void test_a_stuck_radio_is_counted_not_a_hang(void **state)
{
    (void)state;
    assert_int_equal(beacon_app_init(), BEACON_OK);
    provision(C0, 0u);
    nrf_fake.radio_tx_stuck = 1;
    at_ms(100u);
    beacon_app_step();
    assert_int_equal(beacon_app_get()->tx.timeouts, 3u);
    assert_int_equal(pfdoa_beacon_send_failures(&beacon_app_get()->beacon), 1u);
    nrf_fake.radio_tx_stuck = 0;
    at_ms(200u);
    beacon_app_step();
    assert_int_equal(pfdoa_beacon_sent(&beacon_app_get()->beacon), 1u);
    assert_int_equal(radio_tx_ble_event(&beacon_app_get()->tx, nrf_fake.tx[0].data, 2u, 0), RADIO_TX_ERR_ARG);
}

static void test_tx_power_levels_and_no_crystal(void **state)
{
    (void)state;
    assert_int_equal(radio_tx_power(8), 8u);
    assert_int_equal(radio_tx_power(1), 0u);
    assert_int_equal(radio_tx_power(-5), 0xF8u); /* -8 */
    assert_int_equal(radio_tx_power(-100), 0xD8u); /* -40 */
    nrf_fake.hfxo_fails = 1;
    assert_int_equal(beacon_app_init(), BEACON_ERR_HFXO);
    provision(C0, 0u); /* provisioning still answers */
    at_ms(100u);
    beacon_app_step();
    assert_int_equal(nrf_fake.tx_count, 0u);
    assert_int_equal(pfdoa_beacon_send_failures(&beacon_app_get()->beacon), 1u);
}

static void test_idle_sleeps_until_the_next_advertisement(void **state)
{
    (void)state;
    assert_int_equal(beacon_app_init(), BEACON_OK);
    provision(C0, 0u);
    at_ms(10u);
    beacon_app_step();
    const uint32_t wfi = nrf_fake.wfi_count;
    /* The UART has just had its lines and is collecting: a short sleep until it is quiet. */
    beacon_app_idle();
    assert_int_equal(nrf_fake.wfi_count, wfi + 1u);
    assert_int_equal(nrf_fake.wfi_unmasked, 0u);
    uint32_t ahead = (nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu;
    assert_int_equal(ahead, rtc_tick_from_ms(2u));
    test_uarte_stop_flush(&rx_filled, NULL, 0u, UARTE0_UART0_IRQHandler);
    beacon_app_step();
    beacon_app_idle();
    assert_int_equal(nrf_fake.wfi_count, wfi + 2u);
    /* The wake-up compare is about 100 ms on (the next advertisement is due at 110 ms). */
    ahead = (nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu;
    assert_true(ahead >= rtc_tick_from_ms(89u) && ahead <= rtc_tick_from_ms(91u));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_silent_without_key_and_time, setup),
        cmocka_unit_test_setup(test_advertising_events_on_three_channels_that_an_anchor_verifies, setup),
        cmocka_unit_test_setup(test_key_survives_a_power_cycle_the_time_does_not, setup),
        cmocka_unit_test_setup(test_a_stuck_radio_is_counted_not_a_hang, setup),
        cmocka_unit_test_setup(test_tx_power_levels_and_no_crystal, setup),
        cmocka_unit_test_setup(test_idle_sleeps_until_the_next_advertisement, setup),
    };
    return cmocka_run_group_tests_name("nrf52840 beacon", tests, NULL, NULL);
}
