/*
 * Every golden vector of protocol/vectors/ (all the .json files, converted at build time by
 * tools/vectors_to_c.py): CRC, COBS, Q-format arithmetic, UART and CAN frames, invalid
 * frames and streams, and the anchor scripts run against the C anchor.
 */
#include <stdio.h>
#include <stdlib.h>

#include "pfdoa_cobs.h"
#include "pfdoa_crc16.h"
#include "script.h"
#include "test_support.h"
#include "vectors.h"

static const uint8_t all_types[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS,     PFDOA_MSG_CONFIG_SET,
                                    PFDOA_MSG_CONFIG_ACK,  PFDOA_MSG_FILTER_SET, PFDOA_MSG_FILTER_ACK,
                                    PFDOA_MSG_RADIO_INJECT_RAW, PFDOA_MSG_RADIO_INJECT};
static const uint8_t anchor_types[] = {PFDOA_MSG_CONFIG_SET, PFDOA_MSG_FILTER_SET};

static void put_le(uint8_t *const p, const int64_t v, const size_t n)
{
    for (size_t k = 0u; k < n; k++) {
        p[k] = (uint8_t)(((uint64_t)v >> (8u * k)) & 0xFFu);
    }
}

/* The payload of a message built from vector fields with the core's encoders. */
static size_t build_payload(const uint8_t type, const vec_fields_t *const f, uint8_t *const out)
{
    switch (type) {
    case PFDOA_MSG_RSSI_REPORT: {
        const pfdoa_rssi_report_t m = {(uint32_t)f->tick_ms, (uint16_t)f->seq, (int16_t)f->rssi_q8,
                                       (int8_t)f->raw_dbm, (uint8_t)f->n_readings, (uint8_t)f->channel,
                                       (uint8_t)f->flags, (uint8_t)f->beacon};
        pfdoa_msg_pack_rssi_report(&m, out);
        return PFDOA_MSG_RSSI_REPORT_LEN;
    }
    case PFDOA_MSG_STATUS: {
        pfdoa_status_t m;
        m.fw_major = (uint8_t)f->fw_major;
        m.fw_minor = (uint8_t)f->fw_minor;
        m.uptime_s = (uint32_t)f->uptime_s;
        m.config_hash = (uint16_t)f->config_hash;
        m.dropped_events = (uint16_t)f->dropped_events;
        m.rx_errors = (uint16_t)f->rx_errors;
        m.spikes = (uint16_t)f->spikes;
        m.defs_hash = (uint16_t)f->defs_hash;
        m.filter_hash = (uint16_t)f->filter_hash;
        m.filter_slots = (uint8_t)f->filter_slots;
        pfdoa_msg_pack_status(&m, out);
        return PFDOA_MSG_STATUS_LEN;
    }
    case PFDOA_MSG_CONFIG_SET: {
        const pfdoa_config_t c = {(int16_t)f->offset_q8, (uint16_t)f->alpha_q8, (uint8_t)f->spike_db,
                                  (uint8_t)f->report_mode, (uint8_t)f->decimation};
        out[PFDOA_MSG_CONFIG_SET_OFF_TOKEN] = (uint8_t)f->token;
        pfdoa_config_pack(&c, &out[PFDOA_MSG_CONFIG_SET_OFF_OFFSET_Q8]);
        return PFDOA_MSG_CONFIG_SET_LEN;
    }
    case PFDOA_MSG_CONFIG_ACK: {
        const pfdoa_config_ack_t m = {(uint16_t)f->config_hash, (uint8_t)f->token, (uint8_t)f->result};
        pfdoa_msg_pack_config_ack(&m, out);
        return PFDOA_MSG_CONFIG_ACK_LEN;
    }
    case PFDOA_MSG_FILTER_ACK: {
        const pfdoa_filter_ack_t m = {(uint16_t)f->filter_hash, (uint8_t)f->token, (uint8_t)f->result,
                                      (uint8_t)f->index};
        pfdoa_msg_pack_filter_ack(&m, out);
        return PFDOA_MSG_FILTER_ACK_LEN;
    }
    case PFDOA_MSG_FILTER_SET: {
        /* The entry through the core's own packer, after token and index. */
        pfdoa_beacon_filter_t e;
        e.kind = (uint8_t)f->kind;
        e.period_ms = (uint16_t)f->period_ms;
        assert_int_equal(hex_to_bytes(f->match, e.match, sizeof e.match), PFDOA_FILTER_MATCH_LEN);
        out[PFDOA_MSG_FILTER_SET_OFF_TOKEN] = (uint8_t)f->token;
        out[PFDOA_MSG_FILTER_SET_OFF_INDEX] = (uint8_t)f->index;
        pfdoa_beacon_filter_pack(&e, &out[PFDOA_MSG_FILTER_SET_OFF_KIND]);
        return PFDOA_MSG_FILTER_SET_LEN;
    }
    /* No encoder in the core for what the anchor only receives: laid out from the offsets. */
    case PFDOA_MSG_RADIO_INJECT:
        put_le(&out[PFDOA_MSG_RADIO_INJECT_OFF_SEQ], f->seq, 2u);
        put_le(&out[PFDOA_MSG_RADIO_INJECT_OFF_TICK_MS], f->tick_ms, 4u);
        put_le(&out[PFDOA_MSG_RADIO_INJECT_OFF_RSSI_DBM], f->rssi_dbm, 1u);
        out[PFDOA_MSG_RADIO_INJECT_OFF_CHANNEL] = (uint8_t)f->channel;
        out[PFDOA_MSG_RADIO_INJECT_OFF_LQI] = (uint8_t)f->lqi;
        out[PFDOA_MSG_RADIO_INJECT_OFF_RADIO] = (uint8_t)f->radio;
        return PFDOA_MSG_RADIO_INJECT_LEN;
    case PFDOA_MSG_RADIO_INJECT_RAW:
        put_le(&out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_TICK_MS], f->tick_ms, 4u);
        put_le(&out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RSSI_DBM], f->rssi_dbm, 1u);
        out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_CHANNEL] = (uint8_t)f->channel;
        out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LQI] = (uint8_t)f->lqi;
        out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RADIO] = (uint8_t)f->radio;
        out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LENGTH] = (uint8_t)f->length;
        assert_int_equal(hex_to_bytes(f->frame, &out[PFDOA_MSG_RADIO_INJECT_RAW_OFF_FRAME],
                                      PFDOA_MSG_RADIO_INJECT_RAW_FRAME_LEN),
                         PFDOA_MSG_RADIO_INJECT_RAW_FRAME_LEN);
        return PFDOA_MSG_RADIO_INJECT_RAW_LEN;
    default:
        fail_msg("unknown message type %u", type);
        return 0u;
    }
}

