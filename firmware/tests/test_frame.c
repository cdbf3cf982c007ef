/* UART framing, stream decoder and CAN mapping unit tests. */
#include "pfdoa_cobs.h"
#include "pfdoa_crc16.h"
#include "pfdoa_frame.h"
#include "test_support.h"

static const uint8_t all_types[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS,     PFDOA_MSG_CONFIG_SET,
                                    PFDOA_MSG_CONFIG_ACK,  PFDOA_MSG_FILTER_SET, PFDOA_MSG_FILTER_ACK,
                                    PFDOA_MSG_RADIO_INJECT, PFDOA_MSG_RADIO_INJECT_RAW};
static const uint8_t anchor_types[] = {PFDOA_MSG_CONFIG_SET, PFDOA_MSG_FILTER_SET};

/* A version-2 block (SPEC 2.1: COBS body, CRC trailer over it; no delimiter) for any header,
 * the CRC xor-ed with crc_xor. Written here from the SPEC, not with pfdoa_frame_encode. */
static size_t make_block(const uint8_t ver, const uint8_t type, const uint8_t anchor, const uint8_t *const payload,
                         const size_t plen, const uint8_t crc_extra, const uint16_t crc_xor, uint8_t *const wire)
{
    uint8_t body[128];
    body[0] = ver;
    body[1] = type;
    body[2] = anchor;
    memcpy(&body[3], payload, plen);
    const int32_t n = pfdoa_cobs_encode(body, 3u + plen, wire, 200u);
    assert_true(n > 0);
    const uint16_t crc =
        (uint16_t)(pfdoa_crc16_byte(pfdoa_crc16_update(PFDOA_CRC_INIT, wire, (size_t)n), crc_extra) ^ crc_xor);
    wire[n] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc & PFDOA_TRAILER_VALUE_MASK));
    wire[n + 1] = (uint8_t)(PFDOA_TRAILER_MARKER | ((crc >> PFDOA_TRAILER_BITS) & PFDOA_TRAILER_VALUE_MASK));
    wire[n + 2] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc >> (2u * PFDOA_TRAILER_BITS)));
    return (size_t)n + 3u;
}

/* A version-1 block (SPEC 8.2: the CRC inside the COBS block). */
static size_t make_v1_block(const uint8_t type, const uint8_t anchor, const uint8_t *const payload, const size_t plen,
                            const uint8_t crc_extra, uint8_t *const wire)
{
    uint8_t raw[128];
    raw[0] = 1u;
    raw[1] = type;
    raw[2] = anchor;
    memcpy(&raw[3], payload, plen);
    const uint16_t crc = pfdoa_crc16_byte(pfdoa_crc16_update(PFDOA_CRC_INIT, raw, 3u + plen), crc_extra);
    raw[3u + plen] = (uint8_t)(crc & 0xFFu);
    raw[4u + plen] = (uint8_t)(crc >> 8);
    const int32_t n = pfdoa_cobs_encode(raw, plen + 5u, wire, 200u);
    assert_true(n > 0);
    return (size_t)n;
}

static void test_encode_decode_every_type(void **state)
{
    (void)state;
    for (size_t t = 0u; t < sizeof all_types; t++) {
        const pfdoa_msg_desc_t *const d = pfdoa_msg_desc(all_types[t]);
        assert_non_null(d);
        uint8_t payload[PFDOA_MAX_RAW];
        for (size_t i = 0u; i < d->payload_len; i++) {
            payload[i] = (uint8_t)(i * 37u); /* includes zeros */
        }
        for (uint16_t anchor = 0u; anchor <= 127u; anchor++) {
            uint8_t wire[PFDOA_FRAME_WIRE_MAX];
            const int32_t n = pfdoa_frame_encode(d->type, (uint8_t)anchor, payload, d->payload_len, wire, sizeof wire);
            assert_true(n > 0);
            assert_int_equal(wire[n - 1], 0u);
            assert_null(memchr(wire, 0, (size_t)n - 1u));
            pfdoa_frame_t f;
            const int32_t rc = pfdoa_frame_decode(wire, (size_t)n - 1u, all_types, sizeof all_types, &f);
            if ((anchor == 127u) && (d->to_host != 0u)) {
                assert_int_equal(rc, PFDOA_ERR_BAD_ANCHOR);
                continue;
            }
            assert_int_equal(rc, PFDOA_OK);
            assert_int_equal(f.type, d->type);
            assert_int_equal(f.anchor_id, anchor);
            assert_memory_equal(f.payload, payload, d->payload_len);
        }
    }
}

