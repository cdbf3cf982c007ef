/* Message payload encodings, see pfdoa_msg.h. */
#include "pfdoa_msg.h"

#include <stddef.h>

#include "pfdoa_le.h"

/* FILTER_SET carries kind, period_ms, match in the order of the stored entry (SPEC 1.5, 3.1). */
typedef char filter_set_layout_is_the_entry[((PFDOA_MSG_FILTER_SET_OFF_PERIOD_MS == PFDOA_MSG_FILTER_SET_OFF_KIND + 1) &&
                                             (PFDOA_MSG_FILTER_SET_OFF_MATCH == PFDOA_MSG_FILTER_SET_OFF_KIND + 3) &&
                                             (PFDOA_MSG_FILTER_SET_LEN - PFDOA_MSG_FILTER_SET_OFF_KIND ==
                                              PFDOA_FILTER_ENTRY_LEN)) ? 1 : -1];

void pfdoa_msg_pack_rssi_report(const pfdoa_rssi_report_t *const msg, uint8_t out[PFDOA_MSG_RSSI_REPORT_LEN])
{
    if ((msg != NULL) && (out != NULL)) {
        pfdoa_put_u16(&out[PFDOA_MSG_RSSI_REPORT_OFF_SEQ], msg->seq);
        pfdoa_put_u32(&out[PFDOA_MSG_RSSI_REPORT_OFF_TICK_MS], msg->tick_ms);
        pfdoa_put_u16(&out[PFDOA_MSG_RSSI_REPORT_OFF_RSSI_Q8], pfdoa_u16_from_i16(msg->rssi_q8));
        out[PFDOA_MSG_RSSI_REPORT_OFF_RAW_DBM] = pfdoa_u8_from_i8(msg->raw_dbm);
        out[PFDOA_MSG_RSSI_REPORT_OFF_N_READINGS] = msg->n_readings;
        out[PFDOA_MSG_RSSI_REPORT_OFF_CHANNEL] = msg->channel;
        out[PFDOA_MSG_RSSI_REPORT_OFF_FLAGS] = msg->flags;
        out[PFDOA_MSG_RSSI_REPORT_OFF_BEACON] = msg->beacon;
    }
}

void pfdoa_msg_pack_status(const pfdoa_status_t *const msg, uint8_t out[PFDOA_MSG_STATUS_LEN])
{
    if ((msg != NULL) && (out != NULL)) {
        out[PFDOA_MSG_STATUS_OFF_FW_MAJOR] = msg->fw_major;
        out[PFDOA_MSG_STATUS_OFF_FW_MINOR] = msg->fw_minor;
        pfdoa_put_u32(&out[PFDOA_MSG_STATUS_OFF_UPTIME_S], msg->uptime_s);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_CONFIG_HASH], msg->config_hash);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_DROPPED_EVENTS], msg->dropped_events);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_RX_ERRORS], msg->rx_errors);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_SPIKES], msg->spikes);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_DEFS_HASH], msg->defs_hash);
        pfdoa_put_u16(&out[PFDOA_MSG_STATUS_OFF_FILTER_HASH], msg->filter_hash);
        out[PFDOA_MSG_STATUS_OFF_FILTER_SLOTS] = msg->filter_slots;
    }
}

void pfdoa_msg_pack_config_ack(const pfdoa_config_ack_t *const msg, uint8_t out[PFDOA_MSG_CONFIG_ACK_LEN])
{
    if ((msg != NULL) && (out != NULL)) {
        out[PFDOA_MSG_CONFIG_ACK_OFF_TOKEN] = msg->token;
        out[PFDOA_MSG_CONFIG_ACK_OFF_RESULT] = msg->result;
        pfdoa_put_u16(&out[PFDOA_MSG_CONFIG_ACK_OFF_CONFIG_HASH], msg->config_hash);
    }
}

void pfdoa_msg_pack_filter_ack(const pfdoa_filter_ack_t *const msg, uint8_t out[PFDOA_MSG_FILTER_ACK_LEN])
{
    if ((msg != NULL) && (out != NULL)) {
        out[PFDOA_MSG_FILTER_ACK_OFF_TOKEN] = msg->token;
        out[PFDOA_MSG_FILTER_ACK_OFF_RESULT] = msg->result;
        out[PFDOA_MSG_FILTER_ACK_OFF_INDEX] = msg->index;
        pfdoa_put_u16(&out[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH], msg->filter_hash);
    }
}

int32_t pfdoa_msg_unpack_config_set(const uint8_t in[PFDOA_MSG_CONFIG_SET_LEN], uint8_t *const token,
                                    pfdoa_config_t *const cfg)
{
    if ((in == NULL) || (token == NULL) || (cfg == NULL)) {
        return PFDOA_ERR_ARG;
    }
    *token = in[PFDOA_MSG_CONFIG_SET_OFF_TOKEN];
    /* The configuration bytes follow the token in the order of the stored form. */
    return pfdoa_config_unpack(&in[PFDOA_MSG_CONFIG_SET_OFF_OFFSET_Q8], cfg);
}

int32_t pfdoa_msg_unpack_filter_set(const uint8_t in[PFDOA_MSG_FILTER_SET_LEN], uint8_t *const token,
                                    uint8_t *const index, pfdoa_beacon_filter_t *const filter)
{
    if ((in == NULL) || (token == NULL) || (index == NULL) || (filter == NULL)) {
        return PFDOA_ERR_ARG;
    }
    *token = in[PFDOA_MSG_FILTER_SET_OFF_TOKEN];
    *index = in[PFDOA_MSG_FILTER_SET_OFF_INDEX];
    /* kind, period_ms, match follow in the order of the stored entry */
    pfdoa_beacon_filter_unpack(&in[PFDOA_MSG_FILTER_SET_OFF_KIND], filter);
    return PFDOA_OK;
}

void pfdoa_msg_unpack_radio_inject(const uint8_t in[PFDOA_MSG_RADIO_INJECT_LEN], pfdoa_radio_reading_t *const msg)
{
    if ((in != NULL) && (msg != NULL)) {
        msg->seq = pfdoa_get_u16(&in[PFDOA_MSG_RADIO_INJECT_OFF_SEQ]);
        msg->tick_ms = pfdoa_get_u32(&in[PFDOA_MSG_RADIO_INJECT_OFF_TICK_MS]);
        msg->rssi_dbm = pfdoa_i8_from_u8(in[PFDOA_MSG_RADIO_INJECT_OFF_RSSI_DBM]);
        msg->channel = in[PFDOA_MSG_RADIO_INJECT_OFF_CHANNEL];
        msg->lqi = in[PFDOA_MSG_RADIO_INJECT_OFF_LQI];
        msg->radio = in[PFDOA_MSG_RADIO_INJECT_OFF_RADIO];
    }
}
