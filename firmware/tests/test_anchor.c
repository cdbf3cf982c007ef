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

static void send_frame(const uint8_t type, const uint8_t to, const uint8_t *const p, const size_t len)
{
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const int32_t n = pfdoa_frame_encode(type, to, p, len, wire, sizeof wire);
    assert_true(n > 0);
    assert_true(pfdoa_anchor_on_uart_rx(&fx.a, wire, (size_t)n) >= 0);
}

static void send_filter(const uint8_t to, const uint8_t token, const uint8_t index,
                        const pfdoa_beacon_filter_t *const f)
{
    uint8_t p[PFDOA_MSG_FILTER_SET_LEN];
    p[PFDOA_MSG_FILTER_SET_OFF_TOKEN] = token;
    p[PFDOA_MSG_FILTER_SET_OFF_INDEX] = index;
    uint8_t entry[PFDOA_FILTER_ENTRY_LEN];
    pfdoa_beacon_filter_pack(f, entry); /* the stored form is the tail of the payload */
    memcpy(&p[PFDOA_MSG_FILTER_SET_OFF_KIND], entry, sizeof entry);
    send_frame(PFDOA_MSG_FILTER_SET, to, p, sizeof p);
}

/* An iBeacon filter (Apple Proximity Beacon Specification: UUID, major, minor). */
static pfdoa_beacon_filter_t ibeacon_filter(const uint8_t uuid0, const uint16_t period_ms)
{
    pfdoa_beacon_filter_t f;
    memset(&f, 0, sizeof f);
    f.kind = PFDOA_FILTER_IBEACON;
    f.period_ms = period_ms;
    for (size_t i = 0u; i < PFDOA_FILTER_IBEACON_USED; i++) {
        f.match[i] = (uint8_t)(uuid0 + i);
    }
    return f;
}

/* AdvData of the iBeacon that ibeacon_filter(uuid0) matches: Flags AD, then manufacturer data
 * company 0x004C, type, length, UUID(16) major(2) minor(2), measured power. */
static size_t ibeacon_adv(const uint8_t uuid0, uint8_t out[PFDOA_BLE_ADV_DATA_MAX])
{
    size_t n = 0u;
    out[n++] = 2u;
    out[n++] = PFDOA_BLE_AD_FLAGS;
    out[n++] = PFDOA_BLE_FLAGS_GENERAL_NO_BREDR;
    out[n++] = (uint8_t)(PFDOA_IBEACON_LENGTH + 5u); /* AD type, company id(2), type, length */
    out[n++] = PFDOA_BLE_AD_MANUFACTURER;
    out[n++] = (uint8_t)(PFDOA_IBEACON_COMPANY_ID & 0xFFu);
    out[n++] = (uint8_t)(PFDOA_IBEACON_COMPANY_ID >> 8);
    out[n++] = PFDOA_IBEACON_TYPE;
    out[n++] = PFDOA_IBEACON_LENGTH;
    for (size_t i = 0u; i < PFDOA_FILTER_IBEACON_USED; i++) {
        out[n++] = (uint8_t)(uuid0 + i);
    }
    out[n++] = 0xC5u; /* measured power, -59 dBm */
    return n;
}

