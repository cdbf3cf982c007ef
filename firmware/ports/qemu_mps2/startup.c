/*
 * startup.c - Cortex-M3 vector table and reset handler for QEMU mps2-an385.
 *
 * The reset handler copies .data from flash, zeroes .bss and calls main(). Linker
 * symbol bounds are compared as uintptr_t: comparing pointers to different objects
 * is undefined in C (and static analysers rightly flag it).
 */
#include <stdint.h>

#include "board.h"

extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[];

int main(void);
void Reset_Handler(void);
void Default_Handler(void);

void Reset_Handler(void)
{
    const uint32_t *src = _sidata;
    uint32_t *dst = _sdata;
    while ((uintptr_t)dst < (uintptr_t)_edata) {
        *dst++ = *src++;
    }
    for (dst = _sbss; (uintptr_t)dst < (uintptr_t)_ebss; ++dst) {
        *dst = 0u;
    }
    board_exit(main());
}

/* An unexpected exception is a firmware bug: leave QEMU with a distinctive status
 * instead of hanging the test that ran us. */
void Default_Handler(void)
{
    board_exit(BOARD_EXIT_FAULT);
}

typedef void (*handler_t)(void);

/* The initial stack pointer is data, not code: a struct keeps it out of the handler
 * array without casting an object address to a function pointer. */
struct vector_table { /* read by the hardware only */
    /* cppcheck-suppress unusedStructMember */
    uint32_t *initial_sp;
    /* cppcheck-suppress unusedStructMember */
    handler_t system[15];               /* exceptions 1..15 */
    /* cppcheck-suppress unusedStructMember */
    handler_t irq[BOARD_IRQ_COUNT];     /* external interrupts */
};

/* C99 static assertion: the table below puts UART0 RX at IRQ 0. */
typedef char uart0_rx_is_irq0[(BOARD_UART0_RX_IRQ == 0u) ? 1 : -1];

#define H15(h) h, h, h, h, h, h, h, h, h, h, h, h, h, h, h

__attribute__((section(".isr_vector"), used))
static const struct vector_table vectors = {
    .initial_sp = _estack,
    .system = {
        Reset_Handler,
        Default_Handler, /* NMI */
        Default_Handler, /* HardFault */
        Default_Handler, /* MemManage */
        Default_Handler, /* BusFault */
        Default_Handler, /* UsageFault */
        0, 0, 0, 0,      /* reserved */
        Default_Handler, /* SVCall */
        Default_Handler, /* DebugMon */
        0,               /* reserved */
        Default_Handler, /* PendSV */
        SysTick_Handler,
    },
    /* Every external interrupt but UART0 RX is a bug if it fires. */
    .irq = {
        UART0_RX_Handler, /* IRQ 0 = BOARD_UART0_RX_IRQ */
        H15(Default_Handler), H15(Default_Handler), Default_Handler,
    },
};
