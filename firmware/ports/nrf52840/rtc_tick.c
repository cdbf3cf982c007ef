#include "rtc_tick.h"

#include "cortexm.h"
#include "nrf52840.h"

/* COUNTER values are 24 bits; a compare further away than half the range could be read
 * as already passed. */
#define COMPARE_MIN  2u
#define COMPARE_MAX  (1u << 23)
#define COMPARE_CHANNELS 4u

void rtc_tick_start(rtc_tick_t *const tick)
{
    nrf_rtc_t *const rtc = NRF_RTC1;
    rtc->TASKS_STOP = 1u;
    rtc->TASKS_CLEAR = 1u;
    rtc->PRESCALER = 0u;
    tick->overflows = 0u;
    rtc->EVENTS_OVRFLW = 0u;
    rtc->INTENSET = NRF_RTC_INT_OVRFLW;
    rtc->TASKS_START = 1u;
}

/* One overflow pending in the event register: count it. Interrupts masked. */
static void take_overflow(rtc_tick_t *const tick)
{
    nrf_rtc_t *const rtc = NRF_RTC1;
    rtc->EVENTS_OVRFLW = 0u;
    (void)rtc->EVENTS_OVRFLW; /* the write reaches the peripheral before we go on */
    tick->overflows = tick->overflows + 1u;
}

uint64_t rtc_tick_now(rtc_tick_t *const tick)
{
    nrf_rtc_t *const rtc = NRF_RTC1;
    const uint32_t primask = cm_irq_save();
    uint32_t counter = rtc->COUNTER & NRF_RTC_COUNTER_MASK;
    /* A wrap between the COUNTER read and here leaves the event pending: count it and
     * read COUNTER again (it is then past the wrap). A wrap after the event check leaves
     * the first, pre-wrap reading consistent with the old overflow count. */
    if (rtc->EVENTS_OVRFLW != 0u) {
        take_overflow(tick);
        counter = rtc->COUNTER & NRF_RTC_COUNTER_MASK;
    }
    const uint64_t ticks = ((uint64_t)tick->overflows << 24) | counter;
    cm_irq_restore(primask);
    return ticks;
}

uint32_t rtc_tick_to_ms(const uint64_t ticks)
{
    /* 1000 / 32768 = 125 / 4096. ticks * 125 fits in 64 bits for 4 million years of uptime. */
    return (uint32_t)((ticks * 125u) >> 12);
}

uint32_t rtc_tick_ms(rtc_tick_t *const tick)
{
    return rtc_tick_to_ms(rtc_tick_now(tick));
}

uint32_t rtc_tick_from_ms(const uint32_t ms)
{
    return (ms * 4096u + 124u) / 125u;
}

void rtc_tick_compare_in(rtc_tick_t *const tick, const uint32_t channel, uint32_t ticks)
{
    nrf_rtc_t *const rtc = NRF_RTC1;
    (void)tick;
    if (channel >= COMPARE_CHANNELS) {
        return;
    }
    if (ticks < COMPARE_MIN) {
        ticks = COMPARE_MIN;
    } else if (ticks > COMPARE_MAX) {
        ticks = COMPARE_MAX;
    }
    const uint32_t primask = cm_irq_save();
    rtc->EVENTS_COMPARE[channel] = 0u;
    rtc->CC[channel] = (rtc->COUNTER + ticks) & NRF_RTC_COUNTER_MASK;
    rtc->INTENSET = NRF_RTC_INT_COMPARE(channel);
    cm_irq_restore(primask);
}

void rtc_tick_wake_in(rtc_tick_t *const tick, const uint32_t ms)
{
    rtc_tick_compare_in(tick, RTC_TICK_WAKE, rtc_tick_from_ms(ms));
}

uint32_t rtc_tick_isr(rtc_tick_t *const tick)
{
    nrf_rtc_t *const rtc = NRF_RTC1;
    /* Masked: a higher-priority reader between the check and the count would count the
     * same overflow twice. */
    const uint32_t primask = cm_irq_save();
    if (rtc->EVENTS_OVRFLW != 0u) {
        take_overflow(tick);
    }
    cm_irq_restore(primask);
    uint32_t fired = 0u;
    for (uint32_t n = 0u; n < COMPARE_CHANNELS; ++n) {
        if (rtc->EVENTS_COMPARE[n] != 0u) {
            rtc->EVENTS_COMPARE[n] = 0u;
            (void)rtc->EVENTS_COMPARE[n];
            fired |= 1u << n;
        }
    }
    return fired;
}
