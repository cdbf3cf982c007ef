/*
 * The whole port (app.c: start-up, HAL adapters, main loop, sleep, interrupt handlers)
 * with the real core, on the register fake. Built twice: the UART image's app
 * (NRF_LINK_CAN=0) and the CAN image's (NRF_LINK_CAN=1, MCP2515 model on the fake SPIM).
 * Beacon packets are what firmware/beacon builds (protocol version 2).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "app.h"
#include "fake_mcp2515.h"
#include "fake_nrf.h"
#include "nrf_test_support.h"
#include "pfdoa_beacon.h"
#include "pfdoa_frame.h"

#define ID 7u

#if NRF_LINK_CAN
static fake_mcp_t chip;
#endif

static int setup(void **state)
{
    (void)state;
    nrf_fake_reset();
    nrf_fake_uicr_customer0 = ID;
#if NRF_LINK_CAN
    fake_mcp_init(&chip, BOARD_CAN_INT_PIN);
    nrf_fake.spi_cs_mask = 1u << BOARD_CAN_CS_PIN;
#endif
    return 0;
}

static void boot(void)
{
    assert_int_equal(app_init(), APP_OK);
    nrf_fake_radio.TASKS_DISABLE = 0u; /* taken by the fake radio */
}

static void at_ms(uint64_t ms)
{
    nrf_fake_rtc_advance_to(test_rtc_ticks_of_ms(ms), RTC1_IRQHandler);
}

/* Our beacon's packet arrives on whatever channel the radio listens to. */
static void beacon_on_air(uint16_t seq, int rssi_sample)
{
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, seq, 0u);
    test_radio_packet(pdu, n, 1, rssi_sample, RADIO_IRQHandler);
}

/* One advertising event: the same PDU on 37, 38 and 39, 1 ms apart, RSSI samples given;
 * the radio hears a PDU only on the channel it listens to. Returns the PDUs heard. */
static uint32_t advertising_event(const uint8_t *pdu, size_t n, uint64_t t_ms, const int rssi[3])
{
    uint32_t heard = 0u;
    for (uint8_t i = 0u; i < 3u; ++i) {
        at_ms(t_ms + i);
        heard += (uint32_t)test_radio_on_air(pdu, n, RADIO_MODE_BLE, (uint8_t)(37u + i), 1, rssi[i],
                                             RADIO_IRQHandler);
    }
    return heard;
}

/* The hop timer fires; the radio, not receiving, disables at once. */
static void hop(void)
{
    nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_HOP] = 1u;
    RTC1_IRQHandler();
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 1u);
    nrf_fake_radio.TASKS_DISABLE = 0u;
    nrf_fake_radio.EVENTS_DISABLED = 1u;
    RADIO_IRQHandler();
}

static void test_boot_sets_up_the_board(void **state)
{
    (void)state;
    boot();
    app_t *const a = app_get();
    assert_int_equal(a->id, ID);                                  /* from UICR.CUSTOMER[0] */
    assert_int_equal(nrf_fake_clock.HFCLKSTAT & 1u, 1u);          /* HFXO for the radio */
    assert_int_equal(nrf_fake_clock.LFCLKSRC, NRF_CLOCK_LFCLKSRC_XTAL);
    assert_int_equal(nrf_fake_rtc1.TASKS_START, 1u);
    assert_int_equal(nrf_fake_radio.MODE, NRF_RADIO_MODE_BLE_1MBIT);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_HOP], rtc_tick_from_ms(RADIO_BLE_DWELL_MS));
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RADIO)) != 0u);
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RTC1)) != 0u);
    assert_int_equal(nrf_fake.nvic_priority[NRF_IRQ_RADIO], nrf_fake.nvic_priority[NRF_IRQ_RTC1]);
    nrf_fake_uicr_customer0 = 200u; /* not an anchor id: the build's default */
    assert_int_equal(app_anchor_id(), NRF_ANCHOR_ID);
}

static void test_idle_sleeps_only_without_work(void **state)
{
    (void)state;
    boot();
    at_ms(5u);
    app_step();
    /* Nothing waiting: WFI under the mask, the wake-up armed. */
    const uint32_t before = nrf_fake.wfi_count;
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 1u);
    assert_int_equal(nrf_fake.wfi_unmasked, 0u);
    assert_int_equal(nrf_fake.primask, 0u);
    const uint32_t counter = nrf_fake_rtc1.COUNTER;
    /* Just after boot the core may have an event to close soon: a short sleep. */
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - counter) & 0xFFFFFFu, rtc_tick_from_ms(APP_WAKE_BUSY_MS));
    at_ms(1000u);
    app_idle();
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu,
                     rtc_tick_from_ms(APP_WAKE_IDLE_MS));
    /* A packet arrived (its interrupt ran): no sleep until it has been handled. */
    beacon_on_air(1u, 50);
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 2u);
    app_step();
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 3u);
}

