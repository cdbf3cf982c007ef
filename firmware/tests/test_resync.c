/*
 * Garbage and resynchronisation on the anchor's UART receive path (pfdoa_anchor_on_uart_rx),
 * the C twin of tests/unit/test_protocol_stream.py and tests/unit/test_corruption.py for the gateway:
 *  - garbage-only streams are never acted on (no ack, configuration unchanged), and every
 *    rejected frame is counted;
 *  - a bad-CRC frame whose last bytes look like the start of the next frame, a frame cut
 *    short by a corrupted (premature) delimiter, and two frames glued by a lost delimiter
 *    never swallow the next good frame (pymavlink#881's failure mode);
 *  - splitting the stream at every byte boundary, or feeding it a byte at a time, gives the
 *    same acks, counters and configuration as one call.
 */
#include "test_support.h"

/* The ack tokens the anchor sent (UART), in order. */
static size_t ack_tokens(capture_t *const c, uint8_t *const out, const size_t cap)
{
    uint8_t scratch[PFDOA_FRAME_WIRE_MAX];
    size_t n = 0u;
    for (size_t i = 0u; (i < c->n) && (n < cap); i++) {
        const pfdoa_frame_t f = cap_decode(c, i, scratch);
        assert_int_equal(f.type, PFDOA_MSG_CONFIG_ACK);
        out[n++] = f.payload[0];
    }
    return n;
}

static size_t config_set(const uint8_t token, const uint8_t anchor_id, uint8_t *const wire)
{
    const uint8_t p[PFDOA_MSG_CONFIG_SET_LEN] = {token, 0, 0, (uint8_t)(64u + token), 0, 12, 0, 1};
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, anchor_id, p, sizeof p, wire, PFDOA_FRAME_WIRE_MAX);
    assert_true(n > 0);
    return (size_t)n;
}

static void fresh(pfdoa_anchor_t *const a, capture_t *const c, pfdoa_hal_t *const h)
{
    memset(c, 0, sizeof *c);
    *h = cap_hal(c);
    assert_int_equal(pfdoa_anchor_init(a, h, 5u, PFDOA_TRANSPORT_UART), PFDOA_OK);
}

static void test_garbage_only_is_never_acted_on(void **state)
{
    (void)state;
    rng_t r = {0x6A5BA6Eu};
    static uint8_t stream[20000];
    for (int round = 0; round < 20; round++) {
        pfdoa_anchor_t a;
        capture_t c;
        pfdoa_hal_t h;
        fresh(&a, &c, &h);
        const uint16_t hash0 = pfdoa_anchor_config_hash(&a);
        size_t zeros = 0u;
        for (size_t i = 0u; i < sizeof stream; i++) {
            const uint32_t x = rng_next(&r);
            /* Plenty of delimiters (1 in 16) so most pieces reach the later checks; some
             * rounds bias bytes to a valid-looking header (ver 1, type 3, own id). */
            uint8_t b = (uint8_t)x;
            if ((round % 2 == 1) && (((x >> 8) % 4u) == 0u)) {
                static const uint8_t look[] = {1u, 3u, 5u, 0x0Eu, 0x0Fu};
                b = look[(x >> 12) % sizeof look];
            }
            stream[i] = (((x >> 20) % 16u) == 0u) ? 0u : b;
        }
        stream[sizeof stream - 1u] = 0u;
        size_t pieces = 0u;
        size_t start = 0u;
        for (size_t i = 0u; i < sizeof stream; i++) {
            if (stream[i] == 0u) {
                pieces += (i > start) ? 1u : 0u;
                start = i + 1u;
            }
            zeros += (stream[i] == 0u) ? 1u : 0u;
        }
        assert_int_equal(pfdoa_anchor_on_uart_rx(&a, stream, sizeof stream), 0);
        assert_int_equal(c.total, 0u);
        assert_int_equal(pfdoa_anchor_config_hash(&a), hash0);
        /* Every non-empty piece is one rejected frame, counted once. */
        assert_int_equal(pfdoa_anchor_rx_errors(&a), pieces);
        assert_true(zeros > 1000u);
    }
}

