/* UART framing and CAN mapping, see pfdoa_frame.h. */
#include "pfdoa_frame.h"

#include <string.h>

#include "pfdoa_cobs.h"
#include "pfdoa_crc16.h"
#include "pfdoa_le.h"

/* Trailer bits (SPEC 2.1): 7 + 7 + 2 value bits, the marker bit 7 set in each byte. */
#define TRAILER_LAST_MASK ((uint8_t)~PFDOA_TRAILER_LAST_VALUE_MASK)

static const pfdoa_msg_desc_t msg_descs[] = {
    {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_RSSI_REPORT_LEN, PFDOA_MSG_RSSI_REPORT_CRC_EXTRA, 1u},
    {PFDOA_MSG_STATUS, PFDOA_MSG_STATUS_LEN, PFDOA_MSG_STATUS_CRC_EXTRA, 1u},
    {PFDOA_MSG_CONFIG_SET, PFDOA_MSG_CONFIG_SET_LEN, PFDOA_MSG_CONFIG_SET_CRC_EXTRA, 0u},
    {PFDOA_MSG_CONFIG_ACK, PFDOA_MSG_CONFIG_ACK_LEN, PFDOA_MSG_CONFIG_ACK_CRC_EXTRA, 1u},
    {PFDOA_MSG_FILTER_SET, PFDOA_MSG_FILTER_SET_LEN, PFDOA_MSG_FILTER_SET_CRC_EXTRA, 0u},
    {PFDOA_MSG_FILTER_ACK, PFDOA_MSG_FILTER_ACK_LEN, PFDOA_MSG_FILTER_ACK_CRC_EXTRA, 1u},
    {PFDOA_MSG_AUTH_REPORT, PFDOA_MSG_AUTH_REPORT_LEN, PFDOA_MSG_AUTH_REPORT_CRC_EXTRA, 1u},
    {PFDOA_MSG_AUTH_STATUS, PFDOA_MSG_AUTH_STATUS_LEN, PFDOA_MSG_AUTH_STATUS_CRC_EXTRA, 1u},
    {PFDOA_MSG_RADIO_TX, PFDOA_MSG_RADIO_TX_LEN, PFDOA_MSG_RADIO_TX_CRC_EXTRA, 1u},
    {PFDOA_MSG_RADIO_INJECT_RAW, PFDOA_MSG_RADIO_INJECT_RAW_LEN, PFDOA_MSG_RADIO_INJECT_RAW_CRC_EXTRA, 0u},
    {PFDOA_MSG_RADIO_INJECT, PFDOA_MSG_RADIO_INJECT_LEN, PFDOA_MSG_RADIO_INJECT_CRC_EXTRA, 0u},
};

const pfdoa_msg_desc_t *pfdoa_msg_desc(const uint8_t type)
{
    for (size_t i = 0u; i < (sizeof msg_descs / sizeof msg_descs[0]); i++) {
        if (msg_descs[i].type == type) {
            return &msg_descs[i];
        }
    }
    return NULL;
}

