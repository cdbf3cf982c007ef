/*
 * nrf_test_support.h - helpers the nRF52840 port's host tests share (header-only, one
 * translation unit per test): playing the RADIO, the UARTE and the RTC on the register
 * fake, and building the packets our beacon sends.
 */
#ifndef NRF_TEST_SUPPORT_H
#define NRF_TEST_SUPPORT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "fake_nrf.h"
#include "nrf52840.h"

/* Our BLE beacon's advertising PDU in RADIO RAM layout (header, length, AdvA, AdvData):
 * ADV_NONCONN_IND with a flags AD and the manufacturer AD (0xFFFF, "PF", seq). */
static inline size_t test_ble_beacon(uint8_t *out, uint16_t seq)
{
    static const uint8_t adva[6] = { 0x11, 0x22, 0x33, 0x44, 0x55, 0xC6 };
    const uint8_t ad[] = { 0x02, 0x01, 0x06, 0x07, 0xFF, 0xFF, 0xFF, 'P', 'F',
                           (uint8_t)(seq & 0xFFu), (uint8_t)(seq >> 8) };
    out[0] = 0x42u; /* ADV_NONCONN_IND, TxAdd random */
    out[1] = (uint8_t)(6u + sizeof ad);
    memcpy(&out[2], adva, 6u);
    memcpy(&out[8], ad, sizeof ad);
    return 8u + sizeof ad;
}

/* Our 802.15.4 beacon in RADIO RAM layout: PHR, MHR (data frame, PAN id compression,
 * short addresses), "PF" + seq, then the LQI byte and one more byte where the FCS was. */
static inline size_t test_154_beacon(uint8_t *out, uint16_t seq, uint8_t lqi_val)
{
    const uint8_t mpdu[] = { 0x41, 0x88, 0x07, 0xCD, 0xAB, 0xFF, 0xFF, 0x34, 0x12, 'P', 'F',
                             (uint8_t)(seq & 0xFFu), (uint8_t)(seq >> 8) };
    out[0] = (uint8_t)(sizeof mpdu + 2u);
    memcpy(&out[1], mpdu, sizeof mpdu);
    out[1u + sizeof mpdu] = lqi_val;
    out[2u + sizeof mpdu] = 0x5Au;
    return 3u + sizeof mpdu;
}

/* A packet comes in: bytes into the RAM the driver gave PACKETPTR, the events the
 * hardware raises (READY, ADDRESS, RSSIEND when rssi_sample >= 0, END, DISABLED through
 * END_DISABLE), CRCSTATUS; then the RADIO interrupt. */
static inline void test_radio_packet(const uint8_t *ram, size_t n, int crc_ok, int rssi_sample, void (*isr)(void))
{
    uint8_t *const buf = nrf_fake_dma_ptr(NRF_RADIO->PACKETPTR);
    memcpy(buf, ram, n);
    NRF_RADIO->TASKS_RXEN = 0u;
    NRF_RADIO->EVENTS_READY = 1u;
    NRF_RADIO->EVENTS_ADDRESS = 1u;
    if (rssi_sample >= 0) {
        NRF_RADIO->RSSISAMPLE = (uint32_t)rssi_sample;
        NRF_RADIO->EVENTS_RSSIEND = 1u;
    }
    NRF_RADIO->EVENTS_END = 1u;
    NRF_RADIO->CRCSTATUS = crc_ok ? 1u : 0u;
    NRF_RADIO->EVENTS_DISABLED = 1u;
    NRF_RADIO->STATE = NRF_RADIO_STATE_DISABLED;
    isr();
}

/* The UARTE sends what the driver started: copies each DMA transfer's bytes to out
 * (cap bytes at most), raises ENDTX and calls the interrupt, until no transfer is
 * started. Returns the bytes sent. */
static inline size_t test_uarte_drain_tx(uint8_t *out, size_t cap, void (*isr)(void))
{
    size_t n = 0u;
    while (NRF_UARTE0->TASKS_STARTTX != 0u) {
        NRF_UARTE0->TASKS_STARTTX = 0u;
        const uint8_t *const src = nrf_fake_dma_ptr(NRF_UARTE0->TXD_PTR);
        const size_t len = NRF_UARTE0->TXD_MAXCNT;
        if (src != NULL && n + len <= cap) {
            memcpy(&out[n], src, len);
            n += len;
        }
        NRF_UARTE0->TXD_AMOUNT = (uint32_t)len;
        NRF_UARTE0->EVENTS_ENDTX = 1u;
        isr();
    }
    return n;
}

/* Bytes arrive on RXD: each raises RXDRDY and goes into the DMA chunk; a full chunk ends
 * (ENDRX). The interrupt runs after each byte. Returns the bytes left in a partial chunk. */
static inline uint32_t test_uarte_rx(const uint8_t *bytes, size_t n, uint32_t *filled, void (*isr)(void))
{
    for (size_t i = 0u; i < n; ++i) {
        uint8_t *const chunk = nrf_fake_dma_ptr(NRF_UARTE0->RXD_PTR);
        chunk[*filled] = bytes[i];
        *filled += 1u;
        NRF_UARTE0->EVENTS_RXDRDY = 1u;
        if (*filled == NRF_UARTE0->RXD_MAXCNT) {
            NRF_UARTE0->RXD_AMOUNT = *filled;
            NRF_UARTE0->EVENTS_ENDRX = 1u;
            *filled = 0u;
        }
        isr();
    }
    return *filled;
}

/* The UARTE answers a STOPRX (ENDRX with the partial chunk, RXTO) and then the FLUSHRX
 * (ENDRX with what the FIFO held: fifo bytes). */
static inline void test_uarte_stop_flush(uint32_t *filled, const uint8_t *fifo, size_t fifo_n, void (*isr)(void))
{
    NRF_UARTE0->TASKS_STOPRX = 0u;
    NRF_UARTE0->RXD_AMOUNT = *filled;
    NRF_UARTE0->EVENTS_ENDRX = 1u;
    NRF_UARTE0->EVENTS_RXTO = 1u;
    *filled = 0u;
    isr();
    if (NRF_UARTE0->TASKS_FLUSHRX != 0u) {
        NRF_UARTE0->TASKS_FLUSHRX = 0u;
        uint8_t *const chunk = nrf_fake_dma_ptr(NRF_UARTE0->RXD_PTR);
        if (fifo_n > 0u) {
            memcpy(chunk, fifo, fifo_n);
        }
        NRF_UARTE0->RXD_AMOUNT = (uint32_t)fifo_n;
        NRF_UARTE0->EVENTS_ENDRX = 1u;
        isr();
    }
}

/* RTC ticks (1/32768 s) of a millisecond time, the smallest count that reads as ms. */
static inline uint64_t test_rtc_ticks_of_ms(uint64_t ms)
{
    return (ms * 32768u + 999u) / 1000u;
}

#endif /* NRF_TEST_SUPPORT_H */
