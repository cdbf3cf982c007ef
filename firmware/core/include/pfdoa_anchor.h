/*
 * pfdoa_anchor.h - the anchor: radio receptions in, RSSI_REPORT / STATUS / CONFIG_ACK /
 * FILTER_ACK out over UART (COBS frames) and/or CAN, CONFIG_SET and FILTER_SET in
 * (protocol/SPEC.md, version 2).
 *
 * All state lives in one pfdoa_anchor_t that the caller allocates (statically, or with
 * pfdoa_anchor_sizeof() bytes from a foreign runtime). There is no global state, no heap,
 * no floating point. One instance per radio; instances are independent.
 *
 * Radio input, two ways (both may be used by one board):
 *   - pfdoa_anchor_on_radio(): the board has matched our beacon itself and gives a reading
 *     with its sequence number; it is filter entry 0 whatever the table holds (the
 *     original entry point, kept for existing ports and RADIO_INJECT);
 *   - pfdoa_anchor_on_ble_adv() / _on_ble_pdu() / _on_802154(): the board gives what the
 *     radio received (AdvA + AdvData as BLE stacks report advertisements, a raw advertising
 *     PDU, or a raw IEEE 802.15.4 MAC frame) and the core matches it against its beacon
 *     filter table (SPEC 3.1-3.3): our beacons, iBeacon, Eddystone-UID, AltBeacon, MAC
 *     addresses, the other anchors (SPEC 3.5). Receptions that match no entry are ignored
 *     and not counted.
 *
 * Peer readings (SPEC 3.5): with an ANCHORS entry in the table, every reception of another
 * anchor's own advertisement is reported on its own (beacon 128 + that anchor's id), and,
 * given a radio to send on (pfdoa_anchor_use_peer_radio), the anchor sends its own every
 * period_ms of that entry from pfdoa_anchor_poll().
 *
 * Threading: the functions of one instance must not run concurrently. A radio driver that
 * receives in an interrupt should queue receptions and call the entry points from the
 * main loop (or mask the radio interrupt around the other calls).
 *
 * Typical main loop:
 *     pfdoa_anchor_init(&a, &hal, id, PFDOA_TRANSPORT_UART);
 *     pfdoa_anchor_use_filter_storage(&a, &storage);   (optional, protocol version 2)
 *     for (;;) { drain radio queue -> pfdoa_anchor_on_ble_adv() (or _on_radio()); uart bytes ->
 *                pfdoa_anchor_on_uart_rx(); pfdoa_anchor_poll(&a, now_ms()); }
 */
#ifndef PFDOA_ANCHOR_H
#define PFDOA_ANCHOR_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_auth.h"
#include "pfdoa_config.h"
#include "pfdoa_defs.h"
#include "pfdoa_filter.h"
#include "pfdoa_frame.h"
#include "pfdoa_hal.h"
#include "pfdoa_match.h"
#include "pfdoa_msg.h"
#include "pfdoa_peer.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Firmware version reported in STATUS (not the protocol version); a product build may set it. */
#ifndef PFDOA_FW_MAJOR
#define PFDOA_FW_MAJOR 1u
#endif
#ifndef PFDOA_FW_MINOR
#define PFDOA_FW_MINOR 0u
#endif

/* Transport bit mask for pfdoa_anchor_init. */
#define PFDOA_TRANSPORT_UART 0x01u
#define PFDOA_TRANSPORT_CAN  0x02u

/* What a radio reports with a received frame. */
typedef struct pfdoa_rx {
    uint32_t tick_ms;  /* tick at which the driver saw the frame */
    int8_t rssi_dbm;   /* raw RSSI; PFDOA_RSSI_INVALID = not available */
    uint8_t channel;   /* BLE 0..39, IEEE 802.15.4 11..26 */
    uint8_t lqi;       /* IEEE 802.15.4 link quality; anything for BLE */
} pfdoa_rx_t;

/* The state of one beacon filter entry (SPEC 3.4). */
typedef struct pfdoa_slot {
    pfdoa_filter_t filter;  /* EMA and spike run */
    pfdoa_event_t event;    /* the open event (n == 0: none) */
    pfdoa_auth_state_t auth; /* a PFDOA_AUTH entry's key schedule and counter window (SPEC 9.4) */
    pfdoa_auth_verdict_t verified; /* its last verified advertisement (counter, seq, tag) */
    uint32_t ev_counter;    /* the open event's counter (PFDOA_AUTH entries) */
    uint8_t ev_tag[PFDOA_AUTH_TAG_LEN]; /* and its tag, for the AUTH_REPORT */
    uint16_t noseq_next;    /* seq of the next event formed by time */
    uint8_t decim_count;    /* closed events since the last decimated report */
    uint8_t pending_flags;  /* flags of the events since the last report */
} pfdoa_slot_t;

