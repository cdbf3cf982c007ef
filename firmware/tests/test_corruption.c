/*
 * Exhaustive corruption search (SPEC 2.4): every single-bit and every two-bit error in every
 * golden UART frame (protocol/vectors/uart.json), the delimiter included, fed through the
 * anchor's stream decoder; and every three-bit error in the first golden frame of each
 * version-2 type of at most THREE_BIT_MAX_WIRE bytes (the longer ones would take minutes).
 * The decoder knows every type of both directions, so it accepts at least what any real
 * receiver accepts; nothing may come out of it.
 */
#include "pfdoa_frame.h"
#include "test_support.h"
#include "vectors.h"

#define N_ELEMS(a) (sizeof(a) / sizeof((a)[0]))

static const uint8_t ALL_TYPES[] = {PFDOA_MSG_RSSI_REPORT,  PFDOA_MSG_STATUS,     PFDOA_MSG_CONFIG_SET,
                                    PFDOA_MSG_CONFIG_ACK,   PFDOA_MSG_FILTER_SET, PFDOA_MSG_FILTER_ACK,
                                    PFDOA_MSG_RADIO_INJECT, PFDOA_MSG_RADIO_INJECT_RAW};

#define THREE_BIT_MAX_WIRE 27u

typedef struct search {
    uint32_t frames;
    uint32_t patterns[3]; /* 1, 2 and 3 flipped bits */
    uint32_t accepted[3];
    uint32_t rejected;    /* frames the decoder counted as bad */
} search_t;

/* A delimiter, the (damaged) wire bytes, a delimiter: frames the decoder accepted. */
static uint32_t feed(const uint8_t *const wire, const size_t n, uint32_t *const rejected)
{
    pfdoa_decoder_t dec;
    pfdoa_frame_t f;
    pfdoa_decoder_init(&dec, ALL_TYPES, sizeof ALL_TYPES);
    uint32_t ok = 0u;
    for (size_t i = 0u; i <= n + 1u; i++) {
        const uint8_t b = ((i == 0u) || (i > n)) ? 0u : wire[i - 1u];
        const int32_t rc = pfdoa_decoder_push(&dec, b, &f);
        if (rc == 1) {
            ok++;
        } else if (rc < 0) {
            (*rejected)++;
        }
    }
    return ok;
}

static void flip(uint8_t *const b, const size_t bit)
{
    b[bit >> 3] ^= (uint8_t)(0x80u >> (bit & 7u));
}

static void search_frame(const char *const hex, const int three, search_t *const s)
{
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    const size_t n = hex_to_bytes(hex, wire, sizeof wire);
    const size_t nbits = 8u * n;
    s->frames++;
    for (size_t i = 0u; i < nbits; i++) {
        flip(wire, i);
        s->patterns[0]++;
        s->accepted[0] += feed(wire, n, &s->rejected);
        for (size_t j = i + 1u; j < nbits; j++) {
            flip(wire, j);
            s->patterns[1]++;
            s->accepted[1] += feed(wire, n, &s->rejected);
            for (size_t k = j + 1u; three && (k < nbits); k++) {
                flip(wire, k);
                s->patterns[2]++;
                s->accepted[2] += feed(wire, n, &s->rejected);
                flip(wire, k);
            }
            flip(wire, j);
        }
        flip(wire, i);
    }
}

static void test_every_small_bit_error_is_rejected(void **state)
{
    (void)state;
    search_t v2 = {0};
    search_t v1 = {0};
    uint32_t want[3] = {0u, 0u, 0u};
    uint8_t three_done[256] = {0};
    uint32_t three_frames = 0u;
    for (size_t k = 0u; k < N_ELEMS(vec_uart); k++) {
        const vec_uart_t *const v = &vec_uart[k];
        const size_t n_wire = strlen(v->frame) / 2u;
        const size_t nbits = 8u * n_wire;
        const int is_v2 = v->version == PFDOA_PROTO_VERSION;
        const int three = is_v2 && (three_done[v->type] == 0u) && (n_wire <= THREE_BIT_MAX_WIRE);
        three_done[v->type] = (uint8_t)(three_done[v->type] | three);
        three_frames += (uint32_t)three;
        want[0] += (uint32_t)nbits;
        want[1] += (uint32_t)(nbits * (nbits - 1u) / 2u);
        want[2] += three ? (uint32_t)(nbits * (nbits - 1u) * (nbits - 2u) / 6u) : 0u;
        /* The undamaged frame: version 2 is accepted, version 1 is not (anchors speak 2). */
        uint8_t wire[PFDOA_FRAME_WIRE_MAX];
        uint32_t rejected = 0u;
        const size_t n = hex_to_bytes(v->frame, wire, sizeof wire);
        assert_int_equal(feed(wire, n, &rejected), is_v2 ? 1u : 0u);
        search_frame(v->frame, three, is_v2 ? &v2 : &v1);
    }
    print_message("corruption: %u version-2 frames: %u 1-bit, %u 2-bit patterns, %u + %u accepted; "
                  "3 bits in %u of them: %u patterns, %u accepted\n",
                  (unsigned)v2.frames, (unsigned)v2.patterns[0], (unsigned)v2.patterns[1], (unsigned)v2.accepted[0],
                  (unsigned)v2.accepted[1], (unsigned)three_frames, (unsigned)v2.patterns[2],
                  (unsigned)v2.accepted[2]);
    print_message("corruption: %u version-1 frames: %u 1-bit, %u 2-bit patterns, %u + %u accepted\n",
                  (unsigned)v1.frames, (unsigned)v1.patterns[0], (unsigned)v1.patterns[1], (unsigned)v1.accepted[0],
                  (unsigned)v1.accepted[1]);
    assert_true(v2.frames >= 10u);
    assert_true(three_frames >= 5u);
    assert_int_equal(v2.patterns[0] + v1.patterns[0], want[0]);
    assert_int_equal(v2.patterns[1] + v1.patterns[1], want[1]);
    assert_int_equal(v2.patterns[2], want[2]);
    assert_int_equal(v2.accepted[0], 0u);
    assert_int_equal(v2.accepted[1], 0u);
    assert_int_equal(v2.accepted[2], 0u);
    assert_int_equal(v1.accepted[0] + v1.accepted[1], 0u);
    /* Every pattern was rejected by some check (none just vanished). */
    assert_true(v2.rejected >= v2.patterns[0] + v2.patterns[1] + v2.patterns[2]);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_every_small_bit_error_is_rejected),
    };
    return cmocka_run_group_tests_name("corruption", tests, NULL, NULL);
}
