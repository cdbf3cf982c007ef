/* Beacon filter table and reception parsers, see pfdoa_match.h and protocol/SPEC.md 3.1-3.3. */
#include "pfdoa_match.h"

#include <string.h>

#include "pfdoa_auth.h"
#include "pfdoa_crc16.h"
#include "pfdoa_le.h"

/* Match bytes each kind uses (SPEC 3.1), indexed by kind. */
static const uint8_t used_bytes[] = {
    PFDOA_FILTER_NONE_USED,      PFDOA_FILTER_PFDOA_USED, PFDOA_FILTER_IBEACON_USED, PFDOA_FILTER_EDDYSTONE_UID_USED,
    PFDOA_FILTER_ALTBEACON_USED, PFDOA_FILTER_MAC48_USED, PFDOA_FILTER_MAC64_USED,   PFDOA_FILTER_PFDOA_AUTH_USED,
    PFDOA_FILTER_ANCHORS_USED,
};

int32_t pfdoa_beacon_filter_validate(const pfdoa_beacon_filter_t *const f)
{
    if ((f == NULL) || (f->kind >= sizeof used_bytes)) {
        return PFDOA_ERR_ARG;
    }
    for (size_t i = used_bytes[f->kind]; i < PFDOA_FILTER_MATCH_LEN; i++) {
        if (f->match[i] != 0u) {
            return PFDOA_ERR_ARG;
        }
    }
    /* Kinds without a sequence number need a period; ours (and an empty entry) have none. */
    const int no_period =
        (f->kind == PFDOA_FILTER_NONE) || (f->kind == PFDOA_FILTER_PFDOA) || (f->kind == PFDOA_FILTER_PFDOA_AUTH);
    return ((f->period_ms == 0u) == (no_period != 0)) ? PFDOA_OK : PFDOA_ERR_ARG;
}

void pfdoa_beacon_filter_pack(const pfdoa_beacon_filter_t *const f, uint8_t out[PFDOA_FILTER_ENTRY_LEN])
{
    if ((f != NULL) && (out != NULL)) {
        out[0] = f->kind;
        pfdoa_put_u16(&out[1], f->period_ms);
        (void)memcpy(&out[3], f->match, PFDOA_FILTER_MATCH_LEN);
    }
}

void pfdoa_beacon_filter_unpack(const uint8_t in[PFDOA_FILTER_ENTRY_LEN], pfdoa_beacon_filter_t *const f)
{
    if ((in != NULL) && (f != NULL)) {
        f->kind = in[0];
        f->period_ms = pfdoa_get_u16(&in[1]);
        (void)memcpy(f->match, &in[3], PFDOA_FILTER_MATCH_LEN);
    }
}

void pfdoa_beacon_filters_default(pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS])
{
    if (table != NULL) {
        (void)memset(table, 0, PFDOA_BEACON_SLOTS * sizeof table[0]);
        table[PFDOA_FILTER_DEFAULT_INDEX].kind = PFDOA_FILTER_DEFAULT_KIND;
        table[PFDOA_FILTER_DEFAULT_INDEX].match[0] = PFDOA_FILTER_DEFAULT_ID;
    }
}

uint16_t pfdoa_beacon_filters_hash(const pfdoa_beacon_filter_t table[PFDOA_BEACON_SLOTS])
{
    uint16_t crc = PFDOA_CRC_INIT;
    if (table != NULL) {
        for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
            uint8_t entry[PFDOA_FILTER_ENTRY_LEN];
            pfdoa_beacon_filter_pack(&table[i], entry);
            if (table[i].kind == PFDOA_FILTER_PFDOA_AUTH) {
                /* SPEC 9.2: the hash covers the key check value, never the key. */
                pfdoa_auth_key_check(table[i].match, &entry[3]);
                (void)memset(&entry[3u + PFDOA_AUTH_CHECK_LEN], 0, PFDOA_FILTER_MATCH_LEN - PFDOA_AUTH_CHECK_LEN);
            }
            crc = pfdoa_crc16_update(crc, entry, sizeof entry);
            (void)memset(entry, 0, sizeof entry);
        }
    }
    return crc;
}

