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

static int32_t env_filters_load(void *const ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN])
{
    const script_env_t *const env = (const script_env_t *)ctx;
    if (env->have_filters == 0) {
        return -1;
    }
    (void)memcpy(out, env->filters, PFDOA_FILTER_TABLE_LEN);
    return 0;
}

static int32_t env_filters_store(void *const ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    script_env_t *const env = (script_env_t *)ctx;
    if (env->store_fails != 0) {
        return -1;
    }
    (void)memcpy(env->filters, table, PFDOA_FILTER_TABLE_LEN);
    env->have_filters = 1;
    return 0;
}

static int32_t env_peer_send(void *const ctx, const uint8_t *const frame, const size_t len)
{
    const script_env_t *const env = (const script_env_t *)ctx;
    char line[SCRIPT_OUT_LINE_MAX];
    if (len > PFDOA_FRAME_WIRE_MAX) {
        return -1;
    }
    line[0] = 'T';
    line[1] = ' ';
    (void)format_hex(&line[2], frame, len);
    env->emit(env->user, line);
    return 0;
}

void script_peer_radio(script_env_t *const env, const uint8_t radio,
                       const uint8_t address[PFDOA_IEEE802154_EXT_ADDR_LEN], pfdoa_peer_radio_t *const out)
{
    (void)memset(out, 0, sizeof *out);
    out->ctx = env;
    out->send = env_peer_send;
    out->radio = radio;
    (void)memcpy(out->address, address, sizeof out->address);
}

void script_hal(script_env_t *const env, pfdoa_hal_t *const hal)
{
    (void)memset(hal, 0, sizeof *hal);
    hal->ctx = env;
    hal->tick_ms = env_tick;
    hal->uart_write = env_uart_write;
    hal->can_send = env_can_send;
    hal->config_load = env_config_load;
    hal->config_store = env_config_store;
}

