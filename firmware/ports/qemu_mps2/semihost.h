/*
 * semihost.h - ARM semihosting (QEMU -semihosting-config enable=on,target=native):
 * the exit call, so a test reads the firmware's status as QEMU's exit status, and the
 * command line, which carries the anchor id of a QEMU instance. On a board without a
 * debugger attached BKPT would fault: only the QEMU port uses this.
 */
#ifndef SEMIHOST_H
#define SEMIHOST_H

#include <stddef.h>
#include <stdint.h>

/* SYS_EXIT_EXTENDED with ADP_Stopped_ApplicationExit: QEMU exits with `code`
 * (plain SYS_EXIT cannot carry a status on 32-bit ARM). Does not return. */
void semihost_exit(uint32_t code) __attribute__((noreturn));

/* SYS_GET_CMDLINE: copies QEMU's semihosting command line (-semihosting-config
 * arg=...) into buf, NUL-terminated. Returns its length, or -1 if there is none. */
int semihost_cmdline(char *buf, size_t cap);

#endif /* SEMIHOST_H */