/* The beacon identities found in AdvData: the first AD structure of each format. */
typedef struct adv_ids {
    const uint8_t *ibeacon;   /* uuid + major + minor (20) */
    const uint8_t *eddystone; /* namespace + instance (16) */
    const uint8_t *altbeacon; /* beacon id (20) */
    const uint8_t *auth;      /* our authenticated payload (SPEC 9.3) */
    uint16_t seq;             /* ours */
    uint16_t peer_seq;        /* an anchor's own advertisement (SPEC 6.1) */
    uint8_t id;
    uint8_t ours;
    uint8_t peer;             /* the anchor's id; PFDOA_ANCHOR_BROADCAST: none */
} adv_ids_t;

/* An anchor's advertisement payload 'P' 'N' seq id (SPEC 6.1): its id (0..126) and seq, or
 * PFDOA_ANCHOR_BROADCAST for anything else. */
static uint8_t anchor_payload(const uint8_t *const p, const size_t n, uint16_t *const seq)
{
    if ((n != PFDOA_BEACON_PAYLOAD_LEN) || (p[0] != PFDOA_BEACON_MAGIC0) || (p[1] != PFDOA_ANCHOR_MAGIC1) ||
        (p[4] > PFDOA_ANCHOR_ID_MAX)) {
        return PFDOA_ANCHOR_BROADCAST;
    }
    *seq = pfdoa_get_u16(&p[2]);
    return p[4];
}

static void parse_adv_data(const uint8_t *const d, const size_t len, adv_ids_t *const ids)
{
    (void)memset(ids, 0, sizeof *ids);
    ids->peer = PFDOA_ANCHOR_BROADCAST;
    size_t i = 0u;
    while (i < len) {
        const size_t l = d[i];
        if ((l == 0u) || (l > (len - i - 1u))) {
            break; /* the end of the significant part, or a structure that does not fit */
        }
        const uint8_t type = d[i + 1u];
        const uint8_t *const c = &d[i + 2u]; /* the AD data after its type */
        const size_t n = l - 1u;
        if ((type == PFDOA_BLE_AD_MANUFACTURER) && (n >= 4u)) {
            const uint16_t company = pfdoa_get_u16(c);
            uint16_t peer_seq = 0u;
            const uint8_t peer = (company == PFDOA_BEACON_COMPANY_ID) ? anchor_payload(&c[2], n - 2u, &peer_seq)
                                                                      : (uint8_t)PFDOA_ANCHOR_BROADCAST;
            if ((ids->ours == 0u) && (company == PFDOA_BEACON_COMPANY_ID) && (c[2] == PFDOA_BEACON_MAGIC0) &&
                (c[3] == PFDOA_BEACON_MAGIC1) &&
                ((n == (2u + PFDOA_BEACON_PAYLOAD_LEN)) || (n == (2u + PFDOA_BEACON_V1_PAYLOAD_LEN)))) {
                ids->ours = 1u;
                ids->seq = pfdoa_get_u16(&c[4]);
                ids->id = (n == (2u + PFDOA_BEACON_PAYLOAD_LEN)) ? c[6] : 0u; /* the v1 beacon is id 0 */
            } else if ((ids->auth == NULL) && (company == PFDOA_BEACON_COMPANY_ID) && (c[2] == PFDOA_BEACON_MAGIC0) &&
                       (c[3] == PFDOA_AUTH_MAGIC1) && (n == (2u + PFDOA_AUTH_PAYLOAD_LEN))) {
                ids->auth = &c[2];
            } else if ((ids->peer == PFDOA_ANCHOR_BROADCAST) && (peer != PFDOA_ANCHOR_BROADCAST)) {
                ids->peer = peer;
                ids->peer_seq = peer_seq;
            } else if ((ids->ibeacon == NULL) && (company == PFDOA_IBEACON_COMPANY_ID) && (c[2] == PFDOA_IBEACON_TYPE) &&
                       (c[3] == PFDOA_IBEACON_LENGTH) && (n == (4u + PFDOA_IBEACON_LENGTH))) {
                ids->ibeacon = &c[4];
            } else if ((ids->altbeacon == NULL) && (c[2] == PFDOA_ALTBEACON_CODE0) && (c[3] == PFDOA_ALTBEACON_CODE1) &&
                       (n == (2u + PFDOA_ALTBEACON_LEN))) {
                ids->altbeacon = &c[4];
            } else {
                /* another manufacturer's data */
            }
        } else if ((type == PFDOA_BLE_AD_SERVICE_DATA16) && (ids->eddystone == NULL) && (n >= 3u) &&
                   (pfdoa_get_u16(c) == PFDOA_EDDYSTONE_UUID) && (c[2] == PFDOA_EDDYSTONE_FRAME_UID) &&
                   ((n == (2u + PFDOA_EDDYSTONE_UID_MIN_LEN)) || (n == (4u + PFDOA_EDDYSTONE_UID_MIN_LEN)))) {
            ids->eddystone = &c[4];
        } else {
            /* an AD structure no beacon format uses */
        }
        i += 1u + l;
    }
}

