/*
 * pfdoa_peer.h - the anchor's own advertisement (protocol/SPEC.md 6.1), which the other
 * anchors report as peer readings (SPEC 3.5) so that the gateway can calibrate the radio
 * model from anchors that hear each other: the frame builder and the radio the board
 * sends it on.
 *
 * The frame is our beacon's (SPEC 6) with the magic 'P' 'N' and the anchor's id in place of
 * the beacon id: over BLE an ADV_NONCONN_IND PDU (Bluetooth Core Specification v5.3, Vol 6
 * Part B 2.3) from the anchor's AdvA, over IEEE 802.15.4 a data frame (IEEE 802.15.4-2015,
 * 7.2) to the broadcast address of the broadcast PAN from its extended address.
 */
#ifndef PFDOA_PEER_H
#define PFDOA_PEER_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* AdvData: Flags (3 bytes), manufacturer data (length, type, company id, payload). */
#define PFDOA_PEER_ADV_DATA_LEN (3u + 4u + PFDOA_BEACON_PAYLOAD_LEN)
/* The longest frame of either radio (both are 20 bytes). */
#define PFDOA_PEER_FRAME_MAX (PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN + PFDOA_PEER_ADV_DATA_LEN)

/*
 * The radio a board sends the anchor's advertisement on, given with
 * pfdoa_anchor_use_peer_radio(). send() transmits one whole frame (the radio adds the CRC or
 * FCS; a BLE radio sends the PDU on its advertising channels) and returns >= 0 on success; it
 * is called from pfdoa_anchor_poll() and must not call back into the anchor.
 */
typedef struct pfdoa_peer_radio {
    void *ctx;
    int32_t (*send)(void *ctx, const uint8_t *frame, size_t len);
    uint8_t radio;      /* PFDOA_RADIO_BLE or PFDOA_RADIO_IEEE802154 */
    uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN]; /* BLE: AdvA (first 6 bytes); 802.15.4: extended address; on-air order */
} pfdoa_peer_radio_t;

/*
 * Builds the advertisement of anchor_id with sequence number seq for radio into out (cap
 * bytes). Returns its length, PFDOA_ERR_ARG (NULL, an unknown radio, anchor_id > 126) or
 * PFDOA_ERR_CAPACITY.
 */
int32_t pfdoa_peer_frame(uint8_t radio, const uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN], uint8_t anchor_id,
                         uint16_t seq, uint8_t *out, size_t cap);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_PEER_H */
