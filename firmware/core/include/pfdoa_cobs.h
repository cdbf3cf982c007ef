/*
 * pfdoa_cobs.h - Consistent Overhead Byte Stuffing (Cheshire & Baker 1999) as used by
 * the UART framing, protocol/SPEC.md section 2.1. Buffer in, buffer out; no state.
 *
 * Encoded block: no 0x00 bytes; each code byte c (1..255) is followed by c-1 data bytes
 * and an implied zero unless c == 255 or the group ends the block. The delimiter 0x00 is
 * not part of the block (the caller appends it).
 */
#ifndef PFDOA_COBS_H
#define PFDOA_COBS_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Errors are the core's one domain (enum pfdoa_err in pfdoa_defs.h):
 *   PFDOA_ERR_ARG       a NULL pointer
 *   PFDOA_ERR_CAPACITY  the output would not fit in dst_cap
 *   PFDOA_ERR_BAD_COBS  a malformed block: a code byte points past the end, or a 0x00 inside */

/* Worst-case encoded size of n bytes: n + 1 + floor(n / 254). */
#define PFDOA_COBS_MAX_ENCODED(n) ((n) + 1u + ((n) / 254u))

/*
 * Encodes len bytes of src into dst (no delimiter). src and dst must not overlap.
 * Returns the encoded length (>= 1), PFDOA_ERR_ARG or PFDOA_ERR_CAPACITY.
 */
int32_t pfdoa_cobs_encode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap);

/*
 * Decodes the len-byte block src into dst. In-place decoding (dst == src) is allowed:
 * the write position never passes the read position. Reads at most len bytes of src and
 * writes at most dst_cap bytes of dst. Returns the decoded length (>= 0), PFDOA_ERR_ARG,
 * PFDOA_ERR_CAPACITY or PFDOA_ERR_BAD_COBS. An empty block is malformed (PFDOA_ERR_BAD_COBS):
 * even an empty input encodes to one code byte.
 */
int32_t pfdoa_cobs_decode(const uint8_t *src, size_t len, uint8_t *dst, size_t dst_cap);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_COBS_H */