static void test_encode_rejects_bad_arguments(void **state)
{
    (void)state;
    uint8_t payload[16] = {0};
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    assert_int_equal(pfdoa_frame_encode(0x05u, 1u, payload, 4u, wire, sizeof wire), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 5u, wire, sizeof wire), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 128u, payload, 4u, wire, sizeof wire), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, NULL, 4u, wire, sizeof wire), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 4u, NULL, 10u), PFDOA_ERR_ARG);
    /* 4-byte payload: a 7-byte body, 8 encoded, 3 trailer bytes, 12 with the delimiter. */
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 4u, wire, 11u), PFDOA_ERR_CAPACITY);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 4u, wire, 12u), 12);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 4u, wire, 3u), PFDOA_ERR_CAPACITY);
    assert_int_equal(pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 1u, payload, 4u, wire, 0u), PFDOA_ERR_CAPACITY);
}

static void test_check_order(void **state)
{
    (void)state;
    uint8_t p[100] = {0};
    uint8_t w[256];
    pfdoa_frame_t f;
    size_t n;
    const uint8_t x = PFDOA_MSG_CONFIG_SET_CRC_EXTRA;
    /* A good CONFIG_SET first, for reference. */
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 8u, x, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_OK);
    /* A version-1 frame is routed away first (SPEC 2.3 check 2), good or not. */
    n = make_v1_block(PFDOA_MSG_CONFIG_SET, 5u, p, 8u, x, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_VERSION);
    n = make_v1_block(0x55u, 200u, p, 70u, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, 60u, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_VERSION);
    /* Version is checked before the type, the type before the length, the length before the CRC. */
    n = make_block(3u, 0x55u, 5u, p, 3u, 0u, 1u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_VERSION);
    n = make_block(2u, 0x55u, 5u, p, 3u, 0u, 1u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_UNKNOWN_TYPE);
    /* A report is a known type but unknown to an anchor. */
    n = make_block(2u, PFDOA_MSG_RSSI_REPORT, 5u, p, PFDOA_MSG_RSSI_REPORT_LEN, PFDOA_MSG_RSSI_REPORT_CRC_EXTRA, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_UNKNOWN_TYPE);
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 7u, 0u, 1u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_TRUNCATED);
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 9u, 0u, 1u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_LENGTH);
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 8u, PFDOA_MSG_STATUS_CRC_EXTRA, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_CRC);
    /* Every CRC bit counts, and so do the trailer's marker and spare bits. */
    for (unsigned bit = 0u; bit < 16u; bit++) {
        n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 8u, x, (uint16_t)(1u << bit), w);
        assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_CRC);
    }
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 8u, x, 0u, w);
    w[n - 1u] |= 0x04u; /* a spare bit of the last trailer byte */
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_CRC);
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 5u, p, 8u, x, 0u, w);
    w[n - 2u] &= (uint8_t)~PFDOA_TRAILER_MARKER; /* the marker of the middle one */
    if (w[n - 2u] != 0u) {
        assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_CRC);
    }
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 200u, p, 8u, x, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_ERR_BAD_ANCHOR);
    /* 127 is fine host-to-anchor ... */
    n = make_block(2u, PFDOA_MSG_CONFIG_SET, 127u, p, 8u, x, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, anchor_types, sizeof anchor_types, &f), PFDOA_OK);
    /* ... not anchor-to-host. */
    n = make_block(2u, PFDOA_MSG_CONFIG_ACK, 127u, p, 4u, PFDOA_MSG_CONFIG_ACK_CRC_EXTRA, 0u, w);
    assert_int_equal(pfdoa_frame_decode(w, n, all_types, sizeof all_types, &f), PFDOA_ERR_BAD_ANCHOR);
    /* No room for a code byte and the trailer; a body shorter than the header. */
    const uint8_t three[] = {0x81, 0x81, 0x81};
    memcpy(w, three, sizeof three);
    assert_int_equal(pfdoa_frame_decode(w, sizeof three, all_types, sizeof all_types, &f), PFDOA_ERR_TRUNCATED);
    const uint8_t two_byte_body[] = {0x03, 0x02, 0x05, 0x81, 0x81, 0x81};
    memcpy(w, two_byte_body, sizeof two_byte_body);
    assert_int_equal(pfdoa_frame_decode(w, sizeof two_byte_body, all_types, sizeof all_types, &f), PFDOA_ERR_TRUNCATED);
    /* Over MAX_ENCODED is overlong whatever it holds. */
    memset(w, 0x42, 66u);
    assert_int_equal(pfdoa_frame_decode(w, 66u, all_types, sizeof all_types, &f), PFDOA_ERR_OVERLONG);
    assert_int_equal(pfdoa_frame_decode(NULL, 3u, all_types, sizeof all_types, &f), PFDOA_ERR_ARG);
}

