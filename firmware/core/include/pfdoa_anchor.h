/*
 * pfdoa_anchor.h - the anchor: radio readings in, RSSI_REPORT / STATUS / CONFIG_ACK out
 * over UART (COBS frames) and/or CAN, CONFIG_SET in (protocol/SPEC.md).
 *
 * All state lives in one pfdoa_anchor_t that the caller allocates (statically, or with
 * pfdoa_anchor_sizeof() bytes from a foreign runtime). There is no global state, no heap,
 * no floating point. One instance per radio; instances are independent.
 *
 * Threading: the functions of one instance must not run concurrently. A radio driver that
 * receives in an interrupt should queue readings and call pfdoa_anchor_on_radio() from
 * the main loop (or mask the radio interrupt around the other calls).
 *
 * Typical main loop:
 *     pfdoa_anchor_init(&a, &hal, id, PFDOA_TRANSPORT_UART);
 *     for (;;) { drain radio queue -> pfdoa_anchor_on_radio(); uart bytes ->
 *                pfdoa_anchor_on_uart_rx(); pfdoa_anchor_poll(&a, now_ms()); }
 */
#ifndef PFDOA_ANCHOR_H
#define PFDOA_ANCHOR_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_config.h"
#include "pfdoa_defs.h"
#include "pfdoa_filter.h"
#include "pfdoa_frame.h"
#include "pfdoa_hal.h"
#include "pfdoa_msg.h"

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

/* Opaque in spirit: use the functions below, not the fields. */
typedef struct pfdoa_anchor {
    pfdoa_hal_t hal;
    pfdoa_decoder_t decoder;
    pfdoa_config_t config;
    pfdoa_filter_t filter;
    pfdoa_event_t event;
    uint32_t boot_tick;
    uint32_t last_status_tick;
    uint32_t reports_sent;
    uint32_t tx_failures;
    uint16_t rx_error_kind[PFDOA_ERR_COUNT]; /* index -err - 1, saturating */
    uint16_t config_hash;
    uint16_t dropped_events;
    uint16_t rx_errors;
    uint16_t spikes;
    uint8_t anchor_id;
    uint8_t transports;
    uint8_t status_sent;   /* 0 until the first STATUS */
    uint8_t decim_count;   /* closed events since the last decimated report */
    uint8_t pending_flags; /* flags of the events since the last report */
} pfdoa_anchor_t;

/* sizeof(pfdoa_anchor_t), for callers that allocate the instance themselves (ctypes). */
size_t pfdoa_anchor_sizeof(void);

/*
 * Initialises *anchor. hal is copied (NULL = no HAL at all). anchor_id 0..126;
 * transports a non-empty subset of PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN. Loads the
 * stored configuration (defaults if none or invalid) and reads the boot tick.
 * Returns PFDOA_OK or PFDOA_ERR_ARG (instance untouched).
 */
int32_t pfdoa_anchor_init(pfdoa_anchor_t *anchor, const pfdoa_hal_t *hal, uint8_t anchor_id, uint8_t transports);

/*
 * The radio driver's receive callback: one reading (BLE advertising or IEEE 802.15.4).
 * Returns PFDOA_OK, or PFDOA_ERR_ARG for a reading that is dropped (RSSI not available,
 * channel not valid for its radio, unknown radio type; counted in dropped_events) or NULL.
 */
int32_t pfdoa_anchor_on_radio(pfdoa_anchor_t *anchor, const pfdoa_radio_reading_t *reading);

/*
 * Readings the board lost before they reached pfdoa_anchor_on_radio() (its radio queue
 * was full): added to dropped_events (saturating), as SPEC 1.2 counts them.
 */
int32_t pfdoa_anchor_note_dropped(pfdoa_anchor_t *anchor, uint16_t count);

/*
 * The main loop's periodic call: closes a BLE event open for >= 20 ms (at tick_ms), then
 * sends STATUS at the first poll and every >= 1000 ms. Poll at least every few ms: the
 * poll period adds to the report latency of events that see fewer than 3 readings.
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

/* Counters as STATUS reports them (saturating u16). NULL gives 0. */
uint16_t pfdoa_anchor_dropped_events(const pfdoa_anchor_t *anchor);
uint16_t pfdoa_anchor_rx_errors(const pfdoa_anchor_t *anchor);
uint16_t pfdoa_anchor_spikes(const pfdoa_anchor_t *anchor);
/* Rejected frames with one error (a negative PFDOA_ERR_* wire error); 0 for others. */
uint16_t pfdoa_anchor_rx_error_count(const pfdoa_anchor_t *anchor, int32_t err);
/* RSSI_REPORT messages handed to the transports (each counts once); wraps. */
uint32_t pfdoa_anchor_reports_sent(const pfdoa_anchor_t *anchor);
/* HAL uart_write/can_send calls that returned an error; wraps. */
uint32_t pfdoa_anchor_tx_failures(const pfdoa_anchor_t *anchor);
/* The active configuration and its hash. */
uint16_t pfdoa_anchor_config_hash(const pfdoa_anchor_t *anchor);
int32_t pfdoa_anchor_get_config(const pfdoa_anchor_t *anchor, pfdoa_config_t *out);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_ANCHOR_H */
