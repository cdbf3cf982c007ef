/* UART framing and CAN mapping, see pfdoa_frame.h. */
#include "pfdoa_frame.h"

#include <string.h>

#include "pfdoa_cobs.h"
#include "pfdoa_crc16.h"
#include "pfdoa_le.h"

#define FRAME_OVERHEAD (PFDOA_HEADER_LEN + PFDOA_CRC_LEN)

static const pfdoa_msg_desc_t msg_descs[] = {
    {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_RSSI_REPORT_LEN, PFDOA_MSG_RSSI_REPORT_CRC_EXTRA, 1u},
    {PFDOA_MSG_STATUS, PFDOA_MSG_STATUS_LEN, PFDOA_MSG_STATUS_CRC_EXTRA, 1u},
    {PFDOA_MSG_CONFIG_SET, PFDOA_MSG_CONFIG_SET_LEN, PFDOA_MSG_CONFIG_SET_CRC_EXTRA, 0u},
    {PFDOA_MSG_CONFIG_ACK, PFDOA_MSG_CONFIG_ACK_LEN, PFDOA_MSG_CONFIG_ACK_CRC_EXTRA, 1u},
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

static uint16_t frame_crc(const uint8_t *const raw, const size_t len, const uint8_t crc_extra)
{
    return pfdoa_crc16_byte(pfdoa_crc16_update(PFDOA_CRC_INIT, raw, len), crc_extra);
}

int32_t pfdoa_frame_encode(const uint8_t type, const uint8_t anchor_id, const uint8_t *const payload,
                           const size_t len, uint8_t *const out, const size_t out_cap)
{
    const pfdoa_msg_desc_t *const d = pfdoa_msg_desc(type);
    if ((d == NULL) || (len != d->payload_len) || (anchor_id > PFDOA_ANCHOR_BROADCAST) || (out == NULL) ||
        ((payload == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    uint8_t raw[PFDOA_MAX_RAW];
    raw[0] = PFDOA_PROTO_VERSION;
    raw[1] = type;
    raw[2] = anchor_id;
    if (len > 0u) {
        (void)memcpy(&raw[PFDOA_HEADER_LEN], payload, len);
    }
    const size_t body = PFDOA_HEADER_LEN + len;
    pfdoa_put_u16(&raw[body], frame_crc(raw, body, d->crc_extra));
    /* Leave room for the delimiter. */
    const int32_t n = (out_cap > 0u) ? pfdoa_cobs_encode(raw, body + PFDOA_CRC_LEN, out, out_cap - 1u)
                                     : PFDOA_ERR_CAPACITY;
    if (n < 0) {
        return PFDOA_ERR_ARG;
    }
    out[n] = 0u;
    return n + 1;
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
    const int32_t n = pfdoa_cobs_decode(block, len, block, len);
    if (n < 0) {
        return PFDOA_ERR_BAD_COBS; /* in place with dst_cap == len: only a malformed block fails */
    }
    const size_t raw_len = (size_t)n;
    if (raw_len < FRAME_OVERHEAD) {
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
    const size_t want = FRAME_OVERHEAD + (size_t)d->payload_len;
    if (raw_len < want) {
        return PFDOA_ERR_TRUNCATED;
    }
    if (raw_len > want) {
        return PFDOA_ERR_BAD_LENGTH;
    }
    const size_t body = want - PFDOA_CRC_LEN;
    if (frame_crc(block, body, d->crc_extra) != pfdoa_get_u16(&block[body])) {
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
    return (uint16_t)(((uint16_t)can_type << PFDOA_CAN_ANCHOR_BITS) | (uint16_t)(anchor_id & PFDOA_CAN_ANCHOR_MASK));
}

int32_t pfdoa_can_check(const uint16_t id, const uint8_t dlc)
{
    /* DLC per can_type; 0 = not a v1 type. Index 0x2..0x6. */
    static const uint8_t can_dlc[8] = {0u, 0u, PFDOA_CAN_RSSI_REPORT_DLC, PFDOA_CAN_CONFIG_SET_DLC,
                                       PFDOA_CAN_CONFIG_ACK_DLC, PFDOA_CAN_STATUS_A_DLC,
                                       PFDOA_CAN_STATUS_B_DLC, 0u};
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
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_N_READINGS] = msg->n_readings;
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_CHANNEL] = msg->channel;
        out->data[PFDOA_CAN_RSSI_REPORT_OFF_FLAGS] = msg->flags;
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
