/*
 * main.c - the pfdoa anchor on QEMU mps2-an385: the portable core behind this board's
 * HAL, UART0 as the host link. Nothing but protocol frames goes out on the UART; the
 * STATUS frame of the first poll doubles as the banner a host waits for before sending.
 *
 * Built twice (see Makefile): the production image, whose clock is SysTick, and the SIL
 * image (-DPFDOA_SIL_INJECT), where RADIO_INJECT frames enter the core's radio receive
 * path and the simulator owns time (sil_clock.h).
 */
#include <stdint.h>

#include "board.h"
#include "pfdoa_anchor.h"
#ifdef PFDOA_SIL_INJECT
#include "sil_clock.h"
#endif

#define DEFAULT_ANCHOR_ID 1u /* when QEMU is started without arg=id=N (as anchor_script) */
#define EXIT_INIT_FAILED  2

/* Everything the application owns, in one static instance (the stack stays small). */
struct app {
    pfdoa_anchor_t anchor;
#ifdef PFDOA_SIL_INJECT
    sil_clock_t clock;
#endif
};

static struct app app;

#ifdef PFDOA_SIL_INJECT
/* The SIL clock across a warm reset (.noinit: not zeroed at reset; QEMU zeroes RAM at a
 * cold start). A rebooted anchor boots at the time it last saw, not at the tick QEMU was
 * started with, so its uptime restarts as a real anchor's does and the gateway sees the
 * reboot. */
#define SIL_RETAINED_MAGIC 0x53494C54u /* "SILT" */
struct sil_retained {
    uint32_t magic;
    uint32_t tick_ms;
};
__attribute__((section(".noinit"))) static struct sil_retained sil_retained;

static uint32_t sil_boot_tick(void)
{
    if (sil_retained.magic != SIL_RETAINED_MAGIC) {
        sil_retained.tick_ms = board_param_u32("tick", UINT32_MAX, 0u);
        sil_retained.magic = SIL_RETAINED_MAGIC;
    }
    return sil_retained.tick_ms;
}
#endif

static uint32_t now_ms(struct app *a)
{
#ifdef PFDOA_SIL_INJECT
    return a->clock.now_ms;
#else
    (void)a;
    return board_tick_ms();
#endif
}

static uint32_t hal_tick_ms(void *ctx)
{
    return now_ms((struct app *)ctx);
}

static int32_t hal_uart_write(void *ctx, const uint8_t *bytes, size_t len)
{
    (void)ctx;
    board_uart_write(bytes, len); /* blocking: the whole frame always goes out */
    return (int32_t)len;
}

static int32_t hal_config_load(void *ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    return (board_config_load(out, PFDOA_CONFIG_LEN) == PFDOA_CONFIG_LEN) ? 0 : -1;
}

static int32_t hal_config_store(void *ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    return board_config_save(config, PFDOA_CONFIG_LEN);
}

/* One received byte: to the anchor, and in the SIL image, a poll at the injected tick
 * right after each injected reading (what the host build's event script does). */
static void on_rx_byte(struct app *a, uint8_t byte)
{
    (void)pfdoa_anchor_on_uart_rx(&a->anchor, &byte, 1u);
#ifdef PFDOA_SIL_INJECT
    if (sil_clock_push(&a->clock, byte) != 0) {
        sil_retained.tick_ms = a->clock.now_ms;
        (void)pfdoa_anchor_poll(&a->anchor, a->clock.now_ms);
    }
#endif
}

int main(void)
{
    board_init();
    const uint8_t id = (uint8_t)board_param_u32("id", PFDOA_ANCHOR_ID_MAX, DEFAULT_ANCHOR_ID);
#ifdef PFDOA_SIL_INJECT
    sil_clock_init(&app.clock, id, sil_boot_tick());
#else
    board_tick_start();
#endif
    const pfdoa_hal_t hal = {
        .ctx = &app,
        .tick_ms = hal_tick_ms,
        .uart_write = hal_uart_write,
        .can_send = NULL,
        .config_load = hal_config_load,
        .config_store = hal_config_store,
    };
    if (pfdoa_anchor_init(&app.anchor, &hal, id, PFDOA_TRANSPORT_UART) != PFDOA_OK) {
        return EXIT_INIT_FAILED;
    }
    for (;;) {
        uint8_t rx[32];
        const size_t n = board_uart_read(rx, sizeof rx);
        for (size_t i = 0; i < n; ++i) {
            on_rx_byte(&app, rx[i]);
        }
        (void)pfdoa_anchor_poll(&app.anchor, now_ms(&app));
        if (n == 0u) {
            board_idle();
        }
    }
}
