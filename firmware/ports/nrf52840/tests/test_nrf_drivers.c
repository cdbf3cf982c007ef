/*
 * The nRF52840 port's drivers on the register fake: RTC tick (24-bit and 32-bit wraps),
 * clocks, UARTE (TX slots, RX chunks with the ENDRX/RXTO/FLUSHRX sequence), RADIO (BLE
 * and 802.15.4 set-up, the receive state machine, channel hopping, CRC failures, RSSI),
 * beacon parsing and the flash configuration store.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "beacon.h"
#include "clock.h"
#include "fake_nrf.h"
#include "flash_store.h"
#include "nrf_test_support.h"
#include "radio.h"
#include "rtc_tick.h"
#include "uarte.h"

static rtc_tick_t tick;
static uarte_t uart;
static radio_t radio;

static int setup(void **state)
{
    (void)state;
    nrf_fake_reset();
    return 0;
}

static void rtc_irq(void)
{
    (void)rtc_tick_isr(&tick);
}

/* ---------------------------------------------------------------- RTC tick */

static void test_tick_conversion_is_floor_exact(void **state)
{
    (void)state;
    assert_int_equal(rtc_tick_to_ms(0u), 0u);
    assert_int_equal(rtc_tick_to_ms(32u), 0u);   /* 0.977 ms */
    assert_int_equal(rtc_tick_to_ms(33u), 1u);   /* 1.007 ms */
    assert_int_equal(rtc_tick_to_ms(32768u), 1000u);
    assert_int_equal(rtc_tick_to_ms(1u << 24), 512000u);
    /* Every tick of the first 3 wraps, and a spread beyond: floor(t * 1000 / 32768). */
    for (uint64_t t = 0u; t < 3u * (1u << 24); t += 7u) {
        assert_int_equal(rtc_tick_to_ms(t), (uint32_t)(t * 1000u / 32768u));
    }
    /* No drift: 49 days of ticks are exactly 49 days of milliseconds. */
    const uint64_t day = 32768ull * 86400u;
    assert_int_equal(rtc_tick_to_ms(49u * day), (uint32_t)(49ull * 86400000u));
    /* The 32-bit wrap: 2^32 ms after start reads 0 again, and 1 ms before it 2^32 - 1. */
    const uint64_t wrap = test_rtc_ticks_of_ms(1ull << 32);
    assert_int_equal(rtc_tick_to_ms(wrap), 0u);
    assert_int_equal(rtc_tick_to_ms(wrap - 33u), 0xFFFFFFFFu);
    /* ms -> ticks -> ms round trips (the wake-up conversion). */
    for (uint32_t ms = 0u; ms <= 100000u; ++ms) {
        const uint32_t t = rtc_tick_from_ms(ms);
        assert_true(rtc_tick_to_ms(t) >= ms);
        assert_true(rtc_tick_to_ms(t) - ms <= 1u);
        assert_true(t == 0u || rtc_tick_to_ms(t - 1u) < ms + 1u);
    }
}

static void test_tick_start_configures_rtc1(void **state)
{
    (void)state;
    nrf_fake_rtc1.PRESCALER = 99u;
    rtc_tick_start(&tick);
    assert_int_equal(nrf_fake_rtc1.PRESCALER, 0u);
    assert_int_equal(nrf_fake_rtc1.TASKS_CLEAR, 1u);
    assert_int_equal(nrf_fake_rtc1.TASKS_START, 1u);
    assert_true((nrf_fake_rtc1.INTENSET & NRF_RTC_INT_OVRFLW) != 0u);
    assert_int_equal(rtc_tick_ms(&tick), 0u);
}

static void test_tick_24bit_wrap_is_continuous(void **state)
{
    (void)state;
    rtc_tick_start(&tick);
    nrf_fake_rtc_advance_to(0xFFFFFEu, rtc_irq);
    const uint32_t before = rtc_tick_ms(&tick);
    assert_int_equal(before, (uint32_t)(0xFFFFFEull * 1000u / 32768u));
    assert_int_equal(nrf_fake_rtc_advance_to((1u << 24) + 40u, rtc_irq), 1u);
    assert_int_equal(tick.overflows, 1u);
    const uint32_t after = rtc_tick_ms(&tick);
    assert_int_equal(after, (uint32_t)(((1ull << 24) + 40u) * 1000u / 32768u));
    assert_true(after > before && after - before <= 2u);
}

static void test_tick_pending_overflow_counted_once(void **state)
{
    (void)state;
    rtc_tick_start(&tick);
    /* The counter wrapped, but the interrupt has not run yet (masked, or a higher one
     * running): the reader counts the wrap itself... */
    nrf_fake_rtc1.COUNTER = 5u;
    nrf_fake_rtc1.EVENTS_OVRFLW = 1u;
    assert_int_equal(rtc_tick_now(&tick), (1ull << 24) + 5u);
    assert_int_equal(nrf_fake_rtc1.EVENTS_OVRFLW, 0u);
    /* ...and the interrupt that follows finds nothing more to count. */
    assert_int_equal(rtc_tick_isr(&tick), 0u);
    assert_int_equal(tick.overflows, 1u);
    assert_int_equal(rtc_tick_now(&tick), (1ull << 24) + 5u);
    assert_int_equal(nrf_fake.primask, 0u); /* the mask was given back */
}

