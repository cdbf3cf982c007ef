/*
 * Anchor instance through its public API: init arguments, stored configuration, events,
 * reports, STATUS, CONFIG_SET over UART and CAN, transports, counters, HAL failures.
 * Also built with PFDOA_SIL_INJECT (test_anchor_sil) for the RADIO_INJECT path.
 */
#include "pfdoa_anchor.h"
#include "pfdoa_cobs.h"
#include "test_support.h"

typedef struct fixture {
    capture_t cap;
    pfdoa_hal_t hal;
    pfdoa_anchor_t a;
} fixture_t;

static fixture_t fx;

static void setup_anchor(const uint8_t id, const uint8_t transports)
{
    memset(&fx, 0, sizeof fx);
    fx.hal = cap_hal(&fx.cap);
    assert_int_equal(pfdoa_anchor_init(&fx.a, &fx.hal, id, transports), PFDOA_OK);
}

static void reading(const uint32_t tick, const uint16_t seq, const int8_t dbm, const uint8_t ch, const uint8_t radio)
{
    const pfdoa_radio_reading_t r = {tick, seq, dbm, ch, 0u, radio};
    (void)pfdoa_anchor_on_radio(&fx.a, &r);
}

static void send_config(const uint8_t to, const uint8_t token, const pfdoa_config_t *const c)
{
    uint8_t p[PFDOA_MSG_CONFIG_SET_LEN];
    p[0] = token;
    pfdoa_config_pack(c, &p[1]);
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, to, p, sizeof p, wire, sizeof wire);
    assert_true(n > 0);
    /* Byte by byte: the decoder must not care how the UART driver splits data. */
    for (int32_t i = 0; i < n; i++) {
        (void)pfdoa_anchor_on_uart_rx(&fx.a, &wire[i], 1u);
    }
}

