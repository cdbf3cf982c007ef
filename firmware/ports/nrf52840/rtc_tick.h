/*
 * rtc_tick.h - the millisecond tick from RTC1 (32.768 kHz LFCLK, PRESCALER 0).
 *
 * RTC1's COUNTER has 24 bits and wraps every 512 s; the driver counts its OVRFLW events
 * and extends it to a 64-bit count of 1/32768 s ticks. Milliseconds are
 * floor(ticks * 1000 / 32768) = (ticks * 125) >> 12, computed from the whole count each
 * time: exact, with no rounding carried from one call to the next (no drift), and the
 * 32-bit result wraps at 2^32 ms like the core expects (u32 differences stay right).
 *
 * COMPARE[0] wakes the main loop (rtc_tick_wake_in); COMPARE[1] is the radio's channel
 * hop timer (rtc_tick_compare_in). The RTC keeps running while the CPU sleeps.
 */
#ifndef NRF_RTC_TICK_H
#define NRF_RTC_TICK_H

#include <stdint.h>

#define RTC_TICK_HZ      32768u
#define RTC_TICK_WAKE    0u /* COMPARE channel of the main loop's wake-up */
#define RTC_TICK_HOP     1u /* COMPARE channel of the radio's channel hop */

typedef struct rtc_tick {
    volatile uint32_t overflows; /* COUNTER wraps seen (ISR, or a reader under the mask) */
} rtc_tick_t;

/* Starts RTC1 from 0 with the overflow interrupt; the LFCLK must be running. */
void rtc_tick_start(rtc_tick_t *tick);

/* 1/32768 s ticks since rtc_tick_start. Safe from any context (masks interrupts briefly). */
uint64_t rtc_tick_now(rtc_tick_t *tick);

/* Milliseconds since rtc_tick_start, wrapping at 2^32. */
uint32_t rtc_tick_ms(rtc_tick_t *tick);

/* The exact conversion used by rtc_tick_ms: floor(ticks * 1000 / 32768) mod 2^32. */
uint32_t rtc_tick_to_ms(uint64_t ticks);

/* RTC ticks covering at least ms milliseconds (ceil(ms * 32768 / 1000)); ms <= 100000. */
uint32_t rtc_tick_from_ms(uint32_t ms);

/* Arms COMPARE[channel] to fire `ticks` RTC ticks from now (at least 2: the PS says a
 * CC of COUNTER or COUNTER + 1 may not fire; at most 2^23, half the counter's range). */
void rtc_tick_compare_in(rtc_tick_t *tick, uint32_t channel, uint32_t ticks);

/* The main loop's wake-up: COMPARE[RTC_TICK_WAKE] in ms milliseconds. */
void rtc_tick_wake_in(rtc_tick_t *tick, uint32_t ms);

/* Body of RTC1_IRQHandler: counts an overflow and clears the COMPARE events that fired.
 * Returns a bit mask of the COMPARE channels that fired (bit n = channel n). */
uint32_t rtc_tick_isr(rtc_tick_t *tick);

#endif /* NRF_RTC_TICK_H */