static void test_tick_u32_ms_wrap(void **state)
{
    (void)state;
    rtc_tick_start(&tick);
    const uint64_t wrap = test_rtc_ticks_of_ms(1ull << 32);
    nrf_fake_rtc_advance_to(wrap - test_rtc_ticks_of_ms(3000u), rtc_irq);
    const uint32_t a = rtc_tick_ms(&tick);
    assert_int_equal(a, 0xFFFFFFFFu - 2999u);
    nrf_fake_rtc_advance_to(wrap + test_rtc_ticks_of_ms(2000u), rtc_irq);
    const uint32_t b = rtc_tick_ms(&tick);
    assert_int_equal(b, 2000u);
    assert_int_equal((uint32_t)(b - a), 5000u); /* u32 differences stay right */
    assert_int_equal(tick.overflows, (uint32_t)((wrap + test_rtc_ticks_of_ms(2000u)) >> 24));
}

static void test_tick_compare_and_isr(void **state)
{
    (void)state;
    rtc_tick_start(&tick);
    nrf_fake_rtc1.COUNTER = 0xFFFFF0u;
    rtc_tick_compare_in(&tick, RTC_TICK_HOP, 0x20u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_HOP], 0x10u); /* wraps over 24 bits */
    assert_true((nrf_fake_rtc1.INTENSET & NRF_RTC_INT_COMPARE(RTC_TICK_HOP)) != 0u);
    rtc_tick_compare_in(&tick, RTC_TICK_WAKE, 0u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_WAKE], 0xFFFFF2u); /* at least 2 ahead */
    rtc_tick_wake_in(&tick, 100u);
    assert_int_equal(nrf_fake_rtc1.CC[RTC_TICK_WAKE], (0xFFFFF0u + 3277u) & 0xFFFFFFu);
    nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_HOP] = 1u;
    nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_WAKE] = 1u;
    assert_int_equal(rtc_tick_isr(&tick), (1u << RTC_TICK_HOP) | (1u << RTC_TICK_WAKE));
    assert_int_equal(nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_HOP], 0u);
    assert_int_equal(rtc_tick_isr(&tick), 0u);
}

/* ---------------------------------------------------------------- clocks */

static void test_clock_hfxo(void **state)
{
    (void)state;
    assert_int_equal(clock_start_hfxo(), CLOCK_OK);
    assert_int_equal(nrf_fake_clock.HFCLKSTAT & NRF_CLOCK_STAT_SRC_MASK, NRF_CLOCK_HFCLKSTAT_XTAL);
    nrf_fake_reset();
    nrf_fake.hfxo_fails = 1;
    assert_int_equal(clock_start_hfxo(), CLOCK_ERR_HFXO); /* bounded wait, no hang */
}

static void test_clock_lfclk_falls_back_to_rc(void **state)
{
    (void)state;
    assert_int_equal(clock_start_lfclk(), CLOCK_LF_XTAL);
    assert_int_equal(nrf_fake_clock.LFCLKSRC, NRF_CLOCK_LFCLKSRC_XTAL);
    nrf_fake_reset();
    nrf_fake.lfxo_fails = 1;
    assert_int_equal(clock_start_lfclk(), CLOCK_LF_RC);
    assert_int_equal(nrf_fake_clock.LFCLKSRC, NRF_CLOCK_LFCLKSRC_RC);
    assert_int_equal(nrf_fake_clock.LFCLKSTAT, NRF_CLOCK_LFCLKSRC_RC | NRF_CLOCK_STAT_RUNNING);
}

static void test_clock_rc_calibration_schedule(void **state)
{
    (void)state;
    clock_cal_t cal;
    clock_cal_init(&cal, CLOCK_LF_XTAL, 0u);
    clock_cal_poll(&cal, 10000u);
    assert_int_equal(nrf_fake_clock.TASKS_CAL, 0u); /* the crystal needs none */
    clock_cal_init(&cal, CLOCK_LF_RC, 100u);
    clock_cal_poll(&cal, 100u);
    assert_int_equal(nrf_fake_clock.TASKS_CAL, 1u); /* the first one at once */
    nrf_fake_clock.TASKS_CAL = 0u;
    clock_cal_poll(&cal, 150u);
    assert_int_equal(cal.done, 0u);
    nrf_fake_clock.EVENTS_DONE = 1u;
    clock_cal_poll(&cal, 200u);
    assert_int_equal(cal.done, 1u);
    assert_int_equal(nrf_fake_clock.EVENTS_DONE, 0u);
    clock_cal_poll(&cal, 100u + CLOCK_CAL_PERIOD_MS - 1u);
    assert_int_equal(nrf_fake_clock.TASKS_CAL, 0u);
    clock_cal_poll(&cal, 100u + CLOCK_CAL_PERIOD_MS);
    assert_int_equal(nrf_fake_clock.TASKS_CAL, 1u);
}

/* ---------------------------------------------------------------- UARTE */

static void uart_irq(void)
{
    uarte_isr(&uart);
}

