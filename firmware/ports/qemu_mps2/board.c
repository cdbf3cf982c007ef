#include "board.h"

#include <string.h>

#include "cmsdk_uart.h"
#include "cortexm.h"
#include "pfdoa_crc16.h"
#include "semihost.h"

/* The board is a singleton and interrupt handlers take no arguments: this is the one
 * place with file-scope state. The anchor core keeps all of its state in its instance. */
static cmsdk_uart_t uart0;
static volatile uint32_t tick_ms;
static char cmdline[BOARD_CMDLINE_MAX]; /* semihosting command line, read once at init */

#define CONFIG_MAGIC  0x50464431u /* "PFD1" */
#define FILTERS_MAGIC 0x50464632u /* "PFF2" */

/* What every RAM store starts with; its data follows in the store's own struct. */
struct store_head {
    uint32_t magic; /* 0 while half-written */
    uint32_t len;
    uint16_t crc;   /* over len and data */
};

struct config_store {
    struct store_head head;
    uint8_t data[BOARD_CONFIG_MAX];
};

struct filter_store {
    struct store_head head;
    uint8_t data[BOARD_FILTERS_MAX];
};

/* Not zeroed at reset, so the configuration and the beacon filter table survive a warm
 * reset as they would in flash. */
__attribute__((section(".noinit"))) static struct config_store config_ram;
__attribute__((section(".noinit"))) static struct filter_store filters_ram;

void board_init(void)
{
    tick_ms = 0u;
    if (semihost_cmdline(cmdline, sizeof cmdline) < 0) {
        cmdline[0] = '\0';
    }
    cmsdk_uart_init(&uart0, BOARD_UART0_BASE, BOARD_BAUDDIV);
    cm_nvic_enable(BOARD_UART0_RX_IRQ);
    cm_irq_enable();
}

void board_tick_start(void)
{
    CM_SYST_RVR = BOARD_CPU_HZ / 1000u - 1u;
    CM_SYST_CVR = 0u;
    CM_SYST_CSR = CM_SYST_CSR_CLKSOURCE | CM_SYST_CSR_TICKINT | CM_SYST_CSR_ENABLE;
}

/* The value of a "key=value" word of the command line, or NULL. */
static const char *param(const char *key)
{
    size_t klen = 0u;
    while (key[klen] != '\0') {
        ++klen;
    }
    for (size_t i = 0u; cmdline[i] != '\0'; ++i) {
        if (i > 0u && cmdline[i - 1u] != ' ') {
            continue;
        }
        size_t k = 0u;
        while (k < klen && cmdline[i + k] == key[k]) {
            ++k;
        }
        if (k == klen && cmdline[i + k] == '=') {
            return &cmdline[i + k + 1u];
        }
    }
    return NULL;
}

uint32_t board_param_u32(const char *key, uint32_t max, uint32_t fallback)
{
    const char *v = param(key);
    if (v == NULL || *v < '0' || *v > '9') {
        return fallback;
    }
    uint32_t x = 0u;
    for (; *v >= '0' && *v <= '9'; ++v) {
        const uint32_t d = (uint32_t)(*v - '0');
        if (x > (UINT32_MAX - d) / 10u) {
            return fallback;
        }
        x = x * 10u + d;
    }
    return (*v == '\0' || *v == ' ') && x <= max ? x : fallback;
}

static int hex_nibble(char ch)
{
    if (ch >= '0' && ch <= '9') {
        return ch - '0';
    }
    if (ch >= 'a' && ch <= 'f') {
        return ch - 'a' + 10;
    }
    if (ch >= 'A' && ch <= 'F') {
        return ch - 'A' + 10;
    }
    return -1;
}

/* A hex parameter (cfg=, filters=): exactly `len` bytes of hex, else 0. */
static size_t factory_bytes(const char *key, uint8_t *out, size_t len)
{
    const char *v = param(key);
    if (v == NULL) {
        return 0u;
    }
    for (size_t i = 0u; i < len; ++i) {
        const int hi = hex_nibble(v[2u * i]);
        const int lo = (hi < 0) ? -1 : hex_nibble(v[2u * i + 1u]);
        if (lo < 0) {
            return 0u;
        }
        out[i] = (uint8_t)((hi << 4) | lo);
    }
    const char end = v[2u * len];
    return (end == '\0' || end == ' ') ? len : 0u;
}

uint32_t board_tick_ms(void)
{
    return tick_ms; /* one aligned 32-bit load: atomic on Cortex-M */
}

void SysTick_Handler(void)
{
    tick_ms = tick_ms + 1u;
}

void UART0_RX_Handler(void)
{
    cmsdk_uart_rx_isr(&uart0);
}

void board_uart_write(const uint8_t *data, size_t len)
{
    cmsdk_uart_write(&uart0, data, len);
}

size_t board_uart_read(uint8_t *out, size_t cap)
{
    return cmsdk_uart_read(&uart0, out, cap);
}

uint32_t board_uart_overruns(void)
{
    return uart0.overruns;
}

void board_idle(void)
{
    cm_irq_disable();
    if (!cmsdk_uart_rx_ready(&uart0)) {
        cm_wfi();
    }
    cm_irq_enable();
}

static uint16_t store_crc(uint32_t len, const uint8_t *data)
{
    const uint16_t crc = pfdoa_crc16_update(0xFFFFu, (const uint8_t *)&len, sizeof len);
    return pfdoa_crc16_update(crc, data, len);
}

/* The stored length (data copied to out), or 0 when nothing valid of at most cap bytes. */
static size_t store_load(const struct store_head *head, const uint8_t *data, size_t max, uint32_t magic,
                         uint8_t *out, size_t cap)
{
    if (head->magic != magic || head->len > max || head->len > cap || store_crc(head->len, data) != head->crc) {
        return 0u;
    }
    memcpy(out, data, head->len);
    return head->len;
}

static int store_save(struct store_head *head, uint8_t *data, size_t max, uint32_t magic, const uint8_t *in,
                      size_t len)
{
    if (len > max) {
        return -1;
    }
    head->magic = 0u; /* invalid while half-written */
    memcpy(data, in, len);
    head->len = (uint32_t)len;
    head->crc = store_crc(head->len, data);
    head->magic = magic;
    return 0;
}

size_t board_config_load(uint8_t *out, size_t cap)
{
    const size_t n = store_load(&config_ram.head, config_ram.data, sizeof config_ram.data, CONFIG_MAGIC, out, cap);
    return (n > 0u) ? n : factory_bytes("cfg", out, cap);
}

int board_config_save(const uint8_t *data, size_t len)
{
    return store_save(&config_ram.head, config_ram.data, sizeof config_ram.data, CONFIG_MAGIC, data, len);
}

size_t board_filters_load(uint8_t *out, size_t cap)
{
    const size_t n = store_load(&filters_ram.head, filters_ram.data, sizeof filters_ram.data, FILTERS_MAGIC, out, cap);
    return (n > 0u) ? n : factory_bytes("filters", out, cap);
}

int board_filters_save(const uint8_t *data, size_t len)
{
    return store_save(&filters_ram.head, filters_ram.data, sizeof filters_ram.data, FILTERS_MAGIC, data, len);
}

void board_exit(int code)
{
    semihost_exit((uint32_t)code);
}
