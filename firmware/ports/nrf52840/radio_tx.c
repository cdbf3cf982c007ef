#include "radio_tx.h"

#include <string.h>

#include "nrf52840.h"
#include "radio.h"

void radio_tx_ble_start(radio_tx_t *const t)
{
    nrf_radio_t *const hw = NRF_RADIO;
    memset(t, 0, sizeof *t);
    hw->POWER = 0u;
    hw->POWER = 1u;
    hw->INTENCLR = 0xFFFFFFFFu;
    hw->MODECNF0 = NRF_RADIO_MODECNF0_RU_FAST; /* 40 us ramp-up instead of 140 */
    radio_ble_configure();
    hw->SHORTS = NRF_RADIO_SHORT_READY_START | NRF_RADIO_SHORT_END_DISABLE;
    hw->PACKETPTR = NRF_DMA_ADDR(t->buf.bytes);
}

uint32_t radio_tx_power(const int8_t dbm)
{
    /* Two's complement values of the register (PS v1.7 RADIO TXPOWER), highest first. */
    static const int8_t levels[] = { 8, 7, 6, 5, 4, 3, 2, 0, -4, -8, -12, -16, -20, -40 };
    for (size_t i = 0u; i < sizeof levels; ++i) {
        if (dbm >= levels[i]) {
            return (uint32_t)(uint8_t)levels[i];
        }
    }
    return (uint32_t)(uint8_t)levels[sizeof levels - 1u];
}

int32_t radio_tx_ble_event(radio_tx_t *const t, const uint8_t *const pdu, const size_t len, const int8_t tx_power_dbm)
{
    if (t == NULL || pdu == NULL || len < 2u || len > RADIO_TX_MAX || (size_t)pdu[1] + 2u != len) {
        return RADIO_TX_ERR_ARG;
    }
    nrf_radio_t *const hw = NRF_RADIO;
    memcpy(t->buf.bytes, pdu, len);
    hw->TXPOWER = radio_tx_power(tx_power_dbm);
    int32_t rc = 0;
    for (uint8_t ch = 37u; ch <= 39u; ++ch) {
        radio_ble_tune(ch);
        hw->EVENTS_END = 0u;
        hw->EVENTS_DISABLED = 0u;
        hw->TASKS_TXEN = 1u;
        uint32_t i = 0u;
        while (hw->EVENTS_DISABLED == 0u && i < RADIO_TX_SPINS) {
            NRF_SPIN();
            ++i;
        }
        if (hw->EVENTS_DISABLED == 0u) {
            t->timeouts = t->timeouts + 1u;
            hw->TASKS_DISABLE = 1u;
            /* The next channel's TXEN only from DISABLED: wait for the forced one (bounded). */
            for (i = 0u; hw->EVENTS_DISABLED == 0u && i < RADIO_TX_SPINS; ++i) {
                NRF_SPIN();
            }
            rc = RADIO_TX_ERR_TIMEOUT;
        }
    }
    hw->EVENTS_END = 0u;
    hw->EVENTS_DISABLED = 0u;
    if (rc == 0) {
        t->events = t->events + 1u;
    }
    return rc;
}
