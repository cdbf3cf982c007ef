#include "spim.h"

#include <string.h>

void spim_init(spim_t *const s, const uint32_t psel_sck, const uint32_t psel_mosi, const uint32_t psel_miso,
               nrf_gpio_t *const cs_port, const uint32_t cs_pin)
{
    nrf_spim_t *const hw = NRF_SPIM2;
    s->cs_port = cs_port;
    s->cs_pin = cs_pin;
    s->timeouts = 0u;
    cs_port->OUTSET = 1u << cs_pin;
    cs_port->PIN_CNF[cs_pin] = NRF_GPIO_CNF_OUTPUT;
    hw->ENABLE = 0u;
    hw->PSEL_SCK = psel_sck;
    hw->PSEL_MOSI = psel_mosi;
    hw->PSEL_MISO = psel_miso;
    hw->FREQUENCY = NRF_SPIM_FREQ_4M; /* the MCP2515 takes up to 10 MHz */
    hw->CONFIG = NRF_SPIM_CONFIG_MODE0;
    hw->ORC = 0xFFu;
    hw->ENABLE = NRF_SPIM_ENABLE;
}

int32_t spim_xfer(void *const ctx, const uint8_t *const tx, uint8_t *const rx, const size_t len)
{
    spim_t *const s = ctx;
    nrf_spim_t *const hw = NRF_SPIM2;
    /* EasyDMA reads RAM only: the bytes go out from here, whatever tx points to. */
    uint8_t txb[SPIM_MAX_XFER];
    uint8_t rxb[SPIM_MAX_XFER] = { 0 }; /* written by EasyDMA */
    if (s == NULL || tx == NULL || len == 0u || len > SPIM_MAX_XFER) {
        return SPIM_ERR_ARG;
    }
    memcpy(txb, tx, len);
    hw->TXD_PTR = NRF_DMA_ADDR(txb);
    hw->TXD_MAXCNT = (uint32_t)len;
    hw->RXD_PTR = NRF_DMA_ADDR(rxb);
    hw->RXD_MAXCNT = (uint32_t)len;
    hw->EVENTS_END = 0u;
    s->cs_port->OUTCLR = 1u << s->cs_pin;
    hw->TASKS_START = 1u;
    uint32_t spins = SPIM_SPINS;
    while (hw->EVENTS_END == 0u && spins > 0u) {
        NRF_SPIN();
        --spins;
    }
    int32_t rc = SPIM_OK;
    if (hw->EVENTS_END == 0u) {
        hw->EVENTS_STOPPED = 0u;
        hw->TASKS_STOP = 1u;
        s->timeouts++;
        rc = SPIM_ERR_TIMEOUT;
    }
    hw->EVENTS_END = 0u;
    s->cs_port->OUTSET = 1u << s->cs_pin;
    if (rc == SPIM_OK && rx != NULL) {
        memcpy(rx, rxb, len);
    }
    return rc;
}
