/* Fixed-point anchor filter, see pfdoa_filter.h and protocol/SPEC.md section 3. */
#include "pfdoa_filter.h"

#include <stddef.h>

int32_t pfdoa_floor_div(const int32_t a, const int32_t b)
{
    if (b <= 0) {
        return 0;
    }
    int32_t q = a / b;
    if (((a % b) != 0) && (a < 0)) {
        q--;
    }
    return q;
}

int32_t pfdoa_fold_mean_q8(const int32_t sum, const uint8_t n)
{
    if (n == 0u) {
        return 0;
    }
    return pfdoa_floor_div((512 * sum) + (int32_t)n, 2 * (int32_t)n);
}

int32_t pfdoa_ema_step_q8(const int32_t ema_q8, const int32_t mean_q8, const uint16_t alpha_q8)
{
    /* |mean - ema| < 2^16 and alpha <= 256 in use, so the product fits in 32 bits. */
    return ema_q8 + pfdoa_floor_div(((int32_t)alpha_q8 * (mean_q8 - ema_q8)) + 128, 256);
}

int8_t pfdoa_clamp_dbm(const int8_t rssi_dbm, uint8_t *const flags)
{
    if (rssi_dbm > PFDOA_RSSI_MAX_DBM) {
        if (flags != NULL) {
            *flags |= PFDOA_FLAG_SATURATED;
        }
        return PFDOA_RSSI_MAX_DBM;
    }
    /* int8_t cannot be below PFDOA_RSSI_MIN_DBM (-128). */
    return rssi_dbm;
}

void pfdoa_event_open(pfdoa_event_t *const ev, const pfdoa_radio_reading_t *const reading)
{
    if ((ev != NULL) && (reading != NULL)) {
        ev->first_tick = reading->tick_ms;
        ev->seq = reading->seq;
        ev->radio = reading->radio;
        ev->sum = 0;
        ev->n = 0u;
        ev->flags = (reading->radio == PFDOA_RADIO_IEEE802154) ? (uint8_t)PFDOA_FLAG_ZIGBEE : 0u;
        pfdoa_event_add(ev, reading);
    }
}

void pfdoa_event_add(pfdoa_event_t *const ev, const pfdoa_radio_reading_t *const reading)
{
    if ((ev != NULL) && (reading != NULL) && (ev->n < PFDOA_BLE_EVENT_MAX_READINGS)) {
        const int8_t dbm = pfdoa_clamp_dbm(reading->rssi_dbm, &ev->flags);
        ev->sum = (int16_t)(ev->sum + dbm);
        ev->last_dbm = dbm;
        ev->channel = reading->channel;
        ev->n++;
    }
}

void pfdoa_filter_init(pfdoa_filter_t *const f)
{
    if (f != NULL) {
        f->ema_q8 = 0;
        f->have_ema = 0u;
        f->spike_run = 0u;
    }
}

int32_t pfdoa_filter_close_event(pfdoa_filter_t *const f, const pfdoa_config_t *const cfg,
                                 const pfdoa_event_t *const ev, const uint32_t close_tick,
                                 pfdoa_rssi_report_t *const out)
{
    if ((f == NULL) || (cfg == NULL) || (ev == NULL) || (out == NULL) || (ev->n == 0u)) {
        return PFDOA_ERR_ARG;
    }
    uint8_t flags = ev->flags;
    int32_t spike = 0;
    const int32_t mean_q8 = pfdoa_fold_mean_q8(ev->sum, ev->n);

    if (f->have_ema == 0u) {
        f->ema_q8 = mean_q8;
        f->have_ema = 1u;
        f->spike_run = 0u;
        flags |= PFDOA_FLAG_RESET;
    } else {
        const int32_t diff = mean_q8 - f->ema_q8;
        const int32_t mag = (diff < 0) ? -diff : diff;
        if ((cfg->spike_db > 0u) && (mag > (256 * (int32_t)cfg->spike_db))) {
            if (f->spike_run >= PFDOA_SPIKE_RUN_RESET) {
                /* A lasting level change, not a spike: follow it at once. */
                f->ema_q8 = mean_q8;
                f->spike_run = 0u;
                flags |= PFDOA_FLAG_RESET;
            } else {
                f->spike_run++;
                flags |= PFDOA_FLAG_SPIKE;
                spike = 1;
            }
        } else {
            f->spike_run = 0u;
            f->ema_q8 = pfdoa_ema_step_q8(f->ema_q8, mean_q8, cfg->alpha_q8);
        }
    }

    int32_t rssi = f->ema_q8 + cfg->offset_q8;
    if (rssi > INT16_MAX) {
        rssi = INT16_MAX;
        flags |= PFDOA_FLAG_SATURATED;
    } else if (rssi < INT16_MIN) {
        rssi = INT16_MIN;
        flags |= PFDOA_FLAG_SATURATED;
    } else {
        /* in range */
    }
    if (cfg->offset_q8 != 0) {
        flags |= PFDOA_FLAG_CALIBRATED;
    }
    out->seq = ev->seq;
    out->tick_ms = close_tick;
    out->rssi_q8 = (int16_t)rssi;
    out->raw_dbm = ev->last_dbm;
    out->n_readings = ev->n;
    out->channel = ev->channel;
    out->flags = flags;
    return spike;
}