/* Opaque in spirit: use the functions below, not the fields. */
typedef struct pfdoa_anchor {
    pfdoa_hal_t hal;
    pfdoa_filter_storage_t filter_storage;
    pfdoa_decoder_t decoder;
    pfdoa_config_t config;
    pfdoa_beacon_filter_t filters[PFDOA_BEACON_SLOTS];
    pfdoa_slot_t slots[PFDOA_BEACON_SLOTS];
    pfdoa_peer_radio_t peer_radio; /* send == NULL: the anchor sends no advertisement */
    uint32_t peer_tick;            /* when it sent the last one */
    uint32_t boot_tick;
    uint32_t last_status_tick;
    uint32_t reports_sent;
    uint32_t tx_failures;
    uint16_t rx_error_kind[PFDOA_ERR_COUNT]; /* index -err - 1, saturating */
    uint16_t config_hash;
    uint16_t filter_hash;
    uint16_t dropped_events;
    uint16_t rx_errors;
    uint16_t spikes;
    uint16_t auth_rejected[3]; /* PFDOA_AUTH_BAD_TAG, _STALE, _REPLAYED (index result - 2), saturating */
    uint16_t peer_seq;     /* the next advertisement's sequence number */
    uint8_t anchor_id;
    uint8_t transports;
    uint8_t status_sent;   /* 0 until the first STATUS */
    uint8_t peer_sent;     /* 0: the next poll sends the advertisement (SPEC 3.5) */
} pfdoa_anchor_t;

/* sizeof(pfdoa_anchor_t), for callers that allocate the instance themselves (ctypes). */
size_t pfdoa_anchor_sizeof(void);

/*
 * Initialises *anchor. hal is copied (NULL = no HAL at all). anchor_id 0..126;
 * transports a non-empty subset of PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN. Loads the
 * stored configuration (defaults if none or invalid), sets the first-boot filter table and
 * reads the boot tick. Returns PFDOA_OK or PFDOA_ERR_ARG (instance untouched).
 */
int32_t pfdoa_anchor_init(pfdoa_anchor_t *anchor, const pfdoa_hal_t *hal, uint8_t anchor_id, uint8_t transports);

/*
 * Gives the anchor a place to keep its beacon filter table (copied; NULL: none). Call it
 * right after pfdoa_anchor_init: it loads the stored table (kept only if every entry is
 * valid, SPEC 3.1; otherwise the table stays as it is) and from then on FILTER_SET and
 * pfdoa_anchor_set_filter store the table through it. Without storage a valid FILTER_SET
 * is applied and acked PFDOA_ACK_STORE_FAILED. Returns PFDOA_OK, or PFDOA_ERR_ARG (NULL
 * anchor).
 */
int32_t pfdoa_anchor_use_filter_storage(pfdoa_anchor_t *anchor, const pfdoa_filter_storage_t *storage);

/*
 * Gives the anchor the radio it sends its own advertisement on (copied; NULL: none, the
 * default). It sends one at the first poll after an ANCHORS entry is in the table (and after
 * every FILTER_SET or stored table applied), then every period_ms of the first ANCHORS entry.
 * Returns PFDOA_OK, or PFDOA_ERR_ARG (NULL anchor, a radio other than BLE or 802.15.4).
 */
int32_t pfdoa_anchor_use_peer_radio(pfdoa_anchor_t *anchor, const pfdoa_peer_radio_t *radio);

/*
 * One reading of our beacon that the board matched itself (filter entry 0, with its
 * sequence number): the radio driver's receive callback (BLE advertising or IEEE
 * 802.15.4). Returns PFDOA_OK, or PFDOA_ERR_ARG for a reading that is dropped (RSSI not
 * available, channel not valid for its radio, unknown radio type; counted in
 * dropped_events) or NULL.
 */
int32_t pfdoa_anchor_on_radio(pfdoa_anchor_t *anchor, const pfdoa_radio_reading_t *reading);

/*
 * A received BLE advertisement as AdvA (6 bytes, on-air order) + AdvData (what BLE stacks
 * report), a raw BLE advertising PDU (header, AdvA, AdvData), or a raw IEEE 802.15.4 MAC
 * frame without FCS, matched against the filter table. Returns 1 when it matched an entry
 * and was folded into that entry's event, 0 when it matched none (ignored, not counted),
 * PFDOA_ERR_ARG for NULL arguments or a matched reception whose reading is dropped (as for
 * pfdoa_anchor_on_radio, counted in dropped_events). Our authenticated beacon (SPEC 9) is
 * first offered to the PFDOA_AUTH entries: the one whose rolling identifier it carries
 * verifies it (1: accepted; 0: rejected, counted by reason in AUTH_STATUS); with none, the
 * other entries match it as any reception.
 */
