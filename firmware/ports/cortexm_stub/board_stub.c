/*
 * Stub board for the Cortex-M size and no-float checks: a vector table, a reset handler
 * and a main loop that drives every entry point of the anchor core from volatile "device
 * registers", so --gc-sections keeps exactly what a real port would link. It is not a
 * runnable port (see firmware/ports/qemu_mps2 for that).
 */
#include <stdint.h>
#include <string.h>

#include "pfdoa_anchor.h"

extern uint32_t _stack_top;
extern uint32_t _data_load;
extern uint32_t _data_start;
extern uint32_t _data_end;
extern uint32_t _bss_start;
extern uint32_t _bss_end;

void Reset_Handler(void);
void Default_Handler(void);
void SysTick_Handler(void);
int main(void);

/* Fake peripherals: the compiler must assume something reads and writes them. */
static volatile uint32_t systick_ms;
static volatile uint8_t uart_rx_reg;
static volatile uint8_t uart_tx_reg;
static volatile uint16_t can_rx_id;
static volatile uint8_t can_rx_data[8];
static volatile uint8_t can_rx_dlc;
static volatile uint8_t radio_reg[10];
static uint8_t flash_config[PFDOA_CONFIG_LEN];
static uint8_t flash_valid;

static pfdoa_anchor_t anchor;

static uint32_t hal_tick(void *ctx)
{
    (void)ctx;
    return systick_ms;
}

static int32_t hal_uart_write(void *ctx, const uint8_t *bytes, size_t len)
{
    (void)ctx;
    for (size_t i = 0u; i < len; i++) {
        uart_tx_reg = bytes[i];
    }
    return 0;
}

static int32_t hal_can_send(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    (void)ctx;
    uart_tx_reg = (uint8_t)id;
    for (uint8_t i = 0u; i < dlc; i++) {
        uart_tx_reg = data[i];
    }
    return 0;
}

static int32_t hal_config_load(void *ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    if (flash_valid == 0u) {
        return -1;
    }
    (void)memcpy(out, flash_config, PFDOA_CONFIG_LEN);
    return 0;
}

static int32_t hal_config_store(void *ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    (void)memcpy(flash_config, config, PFDOA_CONFIG_LEN);
    flash_valid = 1u;
    return 0;
}

static const pfdoa_hal_t hal = {NULL, hal_tick, hal_uart_write, hal_can_send, hal_config_load, hal_config_store};

int main(void)
{
    (void)pfdoa_anchor_init(&anchor, &hal, 1u, PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN);
    for (;;) {
        pfdoa_radio_reading_t r;
        r.seq = (uint16_t)(radio_reg[0] | (radio_reg[1] << 8));
        r.tick_ms = systick_ms;
        r.rssi_dbm = (int8_t)radio_reg[2];
        r.channel = radio_reg[3];
        r.lqi = radio_reg[4];
        r.radio = radio_reg[5];
        (void)pfdoa_anchor_on_radio(&anchor, &r);
        const uint8_t b = uart_rx_reg;
        (void)pfdoa_anchor_on_uart_rx(&anchor, &b, 1u);
        uint8_t d[8];
        for (uint8_t i = 0u; i < 8u; i++) {
            d[i] = can_rx_data[i];
        }
        (void)pfdoa_anchor_on_can_rx(&anchor, can_rx_id, d, can_rx_dlc);
        (void)pfdoa_anchor_poll(&anchor, systick_ms);
    }
}

void SysTick_Handler(void)
{
    systick_ms++;
}

void Default_Handler(void)
{
    for (;;) {
    }
}

void Reset_Handler(void)
{
    const uint32_t *src = &_data_load;
    for (uint32_t *dst = &_data_start; (uintptr_t)dst < (uintptr_t)&_data_end; dst++) {
        *dst = *src++;
    }
    for (uint32_t *dst = &_bss_start; (uintptr_t)dst < (uintptr_t)&_bss_end; dst++) {
        *dst = 0u;
    }
    (void)main();
    Default_Handler();
}

typedef void (*vector_t)(void);

/* Initial SP, then the Cortex-M exception handlers up to SysTick (index 15). */
__attribute__((section(".vectors"), used)) static const vector_t vectors[16] = {
    (vector_t)(uintptr_t)&_stack_top,
    Reset_Handler,
    Default_Handler, /* NMI */
    Default_Handler, /* HardFault */
    Default_Handler, Default_Handler, Default_Handler, 0, 0, 0, 0,
    Default_Handler, /* SVCall */
    Default_Handler, 0,
    Default_Handler, /* PendSV */
    SysTick_Handler,
};
