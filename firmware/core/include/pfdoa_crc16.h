/*
 * pfdoa_crc16.h - CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection,
 * no final XOR), protocol/SPEC.md section 2.2. Check value: "123456789" -> 0x29B1.
 *
 * Bitwise on purpose: the anchor computes a few CRCs of <= 16 bytes per beacon event,
 * so a 512-byte table would cost more ROM than the cycles it saves.
 */
#ifndef PFDOA_CRC16_H
#define PFDOA_CRC16_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Start value: PFDOA_CRC_INIT from pfdoa_defs.h. */

/* Continues a CRC over len bytes. data may be NULL only when len == 0. */
uint16_t pfdoa_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

/* Continues a CRC over one byte (used for CRC_EXTRA). */
uint16_t pfdoa_crc16_byte(uint16_t crc, uint8_t byte);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_CRC16_H */
