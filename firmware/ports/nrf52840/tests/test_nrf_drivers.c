/*
 * The nRF52840 port's drivers on the register fake: RTC tick (24-bit and 32-bit wraps),
 * clocks, UARTE (TX slots, RX chunks with the ENDRX/RXTO/FLUSHRX sequence), RADIO (BLE
 * and 802.15.4 set-up, the receive state machine, channel hopping, CRC failures, RSSI),
 * and the flash store (configuration and filter table).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "clock.h"
#include "fake_nrf.h"
#include "flash_store.h"
#include "nrf_test_support.h"
#include "pfdoa_peer.h"
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
    assert_int_equal(nrf_fake_p0.OUTSET, 1u << 6);                           /* TXD idles high */
    assert_int_equal(nrf_fake_p0.PIN_CNF[6], NRF_GPIO_CNF_OUTPUT);
    assert_int_equal(nrf_fake_p0.PIN_CNF[8], NRF_GPIO_CNF_INPUT | NRF_GPIO_CNF_PULLUP); /* no float */
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

static const radio_hooks_t clock_only = { radio_now, NULL, NULL, NULL };

/* An accept hook: BLE PDUs whose AdvA starts with 0x11 (the test beacon's). */
static uint32_t hopped_calls;
static int accept_ours(const radio_packet_t *pkt, void *ctx)
{
    (void)ctx;
    return pkt->len > 2u && pkt->data[2] == 0x11u;
}

static void count_hop(void *ctx)
{
    (void)ctx;
    ++hopped_calls;
}

static const radio_hooks_t filtering = { radio_now, accept_ours, count_hop, NULL };
static const radio_hooks_t take_all = { radio_now, NULL, count_hop, NULL };

/* After start-up: the fake radio has taken the DISABLE of the driver's reset. */
static void radio_started(void)
{
    nrf_fake_radio.TASKS_DISABLE = 0u;
}

static void test_radio_ble_setup(void **state)
{
    (void)state;
    radio_start_ble(&radio, &clock_only);
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
    radio_start_ble(&radio, &clock_only);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 0x1234u, 0u);
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
    radio_start_ble(&radio, &clock_only);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 7u, 0u);
    test_radio_packet(pdu, n, 0, 40, radio_irq);
    assert_int_equal(radio.crc_errors, 1u);
    assert_false(radio_pending(&radio));
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
}

static void test_radio_without_rssi_sample(void **state)
{
    (void)state;
    radio_start_ble(&radio, &clock_only);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 7u, 0u);
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
    radio_start_ble(&radio, &clock_only);
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
    radio_start_ble(&radio, &clock_only);
    radio_started();
    nrf_fake_radio.EVENTS_ADDRESS = 1u; /* a packet is coming in on 37 */
    radio_hop(&radio);
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u); /* not cut */
    radio_hop(&radio);                                   /* a second tick: one hop only */
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 9u, 0u);
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
    radio_start_ble(&radio, &filtering);
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 1u, 0u);
    for (uint32_t i = 0u; i < RADIO_QUEUE + 2u; ++i) {
        test_radio_packet(pdu, n, 1, 50, radio_irq);
    }
    assert_int_equal(radio.queue_full, 2u);
    uint8_t other[64];
    memcpy(other, pdu, n);
    other[2] = 0x99u; /* another AdvA: not taken, not queued, not a loss */
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

