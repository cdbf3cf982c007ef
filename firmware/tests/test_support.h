/*
 * Shared helpers for the cmocka tests (header-only, each test is one translation unit):
 * hex decoding, a seeded xorshift generator, and a capturing HAL that records every
 * frame the anchor emits.
 */
#ifndef PFDOA_TEST_SUPPORT_H
#define PFDOA_TEST_SUPPORT_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "pfdoa_anchor.h"

/* Decodes lower/upper-case hex; returns the byte count (fails the test on bad hex). */
static inline size_t hex_to_bytes(const char *const hex, uint8_t *const out, const size_t cap)
{
    const size_t n = strlen(hex);
    assert_int_equal(n % 2u, 0u);
    assert_true((n / 2u) <= cap);
    for (size_t i = 0u; i < n; i += 2u) {
        unsigned v = 0u;
        for (size_t k = 0u; k < 2u; k++) {
            const char c = hex[i + k];
            v <<= 4;
            if ((c >= '0') && (c <= '9')) {
                v |= (unsigned)(c - '0');
            } else if ((c >= 'a') && (c <= 'f')) {
                v |= (unsigned)(c - 'a' + 10);
            } else if ((c >= 'A') && (c <= 'F')) {
                v |= (unsigned)(c - 'A' + 10);
            } else {
                fail_msg("bad hex digit in %s", hex);
            }
        }
        out[i / 2u] = (uint8_t)v;
    }
    return n / 2u;
}

/* xorshift32 (Marsaglia 2003): deterministic, seeded per test. */
typedef struct { uint32_t s; } rng_t;

static inline uint32_t rng_next(rng_t *const r)
{
    uint32_t x = r->s;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    r->s = x;
    return x;
}

/* Uniform-ish in [lo, hi] (modulo bias is irrelevant here). */
static inline int32_t rng_range(rng_t *const r, const int32_t lo, const int32_t hi)
{
    const uint32_t span = (uint32_t)(hi - lo) + 1u;
    return lo + (int32_t)(rng_next(r) % span);
}

/* ---- capturing HAL ---- */

#define CAP_MAX_FRAMES 64

typedef struct captured {
    uint8_t is_can;
    uint16_t can_id;
    uint8_t len;
    uint8_t bytes[PFDOA_FRAME_WIRE_MAX];
} captured_t;

typedef struct capture {
    uint32_t tick;
    int stored_valid;
    int store_result;   /* returned by config_store */
    int uart_result;    /* returned by uart_write */
    int can_result;     /* returned by can_send */
    uint32_t stores;
    uint8_t stored[PFDOA_CONFIG_LEN];
    int filters_valid;          /* cap_filters_load has a table */
    int filters_result;         /* returned by cap_filters_store */
    uint32_t filter_stores;
    uint8_t filters[PFDOA_FILTER_TABLE_LEN];
    size_t n;           /* frames captured (saturates at CAP_MAX_FRAMES, total counts on) */
    size_t total;
    captured_t frames[CAP_MAX_FRAMES];
} capture_t;

static inline uint32_t cap_tick(void *const ctx)
{
    return ((const capture_t *)ctx)->tick;
}

static inline void cap_push(capture_t *const c, const uint8_t is_can, const uint16_t id, const uint8_t *const b,
                            const size_t len)
{
    assert_true(len <= PFDOA_FRAME_WIRE_MAX);
    c->total++;
    if (c->n < CAP_MAX_FRAMES) {
        captured_t *const f = &c->frames[c->n++];
        f->is_can = is_can;
        f->can_id = id;
        f->len = (uint8_t)len;
        if (len > 0u) {
            memcpy(f->bytes, b, len);
        }
    }
}

static inline int32_t cap_uart_write(void *const ctx, const uint8_t *const bytes, const size_t len)
{
    capture_t *const c = (capture_t *)ctx;
    cap_push(c, 0u, 0u, bytes, len);
    return c->uart_result;
}