static void test_uarte_init(void **state)
{
    (void)state;
    uarte_init(&uart, NRF_PSEL(0, 6), NRF_PSEL(0, 8));
    assert_int_equal(nrf_fake_uarte0.PSEL_TXD, 6u);
    assert_int_equal(nrf_fake_uarte0.PSEL_RXD, 8u);
    assert_int_equal(nrf_fake_uarte0.PSEL_RTS, NRF_PSEL_DISCONNECTED);
    assert_int_equal(nrf_fake_uarte0.BAUDRATE, 0x01D60000u);
    assert_int_equal(nrf_fake_uarte0.CONFIG, 0u);
    assert_int_equal(nrf_fake_uarte0.ENABLE, 8u);
    assert_int_equal(nrf_fake_uarte0.RXD_MAXCNT, UARTE_RX_CHUNK);
    assert_ptr_equal(nrf_fake_dma_ptr(nrf_fake_uarte0.RXD_PTR), uart.rx_chunk);
    assert_int_equal(nrf_fake_uarte0.TASKS_STARTRX, 1u);
    assert_true((nrf_fake_uarte0.INTENSET & (NRF_UARTE_INT_ENDRX | NRF_UARTE_INT_RXTO | NRF_UARTE_INT_ENDTX))
                == (NRF_UARTE_INT_ENDRX | NRF_UARTE_INT_RXTO | NRF_UARTE_INT_ENDTX));
}

static void test_uarte_tx_whole_frames_in_order(void **state)
{
    (void)state;
    uarte_init(&uart, 6u, 8u);
    const uint8_t a[] = { 1, 2, 3, 0 };
    const uint8_t b[] = { 4, 5, 0 };
    uint8_t c[UARTE_TX_SLOT_MAX];
    memset(c, 0x77, sizeof c);
    assert_int_equal(uarte_write(&uart, a, sizeof a), (int32_t)sizeof a);
    /* One DMA per frame: the first started at once, whole. */
    assert_int_equal(nrf_fake_uarte0.TASKS_STARTTX, 1u);
    assert_int_equal(nrf_fake_uarte0.TXD_MAXCNT, sizeof a);
    assert_int_equal(uarte_write(&uart, b, sizeof b), (int32_t)sizeof b);
    assert_int_equal(uarte_write(&uart, c, sizeof c), (int32_t)sizeof c);
    assert_true(uarte_tx_busy(&uart));
    uint8_t out[200];
    const size_t n = test_uarte_drain_tx(out, sizeof out, uart_irq);
    assert_int_equal(n, sizeof a + sizeof b + sizeof c);
    assert_memory_equal(out, a, sizeof a);
    assert_memory_equal(&out[sizeof a], b, sizeof b);
    assert_memory_equal(&out[sizeof a + sizeof b], c, sizeof c);
    assert_false(uarte_tx_busy(&uart));
    assert_int_equal(nrf_fake_uarte0.TASKS_STOPTX, 1u); /* stopped after the last */
    assert_int_equal(nrf_fake.primask, 0u);
}

static void test_uarte_tx_full_or_oversized_is_dropped(void **state)
{
    (void)state;
    uarte_init(&uart, 6u, 8u);
    const uint8_t f[10] = { 9 };
    for (uint32_t i = 0u; i < UARTE_TX_SLOTS; ++i) {
        assert_int_equal(uarte_write(&uart, f, sizeof f), 10);
    }
    assert_int_equal(uarte_write(&uart, f, sizeof f), -1);
    uint8_t big[UARTE_TX_SLOT_MAX + 1u] = { 0 };
    assert_int_equal(uarte_write(&uart, big, sizeof big), -1);
    assert_int_equal(uarte_write(&uart, f, 0u), -1);
    assert_int_equal(uart.tx_dropped, 3u);
    uint8_t out[100];
    assert_int_equal(test_uarte_drain_tx(out, sizeof out, uart_irq), UARTE_TX_SLOTS * 10u);
    assert_int_equal(uarte_write(&uart, f, sizeof f), 10); /* room again */
}

static void test_uarte_rx_chunks_idle_flush(void **state)
{
    (void)state;
    uarte_init(&uart, 6u, 8u);
    uint8_t in[21];
    for (uint32_t i = 0u; i < sizeof in; ++i) {
        in[i] = (uint8_t)(0xA0u + i);
    }
    uint32_t filled = 0u;
    nrf_fake_uarte0.TASKS_STARTRX = 0u;
    /* 20 bytes: one full chunk (ENDRX, restarted at once), 4 waiting in the next. */
    assert_int_equal(test_uarte_rx(in, 20u, &filled, uart_irq), 4u);
    assert_int_equal(nrf_fake_uarte0.TASKS_STARTRX, 1u);
    uint8_t out[64];
    assert_int_equal(uarte_read(&uart, out, sizeof out), 16u);
    assert_memory_equal(out, in, 16u);
    assert_true(uarte_rx_pending(&uart));
    /* The line is busy at t = 100; quiet for less than UARTE_RX_IDLE_MS: no stop yet. */
    uarte_poll(&uart, 100u);
    uarte_poll(&uart, 101u);
    assert_int_equal(nrf_fake_uarte0.TASKS_STOPRX, 0u);
    uarte_poll(&uart, 100u + UARTE_RX_IDLE_MS);
    assert_int_equal(nrf_fake_uarte0.TASKS_STOPRX, 1u);
    assert_int_equal(uart.rx_state, UARTE_RX_STOPPING);
    /* ENDRX with the 4, RXTO, FLUSHRX brings the byte still in the FIFO, then STARTRX. */
    nrf_fake_uarte0.TASKS_STARTRX = 0u;
    test_uarte_stop_flush(&filled, &in[20], 1u, uart_irq);
    assert_int_equal(uart.rx_state, UARTE_RX_RUN);
    assert_int_equal(nrf_fake_uarte0.TASKS_STARTRX, 1u);
    assert_int_equal(uarte_read(&uart, out, sizeof out), 5u);
    assert_memory_equal(out, &in[16], 5u);
    assert_false(uarte_rx_pending(&uart));
    assert_false(uarte_rx_available(&uart));
}