static void test_radio_hit_hops_at_once(void **state)
{
    (void)state;
    radio_start_ble(&radio, &filtering);
    radio_started();
    hopped_calls = 0u;
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 5u, 0u);
    uint8_t other[64];
    memcpy(other, pdu, n);
    other[2] = 0x99u;
    /* A stranger on 37: the radio dwells (no hop, no restart of the dwell timer). */
    assert_int_equal(test_radio_on_air(other, n, RADIO_MODE_BLE, 37u, 1, 50, radio_irq), 1);
    assert_int_equal(radio.channel, 37u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 2u);
    assert_int_equal(hopped_calls, 0u);
    /* A CRC failure of ours: no hit either. */
    assert_int_equal(test_radio_on_air(pdu, n, RADIO_MODE_BLE, 37u, 0, 50, radio_irq), 1);
    assert_int_equal(radio.channel, 37u);
    /* One advertising event of ours, 37 -> 38 -> 39, no hop timer in between: each hit
     * retunes to the next channel before the next PDU, all three are heard. */
    static const uint8_t chans[3] = { 37u, 38u, 39u };
    static const uint8_t next_freq[3] = { 26u, 80u, 2u };
    for (uint32_t i = 0u; i < 3u; ++i) {
        fake_ms = 100u + i;
        assert_int_equal(test_radio_on_air(pdu, n, RADIO_MODE_BLE, chans[i], 1, 60, radio_irq), 1);
        assert_int_equal(nrf_fake_radio.FREQUENCY, next_freq[i]);
        assert_int_equal(nrf_fake_radio.DATAWHITEIV, (i < 2u) ? chans[i] + 1u : 37u);
        assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
    }
    assert_int_equal(radio.hit_hops, 3u);
    assert_int_equal(radio.hops, 3u);
    assert_int_equal(hopped_calls, 3u);
    radio_packet_t p;
    for (uint32_t i = 0u; i < 3u; ++i) {
        assert_int_equal(radio_pop(&radio, &p), 1);
        assert_int_equal(p.channel, chans[i]); /* each labelled where it was heard */
        assert_int_equal(p.tick_ms, 100u + i);
    }
    /* Without the hop on a hit the radio would still be on 37 for the 38 and 39 PDUs. */
    assert_int_equal(test_radio_on_air(pdu, n, RADIO_MODE_BLE, 38u, 1, 60, radio_irq), 0);
}

static void test_radio_hit_while_a_hop_is_pending_hops_once(void **state)
{
    (void)state;
    radio_start_ble(&radio, &filtering);
    radio_started();
    hopped_calls = 0u;
    nrf_fake_radio.EVENTS_ADDRESS = 1u; /* our packet is coming in on 37 ... */
    radio_hop(&radio);                  /* ... when the dwell ends */
    uint8_t pdu[64];
    const size_t n = test_ble_beacon(pdu, 6u, 0u);
    test_radio_packet(pdu, n, 1, 60, radio_irq);
    assert_int_equal(radio.channel, 38u); /* one hop, not two */
    assert_int_equal(radio.hops, 1u);
    assert_int_equal(hopped_calls, 1u);   /* and a fresh dwell on 38 */
}

static void test_radio_too_long_packet_is_rejected_not_cut(void **state)
{
    (void)state;
    radio_start_ble(&radio, &clock_only);
    uint8_t pdu[2u + 255u];
    memset(pdu, 0xAB, sizeof pdu);
    pdu[0] = 0x07u; /* ADV_EXT_IND */
    pdu[1] = 255u;
    test_radio_packet(pdu, sizeof pdu, 1, 50, radio_irq);
    assert_false(radio_pending(&radio));
    assert_int_equal(radio.rejected, 1u);
    /* RADIO_PKT_MAX bytes still fit whole. */
    pdu[1] = (uint8_t)(RADIO_PKT_MAX - 2u);
    test_radio_packet(pdu, RADIO_PKT_MAX, 1, 50, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.len, RADIO_PKT_MAX);
    assert_memory_equal(p.data, pdu, RADIO_PKT_MAX);
}

