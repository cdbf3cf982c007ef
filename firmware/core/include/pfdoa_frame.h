/*
 * pfdoa_frame.h - UART framing (protocol/SPEC.md section 2: COBS body, then a CRC-16 with
 * CRC_EXTRA over the encoded bytes, in a 3-byte trailer) and the CAN mapping (section 4).
 * The anchor speaks protocol version 2 only; a version-1 frame is rejected as bad_version.
 *
 * The UART stream decoder is a fixed PFDOA_MAX_ENCODED-byte buffer and two state bytes:
 * it never reads or writes outside that buffer, whatever bytes arrive, and it is always
 * ready for the next frame after a rejected one.
 */
#ifndef PFDOA_FRAME_H
#define PFDOA_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"
#include "pfdoa_msg.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Bytes of one UART frame on the wire, at most: COBS block plus the 0x00 delimiter. */
#define PFDOA_FRAME_WIRE_MAX (PFDOA_MAX_ENCODED + 1)

/* Fixed facts about one message type. */
typedef struct pfdoa_msg_desc {
    uint8_t type;
    uint8_t payload_len;
    uint8_t crc_extra;
    uint8_t to_host; /* 1: anchor to host, 0: host to anchor */
} pfdoa_msg_desc_t;

/* The descriptor of a type of this protocol version, or NULL for an unknown type. */
const pfdoa_msg_desc_t *pfdoa_msg_desc(uint8_t type);

/* A checked, decoded UART frame. payload points into the decoded block (the decoder's buffer). */
typedef struct pfdoa_frame {
    const uint8_t *payload;
    uint8_t type;
    uint8_t anchor_id;
    uint8_t payload_len;
} pfdoa_frame_t;

/*
 * Encodes one UART frame (COBS body, CRC trailer and the 0x00 delimiter) into out. len
 * must be the type's payload length and anchor_id <= 127. Returns the byte count written
 * (<= PFDOA_FRAME_WIRE_MAX), PFDOA_ERR_ARG, or PFDOA_ERR_CAPACITY when out_cap is too small.
 */
int32_t pfdoa_frame_encode(uint8_t type, uint8_t anchor_id, const uint8_t *payload, size_t len,
                           uint8_t *out, size_t out_cap);

/*
 * Checks one COBS block (the bytes between two delimiters, without them), decoding it in
 * place, in SPEC 2.3 order. known lists the types this receiver knows (others are
 * unknown_type). Returns PFDOA_OK with *frame filled, or the first failing check's
 * negative PFDOA_ERR_* (PFDOA_ERR_ARG for NULL arguments).
 */
int32_t pfdoa_frame_decode(uint8_t *block, size_t len, const uint8_t *known, size_t n_known,
                           pfdoa_frame_t *frame);

/* Stream decoder state. */
typedef struct pfdoa_decoder {
    const uint8_t *known;
    size_t n_known;
    uint8_t buf[PFDOA_MAX_ENCODED];
    uint8_t len;        /* bytes buffered, 0..PFDOA_MAX_ENCODED */
    uint8_t discarding; /* 1 after overlong: skipping up to the next delimiter */
} pfdoa_decoder_t;

/* known: the types this receiver accepts (must outlive the decoder). */
void pfdoa_decoder_init(pfdoa_decoder_t *dec, const uint8_t *known, size_t n_known);

/*
 * Feeds one received byte. Returns 0 (nothing complete), 1 (*frame holds a checked frame,
 * valid until the next push), or a negative PFDOA_ERR_* for a rejected frame.
 */
int32_t pfdoa_decoder_push(pfdoa_decoder_t *dec, uint8_t byte, pfdoa_frame_t *frame);

/* ---- CAN (classic 2.0A): can_id = (can_type << 7) | anchor_id ---- */

/* The 11-bit identifier of can_type from (or to) anchor_id. */
#define PFDOA_CAN_ID(can_type, anchor_id)                                                                              \
    ((uint16_t)(((uint16_t)(can_type) << PFDOA_CAN_ANCHOR_BITS) | ((uint16_t)(anchor_id) & PFDOA_CAN_ANCHOR_MASK)))

typedef struct pfdoa_can_frame {
    uint16_t id;
    uint8_t dlc;
    uint8_t data[8];
} pfdoa_can_frame_t;

/*
 * Receiver checks of one CAN frame in SPEC 4 order: can_type known (0x2..0x7), DLC equal
 * to the type's (version 2), anchor id 127 only in CONFIG_SET. Returns PFDOA_OK,
 * PFDOA_ERR_UNKNOWN_TYPE, PFDOA_ERR_BAD_LENGTH, PFDOA_ERR_BAD_ANCHOR, or PFDOA_ERR_ARG (id > 0x7FF).
 */
int32_t pfdoa_can_check(uint16_t id, uint8_t dlc);

void pfdoa_can_encode_rssi_report(const pfdoa_rssi_report_t *msg, uint8_t anchor_id, pfdoa_can_frame_t *out);
void pfdoa_can_encode_config_ack(const pfdoa_config_ack_t *msg, uint8_t anchor_id, pfdoa_can_frame_t *out);
void pfdoa_can_encode_status_a(const pfdoa_status_t *msg, uint8_t anchor_id, pfdoa_can_frame_t *out);
void pfdoa_can_encode_status_b(const pfdoa_status_t *msg, uint8_t anchor_id, pfdoa_can_frame_t *out);
void pfdoa_can_encode_status_c(const pfdoa_status_t *msg, uint8_t anchor_id, pfdoa_can_frame_t *out);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_FRAME_H */
