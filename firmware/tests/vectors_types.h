/* Row types of the generated build/test/vectors.h (see tools/vectors_to_c.py). */
#ifndef PFDOA_VECTORS_TYPES_H
#define PFDOA_VECTORS_TYPES_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_anchor.h"

/* The union of every message's fields, by name; unused ones stay 0. */
typedef struct vec_fields {
    int64_t seq, tick_ms, rssi_q8, raw_dbm, n_readings, channel, flags, beacon;
    int64_t fw_major, fw_minor, uptime_s, config_hash, dropped_events, rx_errors, spikes, defs_hash;
    int64_t filter_hash, filter_slots;
    int64_t token, offset_q8, alpha_q8, spike_db, report_mode, decimation, result;
    int64_t index, kind, period_ms;
    int64_t rssi_dbm, lqi, radio, length;
    const char *match, *frame; /* hex */
} vec_fields_t;

typedef struct { const char *name; const char *data; uint16_t crc; int crc_extra; } vec_crc_t;
typedef struct { const char *name; const char *decoded; const char *encoded; } vec_cobs_t;
typedef struct { const char *name; const char *encoded; } vec_cobs_err_t;
typedef struct { int8_t readings[3]; uint8_t n; int32_t mean_q8; } vec_fold_t;
typedef struct { int32_t ema_q8; int32_t mean_q8; uint16_t alpha_q8; int32_t result; } vec_ema_t;
typedef struct { uint8_t type; uint8_t anchor_id; vec_fields_t f; } vec_msg_t;
typedef struct {
    const char *name; int version; uint8_t type; uint8_t anchor_id; vec_fields_t f; const char *raw; const char *frame;
} vec_uart_t;
typedef struct { const char *name; int at_anchor; int v1_frame; const char *frame; int32_t error; } vec_uart_invalid_t;
typedef struct {
    const char *name; int at_anchor; int v1_frames; const char *stream;
    uint32_t errors[PFDOA_ERR_COUNT]; /* messages.json "errors" order */
    uint32_t frames_ok; size_t n_decoded; const vec_msg_t *decoded;
} vec_stream_t;
typedef struct { uint16_t id; const char *data; } vec_can_frame_t;
typedef struct {
    const char *name; int version; uint8_t type; uint8_t anchor_id; vec_fields_t f; size_t n_frames;
    vec_can_frame_t frames[3];
} vec_can_t;
typedef struct { const char *name; uint16_t id; const char *data; int32_t error; } vec_can_invalid_t;
typedef struct {
    const char *name; uint8_t anchor_id; uint8_t transports; uint32_t boot_tick;
    uint8_t fw_major; uint8_t fw_minor; int store_ok; int has_config; pfdoa_config_t config;
    const char *filters; /* hex of the stored filter table, or NULL */
    const char *const *script; const char *const *expected; /* NULL-terminated */
    int peer_radio; const char *peer_address; /* the radio its advertisement goes out on (-1: none), hex */
} vec_anchor_t;
typedef struct {
    const char *name; uint16_t seq; uint8_t beacon_id; const char *adv_a; const char *adv_data; const char *pdu;
    const char *ext_addr; uint16_t pan_id; const char *mpdu;
} vec_beacon_build_t;
typedef struct {
    const char *name; const char *filters; int input; /* 0 AdvA + AdvData, 1 PDU, 2 802.15.4 */
    const char *adv_a; const char *data; int matched; uint8_t index; int has_seq; uint16_t seq;
    int peer; /* the anchor an ANCHORS entry's match names, -1: none */
} vec_beacon_match_t;
typedef struct {
    const char *name; uint8_t radio; const char *address; uint8_t anchor_id; uint16_t seq; const char *frame;
} vec_peer_build_t;
typedef struct { const char *name; const char *entry; int valid; } vec_beacon_entry_t;
typedef struct { const char *name; const char *data; uint32_t repeat; const char *digest; } vec_sha256_t;
typedef struct { const char *name; const char *key; const char *data; const char *mac; } vec_hmac_t;
typedef struct {
    const char *name; const char *key; uint32_t counter; const char *rid; const char *adv_a; const char *ext_addr;
    uint16_t pad; const char *key_check;
} vec_auth_derive_t;
typedef struct {
    const char *name; const char *key; uint32_t counter; uint16_t seq; uint16_t pan_id; const char *tag;
    const char *payload; const char *adv_data; const char *pdu; const char *mpdu;
} vec_auth_build_t;
typedef struct { uint32_t tick; const char *payload; int32_t result; uint16_t seq; uint32_t counter; } vec_auth_step_t;
typedef struct { const char *name; const char *key; size_t n_steps; const vec_auth_step_t *steps; } vec_auth_verify_t;

#endif /* PFDOA_VECTORS_TYPES_H */