static void test_hop_timer_moves_the_radio(void **state)
{
    (void)state;
    boot();
    hop();
    assert_int_equal(app_get()->radio.channel, 38u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 26u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_HOP],
                     (nrf_fake_rtc1.COUNTER + rtc_tick_from_ms(RADIO_BLE_DWELL_MS)) & 0xFFFFFFu);
}

static void test_queue_overflow_reaches_dropped_events(void **state)
{
    (void)state;
    boot();
    at_ms(10u);
    for (uint32_t i = 0u; i < RADIO_QUEUE + 3u; ++i) {
        beacon_on_air((uint16_t)(100u + i), 50);
    }
    app_step();
    assert_int_equal(pfdoa_anchor_dropped_events(&app_get()->anchor), 3u);
    assert_int_equal(app_get()->readings, RADIO_QUEUE);
}

/* FILTER_SET payload: entry `index` listens to an iBeacon (UUID 00 01 .. 0F, major 1, minor
 * 2, big-endian as on air: test_ibeacon(.., 1, 2)) and forms its events over 100 ms. */
static void ibeacon_filter_set(uint8_t payload[PFDOA_MSG_FILTER_SET_LEN], uint8_t token, uint8_t index)
{
    memset(payload, 0, PFDOA_MSG_FILTER_SET_LEN);
    payload[PFDOA_MSG_FILTER_SET_OFF_TOKEN] = token;
    payload[PFDOA_MSG_FILTER_SET_OFF_INDEX] = index;
    payload[PFDOA_MSG_FILTER_SET_OFF_KIND] = PFDOA_FILTER_IBEACON;
    payload[PFDOA_MSG_FILTER_SET_OFF_PERIOD_MS] = 100u;
    uint8_t *const match = &payload[PFDOA_MSG_FILTER_SET_OFF_MATCH];
    for (uint8_t k = 0u; k < 16u; ++k) {
        match[k] = k;
    }
    match[17] = 1u;
    match[19] = 2u;
}

static uint16_t le16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (p[1] << 8));
}

/* What came out on the UART, decoded with the core's own checks (version 2 frames). */
typedef struct seen {
    size_t n;
    uint8_t types[16];
    pfdoa_rssi_report_t report;                  /* the last RSSI_REPORT */
    uint8_t status[PFDOA_MSG_STATUS_LEN];        /* the last STATUS */
    uint8_t ack[PFDOA_MSG_CONFIG_ACK_LEN];       /* the last CONFIG_ACK */
    uint8_t fack[PFDOA_MSG_FILTER_ACK_LEN];      /* the last FILTER_ACK */
    uint8_t auth[PFDOA_MSG_AUTH_REPORT_LEN];     /* the last AUTH_REPORT */
    uint8_t auth_status[PFDOA_MSG_AUTH_STATUS_LEN]; /* the last AUTH_STATUS */
} seen_t;