static void test_init_arguments(void **state)
{
    (void)state;
    pfdoa_anchor_t a;
    memset(&a, 0x5A, sizeof a);
    assert_int_equal(pfdoa_anchor_init(NULL, NULL, 1u, PFDOA_TRANSPORT_UART), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_init(&a, NULL, 127u, PFDOA_TRANSPORT_UART), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_init(&a, NULL, 1u, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_init(&a, NULL, 1u, 0x04u), PFDOA_ERR_ARG);
    assert_int_equal(((const uint8_t *)&a)[0], 0x5A); /* untouched on error */
    /* No HAL at all: works, sends nothing, defaults. */
    assert_int_equal(pfdoa_anchor_init(&a, NULL, 126u, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_poll(&a, 5u), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_config_hash(&a), 34278);
    assert_int_equal(pfdoa_anchor_sizeof(), sizeof(pfdoa_anchor_t));
    /* NULL instance everywhere. */
    assert_int_equal(pfdoa_anchor_poll(NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_radio(NULL, NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_uart_rx(NULL, NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_uart_rx(&a, NULL, 3u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(NULL, 0x181u, NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(&a, 0x800u, NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(&a, 0x1FFu, NULL, 8u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_dropped_events(NULL), 0);
    assert_int_equal(pfdoa_anchor_rx_errors(NULL), 0);
    assert_int_equal(pfdoa_anchor_spikes(NULL), 0);
    assert_int_equal(pfdoa_anchor_reports_sent(NULL), 0);
    assert_int_equal(pfdoa_anchor_tx_failures(NULL), 0);
    assert_int_equal(pfdoa_anchor_rx_error_count(&a, 0), 0);
    assert_int_equal(pfdoa_anchor_rx_error_count(&a, PFDOA_ERR_ARG), 0);
    pfdoa_config_t c;
    assert_int_equal(pfdoa_anchor_get_config(NULL, &c), PFDOA_ERR_ARG);
}

static void test_stored_config_used_or_rejected(void **state)
{
    (void)state;
    memset(&fx, 0, sizeof fx);
    fx.hal = cap_hal(&fx.cap);
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    c.offset_q8 = 512;
    pfdoa_config_pack(&c, fx.cap.stored);
    fx.cap.stored_valid = 1;
    assert_int_equal(pfdoa_anchor_init(&fx.a, &fx.hal, 3u, PFDOA_TRANSPORT_UART), PFDOA_OK);
    pfdoa_config_t got;
    assert_int_equal(pfdoa_anchor_get_config(&fx.a, &got), PFDOA_OK);
    assert_int_equal(got.offset_q8, 512);
    assert_int_equal(pfdoa_anchor_config_hash(&fx.a), pfdoa_config_hash(&c));
    /* Corrupt storage (alpha 0) falls back to the defaults. */
    fx.cap.stored[2] = 0u;
    fx.cap.stored[3] = 0u;
    assert_int_equal(pfdoa_anchor_init(&fx.a, &fx.hal, 3u, PFDOA_TRANSPORT_UART), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_config_hash(&fx.a), 34278);
}

static void test_reports_and_status_over_uart(void **state)
{
    (void)state;
    setup_anchor(9u, PFDOA_TRANSPORT_UART);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    fx.cap.tick = 0u;
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 0u), PFDOA_OK); /* first poll: STATUS */
    assert_int_equal(fx.cap.n, 1u);
    pfdoa_frame_t f = cap_decode(&fx.cap, 0u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_STATUS);
    assert_int_equal(f.anchor_id, 9);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_STATUS_OFF_DEFS_HASH]), PFDOA_DEFS_HASH);

    reading(10u, 500u, -60, 37u, PFDOA_RADIO_BLE);
    reading(11u, 500u, -62, 38u, PFDOA_RADIO_BLE);
    assert_int_equal(fx.cap.n, 1u); /* still open */
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 29u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 1u);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 30u), PFDOA_OK); /* 20 ms after the first reading */
    assert_int_equal(fx.cap.n, 2u);
    f = cap_decode(&fx.cap, 1u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_SEQ]), 500);
    assert_int_equal(le32(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_TICK_MS]), 30);
    assert_int_equal(le16s(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_RSSI_Q8]), -61 * 256);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS], 2);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_CHANNEL], 38);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS], PFDOA_FLAG_RESET);
    assert_int_equal(pfdoa_anchor_reports_sent(&fx.a), 1);

    /* 802.15.4 closes at once; a BLE reading after it opens a new event. */
    reading(40u, 501u, -70, 15u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.n, 3u);
    f = cap_decode(&fx.cap, 2u, scratch);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS], PFDOA_FLAG_ZIGBEE);
    /* STATUS again only at >= 1000 ms after the last one. */
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 999u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 3u);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 1000u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 4u);
    f = cap_decode(&fx.cap, 3u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_STATUS);
    assert_int_equal(le32(&f.payload[PFDOA_MSG_STATUS_OFF_UPTIME_S]), 1);
}

static void test_dropped_readings(void **state)
{
    (void)state;
    setup_anchor(1u, PFDOA_TRANSPORT_UART);
    reading(1u, 7u, -60, 37u, PFDOA_RADIO_BLE);
    const pfdoa_radio_reading_t bad[] = {
        {2u, 8u, PFDOA_RSSI_INVALID, 37u, 0u, PFDOA_RADIO_BLE},
        {2u, 8u, -60, 40u, 0u, PFDOA_RADIO_BLE},
        {2u, 8u, -60, 10u, 0u, PFDOA_RADIO_IEEE802154},
        {2u, 8u, -60, 27u, 0u, PFDOA_RADIO_IEEE802154},
        {2u, 8u, -60, 15u, 0u, 2u},
    };
    for (size_t i = 0u; i < sizeof bad / sizeof bad[0]; i++) {
        assert_int_equal(pfdoa_anchor_on_radio(&fx.a, &bad[i]), PFDOA_ERR_ARG);
    }
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 5);
    assert_int_equal(fx.cap.n, 0u); /* nothing closed the open event */
    /* Readings the board's queue lost count too, saturating. */
    assert_int_equal(pfdoa_anchor_note_dropped(&fx.a, 10u), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 15);
    assert_int_equal(pfdoa_anchor_note_dropped(NULL, 1u), PFDOA_ERR_ARG);
    reading(3u, 7u, -60, 38u, PFDOA_RADIO_BLE);
    reading(4u, 7u, -60, 39u, PFDOA_RADIO_BLE);
    assert_int_equal(fx.cap.n, 1u);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    const pfdoa_frame_t f = cap_decode(&fx.cap, 0u, scratch);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS], 3);
}

