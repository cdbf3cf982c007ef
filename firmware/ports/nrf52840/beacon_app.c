#include "beacon_app.h"

#include <string.h>

#include "clock.h"
#include "cortexm.h"
#include "flash_store.h"

/* Interrupt handlers take no arguments: the one file-scope instance of the beacon image. */
static beacon_app_t app;

typedef char key_fits_its_log[(PFDOA_AUTH_KEY_LEN <= FLASH_STORE_FILTERS_MAX) ? 1 : -1];

beacon_app_t *beacon_app_get(void)
{
    return &app;
}

/* ---- the beacon's HAL ---- */

static int32_t hal_send(void *ctx, uint8_t radio, int8_t tx_power_dbm, const uint8_t *frame, size_t len)
{
    beacon_app_t *const a = ctx;
    if (radio != PFDOA_RADIO_BLE || a->radio_ok == 0u) {
        return -1;
    }
    return radio_tx_ble_event(&a->tx, frame, len, tx_power_dbm);
}

static uint32_t hal_tick(void *ctx)
{
    return rtc_tick_ms(&((beacon_app_t *)ctx)->tick);
}

static const pfdoa_beacon_hal_t hal = { &app, hal_send, hal_tick, NULL };

/* (Re)starts the beacon with this key, keeping its clock when it had one. */
static int32_t beacon_with_key(beacon_app_t *const a, const uint8_t key[PFDOA_AUTH_KEY_LEN])
{
    const uint32_t now = rtc_tick_ms(&a->tick);
    const uint8_t had_time = a->beacon.time_set;
    const uint32_t counter = pfdoa_beacon_counter(&a->beacon, now);
    const uint32_t phase = (uint32_t)(now - a->beacon.period_tick);
    pfdoa_beacon_config_t cfg;
    pfdoa_beacon_config_defaults(&cfg);
    cfg.interval_ms = NRF_BEACON_INTERVAL_MS;
    cfg.tx_power_dbm = NRF_BEACON_TX_POWER_DBM;
    cfg.auth = 1u;
    memcpy(cfg.auth_key, key, PFDOA_AUTH_KEY_LEN);
    const int32_t rc = pfdoa_beacon_init(&a->beacon, &hal, &cfg);
    memset(&cfg, 0, sizeof cfg);
    if (rc != PFDOA_OK) {
        return rc;
    }
    uint8_t check[PFDOA_AUTH_CHECK_LEN];
    pfdoa_auth_key_check(key, check);
    memcpy(a->key_check, check, sizeof a->key_check);
    a->have_key = 1u;
    if (had_time != 0u) {
        (void)pfdoa_beacon_set_time(&a->beacon, counter, phase, now);
    }
    return PFDOA_OK;
}

/* ---- provisioning lines ---- */

static void reply(beacon_app_t *const a, const char *text)
{
    (void)uarte_write(&a->uart, (const uint8_t *)text, strlen(text));
}

static char *put_hex(char *p, const uint8_t *b, size_t n)
{
    static const char digits[] = "0123456789abcdef";
    for (size_t i = 0u; i < n; ++i) {
        *p++ = digits[b[i] >> 4];
        *p++ = digits[b[i] & 0x0Fu];
    }
    return p;
}

static char *put_u32(char *p, uint32_t v)
{
    char d[10];
    size_t n = 0u;
    do {
        d[n++] = (char)('0' + (char)(v % 10u));
        v /= 10u;
    } while (v != 0u);
    while (n > 0u) {
        *p++ = d[--n];
    }
    return p;
}

static int hex_nibble(const char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1;
}

/* A decimal u32 at *s, then a space or the end; advances *s. 0 when there is none. */
static int parse_u32(const char **s, uint32_t *out)
{
    const char *p = *s;
    uint64_t v = 0u;
    size_t n = 0u;
    while (*p >= '0' && *p <= '9') {
        v = v * 10u + (uint64_t)(*p - '0');
        if (v > 0xFFFFFFFFu || ++n > 10u) {
            return 0;
        }
        ++p;
    }
    if (n == 0u || (*p != '\0' && *p != ' ')) {
        return 0;
    }
    *out = (uint32_t)v;
    *s = (*p == ' ') ? p + 1 : p;
    return 1;
}