static void test_bad_frame_never_swallows_the_next_good_frame(void **state)
{
    (void)state;
    uint8_t good[PFDOA_FRAME_WIRE_MAX];
    const size_t ng = config_set(42u, 5u, good);
    uint8_t tmpl[PFDOA_FRAME_WIRE_MAX];
    const size_t nt = config_set(7u, 5u, tmpl);
    for (int variant = 0; variant < 4; variant++) {
        uint8_t stream[3u * PFDOA_FRAME_WIRE_MAX];
        size_t k = 0u;
        int one_error = 1; /* the damaged bytes make exactly one rejected frame */
        if (variant == 0) {
            /* Bad CRC, last bytes = a code byte and a frame header (01 03 05). */
            memcpy(stream, tmpl, nt);
            stream[nt - 4u] = 0x04u;
            stream[nt - 3u] = 0x01u;
            stream[nt - 2u] = 0x03u;
            k = nt;
        } else if (variant == 1) {
            /* A corrupted byte became a premature delimiter: two bad pieces. */
            memcpy(stream, tmpl, nt);
            stream[5] = 0u;
            k = nt;
            one_error = 0; /* two rejected pieces */
        } else if (variant == 2) {
            /* A lost delimiter glued two frames: one over-long or bad piece. */
            memcpy(stream, tmpl, nt - 1u);
            memcpy(&stream[nt - 1u], tmpl, nt);
            k = 2u * nt - 1u;
            one_error = 0;
        } else {
            /* The last byte before the delimiter is a large value: as a COBS code it would
             * point past the end (the decoder must not wait for more bytes). */
            memcpy(stream, tmpl, nt);
            stream[nt - 2u] = 0x30u;
            k = nt;
        }
        memcpy(&stream[k], good, ng);
        k += ng;
        pfdoa_anchor_t a;
        capture_t c;
        pfdoa_hal_t h;
        fresh(&a, &c, &h);
        assert_int_equal(pfdoa_anchor_on_uart_rx(&a, stream, k), 1);
        uint8_t tokens[8];
        assert_int_equal(ack_tokens(&c, tokens, sizeof tokens), 1u);
        assert_int_equal(tokens[0], 42u);
        assert_true(pfdoa_anchor_rx_errors(&a) >= 1u);
        if (one_error != 0) {
            assert_int_equal(pfdoa_anchor_rx_errors(&a), 1u);
        }
    }
}

/* A stream of good CONFIG_SETs (own id, broadcast, another anchor's) mixed with every
 * kind of damage. */
static size_t faulty_stream(uint8_t *const s, const size_t cap)
{
    rng_t r = {0x5EED5u};
    size_t k = 0u;
    for (uint8_t t = 1u; t <= 24u; t++) {
        uint8_t f[PFDOA_FRAME_WIRE_MAX];
        const uint8_t id = (t % 3u == 0u) ? 127u : ((t % 5u == 0u) ? 9u : 5u);
        size_t n = config_set(t, id, f);
        const uint32_t x = rng_next(&r) % 8u;
        if (x == 0u) {
            f[3] ^= 0x04u; /* bad CRC (no zero introduced: bit 2 of a payload byte) */
            if (f[3] == 0u) {
                f[3] = 1u;
            }
        } else if (x == 1u) {
            n--; /* lost delimiter */
        } else if (x == 2u) {
            assert_true(k + 80u < cap);
            memset(&s[k], 0x55, 70u); /* an over-long run */
            k += 70u;
            s[k++] = 0u;
        } else if (x == 3u) {
            s[k++] = (uint8_t)(rng_next(&r) | 1u); /* a stray byte glued to the front */
        } else {
            /* intact */
        }
        assert_true(k + n < cap);
        memcpy(&s[k], f, n);
        k += n;
    }
    s[k++] = 0u;
    return k;
}

typedef struct {
    size_t n_acks;
    uint8_t acks[CAP_MAX_FRAMES];
    uint16_t errors;
    uint16_t kind[PFDOA_ERR_COUNT];
    uint16_t hash;
} outcome_t;

static outcome_t feed(const uint8_t *const s, const size_t n, const size_t cut, const int bytewise)
{
    pfdoa_anchor_t a;
    capture_t c;
    pfdoa_hal_t h;
    fresh(&a, &c, &h);
    if (bytewise != 0) {
        for (size_t i = 0u; i < n; i++) {
            assert_true(pfdoa_anchor_on_uart_rx(&a, &s[i], 1u) >= 0);
        }
    } else {
        assert_true(pfdoa_anchor_on_uart_rx(&a, s, cut) >= 0);
        assert_true(pfdoa_anchor_on_uart_rx(&a, &s[cut], n - cut) >= 0);
    }
    outcome_t o;
    memset(&o, 0, sizeof o);
    o.n_acks = ack_tokens(&c, o.acks, sizeof o.acks);
    o.errors = pfdoa_anchor_rx_errors(&a);
    for (int32_t e = 1; e <= PFDOA_ERR_COUNT; e++) {
        o.kind[e - 1] = pfdoa_anchor_rx_error_count(&a, -e);
    }
    o.hash = pfdoa_anchor_config_hash(&a);
    return o;
}

/* Field by field (struct padding is indeterminate). */
static void assert_same(const outcome_t *const a, const outcome_t *const b)
{
    assert_int_equal(a->n_acks, b->n_acks);
    assert_memory_equal(a->acks, b->acks, a->n_acks);
    assert_int_equal(a->errors, b->errors);
    assert_memory_equal(a->kind, b->kind, sizeof a->kind);
    assert_int_equal(a->hash, b->hash);
}

static void test_split_at_every_byte_boundary(void **state)
{
    (void)state;
    static uint8_t s[4096];
    const size_t n = faulty_stream(s, sizeof s);
    const outcome_t ref = feed(s, n, n, 0);
    assert_true(ref.n_acks >= 8u);
    assert_true(ref.errors >= 4u);
    for (size_t cut = 0u; cut <= n; cut++) {
        const outcome_t o = feed(s, n, cut, 0);
        assert_same(&o, &ref);
    }
    const outcome_t b = feed(s, n, 0u, 1);
    assert_same(&b, &ref);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_garbage_only_is_never_acted_on),
        cmocka_unit_test(test_bad_frame_never_swallows_the_next_good_frame),
        cmocka_unit_test(test_split_at_every_byte_boundary),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
