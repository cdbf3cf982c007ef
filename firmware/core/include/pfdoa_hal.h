/*
 * pfdoa_hal.h - what the anchor core needs from its board: a struct of function pointers
 * and one user context pointer passed back to each of them. Any pointer may be NULL:
 * that facility is then absent (no tick source: 0; no UART/CAN: frames are not sent; no
 * storage: defaults at boot, CONFIG_ACK / FILTER_ACK result 2 for a valid CONFIG_SET /
 * FILTER_SET). The two storage pairs are independent: a board may keep one and not the other.
 *
 * Contract: every function is called from the context that calls the pfdoa_anchor_*
 * function in progress and must not call back into the anchor. uart_write must take the
 * whole frame (queue it) or drop it; the core never retries.
 */
#ifndef PFDOA_HAL_H
#define PFDOA_HAL_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pfdoa_hal {
    /* Passed unchanged as the first argument of every function below. */
    void *ctx;
    /* Free-running millisecond tick (wraps at 2^32). Read once, at pfdoa_anchor_init. */
    uint32_t (*tick_ms)(void *ctx);
    /* Sends len bytes (one whole frame with its 0x00 delimiter). Returns >= 0 on success. */
    int32_t (*uart_write)(void *ctx, const uint8_t *bytes, size_t len);
    /* Sends one classic CAN frame with an 11-bit id. Returns >= 0 on success. */
    int32_t (*can_send)(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc);
    /* Reads the stored configuration. Returns 0 when out holds it, negative when none. */
    int32_t (*config_load)(void *ctx, uint8_t out[PFDOA_CONFIG_LEN]);
    /* Stores the configuration persistently. Returns 0 on success, negative on failure. */
    int32_t (*config_store)(void *ctx, const uint8_t config[PFDOA_CONFIG_LEN]);
    /* Reads the stored beacon filter table (SPEC 3.1). Returns 0 when out holds it, negative when none.
     * Added in protocol version 2 after the fields above: a board that initialises the HAL by
     * field name and does not set these keeps the default table at every boot. */
    int32_t (*filters_load)(void *ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN]);
    /* Stores the beacon filter table persistently. Returns 0 on success, negative on failure. */
    int32_t (*filters_store)(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN]);
} pfdoa_hal_t;

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_HAL_H */