static void command(beacon_app_t *const a, const char *const line, const uint32_t now)
{
    char out[64];
    char *p = out;
    if (line[0] == 'K' && line[1] == ' ' && strlen(line) == 2u + 2u * PFDOA_AUTH_KEY_LEN) {
        uint8_t key[PFDOA_AUTH_KEY_LEN];
        for (size_t i = 0u; i < PFDOA_AUTH_KEY_LEN; ++i) {
            const int hi = hex_nibble(line[2u + 2u * i]);
            const int lo = hex_nibble(line[3u + 2u * i]);
            if (hi < 0 || lo < 0) {
                reply(a, "ERR key: 32 hex digits\n");
                a->refused++;
                return;
            }
            key[i] = (uint8_t)((hi << 4) | lo);
        }
        const int32_t stored = flash_store_save(FLASH_LOG_FILTERS, key, sizeof key);
        const int32_t rc = beacon_with_key(a, key);
        memset(key, 0, sizeof key);
        if (stored != 0 || rc != PFDOA_OK) {
            reply(a, "ERR key not stored\n");
            a->refused++;
            return;
        }
        memcpy(p, "OK K ", 5u);
        p = put_hex(p + 5, a->key_check, sizeof a->key_check);
    } else if (line[0] == 'T' && line[1] == ' ') {
        const char *s = &line[2];
        uint32_t counter = 0u;
        uint32_t phase = 0u;
        if (a->have_key == 0u) {
            reply(a, "ERR no key\n");
            a->refused++;
            return;
        }
        if (!parse_u32(&s, &counter) || !parse_u32(&s, &phase) || *s != '\0'
            || pfdoa_beacon_set_time(&a->beacon, counter, phase, now) != PFDOA_OK) {
            reply(a, "ERR time: T <counter> <phase_ms 0..4095>\n");
            a->refused++;
            return;
        }
        memcpy(p, "OK T ", 5u);
        p = put_u32(p + 5, counter);
    } else if (line[0] == 'S' && line[1] == '\0') {
        *p++ = 'S';
        *p++ = ' ';
        if (a->have_key != 0u) {
            p = put_hex(p, a->key_check, sizeof a->key_check);
        } else {
            *p++ = '-';
        }
        *p++ = ' ';
        if (a->beacon.time_set != 0u) {
            p = put_u32(p, pfdoa_beacon_counter(&a->beacon, now));
        } else {
            *p++ = '-';
        }
        *p++ = ' ';
        p = put_u32(p, pfdoa_beacon_sent(&a->beacon));
        *p++ = ' ';
        p = put_u32(p, pfdoa_beacon_send_failures(&a->beacon));
    } else {
        reply(a, "ERR unknown command (K, T, S)\n");
        a->refused++;
        return;
    }
    *p++ = '\n';
    *p = '\0';
    reply(a, out);
    a->commands++;
}

static void uart_lines(beacon_app_t *const a, const uint32_t now)
{
    uint8_t rx[32];
    size_t n;
    uarte_poll(&a->uart, now);
    while ((n = uarte_read(&a->uart, rx, sizeof rx)) > 0u) {
        for (size_t i = 0u; i < n; ++i) {
            const char c = (char)rx[i];
            if (c == '\r') {
                continue;
            }
            if (c == '\n') {
                if (a->overlong != 0u) {
                    reply(a, "ERR line too long\n");
                    a->refused++;
                } else if (a->line_len > 0u) {
                    a->line[a->line_len] = '\0';
                    command(a, a->line, now);
                }
                memset(a->line, 0, sizeof a->line); /* a key does not stay behind */
                a->line_len = 0u;
                a->overlong = 0u;
            } else if (a->line_len < BEACON_LINE_MAX) {
                a->line[a->line_len++] = c;
            } else {
                a->overlong = 1u;
            }
        }
    }
}

/* ---- start-up and main loop ---- */

int32_t beacon_app_init(void)
{
    beacon_app_t *const a = &app;
    memset(a, 0, sizeof *a);
    const int hfxo = clock_start_hfxo() == CLOCK_OK;
    (void)clock_start_lfclk();
    rtc_tick_start(&a->tick);
    cm_nvic_enable(NRF_IRQ_RTC1, BOARD_PRIO_RTC);
    uarte_init(&a->uart, BOARD_UART_TXD, BOARD_UART_RXD);
    cm_nvic_enable(NRF_IRQ_UARTE0, BOARD_PRIO_LINK);
    uint8_t key[PFDOA_AUTH_KEY_LEN];
    if (flash_store_load(FLASH_LOG_FILTERS, key, sizeof key) == 0 && beacon_with_key(a, key) != PFDOA_OK) {
        a->status = BEACON_ERR_BEACON;
    }
    memset(key, 0, sizeof key);
    if (!hfxo) {
        a->status = BEACON_ERR_HFXO; /* off frequency: no advertising, provisioning still answers */
        return a->status;
    }
    radio_tx_ble_start(&a->tx);
    a->radio_ok = 1u;
    return a->status;
}

void beacon_app_step(void)
{
    beacon_app_t *const a = &app;
    const uint32_t now = rtc_tick_ms(&a->tick);
    uart_lines(a, now);
    if (a->have_key != 0u) {
        (void)pfdoa_beacon_poll(&a->beacon, now);
    }
}

void beacon_app_idle(void)
{
    beacon_app_t *const a = &app;
    const uint32_t primask = cm_irq_save();
    if (!uarte_rx_available(&a->uart)) {
        uint32_t ms = NRF_BEACON_INTERVAL_MS;
        if (a->have_key != 0u && a->beacon.polled != 0u) {
            const uint32_t due = (uint32_t)(a->beacon.next_tick - rtc_tick_ms(&a->tick));
            ms = (due == 0u || due > NRF_BEACON_INTERVAL_MS) ? 1u : due;
        }
        rtc_tick_wake_in(&a->tick, uarte_rx_pending(&a->uart) ? 2u : ms);
        cm_wfi(); /* masked: an interrupt that came after the checks still wakes us */
    }
    cm_irq_restore(primask);
}

/* ---- interrupt handlers ---- */

void RTC1_IRQHandler(void)
{
    (void)rtc_tick_isr(&app.tick);
}

void UARTE0_UART0_IRQHandler(void)
{
    uarte_isr(&app.uart);
}

void RADIO_IRQHandler(void)
{
    /* The transmitter is polled; its interrupt is never enabled. */
}

void GPIOTE_IRQHandler(void)
{
}
