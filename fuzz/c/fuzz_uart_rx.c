/*
 * libFuzzer target: the anchor's UART receive path (stream decoder, SPEC 2.3 checks,
 * CONFIG_SET and FILTER_SET handling), production build (no RADIO_INJECT).
 *
 * Input: byte 0 = mode, byte 1 = anchor id (mod 127), then the payload.
 *   mode bit 0 = 0: the payload is the UART byte stream as is.
 *   mode bit 0 = 1: the payload is a list of records [ctl][len bytes] that the harness
 *     turns into frames, so most of them get past COBS and the CRC (Auterion/
 *     mavlink-fuzz-testing#2: a fuzzer must produce valid CRCs): ctl & 0x3F = body length
 *     (capped at PFDOA_MAX_BODY); ctl & 0x40 = force ver 2, type CONFIG_SET or FILTER_SET
 *     (by the first body byte's low bit) and the exact length; the body is COBS-encoded and
 *     the CRC trailer (with the CRC_EXTRA of the type byte) appended, unless ctl & 0x80: then
 *     3 more input bytes are the trailer; every record is delimited. ctl == 0xFF inserts one
 *     raw stream byte.
 *   mode bit 1: the config and filter stores fail (ack result 2).
 *
 * Oracle, beyond "no crash" (ASan/UBSan): the same stream fed in one call and in chunks of
 * 1..16 bytes gives identical acks, counters, configuration and filter table (chunking
 * never matters); the rx_errors of each kind equal an independent one-shot check of every
 * delimited piece with pfdoa_frame_decode (overlong = piece longer than MAX_ENCODED);
 * every checked CONFIG_SET / FILTER_SET addressed here is acked once, in order, with its
 * token, its kind of ack, result 0/2 iff its fields are valid, and the hash then active;
 * nothing else is sent.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_anchor.h"
#include "pfdoa_cobs.h"
#include "pfdoa_crc16.h"

#define MAX_STREAM 8192u
#define MAX_ACKS 2048u

typedef struct {
    uint8_t type, token, result;
    uint16_t hash;
} ack_t;

typedef struct {
    ack_t acks[MAX_ACKS];
    size_t n_acks;
    int store_fails;
} sink_t;

static int32_t on_uart(void *ctx, const uint8_t *bytes, size_t len)
{
    sink_t *const s = (sink_t *)ctx;
    static const uint8_t to_host[] = {PFDOA_MSG_CONFIG_ACK, PFDOA_MSG_FILTER_ACK};
    CHECK((len >= 2u) && (len <= PFDOA_FRAME_WIRE_MAX) && (bytes[len - 1u] == 0u));
    uint8_t copy[PFDOA_FRAME_WIRE_MAX];
    memcpy(copy, bytes, len);
    pfdoa_frame_t f;
    CHECK(pfdoa_frame_decode(copy, len - 1u, to_host, sizeof to_host, &f) == PFDOA_OK);
    CHECK(s->n_acks < MAX_ACKS);
    ack_t *const a = &s->acks[s->n_acks++];
    a->type = f.type;
    if (f.type == PFDOA_MSG_CONFIG_ACK) {
        a->token = f.payload[PFDOA_MSG_CONFIG_ACK_OFF_TOKEN];
        a->result = f.payload[PFDOA_MSG_CONFIG_ACK_OFF_RESULT];
        a->hash = (uint16_t)(f.payload[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH] |
                             (f.payload[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH + 1] << 8));
    } else {
        a->token = f.payload[PFDOA_MSG_FILTER_ACK_OFF_TOKEN];
        a->result = f.payload[PFDOA_MSG_FILTER_ACK_OFF_RESULT];
        a->hash = (uint16_t)(f.payload[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH] |
                             (f.payload[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH + 1] << 8));
    }
    return 0;
}

static int32_t on_can(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    (void)ctx, (void)id, (void)data, (void)dlc;
    CHECK(0); /* UART-only anchor, and CONFIG_SET over UART is acked on UART */
    return 0;
}

static int32_t on_store(void *ctx, const uint8_t cfg[PFDOA_CONFIG_LEN])
{
    (void)cfg;
    return ((const sink_t *)ctx)->store_fails ? -1 : 0;
}

static int32_t on_filters_store(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    (void)table;
    return ((const sink_t *)ctx)->store_fails ? -1 : 0;
}

