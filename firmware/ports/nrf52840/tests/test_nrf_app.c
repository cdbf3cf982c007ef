/*
 * The whole port (app.c: start-up, HAL adapters, main loop, sleep, interrupt handlers)
 * with the real core, on the register fake. Built twice: the UART image's app
 * (NRF_LINK_CAN=0) and the CAN image's (NRF_LINK_CAN=1, MCP2515 model on the fake SPIM).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "app.h"
#include "fake_mcp2515.h"
#include "fake_nrf.h"
#include "nrf_test_support.h"
#include "pfdoa_frame.h"

#define ID 7u

#if NRF_LINK_CAN
static fake_mcp_t chip;
#endif

static int setup(void **state)
{
    (void)state;
    nrf_fake_reset();
    nrf_fake_uicr_customer0 = ID;
#if NRF_LINK_CAN
    fake_mcp_init(&chip, BOARD_CAN_INT_PIN);
    nrf_fake.spi_cs_mask = 1u << BOARD_CAN_CS_PIN;
#endif
    return 0;
}

static void boot(void)
{
    assert_int_equal(app_init(), APP_OK);
    nrf_fake_radio.TASKS_DISABLE = 0u; /* taken by the fake radio */
}

static void at_ms(uint64_t ms)
{
    nrf_fake_rtc_advance_to(test_rtc_ticks_of_ms(ms), RTC1_IRQHandler);
}

static void beacon_on_air(uint16_t seq, int rssi_sample)
{
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, seq);
    test_radio_packet(pdu, n, 1, rssi_sample, RADIO_IRQHandler);
}

/* The hop timer fires; the radio, not receiving, disables at once. */
static void hop(void)
{
    nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_HOP] = 1u;
    RTC1_IRQHandler();
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 1u);
    nrf_fake_radio.TASKS_DISABLE = 0u;
    nrf_fake_radio.EVENTS_DISABLED = 1u;
    RADIO_IRQHandler();
}

static void test_boot_sets_up_the_board(void **state)
{
    (void)state;
    boot();
    app_t *const a = app_get();
    assert_int_equal(a->id, ID);                                  /* from UICR.CUSTOMER[0] */
    assert_int_equal(nrf_fake_clock.HFCLKSTAT & 1u, 1u);          /* HFXO for the radio */
    assert_int_equal(nrf_fake_clock.LFCLKSRC, NRF_CLOCK_LFCLKSRC_XTAL);
    assert_int_equal(nrf_fake_rtc1.TASKS_START, 1u);
    assert_int_equal(nrf_fake_radio.MODE, NRF_RADIO_MODE_BLE_1MBIT);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_HOP], rtc_tick_from_ms(RADIO_BLE_DWELL_MS));
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RADIO)) != 0u);
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RTC1)) != 0u);
    assert_int_equal(nrf_fake.nvic_priority[NRF_IRQ_RADIO], nrf_fake.nvic_priority[NRF_IRQ_RTC1]);
    nrf_fake_uicr_customer0 = 200u; /* not an anchor id: the build's default */
    assert_int_equal(app_anchor_id(), NRF_ANCHOR_ID);
}

static void test_idle_sleeps_only_without_work(void **state)
{
    (void)state;
    boot();
    at_ms(5u);
    app_step();
    /* Nothing waiting: WFI under the mask, the wake-up armed. */
    const uint32_t before = nrf_fake.wfi_count;
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 1u);
    assert_int_equal(nrf_fake.wfi_unmasked, 0u);
    assert_int_equal(nrf_fake.primask, 0u);
    const uint32_t counter = nrf_fake_rtc1.COUNTER;
    /* Just after boot the core may have an event to close soon: a short sleep. */
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - counter) & 0xFFFFFFu, rtc_tick_from_ms(APP_WAKE_BUSY_MS));
    at_ms(1000u);
    app_idle();
    assert_int_equal((nrf_fake_rtc1.CC[RTC_TICK_WAKE] - nrf_fake_rtc1.COUNTER) & 0xFFFFFFu,
                     rtc_tick_from_ms(APP_WAKE_IDLE_MS));
    /* A packet arrived (its interrupt ran): no sleep until it has been handled. */
    beacon_on_air(1u, 50);
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 2u);
    app_step();
    app_idle();
    assert_int_equal(nrf_fake.wfi_count, before + 3u);
}