int32_t pfdoa_anchor_on_ble_adv(pfdoa_anchor_t *anchor, const pfdoa_rx_t *rx, const uint8_t adv_a[6],
                                const uint8_t *adv_data, size_t len);
int32_t pfdoa_anchor_on_ble_pdu(pfdoa_anchor_t *anchor, const pfdoa_rx_t *rx, const uint8_t *pdu, size_t len);
int32_t pfdoa_anchor_on_802154(pfdoa_anchor_t *anchor, const pfdoa_rx_t *rx, const uint8_t *mpdu, size_t len);

/*
 * Readings the board lost before they reached the core (its radio queue was full): added
 * to dropped_events (saturating), as SPEC 1.2 counts them.
 */
int32_t pfdoa_anchor_note_dropped(pfdoa_anchor_t *anchor, uint16_t count);

/*
 * The main loop's periodic call: closes events whose time is up (BLE events of our beacon
 * open for >= 20 ms, events without a sequence number open for their entry's period), at
 * tick_ms, then sends STATUS at the first poll and every >= 1000 ms, then the anchor's own
 * advertisement when it is due (pfdoa_anchor_use_peer_radio). Poll at least every
 * few ms: the poll period adds to the report latency of events that see fewer than 3
 * readings.
 */
int32_t pfdoa_anchor_poll(pfdoa_anchor_t *anchor, uint32_t tick_ms);

/*
 * Bytes received on the UART, in any split (the decoder keeps a partial frame between
 * calls). Returns the number of frames acted on (checked, of a type this anchor knows,
 * addressed to it or to 127), or PFDOA_ERR_ARG. Rejected frames are counted in rx_errors;
 * frames for other anchors are ignored and not counted.
 */
int32_t pfdoa_anchor_on_uart_rx(pfdoa_anchor_t *anchor, const uint8_t *bytes, size_t len);

/*
 * One received CAN frame (11-bit id). The anchor's acceptance filter applies first: only
 * ids 0x180 | own id and 0x1FF (CONFIG_SET) are seen; others return 0, not counted, so
 * the controller's hardware filter may or may not be configured. Returns 1 for an
 * accepted CONFIG_SET, PFDOA_ERR_BAD_LENGTH (DLC other than 8, counted in rx_errors), or
 * PFDOA_ERR_ARG for a bad argument (NULL data with dlc > 0, id > 0x7FF; not counted).
 */
int32_t pfdoa_anchor_on_can_rx(pfdoa_anchor_t *anchor, uint16_t id, const uint8_t *data, uint8_t dlc);

/*
 * Sets filter entry `index` as a FILTER_SET would (resets that entry's state, stores the
 * table), without an ack: for boards configured locally. Returns the FILTER_ACK result
 * (PFDOA_ACK_OK, PFDOA_ACK_INVALID, PFDOA_ACK_STORE_FAILED) or PFDOA_ERR_ARG (NULL).
 */
int32_t pfdoa_anchor_set_filter(pfdoa_anchor_t *anchor, uint8_t index, const pfdoa_beacon_filter_t *filter);
int32_t pfdoa_anchor_get_filter(const pfdoa_anchor_t *anchor, uint8_t index, pfdoa_beacon_filter_t *out);

/* Counters as STATUS reports them (saturating u16). NULL gives 0. */
uint16_t pfdoa_anchor_dropped_events(const pfdoa_anchor_t *anchor);
uint16_t pfdoa_anchor_rx_errors(const pfdoa_anchor_t *anchor);
uint16_t pfdoa_anchor_spikes(const pfdoa_anchor_t *anchor);
/* Advertisements of PFDOA_AUTH entries rejected for one reason (PFDOA_AUTH_BAD_TAG, _STALE,
 * _REPLAYED; SPEC 9.4), as AUTH_STATUS reports them; 0 for other values. */
uint16_t pfdoa_anchor_auth_rejected(const pfdoa_anchor_t *anchor, int32_t reason);
/* Rejected frames with one error (a negative PFDOA_ERR_* wire error); 0 for others. */
uint16_t pfdoa_anchor_rx_error_count(const pfdoa_anchor_t *anchor, int32_t err);
/* RSSI_REPORT messages handed to the transports (each counts once); wraps. */
uint32_t pfdoa_anchor_reports_sent(const pfdoa_anchor_t *anchor);
/* HAL uart_write/can_send calls that returned an error; wraps. */
uint32_t pfdoa_anchor_tx_failures(const pfdoa_anchor_t *anchor);
/* The active configuration and its hash; the filter table's hash. */
uint16_t pfdoa_anchor_config_hash(const pfdoa_anchor_t *anchor);
int32_t pfdoa_anchor_get_config(const pfdoa_anchor_t *anchor, pfdoa_config_t *out);
uint16_t pfdoa_anchor_filter_hash(const pfdoa_anchor_t *anchor);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_ANCHOR_H */