static void test_crc(void **state)
{
    (void)state;
    assert_true(VEC_CRC_COUNT > 0u);
    for (size_t i = 0u; i < VEC_CRC_COUNT; i++) {
        uint8_t data[1024];
        const size_t n = hex_to_bytes(vec_crc[i].data, data, sizeof data);
        const uint16_t crc = pfdoa_crc16_update(PFDOA_CRC_INIT, data, n);
        if (crc != vec_crc[i].crc) {
            fail_msg("%s: crc %04x, want %04x", vec_crc[i].name, crc, vec_crc[i].crc);
        }
        if (vec_crc[i].crc_extra >= 0) {
            assert_int_equal((crc & 0xFFu) ^ (crc >> 8), vec_crc[i].crc_extra);
        }
    }
}

static void test_cobs(void **state)
{
    (void)state;
    assert_true(VEC_COBS_COUNT > 0u);
    for (size_t i = 0u; i < VEC_COBS_COUNT; i++) {
        uint8_t dec[1024], enc[1100], out[1100];
        const size_t nd = hex_to_bytes(vec_cobs[i].decoded, dec, sizeof dec);
        const size_t ne = hex_to_bytes(vec_cobs[i].encoded, enc, sizeof enc);
        const int32_t n = pfdoa_cobs_encode(dec, nd, out, sizeof out);
        assert_int_equal(n, (int32_t)ne);
        assert_memory_equal(out, enc, ne);
        const int32_t m = pfdoa_cobs_decode(enc, ne, out, sizeof out);
        assert_int_equal(m, (int32_t)nd);
        if (nd > 0u) {
            assert_memory_equal(out, dec, nd);
        }
        /* In place, as the stream decoder does it. */
        assert_int_equal(pfdoa_cobs_decode(enc, ne, enc, ne), (int32_t)nd);
        if (nd > 0u) {
            assert_memory_equal(enc, dec, nd);
        }
    }
    assert_true(VEC_COBS_ERR_COUNT > 0u);
    for (size_t i = 0u; i < VEC_COBS_ERR_COUNT; i++) {
        uint8_t enc[256], out[256];
        const size_t ne = hex_to_bytes(vec_cobs_err[i].encoded, enc, sizeof enc);
        if (pfdoa_cobs_decode(enc, ne, out, sizeof out) >= 0) {
            fail_msg("%s: decoded a bad block", vec_cobs_err[i].name);
        }
    }
}

