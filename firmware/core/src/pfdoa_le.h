/* Little-endian load/store helpers shared by the core's encoders (private header). */
#ifndef PFDOA_LE_H
#define PFDOA_LE_H

#include <stdint.h>

static inline void pfdoa_put_u16(uint8_t *const p, const uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static inline void pfdoa_put_u32(uint8_t *const p, const uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static inline uint16_t pfdoa_get_u16(const uint8_t *const p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static inline uint32_t pfdoa_get_u32(const uint8_t *const p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

/* Two's complement reinterpretation without implementation-defined conversions. */
static inline int16_t pfdoa_i16_from_u16(const uint16_t v)
{
    return (v >= 0x8000u) ? (int16_t)((int32_t)v - 65536) : (int16_t)v;
}

static inline uint16_t pfdoa_u16_from_i16(const int16_t v)
{
    return (v < 0) ? (uint16_t)((int32_t)v + 65536) : (uint16_t)v;
}

static inline int8_t pfdoa_i8_from_u8(const uint8_t v)
{
    return (v >= 0x80u) ? (int8_t)((int16_t)v - 256) : (int8_t)v;
}

static inline uint8_t pfdoa_u8_from_i8(const int8_t v)
{
    return (v < 0) ? (uint8_t)((int16_t)v + 256) : (uint8_t)v;
}

#endif /* PFDOA_LE_H */