static void test_config_set_uart_ack_and_apply(void **state)
{
    (void)state;
    setup_anchor(4u, PFDOA_TRANSPORT_UART);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    c.report_mode = PFDOA_REPORT_DECIMATE;
    c.decimation = 2u;
    send_config(4u, 0x77u, &c);
    assert_int_equal(fx.cap.n, 1u);
    pfdoa_frame_t f = cap_decode(&fx.cap, 0u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_CONFIG_ACK);
    assert_int_equal(f.anchor_id, 4);
    assert_int_equal(f.payload[PFDOA_MSG_CONFIG_ACK_OFF_TOKEN], 0x77);
    assert_int_equal(f.payload[PFDOA_MSG_CONFIG_ACK_OFF_RESULT], PFDOA_ACK_OK);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH]), pfdoa_config_hash(&c));
    assert_int_equal(fx.cap.stores, 1u);
    /* Decimation 2: one report per two events, flags ORed (RESET from the first). */
    reading(10u, 1u, -60, 12u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.n, 1u);
    reading(20u, 2u, -61, 12u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.n, 2u);
    f = cap_decode(&fx.cap, 1u, scratch);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_SEQ]), 2);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS], PFDOA_FLAG_RESET | PFDOA_FLAG_ZIGBEE);
    /* Another anchor's CONFIG_SET: ignored, not counted, not acked. */
    send_config(5u, 0x01u, &c);
    assert_int_equal(fx.cap.n, 2u);
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 0);
    /* Invalid: result 1, nothing stored, hash unchanged. */
    pfdoa_config_t bad = c;
    bad.alpha_q8 = 0u;
    send_config(127u, 0x02u, &bad);
    f = cap_decode(&fx.cap, 2u, scratch);
    assert_int_equal(f.payload[PFDOA_MSG_CONFIG_ACK_OFF_RESULT], PFDOA_ACK_INVALID);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH]), pfdoa_config_hash(&c));
    assert_int_equal(fx.cap.stores, 1u);
    /* Store failure: applied, result 2. */
    fx.cap.store_result = -1;
    pfdoa_config_defaults(&c);
    send_config(127u, 0x03u, &c);
    f = cap_decode(&fx.cap, 3u, scratch);
    assert_int_equal(f.payload[PFDOA_MSG_CONFIG_ACK_OFF_RESULT], PFDOA_ACK_STORE_FAILED);
    assert_int_equal(pfdoa_anchor_config_hash(&fx.a), 34278);
}

static void test_can_transport(void **state)
{
    (void)state;
    setup_anchor(5u, PFDOA_TRANSPORT_CAN);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 0u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 3u); /* STATUS_A, STATUS_B, STATUS_C */
    assert_int_equal(fx.cap.frames[0].can_id, 0x285);
    assert_int_equal(fx.cap.frames[1].can_id, 0x305);
    assert_int_equal(fx.cap.frames[2].can_id, 0x385);
    assert_int_equal(fx.cap.frames[2].len, 3);
    reading(5u, 9u, -50, 20u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.frames[3].can_id, 0x105);
    assert_int_equal(fx.cap.frames[3].len, 7);
    uint8_t data[8];
    data[0] = 0x42u;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    pfdoa_config_pack(&c, &data[1]);
    /* Not for us (other id, other type): unseen. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x186u, data, 8u), 0);
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x105u, data, 8u), 0);
    assert_int_equal(fx.cap.n, 4u);
    /* Bad DLC: counted. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x185u, data, 7u), PFDOA_ERR_BAD_LENGTH);
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 1);
    assert_int_equal(pfdoa_anchor_rx_error_count(&fx.a, PFDOA_ERR_BAD_LENGTH), 1);
    /* Own and broadcast: acked on CAN with the anchor's own id. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x185u, data, 8u), 1);
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x1FFu, data, 8u), 1);
    assert_int_equal(fx.cap.n, 6u);
    assert_int_equal(fx.cap.frames[4].can_id, 0x205);
    assert_int_equal(fx.cap.frames[5].can_id, 0x205);
    assert_int_equal(fx.cap.frames[5].bytes[0], 0x42);
}

static void test_both_transports_and_ack_route(void **state)
{
    (void)state;
    setup_anchor(2u, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN);
    reading(1u, 1u, -60, 11u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.n, 2u);
    assert_int_equal(fx.cap.frames[0].is_can, 0);
    assert_int_equal(fx.cap.frames[1].is_can, 1);
    assert_int_equal(pfdoa_anchor_reports_sent(&fx.a), 1);
    /* The ack goes back on the transport the CONFIG_SET came from only. */
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    send_config(2u, 1u, &c);
    assert_int_equal(fx.cap.n, 3u);
    assert_int_equal(fx.cap.frames[2].is_can, 0);
    uint8_t data[8] = {2u};
    pfdoa_config_pack(&c, &data[1]);
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, 0x182u, data, 8u), 1);
    assert_int_equal(fx.cap.n, 4u);
    assert_int_equal(fx.cap.frames[3].is_can, 1);
}