void script_filter_storage(script_env_t *const env, pfdoa_filter_storage_t *const storage)
{
    storage->ctx = env;
    storage->load = env_filters_load;
    storage->store = env_filters_store;
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
    if (((strcmp(tok[0], "B") == 0) && (n == 5)) || ((strcmp(tok[0], "A") == 0) && (n == 6)) ||
        ((strcmp(tok[0], "Z") == 0) && (n == 6))) {
        long rssi, channel, lqi = 0;
        const int zb = strcmp(tok[0], "Z") == 0;
        if ((parse_long(tok[2], 10, -128, 127, &rssi) != 0) || (parse_long(tok[3], 10, 0, 255, &channel) != 0) ||
            (zb && (parse_long(tok[4], 10, 0, 255, &lqi) != 0))) {
            return -1;
        }
        pfdoa_rx_t rx;
        rx.tick_ms = (uint32_t)tick;
        rx.rssi_dbm = (int8_t)rssi;
        rx.channel = (uint8_t)channel;
        rx.lqi = (uint8_t)lqi;
        const char *const data_tok = tok[n - 1];
        const long len = (strcmp(data_tok, "-") == 0) ? 0 : parse_hex(data_tok, scratch, scratch_cap);
        if (len < 0) {
            return -1;
        }
        if (zb) {
            (void)pfdoa_anchor_on_802154(a, &rx, scratch, (size_t)len);
            return 0;
        }
        if (tok[0][0] == 'B') {
            (void)pfdoa_anchor_on_ble_pdu(a, &rx, scratch, (size_t)len);
            return 0;
        }
        uint8_t adv_a[PFDOA_BLE_ADV_A_LEN];
        if (parse_hex(tok[4], adv_a, sizeof adv_a) != (long)sizeof adv_a) {
            return -1;
        }
        (void)pfdoa_anchor_on_ble_adv(a, &rx, adv_a, scratch, (size_t)len);
        return 0; /* dropped and unmatched receptions are part of the script */
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

/* ---- a JSON reader for exactly the `init` schema (flat object + one nested object) ---- */

typedef struct json_in {
    const char *p;
    char *err;
    size_t err_cap;
} json_in_t;

/* The first error wins (the outer levels only add "bad member"). */
static int json_fail(json_in_t *const j, const char *const what)
{
    if ((j->err != NULL) && (j->err_cap > 0u) && (j->err[0] == '\0')) {
        const size_t ctx = strcspn(j->p, "\r\n");
        (void)snprintf(j->err, j->err_cap, "%s at '%.*s'", what, (int)((ctx < 20u) ? ctx : 20u), j->p);
    }
    return -1;
}

static void json_ws(json_in_t *const j)
{
    while ((*j->p == ' ') || (*j->p == '\t') || (*j->p == '\r') || (*j->p == '\n')) {
        j->p++;
    }
}

static int json_char(json_in_t *const j, const char c)
{
    json_ws(j);
    if (*j->p != c) {
        return -1;
    }
    j->p++;
    return 0;
}

/* A string without escapes (all keys and values of the schema are plain ASCII words). */
static int json_string(json_in_t *const j, char *const out, const size_t cap)
{
    json_ws(j);
    if (*j->p != '"') {
        return json_fail(j, "expected a string");
    }
    j->p++;
    size_t n = 0u;
    while ((*j->p != '"') && (*j->p != '\0')) {
        if ((*j->p == '\\') || ((n + 1u) >= cap)) {
            return json_fail(j, "unsupported or too long string");
        }
        out[n++] = *j->p++;
    }
    if (*j->p != '"') {
        return json_fail(j, "unterminated string");
    }
    j->p++;
    out[n] = '\0';
    return 0;
}

static int json_int(json_in_t *const j, const long long lo, const long long hi, long long *const out)
{
    json_ws(j);
    char *end = NULL;
    errno = 0;
    const long long v = strtoll(j->p, &end, 10);
    if ((end == j->p) || (errno != 0) || (*end == '.') || (*end == 'e') || (*end == 'E')) {
        return json_fail(j, "expected an integer");
    }
    if ((v < lo) || (v > hi)) {
        return json_fail(j, "integer out of range");
    }
    j->p = end;
    *out = v;
    return 0;
}

static int json_bool(json_in_t *const j, int *const out)
{
    json_ws(j);
    if (strncmp(j->p, "true", 4u) == 0) {
        j->p += 4;
        *out = 1;
        return 0;
    }
    if (strncmp(j->p, "false", 5u) == 0) {
        j->p += 5;
        *out = 0;
        return 0;
    }
    return json_fail(j, "expected true or false");
}

/* Calls field(j, key, ctx) for each member of an object. */
static int json_object(json_in_t *const j, int (*field)(json_in_t *, const char *, void *), void *const ctx)
{
    if (json_char(j, '{') != 0) {
        return json_fail(j, "expected '{'");
    }
    if (json_char(j, '}') == 0) {
        return 0;
    }
    for (;;) {
        char key[32];
        if ((json_string(j, key, sizeof key) != 0) || (json_char(j, ':') != 0) || (field(j, key, ctx) != 0)) {
            return json_fail(j, "bad member");
        }
        if (json_char(j, ',') == 0) {
            continue;
        }
        if (json_char(j, '}') == 0) {
            return 0;
        }
        return json_fail(j, "expected ',' or '}'");
    }
}

static int config_field(json_in_t *const j, const char *const key, void *const ctx)
{
    pfdoa_config_t *const c = (pfdoa_config_t *)ctx;
    long long v = 0;
    if (strcmp(key, "offset_q8") == 0) {
        if (json_int(j, INT16_MIN, INT16_MAX, &v) != 0) {
            return -1;
        }
        c->offset_q8 = (int16_t)v;
    } else if (strcmp(key, "alpha_q8") == 0) {
        if (json_int(j, 0, UINT16_MAX, &v) != 0) {
            return -1;
        }
        c->alpha_q8 = (uint16_t)v;
    } else if (strcmp(key, "spike_db") == 0) {
        if (json_int(j, 0, UINT8_MAX, &v) != 0) {
            return -1;
        }
        c->spike_db = (uint8_t)v;
    } else if (strcmp(key, "report_mode") == 0) {
        if (json_int(j, 0, UINT8_MAX, &v) != 0) {
            return -1;
        }
        c->report_mode = (uint8_t)v;
    } else if (strcmp(key, "decimation") == 0) {
        if (json_int(j, 0, UINT8_MAX, &v) != 0) {
            return -1;
        }
        c->decimation = (uint8_t)v;
    } else {
        return json_fail(j, "unknown config key");
    }
    return 0;
}

static int init_field(json_in_t *const j, const char *const key, void *const ctx)
{
    script_init_t *const in = (script_init_t *)ctx;
    long long v = 0;
    if (strcmp(key, "anchor_id") == 0) {
        if (json_int(j, 0, PFDOA_ANCHOR_ID_MAX, &v) != 0) {
            return -1;
        }
        in->anchor_id = (uint8_t)v;
    } else if (strcmp(key, "boot_tick_ms") == 0) {
        if (json_int(j, 0, UINT32_MAX, &v) != 0) {
            return -1;
        }
        in->boot_tick = (uint32_t)v;
    } else if ((strcmp(key, "fw_major") == 0) || (strcmp(key, "fw_minor") == 0)) {
        if (json_int(j, 0, UINT8_MAX, &v) != 0) {
            return -1;
        }
        if (strcmp(key, "fw_major") == 0) {
            in->fw_major = (uint8_t)v;
        } else {
            in->fw_minor = (uint8_t)v;
        }
    } else if (strcmp(key, "store_ok") == 0) {
        return json_bool(j, &in->store_ok);
    } else if (strcmp(key, "sil_inject") == 0) {
        return json_bool(j, &in->sil_inject);
    } else if (strcmp(key, "transport") == 0) {
        char t[8];
        if (json_string(j, t, sizeof t) != 0) {
            return -1;
        }
        if (strcmp(t, "uart") == 0) {
            in->transports = PFDOA_TRANSPORT_UART;
        } else if (strcmp(t, "can") == 0) {
            in->transports = PFDOA_TRANSPORT_CAN;
        } else if (strcmp(t, "both") == 0) {
            in->transports = PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN;
        } else {
            return json_fail(j, "transport must be uart, can or both");
        }
    } else if (strcmp(key, "peer_radio") == 0) {
        char t[8];
        if (json_string(j, t, sizeof t) != 0) {
            return -1;
        }
        if (strcmp(t, "ble") == 0) {
            in->peer_radio = PFDOA_RADIO_BLE;
        } else if (strcmp(t, "802154") == 0) {
            in->peer_radio = PFDOA_RADIO_IEEE802154;
        } else {
            return json_fail(j, "peer_radio must be ble or 802154");
        }
        in->has_peer_radio |= 1;
    } else if (strcmp(key, "peer_address") == 0) {
        char hex[(2 * PFDOA_IEEE802154_EXT_ADDR_LEN) + 2];
        const long n = (json_string(j, hex, sizeof hex) != 0) ? -1 : parse_hex(hex, in->peer_address, sizeof in->peer_address);
        if ((n != PFDOA_BLE_ADV_A_LEN) && (n != PFDOA_IEEE802154_EXT_ADDR_LEN)) {
            return json_fail(j, "peer_address must be the hex of 6 or 8 bytes");
        }
        in->has_peer_radio |= (n == PFDOA_BLE_ADV_A_LEN) ? 2 : 4;
    } else if (strcmp(key, "filters") == 0) {
        char hex[(2 * PFDOA_FILTER_TABLE_LEN) + 2];
        if ((json_string(j, hex, sizeof hex) != 0) ||
            (parse_hex(hex, in->filters, sizeof in->filters) != (long)sizeof in->filters)) {
            return json_fail(j, "filters must be the hex of a stored filter table");
        }
        in->has_filters = 1;
    } else if (strcmp(key, "config") == 0) {
        pfdoa_config_defaults(&in->config);
        if (json_object(j, config_field, &in->config) != 0) {
            return -1;
        }
        if (pfdoa_config_validate(&in->config) != PFDOA_OK) {
            return json_fail(j, "invalid stored config");
        }
        in->has_config = 1;
    } else {
        return json_fail(j, "unknown init key");
    }
    return 0;
}

int script_parse_init(const char *const json, script_init_t *const out, char *const err, const size_t err_cap)
{
    json_in_t j = {json, err, err_cap};
    if ((err != NULL) && (err_cap > 0u)) {
        err[0] = '\0';
    }
    script_init_t in;
    (void)memset(&in, 0, sizeof in);
    in.anchor_id = 0xFFu; /* required */
    in.transports = PFDOA_TRANSPORT_UART;
    in.fw_major = PFDOA_FW_MAJOR;
    in.fw_minor = PFDOA_FW_MINOR;
    in.store_ok = 1;
    if (json_object(&j, init_field, &in) != 0) {
        return -1;
    }
    json_ws(&j);
    if (*j.p != '\0') {
        return json_fail(&j, "trailing characters");
    }
    if (in.anchor_id == 0xFFu) {
        return json_fail(&j, "anchor_id is required");
    }
    /* bit 0: peer_radio; bit 1 or 2: a 6- or 8-byte peer_address, which must be the radio's */
    if ((in.has_peer_radio != 0) &&
        (in.has_peer_radio != ((in.peer_radio == PFDOA_RADIO_BLE) ? 3 : 5))) {
        return json_fail(&j, "peer_radio needs peer_address of its radio's length (6 bytes ble, 8 bytes 802154)");
    }
    in.has_peer_radio = (in.has_peer_radio != 0) ? 1 : 0;
    *out = in;
    return 0;
}