static seen_t frames(const uint8_t *bytes, size_t n)
{
    static const uint8_t known[] = { PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS, PFDOA_MSG_CONFIG_ACK,
                                     PFDOA_MSG_FILTER_ACK, PFDOA_MSG_AUTH_REPORT, PFDOA_MSG_AUTH_STATUS };
    seen_t s;
    memset(&s, 0, sizeof s);
    pfdoa_decoder_t dec;
    pfdoa_decoder_init(&dec, known, sizeof known);
    for (size_t i = 0u; i < n; ++i) {
        pfdoa_frame_t f;
        const int32_t rc = pfdoa_decoder_push(&dec, bytes[i], &f);
        assert_true(rc >= 0); /* every byte the port sent is part of a valid frame */
        if (rc != 1) {
            continue;
        }
        assert_int_equal(f.anchor_id, ID);
        assert_true(s.n < sizeof s.types);
        s.types[s.n++] = f.type;
        const uint8_t *const p = f.payload;
        if (f.type == PFDOA_MSG_RSSI_REPORT) {
            s.report.seq = le16(&p[PFDOA_MSG_RSSI_REPORT_OFF_SEQ]);
            s.report.raw_dbm = (int8_t)p[PFDOA_MSG_RSSI_REPORT_OFF_RAW_DBM];
            s.report.n_readings = p[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS];
            s.report.channel = p[PFDOA_MSG_RSSI_REPORT_OFF_CHANNEL];
            s.report.flags = p[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS];
            s.report.beacon = p[PFDOA_MSG_RSSI_REPORT_OFF_BEACON];
        } else if (f.type == PFDOA_MSG_STATUS) {
            memcpy(s.status, p, sizeof s.status);
        } else if (f.type == PFDOA_MSG_CONFIG_ACK) {
            memcpy(s.ack, p, sizeof s.ack);
        } else if (f.type == PFDOA_MSG_AUTH_REPORT) {
            memcpy(s.auth, p, sizeof s.auth);
        } else if (f.type == PFDOA_MSG_AUTH_STATUS) {
            memcpy(s.auth_status, p, sizeof s.auth_status);
        } else {
            memcpy(s.fack, p, sizeof s.fack);
        }
    }
    return s;
}

static size_t sent(uint8_t *out, size_t cap)
{
    return test_uarte_drain_tx(out, cap, UARTE0_UART0_IRQHandler);
}

static seen_t sent_frames(void)
{
    uint8_t out[1024];
    const size_t n = sent(out, sizeof out);
    return frames(out, n);
}

/* Host frames arrive on the UART at t_ms in one burst; the chunk's tail is collected once
 * the line is quiet (STOPRX, FLUSHRX), and the main loop hands them to the core. */
static void host_sends(const uint8_t *bytes, size_t n, uint64_t t_ms)
{
    uint32_t filled = 0u;
    at_ms(t_ms);
    const uint32_t partial = test_uarte_rx(bytes, n, &filled, UARTE0_UART0_IRQHandler);
    app_step();
    if (partial > 0u) {
        at_ms(t_ms + UARTE_RX_IDLE_MS);
        app_step(); /* quiet long enough: STOPRX */
        assert_int_equal(nrf_fake_uarte0.TASKS_STOPRX, 1u);
        test_uarte_stop_flush(&filled, NULL, 0u, UARTE0_UART0_IRQHandler);
        app_step();
    }
}

static size_t encode(uint8_t type, const uint8_t *payload, size_t len, uint8_t *out, size_t cap)
{
    const int32_t n = pfdoa_frame_encode(type, ID, payload, len, out, cap);
    assert_true(n > 0);
    return (size_t)n;
}

#if !NRF_LINK_CAN
static void test_uart_boot_status_and_report(void **state)
{
    (void)state;
    boot();
    app_step(); /* first poll: STATUS, the banner */
    seen_t s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_STATUS);
    assert_int_equal(le16(&s.status[PFDOA_MSG_STATUS_OFF_FILTER_HASH]), pfdoa_anchor_filter_hash(&app_get()->anchor));
    assert_int_equal(s.status[PFDOA_MSG_STATUS_OFF_FILTER_SLOTS], PFDOA_BEACON_SLOTS);
    assert_int_equal(le16(&s.status[PFDOA_MSG_STATUS_OFF_DEFS_HASH]), PFDOA_DEFS_HASH);
    /* One advertising event of our beacon on 37, 38 and 39, 1 ms apart, no hop timer in
     * between: the hop on each hit catches all three, one report of 3 readings. */
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 42u, 0u);
    const int rssi[3] = { 60, 61, 63 };
    assert_int_equal(advertising_event(pdu, n, 20u, rssi), 3u);
    at_ms(23u);
    app_step();
    s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(s.report.seq, 42u);
    assert_int_equal(s.report.n_readings, 3u);
    assert_int_equal(s.report.channel, 39u);
    assert_int_equal(s.report.raw_dbm, -63);
    assert_int_equal(s.report.beacon, 0u);
    assert_int_equal(s.report.flags & PFDOA_FLAG_NO_SEQ, 0u);
    assert_int_equal(app_get()->radio.hit_hops, 3u);
    assert_int_equal(app_get()->radio.channel, 37u); /* ready for the next event */
    /* A stranger's advertising event: not taken, no hop, the radio dwells on 37 and hears
     * only its first PDU. A CRC failure of ours changes nothing either. */
    uint8_t other[64];
    const size_t on = test_ibeacon(other, 1u, 2u);
    assert_int_equal(advertising_event(other, on, 200u, rssi), 1u);
    assert_int_equal(app_get()->radio.channel, 37u);
    (void)test_radio_on_air(pdu, n, RADIO_MODE_BLE, 37u, 0, 50, RADIO_IRQHandler);
    /* Our beacon with another beacon id: entry 0 is id 0 only (SPEC 3.1). */
    const size_t n9 = test_ble_beacon(other, 43u, 9u);
    (void)test_radio_on_air(other, n9, RADIO_MODE_BLE, 37u, 1, 50, RADIO_IRQHandler);
    at_ms(300u);
    app_step();
    assert_int_equal(sent(pdu, sizeof pdu), 0u);
    assert_int_equal(app_get()->radio.crc_errors, 1u);
    assert_int_equal(app_get()->radio.rejected, 2u);
    assert_int_equal(app_get()->radio.hit_hops, 3u);
    assert_int_equal(app_get()->readings, 3u);
}

