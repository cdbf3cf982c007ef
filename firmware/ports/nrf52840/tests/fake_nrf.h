/*
 * fake_nrf.h - the register fake the port's drivers run against on the host (-DNRF_FAKE).
 *
 * Every peripheral block of nrf52840.h is a RAM struct here (nrf_fake_radio, ...). A test
 * plays the hardware: it raises events, writes packets into the RAM the driver handed the
 * RADIO (nrf_fake_dma_ptr(NRF_RADIO->PACKETPTR)), calls the interrupt handlers, and reads
 * back the tasks and registers the driver wrote. nrf_fake_spin(), called in every
 * busy-wait loop of the drivers, is the part of the hardware that reacts on its own:
 * clocks start, the radio disables, SPIM transfers run through the attached SPI device
 * (the MCP2515 model of fake_mcp2515.h), the NVMC erases.
 */
#ifndef FAKE_NRF_H
#define FAKE_NRF_H

#include <stddef.h>
#include <stdint.h>

#include "nrf52840.h"

/* One packet the RADIO sent (TXEN with the beacon image's transmitter, radio_tx.h). */
#define NRF_FAKE_TX_MAX 64u
typedef struct nrf_fake_tx {
    uint32_t frequency;      /* FREQUENCY when TXEN was given */
    uint32_t whiteiv;        /* DATAWHITEIV */
    uint32_t txpower;        /* TXPOWER */
    uint32_t tick;           /* the RTC count then */
    uint8_t len;             /* 2 + the PDU's length byte */
    uint8_t data[40];
} nrf_fake_tx_t;

typedef struct nrf_fake {
    /* behaviour knobs (set by tests) */
    int radio_tx_stuck;      /* TXEN never ends (no DISABLED) */
    int hfxo_fails;          /* HFCLKSTART never completes */
    int lfxo_fails;          /* LFCLKSTART with the crystal never completes */
    int spim_stuck;          /* SPIM START never ends */
    /* SPI device on SPIM2: one call per transaction (CS low .. CS high) */
    void (*spi_device)(const uint8_t *tx, uint8_t *rx, size_t len, void *ctx);
    void *spi_ctx;
    uint32_t spi_cs_mask;    /* P1 OUTCLR bit that must be written before START */
    /* what happened */
    uint32_t primask;        /* the fake PRIMASK */
    uint32_t wfi_count;
    uint32_t wfi_unmasked;   /* WFI entered with interrupts enabled (the race) */
    uint32_t spi_transfers;
    uint32_t spi_without_cs;
    uint32_t flash_writes;
    uint32_t flash_erases;
    uint32_t flash_violations; /* write without WEN, erase without EEN, a 0 -> 1 bit */
    uint32_t nvic_enabled[2];
    uint8_t nvic_priority[NRF_IRQ_COUNT];
    nrf_fake_tx_t tx[NRF_FAKE_TX_MAX]; /* packets sent, in order (the first NRF_FAKE_TX_MAX) */
    uint32_t tx_count;
    void (*on_wfi)(void *ctx); /* called inside WFI: an interrupt "arrives" */
    void *on_wfi_ctx;
} nrf_fake_t;

extern nrf_fake_t nrf_fake;

/* Zeroes every block and the state above; flash page erased, UICR erased, READY set. */
void nrf_fake_reset(void);

/* The host pointer behind a 32-bit EasyDMA address the driver wrote (NULL if unknown). */
void *nrf_fake_dma_ptr(uint32_t addr);

/* Moves RTC1 to an absolute count of 1/32768 s ticks, one COUNTER wrap at a time: each
 * wrap raises EVENTS_OVRFLW and calls RTC1_IRQHandler (when irq != NULL), as the
 * hardware would. Returns the wraps done. */
uint32_t nrf_fake_rtc_advance_to(uint64_t ticks, void (*irq)(void));

/* The RTC count a test is at (what nrf_fake_rtc_advance_to moved it to). */
uint64_t nrf_fake_rtc_now(void);

#endif /* FAKE_NRF_H */
