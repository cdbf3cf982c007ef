/*
 * Property tests over seeded random inputs (xorshift32, fixed seeds): whatever the radio
 * readings, host bytes and CAN frames, the anchor never crashes (ASan/UBSan), its output
 * frames are well formed, report fields stay in their SPEC ranges, and counters only grow.
 */
#include "pfdoa_anchor.h"
#include "test_support.h"

static capture_t cap;
static pfdoa_anchor_t anchor;

static void start(const uint8_t id, const uint8_t transports, const uint32_t boot)
{
    memset(&cap, 0, sizeof cap);
    cap.tick = boot;
    const pfdoa_hal_t hal = cap_hal(&cap);
    assert_int_equal(pfdoa_anchor_init(&anchor, &hal, id, transports), PFDOA_OK);
}

/* Checks every captured report (UART) against the SPEC ranges; returns spikes seen. */
static uint32_t check_reports(const int16_t offset, uint32_t *const reports)
{
    uint32_t spikes = 0u;
    for (size_t i = 0u; i < cap.n; i++) {
        uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
        const pfdoa_frame_t f = cap_decode(&cap, i, scratch);
        assert_int_equal(f.anchor_id, anchor.anchor_id);
        if (f.type != PFDOA_MSG_RSSI_REPORT) {
            continue;
        }
        (*reports)++;
        const uint8_t *const p = f.payload;
        const int16_t rssi = le16s(&p[PFDOA_MSG_RSSI_REPORT_OFF_RSSI_Q8]);
        const int8_t raw = (int8_t)p[PFDOA_MSG_RSSI_REPORT_OFF_RAW_DBM];
        const uint8_t n = p[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS];
        const uint8_t ch = p[PFDOA_MSG_RSSI_REPORT_OFF_CHANNEL];
        const uint8_t flags = p[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS];
        assert_true((n >= 1u) && (n <= 3u));
        assert_true(raw <= PFDOA_RSSI_MAX_DBM);
        assert_int_equal(flags & (uint8_t)~PFDOA_FLAGS_DEFINED, 0u); /* the other bits are reserved */
        assert_true(p[PFDOA_MSG_RSSI_REPORT_OFF_BEACON] < PFDOA_BEACON_SLOTS);
        assert_false(((flags & PFDOA_FLAG_SPIKE) != 0u) && ((flags & PFDOA_FLAG_RESET) != 0u));
        if ((flags & PFDOA_FLAG_ZIGBEE) != 0u) {
            assert_int_equal(n, 1u);
            assert_true((ch >= 11u) && (ch <= 26u));
        } else {
            assert_true(ch <= 39u);
        }
        assert_int_equal((flags & PFDOA_FLAG_CALIBRATED) != 0u, offset != 0);
        if (offset == 0) {
            /* The EMA of clamped readings stays inside the reading range. */
            assert_true(rssi <= 20 * 256); /* and >= -128 * 256, the i16 minimum */
        }
        if ((flags & PFDOA_FLAG_SPIKE) != 0u) {
            spikes++;
        }
    }
    return spikes;
}

