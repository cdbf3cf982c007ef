/*
 * nrf_test_support.h - helpers the nRF52840 port's host tests share (header-only, one
 * translation unit per test): playing the RADIO, the UARTE and the RTC on the register
 * fake, and building the packets beacons send.
 */
#ifndef NRF_TEST_SUPPORT_H
#define NRF_TEST_SUPPORT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "fake_nrf.h"
#include "nrf52840.h"
#include "pfdoa_beacon.h"
#include "radio.h"

/* What our beacon sends (firmware/beacon, SPEC 6), in RADIO RAM layout. BLE: the
 * ADV_NONCONN_IND PDU (header, length, AdvA, AdvData = flags + the manufacturer AD with
 * seq and beacon id). */
static inline size_t test_ble_beacon(uint8_t *out, uint16_t seq, uint8_t beacon_id)
{
    static const uint8_t adva[6] = { 0x11, 0x22, 0x33, 0x44, 0x55, 0xC6 };
    const int32_t n = pfdoa_beacon_adv_pdu(adva, seq, beacon_id, out, 64u);
    return (n > 0) ? (size_t)n : 0u;
}

/* 802.15.4: PHR, the beacon's MAC frame (data frame, PAN id compression, to the broadcast
 * short address from its extended address, "PF" seq id), then the LQI byte and one more
 * byte where the FCS was. */
static inline size_t test_154_beacon(uint8_t *out, uint16_t seq, uint8_t beacon_id, uint8_t lqi_val)
{
    static const uint8_t ext[8] = { 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08 };
    const int32_t n = pfdoa_beacon_mpdu(ext, 0xABCDu, seq, beacon_id, &out[1], 127u);
    if (n <= 0) {
        return 0u;
    }
    out[0] = (uint8_t)(n + 2);
    out[1u + (size_t)n] = lqi_val;
    out[2u + (size_t)n] = 0x5Au;
    return 3u + (size_t)n;
}

/* An iBeacon's advertising PDU (Apple Proximity Beacon: manufacturer data 4C 00 02 15,
 * UUID 00 01 .. 0F, major, minor big-endian, measured power), ADV_NONCONN_IND. */
static inline size_t test_ibeacon(uint8_t *out, uint16_t major, uint16_t minor)
{
    static const uint8_t adva[6] = { 0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xE6 };
    uint8_t ad[3u + 27u] = { 0x02, 0x01, 0x06, 0x1A, 0xFF, 0x4C, 0x00, 0x02, 0x15 };
    for (uint8_t k = 0u; k < 16u; ++k) {
        ad[9u + k] = k;
    }
    ad[25] = (uint8_t)(major >> 8);
    ad[26] = (uint8_t)major;
    ad[27] = (uint8_t)(minor >> 8);
    ad[28] = (uint8_t)minor;
    ad[29] = 0xC5u; /* -59 dBm at 1 m */
    out[0] = 0x42u;  /* ADV_NONCONN_IND, TxAdd random */
    out[1] = (uint8_t)(6u + sizeof ad);
    memcpy(&out[2], adva, 6u);
    memcpy(&out[8], ad, sizeof ad);
    return 8u + sizeof ad;
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

/* A packet on the air on a channel: the radio hears it only when it listens there (RXEN
 * given, no DISABLE pending, FREQUENCY tuned to that channel); then as test_radio_packet.
 * Returns 1 when heard, 0 when the radio was elsewhere (nothing happens). */
static inline int test_radio_on_air(const uint8_t *ram, size_t n, radio_mode_t mode, uint8_t channel, int crc_ok,
                                    int rssi_sample, void (*isr)(void))
{
    if (NRF_RADIO->TASKS_RXEN == 0u || NRF_RADIO->TASKS_DISABLE != 0u
        || NRF_RADIO->FREQUENCY != radio_frequency(mode, channel)) {
        return 0;
    }
    test_radio_packet(ram, n, crc_ok, rssi_sample, isr);
    return 1;
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
