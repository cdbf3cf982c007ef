#include "app.h"

#include <string.h>

#include "cortexm.h"
#include "flash_store.h"

/* Interrupt handlers take no arguments: the one file-scope instance of the port. The core
 * keeps all of its own state in app.anchor. */
static app_t app;

typedef char anchor_id_in_range[(NRF_ANCHOR_ID <= PFDOA_ANCHOR_ID_MAX) ? 1 : -1];

app_t *app_get(void)
{
    return &app;
}

uint8_t app_anchor_id(void)
{
    const uint32_t v = NRF_UICR_CUSTOMER0;
    return (v <= PFDOA_ANCHOR_ID_MAX) ? (uint8_t)v : (uint8_t)NRF_ANCHOR_ID;
}

/* ---- HAL adapters ---- */

static uint32_t now_ms(void *ctx)
{
    return rtc_tick_ms(&((app_t *)ctx)->tick);
}

typedef char config_fits_its_log[(PFDOA_CONFIG_LEN <= FLASH_STORE_CONFIG_MAX) ? 1 : -1];
typedef char filter_table_fits_its_log[(PFDOA_FILTER_TABLE_LEN <= FLASH_STORE_FILTERS_MAX) ? 1 : -1];

static int32_t hal_config_load(void *ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    return flash_store_load(FLASH_LOG_CONFIG, out, PFDOA_CONFIG_LEN);
}

static int32_t hal_config_store(void *ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    return flash_store_save(FLASH_LOG_CONFIG, config, PFDOA_CONFIG_LEN);
}

static int32_t filters_load(void *ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    return flash_store_load(FLASH_LOG_FILTERS, out, PFDOA_FILTER_TABLE_LEN);
}

static int32_t filters_store(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    return flash_store_save(FLASH_LOG_FILTERS, table, PFDOA_FILTER_TABLE_LEN);
}

/* Both images write to the UART: the UART image everything, the CAN image the acks of what
 * came in on the UART (the core sends reports and STATUS only on the transport given to
 * pfdoa_anchor_init). */
static int32_t hal_uart_write(void *ctx, const uint8_t *bytes, size_t len)
{
    return uarte_write(&((app_t *)ctx)->uart, bytes, len);
}

#if NRF_LINK_CAN
static int32_t hal_can_send(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    return (mcp2515_send(&((app_t *)ctx)->can, id, data, dlc) == MCP2515_OK) ? 0 : -1;
}
#define HAL_CAN hal_can_send
#define TRANSPORT PFDOA_TRANSPORT_CAN
#else
#define HAL_CAN NULL
#define TRANSPORT PFDOA_TRANSPORT_UART
#endif

static const pfdoa_hal_t hal = {
    .ctx = &app,
    .tick_ms = now_ms,
    .uart_write = hal_uart_write,
    .can_send = HAL_CAN,
    .config_load = hal_config_load,
    .config_store = hal_config_store,
};

/* The beacon filter table (FILTER_SET) in its own flash log, next to the configuration. */
static const pfdoa_filter_storage_t filter_storage = { NULL, filters_load, filters_store };

/* ---- radio hooks (RADIO interrupt) ---- */

/* Queue only what matches the table: the core will match it again, from the main loop.
 * Our authenticated beacon's advertisements (SPEC 9) are queued when the table has a
 * PFDOA_AUTH entry, unverified: the core verifies them (and counts the rejections) there,
 * not in this interrupt. */
static int radio_accept(const radio_packet_t *const pkt, void *const ctx)
{
    const app_t *const a = ctx;
    pfdoa_match_t m;
    const uint8_t *payload;
    const int ble = pkt->mode == RADIO_MODE_BLE;
    const int32_t rc = ble ? pfdoa_match_ble_pdu(a->filters, PFDOA_BEACON_SLOTS, pkt->data, pkt->len, &m)
                           : pfdoa_match_802154(a->filters, PFDOA_BEACON_SLOTS, pkt->data, pkt->len, &m);
    if (rc == 1) {
        return 1;
    }
    if (a->auth_entries == 0u) {
        return 0;
    }
    return (ble ? pfdoa_match_auth_ble_pdu(pkt->data, pkt->len, &payload)
                : pfdoa_match_auth_802154(pkt->data, pkt->len, &payload)) == 1;
}

