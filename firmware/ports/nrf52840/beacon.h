/*
 * beacon.h - the one step from a received packet to a core reading: is this our beacon,
 * and which sequence number does it carry?
 *
 * Kept in this one file on purpose: the core will take raw advertisements and parse the
 * standard beacon formats itself (issue 16). Then this file shrinks to handing the packet
 * over, and the radio driver and main loop stay as they are.
 *
 * BLE: an advertising PDU (ADV_IND, ADV_NONCONN_IND, ADV_SCAN_IND or SCAN_RSP; Core spec
 * Vol 6 Part B 2.3) whose AdvData holds a manufacturer-specific AD structure (type 0xFF)
 * with company id 0xFFFF (little-endian), the bytes "PF" and a u16 sequence number,
 * little-endian - the format firmware/micropython/board_ble.py documents.
 *
 * IEEE 802.15.4: a data frame (IEEE 802.15.4-2006 7.2.2.2) without security, whose MAC
 * payload starts with the same "PF" + u16 sequence number (this port's interim format until
 * the beacon core of issue 16 defines one). The MAC header's own 8-bit sequence number is
 * not used: the core counts losses on 16 bits.
 */
#ifndef NRF_BEACON_H
#define NRF_BEACON_H

#include <stdint.h>

#include "pfdoa_msg.h"
#include "radio.h"

#define BEACON_COMPANY_ID 0xFFFFu /* the Bluetooth SIG's id reserved for tests */
#define BEACON_MAGIC0     0x50u   /* 'P' */
#define BEACON_MAGIC1     0x46u   /* 'F' */

/* The sequence number of a BLE advertising PDU (header, length, AdvA, AdvData) from our
 * beacon: 1 with *seq set, else 0. */
int beacon_ble_seq(const uint8_t *pdu, uint8_t len, uint16_t *seq);

/* The same for an 802.15.4 MPDU without its FCS. */
int beacon_ieee802154_seq(const uint8_t *mpdu, uint8_t len, uint16_t *seq);

/* A received packet -> the core's reading: 1 with *out filled, 0 when it is not ours. */
int beacon_reading(const radio_packet_t *pkt, pfdoa_radio_reading_t *out);

/* radio_t's accept filter: only our beacons are queued (so a full queue loses readings,
 * counted as the core's dropped_events, not strangers' packets). */
int beacon_accept(const radio_packet_t *pkt, void *ctx);

#endif /* NRF_BEACON_H */
