/*
 * libFuzzer target: the raw receive parsers of protocol v2 (SPEC 3.1-3.3): a BLE
 * advertising PDU (pfdoa_match_ble_pdu), AdvA + AdvData (pfdoa_match_ble_adv) and an IEEE
 * 802.15.4 MAC frame without FCS (pfdoa_match_802154), against a filter table the input
 * sets. Input: byte 0 = which parser (bit 0: BLE / 802.15.4); bytes 1..92 = the table in
 * its stored form (4 x 23 bytes; an entry a FILTER_SET could not set becomes NONE, so the
 * table is one an anchor can hold); the rest = the frame, exactly that long (ASan sees a
 * read past its end).
 *
 * Oracle, beyond no crash: the result is 0 or 1; a match names an entry in use whose kind
 * fits the radio (MAC64 only on 802.15.4, MAC48 / iBeacon / Eddystone / AltBeacon only on
 * BLE), has_seq exactly for our beacon's kind and an anchor's advertisement (ANCHORS), a
 * peer exactly for the latter, and never the broadcast id; the first matching entry wins (the table cut
 * before it gives 0, cut after it the same match); the PDU and its AdvA + AdvData, split
 * here by SPEC 3.2 independently of the core, give the same answer, and a PDU that
 * carries no AdvData never matches; the same call twice gives the same answer.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_match.h"

#define TABLE_BYTES (PFDOA_BEACON_SLOTS * PFDOA_FILTER_ENTRY_LEN)

static int same(const pfdoa_match_t *x, const pfdoa_match_t *y)
{
    return (x->index == y->index) && (x->has_seq == y->has_seq) && ((x->has_seq == 0u) || (x->seq == y->seq)) &&
           (x->peer == y->peer);
}

/* AdvA and AdvData of an advertising PDU (SPEC 3.2), written from the spec: 1 when the PDU
 * carries them, else 0. */
static int split_pdu(const uint8_t *pdu, size_t len, const uint8_t **adv_a, const uint8_t **adv_data, size_t *n)
{
    if (len < PFDOA_BLE_PDU_HEADER_LEN) {
        return 0;
    }
    const uint8_t type = (uint8_t)(pdu[0] & PFDOA_BLE_PDU_TYPE_MASK);
    if ((type != PFDOA_BLE_PDU_ADV_IND) && (type != PFDOA_BLE_PDU_ADV_NONCONN_IND) &&
        (type != PFDOA_BLE_PDU_ADV_SCAN_IND) && (type != PFDOA_BLE_PDU_SCAN_RSP)) {
        return 0;
    }
    const size_t length = pdu[1];
    if ((length < PFDOA_BLE_ADV_A_LEN) || (length > PFDOA_BLE_ADV_A_LEN + PFDOA_BLE_ADV_DATA_MAX) ||
        (PFDOA_BLE_PDU_HEADER_LEN + length > len)) {
        return 0;
    }
    *adv_a = &pdu[PFDOA_BLE_PDU_HEADER_LEN];
    *adv_data = &pdu[PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN];
    *n = length - PFDOA_BLE_ADV_A_LEN;
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1u + TABLE_BYTES) {
        return 0;
    }
    const int ieee = (data[0] & 1u) != 0u;
    pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS];
    for (size_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
        pfdoa_beacon_filter_unpack(&data[1u + k * PFDOA_FILTER_ENTRY_LEN], &table[k]);
        if (pfdoa_beacon_filter_validate(&table[k]) != PFDOA_OK) {
            memset(&table[k], 0, sizeof table[k]);
            table[k].kind = PFDOA_FILTER_NONE;
        }
    }
    const uint8_t *const frame = &data[1u + TABLE_BYTES];
    const size_t len = size - 1u - TABLE_BYTES;

    pfdoa_match_t m, again;
    memset(&m, 0, sizeof m);
    memset(&again, 0, sizeof again);
    const int32_t rc = ieee ? pfdoa_match_802154(table, PFDOA_BEACON_SLOTS, frame, len, &m)
                            : pfdoa_match_ble_pdu(table, PFDOA_BEACON_SLOTS, frame, len, &m);
    CHECK((rc == 0) || (rc == 1));
    const int32_t rc2 = ieee ? pfdoa_match_802154(table, PFDOA_BEACON_SLOTS, frame, len, &again)
                             : pfdoa_match_ble_pdu(table, PFDOA_BEACON_SLOTS, frame, len, &again);
    CHECK((rc2 == rc) && ((rc == 0) || same(&m, &again)));

    if (!ieee) {
        const uint8_t *adv_a = NULL;
        const uint8_t *adv_data = NULL;
        size_t n = 0u;
        if (split_pdu(frame, len, &adv_a, &adv_data, &n) == 0) {
            CHECK(rc == 0);
        } else {
            pfdoa_match_t via_adv;
            memset(&via_adv, 0, sizeof via_adv);
            CHECK(pfdoa_match_ble_adv(table, PFDOA_BEACON_SLOTS, adv_a, adv_data, n, &via_adv) == rc);
            CHECK((rc == 0) || same(&m, &via_adv));
        }
    }
    if (rc == 1) {
        CHECK(m.index < PFDOA_BEACON_SLOTS);
        const uint8_t kind = table[m.index].kind;
        CHECK(kind != PFDOA_FILTER_NONE);
        CHECK((m.has_seq != 0u) == ((kind == PFDOA_FILTER_PFDOA) || (kind == PFDOA_FILTER_ANCHORS)));
        CHECK((m.peer != PFDOA_ANCHOR_BROADCAST) == (kind == PFDOA_FILTER_ANCHORS));
        if (ieee) {
            CHECK((kind == PFDOA_FILTER_PFDOA) || (kind == PFDOA_FILTER_MAC64) || (kind == PFDOA_FILTER_ANCHORS));
        } else {
            CHECK(kind != PFDOA_FILTER_MAC64);
        }
        /* The first matching entry wins. */
        pfdoa_match_t cut;
        memset(&cut, 0, sizeof cut);
        const int32_t before = ieee ? pfdoa_match_802154(table, m.index, frame, len, &cut)
                                    : pfdoa_match_ble_pdu(table, m.index, frame, len, &cut);
        CHECK(before == 0);
        const int32_t upto = ieee ? pfdoa_match_802154(table, m.index + 1u, frame, len, &cut)
                                  : pfdoa_match_ble_pdu(table, m.index + 1u, frame, len, &cut);
        CHECK((upto == 1) && same(&cut, &m));
    }
    return 0;
}
