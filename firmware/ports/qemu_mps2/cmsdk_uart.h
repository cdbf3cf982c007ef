/*
 * cmsdk_uart.h - Arm CMSDK APB UART (Cortex-M System Design Kit TRM, DDI0479C):
 * polled TX, interrupt-driven RX into a ring buffer.
 *
 * The UART has a one-byte receive buffer and no FIFO. When the ring is full the RX
 * interrupt is masked and the byte stays in the UART: on QEMU that back-pressures the
 * host (nothing is lost); on silicon the UART flags an overrun, which is counted.
 */
#ifndef CMSDK_UART_H
#define CMSDK_UART_H

#include <stddef.h>
#include <stdint.h>

#define CMSDK_UART_RX_RING 256u /* power of two; two frames of MAX_ENCODED+1 fit easily */

typedef struct {
    uintptr_t base;
    uint8_t ring[CMSDK_UART_RX_RING];
    volatile uint32_t head;      /* written by the RX interrupt only */
    volatile uint32_t tail;      /* written by the main loop only */
    volatile uint32_t overruns;  /* hardware RX overruns seen */
} cmsdk_uart_t;

/* Enables TX and RX at `bauddiv` (PCLK / baud; >= 16) and the RX interrupt in the UART;
 * the caller enables the NVIC line. */
void cmsdk_uart_init(cmsdk_uart_t *uart, uintptr_t base, uint32_t bauddiv);

/* Blocking write (busy-waits on TX-full). */
void cmsdk_uart_write(cmsdk_uart_t *uart, const uint8_t *data, size_t len);

/* Moves up to `cap` received bytes to `out`; returns the count (0 if none). */
size_t cmsdk_uart_read(cmsdk_uart_t *uart, uint8_t *out, size_t cap);

/* True when received bytes wait in the ring or in the UART. */
int cmsdk_uart_rx_ready(const cmsdk_uart_t *uart);

/* Body of the RX interrupt handler. */
void cmsdk_uart_rx_isr(cmsdk_uart_t *uart);

#endif /* CMSDK_UART_H */
