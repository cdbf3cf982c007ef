/*
 * semihost.h - ARM semihosting exit, so a test can read the firmware's status as
 * QEMU's exit status (-semihosting-config enable=on,target=native). On a board
 * without a debugger attached, BKPT would fault: only the QEMU port calls this.
 */
#ifndef SEMIHOST_H
#define SEMIHOST_H

#include <stdint.h>

/* SYS_EXIT_EXTENDED with ADP_Stopped_ApplicationExit: QEMU exits with `code`
 * (plain SYS_EXIT cannot carry a status on 32-bit ARM). Does not return. */
void semihost_exit(uint32_t code) __attribute__((noreturn));

#endif /* SEMIHOST_H */
