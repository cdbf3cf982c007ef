/*
 * pfdoa_hal.h - what the anchor core needs from its board: a struct of function pointers
 * and one user context pointer passed back to each of them. Any pointer may be NULL:
 * that facility is then absent (no tick source: 0; no UART/CAN: frames are not sent; no
 * storage: defaults at boot, CONFIG_ACK result 2 for a valid CONFIG_SET).
 *
 * The beacon filter table's storage (protocol version 2) is a separate, optional struct,
 * pfdoa_filter_storage_t, given with pfdoa_anchor_use_filter_storage(): pfdoa_hal_t keeps
 * the fields it had in version 1, so boards that initialise it positionally still build.
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
} pfdoa_hal_t;

/* Persistent storage of the beacon filter table (SPEC 3.1); either pointer may be NULL. */
typedef struct pfdoa_filter_storage {
    void *ctx;
    /* Reads the stored table. Returns 0 when out holds it, negative when none. */
    int32_t (*load)(void *ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN]);
    /* Stores the table persistently. Returns 0 on success, negative on failure. */
    int32_t (*store)(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN]);
} pfdoa_filter_storage_t;

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_HAL_H */