static const uint8_t ADV_A[PFDOA_BLE_ADV_A_LEN] = {1u, 2u, 3u, 4u, 5u, 6u};

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
    assert_int_equal(pfdoa_anchor_config_hash(&a), PFDOA_CONFIG_DEFAULT_HASH);
    assert_int_equal(pfdoa_anchor_sizeof(), sizeof(pfdoa_anchor_t));
    /* NULL instance everywhere. */
    assert_int_equal(pfdoa_anchor_poll(NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_radio(NULL, NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_uart_rx(NULL, NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_uart_rx(&a, NULL, 3u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(NULL, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, 1u), NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(&a, PFDOA_CAN_ID_MASK + 1u, NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_can_rx(&a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, PFDOA_ANCHOR_BROADCAST), NULL, 8u), PFDOA_ERR_ARG);
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
    assert_int_equal(pfdoa_anchor_config_hash(&fx.a), PFDOA_CONFIG_DEFAULT_HASH);
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
    assert_int_equal(pfdoa_anchor_config_hash(&fx.a), PFDOA_CONFIG_DEFAULT_HASH);
}

static void test_can_transport(void **state)
{
    (void)state;
    setup_anchor(5u, PFDOA_TRANSPORT_CAN);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 0u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 3u); /* STATUS_A, STATUS_B, STATUS_C */
    assert_int_equal(fx.cap.frames[0].can_id, PFDOA_CAN_ID(PFDOA_CAN_STATUS_A, 5u));
    assert_int_equal(fx.cap.frames[1].can_id, PFDOA_CAN_ID(PFDOA_CAN_STATUS_B, 5u));
    assert_int_equal(fx.cap.frames[2].can_id, PFDOA_CAN_ID(PFDOA_CAN_STATUS_C, 5u));
    assert_int_equal(fx.cap.frames[2].len, PFDOA_CAN_STATUS_C_DLC);
    reading(5u, 9u, -50, 20u, PFDOA_RADIO_IEEE802154);
    assert_int_equal(fx.cap.frames[3].can_id, PFDOA_CAN_ID(PFDOA_CAN_RSSI_REPORT, 5u));
    assert_int_equal(fx.cap.frames[3].len, PFDOA_CAN_RSSI_REPORT_DLC);
    uint8_t data[8];
    data[0] = 0x42u;
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    pfdoa_config_pack(&c, &data[1]);
    /* Not for us (other id, other type): unseen. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, 6u), data, 8u), 0);
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_RSSI_REPORT, 5u), data, 8u), 0);
    assert_int_equal(fx.cap.n, 4u);
    /* Bad DLC: counted. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, 5u), data, 7u), PFDOA_ERR_BAD_LENGTH);
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 1);
    assert_int_equal(pfdoa_anchor_rx_error_count(&fx.a, PFDOA_ERR_BAD_LENGTH), 1);
    /* Own and broadcast: acked on CAN with the anchor's own id. */
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, 5u), data, 8u), 1);
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, PFDOA_ANCHOR_BROADCAST), data, 8u), 1);
    assert_int_equal(fx.cap.n, 6u);
    assert_int_equal(fx.cap.frames[4].can_id, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_ACK, 5u));
    assert_int_equal(fx.cap.frames[5].can_id, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_ACK, 5u));
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
    assert_int_equal(pfdoa_anchor_on_can_rx(&fx.a, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_SET, 2u), data, 8u), 1);
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