static int32_t push_all(pfdoa_decoder_t *const d, const uint8_t *const b, const size_t n, int32_t *const first_err,
                        size_t *const frames)
{
    int32_t errs = 0;
    for (size_t i = 0u; i < n; i++) {
        pfdoa_frame_t f;
        const int32_t r = pfdoa_decoder_push(d, b[i], &f);
        if (r < 0) {
            if (errs == 0) {
                *first_err = r;
            }
            errs++;
        } else if (r == 1) {
            (*frames)++;
        } else {
            /* buffered */
        }
        assert_true(d->len <= PFDOA_MAX_ENCODED);
        assert_true(d->discarding <= 1u);
    }
    return errs;
}

static void test_decoder_overlong_boundary(void **state)
{
    (void)state;
    pfdoa_decoder_t d;
    pfdoa_decoder_init(&d, all_types, sizeof all_types);
    uint8_t buf[200];
    int32_t err = 0;
    size_t frames = 0u;
    /* Exactly MAX_ENCODED non-zero bytes then 0x00: checked normally (not overlong). */
    memset(buf, 0x42, 65u);
    buf[65] = 0u;
    assert_int_equal(push_all(&d, buf, 66u, &err, &frames), 1);
    assert_int_not_equal(err, PFDOA_ERR_OVERLONG);
    /* The 66th non-zero byte reports overlong at once, and only once ... */
    memset(buf, 0x42, 150u);
    assert_int_equal(push_all(&d, buf, 65u, &err, &frames), 0);
    assert_int_equal(push_all(&d, buf, 1u, &err, &frames), 1);
    assert_int_equal(err, PFDOA_ERR_OVERLONG);
    assert_int_equal(push_all(&d, buf, 100u, &err, &frames), 0);
    /* ... its delimiter ends it silently, and the next frame decodes. */
    const uint8_t zero = 0u;
    assert_int_equal(push_all(&d, &zero, 1u, &err, &frames), 0);
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const uint8_t p[4] = {9, 0, 1, 2};
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 3u, p, 4u, wire, sizeof wire);
    assert_int_equal(push_all(&d, wire, (size_t)n, &err, &frames), 0);
    assert_int_equal(frames, 1u);
}

