#include "semihost.h"

#define SYS_GET_CMDLINE 0x15u
#define SYS_EXIT_EXTENDED 0x20u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

void semihost_exit(uint32_t code)
{
    uint32_t block[2] = { ADP_STOPPED_APPLICATION_EXIT, code };
    register uint32_t r0 __asm__("r0") = SYS_EXIT_EXTENDED;
    register uint32_t *r1 __asm__("r1") = block;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    for (;;) {
        /* Without a semihosting host the call returns: park here. */
        __asm__ volatile("wfi");
    }
}

int semihost_cmdline(char *buf, size_t cap)
{
    if (cap < 2u) {
        return -1;
    }
    /* The host writes at most len bytes including the NUL and returns the length. */
    uint32_t block[2] = { (uint32_t)(uintptr_t)buf, (uint32_t)(cap - 1u) };
    register uint32_t r0 __asm__("r0") = SYS_GET_CMDLINE;
    register uint32_t *r1 __asm__("r1") = block;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    if (r0 != 0u || block[1] >= cap) {
        return -1;
    }
    buf[block[1]] = '\0';
    return (int)block[1];
}
