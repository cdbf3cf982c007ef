/*
 * auth_bench.c - what our authenticated beacon (SPEC 9) costs, counted in instructions under
 * QEMU with -icount shift=0 (one instruction per virtual nanosecond): built for Cortex-M4
 * (run on mps2-an386) and Cortex-M0+ (run on mps2-an385, which executes v6-M code), with
 * the same flags as the size images (-Os -mthumb), the core and the beacon as they are.
 *
 * SysTick runs on the processor clock, so its count is virtual time: a loop of a known
 * number of instructions (2 per turn, written in assembly) calibrates instructions per
 * tick, and every measurement is a difference of two SysTick reads around N repetitions.
 * Printed through semihosting (SYS_WRITE0), one "name instructions-per-operation" line
 * each, then exit status 0 (bench/firmware.py runs it and checks it).
 */
#include <stdint.h>
#include <string.h>

#include "pfdoa_anchor.h"
#include "pfdoa_auth.h"
#include "pfdoa_beacon.h"
#include "semihost.h"

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SYST_CSR_ENABLE 0x1u
#define SYST_CSR_CLKSOURCE 0x4u /* the processor clock */

#define CALIB_TURNS 200000u
#define REPEAT 64u
#define SYS_WRITE0 0x04u

extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[];
int main(void);
void Reset_Handler(void);
void Fault_Handler(void);

static void write0(const char *s)
{
    register uint32_t r0 __asm__("r0") = SYS_WRITE0;
    register const char *r1 __asm__("r1") = s;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
}

static void print_line(const char *name, const uint32_t value)
{
    char buf[64];
    size_t n = strlen(name);
    (void)memcpy(buf, name, n);
    buf[n++] = ' ';
    char digits[11];
    size_t k = 0u;
    uint32_t v = value;
    do {
        digits[k++] = (char)('0' + (v % 10u));
        v /= 10u;
    } while (v != 0u);
    while (k > 0u) {
        buf[n++] = digits[--k];
    }
    buf[n++] = '\n';
    buf[n] = '\0';
    write0(buf);
}

static uint32_t now(void)
{
    return SYST_CVR; /* counts down */
}

static uint32_t since(const uint32_t t0)
{
    return (t0 - now()) & 0xFFFFFFu;
}

/* 2 * turns instructions: subs + bne per turn. */
static void spin(uint32_t turns)
{
    __asm__ volatile(".syntax unified\n1: subs %0, %0, #1\n\tbne 1b" : "+l"(turns) : : "cc");
}

static uint32_t fake_tick;
static uint32_t beacon_tick(void *ctx)
{
    (void)ctx;
    return fake_tick;
}

static uint8_t last_frame[PFDOA_BEACON_AUTH_PDU_LEN];
static size_t last_len;
static int32_t beacon_send(void *ctx, uint8_t radio, int8_t tx_power_dbm, const uint8_t *frame, size_t len)
{
    (void)ctx;
    (void)radio;
    (void)tx_power_dbm;
    last_len = (len <= sizeof last_frame) ? len : sizeof last_frame;
    (void)memcpy(last_frame, frame, last_len);
    return 0;
}

static pfdoa_beacon_t beacon;
static pfdoa_anchor_t anchor;
static uint8_t pdus[REPEAT][PFDOA_BEACON_AUTH_PDU_LEN];