static void test_qformat(void **state)
{
    (void)state;
    assert_true(VEC_FOLD_COUNT > 0u);
    for (size_t i = 0u; i < VEC_FOLD_COUNT; i++) {
        const vec_fold_t *const v = &vec_fold[i];
        int32_t sum = 0;
        pfdoa_event_t ev;
        for (uint8_t k = 0u; k < v->n; k++) {
            sum += v->readings[k];
            const pfdoa_radio_reading_t r = {0u, 1u, v->readings[k], 37u, 0u, PFDOA_RADIO_BLE};
            if (k == 0u) {
                pfdoa_event_open(&ev, &r);
            } else {
                pfdoa_event_add(&ev, &r);
            }
        }
        assert_int_equal(pfdoa_fold_mean_q8(sum, v->n), v->mean_q8);
        assert_int_equal(pfdoa_fold_mean_q8(ev.sum, ev.n), v->mean_q8);
    }
    assert_true(VEC_EMA_COUNT > 0u);
    for (size_t i = 0u; i < VEC_EMA_COUNT; i++) {
        const vec_ema_t *const v = &vec_ema[i];
        assert_int_equal(pfdoa_ema_step_q8(v->ema_q8, v->mean_q8, v->alpha_q8), v->result);
    }
}

static void test_uart(void **state)
{
    (void)state;
    assert_true(VEC_UART_COUNT > 0u);
    size_t v1 = 0u;
    for (size_t i = 0u; i < VEC_UART_COUNT; i++) {
        const vec_uart_t *const v = &vec_uart[i];
        uint8_t payload[PFDOA_MAX_RAW], want_frame[PFDOA_FRAME_WIRE_MAX], want_raw[PFDOA_MAX_RAW];
        uint8_t wire[PFDOA_FRAME_WIRE_MAX];
        const size_t nf = hex_to_bytes(v->frame, want_frame, sizeof want_frame);
        if (v->version != PFDOA_PROTO_VERSION) {
            /* A version-1 frame (what a v1 anchor sends): this version-2 receiver refuses it. */
            pfdoa_frame_t f;
            assert_int_equal(pfdoa_frame_decode(want_frame, nf - 1u, all_types, sizeof all_types, &f),
                             PFDOA_ERR_BAD_VERSION);
            v1++;
            continue;
        }
        const size_t np = build_payload(v->type, &v->f, payload);
        const size_t nr = hex_to_bytes(v->raw, want_raw, sizeof want_raw);
        const int32_t n = pfdoa_frame_encode(v->type, v->anchor_id, payload, np, wire, sizeof wire);
        if ((n != (int32_t)nf) || (memcmp(wire, want_frame, nf) != 0)) {
            fail_msg("%s: encoded frame differs", v->name);
        }
        /* raw is the body: what the COBS part (before the trailer) decodes to. */
        uint8_t raw[PFDOA_MAX_RAW];
        assert_int_equal(pfdoa_cobs_decode(wire, nf - 1u - PFDOA_TRAILER_LEN, raw, sizeof raw), (int32_t)nr);
        assert_memory_equal(raw, want_raw, nr);
        /* Decoding gives the message back. */
        pfdoa_frame_t f;
        assert_int_equal(pfdoa_frame_decode(wire, nf - 1u, all_types, sizeof all_types, &f), PFDOA_OK);
        assert_int_equal(f.type, v->type);
        assert_int_equal(f.anchor_id, v->anchor_id);
        assert_int_equal(f.payload_len, np);
        assert_memory_equal(f.payload, payload, np);
        if (v->type == PFDOA_MSG_CONFIG_SET) {
            uint8_t token = 0u;
            pfdoa_config_t c;
            if (pfdoa_msg_unpack_config_set(f.payload, &token, &c) == PFDOA_OK) {
                assert_int_equal(token, v->f.token);
                assert_int_equal(c.offset_q8, v->f.offset_q8);
                assert_int_equal(c.alpha_q8, v->f.alpha_q8);
                assert_int_equal(c.spike_db, v->f.spike_db);
                assert_int_equal(c.report_mode, v->f.report_mode);
                assert_int_equal(c.decimation, v->f.decimation);
            }
        }
        if (v->type == PFDOA_MSG_RADIO_INJECT) {
            pfdoa_radio_reading_t r;
            pfdoa_msg_unpack_radio_inject(f.payload, &r);
            assert_int_equal(r.seq, v->f.seq);
            assert_int_equal(r.tick_ms, v->f.tick_ms);
            assert_int_equal(r.rssi_dbm, v->f.rssi_dbm);
            assert_int_equal(r.channel, v->f.channel);
            assert_int_equal(r.lqi, v->f.lqi);
            assert_int_equal(r.radio, v->f.radio);
        }
        if (v->type == PFDOA_MSG_FILTER_SET) {
            uint8_t token = 0u;
            uint8_t index = 0u;
            pfdoa_beacon_filter_t e;
            assert_int_equal(pfdoa_msg_unpack_filter_set(f.payload, &token, &index, &e), PFDOA_OK);
            assert_int_equal(token, v->f.token);
            assert_int_equal(index, v->f.index);
            assert_int_equal(e.kind, v->f.kind);
            assert_int_equal(e.period_ms, v->f.period_ms);
        }
    }
    assert_true((v1 > 0u) && (v1 < VEC_UART_COUNT));
}

