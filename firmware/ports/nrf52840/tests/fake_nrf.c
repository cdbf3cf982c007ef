#include "fake_nrf.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cortexm.h"

nrf_clock_t nrf_fake_clock;
nrf_rtc_t nrf_fake_rtc1;
nrf_uarte_t nrf_fake_uarte0;
nrf_radio_t nrf_fake_radio;
nrf_spim_t nrf_fake_spim2;
nrf_gpio_t nrf_fake_p0;
nrf_gpio_t nrf_fake_p1;
nrf_gpiote_t nrf_fake_gpiote;
nrf_nvmc_t nrf_fake_nvmc;
uint32_t nrf_fake_uicr_customer0;
uint32_t nrf_fake_store_pages[NRF_STORE_PAGES][NRF_FLASH_PAGE_SIZE / 4u];
nrf_fake_t nrf_fake;

/* EasyDMA addresses: handle i maps to dma_table[i]; 4 KB apart, offsets within. */
#define DMA_BASE   0x20000000u
#define DMA_STRIDE 0x1000u
#define DMA_SLOTS  256u
static const volatile void *dma_table[DMA_SLOTS];
static uint32_t dma_used;
static uint64_t rtc_now;

#define CLEAR(x) memset((void *)&(x), 0, sizeof(x))

void nrf_fake_reset(void)
{
    CLEAR(nrf_fake_clock);
    CLEAR(nrf_fake_rtc1);
    CLEAR(nrf_fake_uarte0);
    CLEAR(nrf_fake_radio);
    CLEAR(nrf_fake_spim2);
    CLEAR(nrf_fake_p0);
    CLEAR(nrf_fake_p1);
    CLEAR(nrf_fake_gpiote);
    CLEAR(nrf_fake_nvmc);
    memset(&nrf_fake, 0, sizeof nrf_fake);
    memset(nrf_fake_store_pages, 0xFF, sizeof nrf_fake_store_pages);
    nrf_fake_uicr_customer0 = 0xFFFFFFFFu;
    nrf_fake_nvmc.READY = 1u;
    nrf_fake_p1.IN = 0xFFFFFFFFu; /* pulled-up inputs read high */
    dma_used = 0u;
    rtc_now = 0u;
}

uint32_t nrf_fake_dma_addr(const volatile void *p)
{
    for (uint32_t i = 0u; i < dma_used; ++i) {
        if (dma_table[i] == p) {
            return DMA_BASE + i * DMA_STRIDE;
        }
    }
    if (dma_used == DMA_SLOTS) {
        fprintf(stderr, "fake_nrf: more than %u distinct DMA buffers\n", DMA_SLOTS);
        abort();
    }
    dma_table[dma_used] = p;
    return DMA_BASE + (dma_used++) * DMA_STRIDE;
}

void *nrf_fake_dma_ptr(const uint32_t addr)
{
    if (addr < DMA_BASE) {
        return NULL;
    }
    const uint32_t i = (addr - DMA_BASE) / DMA_STRIDE;
    if (i >= dma_used) {
        return NULL;
    }
    return (uint8_t *)(uintptr_t)dma_table[i] + (addr - DMA_BASE) % DMA_STRIDE;
}

void nrf_fake_flash_write(const volatile uint32_t *addr, const uint32_t word)
{
    const uintptr_t a = (uintptr_t)addr;
    const uintptr_t base = (uintptr_t)nrf_fake_store_pages;
    if (nrf_fake_nvmc.CONFIG != NRF_NVMC_CONFIG_WEN || a < base || a >= base + sizeof nrf_fake_store_pages
        || (a % 4u) != 0u) {
        nrf_fake.flash_violations++;
        return;
    }
    const uintptr_t off = a - base;
    uint32_t *const w = &nrf_fake_store_pages[off / NRF_FLASH_PAGE_SIZE][(off % NRF_FLASH_PAGE_SIZE) / 4u];
    if ((*w & word) != word) {
        nrf_fake.flash_violations++; /* flash programs 1 -> 0 only */
    }
    *w &= word;
    nrf_fake.flash_writes++;
}

static void spin_clock(void)
{
    nrf_clock_t *const c = &nrf_fake_clock;
    if (c->TASKS_HFCLKSTART != 0u) {
        c->TASKS_HFCLKSTART = 0u;
        if (!nrf_fake.hfxo_fails) {
            c->HFCLKSTAT = NRF_CLOCK_HFCLKSTAT_XTAL | NRF_CLOCK_STAT_RUNNING;
            c->EVENTS_HFCLKSTARTED = 1u;
        }
    }
    if (c->TASKS_LFCLKSTOP != 0u) {
        c->TASKS_LFCLKSTOP = 0u;
        c->LFCLKSTAT = 0u;
    }
    if (c->TASKS_LFCLKSTART != 0u) {
        c->TASKS_LFCLKSTART = 0u;
        const uint32_t src = c->LFCLKSRC & NRF_CLOCK_STAT_SRC_MASK;
        if (!(src == NRF_CLOCK_LFCLKSRC_XTAL && nrf_fake.lfxo_fails)) {
            c->LFCLKSTAT = src | NRF_CLOCK_STAT_RUNNING;
            c->EVENTS_LFCLKSTARTED = 1u;
        }
    }
}

