/*
 * pfdoa_match.h - the beacon filter table (protocol/SPEC.md 3.1) and the parsers that match
 * a received BLE advertisement or IEEE 802.15.4 MAC frame against it (SPEC 3.2, 3.3).
 *
 * Pure functions over caller-owned memory: no state, no heap, nothing written but *out.
 * Every length is checked before a byte is read, so any input bytes are safe. Layouts,
 * written from the specifications (constants generated from protocol/messages.json):
 *   - BLE advertising PDU: Bluetooth Core Specification v5.3, Vol 6 Part B 2.3;
 *     AD structures: Vol 3 Part C 11, Core Specification Supplement Part A;
 *   - iBeacon: Apple Proximity Beacon Specification (manufacturer data 4C 00 02 15);
 *   - Eddystone-UID: Google Eddystone protocol specification (service data FEAA, frame 0x00);
 *   - AltBeacon: AltBeacon protocol specification v1.0 (beacon code BE AC);
 *   - IEEE 802.15.4-2015, 7.2 (general MAC frame format, Table 7-2 for frame version 2).
 * An ANCHORS entry matches the other anchors' own advertisements (SPEC 3.5, 6.1).
 */
#ifndef PFDOA_MATCH_H
#define PFDOA_MATCH_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* One entry of the filter table. Stored form: kind u8, period_ms u16 LE, match[20]. */
typedef struct pfdoa_beacon_filter {
    uint16_t period_ms;                      /* event window of kinds without a sequence number */
    uint8_t kind;                            /* PFDOA_FILTER_* */
    uint8_t match[PFDOA_FILTER_MATCH_LEN];   /* by kind (SPEC 3.1); unused bytes are zero */
} pfdoa_beacon_filter_t;

/* A reception that matched entry `index`. */
typedef struct pfdoa_match {
    uint16_t seq;     /* the beacon's sequence number when has_seq */
    uint8_t index;
    uint8_t has_seq;  /* 1 for our beacon (PFDOA) and an anchor's advertisement, 0 for the others */
    uint8_t peer;     /* an ANCHORS entry's match: the anchor heard (0..126); else PFDOA_ANCHOR_BROADCAST */
} pfdoa_match_t;

/* PFDOA_OK for an entry a FILTER_SET may set (SPEC 1.5), else PFDOA_ERR_ARG. */
int32_t pfdoa_beacon_filter_validate(const pfdoa_beacon_filter_t *f);

/* The PFDOA_FILTER_ENTRY_LEN-byte stored form, and back (unpack does not validate). */
void pfdoa_beacon_filter_pack(const pfdoa_beacon_filter_t *f, uint8_t out[PFDOA_FILTER_ENTRY_LEN]);
void pfdoa_beacon_filter_unpack(const uint8_t in[PFDOA_FILTER_ENTRY_LEN], pfdoa_beacon_filter_t *f);

/* The first-boot table: our beacon id 0 in entry 0, the others PFDOA_FILTER_NONE. */
void pfdoa_beacon_filters_default(pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS]);

/* CRC-16 over the stored form of the whole table: STATUS.filter_hash, FILTER_ACK.filter_hash. */
uint16_t pfdoa_beacon_filters_hash(const pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS]);

/*
 * Match an advertisement given as AdvA (6 bytes, on-air order) and AdvData against the
 * n entries of table, in index order (the first match wins). Returns 1 with *out filled,
 * 0 when no entry matches (or the data holds no beacon), PFDOA_ERR_ARG for NULL arguments.
 */
int32_t pfdoa_match_ble_adv(const pfdoa_beacon_filter_t *table, size_t n, const uint8_t adv_a[6],
                            const uint8_t *adv_data, size_t len, pfdoa_match_t *out);

/* The same for a raw advertising PDU (2-byte header, AdvA, AdvData; bytes after the PDU's
 * Length, e.g. a CRC, are ignored). PDU types without AdvData never match. */
int32_t pfdoa_match_ble_pdu(const pfdoa_beacon_filter_t *table, size_t n, const uint8_t *pdu, size_t len,
                            pfdoa_match_t *out);

/* The same for an IEEE 802.15.4 MAC frame without its FCS. */
int32_t pfdoa_match_802154(const pfdoa_beacon_filter_t *table, size_t n, const uint8_t *mpdu, size_t len,
                           pfdoa_match_t *out);

/*
 * Our authenticated beacon (SPEC 9.3) in AdvData, an advertising PDU or an IEEE 802.15.4
 * MAC frame: 1 with *payload pointing at its PFDOA_AUTH_PAYLOAD_LEN bytes inside the
 * input, 0 (*payload NULL) when it carries none, PFDOA_ERR_ARG for NULL arguments. Found,
 * not verified: PFDOA_FILTER_PFDOA_AUTH entries hold a key and are never matched by the
 * functions above; pfdoa_auth_verify (pfdoa_auth.h) decides. A table's hash covers such an
 * entry's key check value, not its key.
 */
int32_t pfdoa_match_auth_ble_adv(const uint8_t *adv_data, size_t len, const uint8_t **payload);
int32_t pfdoa_match_auth_ble_pdu(const uint8_t *pdu, size_t len, const uint8_t **payload);
int32_t pfdoa_match_auth_802154(const uint8_t *mpdu, size_t len, const uint8_t **payload);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_MATCH_H */
