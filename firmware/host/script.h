/*
 * script.h - event scripts (protocol/vectors/README.md) against one anchor: a HAL whose
 * frames become text lines ("U <hex>" / "C <id> <hex>", and "T <hex>" for the anchor's own
 * advertisement sent on its radio), and a line interpreter.
 * Host-side tooling shared by the anchor_script harness and the cmocka vector tests.
 */
#ifndef PFDOA_SCRIPT_H
#define PFDOA_SCRIPT_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_anchor.h"

/* Longest output line: "U " + 2 * PFDOA_FRAME_WIRE_MAX hex digits + NUL. */
#define SCRIPT_OUT_LINE_MAX (2 + (2 * PFDOA_FRAME_WIRE_MAX) + 1)

typedef void (*script_emit_fn)(void *user, const char *line);

/* The board an anchor runs on in a script: tick at boot, storage, output sink. */
typedef struct script_env {
    script_emit_fn emit;
    void *user;
    uint32_t boot_tick;
    int have_stored;  /* storage holds `stored` */
    int store_fails;  /* config_store and the filter storage's store return an error */
    uint8_t stored[PFDOA_CONFIG_LEN];
    int have_filters; /* storage holds `filters` */
    uint8_t filters[PFDOA_FILTER_TABLE_LEN];
} script_env_t;

/* A HAL that reports every frame to env->emit as one line. */
void script_hal(script_env_t *env, pfdoa_hal_t *hal);
/* The filter table storage of env (pfdoa_anchor_use_filter_storage). */
void script_filter_storage(script_env_t *env, pfdoa_filter_storage_t *storage);
/* A radio (pfdoa_anchor_use_peer_radio) whose every frame becomes a "T <hex>" line of env. */
void script_peer_radio(script_env_t *env, uint8_t radio, const uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN],
                       pfdoa_peer_radio_t *out);

/*
 * Applies one script line (modified in place): R, B, A, Z, P, U, C (protocol/vectors/
 * README.md). scratch must hold at least strlen(line) / 2 bytes. Returns 0, or -1 for a
 * malformed line.
 */
int script_run_line(pfdoa_anchor_t *anchor, char *line, uint8_t *scratch, size_t scratch_cap);

/* Parses "offset_q8,alpha_q8,spike_db,report_mode,decimation" into env's storage. */
int script_set_stored_config(script_env_t *env, const char *text);

/* A vector's `init` object (protocol/vectors/README.md), as used by batch mode. */
typedef struct script_init {
    uint8_t anchor_id;
    uint8_t transports;  /* PFDOA_TRANSPORT_* */
    uint32_t boot_tick;
    uint8_t fw_major, fw_minor;
    int store_ok;
    int sil_inject;
    int has_config;
    pfdoa_config_t config;
    int has_filters;
    uint8_t filters[PFDOA_FILTER_TABLE_LEN];
    int has_peer_radio;  /* peer_radio and peer_address given */
    uint8_t peer_radio;  /* PFDOA_RADIO_* */
    uint8_t peer_address[PFDOA_IEEE802154_EXT_ADDR_LEN];
} script_init_t;

/*
 * Parses a JSON `init` object: anchor_id, transport ("uart" | "can" | "both"),
 * boot_tick_ms, fw_major, fw_minor, config {offset_q8, alpha_q8, spike_db, report_mode,
 * decimation}, filters (hex of the stored filter table), store_ok, sil_inject, peer_radio
 * ("ble" | "802154") with peer_address (hex, 6 or 8 bytes as the radio's). Unknown
 * keys, wrong types and out-of-range values are errors. Returns 0, or -1 with a reason in
 * err (err_cap bytes).
 */
int script_parse_init(const char *json, script_init_t *out, char *err, size_t err_cap);

#endif /* PFDOA_SCRIPT_H */