static void test_decoder_skips_empty_frames_and_resyncs(void **state)
{
    (void)state;
    pfdoa_decoder_t d;
    pfdoa_decoder_init(&d, all_types, sizeof all_types);
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const uint8_t p[4] = {1, 2, 3, 4};
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_ACK, 3u, p, 4u, wire, sizeof wire);
    uint8_t stream[200];
    size_t k = 0u;
    stream[k++] = 0u; /* empty frames */
    stream[k++] = 0u;
    memcpy(&stream[k], wire, (size_t)n);
    k += (size_t)n;
    memcpy(&stream[k], wire, (size_t)n); /* corrupt copy: bad CRC */
    stream[k + 4u] ^= 0x10u; /* a payload bit: still no zero byte (bytes 2..7 are 05 04 01 02 03 04) */
    k += (size_t)n;
    memcpy(&stream[k], wire, (size_t)n); /* the next frame is intact */
    k += (size_t)n;
    int32_t err = 0;
    size_t frames = 0u;
    assert_int_equal(push_all(&d, stream, k, &err, &frames), 1);
    assert_int_equal(err, PFDOA_ERR_BAD_CRC);
    assert_int_equal(frames, 2u);
    assert_int_equal(pfdoa_decoder_push(NULL, 0u, NULL), PFDOA_ERR_ARG);
}

static void test_decoder_random_bytes_stay_consistent(void **state)
{
    (void)state;
    /* Whatever arrives: bounded state, every complete frame yields exactly one result,
     * and a valid frame right after any garbage and a delimiter is still decoded. */
    rng_t r = {0xDEC0DEu};
    pfdoa_decoder_t d;
    pfdoa_decoder_init(&d, anchor_types, sizeof anchor_types);
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    uint8_t p[8] = {7, 0, 0, 64, 0, 12, 0, 1};
    const int32_t wn = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, 5u, p, 8u, wire, sizeof wire);
    for (int iter = 0; iter < 3000; iter++) {
        const size_t len = (size_t)rng_range(&r, 0, 300);
        for (size_t i = 0u; i < len; i++) {
            const uint32_t x = rng_next(&r);
            uint8_t b = (uint8_t)x;
            if (((x >> 8) % 16u) == 0u) {
                b = 0u;
            }
            pfdoa_frame_t f;
            const int32_t rc = pfdoa_decoder_push(&d, b, &f);
            assert_true((rc >= -PFDOA_ERR_COUNT) && (rc <= 1));
            if (rc == 1) {
                assert_int_equal(f.type, PFDOA_MSG_CONFIG_SET);
                assert_true(f.payload >= d.buf);
                assert_true((f.payload + f.payload_len) <= (d.buf + sizeof d.buf));
            }
            assert_true(d.len <= PFDOA_MAX_ENCODED);
            assert_true(d.discarding <= 1u);
        }
        const uint8_t zero = 0u;
        int32_t err = 0;
        size_t frames = 0u;
        (void)push_all(&d, &zero, 1u, &err, &frames);
        frames = 0u;
        assert_int_equal(push_all(&d, wire, (size_t)wn, &err, &frames), 0);
        assert_int_equal(frames, 1u);
    }
}