static void test_hop_timer_moves_the_radio(void **state)
{
    (void)state;
    boot();
    hop();
    assert_int_equal(app_get()->radio.channel, 38u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 26u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_HOP],
                     (nrf_fake_rtc1.COUNTER + rtc_tick_from_ms(RADIO_BLE_DWELL_MS)) & 0xFFFFFFu);
}

static void test_queue_overflow_reaches_dropped_events(void **state)
{
    (void)state;
    boot();
    at_ms(10u);
    for (uint32_t i = 0u; i < RADIO_QUEUE + 3u; ++i) {
        beacon_on_air((uint16_t)(100u + i), 50);
    }
    app_step();
    assert_int_equal(pfdoa_anchor_dropped_events(&app_get()->anchor), 3u);
    assert_int_equal(app_get()->readings, RADIO_QUEUE);
}

#if !NRF_LINK_CAN
static size_t sent(uint8_t *out, size_t cap)
{
    return test_uarte_drain_tx(out, cap, UARTE0_UART0_IRQHandler);
}

/* The frames in a byte stream, decoded with the core's own checks. */
static size_t frames(const uint8_t *bytes, size_t n, uint8_t *types, pfdoa_rssi_report_t *last_report,
                     uint8_t ack[4], uint8_t fack[PFDOA_MSG_FILTER_ACK_LEN])
{
    static const uint8_t known[] = { PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS, PFDOA_MSG_CONFIG_ACK,
                                     PFDOA_MSG_FILTER_ACK };
    pfdoa_decoder_t dec;
    pfdoa_decoder_init(&dec, known, sizeof known);
    size_t k = 0u;
    for (size_t i = 0u; i < n; ++i) {
        pfdoa_frame_t f;
        const int32_t rc = pfdoa_decoder_push(&dec, bytes[i], &f);
        assert_true(rc >= 0);
        if (rc == 1) {
            assert_int_equal(f.anchor_id, ID);
            types[k++] = f.type;
            if (f.type == PFDOA_MSG_RSSI_REPORT && last_report != NULL) {
                last_report->seq = (uint16_t)(f.payload[0] | (f.payload[1] << 8));
                last_report->raw_dbm = (int8_t)f.payload[8];
                last_report->n_readings = f.payload[9];
                last_report->channel = f.payload[10];
            }
            if (f.type == PFDOA_MSG_CONFIG_ACK && ack != NULL) {
                memcpy(ack, f.payload, 4u);
            }
            if (f.type == PFDOA_MSG_FILTER_ACK && fack != NULL) {
                memcpy(fack, f.payload, PFDOA_MSG_FILTER_ACK_LEN);
            }
        }
    }
    return k;
}

static void test_uart_boot_status_and_report(void **state)
{
    (void)state;
    boot();
    app_step(); /* first poll: STATUS, the banner */
    uint8_t out[512];
    uint8_t types[16];
    size_t n = sent(out, sizeof out);
    assert_int_equal(frames(out, n, types, NULL, NULL, NULL), 1u);
    assert_int_equal(types[0], PFDOA_MSG_STATUS);
    /* One advertising event heard on 37, 38 and 39 (the hop timer in between). */
    at_ms(20u);
    beacon_on_air(42u, 60);
    hop();
    beacon_on_air(42u, 61);
    hop();
    beacon_on_air(42u, 63);
    at_ms(21u);
    app_step();
    n = sent(out, sizeof out);
    pfdoa_rssi_report_t rep;
    assert_int_equal(frames(out, n, types, &rep, NULL, NULL), 1u);
    assert_int_equal(types[0], PFDOA_MSG_RSSI_REPORT);
    assert_int_equal(rep.seq, 42u);
    assert_int_equal(rep.n_readings, 3u);
    assert_int_equal(rep.channel, 39u);
    assert_int_equal(rep.raw_dbm, -63);
    /* A stranger's advert and a CRC failure change nothing. */
    uint8_t pdu[64];
    size_t len = test_ble_beacon(pdu, 43u);
    pdu[13] = 0x00u;
    test_radio_packet(pdu, len, 1, 50, RADIO_IRQHandler);
    len = test_ble_beacon(pdu, 43u);
    test_radio_packet(pdu, len, 0, 50, RADIO_IRQHandler);
    at_ms(300u);
    app_step();
    assert_int_equal(sent(out, sizeof out), 0u);
    assert_int_equal(app_get()->radio.crc_errors, 1u);
    assert_int_equal(app_get()->radio.rejected, 1u);
}

