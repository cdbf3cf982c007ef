/*
 * replay - a recorded sequence of radio events through the port on the register fake.
 *
 * Reads a recording (tests/radio_events_*.txt, format below) and plays each event on the
 * fake hardware: the RTC is moved to the event's time (every 24-bit wrap raising its
 * overflow interrupt), the hop timer is fired until the radio listens on the event's
 * channel (after a hit the radio is there already), the packet is written into the RAM
 * the RADIO was given with its CRC status and RSSI, the RADIO interrupt runs, then one
 * pass of the main loop (app_step, app_idle). Host bytes go through the UARTE's RX chunks;
 * a partial chunk is collected as the driver does it, once the line has been quiet for
 * UARTE_RX_IDLE_MS (a main-loop pass at that time gives STOPRX, the UARTE answers with
 * ENDRX, RXTO and the FLUSHRX sequence, another pass hands the bytes to the core).
 * Every frame the UARTE's EasyDMA sends is printed as `U <hex>`, the format of the host
 * build's event-script runner (firmware/build/host/anchor_script), so the two outputs
 * compare line for line (tests/replay_check.py).
 *
 * Recording lines ('#' comments):
 *   I <anchor id>                       first line: UICR.CUSTOMER[0]
 *   M ble | M 154 <channel>             the radio mode the image was built for
 *   B <ms> <channel> <crc 0|1> <rssisample|-> <pdu hex>   BLE packet (header, length, payload)
 *   Z <ms> <crc 0|1> <lqi byte> <mpdu hex>                802.15.4 frame (MPDU without FCS)
 *   H <ms> <hex>                        bytes from the host arrive on the UART
 *   T <ms>                              time passes, nothing received
 * <ms> is a 64-bit millisecond count since boot (the anchor's tick is it mod 2^32).
 * Exit status 2 with "line N: ..." on a malformed line.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app.h"
#include "fake_nrf.h"
#include "nrf_test_support.h"

static unsigned long line_no;

static void bad(const char *what)
{
    fprintf(stderr, "line %lu: %s\n", line_no, what);
    exit(2);
}

static size_t hex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0u;
    while (s[0] != '\0' && s[0] != '\n' && s[0] != '\r') {
        unsigned v;
        if (n >= cap || sscanf(s, "%2x", &v) != 1 || s[1] == '\0') {
            bad("bad hex");
        }
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static void print_sent(void)
{
    uint8_t out[4096];
    while (NRF_UARTE0->TASKS_STARTTX != 0u) {
        NRF_UARTE0->TASKS_STARTTX = 0u;
        const uint8_t *const src = nrf_fake_dma_ptr(NRF_UARTE0->TXD_PTR);
        const size_t len = NRF_UARTE0->TXD_MAXCNT;
        if (src == NULL || len > sizeof out) {
            bad("UARTE DMA from an unknown buffer");
        }
        memcpy(out, src, len);
        printf("U ");
        for (size_t i = 0u; i < len; ++i) {
            printf("%02x", out[i]);
        }
        printf("\n");
        NRF_UARTE0->TXD_AMOUNT = (uint32_t)len;
        NRF_UARTE0->EVENTS_ENDTX = 1u;
        UARTE0_UART0_IRQHandler();
    }
}

static uint64_t now_ms;

static void advance(uint64_t ms)
{
    if (ms < now_ms) {
        bad("time goes backwards");
    }
    now_ms = ms;
    nrf_fake_rtc_advance_to(test_rtc_ticks_of_ms(ms), RTC1_IRQHandler);
}

/* The hop timer fires until the radio listens on ch (at most a full turn). */
static void tune_to(uint8_t ch)
{
    for (uint32_t i = 0u; i < 3u && app_get()->radio.channel != ch; ++i) {
        nrf_fake_rtc1.EVENTS_COMPARE[RTC_TICK_HOP] = 1u;
        RTC1_IRQHandler();
        if (nrf_fake_radio.TASKS_DISABLE == 0u) {
            bad("the hop timer did not disable the listening radio");
        }
        nrf_fake_radio.TASKS_DISABLE = 0u;
        nrf_fake_radio.EVENTS_DISABLED = 1u;
        RADIO_IRQHandler();
    }
    if (app_get()->radio.channel != ch) {
        bad("channel not reached by hopping");
    }
}