static void test_can_ids_and_check(void **state)
{
    (void)state;
    const pfdoa_rssi_report_t rep = {123456u, 0xBEEFu, -15701, -63, 3u, 39u, 0x08u, 2u};
    pfdoa_can_frame_t f;
    pfdoa_can_encode_rssi_report(&rep, 5u, &f);
    assert_int_equal(f.id, PFDOA_CAN_ID(PFDOA_CAN_RSSI_REPORT, 5u));
    assert_int_equal(f.dlc, PFDOA_CAN_RSSI_REPORT_DLC);
    assert_int_equal(le16(&f.data[0]), 0xBEEF);
    assert_int_equal(le16s(&f.data[2]), -15701);
    assert_int_equal(f.data[4], 0xC1); /* raw_dbm, then flags and the beacon entry */
    assert_int_equal(f.data[5], 0x08);
    assert_int_equal(f.data[6], 2);
    assert_int_equal(pfdoa_can_check(f.id, f.dlc), PFDOA_OK);
    pfdoa_status_t st;
    memset(&st, 0, sizeof st);
    st.filter_hash = 0xA1B2u;
    st.filter_slots = 4u;
    pfdoa_can_encode_status_c(&st, 9u, &f);
    assert_int_equal(f.id, PFDOA_CAN_ID(PFDOA_CAN_STATUS_C, 9u));
    assert_int_equal(f.dlc, PFDOA_CAN_STATUS_C_DLC);
    assert_int_equal(le16(&f.data[0]), 0xA1B2);
    assert_int_equal(f.data[2], 4);
    const pfdoa_config_ack_t ack = {0x1234u, 9u, PFDOA_ACK_STORE_FAILED};
    pfdoa_can_encode_config_ack(&ack, 126u, &f);
    assert_int_equal(f.id, PFDOA_CAN_ID(PFDOA_CAN_CONFIG_ACK, 126u));
    assert_int_equal(f.dlc, PFDOA_CAN_CONFIG_ACK_DLC);
    assert_int_equal(pfdoa_can_check(f.id, f.dlc), PFDOA_OK);
    /* Every id: only the six can_types are known; the DLC must match; 127 only for CONFIG_SET. */
    uint8_t dlc_of[1u << 4] = {0u}; /* by can_type; 0 = unknown */
    dlc_of[PFDOA_CAN_RSSI_REPORT] = PFDOA_CAN_RSSI_REPORT_DLC;
    dlc_of[PFDOA_CAN_CONFIG_SET] = PFDOA_CAN_CONFIG_SET_DLC;
    dlc_of[PFDOA_CAN_CONFIG_ACK] = PFDOA_CAN_CONFIG_ACK_DLC;
    dlc_of[PFDOA_CAN_STATUS_A] = PFDOA_CAN_STATUS_A_DLC;
    dlc_of[PFDOA_CAN_STATUS_B] = PFDOA_CAN_STATUS_B_DLC;
    dlc_of[PFDOA_CAN_STATUS_C] = PFDOA_CAN_STATUS_C_DLC;
    for (uint16_t id = 0u; id <= PFDOA_CAN_ID_MASK; id++) {
        const uint16_t can_type = (uint16_t)(id >> PFDOA_CAN_ANCHOR_BITS);
        for (uint8_t dlc = 0u; dlc <= 8u; dlc++) {
            const int32_t rc = pfdoa_can_check(id, dlc);
            if (dlc_of[can_type] == 0u) {
                assert_int_equal(rc, PFDOA_ERR_UNKNOWN_TYPE);
            } else if (dlc != dlc_of[can_type]) {
                assert_int_equal(rc, PFDOA_ERR_BAD_LENGTH);
            } else if (((id & PFDOA_CAN_ANCHOR_MASK) == PFDOA_ANCHOR_BROADCAST) && (can_type != PFDOA_CAN_CONFIG_SET)) {
                assert_int_equal(rc, PFDOA_ERR_BAD_ANCHOR);
            } else {
                assert_int_equal(rc, PFDOA_OK);
            }
        }
    }
    assert_int_equal(pfdoa_can_check(0x800u, 8u), PFDOA_ERR_ARG);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_encode_decode_every_type),
        cmocka_unit_test(test_encode_rejects_bad_arguments),
        cmocka_unit_test(test_check_order),
        cmocka_unit_test(test_decoder_overlong_boundary),
        cmocka_unit_test(test_decoder_skips_empty_frames_and_resyncs),
        cmocka_unit_test(test_decoder_random_bytes_stay_consistent),
        cmocka_unit_test(test_can_ids_and_check),
    };
    return cmocka_run_group_tests_name("frame", tests, NULL, NULL);
}
