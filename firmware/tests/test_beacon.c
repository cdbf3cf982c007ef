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
    uint8_t frame[MAX_SENT][PFDOA_BEACON_AUTH_PDU_LEN + PFDOA_BEACON_AUTH_MPDU_LEN];
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

/* Anchor 4 on the UART, its frames captured (the HAL is copied: cap must outlive it). */
static void listening_anchor(pfdoa_anchor_t *const a, capture_t *const cap)
{
    memset(cap, 0, sizeof *cap);
    const pfdoa_hal_t ahal = cap_hal(cap);
    assert_int_equal(pfdoa_anchor_init(a, &ahal, 4u, PFDOA_TRANSPORT_UART), PFDOA_OK);
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
    pfdoa_anchor_t a;
    listening_anchor(&a, &cap);
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

static uint32_t fake_tick;

static uint32_t fake_tick_ms(void *const ctx)
{
    (void)ctx;
    return fake_tick;
}

/* An authenticated beacon (SPEC 9) with the golden vectors' key. */
static void auth_beacon(pfdoa_beacon_t *const b, radio_log_t *const log, const uint8_t radios)
{
    pfdoa_beacon_hal_t hal = log_hal(log);
    hal.tick_ms = fake_tick_ms;
    pfdoa_beacon_config_t c;
    pfdoa_beacon_config_defaults(&c);
    c.radios = radios;
    c.auth = 1u;
    (void)hex_to_bytes(vec_auth_build[0].key, c.auth_key, sizeof c.auth_key);
    assert_int_equal(pfdoa_beacon_init(b, &hal, &c), PFDOA_OK);
    const uint8_t zero[PFDOA_AUTH_KEY_LEN] = {0};
    assert_memory_equal(b->config.auth_key, zero, sizeof zero); /* only the key schedule is kept */
}

static void test_auth_builds_match_the_golden_vectors(void **state)
{
    (void)state;
    assert_true(VEC_AUTH_BUILD_COUNT >= 3u);
    for (size_t i = 0u; i < VEC_AUTH_BUILD_COUNT; i++) {
        const vec_auth_build_t *const v = &vec_auth_build[i];
        uint8_t key[PFDOA_AUTH_KEY_LEN];
        (void)hex_to_bytes(v->key, key, sizeof key);
        pfdoa_hmac_key_t k;
        pfdoa_hmac_init(&k, key, sizeof key);
        pfdoa_auth_ids_t ids;
        pfdoa_auth_derive(&k, v->counter, &ids);
        uint8_t got[64];
        uint8_t want[64];
        size_t n = hex_to_bytes(v->adv_data, want, sizeof want);
        assert_int_equal(n, PFDOA_BEACON_AUTH_ADV_DATA_LEN);
        assert_true(n <= PFDOA_BLE_ADV_DATA_MAX); /* a legacy advertisement */
        assert_int_equal(pfdoa_beacon_auth_adv_data(&k, &ids, v->counter, v->seq, got, sizeof got), (int32_t)n);
        assert_memory_equal(got, want, n);
        n = hex_to_bytes(v->pdu, want, sizeof want);
        assert_int_equal(pfdoa_beacon_auth_adv_pdu(&k, &ids, v->counter, v->seq, got, sizeof got), (int32_t)n);
        assert_memory_equal(got, want, n);
        n = hex_to_bytes(v->mpdu, want, sizeof want);
        assert_int_equal(pfdoa_beacon_auth_mpdu(&k, &ids, v->counter, v->seq, v->pan_id, got, sizeof got),
                         (int32_t)n);
        assert_memory_equal(got, want, n);
        /* Capacity and arguments. */
        assert_int_equal(pfdoa_beacon_auth_adv_data(&k, &ids, 0u, 0u, got, n - 1u > 28u ? 28u : 0u),
                         PFDOA_ERR_CAPACITY);
        assert_int_equal(pfdoa_beacon_auth_adv_pdu(&k, &ids, 0u, 0u, got, PFDOA_BEACON_AUTH_PDU_LEN - 1u),
                         PFDOA_ERR_CAPACITY);
        assert_int_equal(pfdoa_beacon_auth_mpdu(&k, &ids, 0u, 0u, 0u, got, PFDOA_BEACON_AUTH_MPDU_LEN - 1u),
                         PFDOA_ERR_CAPACITY);
        assert_int_equal(pfdoa_beacon_auth_adv_data(NULL, &ids, 0u, 0u, got, sizeof got), PFDOA_ERR_ARG);
        assert_int_equal(pfdoa_beacon_auth_adv_pdu(&k, NULL, 0u, 0u, got, sizeof got), PFDOA_ERR_ARG);
        assert_int_equal(pfdoa_beacon_auth_mpdu(&k, &ids, 0u, 0u, 0u, NULL, sizeof got), PFDOA_ERR_ARG);
    }
}

static void test_auth_beacon_keeps_time_and_rolls_its_identifiers(void **state)
{
    (void)state;
    radio_log_t log = {0};
    pfdoa_beacon_t b;
    auth_beacon(&b, &log, PFDOA_BEACON_BLE | PFDOA_BEACON_802154);
    /* Without the time it sends nothing and keeps its seq. */
    fake_tick = 1000u;
    assert_int_equal(pfdoa_beacon_on_timer(&b), 0);
    assert_int_equal(log.n, 0u);
    assert_int_equal(pfdoa_beacon_seq(&b), 0);
    assert_int_equal(pfdoa_beacon_set_time(&b, 1u, PFDOA_AUTH_PERIOD_MS, 0u), PFDOA_ERR_ARG);
    /* The golden vector's counter, 4000 ms into its period: the next period 96 ms later. */
    const vec_auth_build_t *const v = &vec_auth_build[0];
    assert_int_equal(pfdoa_beacon_set_time(&b, v->counter, 4000u, fake_tick), PFDOA_OK);
    assert_int_equal(pfdoa_beacon_on_timer(&b), 2);
    uint8_t want[64];
    size_t n = hex_to_bytes(v->pdu, want, sizeof want);
    assert_int_equal(log.len[0], n);
    assert_memory_equal(log.frame[0], want, n); /* seq 0 = the vector's */
    n = hex_to_bytes(v->mpdu, want, sizeof want);
    assert_int_equal(log.len[1], n);
    assert_memory_equal(log.frame[1], want, n);
    fake_tick += 95u;
    assert_int_equal(pfdoa_beacon_counter(&b, fake_tick), v->counter);
    (void)pfdoa_beacon_on_timer(&b);
    assert_memory_equal(&log.frame[2][PFDOA_BLE_PDU_HEADER_LEN], &log.frame[0][PFDOA_BLE_PDU_HEADER_LEN],
                        PFDOA_BLE_ADV_A_LEN); /* the same period: the same address */
    fake_tick += 1u;
    (void)pfdoa_beacon_on_timer(&b);
    assert_int_equal(pfdoa_beacon_counter(&b, fake_tick), v->counter + 1u);
    assert_memory_not_equal(&log.frame[4][PFDOA_BLE_PDU_HEADER_LEN], &log.frame[0][PFDOA_BLE_PDU_HEADER_LEN],
                            PFDOA_BLE_ADV_A_LEN); /* the next period: another address */
    /* Ten hours later (counted in whole periods, no drift of its own) and across the u32 wrap. */
    fake_tick += 36000000u;
    assert_int_equal(pfdoa_beacon_counter(&b, fake_tick), v->counter + 1u + (36000000u + 4000u - 4096u) / 4096u);
    fake_tick = 0xFFFFFFF0u;
    const uint32_t before = pfdoa_beacon_counter(&b, fake_tick);
    fake_tick += 4096u;
    assert_int_equal(pfdoa_beacon_counter(&b, fake_tick), before + 1u);
    /* An authenticated beacon needs a tick. */
    pfdoa_beacon_hal_t hal = log_hal(&log);
    pfdoa_beacon_config_t c = b.config;
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_ERR_ARG);
    c.auth = 2u;
    hal.tick_ms = fake_tick_ms;
    assert_int_equal(pfdoa_beacon_init(&b, &hal, &c), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_set_time(NULL, 0u, 0u, 0u), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_beacon_counter(NULL, 0u), 0u);
}

