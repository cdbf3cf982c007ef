/*
 * main.c - the pfdoa anchor on QEMU mps2-an385: the portable core behind this board's
 * HAL, UART0 as the host link. Nothing but protocol frames goes out on the UART; the
 * STATUS frame of the first poll doubles as the banner a host waits for before sending.
 *
 * Built twice (see Makefile): the production image, whose clock is SysTick, and the SIL
 * image (-DPFDOA_SIL_INJECT), where RADIO_INJECT and RADIO_INJECT_RAW frames enter the
 * core's radio receive path and the simulator owns time (sil_clock.h). The SIL image also
 * has a radio to send on: the anchor's own advertisement (SPEC 3.5, 6.1) goes out on the
 * UART as a RADIO_TX frame for the simulator to deliver to the other anchors.
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
    uint8_t id;
    uint8_t started; /* pfdoa_anchor_init done */
#ifdef PFDOA_SIL_INJECT
    sil_clock_t clock;
    uint8_t held[PFDOA_FRAME_WIRE_MAX]; /* the frame in progress while not started */
    uint8_t held_len;
#endif
};

static struct app app;

static uint32_t now_ms(const struct app *a)
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
    return now_ms((const struct app *)ctx);
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

static int32_t filters_load(void *ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    return (board_filters_load(out, PFDOA_FILTER_TABLE_LEN) == PFDOA_FILTER_TABLE_LEN) ? 0 : -1;
}

static int32_t filters_store(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    return board_filters_save(table, PFDOA_FILTER_TABLE_LEN);
}

static const pfdoa_filter_storage_t filter_storage = {
    .ctx = &app,
    .load = filters_load,
    .store = filters_store,
};

#ifdef PFDOA_SIL_INJECT
/* BLE AdvA of the SIL anchor's advertisement, on-air order: its id, then 00 00 00 00 C5 (a
 * random static address: the top two bits of its last byte set). */
#define SIL_ADV_A_TOP 0xC5u

/* The radio sends what it is given as a RADIO_TX frame (SPEC 1.7) at the clock's tick. */
static int32_t peer_send(void *ctx, const uint8_t *frame, size_t len)
{
    const struct app *const a = (const struct app *)ctx;
    uint8_t p[PFDOA_MSG_RADIO_TX_LEN] = {0};
    uint8_t wire[PFDOA_FRAME_WIRE_MAX];
    if (len > PFDOA_MSG_RADIO_TX_FRAME_LEN) {
        return -1;
    }
    for (size_t i = 0u; i < 4u; i++) {
        p[PFDOA_MSG_RADIO_TX_OFF_TICK_MS + i] = (uint8_t)((a->clock.now_ms >> (8u * i)) & 0xFFu);
    }
    p[PFDOA_MSG_RADIO_TX_OFF_RADIO] = PFDOA_RADIO_BLE;
    p[PFDOA_MSG_RADIO_TX_OFF_LENGTH] = (uint8_t)len;
    for (size_t i = 0u; i < len; i++) {
        p[PFDOA_MSG_RADIO_TX_OFF_FRAME + i] = frame[i];
    }
    const int32_t n = pfdoa_frame_encode(PFDOA_MSG_RADIO_TX, a->id, p, sizeof p, wire, sizeof wire);
    if (n > 0) {
        board_uart_write(wire, (size_t)n);
    }
    return n;
}
#endif

static const pfdoa_hal_t hal = {
    .ctx = &app,
    .tick_ms = hal_tick_ms,
    .uart_write = hal_uart_write,
    .can_send = NULL,
    .config_load = hal_config_load,
    .config_store = hal_config_store,
};

/* Initialises the anchor, with the stored filter table if any; its boot tick is now_ms(). */
static void start(struct app *a)
{
    if ((pfdoa_anchor_init(&a->anchor, &hal, a->id, PFDOA_TRANSPORT_UART) != PFDOA_OK)
        || (pfdoa_anchor_use_filter_storage(&a->anchor, &filter_storage) != PFDOA_OK)) {
        board_exit(EXIT_INIT_FAILED);
    }
#ifdef PFDOA_SIL_INJECT
    pfdoa_peer_radio_t radio = {.ctx = a, .send = peer_send, .radio = PFDOA_RADIO_BLE, .address = {0}};
    radio.address[0] = a->id;
    radio.address[PFDOA_BLE_ADV_A_LEN - 1u] = SIL_ADV_A_TOP;
    if (pfdoa_anchor_use_peer_radio(&a->anchor, &radio) != PFDOA_OK) {
        board_exit(EXIT_INIT_FAILED);
    }
#endif
    a->started = 1u;
}

#ifdef PFDOA_SIL_INJECT
/*
 * Cold start (QEMU launched): the anchor starts at once, at the tick= parameter, and its
 * first STATUS is the banner. Warm reset (QMP system_reset: the simulator powered the
 * anchor off and on): like a real MCU it boots when power is back, i.e. at the tick of the
 * first reading injected after the reset; until then the frame in progress is held. So a
 * rebooted anchor's uptime restarts whatever tick base the simulator uses. .noinit
 * survives a warm reset; QEMU zeroes RAM at a cold start.
 */
#define SIL_BOOTED_MAGIC 0x53494C42u /* "SILB" */
__attribute__((section(".noinit"))) static uint32_t sil_booted;

static int sil_warm_reset(void)
{
    const int warm = (sil_booted == SIL_BOOTED_MAGIC);
    sil_booted = SIL_BOOTED_MAGIC;
    return warm;
}

/* One received byte; after each injected reading, a poll at its tick (the host build's
 * event script says `U t <frame>` then `P t`). */
static void on_rx_byte(struct app *a, uint8_t byte)
{
    const int injected = sil_clock_push(&a->clock, byte);
    if (a->started == 0u) {
        if (a->held_len < sizeof a->held) {
            a->held[a->held_len++] = byte;
        }
        if (injected == 0) {
            if (byte == 0u) {
                a->held_len = 0u; /* a whole frame before power-on: never seen */
            }
            return;
        }
        start(a);
        (void)pfdoa_anchor_on_uart_rx(&a->anchor, a->held, a->held_len);
        a->held_len = 0u;
    } else {
        (void)pfdoa_anchor_on_uart_rx(&a->anchor, &byte, 1u);
    }
    if (injected != 0) {
        (void)pfdoa_anchor_poll(&a->anchor, a->clock.now_ms);
    }
}
#else
static void on_rx_byte(struct app *a, uint8_t byte)
{
    (void)pfdoa_anchor_on_uart_rx(&a->anchor, &byte, 1u);
}
#endif

int main(void)
{
    board_init();
    app.id = (uint8_t)board_param_u32("id", PFDOA_ANCHOR_ID_MAX, DEFAULT_ANCHOR_ID);
#ifdef PFDOA_SIL_INJECT
    sil_clock_init(&app.clock, app.id, board_param_u32("tick", UINT32_MAX, 0u));
    if (sil_warm_reset() == 0) {
        start(&app);
    }
#else
    board_tick_start();
    start(&app);
#endif
    for (;;) {
        uint8_t rx[32];
        const size_t n = board_uart_read(rx, sizeof rx);
        for (size_t i = 0; i < n; ++i) {
            on_rx_byte(&app, rx[i]);
        }
        if (app.started != 0u) {
            (void)pfdoa_anchor_poll(&app.anchor, now_ms(&app));
        }
        if (n == 0u) {
            board_idle();
        }
    }
}
