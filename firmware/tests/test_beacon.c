/*
 * The C beacon (firmware/beacon): its builders against the golden vectors
 * (protocol/vectors/beacon.json "builds", the bytes the MicroPython beacon and the Python
 * reference also build), the anchor core parsing what it sends, the send schedule, the
 * HAL and argument errors.
 */
#include "pfdoa_beacon.h"
#include "test_support.h"
#include "vectors.h"

#define MAX_SENT 16

typedef struct radio_log {
    size_t n;
    int32_t result;   /* returned by radio_send */
    uint32_t timer_period;
    int32_t timer_result;
    uint8_t radio[MAX_SENT];
    int8_t power[MAX_SENT];
    uint8_t len[MAX_SENT];
    uint8_t frame[MAX_SENT][PFDOA_BEACON_PDU_LEN + PFDOA_BEACON_MPDU_LEN];
} radio_log_t;

static int32_t log_send(void *const ctx, const uint8_t radio, const int8_t tx_power_dbm, const uint8_t *const frame,
                        const size_t len)
{
    radio_log_t *const l = (radio_log_t *)ctx;
    assert_true(l->n < MAX_SENT);
    assert_true(len <= sizeof l->frame[0]);
    l->radio[l->n] = radio;
    l->power[l->n] = tx_power_dbm;
    l->len[l->n] = (uint8_t)len;
    memcpy(l->frame[l->n], frame, len);
    l->n++;
    return l->result;
}

static int32_t log_timer(void *const ctx, const uint32_t period_ms)
{
    radio_log_t *const l = (radio_log_t *)ctx;
    l->timer_period = period_ms;
    return l->timer_result;
}

static pfdoa_beacon_hal_t log_hal(radio_log_t *const l)
{
    pfdoa_beacon_hal_t h;
    memset(&h, 0, sizeof h);
    h.ctx = l;
    h.radio_send = log_send;
    h.timer_start = log_timer;
    return h;
}

static void test_builds_match_the_golden_vectors(void **state)
{
    (void)state;
    assert_true(VEC_BEACON_BUILD_COUNT >= 3u);
    for (size_t i = 0u; i < VEC_BEACON_BUILD_COUNT; i++) {
        const vec_beacon_build_t *const v = &vec_beacon_build[i];
        uint8_t want[64];
        uint8_t got[64];
        uint8_t adv_a[PFDOA_BLE_ADV_A_LEN];
        uint8_t ext[PFDOA_IEEE802154_EXT_ADDR_LEN];
        assert_int_equal(hex_to_bytes(v->adv_a, adv_a, sizeof adv_a), sizeof adv_a);
        assert_int_equal(hex_to_bytes(v->ext_addr, ext, sizeof ext), sizeof ext);
        size_t n = hex_to_bytes(v->adv_data, want, sizeof want);
        assert_int_equal(pfdoa_beacon_adv_data(v->seq, v->beacon_id, got, sizeof got), (int32_t)n);
        assert_memory_equal(got, want, n);
        n = hex_to_bytes(v->pdu, want, sizeof want);
        assert_int_equal(pfdoa_beacon_adv_pdu(adv_a, v->seq, v->beacon_id, got, sizeof got), (int32_t)n);
        assert_memory_equal(got, want, n);
        n = hex_to_bytes(v->mpdu, want, sizeof want);
        assert_int_equal(pfdoa_beacon_mpdu(ext, v->pan_id, v->seq, v->beacon_id, got, sizeof got), (int32_t)n);
        assert_memory_equal(got, want, n);
    }
}

