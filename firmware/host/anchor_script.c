/*
 * anchor_script - runs an event script (protocol/vectors/README.md) through one C anchor
 * and prints every frame it emits, one per line:
 *     U <hex of the UART frame incl. its 00 delimiter>
 *     C <3-hex-digit id> <hex data>
 * Input lines (decimal unless stated, '#' comments, blank lines ignored):
 *     R <tick_ms> <seq> <rssi_dbm> <channel> <lqi> <radio>
 *     P <tick_ms>
 *     U <tick_ms> <hex>
 *     C <tick_ms> <3-hex-digit id> <hex>
 * Usage: anchor_script [-a anchor_id] [-t uart|can|both] [-b boot_tick_ms]
 *                      [-c offset_q8,alpha_q8,spike_db,report_mode,decimation] [-s]
 *   -c  configuration found in storage at boot (default: none, so SPEC defaults)
 *   -s  the configuration store fails (CONFIG_ACK result 2)
 * Exit status: 0, or 2 with a "line N: ..." message on stderr for a malformed script.
 */
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pfdoa_anchor.h"

typedef struct harness {
    uint32_t boot_tick;
    int have_stored;
    int store_fails;
    uint8_t stored[PFDOA_CONFIG_LEN];
} harness_t;

static void print_hex(const uint8_t *const bytes, const size_t len)
{
    static const char digits[] = "0123456789abcdef";
    for (size_t i = 0u; i < len; i++) {
        (void)putchar(digits[bytes[i] >> 4]);
        (void)putchar(digits[bytes[i] & 0x0Fu]);
    }
}

static uint32_t h_tick(void *const ctx)
{
    return ((const harness_t *)ctx)->boot_tick;
}

static int32_t h_uart_write(void *const ctx, const uint8_t *const bytes, const size_t len)
{
    (void)ctx;
    (void)fputs("U ", stdout);
    print_hex(bytes, len);
    (void)putchar('\n');
    return 0;
}

static int32_t h_can_send(void *const ctx, const uint16_t id, const uint8_t *const data, const uint8_t dlc)
{
    (void)ctx;
    (void)printf("C %03x ", (unsigned)id);
    print_hex(data, dlc);
    (void)putchar('\n');
    return 0;
}

static int32_t h_config_load(void *const ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    const harness_t *const h = (const harness_t *)ctx;
    if (h->have_stored == 0) {
        return -1;
    }
    (void)memcpy(out, h->stored, PFDOA_CONFIG_LEN);
    return 0;
}

static int32_t h_config_store(void *const ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    harness_t *const h = (harness_t *)ctx;
    if (h->store_fails != 0) {
        return -1;
    }
    (void)memcpy(h->stored, config, PFDOA_CONFIG_LEN);
    h->have_stored = 1;
    return 0;
}

static int parse_long(const char *const s, const int base, const long lo, const long hi, long *const out)
{
    if ((s == NULL) || (*s == '\0')) {
        return -1;
    }
    char *end = NULL;
    errno = 0;
    const long v = strtol(s, &end, base);
    if ((errno != 0) || (*end != '\0') || (v < lo) || (v > hi)) {
        return -1;
    }
    *out = v;
    return 0;
}

static int hex_value(const char c)
{
    if ((c >= '0') && (c <= '9')) {
        return c - '0';
    }
    if ((c >= 'a') && (c <= 'f')) {
        return c - 'a' + 10;
    }
    if ((c >= 'A') && (c <= 'F')) {
        return c - 'A' + 10;
    }
    return -1;
}

/* Decodes hex in place into bytes (half the length). Returns the byte count or -1. */
static long parse_hex(char *const s, uint8_t *const out)
{
    const size_t n = strlen(s);
    if ((n % 2u) != 0u) {
        return -1;
    }
    for (size_t i = 0u; i < n; i += 2u) {
        const int hi = hex_value(s[i]);
        const int lo = hex_value(s[i + 1u]);
        if ((hi < 0) || (lo < 0)) {
            return -1;
        }
        out[i / 2u] = (uint8_t)((hi << 4) | lo);
    }
    return (long)(n / 2u);
}

#define MAX_TOKENS 8

static int run_line(pfdoa_anchor_t *const a, char *const line, uint8_t *const scratch)
{
    char *hash = strchr(line, '#');
    if (hash != NULL) {
        *hash = '\0';
    }
    char *tok[MAX_TOKENS];
    int n = 0;
    for (char *t = strtok(line, " \t\r\n"); t != NULL; t = strtok(NULL, " \t\r\n")) {
        if (n == MAX_TOKENS) {
            return -1;
        }
        tok[n++] = t;
    }
    if (n == 0) {
        return 0;
    }
    long tick = 0;
    if ((n < 2) || (parse_long(tok[1], 10, 0, (long)UINT32_MAX, &tick) != 0)) {
        return -1;
    }
    if ((strcmp(tok[0], "R") == 0) && (n == 7)) {
        long seq, rssi, channel, lqi, radio;
        if ((parse_long(tok[2], 10, 0, 65535, &seq) != 0) || (parse_long(tok[3], 10, -128, 127, &rssi) != 0) ||
            (parse_long(tok[4], 10, 0, 255, &channel) != 0) || (parse_long(tok[5], 10, 0, 255, &lqi) != 0) ||
            (parse_long(tok[6], 10, 0, 255, &radio) != 0)) {
            return -1;
        }
        const pfdoa_radio_reading_t r = {(uint32_t)tick, (uint16_t)seq, (int8_t)rssi,
                                         (uint8_t)channel, (uint8_t)lqi, (uint8_t)radio};
        (void)pfdoa_anchor_on_radio(a, &r);
        return 0;
    }
    if ((strcmp(tok[0], "P") == 0) && (n == 2)) {
        return (pfdoa_anchor_poll(a, (uint32_t)tick) < 0) ? -1 : 0;
    }
    if ((strcmp(tok[0], "U") == 0) && (n == 3)) {
        const long len = parse_hex(tok[2], scratch);
        return ((len < 0) || (pfdoa_anchor_on_uart_rx(a, scratch, (size_t)len) < 0)) ? -1 : 0;
    }
    if ((strcmp(tok[0], "C") == 0) && (n == 4)) {
        long id = 0;
        const long len = parse_hex(tok[3], scratch);
        if ((strlen(tok[2]) != 3u) || (parse_long(tok[2], 16, 0, 0x7FF, &id) != 0) || (len < 0) || (len > 8)) {
            return -1;
        }
        (void)pfdoa_anchor_on_can_rx(a, (uint16_t)id, scratch, (uint8_t)len);
        return 0;
    }
    return -1;
}

