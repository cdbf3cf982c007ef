/*
 * beacon_app.h - the robot's beacon on the nRF52840: our authenticated rolling beacon
 * (protocol/SPEC.md 9, firmware/beacon with cfg.auth) advertising over BLE through the
 * RADIO as a transmitter (radio_tx.h), provisioned over UARTE0. main() (main_beacon.c) is
 * beacon_app_init() then beacon_app_step() + beacon_app_idle() forever; the host tests
 * drive the same functions against the register fake.
 *
 * Provisioning, one ASCII line each way on UARTE0 (115200 8N1, the DK's virtual COM port;
 * `pfdoa anchors beacon` speaks it), lines end with '\n' ('\r' ignored):
 *
 *   K <32 hex digits>       the key: kept in flash (the filter-table page, which a beacon
 *                           does not use), answered "OK K <key check, 8 hex>"
 *   T <counter> <phase_ms>  the time: the counter now (floor(Unix ms / 4096)) and the ms
 *                           into its period (0..4095); answered "OK T <counter>"
 *   S                       answered "S <key check or -> <counter or -> <sent> <failures>"
 *
 * anything else, or a line longer than BEACON_LINE_MAX, is answered "ERR <why>". The key is
 * never echoed. Without a key and the time the beacon sends nothing (a counter it made up
 * would be rejected by every anchor, and could link it). A power cycle keeps the key and
 * loses the time: the host sets it again (and at least every day or two: SPEC 9.7).
 */
#ifndef NRF_BEACON_APP_H
#define NRF_BEACON_APP_H

#include <stdint.h>

#include "board.h"
#include "pfdoa_beacon.h"
#include "radio_tx.h"
#include "rtc_tick.h"
#include "uarte.h"

#ifndef NRF_BEACON_INTERVAL_MS
#define NRF_BEACON_INTERVAL_MS 100u
#endif
#ifndef NRF_BEACON_TX_POWER_DBM
#define NRF_BEACON_TX_POWER_DBM 0
#endif

#define BEACON_LINE_MAX 48u  /* "K " + 32 hex digits, "T" + two u32, with room */

typedef enum beacon_status {
    BEACON_OK = 0,
    BEACON_ERR_HFXO = 1,     /* no 64 MHz crystal: the radio stays off, provisioning still works */
    BEACON_ERR_BEACON = 2
} beacon_status_t;

typedef struct beacon_app {
    pfdoa_beacon_t beacon;
    rtc_tick_t tick;
    radio_tx_t tx;
    uarte_t uart;
    char line[BEACON_LINE_MAX + 1u];
    uint8_t line_len;
    uint8_t overlong;        /* the line being read is too long: discard to its end */
    uint8_t have_key;
    uint8_t key_check[4];
    uint8_t radio_ok;
    int32_t status;
    uint32_t commands;       /* lines acted on */
    uint32_t refused;        /* lines answered ERR */
} beacon_app_t;

int32_t beacon_app_init(void);
void beacon_app_step(void);
void beacon_app_idle(void);
beacon_app_t *beacon_app_get(void);

/* The interrupt handlers startup.c's vector table names (those of app.h). */
void RADIO_IRQHandler(void);
void UARTE0_UART0_IRQHandler(void);
void GPIOTE_IRQHandler(void);
void RTC1_IRQHandler(void);

#endif /* NRF_BEACON_APP_H */