static size_t build_stream(const uint8_t *p, size_t n, uint8_t *out)
{
    size_t o = 0u;
    size_t i = 0u;
    while ((i < n) && (o + PFDOA_MAX_ENCODED + 1u < MAX_STREAM)) {
        const uint8_t ctl = p[i++];
        if (ctl == 0xFFu) {
            if (i < n) {
                out[o++] = p[i++];
            }
            continue;
        }
        size_t len = ctl & 0x3Fu;
        if (len > PFDOA_MAX_BODY) {
            len = PFDOA_MAX_BODY;
        }
        uint8_t body[PFDOA_MAX_BODY];
        memset(body, 0, sizeof body);
        const size_t take = (len <= n - i) ? len : n - i;
        memcpy(body, &p[i], take);
        i += take;
        if ((ctl & 0x40u) != 0u) {
            const int filter = (body[0] & 1u) != 0u;
            body[0] = PFDOA_PROTO_VERSION;
            body[1] = filter ? PFDOA_MSG_FILTER_SET : PFDOA_MSG_CONFIG_SET;
            len = PFDOA_HEADER_LEN + (filter ? PFDOA_MSG_FILTER_SET_LEN : PFDOA_MSG_CONFIG_SET_LEN);
        }
        const int32_t e = pfdoa_cobs_encode(body, len, &out[o], MAX_STREAM - o);
        CHECK(e > 0);
        if ((ctl & 0x80u) == 0u) {
            const pfdoa_msg_desc_t *const d = (len >= 2u) ? pfdoa_msg_desc(body[1]) : NULL;
            uint16_t crc = pfdoa_crc16_update(PFDOA_CRC_INIT, &out[o], (size_t)e);
            crc = pfdoa_crc16_byte(crc, (d != NULL) ? d->crc_extra : 0u);
            o += (size_t)e;
            out[o++] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc & PFDOA_TRAILER_VALUE_MASK));
            out[o++] = (uint8_t)(PFDOA_TRAILER_MARKER | ((crc >> PFDOA_TRAILER_BITS) & PFDOA_TRAILER_VALUE_MASK));
            out[o++] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc >> (2u * PFDOA_TRAILER_BITS)));
        } else {
            o += (size_t)e;
            for (int k = 0; (k < 3) && (i < n); k++) {
                out[o++] = p[i++];
            }
        }
        out[o++] = 0u;
    }
    return o;
}

/* Independent oracle: every delimited piece checked alone. */
typedef struct {
    uint16_t kind[PFDOA_ERR_COUNT];
    uint32_t errors;
    ack_t sets[MAX_ACKS]; /* token, valid (as result 0/1) of the addressed CONFIG_SETs */
    size_t n_sets;
} oracle_t;

static void oracle_piece(oracle_t *o, const uint8_t *p, size_t len, uint8_t own)
{
    static const uint8_t known[] = {PFDOA_MSG_CONFIG_SET, PFDOA_MSG_FILTER_SET};
    int32_t rc;
    pfdoa_frame_t f;
    if (len > PFDOA_MAX_ENCODED) {
        rc = PFDOA_ERR_OVERLONG;
    } else {
        uint8_t buf[PFDOA_MAX_ENCODED];
        memcpy(buf, p, len);
        rc = pfdoa_frame_decode(buf, len, known, sizeof known, &f);
        if (rc == PFDOA_OK) {
            if ((f.anchor_id == own) || (f.anchor_id == PFDOA_ANCHOR_BROADCAST)) {
                uint8_t token;
                uint8_t index;
                pfdoa_config_t c;
                pfdoa_beacon_filter_t flt;
                CHECK(o->n_sets < MAX_ACKS);
                ack_t *const want = &o->sets[o->n_sets++];
                want->token = f.payload[0];
                if (f.type == PFDOA_MSG_CONFIG_SET) {
                    want->type = PFDOA_MSG_CONFIG_ACK;
                    want->result = (uint8_t)((pfdoa_msg_unpack_config_set(f.payload, &token, &c) == PFDOA_OK) ? 0u : 1u);
                } else {
                    want->type = PFDOA_MSG_FILTER_ACK;
                    CHECK(pfdoa_msg_unpack_filter_set(f.payload, &token, &index, &flt) == PFDOA_OK);
                    want->result = (uint8_t)(((index < PFDOA_BEACON_SLOTS) &&
                                              (pfdoa_beacon_filter_validate(&flt) == PFDOA_OK)) ? 0u : 1u);
                }
            }
            return;
        }
    }
    CHECK((rc < 0) && (rc >= -PFDOA_ERR_COUNT));
    o->kind[(-rc) - 1]++;
    o->errors++;
}