static void test_uarte_rx_ring_full_counts_lost(void **state)
{
    (void)state;
    uarte_init(&uart, 6u, 8u);
    uint8_t in[UARTE_RX_RING + 3u * UARTE_RX_CHUNK];
    for (uint32_t i = 0u; i < sizeof in; ++i) {
        in[i] = (uint8_t)i;
    }
    uint32_t filled = 0u;
    test_uarte_rx(in, sizeof in, &filled, uart_irq);
    assert_int_equal(uart.rx_lost, 3u * UARTE_RX_CHUNK);
    uint8_t out[UARTE_RX_RING + 10u];
    assert_int_equal(uarte_read(&uart, out, sizeof out), UARTE_RX_RING);
    assert_memory_equal(out, in, UARTE_RX_RING); /* the oldest kept, in order */
}

static void test_uarte_line_errors_counted(void **state)
{
    (void)state;
    uarte_init(&uart, 6u, 8u);
    nrf_fake_uarte0.ERRORSRC = 0x5u; /* overrun + framing */
    nrf_fake_uarte0.EVENTS_ERROR = 1u;
    uarte_isr(&uart);
    assert_int_equal(uart.rx_line_errors, 1u);
    assert_int_equal(nrf_fake_uarte0.ERRORSRC, 0x5u); /* written back: write-1-to-clear */
    assert_int_equal(nrf_fake_uarte0.EVENTS_ERROR, 0u);
}

/* ---------------------------------------------------------------- RADIO */

static uint32_t fake_ms = 1234u;
static uint32_t radio_now(void *ctx)
{
    (void)ctx;
    return fake_ms;
}

static void radio_irq(void)
{
    radio_isr(&radio);
}

/* After start-up: the fake radio has taken the DISABLE of the driver's reset. */
static void radio_started(void)
{
    nrf_fake_radio.TASKS_DISABLE = 0u;
}

static void test_radio_ble_setup(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    assert_int_equal(nrf_fake_radio.POWER, 1u);
    assert_int_equal(nrf_fake_radio.MODE, NRF_RADIO_MODE_BLE_1MBIT);
    assert_int_equal(nrf_fake_radio.PCNF0, 0x00000108u);   /* LFLEN 8, S0LEN 1, 8-bit preamble */
    assert_int_equal(nrf_fake_radio.PCNF1, 0x020300FFu);   /* WHITEEN, BALEN 3, MAXLEN 255 */
    assert_int_equal(nrf_fake_radio.BASE0, 0x89BED600u);   /* access address 0x8E89BED6 */
    assert_int_equal(nrf_fake_radio.PREFIX0, 0x8Eu);
    assert_int_equal(nrf_fake_radio.RXADDRESSES, 1u);
    assert_int_equal(nrf_fake_radio.CRCCNF, 0x103u);       /* 3 bytes, address skipped */
    assert_int_equal(nrf_fake_radio.CRCPOLY, 0x00065Bu);
    assert_int_equal(nrf_fake_radio.CRCINIT, 0x555555u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 2u);        /* channel 37 = 2402 MHz */
    assert_int_equal(nrf_fake_radio.DATAWHITEIV, 37u);
    assert_int_equal(nrf_fake_radio.SHORTS, NRF_RADIO_SHORT_READY_START | NRF_RADIO_SHORT_END_DISABLE
                                               | NRF_RADIO_SHORT_ADDRESS_RSSISTART
                                               | NRF_RADIO_SHORT_DISABLED_RSSISTOP);
    assert_int_equal(nrf_fake_radio.INTENSET, NRF_RADIO_INT_DISABLED);
    assert_ptr_equal(nrf_fake_dma_ptr(nrf_fake_radio.PACKETPTR), radio.buf.bytes);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
}

static void test_radio_good_packet_is_queued(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 0x1234u);
    fake_ms = 5000u;
    test_radio_packet(pdu, n, 1, 57, radio_irq);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);       /* listening again */
    assert_int_equal(nrf_fake_radio.EVENTS_END, 0u);       /* events cleared */
    assert_int_equal(nrf_fake_radio.EVENTS_DISABLED, 0u);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.rssi_dbm, -57);                     /* -RSSISAMPLE dBm */
    assert_int_equal(p.channel, 37u);
    assert_int_equal(p.tick_ms, 5000u);
    assert_int_equal(p.mode, RADIO_MODE_BLE);
    assert_int_equal(p.len, n);
    assert_memory_equal(p.data, pdu, n);
    assert_int_equal(radio_pop(&radio, &p), 0);
    assert_int_equal(radio.packets, 1u);
}

static void test_radio_crc_error_counted_and_dropped(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 7u);
    test_radio_packet(pdu, n, 0, 40, radio_irq);
    assert_int_equal(radio.crc_errors, 1u);
    assert_false(radio_pending(&radio));
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
}