/* FILTER_SET payload: entry `index` listens to an iBeacon (UUID 00 01 .. 0F, major 1, minor
 * 2, big-endian as on air) and forms its events over 100 ms. */
static void ibeacon_filter_set(uint8_t payload[PFDOA_MSG_FILTER_SET_LEN], uint8_t token, uint8_t index)
{
    memset(payload, 0, PFDOA_MSG_FILTER_SET_LEN);
    payload[PFDOA_MSG_FILTER_SET_OFF_TOKEN] = token;
    payload[PFDOA_MSG_FILTER_SET_OFF_INDEX] = index;
    payload[PFDOA_MSG_FILTER_SET_OFF_KIND] = PFDOA_FILTER_IBEACON;
    payload[PFDOA_MSG_FILTER_SET_OFF_PERIOD_MS] = 100u;
    uint8_t *const match = &payload[PFDOA_MSG_FILTER_SET_OFF_MATCH];
    for (uint8_t k = 0u; k < 16u; ++k) {
        match[k] = k;
    }
    match[17] = 1u;
    match[19] = 2u;
}

static void test_uart_config_and_filter_set_acked_stored_and_kept_across_reboot(void **state)
{
    (void)state;
    boot();
    app_step();
    uint8_t out[512];
    uint8_t types[16];
    (void)sent(out, sizeof out);
    const uint16_t boot_filter_hash = pfdoa_anchor_filter_hash(&app_get()->anchor);
    /* CONFIG_SET: token 9, offset +1 dB, alpha 0.5, spike 10 dB, mode 0, decimation 1; then a
     * FILTER_SET for entry 1, in one burst from the host. */
    const uint8_t payload[8] = { 9, 0x00, 0x01, 0x80, 0x00, 10, 0, 1 };
    uint8_t fpayload[PFDOA_MSG_FILTER_SET_LEN];
    ibeacon_filter_set(fpayload, 4u, 1u);
    uint8_t frame[2u * PFDOA_FRAME_WIRE_MAX];
    const int32_t fl = pfdoa_frame_encode(PFDOA_MSG_CONFIG_SET, ID, payload, sizeof payload, frame, sizeof frame);
    assert_true(fl > 0);
    const int32_t fl2 = pfdoa_frame_encode(PFDOA_MSG_FILTER_SET, ID, fpayload, sizeof fpayload, &frame[fl],
                                           sizeof frame - (size_t)fl);
    assert_true(fl2 > 0);
    const size_t total = (size_t)(fl + fl2);
    uint32_t filled = 0u;
    at_ms(100u);
    const uint32_t partial = test_uarte_rx(frame, total, &filled, UARTE0_UART0_IRQHandler);
    assert_true(partial > 0u); /* the burst's tail sits in a chunk that is not full */
    app_step();
    at_ms(100u + UARTE_RX_IDLE_MS);
    app_step();                /* quiet long enough: STOPRX */
    assert_int_equal(nrf_fake_uarte0.TASKS_STOPRX, 1u);
    test_uarte_stop_flush(&filled, NULL, 0u, UARTE0_UART0_IRQHandler);
    app_step();
    size_t n = sent(out, sizeof out);
    uint8_t ack[4];
    uint8_t fack[PFDOA_MSG_FILTER_ACK_LEN];
    assert_int_equal(frames(out, n, types, NULL, ack, fack), 2u);
    assert_int_equal(types[0], PFDOA_MSG_CONFIG_ACK);
    assert_int_equal(ack[0], 9u);
    assert_int_equal(ack[1], 0u);                  /* applied and stored (flash) */
    const uint16_t hash = (uint16_t)(ack[2] | (ack[3] << 8));
    assert_int_equal(pfdoa_anchor_config_hash(&app_get()->anchor), hash);
    assert_int_equal(types[1], PFDOA_MSG_FILTER_ACK);
    assert_int_equal(fack[PFDOA_MSG_FILTER_ACK_OFF_TOKEN], 4u);
    assert_int_equal(fack[PFDOA_MSG_FILTER_ACK_OFF_RESULT], 0u); /* applied and stored (flash) */
    assert_int_equal(fack[PFDOA_MSG_FILTER_ACK_OFF_INDEX], 1u);
    const uint16_t fhash = (uint16_t)(fack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH]
                                      | (fack[PFDOA_MSG_FILTER_ACK_OFF_FILTER_HASH + 1u] << 8));
    assert_int_equal(pfdoa_anchor_filter_hash(&app_get()->anchor), fhash);
    assert_int_not_equal(fhash, boot_filter_hash);
    assert_int_equal(nrf_fake.flash_violations, 0u);
    assert_int_equal(nrf_fake.flash_writes, 4u + 25u); /* one record in each log */
    /* Power cycle: everything but the flash pages starts again. */
    uint32_t pages[NRF_STORE_PAGES][NRF_FLASH_PAGE_SIZE / 4u];
    memcpy(pages, nrf_fake_store_pages, sizeof pages);
    nrf_fake_reset();
    memcpy(nrf_fake_store_pages, pages, sizeof pages);
    nrf_fake_uicr_customer0 = ID;
    boot();
    assert_int_equal(pfdoa_anchor_config_hash(&app_get()->anchor), hash);
    assert_int_equal(pfdoa_anchor_filter_hash(&app_get()->anchor), fhash);
    pfdoa_beacon_filter_t f;
    assert_int_equal(pfdoa_anchor_get_filter(&app_get()->anchor, 1u, &f), PFDOA_OK);
    assert_int_equal(f.kind, PFDOA_FILTER_IBEACON);
    assert_int_equal(f.period_ms, 100u);
}

