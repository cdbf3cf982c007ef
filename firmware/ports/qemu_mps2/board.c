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

#define CONFIG_MAGIC 0x50464431u /* "PFD1" */

struct config_store {
    uint32_t magic;
    uint32_t len;
    uint8_t data[BOARD_CONFIG_MAX];
    uint16_t crc;
};

/* Not zeroed at reset, so a configuration survives a warm reset as it would in flash. */
__attribute__((section(".noinit"))) static struct config_store config_ram;

void board_init(void)
{
    tick_ms = 0u;
    cmsdk_uart_init(&uart0, BOARD_UART0_BASE, BOARD_BAUDDIV);
    cm_nvic_enable(BOARD_UART0_RX_IRQ);
    CM_SYST_RVR = BOARD_CPU_HZ / 1000u - 1u;
    CM_SYST_CVR = 0u;
    CM_SYST_CSR = CM_SYST_CSR_CLKSOURCE | CM_SYST_CSR_TICKINT | CM_SYST_CSR_ENABLE;
    cm_irq_enable();
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

static uint16_t config_crc(const struct config_store *s)
{
    uint16_t crc = pfdoa_crc16_update(0xFFFFu, (const uint8_t *)&s->len, sizeof s->len);
    return pfdoa_crc16_update(crc, s->data, s->len);
}

size_t board_config_load(uint8_t *out, size_t cap)
{
    const struct config_store *s = &config_ram;
    if (s->magic != CONFIG_MAGIC || s->len > BOARD_CONFIG_MAX || s->len > cap
        || config_crc(s) != s->crc) {
        return 0u;
    }
    memcpy(out, s->data, s->len);
    return s->len;
}

int board_config_save(const uint8_t *data, size_t len)
{
    if (len > BOARD_CONFIG_MAX) {
        return -1;
    }
    config_ram.magic = 0u; /* invalid while half-written */
    memcpy(config_ram.data, data, len);
    config_ram.len = (uint32_t)len;
    config_ram.crc = config_crc(&config_ram);
    config_ram.magic = CONFIG_MAGIC;
    return 0;
}

void board_exit(int code)
{
    semihost_exit((uint32_t)code);
}