static void step(void)
{
    app_step();
    app_idle();
    print_sent();
}

/* Host bytes at the current time: whole chunks now, the rest after the quiet time. */
static void host_bytes(const uint8_t *bytes, size_t n)
{
    uint32_t filled = 0u;
    const uint32_t partial = test_uarte_rx(bytes, n, &filled, UARTE0_UART0_IRQHandler);
    step();
    if (partial > 0u) {
        advance(now_ms + UARTE_RX_IDLE_MS);
        step();
        if (nrf_fake_uarte0.TASKS_STOPRX == 0u) {
            bad("the quiet line did not stop reception");
        }
        test_uarte_stop_flush(&filled, NULL, 0u, UARTE0_UART0_IRQHandler);
    }
}

int main(int argc, char **argv)
{
    FILE *in = (argc > 1) ? fopen(argv[1], "r") : stdin;
    if (in == NULL) {
        perror(argv[1]);
        return 2;
    }
    char line[1024];
    int started = 0;
    int mode_checked = 0;
    nrf_fake_reset();
    while (fgets(line, sizeof line, in) != NULL) {
        ++line_no;
        if (line[0] == '#' || line[0] == '\n') {
            continue;
        }
        uint64_t ms;
        unsigned ch, crc, val;
        char rssi[8];
        int off = 0;
        uint8_t ram[RADIO_BUF_SIZE];
        if (!started) {
            unsigned id;
            if (sscanf(line, "I %u", &id) != 1) {
                bad("the first line must be I <anchor id>");
            }
            nrf_fake_uicr_customer0 = id;
            if (app_init() != APP_OK) {
                bad("app_init failed");
            }
            nrf_fake_radio.TASKS_DISABLE = 0u;
            started = 1;
            step(); /* the first poll, at boot: STATUS */
            continue;
        }
        if (line[0] == 'M') {
            unsigned c = 0u;
            const int is154 = sscanf(line, "M 154 %u", &c) == 1;
            if (is154 != (NRF_IEEE802154_CHANNEL != 0) || (is154 && c != (unsigned)NRF_IEEE802154_CHANNEL)) {
                bad("recording made for another radio mode than this build");
            }
            mode_checked = 1;
            continue;
        }
        if (!mode_checked) {
            bad("M line missing");
        }
        if (sscanf(line, "T %" SCNu64, &ms) == 1) {
            advance(ms);
        } else if (sscanf(line, "H %" SCNu64 " %n", &ms, &off) == 1 && off > 0) {
            const size_t n = hex(&line[off], ram, sizeof ram);
            advance(ms);
            host_bytes(ram, n);
        } else if (sscanf(line, "B %" SCNu64 " %u %u %7s %n", &ms, &ch, &crc, rssi, &off) == 4 && off > 0) {
            const size_t n = hex(&line[off], ram, sizeof ram);
            if (n < 2u || n != 2u + ram[1]) {
                bad("BLE PDU length byte does not match");
            }
            advance(ms);
            tune_to((uint8_t)ch);
            const int sample = (rssi[0] == '-') ? -1 : atoi(rssi);
            test_radio_packet(ram, n, (int)crc, sample, RADIO_IRQHandler);
        } else if (sscanf(line, "Z %" SCNu64 " %u %u %n", &ms, &crc, &val, &off) == 3 && off > 0) {
            const size_t n = hex(&line[off], &ram[1], sizeof ram - 3u);
            ram[0] = (uint8_t)(n + 2u);      /* PHR counts the FCS */
            ram[1u + n] = (uint8_t)val;      /* the LQI byte where the FCS was */
            ram[2u + n] = 0u;
            advance(ms);
            test_radio_packet(ram, n + 3u, (int)crc, -1, RADIO_IRQHandler);
        } else {
            bad("unknown line");
        }
        step();
    }
    if (!started) {
        bad("empty recording");
    }
    return 0;
}
