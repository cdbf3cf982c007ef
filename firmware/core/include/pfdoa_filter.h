/*
 * pfdoa_filter.h - anchor filtering in fixed point, protocol/SPEC.md section 3:
 * reading clamp, beacon-event fold, spike rejection, EMA, calibration and saturation.
 * Integer only; every division rounds towards minus infinity as the SPEC says, so the
 * results are bit-exact with the Python and MicroPython implementations.
 */
#ifndef PFDOA_FILTER_H
#define PFDOA_FILTER_H

#include <stdint.h>

#include "pfdoa_config.h"
#include "pfdoa_defs.h"
#include "pfdoa_msg.h"

#ifdef __cplusplus
extern "C" {
#endif

/* One open beacon event: the readings with one seq (and one radio type) so far. */
typedef struct pfdoa_event {
    uint32_t first_tick; /* tick of the first reading, for the BLE timeout */
    uint16_t seq;
    int16_t sum;         /* sum of clamped readings: |sum| <= 3 * 128 */
    int8_t last_dbm;     /* last clamped reading */
    uint8_t channel;     /* channel of the last reading */
    uint8_t n;           /* readings so far; 0 = no open event */
    uint8_t radio;       /* PFDOA_RADIO_* */
    uint8_t flags;       /* SATURATED from clamping, ZIGBEE from the radio */
} pfdoa_event_t;

/* Filter state that survives events. */
typedef struct pfdoa_filter {
    int32_t ema_q8;    /* Q7.8 dBm, uncalibrated */
    uint8_t have_ema;
    uint8_t spike_run; /* consecutive spike events */
} pfdoa_filter_t;

/* floor(a / b) for b > 0 (C division truncates towards zero). b <= 0 gives 0. */
int32_t pfdoa_floor_div(int32_t a, int32_t b);

/* round_half_up(256 * sum / n) = floor((512 * sum + n) / (2 * n)); n >= 1. */
int32_t pfdoa_fold_mean_q8(int32_t sum, uint8_t n);

/* One EMA update: ema_q8 + floor((alpha_q8 * (mean_q8 - ema_q8) + 128) / 256). */
int32_t pfdoa_ema_step_q8(int32_t ema_q8, int32_t mean_q8, uint16_t alpha_q8);

/* Clamps a valid reading to [PFDOA_RSSI_MIN_DBM, PFDOA_RSSI_MAX_DBM]; sets SATURATED in *flags when it clamps. */
int8_t pfdoa_clamp_dbm(int8_t rssi_dbm, uint8_t *flags);

/* Opens *ev with its first reading (already validated). */
void pfdoa_event_open(pfdoa_event_t *ev, const pfdoa_radio_reading_t *reading);

/* Adds a reading of the same seq and radio to the open event *ev. */
void pfdoa_event_add(pfdoa_event_t *ev, const pfdoa_radio_reading_t *reading);

void pfdoa_filter_init(pfdoa_filter_t *f);

/*
 * Runs a closed event through spike rejection, EMA and calibration, and fills *out
 * (seq, tick_ms = close_tick, rssi_q8, raw_dbm, n_readings, channel, flags). Returns 1 if
 * the event was a spike, 0 if not, PFDOA_ERR_ARG on NULL or an empty event.
 */
int32_t pfdoa_filter_close_event(pfdoa_filter_t *f, const pfdoa_config_t *cfg, const pfdoa_event_t *ev,
                                 uint32_t close_tick, pfdoa_rssi_report_t *out);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_FILTER_H */
