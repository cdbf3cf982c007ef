/*
 * radio.h - the nRF52840 RADIO as a receiver (PS v1.7 §6.20 "RADIO - 2.4 GHz radio"):
 * BLE 1 Mbit advertising on channels 37/38/39, or IEEE 802.15.4 on one channel 11..26.
 *
 * State machine (SHORTS do the fast steps in hardware, the DISABLED interrupt the rest):
 *
 *   RXEN -> [RXRU] -READY/START-> [RX: listening] -ADDRESS/RSSISTART-> [RX: receiving]
 *        -END/DISABLE-> [DISABLED] -> radio_isr: packet? CRC ok? -> queue; hop? -> RXEN
 *
 * - BLE: access address 0x8E89BED6, data whitening seeded with the channel index, 24-bit
 *   CRC (poly 0x00065B, init 0x555555) checked by the hardware; RSSI sampled on every
 *   packet (ADDRESS->RSSISTART, RSSISAMPLE after RSSIEND): -RSSISAMPLE dBm.
 * - Channel hopping (BLE): radio_hop(), called by the RTC's hop timer every
 *   RADIO_BLE_DWELL_MS, moves 37 -> 38 -> 39 -> 37. While listening it disables the radio
 *   at once (the DISABLED interrupt retunes); while a packet is coming in (ADDRESS seen) it
 *   waits for that packet's END, so no packet is cut.
 * - Hop on a hit (BLE): a packet the accept hook takes moves the radio to the next
 *   advertising channel at once, in the same DISABLED interrupt, and the hopped hook lets
 *   the hop timer start a new dwell there. An advertiser sends one advertising event on
 *   37, 38 and 39 within a few ms (Core spec Vol 6 Part B 4.4.2.1: less than 10 ms
 *   between the PDUs of one event), so the event's other channels are caught too; without
 *   a hit the radio dwells as above.
 * - IEEE 802.15.4: 250 kbit/s O-QPSK, SFD 0xA7, 16-bit FCS (poly 0x11021, init 0) checked
 *   by the hardware. The RADIO writes a link quality byte where the FCS was; its hardware
 *   value VAL gives the received power P[dBm] = ED_RSSIOFFS + VAL, ED_RSSIOFFS = -92 dBm,
 *   and the 802.15.4 LQI = min(ED_RSSISCALE x VAL, 255), ED_RSSISCALE = 4 (PS v1.7
 *   §6.20.12 "IEEE 802.15.4 operation", energy detection and LQI, with the conversion as
 *   corrected by nRF52840 errata anomaly 236: the PS's "ED_RSSIOFFS + ED_RSSISCALE x VAL"
 *   for dBm is wrong).
 * - A packet with a failed CRC is counted (crc_errors) and dropped. A good one the accept
 *   hook takes is copied whole with its tick, RSSI and channel into a queue of
 *   RADIO_QUEUE packets that the main loop pops; a full queue drops it (queue_full). A
 *   packet longer than RADIO_PKT_MAX (only BLE PDUs beyond a legacy advertisement's 39
 *   bytes can be) is rejected, never cut: a cut frame could parse as something it is not.
 *
 * - Sending (the anchor's own advertisement, protocol/SPEC.md 3.5, 6.1): radio_send() from
 *   the main loop hands over one frame; the next DISABLED interrupt (at once while
 *   listening: radio_send disables the radio; after the packet in progress otherwise) sends
 *   it instead of listening, a BLE PDU on 37, 38 and 39 in turn (one advertising event), an
 *   802.15.4 frame once on the channel listened to (the radio appends the FCS), then listens
 *   again on the channel it left (a hop that fell due meanwhile is done then). The RX
 *   packet RAM stays the receiver's; the frame has its own.
 *
 * radio_isr and radio_hop must run at the same interrupt priority (they never preempt
 * each other); radio_pop and radio_send run in the main loop.
 */
#ifndef NRF_RADIO_DRV_H
#define NRF_RADIO_DRV_H

#include <stddef.h>
#include <stdint.h>

#define RADIO_QUEUE          8u   /* power of two */
#define RADIO_PKT_MAX        125u /* an 802.15.4 MPDU without FCS (127 - 2); a legacy advertising PDU is 2 + 37 */
#define RADIO_BUF_SIZE       260u /* BLE: S0 + LENGTH + 255; 802.15.4: PHR + 127 */
#define RADIO_BLE_DWELL_MS   30u  /* per advertising channel: longer than a 20 ms interval */
#define RADIO_BLE_ACCESS_ADDRESS 0x8E89BED6u
#define RADIO_ED_RSSIOFFS    (-92)
#define RADIO_ED_RSSISCALE   4
#define RADIO_RSSI_NONE      127  /* no RSSI sample: PFDOA_RSSI_INVALID */
#define RADIO_TX_MAX         39u  /* a frame radio_send takes: a legacy advertising PDU (2 + 37) */

typedef enum radio_mode {
    RADIO_MODE_BLE = 0,        /* = PFDOA_RADIO_BLE */
    RADIO_MODE_IEEE802154 = 1  /* = PFDOA_RADIO_IEEE802154 */
} radio_mode_t;