static void test_random_readings(void **state)
{
    (void)state;
    static const int16_t offsets[] = {0, 0, -384, 32767, -32768};
    for (uint32_t seed = 1u; seed <= 200u; seed++) {
        rng_t r = {seed * 2654435761u};
        const int16_t offset = offsets[seed % 5u];
        start((uint8_t)(seed % 127u), PFDOA_TRANSPORT_UART, rng_next(&r));
        pfdoa_config_t c;
        pfdoa_config_defaults(&c);
        c.offset_q8 = offset;
        c.alpha_q8 = (uint16_t)rng_range(&r, 1, 256);
        c.spike_db = (uint8_t)rng_range(&r, 0, 20);
        anchor.config = c; /* white-box: skip the CONFIG_SET round trip */
        uint32_t tick = rng_next(&r);
        uint16_t seq = (uint16_t)rng_next(&r);
        uint32_t dropped = 0u;
        uint32_t reports = 0u;
        uint32_t spikes = 0u;
        for (int step = 0; step < 400; step++) {
            tick += (uint32_t)rng_range(&r, 0, 15);
            const uint32_t what = rng_next(&r) % 16u;
            if (what < 2u) {
                assert_int_equal(pfdoa_anchor_poll(&anchor, tick), PFDOA_OK);
            } else {
                if ((rng_next(&r) % 3u) == 0u) {
                    seq++;
                }
                pfdoa_radio_reading_t rd;
                rd.tick_ms = tick;
                rd.seq = seq;
                rd.rssi_dbm = (int8_t)rng_range(&r, -128, 127);
                rd.radio = (uint8_t)(((rng_next(&r) % 8u) == 0u) ? rng_range(&r, 0, 3) : 0);
                rd.channel = (uint8_t)rng_range(&r, 0, 45);
                rd.lqi = (uint8_t)rng_next(&r);
                const uint16_t before = pfdoa_anchor_dropped_events(&anchor);
                const int32_t rc = pfdoa_anchor_on_radio(&anchor, &rd);
                assert_true((rc == PFDOA_OK) || (rc == PFDOA_ERR_ARG));
                if (rc != PFDOA_OK) {
                    dropped++;
                    assert_int_equal(pfdoa_anchor_dropped_events(&anchor), before + 1u);
                }
            }
            spikes += check_reports(offset, &reports);
            cap.n = 0u;
        }
        assert_int_equal(pfdoa_anchor_dropped_events(&anchor), dropped);
        assert_int_equal(pfdoa_anchor_spikes(&anchor), spikes);
        assert_int_equal(pfdoa_anchor_reports_sent(&anchor), reports);
        assert_true(anchor.slots[0].event.n <= 3u);
    }
}

static void test_random_host_bytes(void **state)
{
    (void)state;
    for (uint32_t seed = 1u; seed <= 100u; seed++) {
        rng_t r = {seed * 40503u + 7u};
        start(5u, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN, 0u);
        uint16_t last_errors = 0u;
        uint8_t buf[300];
        for (int step = 0; step < 100; step++) {
            const size_t len = (size_t)rng_range(&r, 0, 300);
            const uint32_t zero_rate = (rng_next(&r) % 40u) + 2u;
            for (size_t i = 0u; i < len; i++) {
                const uint32_t x = rng_next(&r);
                buf[i] = ((x >> 16) % zero_rate == 0u) ? 0u : (uint8_t)x;
            }
            /* Sometimes splice in a valid frame, possibly with a corrupt byte. */
            if ((rng_next(&r) % 4u) == 0u) {
                uint8_t p[PFDOA_MSG_CONFIG_SET_LEN];
                for (size_t i = 0u; i < sizeof p; i++) {
                    p[i] = (uint8_t)rng_next(&r);
                }
                uint8_t wire[PFDOA_FRAME_WIRE_MAX];
                const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, (uint8_t)rng_range(&r, 0, 127), p, sizeof p,
                                                     wire, sizeof wire);
                assert_true(n > 0);
                if ((size_t)n <= len) {
                    memcpy(&buf[len - (size_t)n], wire, (size_t)n);
                }
            }
            const int32_t acc = pfdoa_anchor_on_uart_rx(&anchor, buf, len);
            assert_true(acc >= 0);
            const uint16_t errors = pfdoa_anchor_rx_errors(&anchor);
            assert_true(errors >= last_errors); /* counters only grow */
            last_errors = errors;
            uint32_t sum = 0u;
            for (int32_t e = -1; e >= -PFDOA_ERR_COUNT; e--) {
                sum += pfdoa_anchor_rx_error_count(&anchor, e);
            }
            assert_int_equal(sum, errors);
            assert_true(anchor.decoder.len <= PFDOA_MAX_ENCODED);
            /* Random CAN traffic too. */
            uint8_t d[8];
            for (size_t i = 0u; i < sizeof d; i++) {
                d[i] = (uint8_t)rng_next(&r);
            }
            const int32_t rc = pfdoa_anchor_on_can_rx(&anchor, (uint16_t)rng_range(&r, 0, 0x7FF), d,
                                                      (uint8_t)rng_range(&r, 0, 8));
            assert_true((rc == 0) || (rc == 1) || (rc == PFDOA_ERR_BAD_LENGTH));
            /* Whatever config got applied is valid. */
            pfdoa_config_t c;
            assert_int_equal(pfdoa_anchor_get_config(&anchor, &c), PFDOA_OK);
            assert_int_equal(pfdoa_config_validate(&c), PFDOA_OK);
            assert_int_equal(pfdoa_anchor_config_hash(&anchor), pfdoa_config_hash(&c));
            for (size_t i = 0u; i < cap.n; i++) {
                if (cap.frames[i].is_can == 0u) {
                    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
                    const pfdoa_frame_t f = cap_decode(&cap, i, scratch);
                    assert_int_equal(f.type, PFDOA_MSG_CONFIG_ACK);
                } else {
                    assert_int_equal(cap.frames[i].can_id, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_ACK, 5u));
                }
            }
            cap.n = 0u;
        }
    }
}