/* The radio hopped after a hit: a whole dwell on the new channel (RADIO and RTC1 share a
 * priority, so this never races the hop timer's own interrupt). */
static void radio_hopped(void *const ctx)
{
    rtc_tick_compare_in(&((app_t *)ctx)->tick, RTC_TICK_HOP, rtc_tick_from_ms(RADIO_BLE_DWELL_MS));
}

static const radio_hooks_t radio_hooks = { now_ms, radio_accept, radio_hopped, &app };

/* The anchor's own advertisement (SPEC 3.5, 6.1), from the core's poll: handed to the radio,
 * which sends it at the next DISABLED interrupt (-1 while the previous one is on air). */
static int32_t peer_send(void *const ctx, const uint8_t *const frame, const size_t len)
{
    return radio_send(&((app_t *)ctx)->radio, frame, len);
}

/* Its address, on-air order: the anchor's id, 00 00 00 (00 00) and C5 on top (for BLE a
 * random static address: the top two bits set). The anchors tell each other apart by the id
 * in the payload, not by the address. */
#define PEER_ADDRESS_TOP 0xC5u

/* The core's filter table into the copy the RADIO interrupt reads. Events of beacons
 * without a sequence number close at the first poll after their entry's period: the
 * main loop keeps polling every APP_WAKE_BUSY_MS that long after a reading, so the
 * report (and its tick) is not up to APP_WAKE_IDLE_MS late. */
static void filters_to_radio(app_t *const a)
{
    uint32_t window = APP_BUSY_AFTER_READING_MS;
    uint8_t auth = 0u;
    const uint32_t primask = cm_irq_save();
    for (uint8_t i = 0u; i < PFDOA_BEACON_SLOTS; ++i) {
        (void)pfdoa_anchor_get_filter(&a->anchor, i, &a->filters[i]);
        auth = (uint8_t)(auth + ((a->filters[i].kind == PFDOA_FILTER_PFDOA_AUTH) ? 1u : 0u));
        const uint32_t w = (uint32_t)a->filters[i].period_ms + APP_WAKE_BUSY_MS;
        window = (w > window) ? w : window;
    }
    a->auth_entries = auth;
    cm_irq_restore(primask);
    a->busy_after_reading_ms = window;
}

/* ---- start-up ---- */