static void test_uart_invalid(void **state)
{
    (void)state;
    assert_true(VEC_UART_INVALID_COUNT > 0u);
    for (size_t i = 0u; i < VEC_UART_INVALID_COUNT; i++) {
        const vec_uart_invalid_t *const v = &vec_uart_invalid[i];
        uint8_t frame[512];
        const size_t n = hex_to_bytes(v->frame, frame, sizeof frame);
        const uint8_t *const known = v->at_anchor ? anchor_types : all_types;
        const size_t n_known = v->at_anchor ? sizeof anchor_types : sizeof all_types;

        /* As one block ... */
        uint8_t copy[512];
        memcpy(copy, frame, n);
        pfdoa_frame_t f;
        const int32_t rc = pfdoa_frame_decode(copy, n, known, n_known, &f);
        /* A frame the gateway checks as version 1 is refused by this version-2 receiver. */
        const int32_t want = v->v1_frame ? PFDOA_ERR_BAD_VERSION : v->error;
        if (rc != want) {
            fail_msg("%s: block check gives %d, want %d", v->name, (int)rc, (int)want);
        }
        /* ... and as a stream: the same single error, then a clean state. Blocks with a
         * 0x00 inside split into several frames on a stream, so only zero-free ones. */
        if (memchr(frame, 0, n) == NULL) {
            pfdoa_decoder_t dec;
            pfdoa_decoder_init(&dec, known, n_known);
            int errors = 0;
            int32_t last = 0;
            for (size_t k = 0u; k <= n; k++) {
                const int32_t r = pfdoa_decoder_push(&dec, (k < n) ? frame[k] : 0u, &f);
                assert_true(r <= 0);
                if (r < 0) {
                    errors++;
                    last = r;
                }
            }
            assert_int_equal(errors, 1);
            assert_int_equal(last, want);
            assert_int_equal(dec.len, 0u);
            assert_int_equal(dec.discarding, 0u);
        }
        /* An anchor counts it once. */
        if (v->at_anchor) {
            capture_t cap;
            memset(&cap, 0, sizeof cap);
            const pfdoa_hal_t hal = cap_hal(&cap);
            pfdoa_anchor_t a;
            assert_int_equal(pfdoa_anchor_init(&a, &hal, 5u, PFDOA_TRANSPORT_UART), PFDOA_OK);
            const uint8_t delim = 0u;
            assert_int_equal(pfdoa_anchor_on_uart_rx(&a, frame, n), 0);
            assert_int_equal(pfdoa_anchor_on_uart_rx(&a, &delim, 1u), 0);
            assert_int_equal(pfdoa_anchor_rx_errors(&a), 1);
            assert_int_equal(pfdoa_anchor_rx_error_count(&a, want), 1);
            assert_int_equal(cap.total, 0u);
        }
    }
}