static void test_uart_filter_set_reaches_the_radio_filter(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)sent_frames();
    /* Entry 1: the iBeacon. Before the FILTER_SET the radio does not even queue it. */
    uint8_t ib[64];
    const size_t ibn = test_ibeacon(ib, 1u, 2u);
    const int rssi[3] = { 70, 71, 72 };
    assert_int_equal(advertising_event(ib, ibn, 10u, rssi), 1u);
    app_step();
    assert_int_equal(app_get()->radio.rejected, 1u);
    uint8_t payload[PFDOA_MSG_FILTER_SET_LEN];
    ibeacon_filter_set(payload, 3u, 1u);
    uint8_t frame[PFDOA_FRAME_WIRE_MAX];
    host_sends(frame, encode(PFDOA_MSG_FILTER_SET, payload, sizeof payload, frame, sizeof frame), 50u);
    seen_t s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_FILTER_ACK);
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_RESULT], 0u);
    /* Now its advertising event is caught on all three channels (hits), and its third
     * reading closes the event (SPEC 3.4): a report of entry 1 without a sequence number. */
    assert_int_equal(advertising_event(ib, ibn, 100u, rssi), 3u);
    app_step();
    s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(s.report.beacon, 1u);
    assert_int_equal(s.report.n_readings, 3u);
    assert_int_equal(s.report.raw_dbm, -72);
    assert_true((s.report.flags & PFDOA_FLAG_NO_SEQ) != 0u);
    assert_int_equal(s.report.seq, 0u); /* the entry's first event formed by time */
    /* A lone PDU (the next event's 37 only): its event closes when the entry's 100 ms
     * period is over, at a poll. */
    at_ms(300u);
    assert_int_equal(test_radio_on_air(ib, ibn, RADIO_MODE_BLE, 37u, 1, 66, RADIO_IRQHandler), 1);
    app_step();
    /* Long after the 40 ms of a sequenced event, the open period keeps the sleeps short
     * (the report's tick is the closing poll's). */
    at_ms(390u);
    app_idle();
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu,
                     rtc_tick_from_ms(APP_WAKE_BUSY_MS));
    at_ms(399u);
    app_step();
    assert_int_equal(sent(frame, sizeof frame), 0u);
    at_ms(400u);
    app_step();
    s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.report.beacon, 1u);
    assert_int_equal(s.report.n_readings, 1u);
    assert_int_equal(s.report.seq, 1u);
}

/* Our authenticated beacon (SPEC 9), key 00 01 .. 0F: its advertising PDU for counter and seq. */
static size_t auth_pdu(uint8_t *out, size_t cap, uint32_t counter, uint16_t seq)
{
    static const uint8_t key[PFDOA_AUTH_KEY_LEN] = { 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15 };
    pfdoa_hmac_key_t k;
    pfdoa_auth_ids_t ids;
    pfdoa_hmac_init(&k, key, sizeof key);
    pfdoa_auth_derive(&k, counter, &ids);
    const int32_t n = pfdoa_beacon_auth_adv_pdu(&k, &ids, counter, seq, out, cap);
    assert_true(n > 0);
    return (size_t)n;
}

