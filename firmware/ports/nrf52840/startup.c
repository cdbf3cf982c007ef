/*
 * startup.c - nRF52840 (Cortex-M4) vector table and reset handler.
 *
 * The reset handler copies .data from flash, zeroes .bss and calls main(). Linker symbol
 * bounds are compared as uintptr_t: comparing pointers to different objects is undefined
 * in C (cppcheck's comparePointers). An unexpected exception resets the chip (the gateway
 * sees the anchor reboot) instead of hanging it.
 */
#include <stdint.h>

#include "app.h"
#include "nrf52840.h"

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
    (void)main();
    Default_Handler();
}

/* ARMv7-M ARM B3.2.6: AIRCR = VECTKEY | SYSRESETREQ. */
#define CM_AIRCR (*(volatile uint32_t *)0xE000ED0Cu)

void Default_Handler(void)
{
    __asm__ volatile("dsb" ::: "memory");
    CM_AIRCR = 0x05FA0004u;
    for (;;) {
    }
}

typedef void (*handler_t)(void);

/* The initial stack pointer is data, not code: a struct keeps it out of the handler array
 * without casting an object address to a function pointer. */
struct vector_table { /* read by the hardware only */
    /* cppcheck-suppress unusedStructMember */
    uint32_t *initial_sp;
    /* cppcheck-suppress unusedStructMember */
    handler_t system[15];             /* exceptions 1..15 */
    /* cppcheck-suppress unusedStructMember */
    handler_t irq[NRF_IRQ_COUNT];     /* PS v1.7 "Memory", peripheral ID = IRQ number */
};

#define D Default_Handler

__attribute__((section(".isr_vector"), used))
static const struct vector_table vectors = {
    .initial_sp = _estack,
    .system = {
        Reset_Handler,
        D, D, D, D, D,       /* NMI, HardFault, MemManage, BusFault, UsageFault */
        0, 0, 0, 0,          /* reserved */
        D, D, 0, D, D,       /* SVCall, DebugMon, reserved, PendSV, SysTick */
    },
    .irq = {
        [NRF_IRQ_POWER_CLOCK] = D,
        [NRF_IRQ_RADIO] = RADIO_IRQHandler,
        [NRF_IRQ_UARTE0] = UARTE0_UART0_IRQHandler,
        [3] = D, [4] = D, [5] = D,
        [NRF_IRQ_GPIOTE] = GPIOTE_IRQHandler,
        [7] = D, [8] = D, [9] = D, [10] = D, [11] = D, [12] = D, [13] = D, [14] = D, [15] = D, [16] = D,
        [NRF_IRQ_RTC1] = RTC1_IRQHandler,
        [18] = D, [19] = D, [20] = D, [21] = D, [22] = D, [23] = D, [24] = D, [25] = D, [26] = D,
        [27] = D, [28] = D, [29] = D, [30] = D, [31] = D, [32] = D, [33] = D, [34] = D, [35] = D,
        [36] = D, [37] = D, [38] = D, [39] = D, [40] = D, [41] = D, [42] = D, [43] = D, [44] = D,
        [45] = D, [46] = D, [47] = D,
    },
};
