/*
 * spim.h - SPIM2 as a blocking SPI master (PS v1.7, chapter "SPIM - Serial peripheral
 * interface master with EasyDMA"), mode 0 (CPOL 0, CPHA 0), MSB first, with a GPIO chip
 * select held low for the whole transfer.
 *
 * One spim_xfer is one transaction: CS low, TXD.MAXCNT bytes out while RXD.MAXCNT bytes
 * come in (EasyDMA, both buffers in RAM), END, CS high. A transfer that does not end
 * within SPIM_SPINS polls is stopped and reported (a missing or stuck device never hangs
 * the firmware).
 */
#ifndef NRF_SPIM_H
#define NRF_SPIM_H

#include <stddef.h>
#include <stdint.h>

#include "nrf52840.h"

#define SPIM_MAX_XFER 32u      /* longest transaction a driver here needs */
#define SPIM_SPINS    100000u  /* 32 bytes at 4 MHz take 64 us */
#define SPIM_OK        0
#define SPIM_ERR_ARG  -1
#define SPIM_ERR_TIMEOUT -2

typedef struct spim {
    nrf_gpio_t *cs_port;
    uint32_t cs_pin;
    uint32_t timeouts;
} spim_t;

/* Configures SPIM2 on the given PSEL values at 4 MHz and the CS pin as an output, high. */
void spim_init(spim_t *s, uint32_t psel_sck, uint32_t psel_mosi, uint32_t psel_miso, nrf_gpio_t *cs_port,
               uint32_t cs_pin);

/* One transaction of len bytes (1..SPIM_MAX_XFER): tx out, the same number of bytes into
 * rx (rx may be NULL). Returns SPIM_OK, SPIM_ERR_ARG or SPIM_ERR_TIMEOUT. The
 * int32_t (*)(void *, const uint8_t *, uint8_t *, size_t) shape a device driver takes. */
int32_t spim_xfer(void *s, const uint8_t *tx, uint8_t *rx, size_t len);

#endif /* NRF_SPIM_H */