static void test_uart_streams(void **state)
{
    (void)state;
    assert_true(VEC_STREAM_COUNT > 0u);
    for (size_t i = 0u; i < VEC_STREAM_COUNT; i++) {
        const vec_stream_t *const v = &vec_stream[i];
        if (v->v1_frames > 0) {
            continue; /* the gateway's two-version streams: not this receiver's */
        }
        uint8_t stream[2048];
        const size_t n = hex_to_bytes(v->stream, stream, sizeof stream);
        pfdoa_decoder_t dec;
        if (v->at_anchor) {
            pfdoa_decoder_init(&dec, anchor_types, sizeof anchor_types);
        } else {
            pfdoa_decoder_init(&dec, all_types, sizeof all_types);
        }
        uint32_t errors[PFDOA_ERR_COUNT] = {0};
        size_t ok = 0u;
        for (size_t k = 0u; k < n; k++) {
            pfdoa_frame_t f;
            const int32_t r = pfdoa_decoder_push(&dec, stream[k], &f);
            if (r < 0) {
                assert_true(r >= -PFDOA_ERR_COUNT);
                errors[(-r) - 1]++;
            } else if (r == 1) {
                if (ok >= v->n_decoded) {
                    fail_msg("%s: more frames than expected", v->name);
                }
                const vec_msg_t *const m = &v->decoded[ok];
                uint8_t payload[PFDOA_MAX_RAW];
                const size_t np = build_payload(m->type, &m->f, payload);
                assert_int_equal(f.type, m->type);
                assert_int_equal(f.anchor_id, m->anchor_id);
                assert_int_equal(f.payload_len, np);
                assert_memory_equal(f.payload, payload, np);
                ok++;
            } else {
                /* byte buffered */
            }
        }
        for (size_t e = 0u; e < PFDOA_ERR_COUNT; e++) {
            if (errors[e] != v->errors[e]) {
                fail_msg("%s: error %zu counted %u, want %u", v->name, e, errors[e], v->errors[e]);
            }
        }
        assert_int_equal(ok, v->frames_ok);
        assert_int_equal(ok, v->n_decoded);
    }
}

