/*
 * pfdoa_msg.h - message structs and their payload encodings (protocol/SPEC.md section 1).
 * Pack functions write exactly the message's PFDOA_MSG_*_LEN bytes; unpack functions read
 * exactly that many. Framing (UART/CAN) is in pfdoa_frame.h.
 */
#ifndef PFDOA_MSG_H
#define PFDOA_MSG_H

#include <stdint.h>

#include "pfdoa_config.h"
#include "pfdoa_defs.h"
#include "pfdoa_match.h"

#ifdef __cplusplus
extern "C" {
#endif

/* RSSI_REPORT. */
typedef struct pfdoa_rssi_report {
    uint32_t tick_ms;    /* tick at which the event closed */
    uint16_t seq;        /* beacon sequence number (with PFDOA_FLAG_NO_SEQ: the entry's event count) */
    int16_t rssi_q8;     /* filtered, calibrated RSSI, Q7.8 dBm */
    int8_t raw_dbm;      /* last clamped reading of the event */
    uint8_t n_readings;  /* readings folded into the event */
    uint8_t channel;     /* channel of the last reading */
    uint8_t flags;       /* PFDOA_FLAG_* */
    uint8_t beacon;      /* the filter entry the event belongs to */
} pfdoa_rssi_report_t;

/* STATUS. */
typedef struct pfdoa_status {
    uint32_t uptime_s;
    uint16_t config_hash;
    uint16_t dropped_events;
    uint16_t rx_errors;
    uint16_t spikes;
    uint16_t defs_hash;
    uint16_t filter_hash;
    uint8_t fw_major;
    uint8_t fw_minor;
    uint8_t filter_slots;
} pfdoa_status_t;

/* CONFIG_ACK. */
typedef struct pfdoa_config_ack {
    uint16_t config_hash;
    uint8_t token;
    uint8_t result; /* PFDOA_ACK_* */
} pfdoa_config_ack_t;

/* FILTER_ACK. */
typedef struct pfdoa_filter_ack {
    uint16_t filter_hash;
    uint8_t token;
    uint8_t result; /* PFDOA_ACK_* */
    uint8_t index;
} pfdoa_filter_ack_t;

/*
 * One reading of filter entry 0 (our beacon, matched by the board) as a radio driver's
 * receive callback reports it; also the payload of RADIO_INJECT, which feeds it through
 * the same path in SIL builds.
 */
typedef struct pfdoa_radio_reading {
    uint32_t tick_ms;  /* tick at which the driver saw the packet */
    uint16_t seq;      /* sequence number carried by the beacon */
    int8_t rssi_dbm;   /* raw RSSI; PFDOA_RSSI_INVALID = not available */
    uint8_t channel;   /* BLE 0..39, IEEE 802.15.4 11..26 */
    uint8_t lqi;       /* IEEE 802.15.4 link quality; 0 for BLE */
    uint8_t radio;     /* PFDOA_RADIO_BLE or PFDOA_RADIO_IEEE802154 */
} pfdoa_radio_reading_t;

void pfdoa_msg_pack_rssi_report(const pfdoa_rssi_report_t *msg, uint8_t out[PFDOA_MSG_RSSI_REPORT_LEN]);
void pfdoa_msg_pack_status(const pfdoa_status_t *msg, uint8_t out[PFDOA_MSG_STATUS_LEN]);
void pfdoa_msg_pack_config_ack(const pfdoa_config_ack_t *msg, uint8_t out[PFDOA_MSG_CONFIG_ACK_LEN]);
void pfdoa_msg_pack_filter_ack(const pfdoa_filter_ack_t *msg, uint8_t out[PFDOA_MSG_FILTER_ACK_LEN]);

/*
 * CONFIG_SET (0x03): the token and the 7-byte configuration. Returns PFDOA_OK with both
 * written, or PFDOA_ERR_ARG (a value out of range: *token is still written, *cfg is not).
 */
int32_t pfdoa_msg_unpack_config_set(const uint8_t in[PFDOA_MSG_CONFIG_SET_LEN], uint8_t *token,
                                    pfdoa_config_t *cfg);

/*
 * FILTER_SET: the token, the entry index and the filter entry, unchecked (the anchor
 * validates them: pfdoa_beacon_filter_validate). Returns PFDOA_OK or PFDOA_ERR_ARG (NULL).
 */
int32_t pfdoa_msg_unpack_filter_set(const uint8_t in[PFDOA_MSG_FILTER_SET_LEN], uint8_t *token, uint8_t *index,
                                    pfdoa_beacon_filter_t *filter);

/* RADIO_INJECT. No range checks: the receive path checks readings. */
void pfdoa_msg_unpack_radio_inject(const uint8_t in[PFDOA_MSG_RADIO_INJECT_LEN], pfdoa_radio_reading_t *msg);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_MSG_H */
