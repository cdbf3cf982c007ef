/*
 * clock.h - start-up of the nRF52840's clocks (PS v1.7, chapter "CLOCK - Clock control").
 *
 * The RADIO needs the 64 MHz crystal oscillator (HFXO; the internal HFINT is not accurate
 * enough for BLE or 802.15.4). The RTC tick runs on the 32.768 kHz LFCLK: the crystal
 * (LFXO, fitted on the nRF52840 DK) when it starts, else the internal RC oscillator
 * (LFRC), which must then be calibrated against the HFXO at least every few seconds to
 * stay within +-500 ppm (clock_calibrate).
 */
#ifndef NRF_CLOCK_H
#define NRF_CLOCK_H

#include <stdint.h>

#define CLOCK_OK           0
#define CLOCK_ERR_HFXO    -1 /* the 64 MHz crystal did not start */

/* Busy-wait bounds: each iteration is one register read (a few CPU cycles at 64 MHz).
 * HFXO starts in about 0.3 ms, the LFXO in about 0.25 s (PS electrical specifications). */
#define CLOCK_HFXO_SPINS   200000u
#define CLOCK_LFXO_SPINS   40000000u
/* LFRC calibration period: the PS's +-500 ppm LFRC tolerance holds when calibrated at
 * least every 8 s with temperature changes under 0.5 degC; 4 s leaves margin. */
#define CLOCK_CAL_PERIOD_MS 4000u

typedef enum clock_lf_source {
    CLOCK_LF_XTAL = 1, /* LFXO */
    CLOCK_LF_RC = 0    /* LFRC, calibrated */
} clock_lf_source_t;

/* Starts the HFXO and waits for it. Returns CLOCK_OK or CLOCK_ERR_HFXO. */
int32_t clock_start_hfxo(void);

/* Starts the LFCLK from the LFXO; falls back to the LFRC when the crystal does not start
 * within CLOCK_LFXO_SPINS. Returns the source now running. */
clock_lf_source_t clock_start_lfclk(void);

/* LFRC calibration, driven from the main loop without waiting (it takes milliseconds):
 * starts TASKS_CAL every CLOCK_CAL_PERIOD_MS and collects EVENTS_DONE. Needs the HFXO.
 * Does nothing for the LFXO. */
typedef struct clock_cal {
    clock_lf_source_t source;
    uint32_t last_ms;   /* when the last calibration started */
    uint32_t done;      /* calibrations completed */
    uint8_t busy;       /* one is running */
} clock_cal_t;

void clock_cal_init(clock_cal_t *cal, clock_lf_source_t source, uint32_t now_ms);
void clock_cal_poll(clock_cal_t *cal, uint32_t now_ms);

#endif /* NRF_CLOCK_H */
