/*
 * sil_clock.h - the SIL image's millisecond clock: the simulator owns time.
 *
 * Each RADIO_INJECT and RADIO_INJECT_RAW frame carries the anchor tick at which its
 * reading (or raw frame) was heard; the clock follows the tick of the last one addressed
 * to this anchor. main polls the anchor
 * at that tick right after each injected reading, so the firmware under QEMU sees exactly
 * the sequence "reading at t, poll at t" that the host build's event script spells out
 * (`U t <frame>` then `P t`), and its output is independent of how fast QEMU or the host
 * runs. Real images tick from SysTick instead (board_tick_ms).
 *
 * It watches the same received bytes as the anchor with its own instance of the core's
 * frame decoder (no second parser), knowing only the two injections; everything else, errors
 * included, is the anchor's business.
 */
#ifndef SIL_CLOCK_H
#define SIL_CLOCK_H

#include <stdint.h>

#include "pfdoa_frame.h"

typedef struct sil_clock {
    pfdoa_decoder_t decoder;
    uint32_t now_ms;
    uint8_t anchor_id;
} sil_clock_t;

void sil_clock_init(sil_clock_t *clock, uint8_t anchor_id, uint32_t start_ms);

/* Feeds one received byte. Returns 1 when it completed a RADIO_INJECT or
 * RADIO_INJECT_RAW frame for this anchor (now_ms is then its tick), else 0. */
int sil_clock_push(sil_clock_t *clock, uint8_t byte);

#endif /* SIL_CLOCK_H */