static void test_filter_set_ack_and_apply(void **state)
{
    (void)state;
    setup_anchor(6u, PFDOA_TRANSPORT_UART);
    const pfdoa_filter_storage_t storage = cap_filter_storage(&fx.cap);
    assert_int_equal(pfdoa_anchor_use_filter_storage(&fx.a, &storage), PFDOA_OK); /* nothing stored yet */
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];

    const pfdoa_beacon_filter_t ib = ibeacon_filter(0x10u, 50u);
    send_filter(6u, 0x21u, 2u, &ib);
    assert_int_equal(fx.cap.n, 1u);
    pfdoa_frame_t f = cap_decode(&fx.cap, 0u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_FILTER_ACK);
    assert_int_equal(f.anchor_id, 6);
    assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_TOKEN], 0x21);
    assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_RESULT], PFDOA_ACK_OK);
    assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_INDEX], 2);
    pfdoa_beacon_filter_t want[PFDOA_BEACON_SLOTS];
    pfdoa_beacon_filters_default(want);
    want[2] = ib;
    const uint16_t hash = pfdoa_beacon_filters_hash(want);
    assert_int_not_equal(hash, PFDOA_FILTER_TABLE_DEFAULT_HASH);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]), hash);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), hash);
    /* Stored as the whole table, entry by entry. */
    assert_int_equal(fx.cap.filter_stores, 1u);
    uint8_t entry[PFDOA_FILTER_ENTRY_LEN];
    pfdoa_beacon_filter_pack(&ib, entry);
    assert_memory_equal(&fx.cap.filters[2u * PFDOA_FILTER_ENTRY_LEN], entry, sizeof entry);
    pfdoa_beacon_filter_t got;
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, 2u, &got), PFDOA_OK);
    assert_int_equal(got.kind, PFDOA_FILTER_IBEACON);
    assert_int_equal(got.period_ms, 50);
    assert_memory_equal(got.match, ib.match, sizeof ib.match);

    /* STATUS carries the hash and the table size. */
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 0u), PFDOA_OK);
    f = cap_decode(&fx.cap, 1u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_STATUS);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_STATUS_OFF_FILTER_HASH]), hash);
    assert_int_equal(f.payload[PFDOA_MSG_STATUS_OFF_FILTER_SLOTS], PFDOA_BEACON_SLOTS);

    /* The iBeacon now reports as beacon 2, events by time (50 ms), no sequence. */
    uint8_t adv[PFDOA_BLE_ADV_DATA_MAX];
    const size_t n = ibeacon_adv(0x10u, adv);
    const pfdoa_rx_t rx1 = {10u, -60, 37u, 0u};
    const pfdoa_rx_t rx2 = {30u, -64, 38u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx1, ADV_A, adv, n), 1);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx2, ADV_A, adv, n), 1);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 59u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 2u); /* 49 ms: still open */
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 60u), PFDOA_OK);
    assert_int_equal(fx.cap.n, 3u);
    f = cap_decode(&fx.cap, 2u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_BEACON], 2);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS], 2);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_SEQ]), 0); /* entry's event counter */
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS], PFDOA_FLAG_RESET | PFDOA_FLAG_NO_SEQ);
    assert_int_equal(le16s(&f.payload[PFDOA_MSG_RSSI_REPORT_OFF_RSSI_Q8]), -62 * 256);
    /* Another iBeacon (other UUID) matches nothing: ignored, not counted. */
    const size_t n2 = ibeacon_adv(0x11u, adv);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx1, ADV_A, adv, n2), 0);
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 0);

    /* Invalid entries: acked INVALID, nothing changed or stored. */
    pfdoa_beacon_filter_t bad = ib;
    bad.period_ms = 0u; /* kinds without a sequence need a period */
    send_filter(127u, 0x22u, 1u, &bad);
    bad = ib;
    bad.kind = PFDOA_FILTER_MAC48;  /* MAC-48 uses 6 match bytes: the rest must be zero */
    send_filter(6u, 0x23u, 1u, &bad);
    bad.kind = (uint8_t)(PFDOA_FILTER_ANCHORS + 1u);
    send_filter(6u, 0x24u, 1u, &bad);
    send_filter(6u, 0x25u, PFDOA_BEACON_SLOTS, &ib);
    assert_int_equal(fx.cap.n, 7u);
    for (size_t i = 3u; i < 7u; i++) {
        f = cap_decode(&fx.cap, i, scratch);
        assert_int_equal(f.type, PFDOA_MSG_FILTER_ACK);
        assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_TOKEN], 0x22u + (i - 3u));
        assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_RESULT], PFDOA_ACK_INVALID);
        assert_int_equal(le16(&f.payload[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]), hash);
    }
    assert_int_equal(fx.cap.filter_stores, 1u);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), hash);
    /* Another anchor's FILTER_SET: ignored, not counted, not acked. */
    send_filter(7u, 0x26u, 1u, &ib);
    assert_int_equal(fx.cap.n, 7u);
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 0);

    /* Store failure: applied, acked STORE_FAILED. */
    fx.cap.filters_result = -1;
    pfdoa_beacon_filter_t none;
    memset(&none, 0, sizeof none);
    send_filter(6u, 0x27u, 2u, &none);
    f = cap_decode(&fx.cap, 7u, scratch);
    assert_int_equal(f.payload[PFDOA_MSG_FILTER_ACK_OFF_RESULT], PFDOA_ACK_STORE_FAILED);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    assert_int_equal(le16(&f.payload[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx1, ADV_A, adv, ibeacon_adv(0x10u, adv)), 0);
}

static void test_stored_filters_used_or_rejected(void **state)
{
    (void)state;
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    const pfdoa_filter_storage_t storage = cap_filter_storage(&fx.cap);
    assert_int_equal(pfdoa_anchor_use_filter_storage(NULL, &storage), PFDOA_ERR_ARG);
    pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS];
    pfdoa_beacon_filters_default(table);
    table[0] = ibeacon_filter(0x40u, 100u); /* entry 0 need not be our beacon */
    table[3].kind = PFDOA_FILTER_PFDOA;
    table[3].match[0] = 9u;
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        pfdoa_beacon_filter_pack(&table[i], &fx.cap.filters[i * PFDOA_FILTER_ENTRY_LEN]);
    }
    fx.cap.filters_valid = 1;
    /* init alone does not know the storage: the first-boot table. */
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    assert_int_equal(pfdoa_anchor_use_filter_storage(&fx.a, &storage), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), pfdoa_beacon_filters_hash(table));
    pfdoa_beacon_filter_t got;
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, 3u, &got), PFDOA_OK);
    assert_int_equal(got.kind, PFDOA_FILTER_PFDOA);
    assert_int_equal(got.match[0], 9);
    assert_int_equal(fx.cap.filter_stores, 0u); /* loading does not write */
    /* One invalid entry (entry 3's PFDOA kind uses one match byte; a second is set): the
     * whole stored table is ignored. */
    fx.cap.filters[3u * PFDOA_FILTER_ENTRY_LEN + 3u + 1u] = 1u;
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    assert_int_equal(pfdoa_anchor_use_filter_storage(&fx.a, &storage), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    /* Load failure: the table stays. */
    fx.cap.filters_valid = 0;
    assert_int_equal(pfdoa_anchor_use_filter_storage(&fx.a, &storage), PFDOA_OK);
    assert_int_equal(pfdoa_anchor_filter_hash(&fx.a), PFDOA_FILTER_TABLE_DEFAULT_HASH);
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, 0u, &got), PFDOA_OK);
    assert_int_equal(got.kind, PFDOA_FILTER_DEFAULT_KIND);
    assert_int_equal(got.match[0], PFDOA_FILTER_DEFAULT_ID);
    /* Storage removed: a set filter is applied but not stored. */
    assert_int_equal(pfdoa_anchor_use_filter_storage(&fx.a, NULL), PFDOA_OK);
    const pfdoa_beacon_filter_t ib = ibeacon_filter(0x40u, 100u);
    assert_int_equal(pfdoa_anchor_set_filter(&fx.a, 1u, &ib), PFDOA_ACK_STORE_FAILED);
    assert_int_equal(fx.cap.filter_stores, 0u);
}