/* A random filter entry of a random kind, valid or not. */
static void random_filter(rng_t *const r, pfdoa_beacon_filter_t *const f)
{
    memset(f, 0, sizeof *f);
    f->kind = (uint8_t)rng_range(r, 0, 7);
    f->period_ms = (f->kind >= PFDOA_FILTER_IBEACON) ? (uint16_t)rng_range(r, 1, 300) : 0u;
    const size_t used = (rng_next(r) % 8u == 0u) ? PFDOA_FILTER_MATCH_LEN : 8u;
    for (size_t i = 0u; i < used; i++) {
        f->match[i] = (uint8_t)(rng_next(r) % 4u); /* few values: random frames match now and then */
    }
}

static void test_random_receptions_and_filters(void **state)
{
    (void)state;
    /* Random frames through the raw entry points against random filter tables: never a
     * crash, reports name a valid entry, NO_SEQ exactly for the entries without a sequence
     * number, only matched receptions count as dropped, the table stays valid. */
    for (uint32_t seed = 1u; seed <= 150u; seed++) {
        rng_t r = {seed * 2246822519u};
        start(7u, PFDOA_TRANSPORT_UART, rng_next(&r));
        for (uint8_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
            pfdoa_beacon_filter_t f;
            random_filter(&r, &f);
            const int32_t rc = pfdoa_anchor_set_filter(&anchor, i, &f);
            assert_int_equal(rc, (pfdoa_beacon_filter_validate(&f) == PFDOA_OK) ? PFDOA_ACK_STORE_FAILED
                                                                               : PFDOA_ACK_INVALID);
        }
        uint32_t tick = rng_next(&r);
        uint32_t reports = 0u;
        for (int step = 0; step < 300; step++) {
            tick += (uint32_t)rng_range(&r, 0, 40);
            uint8_t frame[48];
            const size_t len = (size_t)rng_range(&r, 0, (int32_t)sizeof frame);
            for (size_t i = 0u; i < len; i++) {
                frame[i] = (uint8_t)(((rng_next(&r) % 3u) == 0u) ? rng_range(&r, 0, 3) : (int32_t)rng_next(&r));
            }
            if ((len >= 8u) && ((rng_next(&r) % 2u) == 0u)) { /* a plausible PDU header */
                frame[0] = (uint8_t)(frame[0] & 0x4Fu);
                frame[1] = (uint8_t)rng_range(&r, 6, (int32_t)len - 2);
            }
            pfdoa_rx_t rx = {tick, (int8_t)rng_range(&r, -128, 127), (uint8_t)rng_range(&r, 0, 40), 0u};
            const uint16_t before = pfdoa_anchor_dropped_events(&anchor);
            const uint32_t what = rng_next(&r) % 4u;
            int32_t rc;
            if (what == 0u) {
                rc = pfdoa_anchor_on_ble_pdu(&anchor, &rx, frame, len);
            } else if (what == 1u) {
                rc = pfdoa_anchor_on_802154(&anchor, &rx, frame, len);
            } else if (what == 2u) {
                rc = pfdoa_anchor_on_ble_adv(&anchor, &rx, frame, (len > 6u) ? &frame[6] : NULL,
                                             (len > 6u) ? len - 6u : 0u);
            } else {
                rc = pfdoa_anchor_poll(&anchor, tick);
            }
            assert_true((rc == 0) || (rc == 1) || (rc == PFDOA_ERR_ARG));
            const uint16_t after = pfdoa_anchor_dropped_events(&anchor);
            assert_int_equal(after, (rc == PFDOA_ERR_ARG) ? before + 1u : before);
            for (size_t i = 0u; i < cap.n; i++) {
                uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
                const pfdoa_frame_t f = cap_decode(&cap, i, scratch);
                if (f.type != PFDOA_MSG_RSSI_REPORT) {
                    continue;
                }
                reports++;
                const uint8_t b = f.payload[PFDOA_MSG_RSSI_REPORT_OFF_BEACON];
                assert_true(b < PFDOA_BEACON_SLOTS);
                pfdoa_beacon_filter_t e;
                assert_int_equal(pfdoa_anchor_get_filter(&anchor, b, &e), PFDOA_OK);
                assert_true(e.kind != PFDOA_FILTER_NONE);
                const int no_seq = (f.payload[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS] & PFDOA_FLAG_NO_SEQ) != 0u;
                assert_int_equal(no_seq, e.kind != PFDOA_FILTER_PFDOA);
            }
            cap.n = 0u;
        }
        assert_int_equal(pfdoa_anchor_reports_sent(&anchor), reports);
        for (uint8_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
            pfdoa_beacon_filter_t e;
            assert_int_equal(pfdoa_anchor_get_filter(&anchor, i, &e), PFDOA_OK);
            assert_int_equal(pfdoa_beacon_filter_validate(&e), PFDOA_OK);
        }
    }
}