static int same(const uint8_t *const a, const uint8_t *const b, const size_t n)
{
    return (a != NULL) && (memcmp(a, b, n) == 0);
}

static int32_t found(pfdoa_match_t *const out, const size_t index, const uint8_t has_seq, const uint16_t seq)
{
    out->index = (uint8_t)index;
    out->has_seq = has_seq;
    out->seq = seq;
    out->peer = PFDOA_ANCHOR_BROADCAST;
    return 1;
}

/* A match of an ANCHORS entry: the anchor heard and its advertisement's seq. */
static int32_t found_peer(pfdoa_match_t *const out, const size_t index, const uint8_t peer, const uint16_t seq)
{
    (void)found(out, index, 1u, seq);
    out->peer = peer;
    return 1;
}

int32_t pfdoa_match_ble_adv(const pfdoa_beacon_filter_t *const table, const size_t n, const uint8_t adv_a[6],
                            const uint8_t *const adv_data, const size_t len, pfdoa_match_t *const out)
{
    if ((table == NULL) || (adv_a == NULL) || (out == NULL) || ((adv_data == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    adv_ids_t ids;
    parse_adv_data(adv_data, len, &ids);
    for (size_t i = 0u; i < n; i++) {
        const pfdoa_beacon_filter_t *const f = &table[i];
        switch (f->kind) {
        case PFDOA_FILTER_PFDOA:
            if ((ids.ours != 0u) && (ids.id == f->match[0])) {
                return found(out, i, 1u, ids.seq);
            }
            break;
        case PFDOA_FILTER_IBEACON:
            if (same(ids.ibeacon, f->match, PFDOA_FILTER_IBEACON_USED)) {
                return found(out, i, 0u, 0u);
            }
            break;
        case PFDOA_FILTER_EDDYSTONE_UID:
            if (same(ids.eddystone, f->match, PFDOA_FILTER_EDDYSTONE_UID_USED)) {
                return found(out, i, 0u, 0u);
            }
            break;
        case PFDOA_FILTER_ALTBEACON:
            if (same(ids.altbeacon, f->match, PFDOA_FILTER_ALTBEACON_USED)) {
                return found(out, i, 0u, 0u);
            }
            break;
        case PFDOA_FILTER_MAC48:
            if (same(adv_a, f->match, PFDOA_FILTER_MAC48_USED)) {
                return found(out, i, 0u, 0u);
            }
            break;
        case PFDOA_FILTER_ANCHORS:
            if (ids.peer != PFDOA_ANCHOR_BROADCAST) {
                return found_peer(out, i, ids.peer, ids.peer_seq);
            }
            break;
        default:
            break; /* NONE, and MAC64 which is never a BLE address */
        }
    }
    return 0;
}

/* AdvA and AdvData of an advertising PDU that carries them (SPEC 3.2): 1, else 0. */
static int pdu_parts(const uint8_t *const pdu, const size_t len, const uint8_t **const adv_a, size_t *const data_len)
{
    if (len < PFDOA_BLE_PDU_HEADER_LEN) {
        return 0;
    }
    const uint8_t type = (uint8_t)(pdu[0] & PFDOA_BLE_PDU_TYPE_MASK);
    const size_t plen = pdu[1];
    if (((type != PFDOA_BLE_PDU_ADV_IND) && (type != PFDOA_BLE_PDU_ADV_NONCONN_IND) &&
         (type != PFDOA_BLE_PDU_ADV_SCAN_IND) && (type != PFDOA_BLE_PDU_SCAN_RSP)) ||
        (plen < PFDOA_BLE_ADV_A_LEN) || (plen > (PFDOA_BLE_ADV_A_LEN + PFDOA_BLE_ADV_DATA_MAX)) ||
        (plen > (len - PFDOA_BLE_PDU_HEADER_LEN))) {
        return 0;
    }
    *adv_a = &pdu[PFDOA_BLE_PDU_HEADER_LEN];
    *data_len = plen - PFDOA_BLE_ADV_A_LEN;
    return 1;
}

int32_t pfdoa_match_ble_pdu(const pfdoa_beacon_filter_t *const table, const size_t n, const uint8_t *const pdu,
                            const size_t len, pfdoa_match_t *const out)
{
    if ((table == NULL) || (out == NULL) || ((pdu == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    const uint8_t *adv_a = NULL;
    size_t data_len = 0u;
    if (pdu_parts(pdu, len, &adv_a, &data_len) == 0) {
        return 0;
    }
    return pfdoa_match_ble_adv(table, n, adv_a, &adv_a[PFDOA_BLE_ADV_A_LEN], data_len, out);
}

static size_t addr_len(const unsigned mode)
{
    return (mode == PFDOA_IEEE802154_ADDR_EXT) ? PFDOA_IEEE802154_EXT_ADDR_LEN
                                               : ((mode == PFDOA_IEEE802154_ADDR_SHORT) ? PFDOA_IEEE802154_SHORT_ADDR_LEN : 0u);
}

/* Where an IEEE 802.15.4 MAC frame's payload and source address are (SPEC 3.3). */
typedef struct mac_frame {
    size_t payload_at;  /* mpdu[payload_at..len) is the payload */
    size_t src_at;      /* the source address */
    unsigned fcf;
    unsigned src_mode;
    int readable;       /* no security, no IEs: the payload can be read */
} mac_frame_t;

static int mac_parse(const uint8_t *const mpdu, const size_t len, mac_frame_t *const f)
{
    if (len < PFDOA_IEEE802154_FCF_LEN) {
        return 0;
    }
    const unsigned fcf = pfdoa_get_u16(mpdu);
    const unsigned version = (fcf >> PFDOA_IEEE802154_FCF_VERSION_SHIFT) & 3u;
    const unsigned dst = (fcf >> PFDOA_IEEE802154_FCF_DST_MODE_SHIFT) & 3u;
    const unsigned src = (fcf >> PFDOA_IEEE802154_FCF_SRC_MODE_SHIFT) & 3u;
    if ((version > PFDOA_IEEE802154_VERSION_2015) || (dst == 1u) || (src == 1u)) {
        return 0; /* reserved frame version or addressing mode */
    }
    const int comp = (fcf & PFDOA_IEEE802154_FCF_PANID_COMP) != 0u;
    const int v2015 = version == PFDOA_IEEE802154_VERSION_2015;
    size_t pos = PFDOA_IEEE802154_FCF_LEN;
    if (!(v2015 && ((fcf & PFDOA_IEEE802154_FCF_SEQ_SUPPRESS) != 0u))) {
        pos++; /* sequence number */
    }
    /* Which PAN ids are present: 7.2.2.6 for frame versions 0 and 1, Table 7-2 for 2. */
    int dst_pan;
    int src_pan;
    if (!v2015) {
        dst_pan = dst != 0u;
        src_pan = (src != 0u) && !(comp && (dst != 0u));
    } else if ((dst == 0u) && (src == 0u)) {
        dst_pan = comp;
        src_pan = 0;
    } else if (src == 0u) {
        dst_pan = !comp;
        src_pan = 0;
    } else if (dst == 0u) {
        dst_pan = 0;
        src_pan = !comp;
    } else if ((dst == PFDOA_IEEE802154_ADDR_EXT) && (src == PFDOA_IEEE802154_ADDR_EXT)) {
        dst_pan = !comp;
        src_pan = 0;
    } else {
        dst_pan = 1;
        src_pan = !comp;
    }
    pos += (dst_pan ? PFDOA_IEEE802154_PAN_ID_LEN : 0u) + addr_len(dst) + (src_pan ? PFDOA_IEEE802154_PAN_ID_LEN : 0u);
    f->src_at = pos;
    pos += addr_len(src);
    if (pos > len) {
        return 0;
    }
    f->payload_at = pos;
    f->fcf = fcf;
    f->src_mode = src;
    f->readable = !(((fcf & PFDOA_IEEE802154_FCF_SECURITY) != 0u) ||
                    (v2015 && ((fcf & PFDOA_IEEE802154_FCF_IE_PRESENT) != 0u)));
    return 1;
}

/* A readable data frame whose payload is n bytes starting 'P' magic1. */
static int our_payload(const uint8_t *const mpdu, const size_t len, const mac_frame_t *const f, const size_t n,
                       const uint8_t magic1)
{
    const uint8_t *const p = &mpdu[f->payload_at];
    return f->readable && ((f->fcf & PFDOA_IEEE802154_FRAME_TYPE_MASK) == PFDOA_IEEE802154_FRAME_DATA) &&
           ((len - f->payload_at) == n) && (p[0] == PFDOA_BEACON_MAGIC0) && (p[1] == magic1);
}

int32_t pfdoa_match_802154(const pfdoa_beacon_filter_t *const table, const size_t n, const uint8_t *const mpdu,
                           const size_t len, pfdoa_match_t *const out)
{
    if ((table == NULL) || (out == NULL) || ((mpdu == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    mac_frame_t f;
    if (mac_parse(mpdu, len, &f) == 0) {
        return 0;
    }
    const uint8_t *const p = &mpdu[f.payload_at];
    const int ours = our_payload(mpdu, len, &f, PFDOA_BEACON_PAYLOAD_LEN, PFDOA_BEACON_MAGIC1);
    uint16_t peer_seq = 0u;
    const uint8_t peer = our_payload(mpdu, len, &f, PFDOA_BEACON_PAYLOAD_LEN, PFDOA_ANCHOR_MAGIC1)
                             ? anchor_payload(p, len - f.payload_at, &peer_seq)
                             : (uint8_t)PFDOA_ANCHOR_BROADCAST;
    for (size_t i = 0u; i < n; i++) {
        const pfdoa_beacon_filter_t *const e = &table[i];
        if ((e->kind == PFDOA_FILTER_PFDOA) && ours && (p[4] == e->match[0])) {
            return found(out, i, 1u, pfdoa_get_u16(&p[2]));
        }
        if ((e->kind == PFDOA_FILTER_ANCHORS) && (peer != PFDOA_ANCHOR_BROADCAST)) {
            return found_peer(out, i, peer, peer_seq);
        }
        if ((e->kind == PFDOA_FILTER_MAC64) && (f.src_mode == PFDOA_IEEE802154_ADDR_EXT) &&
            (memcmp(&mpdu[f.src_at], e->match, PFDOA_FILTER_MAC64_USED) == 0)) {
            return found(out, i, 0u, 0u);
        }
    }
    return 0;
}

int32_t pfdoa_match_auth_ble_adv(const uint8_t *const adv_data, const size_t len, const uint8_t **const payload)
{
    if ((payload == NULL) || ((adv_data == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    adv_ids_t ids;
    parse_adv_data(adv_data, len, &ids);
    *payload = ids.auth;
    return (ids.auth != NULL) ? 1 : 0;
}

int32_t pfdoa_match_auth_ble_pdu(const uint8_t *const pdu, const size_t len, const uint8_t **const payload)
{
    if ((payload == NULL) || ((pdu == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    const uint8_t *adv_a = NULL;
    size_t data_len = 0u;
    *payload = NULL;
    if (pdu_parts(pdu, len, &adv_a, &data_len) == 0) {
        return 0;
    }
    return pfdoa_match_auth_ble_adv(&adv_a[PFDOA_BLE_ADV_A_LEN], data_len, payload);
}

int32_t pfdoa_match_auth_802154(const uint8_t *const mpdu, const size_t len, const uint8_t **const payload)
{
    if ((payload == NULL) || ((mpdu == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    mac_frame_t f;
    *payload = NULL;
    if ((mac_parse(mpdu, len, &f) == 0) || (our_payload(mpdu, len, &f, PFDOA_AUTH_PAYLOAD_LEN, PFDOA_AUTH_MAGIC1) == 0)) {
        return 0;
    }
    *payload = &mpdu[f.payload_at];
    return 1;
}
