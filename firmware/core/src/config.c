/* Active configuration: defaults, validation, packing, hash. See pfdoa_config.h. */
#include "pfdoa_config.h"

#include <stddef.h>

#include "pfdoa_crc16.h"
#include "pfdoa_le.h"

/* Offsets inside the 7-byte form (CONFIG_SET payload minus the leading token). */
#define CFG_OFF_OFFSET_Q8   (PFDOA_MSG_CONFIG_SET_OFF_OFFSET_Q8 - 1)
#define CFG_OFF_ALPHA_Q8    (PFDOA_MSG_CONFIG_SET_OFF_ALPHA_Q8 - 1)
#define CFG_OFF_SPIKE_DB    (PFDOA_MSG_CONFIG_SET_OFF_SPIKE_DB - 1)
#define CFG_OFF_REPORT_MODE (PFDOA_MSG_CONFIG_SET_OFF_REPORT_MODE - 1)
#define CFG_OFF_DECIMATION  (PFDOA_MSG_CONFIG_SET_OFF_DECIMATION - 1)

void pfdoa_config_defaults(pfdoa_config_t *const cfg)
{
    if (cfg != NULL) {
        cfg->offset_q8 = PFDOA_DEFAULT_OFFSET_Q8;
        cfg->alpha_q8 = PFDOA_DEFAULT_ALPHA_Q8;
        cfg->spike_db = PFDOA_DEFAULT_SPIKE_DB;
        cfg->report_mode = PFDOA_DEFAULT_REPORT_MODE;
        cfg->decimation = PFDOA_DEFAULT_DECIMATION;
    }
}

int32_t pfdoa_config_validate(const pfdoa_config_t *const cfg)
{
    if ((cfg == NULL) || (cfg->alpha_q8 < PFDOA_VALID_ALPHA_Q8_MIN) ||
        (cfg->alpha_q8 > PFDOA_VALID_ALPHA_Q8_MAX) || (cfg->report_mode > PFDOA_VALID_REPORT_MODE_MAX) ||
        (cfg->decimation < PFDOA_VALID_DECIMATION_MIN)) {
        return PFDOA_ERR_ARG;
    }
    return PFDOA_OK;
}

void pfdoa_config_pack(const pfdoa_config_t *const cfg, uint8_t out[PFDOA_CONFIG_LEN])
{
    if ((cfg != NULL) && (out != NULL)) {
        pfdoa_put_u16(&out[CFG_OFF_OFFSET_Q8], pfdoa_u16_from_i16(cfg->offset_q8));
        pfdoa_put_u16(&out[CFG_OFF_ALPHA_Q8], cfg->alpha_q8);
        out[CFG_OFF_SPIKE_DB] = cfg->spike_db;
        out[CFG_OFF_REPORT_MODE] = cfg->report_mode;
        out[CFG_OFF_DECIMATION] = cfg->decimation;
    }
}

int32_t pfdoa_config_unpack(const uint8_t in[PFDOA_CONFIG_LEN], pfdoa_config_t *const cfg)
{
    if ((in == NULL) || (cfg == NULL)) {
        return PFDOA_ERR_ARG;
    }
    pfdoa_config_t c;
    c.offset_q8 = pfdoa_i16_from_u16(pfdoa_get_u16(&in[CFG_OFF_OFFSET_Q8]));
    c.alpha_q8 = pfdoa_get_u16(&in[CFG_OFF_ALPHA_Q8]);
    c.spike_db = in[CFG_OFF_SPIKE_DB];
    c.report_mode = in[CFG_OFF_REPORT_MODE];
    c.decimation = in[CFG_OFF_DECIMATION];
    const int32_t rc = pfdoa_config_validate(&c);
    if (rc == PFDOA_OK) {
        *cfg = c;
    }
    return rc;
}

uint16_t pfdoa_config_hash(const pfdoa_config_t *const cfg)
{
    if (cfg == NULL) {
        return 0u;
    }
    uint8_t bytes[PFDOA_CONFIG_LEN];
    pfdoa_config_pack(cfg, bytes);
    return pfdoa_crc16_update(PFDOA_CRC_INIT, bytes, sizeof bytes);
}