static void test_radio_ieee802154(void **state)
{
    (void)state;
    assert_int_equal(radio_start_ieee802154(&radio, 10u, &clock_only), -1);
    assert_int_equal(radio_start_ieee802154(&radio, 27u, &clock_only), -1);
    assert_int_equal(radio_start_ieee802154(&radio, 15u, &take_all), 0);
    radio_started();
    hopped_calls = 0u;
    assert_int_equal(nrf_fake_radio.MODE, NRF_RADIO_MODE_IEEE802154_250KBIT);
    assert_int_equal(nrf_fake_radio.PCNF0, 0x06000008u); /* LFLEN 8, 32-bit zero preamble, CRCINC */
    assert_int_equal(nrf_fake_radio.PCNF1, 127u);
    assert_int_equal(nrf_fake_radio.CRCCNF, 0x202u);
    assert_int_equal(nrf_fake_radio.CRCPOLY, 0x11021u);
    assert_int_equal(nrf_fake_radio.CRCINIT, 0u);
    assert_int_equal(nrf_fake_radio.SFD, 0xA7u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 25u); /* 2425 MHz */
    uint8_t ram[140];
    const size_t n = test_154_beacon(ram, 0xBEEFu, 3u, 40u);
    assert_int_equal(n, 3u + PFDOA_BEACON_MPDU_LEN);
    fake_ms = 77u;
    assert_int_equal(test_radio_on_air(ram, n, RADIO_MODE_IEEE802154, 15u, 1, -1, radio_irq), 1);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.rssi_dbm, -92 + 40);
    assert_int_equal(p.lqi, 160u);
    assert_int_equal(p.channel, 15u);
    assert_int_equal(p.len, n - 3u);     /* MPDU without the FCS */
    assert_memory_equal(p.data, &ram[1], n - 3u);
    radio_hop(&radio);                   /* no hopping in 802.15.4, by timer or by hit */
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u);
    assert_int_equal(nrf_fake_radio.FREQUENCY, 25u);
    assert_int_equal(hopped_calls, 0u);
    assert_int_equal(radio.hops, 0u);
    /* The longest frame (PHR 127) is taken whole. */
    memset(&ram[1], 0x5Cu, 125u);
    ram[0] = 127u;
    test_radio_packet(ram, 128u, 1, -1, radio_irq);
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.len, 125u);
    /* A PHR too short to hold an FCS is dropped, not read out of bounds. */
    ram[0] = 2u;
    test_radio_packet(ram, 3u, 1, -1, radio_irq);
    assert_false(radio_pending(&radio));
    assert_int_equal(radio.rejected, 1u);
}

/* The radio as the hardware ends a transmission: the DISABLED event (END_DISABLE short). */
static void tx_ends(void)
{
    nrf_fake_radio.TASKS_TXEN = 0u;
    nrf_fake_radio.TASKS_RXEN = 0u;
    nrf_fake_radio.EVENTS_END = 1u;
    nrf_fake_radio.EVENTS_DISABLED = 1u;
    radio_isr(&radio);
}

static void test_radio_sends_an_advertising_event_then_listens_again(void **state)
{
    (void)state;
    radio_start_ble(&radio, &clock_only);
    radio_started();
    radio_hop(&radio);
    disabled_without_packet(); /* listening on 38 now */
    uint8_t pdu[PFDOA_PEER_FRAME_MAX];
    static const uint8_t addr[8] = {5u, 0u, 0u, 0u, 0u, 0xC5u};
    const int32_t n = pfdoa_peer_frame(PFDOA_RADIO_BLE, addr, 5u, 0x0102u, pdu, sizeof pdu);
    assert_true(n > 0);
    assert_int_equal(radio_send(&radio, pdu, (size_t)n - 1u), -1); /* the length byte says otherwise */
    nrf_fake_radio.TASKS_DISABLE = 0u;
    assert_int_equal(radio_send(&radio, pdu, (size_t)n), 0);
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 1u);             /* listening: stopped at once */
    assert_int_equal(radio_send(&radio, pdu, (size_t)n), -1);       /* one frame at a time */
    disabled_without_packet();
    static const uint8_t ch[] = {37u, 38u, 39u};
    static const uint8_t freq[] = {2u, 26u, 80u};
    for (uint32_t i = 0u; i < 3u; ++i) {
        assert_int_equal(nrf_fake_radio.TASKS_TXEN, 1u);
        assert_int_equal(nrf_fake_radio.TASKS_RXEN, 0u);
        assert_int_equal(nrf_fake_radio.FREQUENCY, freq[i]);
        assert_int_equal(nrf_fake_radio.DATAWHITEIV, ch[i]);
        assert_memory_equal(nrf_fake_dma_ptr(nrf_fake_radio.PACKETPTR), pdu, (size_t)n);
        if (i == 1u) {
            radio_hop(&radio); /* the hop timer while sending: not cut, done afterwards */
            assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u);
        }
        nrf_fake_radio.TASKS_DISABLE = 0u;
        tx_ends();
    }
    assert_int_equal(radio.sent, 3u);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);                /* listening again ... */
    assert_ptr_equal(nrf_fake_dma_ptr(nrf_fake_radio.PACKETPTR), radio.buf.bytes);
    assert_int_equal(radio.channel, 39u);                           /* ... after the hop that fell due */
    assert_int_equal(nrf_fake_radio.FREQUENCY, 80u);
    /* and it receives as before */
    uint8_t beacon[64];
    const size_t bn = test_ble_beacon(beacon, 3u, 0u);
    test_radio_packet(beacon, bn, 1, 55, radio_irq);
    radio_packet_t p;
    assert_int_equal(radio_pop(&radio, &p), 1);
    assert_int_equal(p.channel, 39u);
}