static void test_what_the_auth_beacon_sends_the_anchor_verifies(void **state)
{
    (void)state;
    radio_log_t log = {0};
    pfdoa_beacon_t b;
    auth_beacon(&b, &log, PFDOA_BEACON_BLE);
    fake_tick = 0u;
    assert_int_equal(pfdoa_beacon_set_time(&b, 1000u, 0u, 0u), PFDOA_OK);
    b.seq = 0xFFFFu;
    assert_int_equal(pfdoa_beacon_on_timer(&b), 1);

    capture_t cap;
    pfdoa_anchor_t a;
    listening_anchor(&a, &cap);
    pfdoa_beacon_filter_t f;
    memset(&f, 0, sizeof f);
    f.kind = PFDOA_FILTER_PFDOA_AUTH;
    (void)hex_to_bytes(vec_auth_build[0].key, f.match, PFDOA_AUTH_KEY_LEN);
    assert_int_equal(pfdoa_anchor_set_filter(&a, 1u, &f), PFDOA_ACK_STORE_FAILED); /* applied, no storage */
    for (uint8_t ch = 37u; ch <= 39u; ch++) {
        const pfdoa_rx_t rx = {(uint32_t)(ch - 37u), -60, ch, 0u};
        assert_int_equal(pfdoa_anchor_on_ble_pdu(&a, &rx, log.frame[0], log.len[0]), 1);
    }
    /* The same PDU again later: a replay, rejected and counted. */
    const pfdoa_rx_t late = {500u, -40, 37u, 0u};
    assert_int_equal(pfdoa_anchor_on_ble_pdu(&a, &late, log.frame[0], log.len[0]), 0);
    assert_int_equal(pfdoa_anchor_auth_rejected(&a, PFDOA_AUTH_REPLAYED), 1u);
    assert_int_equal(pfdoa_anchor_auth_rejected(&a, PFDOA_AUTH_BAD_TAG), 0u);
    assert_int_equal(pfdoa_anchor_auth_rejected(&a, PFDOA_AUTH_ACCEPT), 0u);
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    assert_int_equal(cap.n, 1u);
    const pfdoa_frame_t fr = cap_decode(&cap, 0u, scratch);
    assert_int_equal(fr.type, PFDOA_MSG_AUTH_REPORT);
    assert_int_equal(le16(&fr.payload[PFDOA_MSG_AUTH_REPORT_OFF_SEQ]), 0xFFFF);
    assert_int_equal(fr.payload[PFDOA_MSG_AUTH_REPORT_OFF_BEACON], 1);
    assert_int_equal(fr.payload[PFDOA_MSG_AUTH_REPORT_OFF_N_READINGS], 3);
    pfdoa_hmac_key_t k;
    uint8_t key[PFDOA_AUTH_KEY_LEN];
    uint8_t tag[PFDOA_AUTH_TAG_LEN];
    (void)hex_to_bytes(vec_auth_build[0].key, key, sizeof key);
    pfdoa_hmac_init(&k, key, sizeof key);
    pfdoa_auth_tag(&k, 1000u, 0xFFFFu, tag);
    assert_memory_equal(&fr.payload[PFDOA_MSG_AUTH_REPORT_OFF_TAG], tag, sizeof tag);
    assert_int_equal(fr.payload[PFDOA_MSG_AUTH_REPORT_OFF_COUNTER], 1000u & 0xFFu);
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
        cmocka_unit_test(test_auth_builds_match_the_golden_vectors),
        cmocka_unit_test(test_auth_beacon_keeps_time_and_rolls_its_identifiers),
        cmocka_unit_test(test_what_the_auth_beacon_sends_the_anchor_verifies),
    };
    return cmocka_run_group_tests_name("beacon", tests, NULL, NULL);
}