static void test_chunking_does_not_matter(void **state)
{
    (void)state;
    /* The same byte stream in random chunks gives the same frames and counters. */
    rng_t r = {0xC4u};
    static uint8_t stream[4000];
    for (size_t i = 0u; i < sizeof stream; i++) {
        const uint32_t x = rng_next(&r);
        stream[i] = ((x >> 20) % 9u == 0u) ? 0u : (uint8_t)x;
    }
    for (size_t k = 0u; k < 20u; k++) { /* valid frames every ~200 bytes */
        uint8_t p[PFDOA_MSG_CONFIG_SET_LEN] = {(uint8_t)k, 0, 0, 64, 0, 12, 0, 1};
        uint8_t wire[PFDOA_FRAME_WIRE_MAX];
        const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, 5u, p, sizeof p, wire, sizeof wire);
        memcpy(&stream[(k * 200u) + 50u], wire, (size_t)n);
        stream[(k * 200u) + 49u] = 0u;
    }
    start(5u, PFDOA_TRANSPORT_UART, 0u);
    assert_int_equal(pfdoa_anchor_on_uart_rx(&anchor, stream, sizeof stream), 20);
    const size_t frames = cap.n;
    const uint16_t errors = pfdoa_anchor_rx_errors(&anchor);
    static capture_t whole;
    whole = cap;
    for (int rep = 0; rep < 10; rep++) {
        start(5u, PFDOA_TRANSPORT_UART, 0u);
        size_t off = 0u;
        while (off < sizeof stream) {
            size_t len = (size_t)rng_range(&r, 0, 70);
            if (len > (sizeof stream - off)) {
                len = sizeof stream - off;
            }
            (void)pfdoa_anchor_on_uart_rx(&anchor, &stream[off], len);
            off += len;
        }
        assert_int_equal(cap.n, frames);
        assert_int_equal(pfdoa_anchor_rx_errors(&anchor), errors);
        for (size_t i = 0u; i < frames; i++) {
            assert_memory_equal(cap.frames[i].bytes, whole.frames[i].bytes, whole.frames[i].len);
        }
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_random_readings),
        cmocka_unit_test(test_random_host_bytes),
        cmocka_unit_test(test_random_receptions_and_filters),
        cmocka_unit_test(test_chunking_does_not_matter),
    };
    return cmocka_run_group_tests_name("property", tests, NULL, NULL);
}
