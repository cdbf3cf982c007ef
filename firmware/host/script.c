/* Event-script interpreter and line-emitting HAL, see script.h. */
#include "script.h"

#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static size_t format_hex(char *const out, const uint8_t *const bytes, const size_t len)
{
    static const char digits[] = "0123456789abcdef";
    for (size_t i = 0u; i < len; i++) {
        out[2u * i] = digits[bytes[i] >> 4];
        out[(2u * i) + 1u] = digits[bytes[i] & 0x0Fu];
    }
    out[2u * len] = '\0';
    return 2u * len;
}

static uint32_t env_tick(void *const ctx)
{
    return ((const script_env_t *)ctx)->boot_tick;
}

static int32_t env_uart_write(void *const ctx, const uint8_t *const bytes, const size_t len)
{
    const script_env_t *const env = (const script_env_t *)ctx;
    char line[SCRIPT_OUT_LINE_MAX];
    if (len > PFDOA_FRAME_WIRE_MAX) {
        return -1;
    }
    line[0] = 'U';
    line[1] = ' ';
    (void)format_hex(&line[2], bytes, len);
    env->emit(env->user, line);
    return 0;
}

static int32_t env_can_send(void *const ctx, const uint16_t id, const uint8_t *const data, const uint8_t dlc)
{
    const script_env_t *const env = (const script_env_t *)ctx;
    char line[SCRIPT_OUT_LINE_MAX];
    if (dlc > 8u) {
        return -1;
    }
    (void)snprintf(line, sizeof line, "C %03x ", (unsigned)id);
    (void)format_hex(&line[6], data, dlc);
    env->emit(env->user, line);
    return 0;
}

static int32_t env_config_load(void *const ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    const script_env_t *const env = (const script_env_t *)ctx;
    if (env->have_stored == 0) {
        return -1;
    }
    (void)memcpy(out, env->stored, PFDOA_CONFIG_LEN);
    return 0;
}

static int32_t env_config_store(void *const ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    script_env_t *const env = (script_env_t *)ctx;
    if (env->store_fails != 0) {
        return -1;
    }
    (void)memcpy(env->stored, config, PFDOA_CONFIG_LEN);
    env->have_stored = 1;
    return 0;
}

void script_hal(script_env_t *const env, pfdoa_hal_t *const hal)
{
    hal->ctx = env;
    hal->tick_ms = env_tick;
    hal->uart_write = env_uart_write;
    hal->can_send = env_can_send;
    hal->config_load = env_config_load;
    hal->config_store = env_config_store;
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

/* Hex text to bytes. Returns the byte count or -1. */
static long parse_hex(const char *const s, uint8_t *const out, const size_t cap)
{
    const size_t n = strlen(s);
    if (((n % 2u) != 0u) || ((n / 2u) > cap)) {
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

int script_run_line(pfdoa_anchor_t *const a, char *const line, uint8_t *const scratch, const size_t scratch_cap)
{
    char *const hash = strchr(line, '#');
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
        pfdoa_radio_reading_t r;
        r.tick_ms = (uint32_t)tick;
        r.seq = (uint16_t)seq;
        r.rssi_dbm = (int8_t)rssi;
        r.channel = (uint8_t)channel;
        r.lqi = (uint8_t)lqi;
        r.radio = (uint8_t)radio;
        (void)pfdoa_anchor_on_radio(a, &r); /* dropped readings are part of the script */
        return 0;
    }
    if ((strcmp(tok[0], "P") == 0) && (n == 2)) {
        return (pfdoa_anchor_poll(a, (uint32_t)tick) < 0) ? -1 : 0;
    }
    if ((strcmp(tok[0], "U") == 0) && (n == 3)) {
        const long len = parse_hex(tok[2], scratch, scratch_cap);
        return ((len < 0) || (pfdoa_anchor_on_uart_rx(a, scratch, (size_t)len) < 0)) ? -1 : 0;
    }
    if ((strcmp(tok[0], "C") == 0) && (n == 4)) {
        long id = 0;
        const long len = parse_hex(tok[3], scratch, scratch_cap);
        if ((strlen(tok[2]) != 3u) || (parse_long(tok[2], 16, 0, 0x7FF, &id) != 0) || (len < 0) || (len > 8)) {
            return -1;
        }
        (void)pfdoa_anchor_on_can_rx(a, (uint16_t)id, scratch, (uint8_t)len);
        return 0;
    }
    return -1;
}

int script_set_stored_config(script_env_t *const env, const char *const text)
{
    static const long lo[5] = {INT16_MIN, 0, 0, 0, 0};
    static const long hi[5] = {INT16_MAX, UINT16_MAX, UINT8_MAX, UINT8_MAX, UINT8_MAX};
    long v[5];
    char buf[64];
    if (strlen(text) >= sizeof buf) {
        return -1;
    }
    (void)strcpy(buf, text);
    int n = 0;
    for (char *t = strtok(buf, ","); t != NULL; t = strtok(NULL, ",")) {
        if ((n == 5) || (parse_long(t, 10, lo[n], hi[n], &v[n]) != 0)) {
            return -1;
        }
        n++;
    }
    if (n != 5) {
        return -1;
    }
    pfdoa_config_t cfg;
    cfg.offset_q8 = (int16_t)v[0];
    cfg.alpha_q8 = (uint16_t)v[1];
    cfg.spike_db = (uint8_t)v[2];
    cfg.report_mode = (uint8_t)v[3];
    cfg.decimation = (uint8_t)v[4];
    if (pfdoa_config_validate(&cfg) != PFDOA_OK) {
        return -1;
    }
    pfdoa_config_pack(&cfg, env->stored);
    env->have_stored = 1;
    return 0;
}