static void test_filter_api_and_raw_entry_points(void **state)
{
    (void)state;
    setup_anchor(2u, PFDOA_TRANSPORT_UART);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    const pfdoa_beacon_filter_t ib = ibeacon_filter(0x50u, 20u);
    pfdoa_beacon_filter_t got;
    assert_int_equal(pfdoa_anchor_set_filter(NULL, 1u, &ib), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_set_filter(&fx.a, 1u, NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_set_filter(&fx.a, PFDOA_BEACON_SLOTS, &ib), PFDOA_ACK_INVALID);
    assert_int_equal(pfdoa_anchor_get_filter(NULL, 0u, &got), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, 0u, NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, PFDOA_BEACON_SLOTS, &got), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_filter_hash(NULL), 0);
    /* No filter storage: applied, not stored; no ack frame is sent. */
    assert_int_equal(pfdoa_anchor_set_filter(&fx.a, 1u, &ib), PFDOA_ACK_STORE_FAILED);
    assert_int_equal(fx.cap.n, 0u);
    assert_int_equal(pfdoa_anchor_get_filter(&fx.a, 1u, &got), PFDOA_OK);
    assert_int_equal(got.kind, PFDOA_FILTER_IBEACON);

    uint8_t adv[PFDOA_BLE_ADV_DATA_MAX];
    const size_t n = ibeacon_adv(0x50u, adv);
    const pfdoa_rx_t rx = {5u, -70, 39u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_adv(NULL, &rx, ADV_A, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, NULL, ADV_A, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx, NULL, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx, ADV_A, NULL, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_pdu(NULL, &rx, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&fx.a, &rx, NULL, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_802154(NULL, &rx, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_802154(&fx.a, NULL, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 0);
    /* Empty or short input matches nothing. */
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx, ADV_A, adv, 0u), 0);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &rx, ADV_A, adv, n - 1u), 0);
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&fx.a, &rx, adv, 1u), 0);
    assert_int_equal(pfdoa_anchor_on_802154(&fx.a, &rx, adv, 0u), 0);
    /* A matched reception without RSSI, or on a channel its radio does not have: dropped. */
    const pfdoa_rx_t no_rssi = {5u, PFDOA_RSSI_INVALID, 39u, 0u};
    const pfdoa_rx_t bad_channel = {5u, -70, PFDOA_CHANNEL_BLE_MAX + 1u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &no_rssi, ADV_A, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&fx.a, &bad_channel, ADV_A, adv, n), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_anchor_dropped_events(&fx.a), 2);
    /* The raw PDU of the same advertisement (ADV_NONCONN_IND, random AdvA) matches too. */
    uint8_t pdu[PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN + PFDOA_BLE_ADV_DATA_MAX];
    pdu[0] = (uint8_t)(PFDOA_BLE_PDU_ADV_NONCONN_IND | PFDOA_BLE_PDU_TXADD);
    pdu[1] = (uint8_t)(PFDOA_BLE_ADV_A_LEN + n);
    memcpy(&pdu[PFDOA_BLE_PDU_HEADER_LEN], ADV_A, sizeof ADV_A);
    memcpy(&pdu[PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN], adv, n);
    const size_t pdu_len = PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN + n;
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&fx.a, &rx, pdu, pdu_len), 1);
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&fx.a, &rx, pdu, pdu_len - 1u), 0); /* Length says more */
    pdu[0] = PFDOA_BLE_PDU_SCAN_RSP; /* scan responses carry AdvData too */
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&fx.a, &rx, pdu, pdu_len), 1);
    assert_int_equal(pfdoa_anchor_poll(&fx.a, 25u), PFDOA_OK); /* period 20 ms */
    assert_int_equal(fx.cap.n, 2u); /* the report, then the first STATUS */
    const pfdoa_frame_t f = cap_decode(&fx.cap, 0u, scratch);
    assert_int_equal(f.type, PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_BEACON], 1);
    assert_int_equal(f.payload[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS], 2);
}

