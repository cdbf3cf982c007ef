#include "cmsdk_uart.h"

#include "cortexm.h"

#define UART_DATA(b)     (*(volatile uint32_t *)((b) + 0x00u))
#define UART_STATE(b)    (*(volatile uint32_t *)((b) + 0x04u))
#define UART_CTRL(b)     (*(volatile uint32_t *)((b) + 0x08u))
#define UART_INTCLEAR(b) (*(volatile uint32_t *)((b) + 0x0Cu))
#define UART_BAUDDIV(b)  (*(volatile uint32_t *)((b) + 0x10u))

#define STATE_TX_FULL    (1u << 0)
#define STATE_RX_FULL    (1u << 1)
#define STATE_RX_OVERRUN (1u << 3)
#define CTRL_TX_EN       (1u << 0)
#define CTRL_RX_EN       (1u << 1)
#define CTRL_RX_INT_EN   (1u << 3)
#define INT_RX           (1u << 1)

#define RING_MASK (CMSDK_UART_RX_RING - 1u)

void cmsdk_uart_init(cmsdk_uart_t *uart, uintptr_t base, uint32_t bauddiv)
{
    uart->base = base;
    uart->head = 0u;
    uart->tail = 0u;
    uart->overruns = 0u;
    UART_BAUDDIV(base) = bauddiv;
    UART_INTCLEAR(base) = 0xFu;
    UART_CTRL(base) = CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN;
}

void cmsdk_uart_write(cmsdk_uart_t *uart, const uint8_t *data, size_t len)
{
    for (size_t i = 0; i < len; ++i) {
        while ((UART_STATE(uart->base) & STATE_TX_FULL) != 0u) {
        }
        UART_DATA(uart->base) = data[i];
    }
}

/* Moves bytes from the UART into the ring until the UART is empty or the ring full.
 * Runs in the ISR, or in the main loop with interrupts masked. */
static void drain_hw(cmsdk_uart_t *uart)
{
    const uintptr_t b = uart->base;
    uint32_t state = UART_STATE(b);
    if ((state & STATE_RX_OVERRUN) != 0u) {
        UART_STATE(b) = STATE_RX_OVERRUN; /* write 1 to clear */
        uart->overruns++;
    }
    while ((state & STATE_RX_FULL) != 0u) {
        const uint32_t head = uart->head;
        if (head - uart->tail >= CMSDK_UART_RX_RING) {
            /* Ring full: stop taking interrupts, leave the byte in the UART. */
            UART_CTRL(b) &= ~CTRL_RX_INT_EN;
            return;
        }
        uart->ring[head & RING_MASK] = (uint8_t)UART_DATA(b);
        uart->head = head + 1u;
        state = UART_STATE(b);
    }
}

void cmsdk_uart_rx_isr(cmsdk_uart_t *uart)
{
    UART_INTCLEAR(uart->base) = INT_RX;
    drain_hw(uart);
}

size_t cmsdk_uart_read(cmsdk_uart_t *uart, uint8_t *out, size_t cap)
{
    size_t n = 0;
    uint32_t tail = uart->tail;
    while (n < cap && tail != uart->head) {
        out[n++] = uart->ring[tail & RING_MASK];
        ++tail;
    }
    uart->tail = tail;
    if (n > 0u) {
        /* Room again: pick up a byte held back while the ring was full and re-arm. */
        cm_irq_disable();
        drain_hw(uart);
        if (uart->head - uart->tail < CMSDK_UART_RX_RING) {
            UART_CTRL(uart->base) |= CTRL_RX_INT_EN;
        }
        cm_irq_enable();
    }
    return n;
}

int cmsdk_uart_rx_ready(const cmsdk_uart_t *uart)
{
    return uart->head != uart->tail || (UART_STATE(uart->base) & STATE_RX_FULL) != 0u;
}