static void run(pfdoa_anchor_t *a, sink_t *s, uint8_t own, const uint8_t *stream, size_t n, const uint8_t *cuts,
                size_t n_cuts)
{
    const pfdoa_hal_t hal = {s, NULL, on_uart, on_can, NULL, on_store};
    const pfdoa_filter_storage_t storage = {s, NULL, on_filters_store};
    CHECK(pfdoa_anchor_init(a, &hal, own, PFDOA_TRANSPORT_UART) == PFDOA_OK);
    CHECK(pfdoa_anchor_use_filter_storage(a, &storage) == PFDOA_OK);
    size_t i = 0u;
    size_t k = 0u;
    int32_t handled = 0;
    while (i < n) {
        size_t step = (n_cuts > 0u) ? (size_t)(cuts[k++ % n_cuts] % 16u) + 1u : n;
        if (step > n - i) {
            step = n - i;
        }
        const int32_t rc = pfdoa_anchor_on_uart_rx(a, &stream[i], step);
        CHECK(rc >= 0);
        handled += rc;
        i += step;
        CHECK(a->decoder.len <= PFDOA_MAX_ENCODED);
    }
    CHECK((size_t)handled == s->n_acks);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static uint8_t stream[MAX_STREAM];
    static pfdoa_anchor_t one, chunked;
    static sink_t s1, s2;
    static oracle_t o;
    if ((size < 2u) || (size > 4096u)) {
        return 0;
    }
    const uint8_t mode = data[0];
    const uint8_t own = (uint8_t)(data[1] % 127u);
    size_t n;
    if ((mode & 1u) != 0u) {
        n = build_stream(&data[2], size - 2u, stream);
    } else {
        n = size - 2u;
        memcpy(stream, &data[2], n);
    }
    memset(&s1, 0, sizeof s1);
    memset(&s2, 0, sizeof s2);
    s1.store_fails = s2.store_fails = (mode & 2u) != 0u;
    run(&one, &s1, own, stream, n, NULL, 0u);
    run(&chunked, &s2, own, stream, n, data, size);

    /* Chunking never matters. */
    CHECK(s1.n_acks == s2.n_acks);
    CHECK(memcmp(s1.acks, s2.acks, s1.n_acks * sizeof s1.acks[0]) == 0);
    CHECK(memcmp(one.rx_error_kind, chunked.rx_error_kind, sizeof one.rx_error_kind) == 0);
    CHECK(one.rx_errors == chunked.rx_errors);
    CHECK(CONFIG_EQ(one.config, chunked.config));
    CHECK(one.filter_hash == chunked.filter_hash);
    CHECK(one.decoder.len == chunked.decoder.len && one.decoder.discarding == chunked.decoder.discarding);

    /* The one-shot oracle over the delimited pieces (a trailing piece without delimiter is
     * pending, unless it is already overlong). */
    memset(&o, 0, sizeof o);
    size_t start = 0u;
    for (size_t i = 0u; i < n; i++) {
        if (stream[i] == 0u) {
            if (i > start) {
                oracle_piece(&o, &stream[start], i - start, own);
            }
            start = i + 1u;
        }
    }
    if (n - start > PFDOA_MAX_ENCODED) {
        o.kind[(-PFDOA_ERR_OVERLONG) - 1]++;
        o.errors++;
    }
    CHECK(one.rx_errors == ((o.errors > UINT16_MAX) ? UINT16_MAX : o.errors));
    for (size_t k = 0u; k < PFDOA_ERR_COUNT; k++) {
        CHECK(one.rx_error_kind[k] == o.kind[k]);
    }
    CHECK(o.n_sets == s1.n_acks);
    uint16_t last_config_hash = pfdoa_config_hash(&one.config);
    uint16_t last_filter_hash = one.filter_hash;
    int config_acked = 0;
    int filter_acked = 0;
    for (size_t k = 0u; k < o.n_sets; k++) {
        const ack_t *const a = &s1.acks[k];
        CHECK(a->token == o.sets[k].token);
        CHECK(a->type == o.sets[k].type);
        if (a->type == PFDOA_MSG_CONFIG_ACK) {
            last_config_hash = a->hash;
            config_acked = 1;
        } else {
            last_filter_hash = a->hash;
            filter_acked = 1;
        }
        if (o.sets[k].result == 0u) {
            CHECK(a->result == (s1.store_fails ? PFDOA_ACK_STORE_FAILED : PFDOA_ACK_OK));
        } else {
            CHECK(a->result == PFDOA_ACK_INVALID);
        }
    }
    /* The active configuration and table are valid, their hashes those the last acks carried. */
    CHECK(pfdoa_config_validate(&one.config) == PFDOA_OK);
    CHECK(one.config_hash == pfdoa_config_hash(&one.config));
    CHECK(!config_acked || (last_config_hash == one.config_hash));
    CHECK(!filter_acked || (last_filter_hash == one.filter_hash));
    CHECK(one.filter_hash == pfdoa_beacon_filters_hash(one.filters));
    for (size_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
        CHECK(pfdoa_beacon_filter_validate(&one.filters[k]) == PFDOA_OK);
    }
    return 0;
}