static void test_radio_inject_raw(void **state)
{
    (void)state;
    /* RADIO_INJECT_RAW hands a frame to the raw entry points, in SIL builds only. */
    uint8_t p[PFDOA_MSG_RADIO_INJECT_RAW_LEN];
    memset(p, 0, sizeof p);
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_TICK_MS] = 7u;
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RSSI_DBM] = (uint8_t)-55;
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_CHANNEL] = 11u;
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RADIO] = PFDOA_RADIO_IEEE802154;
    /* Our beacon over IEEE 802.15.4 (SPEC 3.3): data frame, PAN id compression, short
     * broadcast destination, extended source, frame version 2006; payload magic, seq, id. */
    const uint16_t fcf = (uint16_t)(PFDOA_IEEE802154_FRAME_DATA | PFDOA_IEEE802154_FCF_PANID_COMP |
                                    (PFDOA_IEEE802154_ADDR_SHORT << PFDOA_IEEE802154_FCF_DST_MODE_SHIFT) |
                                    (1u << PFDOA_IEEE802154_FCF_VERSION_SHIFT) |
                                    (PFDOA_IEEE802154_ADDR_EXT << PFDOA_IEEE802154_FCF_SRC_MODE_SHIFT));
    const uint8_t mpdu[] = {(uint8_t)(fcf & 0xFFu), (uint8_t)(fcf >> 8), 0x34u, 0xFFu, 0xFFu, 0xFFu, 0xFFu,
                            8u, 7u, 6u, 5u, 4u, 3u, 2u, 1u, PFDOA_BEACON_MAGIC0, PFDOA_BEACON_MAGIC1, 0x34u,
                            0x12u, 0u};
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LENGTH] = (uint8_t)sizeof mpdu;
    memcpy(&p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_FRAME], mpdu, sizeof mpdu);
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_RADIO_INJECT_RAW, 3u, p, sizeof p, wire, sizeof wire);
    assert_true(n > 0);
    const int32_t accepted = pfdoa_anchor_on_uart_rx(&fx.a, wire, (size_t)n);
    static capture_t injected;
    injected = fx.cap;
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    const pfdoa_rx_t rx = {7u, -55, 11u, 0u};
    assert_int_equal(pfdoa_anchor_on_802154(&fx.a, &rx, mpdu, sizeof mpdu), 1);
    assert_int_equal(fx.cap.n, 1u); /* IEEE 802.15.4 events close at once */
#ifdef PFDOA_SIL_INJECT
    assert_int_equal(accepted, 1);
    assert_int_equal(injected.n, 1u);
    assert_int_equal(injected.frames[0].len, fx.cap.frames[0].len);
    assert_memory_equal(injected.frames[0].bytes, fx.cap.frames[0].bytes, fx.cap.frames[0].len);
    /* A length beyond the frame field: ignored, nothing reported. */
    p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LENGTH] = PFDOA_MSG_RADIO_INJECT_RAW_FRAME_LEN + 1u;
    setup_anchor(3u, PFDOA_TRANSPORT_UART);
    send_frame(PFDOA_MSG_RADIO_INJECT_RAW, 3u, p, sizeof p);
    assert_int_equal(fx.cap.n, 0u);
    assert_int_equal(pfdoa_anchor_rx_errors(&fx.a), 0);
#else
    assert_int_equal(accepted, 0);
    assert_int_equal(injected.n, 0u);
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
        cmocka_unit_test(test_filter_set_ack_and_apply),
        cmocka_unit_test(test_stored_filters_used_or_rejected),
        cmocka_unit_test(test_filter_api_and_raw_entry_points),
        cmocka_unit_test(test_radio_inject_raw),
    };
#ifdef PFDOA_SIL_INJECT
    return cmocka_run_group_tests_name("anchor (PFDOA_SIL_INJECT)", tests, NULL, NULL);
#else
    return cmocka_run_group_tests_name("anchor", tests, NULL, NULL);
#endif
}
