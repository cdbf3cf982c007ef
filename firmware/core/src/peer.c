/* The anchor's own advertisement (SPEC 6.1), see pfdoa_peer.h. */
#include "pfdoa_peer.h"

#include <string.h>

#include "pfdoa_le.h"

/* IEEE 802.15.4-2015 7.2.2: a data frame, PAN ID Compression, short destination, frame
 * version 0, extended source. */
#define PEER_FCF                                                                                                      \
    ((uint16_t)(PFDOA_IEEE802154_FRAME_DATA | PFDOA_IEEE802154_FCF_PANID_COMP |                                     \
                (PFDOA_IEEE802154_ADDR_SHORT << PFDOA_IEEE802154_FCF_DST_MODE_SHIFT) |                              \
                (PFDOA_IEEE802154_ADDR_EXT << PFDOA_IEEE802154_FCF_SRC_MODE_SHIFT)))

int32_t pfdoa_peer_frame(const uint8_t radio, const uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN],
                         const uint8_t anchor_id, const uint16_t seq, uint8_t *const out, const size_t cap)
{
    if ((address == NULL) || (out == NULL) || (anchor_id > PFDOA_ANCHOR_ID_MAX) ||
        ((radio != PFDOA_RADIO_BLE) && (radio != PFDOA_RADIO_IEEE802154))) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_PEER_FRAME_MAX) {
        return PFDOA_ERR_CAPACITY;
    }
    size_t at;
    size_t alen;
    if (radio == PFDOA_RADIO_BLE) {
        /* Vol 6 Part B 2.3: header (ADV_NONCONN_IND, TxAdd: a random address), AdvA, then the
         * AdvData: Flags and the manufacturer data (Vol 3 Part C 11, CSS Part A 1.3, 1.4). */
        static const uint8_t head[] = {
            (uint8_t)(PFDOA_BLE_PDU_ADV_NONCONN_IND | PFDOA_BLE_PDU_TXADD),
            (uint8_t)(PFDOA_BLE_ADV_A_LEN + PFDOA_PEER_ADV_DATA_LEN)};
        static const uint8_t ad[] = {2u, PFDOA_BLE_AD_FLAGS, PFDOA_BLE_FLAGS_GENERAL_NO_BREDR,
                                     (uint8_t)(1u + 2u + PFDOA_BEACON_PAYLOAD_LEN), PFDOA_BLE_AD_MANUFACTURER,
                                     (uint8_t)(PFDOA_BEACON_COMPANY_ID & 0xFFu), (uint8_t)(PFDOA_BEACON_COMPANY_ID >> 8)};
        (void)memcpy(out, head, sizeof head);
        alen = PFDOA_BLE_ADV_A_LEN;
        (void)memcpy(&out[sizeof head], address, alen);
        at = sizeof head + alen;
        (void)memcpy(&out[at], ad, sizeof ad);
        at += sizeof ad;
    } else {
        /* 7.2: FCF, sequence number, destination PAN and short address (broadcast), the
         * extended source address (its PAN elided by PAN ID Compression), payload. */
        pfdoa_put_u16(out, PEER_FCF);
        out[2] = (uint8_t)(seq & 0xFFu);
        pfdoa_put_u16(&out[3], PFDOA_IEEE802154_BROADCAST);
        pfdoa_put_u16(&out[5], PFDOA_IEEE802154_BROADCAST);
        alen = PFDOA_IEEE802154_EXT_ADDR_LEN;
        (void)memcpy(&out[7], address, alen);
        at = 7u + alen;
    }
    out[at] = PFDOA_BEACON_MAGIC0;
    out[at + 1u] = PFDOA_ANCHOR_MAGIC1;
    pfdoa_put_u16(&out[at + 2u], seq);
    out[at + 4u] = anchor_id;
    return (int32_t)(at + PFDOA_BEACON_PAYLOAD_LEN);
}