/* One received packet, as it came off the air. */
typedef struct radio_packet {
    uint32_t tick_ms;           /* at the END of the packet */
    uint8_t data[RADIO_PKT_MAX];/* BLE: PDU header, length, AdvA, AdvData; 802.15.4: MPDU without FCS */
    uint8_t len;                /* bytes in data */
    int8_t rssi_dbm;            /* RADIO_RSSI_NONE without a sample */
    uint8_t channel;            /* BLE 37..39, 802.15.4 11..26 */
    uint8_t lqi;                /* 802.15.4 LQI 0..255; 0 for BLE */
    uint8_t mode;               /* radio_mode_t */
} radio_packet_t;

/* What the driver calls (each may be NULL); ctx is passed back. now_ms and accept run in
 * the RADIO interrupt, hopped too. */
typedef struct radio_hooks {
    uint32_t (*now_ms)(void *ctx);  /* the tick stamped on packets (NULL: 0) */
    /* Which good packets to queue (NULL: all). A BLE packet it takes is a hit: hop at once. */
    int (*accept)(const radio_packet_t *pkt, void *ctx);
    /* The driver hopped by itself after a hit: restart the dwell timer. */
    void (*hopped)(void *ctx);
    void *ctx;
} radio_hooks_t;

typedef struct radio {
    /* The packet RAM the RADIO's EasyDMA writes (PACKETPTR): word aligned. */
    union { uint32_t align; uint8_t bytes[RADIO_BUF_SIZE]; } buf;
    /* The frame being sent (radio_send): BLE as the PDU is in RAM, 802.15.4 PHR + MPDU. */
    union { uint32_t align; uint8_t bytes[RADIO_TX_MAX + 1u]; } tx;
    radio_packet_t queue[RADIO_QUEUE];
    volatile uint32_t q_head;       /* written by radio_isr */
    volatile uint32_t q_tail;       /* written by radio_pop */
    radio_hooks_t hooks;
    uint8_t mode;
    uint8_t channel;                /* the channel listened to now */
    volatile uint8_t hop_pending;
    volatile uint32_t packets;      /* CRC ok */
    volatile uint32_t crc_errors;
    volatile uint32_t rejected;     /* CRC ok, not accepted (or malformed or too long) */
    volatile uint32_t queue_full;   /* accepted but dropped: the queue was full */
    volatile uint32_t hops;         /* all hops */
    volatile uint32_t hit_hops;     /* of them, at once after a hit */
    volatile uint8_t tx_left;       /* transmissions of the frame still to make (0: none) */
    volatile uint8_t txing;         /* the radio is sending (the next DISABLED ends it) */
    uint8_t tx_channel;             /* BLE: the advertising channel being sent on */
    volatile uint32_t sent;         /* transmissions made (a BLE advertising event is 3) */
} radio_t;

/* Starts continuous BLE advertising reception on channel 37. The HFXO must run. hooks is
 * copied (NULL: none). */
void radio_start_ble(radio_t *r, const radio_hooks_t *hooks);

/* Starts continuous IEEE 802.15.4 reception on channel 11..26. Returns 0, or -1 for a bad
 * channel (nothing started). */
int32_t radio_start_ieee802154(radio_t *r, uint8_t channel, const radio_hooks_t *hooks);

/* BLE 1 Mbit advertising, receive or transmit alike: mode, packet layout, access address,
 * CRC (radio_start_ble and the transmitter of radio_tx.h share it); and tuning to one
 * advertising channel (frequency and whitening seed). */
void radio_ble_configure(void);
void radio_ble_tune(uint8_t channel);

/* The next advertising channel after ch (37 -> 38 -> 39 -> 37). */
uint8_t radio_ble_next_channel(uint8_t ch);

/* RADIO FREQUENCY register value (MHz above 2400) of a BLE or 802.15.4 channel; 0xFF for
 * a channel this driver does not listen on. */
uint8_t radio_frequency(radio_mode_t mode, uint8_t channel);

/* The hop timer's callback (BLE only): move to the next advertising channel. */
void radio_hop(radio_t *r);

/* Body of RADIO_IRQHandler (the DISABLED interrupt). */
void radio_isr(radio_t *r);

/* Sends one frame (see the header comment): a BLE advertising PDU (header, length, AdvA,
 * AdvData; 2..RADIO_TX_MAX bytes, its length byte the rest) or an IEEE 802.15.4 MAC frame
 * without FCS (1..RADIO_TX_MAX - 1 bytes). Returns 0, or -1 when the radio is not started,
 * a frame is still being sent, or this one does not fit. Main loop only. */
int32_t radio_send(radio_t *r, const uint8_t *frame, size_t len);

/* Pops the oldest queued packet into *out: 1, or 0 when the queue is empty. */
int radio_pop(radio_t *r, radio_packet_t *out);

/* True when packets wait. */
int radio_pending(const radio_t *r);

/* 802.15.4: the link quality byte's hardware value to dBm and to an 802.15.4 LQI. */
int8_t radio_ieee802154_dbm(uint8_t val);
uint8_t radio_ieee802154_lqi(uint8_t val);

#endif /* NRF_RADIO_DRV_H */