int32_t pfdoa_frame_encode(const uint8_t type, const uint8_t anchor_id, const uint8_t *const payload,
                           const size_t len, uint8_t *const out, const size_t out_cap)
{
    const pfdoa_msg_desc_t *const d = pfdoa_msg_desc(type);
    if ((d == NULL) || (len != d->payload_len) || (anchor_id > PFDOA_ANCHOR_BROADCAST) || (out == NULL) ||
        ((payload == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    uint8_t body[PFDOA_MAX_BODY];
    body[0] = PFDOA_PROTO_VERSION;
    body[1] = type;
    body[2] = anchor_id;
    if (len > 0u) {
        (void)memcpy(&body[PFDOA_HEADER_LEN], payload, len);
    }
    /* Leave room for the trailer and the delimiter. */
    const int32_t n = (out_cap > PFDOA_TRAILER_LEN) ? pfdoa_cobs_encode(body, PFDOA_HEADER_LEN + len, out,
                                                                        out_cap - PFDOA_TRAILER_LEN - 1u)
                                                    : PFDOA_ERR_CAPACITY;
    if (n < 0) {
        return n;
    }
    /* The CRC covers the bytes as they are sent (SPEC 2.1). */
    const uint16_t crc = pfdoa_crc16_byte(pfdoa_crc16_update(PFDOA_CRC_INIT, out, (size_t)n), d->crc_extra);
    uint8_t *const t = &out[n];
    t[0] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc & PFDOA_TRAILER_VALUE_MASK));
    t[1] = (uint8_t)(PFDOA_TRAILER_MARKER | ((crc >> PFDOA_TRAILER_BITS) & PFDOA_TRAILER_VALUE_MASK));
    t[2] = (uint8_t)(PFDOA_TRAILER_MARKER | (crc >> (2u * PFDOA_TRAILER_BITS)));
    t[3] = 0u;
    return n + (int32_t)PFDOA_TRAILER_LEN + 1;
}

static int known_type(const uint8_t *const known, const size_t n_known, const uint8_t type)
{
    for (size_t i = 0u; i < n_known; i++) {
        if (known[i] == type) {
            return 1;
        }
    }
    return 0;
}

int32_t pfdoa_frame_decode(uint8_t *const block, const size_t len, const uint8_t *const known,
                           const size_t n_known, pfdoa_frame_t *const frame)
{
    if ((block == NULL) || (frame == NULL) || ((known == NULL) && (n_known > 0u))) {
        return PFDOA_ERR_ARG;
    }
    if (len > PFDOA_MAX_ENCODED) {
        return PFDOA_ERR_OVERLONG;
    }
    /* A version-1 frame: its first COBS group starts with ver 1 (SPEC 2.3 check 2). */
    if ((len >= 2u) && (block[0] >= 2u) && (block[1] == PFDOA_V1_PROTO_VERSION)) {
        return PFDOA_ERR_BAD_VERSION;
    }
    if (len < (1u + PFDOA_TRAILER_LEN)) {
        return PFDOA_ERR_TRUNCATED;
    }
    const size_t enc_len = len - PFDOA_TRAILER_LEN;
    /* The CRC runs over the encoded bytes before they are decoded in place; decoding writes
     * fewer bytes than it reads, so the trailer after them stays intact. */
    const uint16_t crc_enc = pfdoa_crc16_update(PFDOA_CRC_INIT, block, enc_len);
    const int32_t n = pfdoa_cobs_decode(block, enc_len, block, enc_len);
    if (n < 0) {
        return PFDOA_ERR_BAD_COBS; /* in place with dst_cap == len: only a malformed block fails */
    }
    const size_t body_len = (size_t)n;
    if (body_len < PFDOA_HEADER_LEN) {
        return PFDOA_ERR_TRUNCATED;
    }
    if (block[0] != PFDOA_PROTO_VERSION) {
        return PFDOA_ERR_BAD_VERSION;
    }
    const uint8_t type = block[1];
    const pfdoa_msg_desc_t *const d = pfdoa_msg_desc(type);
    if ((d == NULL) || (known_type(known, n_known, type) == 0)) {
        return PFDOA_ERR_UNKNOWN_TYPE;
    }
    const size_t want = PFDOA_HEADER_LEN + (size_t)d->payload_len;
    if (body_len < want) {
        return PFDOA_ERR_TRUNCATED;
    }
    if (body_len > want) {
        return PFDOA_ERR_BAD_LENGTH;
    }
    const uint8_t *const t = &block[enc_len];
    const uint16_t crc = pfdoa_crc16_byte(crc_enc, d->crc_extra);
    if (((t[0] & t[1] & PFDOA_TRAILER_MARKER) == 0u) || ((t[2] & TRAILER_LAST_MASK) != PFDOA_TRAILER_MARKER) ||
        (crc != (uint16_t)((t[0] & PFDOA_TRAILER_VALUE_MASK) |
                           ((uint16_t)(t[1] & PFDOA_TRAILER_VALUE_MASK) << PFDOA_TRAILER_BITS) |
                           ((uint16_t)(t[2] & PFDOA_TRAILER_LAST_VALUE_MASK) << (2u * PFDOA_TRAILER_BITS))))) {
        return PFDOA_ERR_BAD_CRC;
    }
    const uint8_t anchor_id = block[2];
    if ((anchor_id > PFDOA_ANCHOR_BROADCAST) || ((anchor_id == PFDOA_ANCHOR_BROADCAST) && (d->to_host != 0u))) {
        return PFDOA_ERR_BAD_ANCHOR;
    }
    frame->type = type;
    frame->anchor_id = anchor_id;
    frame->payload_len = d->payload_len;
    frame->payload = &block[PFDOA_HEADER_LEN];
    return PFDOA_OK;
}

void pfdoa_decoder_init(pfdoa_decoder_t *const dec, const uint8_t *const known, const size_t n_known)
{
    if (dec != NULL) {
        (void)memset(dec, 0, sizeof *dec);
        dec->known = known;
        dec->n_known = (known != NULL) ? n_known : 0u;
    }
}

int32_t pfdoa_decoder_push(pfdoa_decoder_t *const dec, const uint8_t byte, pfdoa_frame_t *const frame)
{
    if ((dec == NULL) || (frame == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (byte == 0u) {
        const size_t len = dec->len;
        dec->len = 0u;
        if (dec->discarding != 0u) {
            dec->discarding = 0u; /* the delimiter ends the overlong frame */
            return 0;
        }
        if (len == 0u) {
            return 0; /* empty frames are skipped silently */
        }
        const int32_t rc = pfdoa_frame_decode(dec->buf, len, dec->known, dec->n_known, frame);
        return (rc == PFDOA_OK) ? 1 : rc;
    }
    if (dec->discarding != 0u) {
        return 0;
    }
    if (dec->len >= PFDOA_MAX_ENCODED) {
        /* Reported once; the rest of the frame is skipped without a second error. */
        dec->len = 0u;
        dec->discarding = 1u;
        return PFDOA_ERR_OVERLONG;
    }
    dec->buf[dec->len] = byte;
    dec->len++;
    return 0;
}

static uint16_t can_id(const uint8_t can_type, const uint8_t anchor_id)
{
    return PFDOA_CAN_ID(can_type, anchor_id);
}

int32_t pfdoa_can_check(const uint16_t id, const uint8_t dlc)
{
    /* DLC per can_type; 0 = not a type of this version. Index 0x2..0x7. */
    static const uint8_t can_dlc[8] = {0u, 0u, PFDOA_CAN_RSSI_REPORT_DLC, PFDOA_CAN_CONFIG_SET_DLC,
                                       PFDOA_CAN_CONFIG_ACK_DLC, PFDOA_CAN_STATUS_A_DLC,
                                       PFDOA_CAN_STATUS_B_DLC, PFDOA_CAN_STATUS_C_DLC};
    if (id > PFDOA_CAN_ID_MASK) {
        return PFDOA_ERR_ARG;
    }
    const uint16_t can_type = (uint16_t)(id >> PFDOA_CAN_ANCHOR_BITS);
    if ((can_type >= (sizeof can_dlc)) || (can_dlc[can_type] == 0u)) {
        return PFDOA_ERR_UNKNOWN_TYPE;
    }
    if (dlc != can_dlc[can_type]) {
        return PFDOA_ERR_BAD_LENGTH;
    }
    if (((id & PFDOA_CAN_ANCHOR_MASK) == PFDOA_ANCHOR_BROADCAST) && (can_type != PFDOA_CAN_CONFIG_SET)) {
        return PFDOA_ERR_BAD_ANCHOR;
    }
    return PFDOA_OK;
}

void pfdoa_can_encode_rssi_report(const pfdoa_rssi_report_t *const msg, const uint8_t anchor_id,
                                  pfdoa_can_frame_t *const out)
{
    if ((msg != NULL) && (out != NULL)) {
        out->id = can_id(PFDOA_CAN_RSSI_REPORT, anchor_id);
        out->dlc = PFDOA_CAN_RSSI_REPORT_DLC;
        pfdoa_put_u16(&out->data[PFDOA_CAN_RSSI_REPORT_OFF_SEQ], msg->seq);
        pfdoa_put_u16(&out->data[PFDOA_CAN_RSSI_REPORT_OFF_RSSI_Q8], pfdoa_u16_from_i16(msg->rssi_q8));
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_RAW_DBM] = pfdoa_u8_from_i8(msg->raw_dbm);
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_FLAGS] = msg->flags;
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_BEACON] = msg->beacon;
        out->data[PFDOA_CAN_RSSI_REPORT_DLC] = 0u; /* past the DLC: not sent, but defined */
    }
}