static inline int32_t cap_can_send(void *const ctx, const uint16_t id, const uint8_t *const data, const uint8_t dlc)
{
    capture_t *const c = (capture_t *)ctx;
    assert_true(dlc <= 8u);
    assert_true(id <= 0x7FFu);
    cap_push(c, 1u, id, data, dlc);
    return c->can_result;
}

static inline int32_t cap_config_load(void *const ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    const capture_t *const c = (const capture_t *)ctx;
    if (c->stored_valid == 0) {
        return -1;
    }
    memcpy(out, c->stored, PFDOA_CONFIG_LEN);
    return 0;
}

static inline int32_t cap_config_store(void *const ctx, const uint8_t config[PFDOA_CONFIG_LEN])
{
    capture_t *const c = (capture_t *)ctx;
    c->stores++;
    if (c->store_result >= 0) {
        memcpy(c->stored, config, PFDOA_CONFIG_LEN);
        c->stored_valid = 1;
    }
    return c->store_result;
}

/* Filter table storage (cap_filter_storage), given with pfdoa_anchor_use_filter_storage. */
static inline int32_t cap_filters_load(void *const ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN])
{
    const capture_t *const c = (const capture_t *)ctx;
    if (c->filters_valid == 0) {
        return -1;
    }
    memcpy(out, c->filters, PFDOA_FILTER_TABLE_LEN);
    return 0;
}

static inline int32_t cap_filters_store(void *const ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    capture_t *const c = (capture_t *)ctx;
    c->filter_stores++;
    if (c->filters_result >= 0) {
        memcpy(c->filters, table, PFDOA_FILTER_TABLE_LEN);
        c->filters_valid = 1;
    }
    return c->filters_result;
}

static inline pfdoa_hal_t cap_hal(capture_t *const c)
{
    pfdoa_hal_t h;
    memset(&h, 0, sizeof h);
    h.ctx = c;
    h.tick_ms = cap_tick;
    h.uart_write = cap_uart_write;
    h.can_send = cap_can_send;
    h.config_load = cap_config_load;
    h.config_store = cap_config_store;
    return h;
}

static inline pfdoa_filter_storage_t cap_filter_storage(capture_t *const c)
{
    const pfdoa_filter_storage_t st = {c, cap_filters_load, cap_filters_store};
    return st;
}

/* Decodes captured UART frame i (must be a whole frame with delimiter) for inspection. */
static inline pfdoa_frame_t cap_decode(capture_t *const c, const size_t i, uint8_t *const scratch)
{
    static const uint8_t all_types[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS,         PFDOA_MSG_CONFIG_SET,
                                        PFDOA_MSG_CONFIG_ACK,  PFDOA_MSG_FILTER_SET,     PFDOA_MSG_FILTER_ACK,
                                        PFDOA_MSG_RADIO_INJECT, PFDOA_MSG_RADIO_INJECT_RAW, PFDOA_MSG_AUTH_REPORT,
                                        PFDOA_MSG_AUTH_STATUS};
    pfdoa_frame_t f;
    assert_true(i < c->n);
    const captured_t *const cf = &c->frames[i];
    assert_int_equal(cf->is_can, 0);
    assert_true(cf->len >= 2u);
    assert_int_equal(cf->bytes[cf->len - 1u], 0u);
    memcpy(scratch, cf->bytes, cf->len);
    assert_int_equal(pfdoa_frame_decode(scratch, cf->len - 1u, all_types, sizeof all_types, &f), PFDOA_OK);
    return f;
}

static inline uint16_t le16(const uint8_t *const p)
{
    return (uint16_t)(p[0] | (p[1] << 8));
}

static inline uint32_t le32(const uint8_t *const p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static inline int16_t le16s(const uint8_t *const p)
{
    const uint16_t u = le16(p);
    return (u >= 0x8000u) ? (int16_t)((int32_t)u - 65536) : (int16_t)u;
}

#endif /* PFDOA_TEST_SUPPORT_H */
