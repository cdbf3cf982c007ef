/*
 * libFuzzer target: the anchor's CAN receive path (acceptance filter, DLC check,
 * CONFIG_SET handling). Input: byte 0 = anchor id (mod 127) and, bit 7, a failing config
 * store; then records [id lo][id hi: bits 0-2 = id bits 8-10, bits 4-7 = DLC code, 0..8
 * as is, 9..15 -> 0..6][DLC data bytes].
 *
 * Oracle: an independent model of SPEC 4 + 3 Configuration: only ids 0x180|own and 0x1FF
 * are seen; a DLC other than 8 is bad_length (counted, nothing sent); an 8-byte CONFIG_SET
 * is acked once on CAN with id 0x200|own, DLC 4, its token, result 0/2 (valid) or 1
 * (invalid, configuration unchanged), and the hash of the configuration then active;
 * nothing else is ever sent; the active configuration always validates.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_anchor.h"

typedef struct {
    uint16_t id;
    uint8_t dlc;
    uint8_t data[8];
    size_t n;
    int store_fails;
} sink_t;

static int32_t on_uart(void *ctx, const uint8_t *bytes, size_t len)
{
    (void)ctx, (void)bytes, (void)len;
    CHECK(0);
    return 0;
}

static int32_t on_can(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    sink_t *const s = (sink_t *)ctx;
    CHECK(dlc <= 8u);
    s->id = id;
    s->dlc = dlc;
    memcpy(s->data, data, dlc);
    s->n++;
    return 0;
}

static int32_t on_store(void *ctx, const uint8_t cfg[PFDOA_CONFIG_LEN])
{
    (void)cfg;
    return ((const sink_t *)ctx)->store_fails ? -1 : 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static pfdoa_anchor_t a;
    static sink_t s;
    if (size < 1u) {
        return 0;
    }
    memset(&s, 0, sizeof s);
    const uint8_t own = (uint8_t)((data[0] & PFDOA_CAN_ANCHOR_MASK) % (PFDOA_ANCHOR_ID_MAX + 1u));
    s.store_fails = (data[0] & 0x80u) != 0u;
    const pfdoa_hal_t hal = {&s, NULL, on_uart, on_can, NULL, on_store};
    CHECK(pfdoa_anchor_init(&a, &hal, own, PFDOA_TRANSPORT_CAN) == PFDOA_OK);
    pfdoa_config_t model;
    pfdoa_config_defaults(&model);
    uint32_t bad_len = 0u;
    size_t i = 1u;
    while (i + 2u <= size) {
        const uint16_t id = (uint16_t)(data[i] | ((data[i + 1u] & 0x07u) << 8));
        uint8_t dlc = (uint8_t)(data[i + 1u] >> 4);
        if (dlc > 8u) {
            dlc = (uint8_t)(dlc - 9u);
        }
        i += 2u;
        if (dlc > size - i) {
            dlc = (uint8_t)(size - i);
        }
        uint8_t frame[8] = {0};
        memcpy(frame, &data[i], dlc);
        i += dlc;
        const size_t sent_before = s.n;
        const int32_t rc = pfdoa_anchor_on_can_rx(&a, id, frame, dlc);
        const int seen = ((id >> PFDOA_CAN_ANCHOR_BITS) == PFDOA_CAN_CONFIG_SET) &&
                         (((id & PFDOA_CAN_ANCHOR_MASK) == own) || ((id & PFDOA_CAN_ANCHOR_MASK) == PFDOA_ANCHOR_BROADCAST));
        if (!seen) {
            CHECK(rc == 0);
            CHECK(s.n == sent_before);
        } else if (dlc != PFDOA_CAN_CONFIG_SET_DLC) {
            CHECK(rc == PFDOA_ERR_BAD_LENGTH);
            CHECK(s.n == sent_before);
            bad_len++;
        } else {
            CHECK(rc == 1);
            CHECK(s.n == sent_before + 1u);
            CHECK(s.id == PFDOA_CAN_ID(PFDOA_CAN_CONFIG_ACK, own));
            CHECK(s.dlc == PFDOA_CAN_CONFIG_ACK_DLC);
            CHECK(s.data[0] == frame[0]);
            uint8_t token;
            pfdoa_config_t c;
            if (pfdoa_msg_unpack_config_set(frame, &token, &c) == PFDOA_OK) {
                model = c;
                CHECK(s.data[1] == (s.store_fails ? PFDOA_ACK_STORE_FAILED : PFDOA_ACK_OK));
            } else {
                CHECK(s.data[1] == PFDOA_ACK_INVALID);
            }
            const uint16_t hash = pfdoa_config_hash(&model);
            CHECK(s.data[2] == (hash & 0xFFu) && s.data[3] == (hash >> 8));
        }
        pfdoa_config_t now;
        CHECK(pfdoa_anchor_get_config(&a, &now) == PFDOA_OK);
        CHECK(CONFIG_EQ(now, model));
        CHECK(pfdoa_config_validate(&now) == PFDOA_OK);
        CHECK(pfdoa_anchor_rx_errors(&a) == ((bad_len > UINT16_MAX) ? UINT16_MAX : bad_len));
        CHECK(pfdoa_anchor_rx_error_count(&a, PFDOA_ERR_BAD_LENGTH) == pfdoa_anchor_rx_errors(&a));
    }
    return 0;
}