void pfdoa_can_encode_config_ack(const pfdoa_config_ack_t *const msg, const uint8_t anchor_id,
                                 pfdoa_can_frame_t *const out)
{
    if ((msg != NULL) && (out != NULL)) {
        (void)memset(out->data, 0, sizeof out->data);
        out->id = can_id(PFDOA_CAN_CONFIG_ACK, anchor_id);
        out->dlc = PFDOA_CAN_CONFIG_ACK_DLC;
        /* Same layout as the UART payload. */
        pfdoa_msg_pack_config_ack(msg, out->data);
    }
}

void pfdoa_can_encode_status_a(const pfdoa_status_t *const msg, const uint8_t anchor_id,
                               pfdoa_can_frame_t *const out)
{
    if ((msg != NULL) && (out != NULL)) {
        out->id = can_id(PFDOA_CAN_STATUS_A, anchor_id);
        out->dlc = PFDOA_CAN_STATUS_A_DLC;
        out->data[PFDOA_CAN_STATUS_A_OFF_FW_MAJOR] = msg->fw_major;
        out->data[PFDOA_CAN_STATUS_A_OFF_FW_MINOR] = msg->fw_minor;
        pfdoa_put_u32(&out->data[PFDOA_CAN_STATUS_A_OFF_UPTIME_S], msg->uptime_s);
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_A_OFF_CONFIG_HASH], msg->config_hash);
    }
}