static void test_uart_no_crystal_radio_off_status_still_sent(void **state)
{
    (void)state;
    nrf_fake.hfxo_fails = 1;
    assert_int_equal(app_init(), APP_ERR_HFXO);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 0u);              /* off frequency: never on */
    assert_int_equal(nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_RADIO), 0u);
    app_step();
    uint8_t out[128];
    uint8_t types[4];
    assert_int_equal(frames(out, sent(out, sizeof out), types, NULL, NULL, NULL), 1u);
    assert_int_equal(types[0], PFDOA_MSG_STATUS);
}

static void test_uart_tx_slots_full_counts_core_failure(void **state)
{
    (void)state;
    boot();
    /* The UART never finishes a transfer: the first frame holds the DMA, the slots fill,
     * later frames are refused and the core counts them. */
    for (uint32_t t = 0u; t < 8u; ++t) {
        at_ms(1000u * t + 1u);
        app_step();
    }
    assert_true(pfdoa_anchor_tx_failures(&app_get()->anchor) >= 8u - UARTE_TX_SLOTS);
    assert_int_equal(app_get()->uart.tx_dropped, pfdoa_anchor_tx_failures(&app_get()->anchor));
}
#else
static void test_can_boot_status_on_bus(void **state)
{
    (void)state;
    boot();
    assert_int_equal(fake_mcp_opmode(&chip), 0x00u);
    assert_int_equal(nrf_fake_gpiote.CONFIG[0], NRF_GPIOTE_CONFIG_EVENT_HITOLO(1u, BOARD_CAN_INT_PIN));
    assert_true((nrf_fake.nvic_enabled[0] & (1u << NRF_IRQ_GPIOTE)) != 0u);
    /* 16 MHz / 500 kbit/s as built for this test. */
    assert_int_equal(chip.reg[0x2A], 0x00u);
    assert_int_equal(chip.reg[0x29], 0xB5u);
    assert_int_equal(chip.reg[0x28], 0x01u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 2u);
    assert_int_equal(chip.sent[0].id, (PFDOA_CAN_STATUS_A << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[1].id, (PFDOA_CAN_STATUS_B << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(nrf_fake.spi_without_cs, 0u);
}

static void test_can_config_set_through_filters(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)fake_mcp_bus_run(&chip, 10u);
    const uint8_t cfg[8] = { 5, 0, 0, 64, 0, 12, 0, 1 };
    /* Another anchor's CONFIG_SET never gets past the chip's filters. */
    assert_int_equal(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | (ID + 1u), 0, 0, 8u,
                                        cfg), -1);
    /* Ours does: INT falls, GPIOTE's event, the main loop takes it, the ack goes out. */
    assert_true(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | ID, 0, 0, 8u, cfg) >= 0);
    nrf_fake_gpiote.EVENTS_IN[0] = 1u;
    GPIOTE_IRQHandler();
    assert_int_equal(app_get()->can_irq, 1u);
    at_ms(50u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
    const fake_mcp_frame_t *const ack = &chip.sent[chip.n_sent - 1u];
    assert_int_equal(ack->id, (PFDOA_CAN_CONFIG_ACK << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(ack->dlc, PFDOA_CAN_CONFIG_ACK_DLC);
    assert_int_equal(ack->data[0], 5u);  /* token */
    assert_int_equal(ack->data[1], 0u);  /* applied and stored */
    /* The broadcast id is accepted too. */
    assert_true(fake_mcp_bus_frame(&chip, (PFDOA_CAN_CONFIG_SET << PFDOA_CAN_ANCHOR_BITS) | PFDOA_ANCHOR_BROADCAST, 0,
                                   0, 8u, cfg) >= 0);
    at_ms(60u);
    app_step();
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
}

static void test_can_bus_off_counts_failures_and_recovers(void **state)
{
    (void)state;
    boot();
    app_step();
    (void)fake_mcp_bus_run(&chip, 10u);
    fake_mcp_set_errors(&chip, 256, 0);
    at_ms(10u);
    app_step(); /* INT low: serviced, bus-off */
    assert_int_equal(app_get()->can.state, MCP2515_BUS_OFF);
    beacon_on_air(1u, 50);
    at_ms(12u);
    app_step();
    beacon_on_air(2u, 50); /* closes seq 1: its report cannot be sent */
    at_ms(14u);
    app_step();
    assert_int_equal(pfdoa_anchor_tx_failures(&app_get()->anchor), 1u);
    fake_mcp_bus_off_recovered(&chip);
    at_ms(200u); /* the periodic service sees the recovery */
    app_step();
    assert_int_equal(app_get()->can.state, MCP2515_ERROR_ACTIVE);
    assert_int_equal(app_get()->can.recoveries, 1u);
    beacon_on_air(3u, 50);
    at_ms(202u);
    app_step();
    const uint32_t before = chip.n_sent;
    assert_int_equal(fake_mcp_bus_run(&chip, 10u), 1u);
    assert_int_equal(chip.sent[before].id, (PFDOA_CAN_RSSI_REPORT << PFDOA_CAN_ANCHOR_BITS) | ID);
    assert_int_equal(chip.sent[before].data[0], 2u); /* seq 2's report */
}

static void test_can_missing_controller_is_reported(void **state)
{
    (void)state;
    chip.absent = 1;
    assert_int_equal(app_init(), APP_ERR_LINK);
}
#endif

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_boot_sets_up_the_board, setup),
        cmocka_unit_test_setup(test_idle_sleeps_only_without_work, setup),
        cmocka_unit_test_setup(test_hop_timer_moves_the_radio, setup),
        cmocka_unit_test_setup(test_queue_overflow_reaches_dropped_events, setup),
#if !NRF_LINK_CAN
        cmocka_unit_test_setup(test_uart_boot_status_and_report, setup),
        cmocka_unit_test_setup(test_uart_config_and_filter_set_acked_stored_and_kept_across_reboot, setup),
        cmocka_unit_test_setup(test_uart_no_crystal_radio_off_status_still_sent, setup),
        cmocka_unit_test_setup(test_uart_tx_slots_full_counts_core_failure, setup),
#else
        cmocka_unit_test_setup(test_can_boot_status_on_bus, setup),
        cmocka_unit_test_setup(test_can_config_set_through_filters, setup),
        cmocka_unit_test_setup(test_can_bus_off_counts_failures_and_recovers, setup),
        cmocka_unit_test_setup(test_can_missing_controller_is_reported, setup),
#endif
    };
    return cmocka_run_group_tests_name(NRF_LINK_CAN ? "nrf52840 app (CAN image)" : "nrf52840 app (UART image)", tests,
                                       NULL, NULL);
}