static void test_can(void **state)
{
    (void)state;
    assert_true(VEC_CAN_COUNT > 0u);
    for (size_t i = 0u; i < VEC_CAN_COUNT; i++) {
        const vec_can_t *const v = &vec_can[i];
        if (v->version != PFDOA_PROTO_VERSION) {
            /* A version-1 anchor's frames: its 8-byte reports are not version-2 reports. */
            for (size_t k = 0u; k < v->n_frames; k++) {
                uint8_t data[8];
                const size_t nd = hex_to_bytes(v->frames[k].data, data, sizeof data);
                const int report = (v->frames[k].id >> PFDOA_CAN_ANCHOR_BITS) == PFDOA_CAN_RSSI_REPORT;
                assert_int_equal(pfdoa_can_check(v->frames[k].id, (uint8_t)nd),
                                 report ? PFDOA_ERR_BAD_LENGTH : PFDOA_OK);
            }
            continue;
        }
        pfdoa_can_frame_t fr[3];
        size_t n = 1u;
        uint8_t payload[PFDOA_MAX_RAW];
        (void)build_payload(v->type, &v->f, payload);
        switch (v->type) {
        case PFDOA_MSG_RSSI_REPORT: {
            const pfdoa_rssi_report_t m = {0u, (uint16_t)v->f.seq, (int16_t)v->f.rssi_q8, (int8_t)v->f.raw_dbm,
                                           0u, 0u, (uint8_t)v->f.flags, (uint8_t)v->f.beacon};
            pfdoa_can_encode_rssi_report(&m, v->anchor_id, &fr[0]);
            break;
        }
        case PFDOA_MSG_STATUS: {
            pfdoa_status_t m;
            m.fw_major = (uint8_t)v->f.fw_major;
            m.fw_minor = (uint8_t)v->f.fw_minor;
            m.uptime_s = (uint32_t)v->f.uptime_s;
            m.config_hash = (uint16_t)v->f.config_hash;
            m.dropped_events = (uint16_t)v->f.dropped_events;
            m.rx_errors = (uint16_t)v->f.rx_errors;
            m.spikes = (uint16_t)v->f.spikes;
            m.defs_hash = (uint16_t)v->f.defs_hash;
            m.filter_hash = (uint16_t)v->f.filter_hash;
            m.filter_slots = (uint8_t)v->f.filter_slots;
            pfdoa_can_encode_status_a(&m, v->anchor_id, &fr[0]);
            pfdoa_can_encode_status_b(&m, v->anchor_id, &fr[1]);
            pfdoa_can_encode_status_c(&m, v->anchor_id, &fr[2]);
            n = 3u;
            break;
        }
        case PFDOA_MSG_CONFIG_ACK: {
            const pfdoa_config_ack_t m = {(uint16_t)v->f.config_hash, (uint8_t)v->f.token, (uint8_t)v->f.result};
            pfdoa_can_encode_config_ack(&m, v->anchor_id, &fr[0]);
            break;
        }
        case PFDOA_MSG_CONFIG_SET:
            /* Host to anchor: the CAN data is the UART payload (SPEC 4). */
            fr[0].id = (uint16_t)((PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | v->anchor_id);
            fr[0].dlc = PFDOA_CAN_CONFIG_SET_DLC;
            memcpy(fr[0].data, payload, PFDOA_CAN_CONFIG_SET_DLC);
            break;
        default:
            fail_msg("%s: no CAN mapping", v->name);
        }
        assert_int_equal(n, v->n_frames);
        for (size_t k = 0u; k < n; k++) {
            uint8_t want[8];
            const size_t nd = hex_to_bytes(v->frames[k].data, want, sizeof want);
            assert_int_equal(fr[k].id, v->frames[k].id);
            assert_int_equal(fr[k].dlc, nd);
            assert_memory_equal(fr[k].data, want, nd);
            assert_int_equal(pfdoa_can_check(fr[k].id, fr[k].dlc), PFDOA_OK);
        }
    }
}

static void test_can_invalid(void **state)
{
    (void)state;
    assert_true(VEC_CAN_INVALID_COUNT > 0u);
    for (size_t i = 0u; i < VEC_CAN_INVALID_COUNT; i++) {
        const vec_can_invalid_t *const v = &vec_can_invalid[i];
        uint8_t data[8];
        const size_t n = hex_to_bytes(v->data, data, sizeof data);
        const int32_t rc = pfdoa_can_check(v->id, (uint8_t)n);
        if (rc != v->error) {
            fail_msg("%s: %d, want %d", v->name, (int)rc, (int)v->error);
        }
    }
}

/* Output lines of one anchor run. */
typedef struct lines {
    size_t n;
    char text[256][SCRIPT_OUT_LINE_MAX];
} lines_t;

static void collect(void *const user, const char *const line)
{
    lines_t *const l = (lines_t *)user;
    assert_true(l->n < 256u);
    assert_true(strlen(line) < SCRIPT_OUT_LINE_MAX);
    strcpy(l->text[l->n++], line);
}

static void run_anchor_scripts(const vec_anchor_t *const vectors, const size_t count)
{
    assert_true(count > 0u);
    static lines_t out;
    for (size_t i = 0u; i < count; i++) {
        const vec_anchor_t *const v = &vectors[i];
        /* STATUS carries the firmware's own version; every vector uses 1.0. */
        assert_int_equal(v->fw_major, PFDOA_FW_MAJOR);
        assert_int_equal(v->fw_minor, PFDOA_FW_MINOR);
        memset(&out, 0, sizeof out);
        script_env_t env;
        memset(&env, 0, sizeof env);
        env.emit = collect;
        env.user = &out;
        env.boot_tick = v->boot_tick;
        env.store_fails = !v->store_ok;
        if (v->has_config) {
            pfdoa_config_pack(&v->config, env.stored);
            env.have_stored = 1;
        }
        if (v->filters != NULL) {
            assert_int_equal(hex_to_bytes(v->filters, env.filters, sizeof env.filters), PFDOA_FILTER_TABLE_LEN);
            env.have_filters = 1;
        }
        pfdoa_hal_t hal;
        script_hal(&env, &hal);
        pfdoa_filter_storage_t storage;
        script_filter_storage(&env, &storage);
        pfdoa_anchor_t a;
        assert_int_equal(pfdoa_anchor_init(&a, &hal, v->anchor_id, v->transports), PFDOA_OK);
        assert_int_equal(pfdoa_anchor_use_filter_storage(&a, &storage), PFDOA_OK);
        if (v->peer_radio >= 0) {
            uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN] = {0};
            pfdoa_peer_radio_t radio;
            assert_true(hex_to_bytes(v->peer_address, address, sizeof address) > 0u);
            script_peer_radio(&env, (uint8_t)v->peer_radio, address, &radio);
            assert_int_equal(pfdoa_anchor_use_peer_radio(&a, &radio), PFDOA_OK);
        }
        for (size_t k = 0u; v->script[k] != NULL; k++) {
            char line[1024];
            uint8_t scratch[512];
            assert_true(strlen(v->script[k]) < sizeof line);
            strcpy(line, v->script[k]);
            if (script_run_line(&a, line, scratch, sizeof scratch) != 0) {
                fail_msg("%s: script line %zu rejected: %s", v->name, k + 1u, v->script[k]);
            }
        }
        size_t k = 0u;
        for (; v->expected[k] != NULL; k++) {
            if ((k >= out.n) || (strcmp(out.text[k], v->expected[k]) != 0)) {
                fail_msg("%s: output line %zu is '%s', want '%s'", v->name, k + 1u, (k < out.n) ? out.text[k] : "<none>",
                         v->expected[k]);
            }
        }
        if (out.n != k) {
            fail_msg("%s: %zu extra output lines, first '%s'", v->name, out.n - k, out.text[k]);
        }
    }
}