void pfdoa_can_encode_status_b(const pfdoa_status_t *const msg, const uint8_t anchor_id,
                               pfdoa_can_frame_t *const out)
{
    if ((msg != NULL) && (out != NULL)) {
        out->id = can_id(PFDOA_CAN_STATUS_B, anchor_id);
        out->dlc = PFDOA_CAN_STATUS_B_DLC;
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_B_OFF_DROPPED_EVENTS], msg->dropped_events);
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_B_OFF_RX_ERRORS], msg->rx_errors);
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_B_OFF_SPIKES], msg->spikes);
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_B_OFF_DEFS_HASH], msg->defs_hash);
    }
}

void pfdoa_can_encode_status_c(const pfdoa_status_t *const msg, const uint8_t anchor_id,
                               pfdoa_can_frame_t *const out)
{
    if ((msg != NULL) && (out != NULL)) {
        (void)memset(out->data, 0, sizeof out->data);
        out->id = can_id(PFDOA_CAN_STATUS_C, anchor_id);
        out->dlc = PFDOA_CAN_STATUS_C_DLC;
        pfdoa_put_u16(&out->data[PFDOA_CAN_STATUS_C_OFF_FILTER_HASH], msg->filter_hash);
        out->data[PFDOA_CAN_STATUS_C_OFF_FILTER_SLOTS] = msg->filter_slots;
    }
}