static int parse_config(const char *const arg, harness_t *const h)
{
    long v[5];
    char buf[64];
    if (strlen(arg) >= sizeof buf) {
        return -1;
    }
    (void)strcpy(buf, arg);
    int n = 0;
    static const long lo[5] = {-32768, 0, 0, 0, 0};
    static const long hi[5] = {32767, 65535, 255, 255, 255};
    for (char *t = strtok(buf, ","); t != NULL; t = strtok(NULL, ",")) {
        if ((n == 5) || (parse_long(t, 10, lo[n], hi[n], &v[n]) != 0)) {
            return -1;
        }
        n++;
    }
    if (n != 5) {
        return -1;
    }
    const pfdoa_config_t cfg = {(int16_t)v[0], (uint16_t)v[1], (uint8_t)v[2], (uint8_t)v[3], (uint8_t)v[4]};
    if (pfdoa_config_validate(&cfg) != PFDOA_OK) {
        return -1;
    }
    pfdoa_config_pack(&cfg, h->stored);
    h->have_stored = 1;
    return 0;
}

static int usage(void)
{
    (void)fputs("usage: anchor_script [-a anchor_id] [-t uart|can|both] [-b boot_tick_ms]\n"
                "                     [-c offset_q8,alpha_q8,spike_db,report_mode,decimation] [-s] < script\n",
                stderr);
    return 2;
}

int main(int argc, char **argv)
{
    harness_t h;
    (void)memset(&h, 0, sizeof h);
    long anchor_id = 1;
    uint8_t transports = PFDOA_TRANSPORT_UART;
    for (int i = 1; i < argc; i++) {
        const char *const opt = argv[i];
        const char *const val = (i + 1 < argc) ? argv[i + 1] : NULL;
        long v = 0;
        if (strcmp(opt, "-s") == 0) {
            h.store_fails = 1;
            continue;
        }
        if (val == NULL) {
            return usage();
        }
        i++;
        if ((strcmp(opt, "-a") == 0) && (parse_long(val, 10, 0, PFDOA_ANCHOR_ID_MAX, &anchor_id) == 0)) {
            continue;
        }
        if ((strcmp(opt, "-b") == 0) && (parse_long(val, 10, 0, (long)UINT32_MAX, &v) == 0)) {
            h.boot_tick = (uint32_t)v;
            continue;
        }
        if ((strcmp(opt, "-c") == 0) && (parse_config(val, &h) == 0)) {
            continue;
        }
        if (strcmp(opt, "-t") == 0) {
            if (strcmp(val, "uart") == 0) {
                transports = PFDOA_TRANSPORT_UART;
                continue;
            }
            if (strcmp(val, "can") == 0) {
                transports = PFDOA_TRANSPORT_CAN;
                continue;
            }
            if (strcmp(val, "both") == 0) {
                transports = PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN;
                continue;
            }
        }
        return usage();
    }

    const pfdoa_hal_t hal = {&h, h_tick, h_uart_write, h_can_send, h_config_load, h_config_store};
    static pfdoa_anchor_t anchor;
    if (pfdoa_anchor_init(&anchor, &hal, (uint8_t)anchor_id, transports) != PFDOA_OK) {
        return usage();
    }

    /* Lines up to 1 MiB: long enough for any UART chunk a test feeds. */
    enum { LINE_MAX_BYTES = 1 << 20 };
    static char line[LINE_MAX_BYTES];
    static uint8_t scratch[LINE_MAX_BYTES / 2];
    unsigned long lineno = 0u;
    while (fgets(line, sizeof line, stdin) != NULL) {
        lineno++;
        const size_t len = strlen(line);
        if ((len == (sizeof line - 1u)) && (line[len - 1u] != '\n')) {
            (void)fprintf(stderr, "line %lu: longer than %d bytes\n", lineno, LINE_MAX_BYTES - 2);
            return 2;
        }
        char copy[96];
        (void)snprintf(copy, sizeof copy, "%.80s", line);
        copy[strcspn(copy, "\r\n")] = '\0';
        if (run_line(&anchor, line, scratch) != 0) {
            (void)fflush(stdout);
            (void)fprintf(stderr, "line %lu: malformed: %s\n", lineno, copy);
            return 2;
        }
    }
    return (fflush(stdout) == 0) ? 0 : 1;
}
