/*
 * cortexm.h - the few Cortex-M4 core registers and instructions this port uses (ARMv7-M
 * Architecture Reference Manual: B3.4 NVIC, B5.2 PRIMASK/CPS, A7.7 WFI). No CMSIS.
 *
 * In a host test build (-DNRF_FAKE) the same functions are the fake's (tests/fake_nrf.c),
 * which records interrupt masking and sleeps so tests can check the check-then-sleep rule.
 */
#ifndef NRF_CORTEXM_H
#define NRF_CORTEXM_H

#include <stdint.h>

#ifdef NRF_FAKE
uint32_t cm_irq_save(void);
void cm_irq_restore(uint32_t primask);
void cm_wfi(void);
void cm_nvic_enable(uint32_t irq, uint32_t priority);
#else
#define CM_REG(addr) (*(volatile uint32_t *)(addr))
#define CM_NVIC_ISER(n) CM_REG(0xE000E100u + 4u * (n))
#define CM_NVIC_ICPR(n) CM_REG(0xE000E280u + 4u * (n))
#define CM_NVIC_IPR8(irq) (*(volatile uint8_t *)(0xE000E400u + (irq)))

/* Masks interrupts (PRIMASK = 1) and returns the previous PRIMASK, for nesting. */
static inline uint32_t cm_irq_save(void)
{
    uint32_t primask;
    __asm__ volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask)::"memory");
    return primask;
}

static inline void cm_irq_restore(uint32_t primask)
{
    __asm__ volatile("msr primask, %0" ::"r"(primask) : "memory");
}

/* Sleeps until an interrupt is pending. Called with PRIMASK set, WFI still wakes on a
 * pending interrupt (which then runs once PRIMASK is cleared): checking for work and
 * sleeping under the mask closes the race with an interrupt arriving in between. */
static inline void cm_wfi(void)
{
    __asm__ volatile("dsb\n\twfi" ::: "memory");
}

/* nRF52840 implements 3 priority bits (the top bits of each byte). */
static inline void cm_nvic_enable(uint32_t irq, uint32_t priority)
{
    CM_NVIC_IPR8(irq) = (uint8_t)(priority << 5);
    CM_NVIC_ICPR(irq >> 5) = 1u << (irq & 31u);
    CM_NVIC_ISER(irq >> 5) = 1u << (irq & 31u);
}
#endif

#endif /* NRF_CORTEXM_H */