static void test_radio_without_rssi_sample(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 7u);
    test_radio_packet(pdu, n, 1, -1, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.rssi_dbm, RADIO_RSSI_NONE); /* the core counts it as dropped */
    /* RSSISAMPLE is 7 bits: 127 -> -127 dBm. */
    test_radio_packet(pdu, n, 1, 0xFF, radio_irq);
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.rssi_dbm, -127);
}

static void disabled_without_packet(void)
{
    nrf_fake_radio.TASKS_DISABLE = 0u;
    nrf_fake_radio.TASKS_RXEN = 0u;
    nrf_fake_radio.EVENTS_DISABLED = 1u;
    radio_isr(&radio);
}

static void test_radio_hops_37_38_39_while_listening(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    radio_started();
    static const uint8_t ch[] = { 38u, 39u, 37u, 38u };
    static const uint8_t freq[] = { 26u, 80u, 2u, 26u };
    for (uint32_t i = 0u; i < sizeof ch; ++i) {
        radio_hop(&radio);
        assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 1u); /* no packet coming: at once */
        disabled_without_packet();
        assert_int_equal(radio.channel, ch[i]);
        assert_int_equal(nrf_fake_radio.FREQUENCY, freq[i]);
        assert_int_equal(nrf_fake_radio.DATAWHITEIV, ch[i]);
        assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
    }
    assert_int_equal(radio.hops, 4u);
    assert_false(radio_pending(&radio));
}

static void test_radio_hop_waits_for_packet_in_progress(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    radio_started();
    nrf_fake_radio.EVENTS_ADDRESS = 1u; /* a packet is coming in on 37 */
    radio_hop(&radio);
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u); /* not cut */
    radio_hop(&radio);                                   /* a second tick: one hop only */
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 9u);
    test_radio_packet(pdu, n, 1, 60, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.channel, 37u);                    /* labelled where it was heard */
    assert_int_equal(radio.channel, 38u);                /* then the hop */
    assert_int_equal(nrf_fake_radio.FREQUENCY, 26u);
    assert_int_equal(radio.hops, 1u);
}

static void test_radio_queue_full_and_filter(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, beacon_accept, NULL);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 1u);
    for (uint32_t i = 0u; i < RADIO_QUEUE + 2u; ++i) {
        test_radio_packet(pdu, n, 1, 50, radio_irq);
    }
    assert_int_equal(radio.queue_full, 2u);
    uint8_t other[64];
    memcpy(other, pdu, n);
    other[15] = 'X'; /* not "PF": not ours, not queued, not a loss */
    test_radio_packet(other, n, 1, 50, radio_irq);
    assert_int_equal(radio.rejected, 1u);
    assert_int_equal(radio.queue_full, 2u);
    radio_packet_t p;
    uint32_t popped = 0u;
    while (radio_pop(&radio, &p) != 0) {
        ++popped;
    }
    assert_int_equal(popped, RADIO_QUEUE);
}

static void test_radio_long_packet_is_truncated_not_overrun(void **state)
{
    (void)state;
    radio_start_ble(&radio, radio_now, NULL, NULL);
    uint8_t pdu[2u + 255u];
    memset(pdu, 0xAB, sizeof pdu);
    pdu[0] = 0x07u; /* ADV_EXT_IND */
    pdu[1] = 255u;
    test_radio_packet(pdu, sizeof pdu, 1, 50, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.len, RADIO_PKT_MAX);
    assert_int_equal(p.full_len, 257u);
}

static void test_radio_ieee802154(void **state)
{
    (void)state;
    assert_int_equal(radio_start_ieee802154(&radio, 10u, radio_now, NULL, NULL), -1);
    assert_int_equal(radio_start_ieee802154(&radio, 27u, radio_now, NULL, NULL), -1);
    assert_int_equal(radio_start_ieee802154(&radio, 15u, radio_now, NULL, NULL), 0);
    radio_started();
    assert_int_equal(nrf_fake_radio.MODE, NRF_RADIO_MODE_IEEE802154_250KBIT);
    assert_int_equal(nrf_fake_radio.PCNF0, 0x06000008u); /* LFLEN 8, 32-bit zero preamble, CRCINC */
    assert_int_equal(nrf_fake_radio.PCNF1, 127u);
    assert_int_equal(nrf_fake_radio.CRCCNF, 0x202u);
    assert_int_equal(nrf_fake_radio.CRCPOLY, 0x11021u);
    assert_int_equal(nrf_fake_radio.CRCINIT, 0u);
    assert_int_equal(nrf_fake_radio.SFD, 0xA7u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 25u); /* 2425 MHz */
    uint8_t ram[64];
    const size_t n = test_154_beacon(ram, 0xBEEFu, 40u);
    fake_ms = 77u;
    test_radio_packet(ram, n, 1, -1, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.rssi_dbm, -92 + 40);
    assert_int_equal(p.lqi, 160u);
    assert_int_equal(p.channel, 15u);
    assert_int_equal(p.len, n - 3u);     /* MPDU without the FCS */
    assert_memory_equal(p.data, &ram[1], n - 3u);
    radio_hop(&radio);                   /* no hopping in 802.15.4 */
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u);
    /* A PHR too short to hold an FCS is dropped, not read out of bounds. */
    ram[0] = 2u;
    test_radio_packet(ram, 3u, 1, -1, radio_irq);
    assert_false(radio_pending(&radio));
    assert_int_equal(radio.rejected, 1u);
}