static void test_builder_arguments(void **state)
{
    (void)state;
    uint8_t out[PFDOA_BEACON_PDU_LEN];
    const uint8_t addr[PFDOA_IEEE802154_EXT_ADDR_LEN] = {0};
    memset(out, 0xA5, sizeof out);
    assert_int_equal(pfdoa_beacon_adv_data(1u, 2u, NULL, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_adv_data(1u, 2u, out, PFDOA_BEACON_ADV_DATA_LEN - 1u), PFDOA_ERR_CAPACITY);
    assert_int_equal(pfdoa_beacon_adv_pdu(NULL, 1u, 2u, out, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_adv_pdu(addr, 1u, 2u, NULL, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_adv_pdu(addr, 1u, 2u, out, PFDOA_BEACON_PDU_LEN - 1u), PFDOA_ERR_CAPACITY);
    assert_int_equal(pfdoa_beacon_mpdu(NULL, 0u, 1u, 2u, out, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_mpdu(addr, 0u, 1u, 2u, NULL, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_mpdu(addr, 0u, 1u, 2u, out, PFDOA_BEACON_MPDU_LEN - 1u), PFDOA_ERR_CAPACITY);
    for (size_t i = 0u; i < sizeof out; i++) {
        assert_int_equal(out[i], 0xA5); /* nothing written on error */
    }
}

static void test_config_and_init(void **state)
{
    (void)state;
    radio_log_t log = {0};
    const pfdoa_beacon_hal_t hal = log_hal(&log);
    pfdoa_beacon_config_t c;
    pfdoa_beacon_config_defaults(NULL);
    pfdoa_beacon_config_defaults(&c);
    assert_int_equal(c.interval_ms, PFDOA_BEACON_INTERVAL_MS_DEFAULT);
    assert_int_equal(c.tx_power_dbm, PFDOA_BEACON_TX_POWER_DBM_DEFAULT);
    assert_int_equal(c.pan_id, PFDOA_BEACON_PAN_ID_DEFAULT);
    assert_int_equal(c.radios, PFDOA_BEACON_BLE);
    assert_int_equal(pfdoa_beacon_config_validate(&c), PFDOA_OK);
    assert_int_equal(pfdoa_beacon_config_validate(NULL), PFDOA_ERR_ARG);
    pfdoa_beacon_config_t bad = c;
    bad.interval_ms = PFDOA_BEACON_INTERVAL_MS_MIN - 1u;
    assert_int_equal(pfdoa_beacon_config_validate(&bad), PFDOA_ERR_ARG);
    bad.interval_ms = PFDOA_BEACON_INTERVAL_MS_MAX + 1u;
    assert_int_equal(pfdoa_beacon_config_validate(&bad), PFDOA_ERR_ARG);
    bad = c;
    bad.radios = 0u;
    assert_int_equal(pfdoa_beacon_config_validate(&bad), PFDOA_ERR_ARG);
    bad.radios = 0x04u;
    assert_int_equal(pfdoa_beacon_config_validate(&bad), PFDOA_ERR_ARG);

    pfdoa_beacon_t b;
    memset(&b, 0x5A, sizeof b);
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &bad), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_init(&b, NULL, &c), PFDOA_ERR_ARG);
    pfdoa_beacon_hal_t no_radio = hal;
    no_radio.radio_send = NULL;
    assert_int_equal(pfdoa_beacon_init(&b, &no_radio, &c), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_init(NULL, &hal, &c), PFDOA_ERR_ARG);
    assert_int_equal(((const uint8_t *)&b)[0], 0x5A); /* untouched on error */
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_OK);
    assert_int_equal(pfdoa_beacon_seq(&b), 0);
    /* The timer runs at the interval; its failure is returned; no timer: poll instead. */
    assert_int_equal(pfdoa_beacon_start(&b), PFDOA_OK);
    assert_int_equal(log.timer_period, PFDOA_BEACON_INTERVAL_MS_DEFAULT);
    log.timer_result = -7;
    assert_int_equal(pfdoa_beacon_start(&b), -7);
    no_radio = hal;
    no_radio.timer_start = NULL;
    assert_int_equal(pfdoa_beacon_init(&b, &no_radio, &c), PFDOA_OK);
    assert_int_equal(pfdoa_beacon_start(&b), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_start(NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_on_timer(NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_poll(NULL, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_seq(NULL), 0);
    assert_int_equal(pfdoa_beacon_sent(NULL), 0);
    assert_int_equal(pfdoa_beacon_send_failures(NULL), 0);
}

static void test_sends_each_sequence_number_on_both_radios(void **state)
{
    (void)state;
    radio_log_t log = {0};
    const pfdoa_beacon_hal_t hal = log_hal(&log);
    pfdoa_beacon_config_t c;
    pfdoa_beacon_config_defaults(&c);
    const vec_beacon_build_t *const v = &vec_beacon_build[VEC_BEACON_BUILD_COUNT - 1u];
    (void)hex_to_bytes(v->adv_a, c.adv_a, sizeof c.adv_a);
    (void)hex_to_bytes(v->ext_addr, c.ext_addr, sizeof c.ext_addr);
    c.pan_id = v->pan_id;
    c.beacon_id = v->beacon_id;
    c.tx_power_dbm = -8;
    c.radios = PFDOA_BEACON_BLE | PFDOA_BEACON_802154;
    pfdoa_beacon_t b;
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_OK);
    b.seq = v->seq; /* the vector's sequence number, as if it had run that long */
    assert_int_equal(pfdoa_beacon_on_timer(&b), 2);
    assert_int_equal(log.n, 2u);
    uint8_t want[64];
    size_t n = hex_to_bytes(v->pdu, want, sizeof want);
    assert_int_equal(log.radio[0], PFDOA_RADIO_BLE);
    assert_int_equal(log.power[0], -8);
    assert_int_equal(log.len[0], n);
    assert_memory_equal(log.frame[0], want, n);
    n = hex_to_bytes(v->mpdu, want, sizeof want);
    assert_int_equal(log.radio[1], PFDOA_RADIO_IEEE802154);
    assert_int_equal(log.len[1], n);
    assert_memory_equal(log.frame[1], want, n);
    assert_int_equal(pfdoa_beacon_seq(&b), (uint16_t)(v->seq + 1u));
    assert_int_equal(pfdoa_beacon_sent(&b), 2u);
    /* A failing radio is counted; the sequence number advances anyway (a lost beacon). */
    log.result = -1;
    assert_int_equal(pfdoa_beacon_on_timer(&b), 0);
    assert_int_equal(pfdoa_beacon_send_failures(&b), 2u);
    assert_int_equal(pfdoa_beacon_sent(&b), 2u);
    /* The sequence number wraps. */
    log.result = 0;
    b.seq = UINT16_MAX;
    (void)pfdoa_beacon_on_timer(&b);
    assert_int_equal(pfdoa_beacon_seq(&b), 0);
}

static void test_what_the_beacon_sends_the_anchor_reports(void **state)
{
    (void)state;
    /* Beacon id 3 over BLE (raw PDU) and IEEE 802.15.4; the anchor listens for it in entry 2. */
    radio_log_t log = {0};
    const pfdoa_beacon_hal_t hal = log_hal(&log);
    pfdoa_beacon_config_t c;
    pfdoa_beacon_config_defaults(&c);
    c.beacon_id = 3u;
    c.radios = PFDOA_BEACON_BLE | PFDOA_BEACON_802154;
    pfdoa_beacon_t b;
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_OK);
    b.seq = 0x1234u;
    assert_int_equal(pfdoa_beacon_on_timer(&b), 2);

    capture_t cap;
    memset(&cap, 0, sizeof cap);
    const pfdoa_hal_t ahal = cap_hal(&cap);
    pfdoa_anchor_t a;
    assert_int_equal(pfdoa_anchor_init(&a, &ahal, 4u, PFDOA_TRANSPORT_UART), PFDOA_OK);
    pfdoa_beacon_filter_t f;
    memset(&f, 0, sizeof f);
    f.kind = PFDOA_FILTER_PFDOA;
    f.match[0] = 3u;
    (void)pfdoa_anchor_set_filter(&a, 2u, &f);
    const pfdoa_rx_t rx = {10u, -61, 12u, 200u};
    assert_int_equal(pfdoa_anchor_on_802154(&a, &rx, log.frame[1], log.len[1]), 1);
    const pfdoa_rx_t rx_ble = {20u, -65, 37u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&a, &rx_ble, log.frame[0], log.len[0]), 1);
    assert_int_equal(pfdoa_anchor_on_ble_adv(&a, &rx_ble, &log.frame[0][PFDOA_BLE_PDU_HEADER_LEN],
                                             &log.frame[0][PFDOA_BEACON_ADV_DATA_OFFSET],
                                             log.len[0] - PFDOA_BEACON_ADV_DATA_OFFSET),
                     1);
    assert_int_equal(pfdoa_anchor_poll(&a, 40u), PFDOA_OK);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    assert_true(cap.n >= 2u);
    for (size_t i = 0u; i < 2u; i++) { /* the 802.15.4 event, then the BLE event of two readings */
        const pfdoa_frame_t fr = cap_decode(&cap, i, scratch);
        assert_int_equal(fr.type, PFDOA_MSG_RSSI_REPORT);
        assert_int_equal(le16(&fr.payload[PFDOA_MSG_RSSI_REPORT_OFF_SEQ]), 0x1234);
        assert_int_equal(fr.payload[PFDOA_MSG_RSSI_REPORT_OFF_BEACON], 2);
        assert_int_equal(fr.payload[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS], (i == 0u) ? 1 : 2);
        assert_int_equal(fr.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS] & PFDOA_FLAG_NO_SEQ, 0);
    }
}

static void test_poll_schedule(void **state)
{
    (void)state;
    radio_log_t log = {0};
    pfdoa_beacon_hal_t hal = log_hal(&log);
    hal.timer_start = NULL;
    pfdoa_beacon_config_t c;
    pfdoa_beacon_config_defaults(&c);
    c.interval_ms = 50u;
    pfdoa_beacon_t b;
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_OK);
    /* Near the u32 wrap: first poll sends, then every 50 ms, late polls keep the cadence. */
    const uint32_t t0 = UINT32_MAX - 60u;
    assert_int_equal(pfdoa_beacon_poll(&b, t0), 1);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 49u), 0);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 50u), 1);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 123u), 1); /* 23 ms late (past the wrap) */
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 149u), 0);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 150u), 1);
    /* A stall of 10 intervals: one advertisement, then the interval restarts from now. */
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 700u), 1);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 701u), 0);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 749u), 0);
    assert_int_equal(pfdoa_beacon_poll(&b, t0 + 750u), 1);
    assert_int_equal(log.n, 6u);
    assert_int_equal(pfdoa_beacon_seq(&b), 6);
    for (size_t i = 0u; i < log.n; i++) {
        /* seq follows 'P' 'F' in the manufacturer data, 7 bytes into the AdvData */
        assert_int_equal(le16(&log.frame[i][PFDOA_BEACON_ADV_DATA_OFFSET + 7u + 2u]), i);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_builds_match_the_golden_vectors),
        cmocka_unit_test(test_builder_arguments),
        cmocka_unit_test(test_config_and_init),
        cmocka_unit_test(test_sends_each_sequence_number_on_both_radios),
        cmocka_unit_test(test_what_the_beacon_sends_the_anchor_reports),
        cmocka_unit_test(test_poll_schedule),
    };
    return cmocka_run_group_tests_name("beacon", tests, NULL, NULL);
}