static void test_uart_auth_entry_queues_what_the_core_verifies(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)sent_frames();
    uint8_t pdu[64];
    const size_t n = auth_pdu(pdu, sizeof pdu, 432900000u, 7u);
    const int rssi[3] = { 60, 61, 62 };
    /* No PFDOA_AUTH entry yet: the radio does not even queue it. */
    assert_int_equal(advertising_event(pdu, n, 10u, rssi), 1u);
    app_step();
    assert_int_equal(app_get()->radio.rejected, 1u);
    /* Entry 1 holds the key (FILTER_SET on the installation link, SPEC 9.5). */
    uint8_t payload[PFDOA_MSG_FILTER_SET_LEN];
    memset(payload, 0, sizeof payload);
    payload[PFDOA_MSG_FILTER_SET_OFF_TOKEN] = 5u;
    payload[PFDOA_MSG_FILTER_SET_OFF_INDEX] = 1u;
    payload[PFDOA_MSG_FILTER_SET_OFF_KIND] = PFDOA_FILTER_PFDOA_AUTH; /* period 0: it numbers its events */
    for (uint8_t k = 0u; k < PFDOA_AUTH_KEY_LEN; ++k) {
        payload[PFDOA_MSG_FILTER_SET_OFF_MATCH + k] = k;
    }
    uint8_t frame[PFDOA_FRAME_WIRE_MAX];
    host_sends(frame, encode(PFDOA_MSG_FILTER_SET, payload, sizeof payload, frame, sizeof frame), 50u);
    seen_t s = sent_frames();
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_RESULT], 0u);
    assert_int_equal(app_get()->auth_entries, 1u);
    /* Now the whole event is queued, verified by the core, and reported as entry 1's. */
    assert_int_equal(advertising_event(pdu, n, 100u, rssi), 3u);
    app_step();
    s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_AUTH_REPORT);
    assert_int_equal(le16(&s.auth[PFDOA_MSG_AUTH_REPORT_OFF_SEQ]), 7u);
    assert_int_equal(s.auth[PFDOA_MSG_AUTH_REPORT_OFF_BEACON], 1u);
    assert_int_equal(s.auth[PFDOA_MSG_AUTH_REPORT_OFF_N_READINGS], 3u);
    assert_int_equal((int8_t)s.auth[PFDOA_MSG_AUTH_REPORT_OFF_RAW_DBM], -62);
    /* A forged tag is queued too (the radio does not verify) and rejected by the core. */
    pdu[n - 1u] ^= 1u;
    assert_int_equal(advertising_event(pdu, n, 300u, rssi), 3u);
    at_ms(1100u);
    app_step();
    s = sent_frames();
    for (size_t i = 0u; i < s.n; ++i) {
        assert_int_not_equal(s.types[i], PFDOA_MSG_AUTH_REPORT);
    }
    assert_int_equal(pfdoa_anchor_auth_rejected(&app_get()->anchor, PFDOA_AUTH_BAD_TAG), 3u);
    assert_int_equal(s.types[s.n - 1u], PFDOA_MSG_AUTH_STATUS); /* after the STATUS: 3 bad tags */
    assert_int_equal(le16(&s.auth_status[PFDOA_MSG_AUTH_STATUS_OFF_AUTH_BAD_TAG]), 3u);
}