static void test_rssi_conversions(void **state)
{
    (void)state;
    for (uint32_t v = 0u; v < 256u; ++v) {
        const int32_t dbm = -92 + (int32_t)v;
        assert_int_equal(radio_ieee802154_dbm((uint8_t)v), (dbm > 126) ? 126 : dbm);
        assert_int_equal(radio_ieee802154_lqi((uint8_t)v), (4u * v > 255u) ? 255u : 4u * v);
    }
    for (uint8_t ch = 11u; ch <= 26u; ++ch) {
        assert_int_equal(radio_frequency(RADIO_MODE_IEEE802154, ch), 5u + 5u * (ch - 11u));
    }
    assert_int_equal(radio_frequency(RADIO_MODE_BLE, 0u), 0xFFu);
    assert_int_equal(radio_ble_next_channel(39u), 37u);
    assert_int_equal(radio_ble_next_channel(5u), 37u);
}

/* ---------------------------------------------------------------- beacon */

static void test_beacon_ble_formats(void **state)
{
    (void)state;
    uint8_t pdu[64];
    uint16_t seq = 0u;
    size_t n = test_ble_beacon(pdu, 0xABCDu);
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), 1);
    assert_int_equal(seq, 0xABCDu);
    for (uint8_t type = 0u; type < 16u; ++type) { /* advertising PDUs that carry AdvData */
        pdu[0] = type;
        const int want = (type == 0u || type == 2u || type == 4u || type == 6u);
        assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), want);
    }
    n = test_ble_beacon(pdu, 1u);
    pdu[12] = 0xFEu; /* company id 0xFFFE */
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), 0);
    n = test_ble_beacon(pdu, 1u);
    pdu[14] = 'Q';
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), 0);
    n = test_ble_beacon(pdu, 1u);
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)(n - 1u), &seq), 0); /* shorter than its length */
    pdu[1] = 38u;                                                        /* longer than legacy */
    assert_int_equal(beacon_ble_seq(pdu, 60u, &seq), 0);
    n = test_ble_beacon(pdu, 1u);
    pdu[8] = 0u;                        /* a zero-length AD ends the data before ours */
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), 0);
    n = test_ble_beacon(pdu, 1u);
    pdu[11] = 8u;                       /* ours claims a byte past the end */
    assert_int_equal(beacon_ble_seq(pdu, (uint8_t)n, &seq), 0);
    assert_int_equal(beacon_ble_seq(NULL, 10u, &seq), 0);
}

static void test_beacon_154_formats(void **state)
{
    (void)state;
    uint8_t ram[64];
    uint16_t seq = 0u;
    size_t n = test_154_beacon(ram, 0x0102u, 0u);
    uint8_t *const m = &ram[1];
    const uint8_t len = (uint8_t)(n - 3u);
    assert_int_equal(beacon_ieee802154_seq(m, len, &seq), 1);
    assert_int_equal(seq, 0x0102u);
    /* Without PAN id compression: a source PAN id (2 bytes) before the source address. */
    const uint8_t nocomp[] = { 0x01, 0x88, 1, 0xCD, 0xAB, 0xFF, 0xFF, 0xCD, 0xAB, 0x34, 0x12, 'P', 'F', 9, 0 };
    assert_int_equal(beacon_ieee802154_seq(nocomp, sizeof nocomp, &seq), 1);
    assert_int_equal(seq, 9u);
    /* Extended (8-byte) source address, compressed PAN. */
    const uint8_t ext[] = { 0x41, 0xC8, 1, 0xCD, 0xAB, 0xFF, 0xFF, 1, 2, 3, 4, 5, 6, 7, 8, 'P', 'F', 0x34, 0x12 };
    assert_int_equal(beacon_ieee802154_seq(ext, sizeof ext, &seq), 1);
    assert_int_equal(seq, 0x1234u);
    uint8_t bad[sizeof ext];
    memcpy(bad, ext, sizeof ext);
    bad[0] = 0x49u; /* security enabled */
    assert_int_equal(beacon_ieee802154_seq(bad, sizeof bad, &seq), 0);
    bad[0] = 0x40u; /* beacon frame type */
    assert_int_equal(beacon_ieee802154_seq(bad, sizeof bad, &seq), 0);
    memcpy(bad, ext, sizeof ext);
    bad[1] = 0x48u; /* source mode 1: reserved */
    assert_int_equal(beacon_ieee802154_seq(bad, sizeof bad, &seq), 0);
    assert_int_equal(beacon_ieee802154_seq(ext, sizeof ext - 1u, &seq), 0); /* truncated */
}

static void test_beacon_reading(void **state)
{
    (void)state;
    radio_packet_t p;
    memset(&p, 0, sizeof p);
    p.len = (uint8_t)test_ble_beacon(p.data, 500u);
    p.tick_ms = 99u;
    p.rssi_dbm = -61;
    p.channel = 39u;
    p.mode = RADIO_MODE_BLE;
    pfdoa_radio_reading_t r;
    assert_int_equal(beacon_reading(&p, &r), 1);
    assert_int_equal(r.seq, 500u);
    assert_int_equal(r.tick_ms, 99u);
    assert_int_equal(r.rssi_dbm, -61);
    assert_int_equal(r.channel, 39u);
    assert_int_equal(r.lqi, 0u);
    assert_int_equal(r.radio, PFDOA_RADIO_BLE);
    p.mode = RADIO_MODE_IEEE802154; /* a BLE PDU is no 802.15.4 beacon */
    assert_int_equal(beacon_reading(&p, &r), 0);
}

