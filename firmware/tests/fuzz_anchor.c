/*
 * libFuzzer target: arbitrary bytes drive one anchor through every entry point (radio
 * readings, polls, UART chunks, CAN frames), in the order the bytes say. Checked on every
 * step, beyond "no crash" (ASan/UBSan): each emitted UART frame is a whole, valid
 * anchor-to-host frame from this anchor; CAN frames have valid ids and DLCs; the decoder
 * state is bounded; the active configuration is valid and matches its hash.
 *
 *   make -C firmware fuzz FUZZ_SECONDS=60        (clang + libFuzzer)
 * Built with -DFUZZ_STANDALONE it instead runs each file named on the command line once
 * (regression replay of crash-* files without libFuzzer).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pfdoa_anchor.h"

static const uint8_t to_host_types[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS, PFDOA_MSG_CONFIG_ACK};

#define CHECK(cond)                                                                            \
    do {                                                                                       \
        if (!(cond)) {                                                                         \
            (void)fprintf(stderr, "fuzz_anchor: check failed: %s (line %d)\n", #cond, __LINE__); \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

static uint8_t own_id;
static uint8_t stored[PFDOA_CONFIG_LEN];
static int have_stored;

static uint32_t f_tick(void *ctx)
{
    (void)ctx;
    return 0u;
}

static int32_t f_uart(void *ctx, const uint8_t *bytes, size_t len)
{
    (void)ctx;
    CHECK((len >= 2u) && (len <= PFDOA_FRAME_WIRE_MAX));
    CHECK(bytes[len - 1u] == 0u);
    CHECK(memchr(bytes, 0, len - 1u) == NULL);
    uint8_t copy[PFDOA_FRAME_WIRE_MAX];
    memcpy(copy, bytes, len);
    pfdoa_frame_t f;
    CHECK(pfdoa_frame_decode(copy, len - 1u, to_host_types, sizeof to_host_types, &f) == PFDOA_OK);
    CHECK(f.anchor_id == own_id);
    return 0;
}

static int32_t f_can(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    (void)ctx;
    (void)data;
    CHECK((id & 0x7Fu) == own_id);
    CHECK(pfdoa_can_check(id, dlc) == PFDOA_OK);
    CHECK((id >> 7) != PFDOA_CAN_CONFIG_SET);
    return 0;
}

static int32_t f_load(void *ctx, uint8_t out[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    if (have_stored == 0) {
        return -1;
    }
    memcpy(out, stored, PFDOA_CONFIG_LEN);
    return 0;
}

static int32_t f_store(void *ctx, const uint8_t cfg[PFDOA_CONFIG_LEN])
{
    (void)ctx;
    memcpy(stored, cfg, PFDOA_CONFIG_LEN);
    have_stored = 1;
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static pfdoa_anchor_t a;
    static const pfdoa_hal_t hal = {NULL, f_tick, f_uart, f_can, f_load, f_store};
    if (size < 2u) {
        return 0;
    }
    own_id = (uint8_t)(data[0] % 127u);
    /* The first byte's high bit: start from a stored configuration taken from the input. */
    have_stored = ((data[1] & 0x80u) != 0u) && (size >= 9u);
    if (have_stored != 0) {
        memcpy(stored, &data[2], PFDOA_CONFIG_LEN);
    }
    CHECK(pfdoa_anchor_init(&a, &hal, own_id, (uint8_t)((data[1] % 3u) + 1u)) == PFDOA_OK);
    size_t i = 2u;
    uint32_t tick = 0u;
    while (i < size) {
        const uint8_t op = data[i++];
        const size_t left = size - i;
        switch (op % 4u) {
        case 0u: { /* radio reading: seq(2) rssi channel radio-bits dt */
            if (left < 5u) {
                return 0;
            }
            pfdoa_radio_reading_t r;
            tick += data[i + 4u];
            r.tick_ms = tick;
            r.seq = (uint16_t)(data[i] | (data[i + 1u] << 8));
            r.rssi_dbm = (int8_t)data[i + 2u];
            r.channel = (uint8_t)(data[i + 3u] & 0x3Fu);
            r.radio = (uint8_t)((op >> 2) % 3u);
            r.lqi = op;
            const int32_t rc = pfdoa_anchor_on_radio(&a, &r);
            CHECK((rc == PFDOA_OK) || (rc == PFDOA_ERR_ARG));
            i += 5u;
            break;
        }
        case 1u: /* poll after (op >> 2) * 7 ms */
            tick += (uint32_t)(op >> 2) * 7u;
            CHECK(pfdoa_anchor_poll(&a, tick) == PFDOA_OK);
            break;
        case 2u: { /* UART chunk of up to 63 bytes */
            size_t n = (size_t)(op >> 2);
            if (n > left) {
                n = left;
            }
            CHECK(pfdoa_anchor_on_uart_rx(&a, &data[i], n) >= 0);
            i += n;
            break;
        }
        default: { /* CAN frame: id(2) + up to 8 data bytes */
            if (left < 2u) {
                return 0;
            }
            const uint16_t id = (uint16_t)(((unsigned)data[i] | ((unsigned)data[i + 1u] << 8)) & 0x7FFu);
            i += 2u;
            uint8_t dlc = (uint8_t)((op >> 2) % 9u);
            if (dlc > (size - i)) {
                dlc = (uint8_t)(size - i);
            }
            const int32_t rc = pfdoa_anchor_on_can_rx(&a, id, &data[i], dlc);
            CHECK((rc == 0) || (rc == 1) || (rc == PFDOA_ERR_BAD_LENGTH));
            i += dlc;
            break;
        }
        }
        CHECK(a.decoder.len <= PFDOA_MAX_ENCODED);
        CHECK(a.event.n <= 3u);
        pfdoa_config_t c;
        CHECK(pfdoa_anchor_get_config(&a, &c) == PFDOA_OK);
        CHECK(pfdoa_config_validate(&c) == PFDOA_OK);
        CHECK(pfdoa_anchor_config_hash(&a) == pfdoa_config_hash(&c));
    }
    return 0;
}

#ifdef FUZZ_STANDALONE
int main(int argc, char **argv)
{
    static uint8_t buf[1 << 16];
    for (int k = 1; k < argc; k++) {
        FILE *const fp = fopen(argv[k], "rb");
        if (fp == NULL) {
            perror(argv[k]);
            return 2;
        }
        const size_t n = fread(buf, 1u, sizeof buf, fp);
        (void)fclose(fp);
        (void)LLVMFuzzerTestOneInput(buf, n);
        (void)printf("%s: ok (%zu bytes)\n", argv[k], n);
    }
    return 0;
}
#endif