static void test_uart_config_and_filter_set_acked_stored_and_kept_across_reboot(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)sent_frames();
    const uint16_t boot_filter_hash = pfdoa_anchor_filter_hash(&app_get()->anchor);
    /* CONFIG_SET: token 9, offset +1 dB, alpha 0.5, spike 10 dB, mode 0, decimation 1; then a
     * FILTER_SET for entry 1, in one burst from the host (its tail in a partial chunk). */
    const uint8_t payload[8] = { 9, 0x00, 0x01, 0x80, 0x00, 10, 0, 1 };
    uint8_t fpayload[PFDOA_MSG_FILTER_SET_LEN];
    ibeacon_filter_set(fpayload, 4u, 1u);
    uint8_t frame[2u * PFDOA_FRAME_WIRE_MAX];
    size_t total = encode(PFDOA_MSG_CONFIG_SET, payload, sizeof payload, frame, sizeof frame);
    total += encode(PFDOA_MSG_FILTER_SET, fpayload, sizeof fpayload, &frame[total], sizeof frame - total);
    assert_true(total % UARTE_RX_CHUNK != 0u);
    host_sends(frame, total, 100u);
    const seen_t s = sent_frames();
    assert_int_equal(s.n, 2u);
    assert_int_equal(s.types[0], PFDOA_MSG_CONFIG_ACK);
    assert_int_equal(s.ack[PFDOA_MSG_CONFIG_ACK_OFF_TOKEN], 9u);
    assert_int_equal(s.ack[PFDOA_MSG_CONFIG_ACK_OFF_RESULT], 0u); /* applied and stored (flash) */
    const uint16_t hash = le16(&s.ack[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH]);
    assert_int_equal(pfdoa_anchor_config_hash(&app_get()->anchor), hash);
    assert_int_equal(s.types[1], PFDOA_MSG_FILTER_ACK);
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_TOKEN], 4u);
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_RESULT], 0u); /* applied and stored (flash) */
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_INDEX], 1u);
    const uint16_t fhash = le16(&s.fack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]);
    assert_int_equal(pfdoa_anchor_filter_hash(&app_get()->anchor), fhash);
    assert_int_not_equal(fhash, boot_filter_hash);
    assert_int_equal(nrf_fake.flash_violations, 0u);
    assert_int_equal(nrf_fake.flash_writes, 4u + 25u); /* one record in each log */
    /* Power cycle: everything but the flash pages starts again. */
    uint32_t pages[NRF_STORE_PAGES][NRF_FLASH_PAGE_SIZE / 4u];
    memcpy(pages, nrf_fake_store_pages, sizeof pages);
    nrf_fake_reset();
    memcpy(nrf_fake_store_pages, pages, sizeof pages);
    nrf_fake_uicr_customer0 = ID;
    boot();
    assert_int_equal(pfdoa_anchor_config_hash(&app_get()->anchor), hash);
    assert_int_equal(pfdoa_anchor_filter_hash(&app_get()->anchor), fhash);
    pfdoa_beacon_filter_t f;
    assert_int_equal(pfdoa_anchor_get_filter(&app_get()->anchor, 1u, &f), PFDOA_OK);
    assert_int_equal(f.kind, PFDOA_FILTER_IBEACON);
    assert_int_equal(f.period_ms, 100u);
    /* The radio's filter follows the stored table from boot: the iBeacon is a hit. */
    uint8_t ib[64];
    const size_t ibn = test_ibeacon(ib, 1u, 2u);
    const int rssi[3] = { 70, 71, 72 };
    assert_int_equal(advertising_event(ib, ibn, 10u, rssi), 3u);
}

static void test_uart_no_crystal_radio_off_status_still_sent(void **state)
{
    (void)state;
    nrf_fake.hfxo_fails = 1;
    assert_int_equal(app_init(), APP_ERR_HFXO);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 0u);              /* off frequency: never on */
    assert_int_equal(nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RADIO), 0u);
    app_step();
    const seen_t s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_STATUS);
}

