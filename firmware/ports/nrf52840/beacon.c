#include "beacon.h"

#include <stddef.h>

#include "pfdoa_defs.h"

#define ADV_IND          0x0u
#define ADV_NONCONN_IND  0x2u
#define SCAN_RSP         0x4u
#define ADV_SCAN_IND     0x6u
#define PDU_TYPE_MASK    0x0Fu
#define ADVA_LEN         6u
#define ADV_PAYLOAD_MAX  37u /* legacy advertising PDU payload */
#define AD_MANUFACTURER  0xFFu
#define OUR_AD_LEN       7u  /* type, company id (2), "PF", seq (2) */

/* Walks AD structures (length, type, data): the seq of ours, if present. A zero length
 * ends the data; a structure running past the end is not looked into. */
static int ad_seq(const uint8_t *ad, size_t n, uint16_t *seq)
{
    size_t i = 0u;
    while (i + 1u < n) {
        const size_t len = ad[i];
        if (len == 0u) {
            break;
        }
        if (ad[i + 1u] == AD_MANUFACTURER && len >= OUR_AD_LEN && i + len < n
            && ad[i + 2u] == (uint8_t)(BEACON_COMPANY_ID & 0xFFu) && ad[i + 3u] == (uint8_t)(BEACON_COMPANY_ID >> 8)
            && ad[i + 4u] == BEACON_MAGIC0 && ad[i + 5u] == BEACON_MAGIC1) {
            *seq = (uint16_t)(ad[i + 6u] | ((uint16_t)ad[i + 7u] << 8));
            return 1;
        }
        i += len + 1u;
    }
    return 0;
}

int beacon_ble_seq(const uint8_t *const pdu, const uint8_t len, uint16_t *const seq)
{
    if (pdu == NULL || seq == NULL || len < 2u) {
        return 0;
    }
    const uint8_t type = pdu[0] & PDU_TYPE_MASK;
    const size_t payload = pdu[1];
    if ((type != ADV_IND && type != ADV_NONCONN_IND && type != ADV_SCAN_IND && type != SCAN_RSP)
        || payload < ADVA_LEN || payload > ADV_PAYLOAD_MAX || (size_t)len < 2u + payload) {
        return 0;
    }
    return ad_seq(&pdu[2u + ADVA_LEN], payload - ADVA_LEN, seq);
}

/* IEEE 802.15.4-2006 7.2.1.1: frame control bits. */
#define FCF_TYPE_MASK     0x0007u
#define FCF_TYPE_DATA     0x0001u
#define FCF_SECURITY      0x0008u
#define FCF_PANID_COMP    0x0040u
#define FCF_DST_MODE(f)   (((f) >> 10) & 3u)
#define FCF_VERSION(f)    (((f) >> 12) & 3u)
#define FCF_SRC_MODE(f)   (((f) >> 14) & 3u)
#define FCF_IE_PRESENT    0x0200u

/* Bytes of an address field for an addressing mode: none, reserved, short, extended. */
static size_t addr_len(const uint32_t mode)
{
    static const uint8_t len[4] = { 0u, 0xFFu, 2u, 8u };
    return len[mode & 3u];
}

int beacon_ieee802154_seq(const uint8_t *const mpdu, const uint8_t len, uint16_t *const seq)
{
    if (mpdu == NULL || seq == NULL || len < 3u) {
        return 0;
    }
    const uint32_t fcf = (uint32_t)mpdu[0] | ((uint32_t)mpdu[1] << 8);
    if ((fcf & FCF_TYPE_MASK) != FCF_TYPE_DATA || (fcf & FCF_SECURITY) != 0u
        || (FCF_VERSION(fcf) == 2u && (fcf & FCF_IE_PRESENT) != 0u)) {
        return 0;
    }
    const size_t dst = addr_len(FCF_DST_MODE(fcf));
    const size_t src = addr_len(FCF_SRC_MODE(fcf));
    if (dst == 0xFFu || src == 0xFFu) {
        return 0;
    }
    /* FCF, sequence number, destination PAN + address, source PAN (unless compressed) +
     * address. */
    size_t off = 3u;
    if (dst != 0u) {
        off += 2u + dst;
    }
    if (src != 0u) {
        off += (((fcf & FCF_PANID_COMP) != 0u && dst != 0u) ? 0u : 2u) + src;
    }
    if ((size_t)len < off + 4u || mpdu[off] != BEACON_MAGIC0 || mpdu[off + 1u] != BEACON_MAGIC1) {
        return 0;
    }
    *seq = (uint16_t)(mpdu[off + 2u] | ((uint16_t)mpdu[off + 3u] << 8));
    return 1;
}

int beacon_reading(const radio_packet_t *const pkt, pfdoa_radio_reading_t *const out)
{
    uint16_t seq = 0u;
    const int ours = (pkt->mode == RADIO_MODE_BLE) ? beacon_ble_seq(pkt->data, pkt->len, &seq)
                                                   : beacon_ieee802154_seq(pkt->data, pkt->len, &seq);
    if (ours == 0) {
        return 0;
    }
    out->tick_ms = pkt->tick_ms;
    out->seq = seq;
    out->rssi_dbm = pkt->rssi_dbm;
    out->channel = pkt->channel;
    out->lqi = pkt->lqi;
    out->radio = (pkt->mode == RADIO_MODE_BLE) ? (uint8_t)PFDOA_RADIO_BLE : (uint8_t)PFDOA_RADIO_IEEE802154;
    return 1;
}

int beacon_accept(const radio_packet_t *const pkt, void *const ctx)
{
    pfdoa_radio_reading_t r;
    (void)ctx;
    return beacon_reading(pkt, &r);
}