int main(void)
{
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = SYST_CSR_ENABLE | SYST_CSR_CLKSOURCE;

    /* Instructions per 1,000 SysTick ticks, from the calibration loop. */
    uint32_t t0 = now();
    spin(CALIB_TURNS);
    const uint32_t calib_ticks = since(t0);
    const uint32_t per_kilotick = (uint32_t)((2ull * CALIB_TURNS * 1000ull) / calib_ticks);
#define INSNS(ticks) ((uint32_t)(((uint64_t)(ticks) * per_kilotick) / (1000ull * REPEAT)))

    static const uint8_t key[PFDOA_AUTH_KEY_LEN] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};
    pfdoa_beacon_hal_t hal;
    (void)memset(&hal, 0, sizeof hal);
    hal.radio_send = beacon_send;
    hal.tick_ms = beacon_tick;
    pfdoa_beacon_config_t cfg;
    pfdoa_beacon_config_defaults(&cfg);
    cfg.auth = 1u;
    (void)memcpy(cfg.auth_key, key, sizeof key);
    if ((pfdoa_beacon_init(&beacon, &hal, &cfg) != PFDOA_OK) ||
        (pfdoa_beacon_set_time(&beacon, 432900000u, 0u, 0u) != PFDOA_OK)) {
        semihost_exit(2u);
    }
    (void)pfdoa_beacon_on_timer(&beacon); /* the period's identifiers: derived once */

    /* The beacon: one advertisement within a period (tag, payload, PDU, the radio HAL). */
    t0 = now();
    for (uint32_t i = 0u; i < REPEAT; i++) {
        (void)pfdoa_beacon_on_timer(&beacon);
        (void)memcpy(pdus[i], last_frame, last_len);
    }
    print_line("beacon_advertisement", INSNS(since(t0)));

    /* A new period's identifiers (once every 4.096 s). */
    pfdoa_hmac_key_t k;
    pfdoa_hmac_init(&k, key, sizeof key);
    pfdoa_auth_ids_t ids;
    t0 = now();
    for (uint32_t i = 0u; i < REPEAT; i++) {
        pfdoa_auth_derive(&k, 432900000u + i, &ids);
    }
    print_line("period_identifiers", INSNS(since(t0)));

    /* The anchor: a reception of the beacon's PDU through pfdoa_anchor_on_ble_pdu, verified
     * (the period's rid cached: one HMAC) and folded; each advertisement heard once. */
    if (pfdoa_anchor_init(&anchor, NULL, 1u, PFDOA_TRANSPORT_UART) != PFDOA_OK) {
        semihost_exit(3u);
    }
    pfdoa_beacon_filter_t f;
    (void)memset(&f, 0, sizeof f);
    f.kind = PFDOA_FILTER_PFDOA_AUTH;
    (void)memcpy(f.match, key, sizeof key);
    (void)pfdoa_anchor_set_filter(&anchor, 0u, &f);
    const pfdoa_rx_t warm = {0u, -60, 37u, 0u};
    (void)pfdoa_anchor_on_ble_pdu(&anchor, &warm, pdus[0], PFDOA_BEACON_AUTH_PDU_LEN);
    int32_t accepted = 0;
    t0 = now();
    for (uint32_t i = 1u; i < REPEAT; i++) {
        const pfdoa_rx_t rx = {i * 100u, -60, 37u, 0u};
        accepted += pfdoa_anchor_on_ble_pdu(&anchor, &rx, pdus[i], PFDOA_BEACON_AUTH_PDU_LEN);
    }
    const uint32_t verify_ticks = since(t0);
    print_line("anchor_reception", INSNS(((uint64_t)verify_ticks * REPEAT) / (REPEAT - 1u)));
    /* The same PDUs again: every one a replay, rejected after its tag is checked. */
    t0 = now();
    for (uint32_t i = 0u; i < REPEAT; i++) {
        const pfdoa_rx_t rx = {10000u + i, -60, 38u, 0u};
        (void)pfdoa_anchor_on_ble_pdu(&anchor, &rx, pdus[i], PFDOA_BEACON_AUTH_PDU_LEN);
    }
    print_line("anchor_replay_rejected", INSNS(since(t0)));
    /* For comparison: our static beacon's PDU through the same entry point. */
    f.kind = PFDOA_FILTER_PFDOA;
    (void)memset(f.match, 0, sizeof f.match);
    (void)pfdoa_anchor_set_filter(&anchor, 0u, &f);
    uint8_t plain[PFDOA_BEACON_PDU_LEN];
    static const uint8_t adv_a[6] = {1, 2, 3, 4, 5, 6};
    t0 = now();
    for (uint32_t i = 0u; i < REPEAT; i++) {
        (void)pfdoa_beacon_adv_pdu(adv_a, (uint16_t)i, 0u, plain, sizeof plain);
        const pfdoa_rx_t rx = {20000u + i * 100u, -60, 37u, 0u};
        accepted += pfdoa_anchor_on_ble_pdu(&anchor, &rx, plain, sizeof plain);
    }
    print_line("static_beacon_reception", INSNS(since(t0)));
    print_line("instructions_per_kilotick", per_kilotick);
    semihost_exit((accepted == (int32_t)(2u * REPEAT - 1u)) ? 0u : 4u);
}

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
    semihost_exit((uint32_t)main());
}

void Fault_Handler(void)
{
    semihost_exit(127u);
}

typedef void (*handler_t)(void);
struct vector_table {
    /* cppcheck-suppress unusedStructMember */
    uint32_t *initial_sp;
    /* cppcheck-suppress unusedStructMember */
    handler_t system[15];
};

__attribute__((section(".isr_vector"), used)) static const struct vector_table vectors = {
    .initial_sp = _estack,
    .system = {Reset_Handler, Fault_Handler, Fault_Handler, Fault_Handler, Fault_Handler, Fault_Handler, 0, 0, 0, 0,
               Fault_Handler, Fault_Handler, 0, Fault_Handler, Fault_Handler},
};