static void spin_spim(void)
{
    nrf_spim_t *const s = &nrf_fake_spim2;
    if (s->TASKS_START == 0u || nrf_fake.spim_stuck) {
        return;
    }
    s->TASKS_START = 0u;
    const uint8_t *const tx = nrf_fake_dma_ptr(s->TXD_PTR);
    uint8_t *const rx = nrf_fake_dma_ptr(s->RXD_PTR);
    const size_t n = (s->TXD_MAXCNT > s->RXD_MAXCNT) ? s->TXD_MAXCNT : s->RXD_MAXCNT;
    uint8_t txb[256];
    uint8_t rxb[256];
    memset(txb, (int)(s->ORC & 0xFFu), sizeof txb); /* past TXD.MAXCNT the ORC byte goes out */
    memset(rxb, 0xFF, sizeof rxb);
    if (tx != NULL) {
        memcpy(txb, tx, s->TXD_MAXCNT);
    }
    if ((nrf_fake_p1.OUTCLR & nrf_fake.spi_cs_mask) != nrf_fake.spi_cs_mask || nrf_fake.spi_cs_mask == 0u) {
        nrf_fake.spi_without_cs++;
    }
    nrf_fake_p1.OUTCLR = 0u; /* consumed: the next transfer must assert CS again */
    if (nrf_fake.spi_device != NULL) {
        nrf_fake.spi_device(txb, rxb, n, nrf_fake.spi_ctx);
    }
    if (rx != NULL) {
        memcpy(rx, rxb, s->RXD_MAXCNT);
    }
    s->TXD_AMOUNT = s->TXD_MAXCNT;
    s->RXD_AMOUNT = s->RXD_MAXCNT;
    nrf_fake.spi_transfers++;
    s->EVENTS_END = 1u;
}

static void spin_nvmc(void)
{
    nrf_nvmc_t *const n = &nrf_fake_nvmc;
    if (n->ERASEPAGE == 0u) {
        return;
    }
    void *const page = nrf_fake_dma_ptr(n->ERASEPAGE);
    uint32_t p = 0u;
    while (p < NRF_STORE_PAGES && page != (void *)nrf_fake_store_pages[p]) {
        ++p;
    }
    if (n->CONFIG != NRF_NVMC_CONFIG_EEN || p == NRF_STORE_PAGES) {
        nrf_fake.flash_violations++;
    } else {
        memset(nrf_fake_store_pages[p], 0xFF, sizeof nrf_fake_store_pages[p]);
        nrf_fake.flash_erases++;
    }
    n->ERASEPAGE = 0u;
}

/* The RADIO transmits what TXEN started (header, length byte, payload from PACKETPTR):
 * logged, then READY, END and DISABLED through the shortcuts. */
static void spin_radio_tx(void)
{
    if (nrf_fake_radio.TASKS_TXEN == 0u || nrf_fake.radio_tx_stuck) {
        return;
    }
    nrf_fake_radio.TASKS_TXEN = 0u;
    const uint8_t *const p = nrf_fake_dma_ptr(nrf_fake_radio.PACKETPTR);
    if (nrf_fake.tx_count < NRF_FAKE_TX_MAX && p != NULL) {
        nrf_fake_tx_t *const t = &nrf_fake.tx[nrf_fake.tx_count];
        const size_t n = 2u + (size_t)p[1];
        t->frequency = nrf_fake_radio.FREQUENCY;
        t->whiteiv = nrf_fake_radio.DATAWHITEIV;
        t->txpower = nrf_fake_radio.TXPOWER;
        t->tick = (uint32_t)nrf_fake_rtc_now();
        t->len = (uint8_t)((n <= sizeof t->data) ? n : sizeof t->data);
        memcpy(t->data, p, t->len);
    }
    nrf_fake.tx_count++;
    nrf_fake_radio.EVENTS_READY = 1u;
    nrf_fake_radio.EVENTS_END = 1u;
    nrf_fake_radio.EVENTS_DISABLED = 1u;
    nrf_fake_radio.STATE = NRF_RADIO_STATE_DISABLED;
}

void nrf_fake_spin(void)
{
    spin_clock();
    spin_spim();
    spin_nvmc();
    spin_radio_tx();
    if (nrf_fake_radio.TASKS_DISABLE != 0u) {
        nrf_fake_radio.TASKS_DISABLE = 0u;
        nrf_fake_radio.STATE = NRF_RADIO_STATE_DISABLED;
        nrf_fake_radio.EVENTS_DISABLED = 1u;
    }
}

uint32_t nrf_fake_rtc_advance_to(const uint64_t ticks, void (*const irq)(void))
{
    uint32_t wraps = 0u;
    while ((rtc_now >> 24) < (ticks >> 24)) {
        rtc_now = ((rtc_now >> 24) + 1u) << 24;
        nrf_fake_rtc1.COUNTER = 0u;
        nrf_fake_rtc1.EVENTS_OVRFLW = 1u;
        ++wraps;
        if (irq != NULL) {
            irq();
        }
    }
    if (ticks > rtc_now) {
        rtc_now = ticks;
    }
    nrf_fake_rtc1.COUNTER = (uint32_t)(rtc_now & NRF_RTC_COUNTER_MASK);
    return wraps;
}

uint64_t nrf_fake_rtc_now(void)
{
    return rtc_now;
}

/* ---- the core's side: PRIMASK, WFI, NVIC ---- */

uint32_t cm_irq_save(void)
{
    const uint32_t p = nrf_fake.primask;
    nrf_fake.primask = 1u;
    return p;
}

void cm_irq_restore(const uint32_t primask)
{
    nrf_fake.primask = primask;
}

void cm_wfi(void)
{
    nrf_fake.wfi_count++;
    if (nrf_fake.primask == 0u) {
        nrf_fake.wfi_unmasked++;
    }
    if (nrf_fake.on_wfi != NULL) {
        nrf_fake.on_wfi(nrf_fake.on_wfi_ctx);
    }
}

void cm_nvic_enable(const uint32_t irq, const uint32_t priority)
{
    if (irq < NRF_IRQ_COUNT) {
        nrf_fake.nvic_enabled[irq / 32u] |= 1u << (irq % 32u);
        nrf_fake.nvic_priority[irq] = (uint8_t)priority;
    }
}