static void test_beacon_parsers_random_bytes(void **state)
{
    (void)state;
    uint32_t s = 12345u;
    uint32_t hits = 0u;
    for (uint32_t iter = 0u; iter < 20000u; ++iter) {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        const uint8_t len = (uint8_t)(s % (RADIO_PKT_MAX + 1u));
        uint8_t *const buf = malloc(len ? len : 1u); /* exact size: ASan sees any overread */
        for (uint32_t i = 0u; i < len; ++i) {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            buf[i] = (uint8_t)(s >> 8);
        }
        if (len > 1u && (iter & 1u)) {
            buf[1] = (uint8_t)(len - 2u); /* a consistent BLE length byte, more often */
        }
        uint16_t seq;
        hits += (uint32_t)beacon_ble_seq(buf, len, &seq);
        hits += (uint32_t)beacon_ieee802154_seq(buf, len, &seq);
        free(buf);
    }
    assert_true(hits < 20000u);
}

/* ---------------------------------------------------------------- flash store */

static void test_flash_store_log(void **state)
{
    (void)state;
    uint8_t out[7];
    assert_int_equal(flash_store_records(FLASH_LOG_CONFIG), 256u);   /* 16-byte records */
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), -1); /* erased page */
    const uint8_t a[7] = { 1, 2, 3, 4, 5, 6, 7 };
    const uint8_t b[7] = { 7, 6, 5, 4, 3, 2, 1 };
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, a, sizeof a), 0);
    assert_int_equal(nrf_fake.flash_writes, 4u);
    assert_int_equal(nrf_fake_nvmc.CONFIG, NRF_NVMC_CONFIG_REN);
    assert_int_equal(nrf_fake_store_pages[0][0], 0x50464431u);       /* "PFD1" in the last page */
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, a, 7u);
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, 6u), -1); /* wrong length */
    assert_int_equal(flash_store_load(FLASH_LOG_FILTERS, out, sizeof out), -1); /* the other log */
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, a, sizeof a), 0);
    assert_int_equal(nrf_fake.flash_writes, 4u);       /* unchanged: not written again */
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, b, sizeof b), 0);
    assert_int_equal(nrf_fake.flash_writes, 8u);       /* appended */
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, b, 7u);
    /* Fill the page: one erase after flash_store_records() records. */
    uint8_t c[7] = { 0 };
    for (uint32_t i = 2u; i < flash_store_records(FLASH_LOG_CONFIG) + 3u; ++i) {
        c[0] = (uint8_t)i;
        c[1] = (uint8_t)(i >> 8);
        assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, c, sizeof c), 0);
    }
    assert_int_equal(nrf_fake.flash_erases, 1u);
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, c, 7u);
    assert_int_equal(nrf_fake.flash_violations, 0u); /* WEN/EEN set, only 1 -> 0 bits */
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, a, 0u), FLASH_STORE_ERR_ARG);
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, a, FLASH_STORE_CONFIG_MAX + 1u), FLASH_STORE_ERR_ARG);
    assert_int_equal(flash_store_save((flash_log_t)2, a, sizeof a), FLASH_STORE_ERR_ARG);
    assert_int_equal(flash_store_load((flash_log_t)2, out, sizeof out), -1);
}

static void test_flash_store_filter_table_beside_the_config(void **state)
{
    (void)state;
    uint8_t table[FLASH_STORE_FILTERS_MAX];
    uint8_t out[FLASH_STORE_FILTERS_MAX];
    const uint8_t cfg[7] = { 1, 2, 3, 4, 5, 6, 7 };
    for (uint32_t k = 0u; k < sizeof table; ++k) {
        table[k] = (uint8_t)(k * 7u + 1u);
    }
    assert_int_equal(flash_store_records(FLASH_LOG_FILTERS), 40u); /* 100-byte records */
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, cfg, sizeof cfg), 0);
    assert_int_equal(flash_store_save(FLASH_LOG_FILTERS, table, sizeof table), 0);
    assert_int_equal(nrf_fake.flash_writes, 4u + 25u);
    assert_int_equal(nrf_fake_store_pages[1][0], 0x50464631u);     /* "PFF1" in the page before */
    assert_int_equal(flash_store_load(FLASH_LOG_FILTERS, out, sizeof out), 0);
    assert_memory_equal(out, table, sizeof table);
    /* Wear the filter page through two erases: the configuration stays. */
    for (uint32_t i = 0u; i < 2u * flash_store_records(FLASH_LOG_FILTERS) + 1u; ++i) {
        table[0] = (uint8_t)i;
        assert_int_equal(flash_store_save(FLASH_LOG_FILTERS, table, sizeof table), 0);
    }
    assert_int_equal(nrf_fake.flash_erases, 2u);
    assert_int_equal(flash_store_load(FLASH_LOG_FILTERS, out, sizeof out), 0);
    assert_memory_equal(out, table, sizeof table);
    uint8_t got[7];
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, got, sizeof got), 0);
    assert_memory_equal(got, cfg, sizeof cfg);
    assert_int_equal(nrf_fake.flash_violations, 0u);
    assert_int_equal(flash_store_save(FLASH_LOG_FILTERS, table, FLASH_STORE_FILTERS_MAX + 1u), FLASH_STORE_ERR_ARG);
    /* Power lost while the next record was written (slot 2; 0 and 1 hold the last two):
     * magic and data words, no length/CRC word. It is not the table; the next store goes
     * after it. */
    nrf_fake_store_pages[1][2u * 25u] = 0x50464631u;
    for (uint32_t w = 1u; w < 24u; ++w) {
        nrf_fake_store_pages[1][2u * 25u + w] = 0u;
    }
    assert_int_equal(flash_store_load(FLASH_LOG_FILTERS, out, sizeof out), 0);
    assert_memory_equal(out, table, sizeof table);
    table[1] ^= 0xFFu;
    assert_int_equal(flash_store_save(FLASH_LOG_FILTERS, table, sizeof table), 0);
    assert_int_equal(nrf_fake_store_pages[1][3u * 25u], 0x50464631u);
    assert_int_equal(flash_store_load(FLASH_LOG_FILTERS, out, sizeof out), 0);
    assert_memory_equal(out, table, sizeof table);
    assert_int_equal(nrf_fake.flash_violations, 0u);
}

