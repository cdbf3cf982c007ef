/*
 * radio_tx.h - the nRF52840 RADIO as a BLE advertiser (PS v1.7 §6.20 "RADIO - 2.4 GHz
 * radio"): one legacy advertising PDU sent on 37, 38 and 39 in turn, one advertising event
 * (Core Spec Vol 6 Part B 4.4.2: the PDUs of an event on the advertising channels, in
 * order, less than 10 ms apart). The beacon image's transmitter (beacon_app.h).
 *
 *   per channel: tune (FREQUENCY, DATAWHITEIV), PDU into the EasyDMA buffer, TXPOWER,
 *   TXEN -> [TXRU] -READY/START-> [TX] -END/DISABLE-> [DISABLED]
 *
 * The same BLE set-up as the receiver (radio_ble_configure: access address 0x8E89BED6,
 * whitening, 24-bit CRC made by the hardware). Polled, not interrupt-driven: an event
 * takes about 1.3 ms (3 x (40 us fast ramp-up + 376 us for a 39-byte PDU at 1 Mbit/s)),
 * and the beacon has nothing else to do meanwhile. A radio that does not finish within
 * RADIO_TX_SPINS polls is an error (counted by the caller), never a hang.
 */
#ifndef NRF_RADIO_TX_H
#define NRF_RADIO_TX_H

#include <stddef.h>
#include <stdint.h>

#define RADIO_TX_MAX     39u      /* a legacy advertising PDU: header 2 + AdvA 6 + AdvData 31 */
#define RADIO_TX_SPINS   100000u  /* DISABLED polls per channel: far more than 416 us */
#define RADIO_TX_ERR_ARG     -1
#define RADIO_TX_ERR_TIMEOUT -2

typedef struct radio_tx {
    /* The packet RAM the RADIO's EasyDMA reads (PACKETPTR): word aligned. */
    union { uint32_t align; uint8_t bytes[RADIO_TX_MAX]; } buf;
    uint32_t events;   /* advertising events sent */
    uint32_t timeouts; /* channels the radio did not finish on */
} radio_tx_t;

/* Powers the RADIO up for BLE advertising (the HFXO must run). */
void radio_tx_ble_start(radio_tx_t *t);

/* The TXPOWER register value for dbm: the nearest supported level at or below it
 * (+8..+2 in 1 dB steps, 0, -4, -8, -12, -16, -20, -40; PS v1.7 TXPOWER). */
uint32_t radio_tx_power(int8_t dbm);

/* Sends the PDU (header, length, payload; at most RADIO_TX_MAX bytes, its length byte
 * consistent) on 37, 38 and 39. Returns 0, RADIO_TX_ERR_ARG, or RADIO_TX_ERR_TIMEOUT. */
int32_t radio_tx_ble_event(radio_tx_t *t, const uint8_t *pdu, size_t len, int8_t tx_power_dbm);

#endif /* NRF_RADIO_TX_H */