static void test_uart_tx_slots_full_counts_core_failure(void **state)
{
    (void)state;
    boot();
    /* The UART never finishes a transfer: the first frame holds the DMA, the slots fill,
     * later frames are refused and the core counts them. */
    for (uint32_t t = 0u; t < 8u; ++t) {
        at_ms(1000u * t + 1u);
        app_step();
    }
    assert_true(pfdoa_anchor_tx_failures(&app_get()->anchor) >= 8u - UARTE_TX_SLOTS);
    assert_int_equal(app_get()->uart.tx_dropped, pfdoa_anchor_tx_failures(&app_get()->anchor));
}
#else
static void test_can_boot_status_on_bus(void **state)
{
    (void)state;
    boot();
    assert_int_equal(fake_mcp_opmode(&chip), 0x00u);
    assert_int_equal(nrf_fake_gpiote.CONFIG[0], NRF_GPIOTE_CONFIG_EVENT_HITOLO(1u, BOARD_CAN_INT_PIN));
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_GPIOTE)) != 0u);
    /* 16 MHz / 500 kbit/s as built for this test. */
    assert_int_equal(chip.reg[0x2A], 0x00u);
    assert_int_equal(chip.reg[0x29], 0xB5u);
    assert_int_equal(chip.reg[0x28], 0x01u);
    app_step();
    /* STATUS is STATUS_A, STATUS_B and STATUS_C (SPEC 4), in that order. */
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 3u);
    assert_int_equal(chip.sent[0].id, (PFDOA_CAN_STATUS_A << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[1].id, (PFDOA_CAN_STATUS_B << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[1].data[6] | (chip.sent[1].data[7] << 8), PFDOA_DEFS_HASH);
    assert_int_equal(chip.sent[2].id, (PFDOA_CAN_STATUS_C << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[2].dlc, PFDOA_CAN_STATUS_C_DLC);
    assert_int_equal(chip.sent[2].data[0] | (chip.sent[2].data[1] << 8), pfdoa_anchor_filter_hash(&app_get()->anchor));
    assert_int_equal(chip.sent[2].data[2], PFDOA_BEACON_SLOTS);
    assert_int_equal(nrf_fake.spi_without_cs, 0u);
    /* Nothing on the UART: reports and STATUS go on CAN only. */
    uint8_t out[64];
    assert_int_equal(sent(out, sizeof out), 0u);
}

static void test_can_image_takes_filter_set_on_the_uart(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)fake_mcp_bus_run(&chip, 10u);
    /* FILTER_SET has no CAN mapping (SPEC 4): the CAN image listens on the DK's UART too,
     * and acks there. */
    uint8_t payload[PFDOA_MSG_FILTER_SET_LEN];
    ibeacon_filter_set(payload, 8u, 2u);
    uint8_t frame[PFDOA_FRAME_WIRE_MAX];
    host_sends(frame, encode(PFDOA_MSG_FILTER_SET, payload, sizeof payload, frame, sizeof frame), 40u);
    const seen_t s = sent_frames();
    assert_int_equal(s.n, 1u);
    assert_int_equal(s.types[0], PFDOA_MSG_FILTER_ACK);
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_TOKEN], 8u);
    assert_int_equal(s.fack[PFDOA_MSG_FILTER_ACK_OFF_RESULT], 0u);
    const uint16_t fhash = le16(&s.fack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]);
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 0u); /* no ack on CAN */
    /* The iBeacon's advertising event is now a hit on every channel; its report (entry 2,
     * NO_SEQ) goes out on CAN, and the next STATUS_C carries the new table's hash. */
    uint8_t ib[64];
    const size_t ibn = test_ibeacon(ib, 1u, 2u);
    const int rssi[3] = { 70, 71, 72 };
    assert_int_equal(advertising_event(ib, ibn, 100u, rssi), 3u);
    at_ms(200u);
    app_step();
    const uint32_t before = chip.n_sent;
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
    const fake_mcp_frame_t *const rep = &chip.sent[before];
    assert_int_equal(rep->id, (PFDOA_CAN_RSSI_REPORT << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(rep->dlc, PFDOA_CAN_RSSI_REPORT_DLC);
    assert_int_equal(rep->data[PFDOA_CAN_RSSI_REPORT_OFF_BEACON], 2u);
    assert_true((rep->data[PFDOA_CAN_RSSI_REPORT_OFF_FLAGS] & PFDOA_FLAG_NO_SEQ) != 0u);
    at_ms(1000u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 3u);
    const fake_mcp_frame_t *const c = &chip.sent[chip.n_sent - 1u];
    assert_int_equal(c->id, (PFDOA_CAN_STATUS_C << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(c->data[0] | (c->data[1] << 8), fhash);
}

static void test_can_report_and_status_in_one_poll_all_sent(void **state)
{
    (void)state;
    boot();
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 3u);
    /* A lone reading at 990 ms: the poll at 1010 closes its event (timeout) and then sends
     * STATUS: four frames for three TX buffers. */
    at_ms(990u);
    beacon_on_air(77u, 58);
    app_step();
    at_ms(1010u);
    app_step();
    assert_int_equal(mcp2515_tx_waiting(&app_get()->can), 1u);
    at_ms(1031u); /* 41 ms after the reading: only the waiting frame keeps the sleep short */
    const uint32_t before = nrf_fake.wfi_count;
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 1u);
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu,
                     rtc_tick_from_ms(APP_WAKE_BUSY_MS));
    assert_int_equal(fake_mcp_bus_run(&chip, 1u), 1u); /* the bus takes the report */
    at_ms(1033u);
    app_step();                                         /* the main loop moves STATUS_C in */
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 3u);
    static const uint8_t types[4] = { PFDOA_CAN_RSSI_REPORT, PFDOA_CAN_STATUS_A, PFDOA_CAN_STATUS_B,
                                      PFDOA_CAN_STATUS_C };
    for (uint32_t k = 0u; k < 4u; ++k) {
        assert_int_equal(chip.sent[3u + k].id, ((uint32_t)types[k] << PFDOA_CAN_ANCHOR_BITS) | ID);
    }
    assert_int_equal(pfdoa_anchor_tx_failures(&app_get()->anchor), 0u);
    assert_int_equal(app_get()->can.tx_full, 0u);
}

