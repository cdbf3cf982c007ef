/* COBS encode/decode, see pfdoa_cobs.h. */
#include "pfdoa_cobs.h"

int32_t pfdoa_cobs_encode(const uint8_t *const src, const size_t len, uint8_t *const dst,
                          const size_t dst_cap)
{
    if ((dst == NULL) || ((src == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    if ((len > (size_t)INT32_MAX - 1u - (len / 254u)) || (dst_cap < PFDOA_COBS_MAX_ENCODED(len))) {
        return PFDOA_ERR_CAPACITY;
    }
    size_t code_pos = 0u; /* where the current group's code byte goes */
    size_t out = 1u;
    uint8_t code = 1u;
    for (size_t i = 0u; i < len; i++) {
        if (src[i] == 0u) {
            dst[code_pos] = code;
            code_pos = out++;
            code = 1u;
        } else {
            dst[out++] = src[i];
            code++;
            /* A full group of 254 data bytes: close it; open another only if data follows. */
            if (code == 0xFFu) {
                dst[code_pos] = code;
                code = 1u;
                if ((i + 1u) < len) {
                    code_pos = out++;
                } else {
                    return (int32_t)out;
                }
            }
        }
    }
    dst[code_pos] = code;
    return (int32_t)out;
}

int32_t pfdoa_cobs_decode(const uint8_t *const src, const size_t len, uint8_t *const dst,
                          const size_t dst_cap)
{
    if ((dst == NULL) || ((src == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    if (len == 0u) {
        return PFDOA_ERR_BAD_COBS; /* a block has at least its first code byte */
    }
    if (len > (size_t)INT32_MAX) {
        return PFDOA_ERR_CAPACITY;
    }
    size_t in = 0u;
    size_t out = 0u;
    while (in < len) {
        const uint8_t code = src[in++];
        if (code == 0u) {
            return PFDOA_ERR_BAD_COBS;
        }
        const size_t n = (size_t)code - 1u;
        if (n > (len - in)) {
            return PFDOA_ERR_BAD_COBS;
        }
        if (n > (dst_cap - out)) {
            return PFDOA_ERR_CAPACITY;
        }
        for (size_t k = 0u; k < n; k++) {
            const uint8_t b = src[in++];
            if (b == 0u) {
                return PFDOA_ERR_BAD_COBS;
            }
            dst[out++] = b;
        }
        if ((code != 0xFFu) && (in < len)) {
            if (out >= dst_cap) {
                return PFDOA_ERR_CAPACITY;
            }
            dst[out++] = 0u;
        }
    }
    return (int32_t)out;
}
