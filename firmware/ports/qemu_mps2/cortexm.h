/*
 * cortexm.h - the few Cortex-M3 core registers and instructions this port uses
 * (ARMv7-M Architecture Reference Manual, B3.2 and B3.3). No vendor CMSIS headers:
 * the port stays self-contained and the core needs none of it.
 */
#ifndef CORTEXM_H
#define CORTEXM_H

#include <stdint.h>

#define CM_REG(addr) (*(volatile uint32_t *)(addr))

/* SysTick */
#define CM_SYST_CSR CM_REG(0xE000E010u)
#define CM_SYST_RVR CM_REG(0xE000E014u)
#define CM_SYST_CVR CM_REG(0xE000E018u)
#define CM_SYST_CSR_ENABLE    (1u << 0)
#define CM_SYST_CSR_TICKINT   (1u << 1)
#define CM_SYST_CSR_CLKSOURCE (1u << 2) /* processor clock */

/* NVIC: one enable bit per interrupt, 32 per register. */
#define CM_NVIC_ISER0 CM_REG(0xE000E100u)
#define CM_NVIC_ICER0 CM_REG(0xE000E180u)

static inline void cm_irq_disable(void) { __asm__ volatile("cpsid i" ::: "memory"); }
static inline void cm_irq_enable(void) { __asm__ volatile("cpsie i" ::: "memory"); }

/* Sleeps until an interrupt is pending. Called with interrupts masked (PRIMASK), WFI
 * still wakes on a pending interrupt, which closes the check-then-sleep race. */
static inline void cm_wfi(void) { __asm__ volatile("wfi" ::: "memory"); }

static inline void cm_nvic_enable(uint32_t irq) { CM_NVIC_ISER0 = 1u << irq; }

#endif /* CORTEXM_H */
