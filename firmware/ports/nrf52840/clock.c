#include "clock.h"

#include "nrf52840.h"

/* Waits for an event register to be set, at most `spins` reads. Returns 1 if it was. */
static int wait_event(const nrf_reg_t *event, uint32_t spins)
{
    while (spins-- > 0u) {
        if (*event != 0u) {
            return 1;
        }
        NRF_SPIN();
    }
    return 0;
}

int32_t clock_start_hfxo(void)
{
    nrf_clock_t *const clk = NRF_CLOCK;
    clk->EVENTS_HFCLKSTARTED = 0u;
    clk->TASKS_HFCLKSTART = 1u;
    if (wait_event(&clk->EVENTS_HFCLKSTARTED, CLOCK_HFXO_SPINS) == 0) {
        return CLOCK_ERR_HFXO;
    }
    clk->EVENTS_HFCLKSTARTED = 0u;
    return ((clk->HFCLKSTAT & NRF_CLOCK_STAT_SRC_MASK) == NRF_CLOCK_HFCLKSTAT_XTAL) ? CLOCK_OK : CLOCK_ERR_HFXO;
}

static int start_lf(uint32_t src, uint32_t spins)
{
    nrf_clock_t *const clk = NRF_CLOCK;
    clk->TASKS_LFCLKSTOP = 1u;
    clk->LFCLKSRC = src; /* may only change while the LFCLK is stopped */
    clk->EVENTS_LFCLKSTARTED = 0u;
    clk->TASKS_LFCLKSTART = 1u;
    const int ok = wait_event(&clk->EVENTS_LFCLKSTARTED, spins);
    clk->EVENTS_LFCLKSTARTED = 0u;
    return ok && ((clk->LFCLKSTAT & NRF_CLOCK_STAT_SRC_MASK) == src);
}

clock_lf_source_t clock_start_lfclk(void)
{
    if (start_lf(NRF_CLOCK_LFCLKSRC_XTAL, CLOCK_LFXO_SPINS)) {
        return CLOCK_LF_XTAL;
    }
    /* No crystal (or a broken one): the RC oscillator always starts. */
    (void)start_lf(NRF_CLOCK_LFCLKSRC_RC, CLOCK_LFXO_SPINS);
    return CLOCK_LF_RC;
}

void clock_cal_init(clock_cal_t *const cal, const clock_lf_source_t source, const uint32_t now_ms)
{
    cal->source = source;
    cal->last_ms = now_ms - CLOCK_CAL_PERIOD_MS; /* the first one at once */
    cal->done = 0u;
    cal->busy = 0u;
}

void clock_cal_poll(clock_cal_t *const cal, const uint32_t now_ms)
{
    nrf_clock_t *const clk = NRF_CLOCK;
    if (cal->source != CLOCK_LF_RC) {
        return;
    }
    if (cal->busy != 0u) {
        if (clk->EVENTS_DONE != 0u) {
            clk->EVENTS_DONE = 0u;
            cal->busy = 0u;
            cal->done++;
        }
        return;
    }
    if ((uint32_t)(now_ms - cal->last_ms) >= CLOCK_CAL_PERIOD_MS) {
        clk->EVENTS_DONE = 0u;
        clk->TASKS_CAL = 1u;
        cal->busy = 1u;
        cal->last_ms = now_ms;
    }
}