static void test_tx_failures_counted(void **state)
{
    (void)state;
    setup_anchor(2u, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN);
    fx.cap.uart_result = -1;
    fx.cap.can_result = -5;
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 0u), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_tx_failures(&fx.a), 4); /* UART STATUS + STATUS_A, _B, _C */
}

static void test_counters_saturate(void **state)
{
    (void)state;
    setup_anchor(1u, PFDOA_TRANSPORT_UART);
    const pfdoa_radio_reading_t bad = {0u, 0u, PFDOA_RSSI_INVALID, 0u, 0u, 0u};
    for (uint32_t i = 0u; i < 70000u; i++) {
        (void)pfdoa_anchor_on_radio(&fx.a, &bad);
    }
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 65535);
    assert_int_equal(pfdoa_anchor_note_dropped(&fx.a, 65535u), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 65535);
    const uint8_t junk[] = {0x01, 0x00}; /* truncated frame, 70000 times */
    for (uint32_t i = 0u; i < 70000u; i++) {
        (void)pfdoa_anchor_on_uart_rx(&fx.a, junk, sizeof junk);
    }
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 65535);
    assert_int_equal(pfdoa_anchor_rx_error_count(&fx.a, PFDOA_ERR_TRUNCATED), 65535);
}

static void test_radio_inject(void **state)
{
    (void)state;
    /* RADIO_INJECT gives exactly what the radio callback gives, in SIL builds only. */
    uint8_t p[PFDOA_MSG_RADIO_INJECT_LEN] = {0x34, 0x12, 100, 0, 0, 0, (uint8_t)-60, 15, 200, 1};
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_RADIO_INJECT, 3u, p, sizeof p, wire, sizeof wire);
    assert_true(n > 0);
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    const int32_t accepted = pfdoa_anchor_on_uart_rx(&fx.a, wire, (size_t)n);
    static capture_t injected;
    injected = fx.cap;
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    reading(100u, 0x1234u, -60, 15u, PFDOA_RADIO_IEEE802154);
#ifdef PFDOA_SIL_INJECT
    assert_int_equal(accepted, 1);
    assert_int_equal(injected.n, 1u);
    assert_int_equal(injected.frames[0].len, fx.cap.frames[0].len);
    assert_memory_equal(injected.frames[0].bytes, fx.cap.frames[0].bytes, fx.cap.frames[0].len);
#else
    assert_int_equal(accepted, 0);
    assert_int_equal(injected.n, 0u);
    assert_int_equal(fx.cap.n, 1u);
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    (void)pfdoa_anchor_on_uart_rx(&fx.a, wire, (size_t)n);
    assert_int_equal(pfdoa_anchor_rx_error_count(&fx.a, PFDOA_ERR_UNKNOWN_TYPE), 1);
#endif
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_init_arguments),
        cmocka_unit_test(test_stored_config_used_or_rejected),
        cmocka_unit_test(test_reports_and_status_over_uart),
        cmocka_unit_test(test_dropped_readings),
        cmocka_unit_test(test_config_set_uart_ack_and_apply),
        cmocka_unit_test(test_can_transport),
        cmocka_unit_test(test_both_transports_and_ack_route),
        cmocka_unit_test(test_tx_failures_counted),
        cmocka_unit_test(test_counters_saturate),
        cmocka_unit_test(test_radio_inject),
    };
#ifdef PFDOA_SIL_INJECT
    return cmocka_run_group_tests_name("anchor (PFDOA_SIL_INJECT)", tests, NULL, NULL);
#else
    return cmocka_run_group_tests_name("anchor", tests, NULL, NULL);
#endif
}