static void test_radio_send_waits_for_a_packet_in_progress_and_802154(void **state)
{
    (void)state;
    assert_int_equal(radio_start_ieee802154(&radio, 15u, &clock_only), 0);
    radio_started();
    uint8_t mpdu[PFDOA_PEER_FRAME_MAX];
    static const uint8_t addr[8] = {7u, 0u, 0u, 0u, 0u, 0u, 0u, 0xC5u};
    const int32_t n = pfdoa_peer_frame(PFDOA_RADIO_IEEE802154, addr, 7u, 9u, mpdu, sizeof mpdu);
    assert_true(n > 0);
    nrf_fake_radio.EVENTS_ADDRESS = 1u; /* a frame is coming in */
    assert_int_equal(radio_send(&radio, mpdu, (size_t)n), 0);
    assert_int_equal(nrf_fake_radio.TASKS_DISABLE, 0u); /* not cut: sent after it */
    uint8_t ram[140];
    const size_t rn = test_154_beacon(ram, 0xBEEFu, 3u, 40u);
    test_radio_packet(ram, rn, 1, -1, radio_irq);
    assert_int_equal(radio_pending(&radio), 1);          /* the frame that was coming in */
    assert_int_equal(nrf_fake_radio.TASKS_TXEN, 1u);     /* then the send, on the channel listened to */
    assert_int_equal(nrf_fake_radio.FREQUENCY, 25u);
    const uint8_t *const tx = nrf_fake_dma_ptr(nrf_fake_radio.PACKETPTR);
    assert_int_equal(tx[0], (uint8_t)((uint32_t)n + 2u)); /* PHR: the MPDU and the FCS the radio adds */
    assert_memory_equal(&tx[1], mpdu, (size_t)n);
    tx_ends();
    assert_int_equal(radio.sent, 1u);
    assert_int_equal(nrf_fake_radio.TASKS_RXEN, 1u);
    assert_int_equal(radio_send(&radio, mpdu, RADIO_TX_MAX), -1); /* too long for its PHR + frame */
    assert_int_equal(radio_send(&radio, NULL, 5u), -1);
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
        cmocka_unit_test_setup(test_radio_hit_hops_at_once, setup),
        cmocka_unit_test_setup(test_radio_hit_while_a_hop_is_pending_hops_once, setup),
        cmocka_unit_test_setup(test_radio_too_long_packet_is_rejected_not_cut, setup),
        cmocka_unit_test_setup(test_radio_ieee802154, setup),
        cmocka_unit_test_setup(test_radio_sends_an_advertising_event_then_listens_again, setup),
        cmocka_unit_test_setup(test_radio_send_waits_for_a_packet_in_progress_and_802154, setup),
        cmocka_unit_test_setup(test_rssi_conversions, setup),
        cmocka_unit_test_setup(test_flash_store_log, setup),
        cmocka_unit_test_setup(test_flash_store_filter_table_beside_the_config, setup),
        cmocka_unit_test_setup(test_flash_store_torn_record_is_ignored, setup),
    };
    return cmocka_run_group_tests_name("nrf52840 drivers", tests, NULL, NULL);
}
