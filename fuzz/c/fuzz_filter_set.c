/*
 * libFuzzer target: FILTER_SET through the anchor's UART receive path (SPEC 1.5, 3.1,
 * 3.4). Input: byte 0 = anchor id (mod 127) and, bit 7, a failing table store; then
 * records of 26 bytes: [target: bit 0 = own id, else broadcast; bit 1 = the frame cut in
 * half and ended (a damaged frame)] and a 25-byte FILTER_SET payload (token, index, kind,
 * period_ms, match[20]), each sent as a whole frame.
 *
 * Oracle: a model table, changed only by a FILTER_SET whose index is in range and whose
 * entry validates; every whole FILTER_SET gets exactly one FILTER_ACK from this anchor with
 * its token and index, result 0 (or 2 when the store fails) for a valid one and 1 for an
 * invalid one, and the hash of the model table; a damaged frame gets nothing and is counted
 * as an rx error; the anchor's table equals the model entry for entry and its hash; a table
 * stored successfully is the model's stored form.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_anchor.h"
#include "pfdoa_frame.h"

#define RECORD (1u + PFDOA_MSG_FILTER_SET_LEN)
#define RECORD_TO_OWN_ID 0x01u  /* else broadcast */
#define RECORD_DAMAGED   0x02u  /* the frame cut in half and ended */

typedef struct {
    uint8_t own;
    int store_fails;
    size_t acks;
    uint8_t ack[PFDOA_MSG_FILTER_ACK_LEN];
    uint8_t stored[PFDOA_FILTER_TABLE_LEN];
    int have_stored;
} sink_t;

static sink_t s;
static const uint8_t to_host[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS, PFDOA_MSG_CONFIG_ACK, PFDOA_MSG_FILTER_ACK};

static int32_t on_uart(void *ctx, const uint8_t *bytes, size_t len)
{
    (void)ctx;
    CHECK((len >= 2u) && (len <= PFDOA_FRAME_WIRE_MAX) && (bytes[len - 1u] == 0u));
    uint8_t copy[PFDOA_FRAME_WIRE_MAX];
    memcpy(copy, bytes, len);
    pfdoa_frame_t f;
    CHECK(pfdoa_frame_decode(copy, len - 1u, to_host, sizeof to_host, &f) == PFDOA_OK);
    CHECK(f.anchor_id == s.own);
    if (f.type == PFDOA_MSG_FILTER_ACK) {
        memcpy(s.ack, f.payload, PFDOA_MSG_FILTER_ACK_LEN);
        s.acks++;
    } else {
        CHECK(f.type == PFDOA_MSG_STATUS); /* the first poll's banner only; no readings here */
    }
    return 0;
}

static int32_t on_store(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    if (s.store_fails) {
        return -1;
    }
    memcpy(s.stored, table, PFDOA_FILTER_TABLE_LEN);
    s.have_stored = 1;
    return 0;
}

static int entry_eq(const pfdoa_beacon_filter_t *x, const pfdoa_beacon_filter_t *y)
{
    return (x->kind == y->kind) && (x->period_ms == y->period_ms) && (memcmp(x->match, y->match, sizeof x->match) == 0);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static pfdoa_anchor_t a;
    if (size < 1u) {
        return 0;
    }
    memset(&s, 0, sizeof s);
    s.own = (uint8_t)((data[0] & PFDOA_CAN_ANCHOR_MASK) % (PFDOA_ANCHOR_ID_MAX + 1u));
    s.store_fails = (data[0] & 0x80u) != 0u;
    const pfdoa_hal_t hal = {&s, NULL, on_uart, NULL, NULL, NULL};
    const pfdoa_filter_storage_t storage = {&s, NULL, on_store};
    CHECK(pfdoa_anchor_init(&a, &hal, s.own, PFDOA_TRANSPORT_UART) == PFDOA_OK);
    CHECK(pfdoa_anchor_use_filter_storage(&a, &storage) == PFDOA_OK);
    pfdoa_beacon_filter_t model[PFDOA_BEACON_SLOTS];
    pfdoa_beacon_filters_default(model);
    uint32_t errors = 0u;
    for (size_t i = 1u; i + RECORD <= size; i += RECORD) {
        const uint8_t how = data[i];
        const uint8_t *const p = &data[i + 1u];
        uint8_t wire[PFDOA_FRAME_WIRE_MAX];
        const uint8_t target = ((how & RECORD_TO_OWN_ID) != 0u) ? s.own : PFDOA_ANCHOR_BROADCAST;
        const int32_t n = pfdoa_frame_encode(PFDOA_MSG_FILTER_SET, target, p, PFDOA_MSG_FILTER_SET_LEN, wire, sizeof wire);
        CHECK(n > 2);
        size_t len = (size_t)n;
        const int damaged = (how & RECORD_DAMAGED) != 0u;
        if (damaged) {
            len = len / 2u; /* the first half, then the delimiter: never a valid frame */
            wire[len - 1u] = 0u;
        }
        const size_t acks_before = s.acks;
        (void)pfdoa_anchor_on_uart_rx(&a, wire, len);
        if (damaged) {
            CHECK(s.acks == acks_before);
            errors++;
        } else {
            uint8_t token, index;
            pfdoa_beacon_filter_t f;
            const int valid = (pfdoa_msg_unpack_filter_set(p, &token, &index, &f) == PFDOA_OK) &&
                              (index < PFDOA_BEACON_SLOTS) && (pfdoa_beacon_filter_validate(&f) == PFDOA_OK);
            if (valid) {
                model[index] = f;
            }
            const uint16_t hash = pfdoa_beacon_filters_hash(model);
            CHECK(s.acks == acks_before + 1u);
            CHECK(s.ack[PFDOA_MSG_FILTER_ACK_OFF_TOKEN] == p[PFDOA_MSG_FILTER_SET_OFF_TOKEN]);
            CHECK(s.ack[PFDOA_MSG_FILTER_ACK_OFF_INDEX] == p[PFDOA_MSG_FILTER_SET_OFF_INDEX]);
            CHECK(s.ack[PFDOA_MSG_FILTER_ACK_OFF_RESULT] ==
                  (valid ? (s.store_fails ? PFDOA_ACK_STORE_FAILED : PFDOA_ACK_OK) : PFDOA_ACK_INVALID));
            CHECK((s.ack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH] | (s.ack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH + 1u] << 8)) == hash);
        }
        for (uint8_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
            pfdoa_beacon_filter_t now;
            CHECK(pfdoa_anchor_get_filter(&a, k, &now) == PFDOA_OK);
            CHECK(entry_eq(&now, &model[k]));
        }
        CHECK(pfdoa_anchor_filter_hash(&a) == pfdoa_beacon_filters_hash(model));
        if (s.have_stored) {
            for (size_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
                uint8_t packed[PFDOA_FILTER_ENTRY_LEN];
                pfdoa_beacon_filter_pack(&model[k], packed);
                CHECK(memcmp(&s.stored[k * PFDOA_FILTER_ENTRY_LEN], packed, sizeof packed) == 0);
            }
        }
        CHECK(pfdoa_anchor_rx_errors(&a) == ((errors > UINT16_MAX) ? UINT16_MAX : errors));
    }
    return 0;
}
