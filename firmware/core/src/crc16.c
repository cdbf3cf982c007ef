/* CRC-16/CCITT-FALSE, see pfdoa_crc16.h. */
#include "pfdoa_crc16.h"

uint16_t pfdoa_crc16_byte(uint16_t crc, const uint8_t byte)
{
    uint16_t c = (uint16_t)(crc ^ (uint16_t)((uint16_t)byte << 8));
    for (uint8_t bit = 0u; bit < 8u; bit++) {
        const int top = (c & 0x8000u) != 0u;
        c = (uint16_t)(c << 1);
        if (top) {
            c ^= (uint16_t)PFDOA_CRC_POLY;
        }
    }
    return c;
}

uint16_t pfdoa_crc16_update(uint16_t crc, const uint8_t *const data, const size_t len)
{
    uint16_t c = crc;
    if (data != NULL) {
        for (size_t i = 0u; i < len; i++) {
            c = pfdoa_crc16_byte(c, data[i]);
        }
    }
    return c;
}
