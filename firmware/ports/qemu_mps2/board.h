/*
 * board.h - QEMU mps2-an385 board support: Cortex-M3, CMSDK APB UART0 at 0x40004000,
 * SysTick millisecond tick, a RAM "persistent" configuration store, semihosting exit.
 *
 * Everything board-specific lives behind this header; main.c adapts it to the anchor
 * core's HAL. A port for real silicon provides the same functions in its own folder.
 */
#ifndef BOARD_H
#define BOARD_H

#include <stddef.h>
#include <stdint.h>

#define BOARD_CPU_HZ       25000000u   /* mps2 SYSCLK as QEMU models it */
#define BOARD_UART0_BASE   0x40004000u
#define BOARD_UART0_RX_IRQ 0u          /* UART0 TX is IRQ 1 */
#define BOARD_IRQ_COUNT    32
#define BOARD_BAUDDIV      (BOARD_CPU_HZ / 115200u)

#define BOARD_EXIT_FAULT   0x7Fu       /* QEMU exit status after an unexpected exception */

/* Bytes the RAM configuration store holds (the anchor's 8-byte config fits many times). */
#define BOARD_CONFIG_MAX   32u
/* Bytes the RAM beacon filter table store holds (the core's table is 92). */
#define BOARD_FILTERS_MAX  96u
#define BOARD_CMDLINE_MAX  320u /* id, tick, cfg (14 hex digits), filters (184) */

void board_init(void);

/* Starts the SysTick millisecond tick. Images that take time from elsewhere (the SIL
 * image: the simulator's ticks) leave it off, so an idle QEMU really idles. */
void board_tick_start(void);

/* Milliseconds since board_tick_start (wraps after 49.7 days); 0 if never started. */
uint32_t board_tick_ms(void);

void board_uart_write(const uint8_t *data, size_t len);
size_t board_uart_read(uint8_t *out, size_t cap);

/* Hardware RX overruns so far (bytes lost before the driver saw them). */
uint32_t board_uart_overruns(void);

/* Sleeps until the next interrupt (tick or UART RX), unless RX bytes already wait. */
void board_idle(void);

/* RAM configuration store, kept across a warm reset (.noinit) and validated by a CRC.
 * load returns the stored length: what was saved, else the cfg= parameter when it
 * decodes to exactly `cap` bytes, else 0 (nothing stored). save returns 0, or a negative
 * value when len exceeds BOARD_CONFIG_MAX. */
size_t board_config_load(uint8_t *out, size_t cap);
int board_config_save(const uint8_t *data, size_t len);

/* RAM beacon filter table store (protocol v2), kept and validated like the configuration
 * store: load returns the stored length, else the filters= parameter when it decodes to
 * exactly `cap` bytes, else 0 (the anchor then boots with its first-boot table); save
 * returns 0, or a negative value when len exceeds BOARD_FILTERS_MAX. */
size_t board_filters_load(uint8_t *out, size_t cap);
int board_filters_save(const uint8_t *data, size_t len);

/* Instance parameters, as "key=value" words on the semihosting command line
 * (-semihosting-config ...,arg=id=3,arg=tick=1000). Real boards read the equivalent from
 * OTP, flash or strapping pins.
 *   id=N      anchor id 0..126
 *   tick=N    the SIL image's clock at boot (u32 ms)
 *   cfg=HEX   the configuration "flash" holds at first boot: 7 bytes, 14 hex digits,
 *             the layout of the anchor's stored configuration (offset_q8 i16 LE,
 *             alpha_q8 u16 LE, spike_db, report_mode, decimation)
 *   filters=HEX the beacon filter table "flash" holds at first boot: 92 bytes, 184 hex
 *             digits, the layout of the stored table (SPEC 3.1); an invalid entry
 *             leaves the first-boot table
 * board_param_u32 returns `fallback` when the key is absent, not a decimal number, or
 * above `max`. */
uint32_t board_param_u32(const char *key, uint32_t max, uint32_t fallback);

/* Ends the QEMU run with `code` as its exit status (semihosting). */
void board_exit(int code) __attribute__((noreturn));

/* Interrupt handlers (referenced by the vector table). */
void SysTick_Handler(void);
void UART0_RX_Handler(void);

#endif /* BOARD_H */
