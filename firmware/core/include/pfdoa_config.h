/*
 * pfdoa_config.h - the anchor's 7-byte active configuration (protocol/SPEC.md 1.3 without
 * `token`): defaults, validation, wire/storage encoding and the config hash.
 *
 * The stored form (HAL config_load/config_store) is the wire form, so a configuration
 * read back from flash is validated exactly like one received from the host.
 */
#ifndef PFDOA_CONFIG_H
#define PFDOA_CONFIG_H

#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pfdoa_config {
    int16_t offset_q8;   /* calibration offset, Q7.8 dB, added to the filtered RSSI */
    uint16_t alpha_q8;   /* EMA constant alpha_q8 / 256, 1..256 */
    uint8_t spike_db;    /* spike threshold in whole dB, 0 disables */
    uint8_t report_mode; /* PFDOA_REPORT_EVERY / _DECIMATE / _SILENT */
    uint8_t decimation;  /* 1..255 */
} pfdoa_config_t;

/* The first-boot configuration (SPEC 1.3 defaults). */
void pfdoa_config_defaults(pfdoa_config_t *cfg);

/* PFDOA_OK if every field is in its valid range, else PFDOA_ERR_ARG. */
int32_t pfdoa_config_validate(const pfdoa_config_t *cfg);

/* Writes the PFDOA_CONFIG_LEN-byte little-endian form. */
void pfdoa_config_pack(const pfdoa_config_t *cfg, uint8_t out[PFDOA_CONFIG_LEN]);

/*
 * Reads the PFDOA_CONFIG_LEN-byte form. On PFDOA_OK *cfg holds it; on PFDOA_ERR_ARG
 * (NULL, or a field out of range) *cfg is unchanged.
 */
int32_t pfdoa_config_unpack(const uint8_t in[PFDOA_CONFIG_LEN], pfdoa_config_t *cfg);

/* CRC-16 over the packed form: STATUS.config_hash and CONFIG_ACK.config_hash. */
uint16_t pfdoa_config_hash(const pfdoa_config_t *cfg);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_CONFIG_H */