static void test_can_config_set_through_filters(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)fake_mcp_bus_run(&chip, 10u);
    const uint8_t cfg[8] = { 5, 0, 0, 64, 0, 12, 0, 1 };
    /* Another anchor's CONFIG_SET never gets past the chip's filters. */
    assert_int_equal(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | (ID + 1u), 0, 0, 8u,
                                        cfg), -1);
    /* Ours does: INT falls, GPIOTE's event, the main loop takes it, the ack goes out. */
    assert_true(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | ID, 0, 0, 8u, cfg) >= 0);
    nrf_fake_gpiote.EVENTS_IN[0] = 1u;
    GPIOTE_IRQHandler();
    assert_int_equal(app_get()->can_irq, 1u);
    at_ms(50u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
    const fake_mcp_frame_t *const ack = &chip.sent[chip.n_sent - 1u];
    assert_int_equal(ack->id, (PFDOA_CAN_CONFIG_ACK << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(ack->dlc, PFDOA_CAN_CONFIG_ACK_DLC);
    assert_int_equal(ack->data[0], 5u);  /* token */
    assert_int_equal(ack->data[1], 0u);  /* applied and stored */
    /* The broadcast id is accepted too. */
    assert_true(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | PFDOA_ANCHOR_BROADCAST, 0,
                                   0, 8u, cfg) >= 0);
    at_ms(60u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
}

static void test_can_bus_off_counts_failures_and_recovers(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)fake_mcp_bus_run(&chip, 10u);
    fake_mcp_set_errors(&chip, 256, 0);
    at_ms(10u);
    app_step(); /* INT low: serviced, bus-off */
    assert_int_equal(app_get()->can.state, MCP2515_BUS_OFF);
    beacon_on_air(1u, 50);
    at_ms(12u);
    app_step();
    beacon_on_air(2u, 50); /* closes seq 1: its report cannot be sent */
    at_ms(14u);
    app_step();
    assert_int_equal(pfdoa_anchor_tx_failures(&app_get()->anchor), 1u);
    fake_mcp_bus_off_recovered(&chip);
    at_ms(200u); /* the periodic service sees the recovery */
    app_step();
    assert_int_equal(app_get()->can.state, MCP2515_ERROR_ACTIVE);
    assert_int_equal(app_get()->can.recoveries, 1u);
    beacon_on_air(3u, 50);
    at_ms(202u);
    app_step();
    const uint32_t before = chip.n_sent;
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
    assert_int_equal(chip.sent[before].id, (PFDOA_CAN_RSSI_REPORT << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[before].data[0], 2u); /* seq 2's report */
}

static void test_can_missing_controller_is_reported(void **state)
{
    (void)state;
    chip.absent = 1;
    assert_int_equal(app_init(), APP_ERR_LINK);
}
#endif

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_boot_sets_up_the_board, setup),
        cmocka_unit_test_setup(test_idle_sleeps_only_without_work, setup),
        cmocka_unit_test_setup(test_hop_timer_moves_the_radio, setup),
        cmocka_unit_test_setup(test_queue_overflow_reaches_dropped_events, setup),
#if !NRF_LINK_CAN
        cmocka_unit_test_setup(test_uart_boot_status_and_report, setup),
        cmocka_unit_test_setup(test_uart_filter_set_reaches_the_radio_filter, setup),
        cmocka_unit_test_setup(test_uart_auth_entry_queues_what_the_core_verifies, setup),
        cmocka_unit_test_setup(test_uart_config_and_filter_set_acked_stored_and_kept_across_reboot, setup),
        cmocka_unit_test_setup(test_uart_no_crystal_radio_off_status_still_sent, setup),
        cmocka_unit_test_setup(test_uart_tx_slots_full_counts_core_failure, setup),
#else
        cmocka_unit_test_setup(test_can_boot_status_on_bus, setup),
        cmocka_unit_test_setup(test_can_image_takes_filter_set_on_the_uart, setup),
        cmocka_unit_test_setup(test_can_report_and_status_in_one_poll_all_sent, setup),
        cmocka_unit_test_setup(test_can_config_set_through_filters, setup),
        cmocka_unit_test_setup(test_can_bus_off_counts_failures_and_recovers, setup),
        cmocka_unit_test_setup(test_can_missing_controller_is_reported, setup),
#endif
    };
    return cmocka_run_group_tests_name(NRF_LINK_CAN ? "nrf52840 app (CAN image)" : "nrf52840 app (UART image)", tests,
                                       NULL, NULL);
}