static void test_anchor_scripts(void **state)
{
    (void)state;
    run_anchor_scripts(vec_anchor, VEC_ANCHOR_COUNT);
}

/* peer.json "vectors": the anchor's own advertisement (T lines) and peer readings. */
static void test_peer_scripts(void **state)
{
    (void)state;
    run_anchor_scripts(vec_peer_anchor, VEC_PEER_ANCHOR_COUNT);
}

static void test_peer_builds(void **state)
{
    (void)state;
    assert_true(VEC_PEER_BUILD_COUNT > 0u);
    for (size_t i = 0u; i < VEC_PEER_BUILD_COUNT; i++) {
        const vec_peer_build_t *const v = &vec_peer_build[i];
        uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN] = {0}, want[2u * PFDOA_PEER_FRAME_MAX], got[PFDOA_PEER_FRAME_MAX];
        assert_true(hex_to_bytes(v->address, address, sizeof address) > 0u);
        const size_t n = hex_to_bytes(v->frame, want, sizeof want);
        const int32_t rc = pfdoa_peer_frame(v->radio, address, v->anchor_id, v->seq, got, sizeof got);
        if ((rc != (int32_t)n) || (memcmp(got, want, n) != 0)) {
            fail_msg("%s: the frame differs (%d bytes, want %zu)", v->name, (int)rc, n);
        }
        assert_int_equal(pfdoa_peer_frame(v->radio, address, v->anchor_id, v->seq, got, n - 1u), PFDOA_ERR_CAPACITY);
    }
    uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN] = {0}, out[PFDOA_PEER_FRAME_MAX];
    assert_int_equal(pfdoa_peer_frame(2u, address, 1u, 0u, out, sizeof out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_peer_frame(PFDOA_RADIO_BLE, address, PFDOA_ANCHOR_BROADCAST, 0u, out, sizeof out),
                     PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_peer_frame(PFDOA_RADIO_BLE, NULL, 1u, 0u, out, sizeof out), PFDOA_ERR_ARG);
}

static void run_matches(const vec_beacon_match_t *const vectors, const size_t count)
{
    assert_true(count > 0u);
    size_t matched = 0u;
    for (size_t i = 0u; i < count; i++) {
        const vec_beacon_match_t *const v = &vectors[i];
        uint8_t table_bytes[PFDOA_FILTER_TABLE_LEN], adv_a[PFDOA_BLE_ADV_A_LEN], data[256];
        pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS];
        assert_int_equal(hex_to_bytes(v->filters, table_bytes, sizeof table_bytes), sizeof table_bytes);
        for (size_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
            pfdoa_beacon_filter_unpack(&table_bytes[k * PFDOA_FILTER_ENTRY_LEN], &table[k]);
        }
        const size_t n = hex_to_bytes(v->data, data, sizeof data);
        /* An exact-size heap copy, so ASan sees any read past the frame. */
        uint8_t *const exact = (uint8_t *)malloc((n > 0u) ? n : 1u);
        assert_non_null(exact);
        memcpy(exact, data, n);
        pfdoa_match_t m;
        memset(&m, 0xA5, sizeof m);
        int32_t rc;
        if (v->input == 0) {
            assert_int_equal(hex_to_bytes(v->adv_a, adv_a, sizeof adv_a), sizeof adv_a);
            rc = pfdoa_match_ble_adv(table, PFDOA_BEACON_SLOTS, adv_a, exact, n, &m);
        } else if (v->input == 1) {
            rc = pfdoa_match_ble_pdu(table, PFDOA_BEACON_SLOTS, exact, n, &m);
        } else {
            rc = pfdoa_match_802154(table, PFDOA_BEACON_SLOTS, exact, n, &m);
        }
        free(exact);
        if (rc != v->matched) {
            fail_msg("%s: match gives %d, want %d", v->name, (int)rc, v->matched);
        }
        if (rc == 1) {
            matched++;
            assert_int_equal(m.index, v->index);
            assert_int_equal(m.has_seq, v->has_seq);
            if (v->has_seq) {
                assert_int_equal(m.seq, v->seq);
            }
            if (m.peer != ((v->peer >= 0) ? (uint8_t)v->peer : (uint8_t)PFDOA_ANCHOR_BROADCAST)) {
                fail_msg("%s: names anchor %u, want %d", v->name, m.peer, v->peer);
            }
        }
    }
    assert_true((matched > 3u) && (matched < count));
}

