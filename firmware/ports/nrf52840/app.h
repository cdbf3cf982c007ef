/*
 * app.h - the anchor on the nRF52840: the portable core (firmware/core) behind this
 * board's HAL, fed by the radio driver, reporting on the UART or (NRF_LINK_CAN) the
 * MCP2515. main() is app_init() then app_step() + app_idle() forever; the host tests
 * drive the same functions against the register fakes.
 *
 * Radio path: the RADIO interrupt queues the packets that match the anchor's beacon
 * filter table (pfdoa_match_ble_pdu / pfdoa_match_802154 on a copy of the core's table,
 * so the queue holds only configured beacons and a full queue is a loss of readings,
 * counted as the core's dropped_events); the main loop hands each queued packet, raw, to
 * pfdoa_anchor_on_ble_pdu / pfdoa_anchor_on_802154, which match and parse it again in
 * the core. The copy is refreshed, interrupts masked, at boot and after every host frame
 * the core acted on (FILTER_SET is the only way the table changes).
 *
 * Host link: the UART image reports, and takes CONFIG_SET / FILTER_SET, on UARTE0 (the
 * DK's virtual COM port). The CAN image reports on CAN and takes CONFIG_SET there, and
 * still listens on UARTE0 for CONFIG_SET and FILTER_SET (FILTER_SET has no CAN mapping,
 * SPEC 4), acked on the UART.
 */
#ifndef NRF_APP_H
#define NRF_APP_H

#include <stdint.h>

#include "board.h"
#include "clock.h"
#include "pfdoa_anchor.h"
#include "radio.h"
#include "rtc_tick.h"
#include "uarte.h"
#if NRF_LINK_CAN
#include "mcp2515.h"
#include "spim.h"
#endif

#define APP_WAKE_BUSY_MS 2u   /* an event may close soon, a UART chunk or a CAN frame waits */
#define APP_WAKE_IDLE_MS 100u /* STATUS goes out at most this late */
#define APP_BUSY_AFTER_READING_MS 40u /* 2 x the core's 20 ms event timeout; longer with */
                                      /* entries whose events close after their period */
#define APP_CAN_SERVICE_MS 100u /* error counters read at least this often */

typedef enum app_status {
    APP_OK = 0,
    APP_ERR_HFXO = 1,     /* no 64 MHz crystal: radio off, STATUS still sent */
    APP_ERR_LINK = 2,     /* the MCP2515 did not come up */
    APP_ERR_ANCHOR = 3
} app_status_t;

typedef struct app {
    pfdoa_anchor_t anchor;
    /* The filter table the RADIO interrupt matches against (a copy of the core's). */
    pfdoa_beacon_filter_t filters[PFDOA_BEACON_SLOTS];
    rtc_tick_t tick;
    clock_cal_t cal;
    radio_t radio;
    uarte_t uart;               /* the host link, or (CAN image) the configuration port */
#if NRF_LINK_CAN
    spim_t spim;
    mcp2515_t can;
    volatile uint8_t can_irq;   /* GPIOTE saw INT fall */
    uint32_t can_serviced_ms;
#endif
    uint32_t busy_after_reading_ms; /* short sleeps this long after a reading: an event may close */
    uint8_t auth_entries;       /* PFDOA_AUTH entries in filters: queue SPEC 9 advertisements */
    uint32_t lost_noted;        /* radio.queue_full already given to the core */
    uint32_t last_reading_ms;
    uint32_t readings;          /* receptions the core matched (folded, or dropped and counted) */
    uint32_t ignored;           /* receptions the core matched to no entry (its table changed meanwhile) */
    uint8_t id;
    uint8_t status;             /* app_status_t */
} app_t;

/* The one instance (interrupt handlers take no arguments). */
app_t *app_get(void);

/* Clocks, tick, host link, anchor core, radio, interrupts. Returns app_status_t. */
int32_t app_init(void);

/* One pass of the main loop: packets -> core, host bytes/frames -> core, poll. */
void app_step(void);

/* Sleeps until the next interrupt unless work is already waiting; arms the RTC wake-up. */
void app_idle(void);

/* The anchor id: UICR.CUSTOMER[0] when it holds 0..126, else NRF_ANCHOR_ID. */
uint8_t app_anchor_id(void);

/* Interrupt handlers (the vector table's). */
void RADIO_IRQHandler(void);
void UARTE0_UART0_IRQHandler(void);
void GPIOTE_IRQHandler(void);
void RTC1_IRQHandler(void);

#endif /* NRF_APP_H */