static void test_flash_store_torn_record_is_ignored(void **state)
{
    (void)state;
    const uint8_t a[7] = { 1, 2, 3, 4, 5, 6, 7 };
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, a, sizeof a), 0);
    /* Power lost after three words of the next record: its length/CRC word is erased. */
    nrf_fake_store_pages[0][4] = 0x50464431u;
    nrf_fake_store_pages[0][5] = 0x01010101u;
    nrf_fake_store_pages[0][6] = 0x01010101u;
    uint8_t out[7];
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, a, 7u);
    /* A flipped data bit fails the CRC. */
    const uint8_t b[7] = { 9, 9, 9, 9, 9, 9, 9 };
    assert_int_equal(flash_store_save(FLASH_LOG_CONFIG, b, sizeof b), 0); /* goes after the torn one */
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, b, 7u);
    nrf_fake_store_pages[0][9] ^= 0x100u;
    assert_int_equal(flash_store_load(FLASH_LOG_CONFIG, out, sizeof out), 0);
    assert_memory_equal(out, a, 7u);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_tick_conversion_is_floor_exact, setup),
        cmocka_unit_test_setup(test_tick_start_configures_rtc1, setup),
        cmocka_unit_test_setup(test_tick_24bit_wrap_is_continuous, setup),
        cmocka_unit_test_setup(test_tick_pending_overflow_counted_once, setup),
        cmocka_unit_test_setup(test_tick_u32_ms_wrap, setup),
        cmocka_unit_test_setup(test_tick_compare_and_isr, setup),
        cmocka_unit_test_setup(test_clock_hfxo, setup),
        cmocka_unit_test_setup(test_clock_lfclk_falls_back_to_rc, setup),
        cmocka_unit_test_setup(test_clock_rc_calibration_schedule, setup),
        cmocka_unit_test_setup(test_uarte_init, setup),
        cmocka_unit_test_setup(test_uarte_tx_whole_frames_in_order, setup),
        cmocka_unit_test_setup(test_uarte_tx_full_or_oversized_is_dropped, setup),
        cmocka_unit_test_setup(test_uarte_rx_chunks_idle_flush, setup),
        cmocka_unit_test_setup(test_uarte_rx_ring_full_counts_lost, setup),
        cmocka_unit_test_setup(test_uarte_line_errors_counted, setup),
        cmocka_unit_test_setup(test_radio_ble_setup, setup),
        cmocka_unit_test_setup(test_radio_good_packet_is_queued, setup),
        cmocka_unit_test_setup(test_radio_crc_error_counted_and_dropped, setup),
        cmocka_unit_test_setup(test_radio_without_rssi_sample, setup),
        cmocka_unit_test_setup(test_radio_hops_37_38_39_while_listening, setup),
        cmocka_unit_test_setup(test_radio_hop_waits_for_packet_in_progress, setup),
        cmocka_unit_test_setup(test_radio_queue_full_and_filter, setup),
        cmocka_unit_test_setup(test_radio_long_packet_is_truncated_not_overrun, setup),
        cmocka_unit_test_setup(test_radio_ieee802154, setup),
        cmocka_unit_test_setup(test_rssi_conversions, setup),
        cmocka_unit_test_setup(test_beacon_ble_formats, setup),
        cmocka_unit_test_setup(test_beacon_154_formats, setup),
        cmocka_unit_test_setup(test_beacon_reading, setup),
        cmocka_unit_test_setup(test_beacon_parsers_random_bytes, setup),
        cmocka_unit_test_setup(test_flash_store_log, setup),
        cmocka_unit_test_setup(test_flash_store_filter_table_beside_the_config, setup),
        cmocka_unit_test_setup(test_flash_store_torn_record_is_ignored, setup),
    };
    return cmocka_run_group_tests_name("nrf52840 drivers", tests, NULL, NULL);
}