static void test_beacon_matches(void **state)
{
    (void)state;
    run_matches(vec_beacon_match, VEC_BEACON_MATCH_COUNT);
}

static void test_peer_matches(void **state)
{
    (void)state;
    run_matches(vec_peer_match, VEC_PEER_MATCH_COUNT);
}

static void run_entries(const vec_beacon_entry_t *const vectors, const size_t count)
{
    assert_true(count > 0u);
    for (size_t i = 0u; i < count; i++) {
        uint8_t bytes[PFDOA_FILTER_ENTRY_LEN], back[PFDOA_FILTER_ENTRY_LEN];
        assert_int_equal(hex_to_bytes(vectors[i].entry, bytes, sizeof bytes), sizeof bytes);
        pfdoa_beacon_filter_t f;
        pfdoa_beacon_filter_unpack(bytes, &f);
        if ((pfdoa_beacon_filter_validate(&f) == PFDOA_OK) != vectors[i].valid) {
            fail_msg("%s: validity differs", vectors[i].name);
        }
        pfdoa_beacon_filter_pack(&f, back);
        assert_memory_equal(back, bytes, sizeof bytes);
    }
}

static void test_beacon_filter_entries(void **state)
{
    (void)state;
    run_entries(vec_beacon_entry, VEC_BEACON_ENTRY_COUNT);
    run_entries(vec_peer_entry, VEC_PEER_ENTRY_COUNT);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_crc),          cmocka_unit_test(test_cobs),
        cmocka_unit_test(test_qformat),      cmocka_unit_test(test_uart),
        cmocka_unit_test(test_uart_invalid), cmocka_unit_test(test_uart_streams),
        cmocka_unit_test(test_can),          cmocka_unit_test(test_can_invalid),
        cmocka_unit_test(test_anchor_scripts), cmocka_unit_test(test_beacon_matches),
        cmocka_unit_test(test_beacon_filter_entries), cmocka_unit_test(test_peer_builds),
        cmocka_unit_test(test_peer_matches), cmocka_unit_test(test_peer_scripts),
    };
    (void)printf("golden vectors: crc %zu, cobs %zu+%zu, fold %zu, ema %zu, uart %zu, uart_invalid %zu, "
                 "streams %zu, can %zu, can_invalid %zu, anchor %zu, beacon matches %zu, filter entries %zu, "
                 "peer builds %zu, peer matches %zu, peer anchor %zu\n",
                 VEC_CRC_COUNT, VEC_COBS_COUNT, VEC_COBS_ERR_COUNT, VEC_FOLD_COUNT, VEC_EMA_COUNT, VEC_UART_COUNT,
                 VEC_UART_INVALID_COUNT, VEC_STREAM_COUNT, VEC_CAN_COUNT, VEC_CAN_INVALID_COUNT, VEC_ANCHOR_COUNT,
                 VEC_BEACON_MATCH_COUNT, VEC_BEACON_ENTRY_COUNT + VEC_PEER_ENTRY_COUNT, VEC_PEER_BUILD_COUNT,
                 VEC_PEER_MATCH_COUNT, VEC_PEER_ANCHOR_COUNT);
    return cmocka_run_group_tests_name("golden vectors", tests, NULL, NULL);
}