#if NRF_LINK_CAN
static int32_t link_init(app_t *const a)
{
    mcp2515_timing_t timing;
    /* What the core accepts (SPEC 4): CONFIG_SET to this anchor, and to all. */
    const uint16_t ids[2] = {
        (uint16_t)((PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | a->id),
        (uint16_t)((PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | PFDOA_ANCHOR_BROADCAST),
    };
    if (mcp2515_bit_timing(NRF_CAN_OSC_HZ, NRF_CAN_BITRATE, &timing) != MCP2515_OK) {
        return -1;
    }
    spim_init(&a->spim, BOARD_SPI_SCK, BOARD_SPI_MOSI, BOARD_SPI_MISO, BOARD_CAN_CS_PORT, BOARD_CAN_CS_PIN);
    /* INT is open-drain-like (low while a flag is set): pulled up, its falling edge an
     * event on GPIOTE channel 0. */
    BOARD_CAN_INT_PORT->PIN_CNF[BOARD_CAN_INT_PIN] = NRF_GPIO_CNF_INPUT | NRF_GPIO_CNF_PULLUP;
    NRF_GPIOTE->CONFIG[0] = NRF_GPIOTE_CONFIG_EVENT_HITOLO(BOARD_CAN_INT_PORTNUM, BOARD_CAN_INT_PIN);
    NRF_GPIOTE->EVENTS_IN[0] = 0u;
    NRF_GPIOTE->INTENSET = 1u;
    cm_nvic_enable(NRF_IRQ_GPIOTE, BOARD_PRIO_LINK);
    return (mcp2515_init(&a->can, spim_xfer, &a->spim, &timing, ids, 2u) == MCP2515_OK) ? 0 : -1;
}

static int can_int_low(void)
{
    return (BOARD_CAN_INT_PORT->IN & (1u << BOARD_CAN_INT_PIN)) == 0u;
}
#endif

static void uart_init(app_t *const a)
{
    uarte_init(&a->uart, BOARD_UART_TXD, BOARD_UART_RXD);
    cm_nvic_enable(NRF_IRQ_UARTE0, BOARD_PRIO_LINK);
}

int32_t app_init(void)
{
    app_t *const a = &app;
    memset(a, 0, sizeof *a);
    a->id = app_anchor_id();
    /* Without the crystal the radio would be off frequency: it stays off, and the anchor
     * still sends STATUS over its link (no reports is how the host sees it). */
    const int hfxo = clock_start_hfxo() == CLOCK_OK;
    const clock_lf_source_t lf = clock_start_lfclk();
    rtc_tick_start(&a->tick);
    clock_cal_init(&a->cal, lf, 0u);
    cm_nvic_enable(NRF_IRQ_RTC1, BOARD_PRIO_RTC);
    uart_init(a);
#if NRF_LINK_CAN
    if (link_init(a) != 0) {
        a->status = APP_ERR_LINK;
    }
#endif
    if (pfdoa_anchor_init(&a->anchor, &hal, a->id, TRANSPORT) != PFDOA_OK
        || pfdoa_anchor_use_filter_storage(&a->anchor, &filter_storage) != PFDOA_OK) {
        a->status = APP_ERR_ANCHOR;
        return a->status;
    }
    pfdoa_peer_radio_t peer = { .ctx = a, .send = peer_send, .radio = NRF_IEEE802154_CHANNEL ? PFDOA_RADIO_IEEE802154
                                                                                          : PFDOA_RADIO_BLE,
                                .address = {0} };
    peer.address[0] = a->id;
    peer.address[(NRF_IEEE802154_CHANNEL ? PFDOA_IEEE802154_EXT_ADDR_LEN : PFDOA_BLE_ADV_A_LEN) - 1u] = PEER_ADDRESS_TOP;
    if (hfxo) { /* without the crystal the radio stays off: nothing to send on */
        (void)pfdoa_anchor_use_peer_radio(&a->anchor, &peer);
    }
    filters_to_radio(a);
    if (!hfxo) {
        a->status = APP_ERR_HFXO;
        return a->status;
    }
#if NRF_IEEE802154_CHANNEL
    (void)radio_start_ieee802154(&a->radio, NRF_IEEE802154_CHANNEL, &radio_hooks);
#else
    radio_start_ble(&a->radio, &radio_hooks);
    rtc_tick_compare_in(&a->tick, RTC_TICK_HOP, rtc_tick_from_ms(RADIO_BLE_DWELL_MS));
#endif
    cm_nvic_enable(NRF_IRQ_RADIO, BOARD_PRIO_RADIO);
    return a->status;
}

/* ---- main loop ---- */

static void radio_to_core(app_t *const a, const uint32_t now)
{
    radio_packet_t pkt;
    while (radio_pop(&a->radio, &pkt) != 0) {
        const pfdoa_rx_t rx = { .tick_ms = pkt.tick_ms, .rssi_dbm = pkt.rssi_dbm, .channel = pkt.channel,
                                .lqi = pkt.lqi };
        const int32_t rc = (pkt.mode == RADIO_MODE_BLE)
                               ? pfdoa_anchor_on_ble_pdu(&a->anchor, &rx, pkt.data, pkt.len)
                               : pfdoa_anchor_on_802154(&a->anchor, &rx, pkt.data, pkt.len);
        if (rc == 0) {
            a->ignored++;
            continue;
        }
        /* 1: folded; PFDOA_ERR_ARG: a matched reading the core dropped (no RSSI) and counted. */
        a->readings++;
        a->last_reading_ms = now;
    }
    /* Readings lost to a full queue count as the core's dropped_events (SPEC 1.2). */
    const uint32_t lost = a->radio.queue_full - a->lost_noted;
    if (lost != 0u) {
        const uint16_t n = (lost > 0xFFFFu) ? 0xFFFFu : (uint16_t)lost;
        (void)pfdoa_anchor_note_dropped(&a->anchor, n);
        a->lost_noted += n;
    }
}

/* Host bytes on the UART; the table copy follows whatever the core acted on. */
static void uart_to_core(app_t *const a, const uint32_t now)
{
    uint8_t rx[32];
    uarte_poll(&a->uart, now);
    size_t n;
    int32_t acted = 0;
    while ((n = uarte_read(&a->uart, rx, sizeof rx)) > 0u) {
        if (pfdoa_anchor_on_uart_rx(&a->anchor, rx, n) > 0) {
            acted = 1;
        }
    }
    if (acted) {
        filters_to_radio(a);
    }
}

#if NRF_LINK_CAN
static void can_to_core(app_t *const a, const uint32_t now)
{
    /* Frames that found the TX buffers busy (a report and STATUS_A/B/C in one poll). */
    if (mcp2515_tx_waiting(&a->can) > 0u) {
        (void)mcp2515_tx_pump(&a->can);
    }
    const int due = (uint32_t)(now - a->can_serviced_ms) >= APP_CAN_SERVICE_MS;
    if (a->can_irq == 0u && !can_int_low() && !due) {
        return;
    }
    a->can_irq = 0u;
    a->can_serviced_ms = now;
    (void)mcp2515_service(&a->can, now);
    mcp2515_frame_t f;
    /* Bounded: both receive buffers, twice over, per pass. */
    for (uint32_t i = 0u; i < 4u && mcp2515_receive(&a->can, &f) == 1; ++i) {
        (void)pfdoa_anchor_on_can_rx(&a->anchor, f.id, f.data, f.dlc);
    }
}
#endif

void app_step(void)
{
    app_t *const a = &app;
    const uint32_t now = rtc_tick_ms(&a->tick);
    radio_to_core(a, now);
    uart_to_core(a, now);
#if NRF_LINK_CAN
    can_to_core(a, now);
#endif
    clock_cal_poll(&a->cal, now);
    (void)pfdoa_anchor_poll(&a->anchor, now);
}

void app_idle(void)
{
    app_t *const a = &app;
    const uint32_t primask = cm_irq_save();
    const uint32_t now = rtc_tick_ms(&a->tick);
    int work = radio_pending(&a->radio) || uarte_rx_available(&a->uart);
    int busy = (uint32_t)(now - a->last_reading_ms) < a->busy_after_reading_ms || a->cal.busy != 0u
               || uarte_rx_pending(&a->uart);
#if NRF_LINK_CAN
    work = work || a->can_irq != 0u || can_int_low();
    busy = busy || a->can.state != MCP2515_ERROR_ACTIVE || mcp2515_tx_waiting(&a->can) > 0u;
#endif
    if (!work) {
        rtc_tick_wake_in(&a->tick, busy ? APP_WAKE_BUSY_MS : APP_WAKE_IDLE_MS);
        cm_wfi(); /* masked: an interrupt that came after the checks still wakes us */
    }
    cm_irq_restore(primask);
}

/* ---- interrupt handlers ---- */

void RADIO_IRQHandler(void)
{
    radio_isr(&app.radio);
}

void RTC1_IRQHandler(void)
{
    const uint32_t fired = rtc_tick_isr(&app.tick);
    if ((fired & (1u << RTC_TICK_HOP)) != 0u) {
        radio_hop(&app.radio);
        rtc_tick_compare_in(&app.tick, RTC_TICK_HOP, rtc_tick_from_ms(RADIO_BLE_DWELL_MS));
    }
}

void UARTE0_UART0_IRQHandler(void)
{
    uarte_isr(&app.uart);
}

void GPIOTE_IRQHandler(void)
{
#if NRF_LINK_CAN
    if (NRF_GPIOTE->EVENTS_IN[0] != 0u) {
        NRF_GPIOTE->EVENTS_IN[0] = 0u;
        (void)NRF_GPIOTE->EVENTS_IN[0];
        app.can_irq = 1u;
    }
#endif
}
