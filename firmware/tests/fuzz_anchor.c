/*
 * libFuzzer target: arbitrary bytes drive one anchor through every entry point (radio
 * readings, raw BLE advertisements / PDUs / 802.15.4 frames, filter entries set locally,
 * polls, UART chunks, CAN frames), in the order the bytes say. Checked on every step,
 * beyond "no crash" (ASan/UBSan): each emitted UART frame is a whole, valid anchor-to-host
 * frame from this anchor and a report names a used filter entry; CAN frames have valid ids
 * and DLCs; the decoder and event state are bounded; the active configuration and filter
 * table are valid and match their hashes.
 *
 *   make -C firmware fuzz FUZZ_SECONDS=60        (clang + libFuzzer)
 * Built with -DFUZZ_STANDALONE it instead runs each file named on the command line once
 * (regression replay of crash-* files without libFuzzer).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pfdoa_anchor.h"

static const uint8_t to_host_types[] = {PFDOA_MSG_RSSI_REPORT, PFDOA_MSG_STATUS, PFDOA_MSG_CONFIG_ACK,
                                        PFDOA_MSG_FILTER_ACK};

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
static uint8_t stored_table[PFDOA_FILTER_TABLE_LEN];
static int have_table;
static pfdoa_anchor_t a;

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
    if (f.type == PFDOA_MSG_RSSI_REPORT) {
        const uint8_t b = f.payload[PFDOA_MSG_RSSI_REPORT_OFF_BEACON];
        CHECK(b < PFDOA_BEACON_SLOTS);
        CHECK((b == 0u) || (a.filters[b].kind != PFDOA_FILTER_NONE)); /* on_radio readings are entry 0 */
    }
    return 0;
}

static int32_t f_can(void *ctx, uint16_t id, const uint8_t *data, uint8_t dlc)
{
    (void)ctx;
    (void)data;
    CHECK((id & PFDOA_CAN_ANCHOR_MASK) == own_id);
    CHECK(pfdoa_can_check(id, dlc) == PFDOA_OK);
    CHECK((id >> PFDOA_CAN_ANCHOR_BITS) != PFDOA_CAN_CONFIG_SET);
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

static int32_t f_tload(void *ctx, uint8_t out[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    if (have_table == 0) {
        return -1;
    }
    memcpy(out, stored_table, PFDOA_FILTER_TABLE_LEN);
    return 0;
}

static int32_t f_tstore(void *ctx, const uint8_t table[PFDOA_FILTER_TABLE_LEN])
{
    (void)ctx;
    memcpy(stored_table, table, PFDOA_FILTER_TABLE_LEN);
    have_table = 1;
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const pfdoa_hal_t hal = {NULL, f_tick, f_uart, f_can, f_load, f_store};
    static const pfdoa_filter_storage_t storage = {NULL, f_tload, f_tstore};
    if (size < 2u) {
        return 0;
    }
    own_id = (uint8_t)(data[0] % 127u);
    /* The second byte's high bit: start from a stored configuration taken from the input;
     * bit 6: a stored filter table from the input after it (valid or not). */
    have_stored = ((data[1] & 0x80u) != 0u) && (size >= 9u);
    if (have_stored != 0) {
        memcpy(stored, &data[2], PFDOA_CONFIG_LEN);
    }
    have_table = ((data[1] & 0x40u) != 0u) && (size >= 2u + PFDOA_FILTER_TABLE_LEN);
    if (have_table != 0) {
        memcpy(stored_table, &data[2], PFDOA_FILTER_TABLE_LEN);
    }
    CHECK(pfdoa_anchor_init(&a, &hal, own_id, (uint8_t)((data[1] % 3u) + 1u)) == PFDOA_OK);
    CHECK(pfdoa_anchor_use_filter_storage(&a, &storage) == PFDOA_OK);
    size_t i = 2u;
    uint32_t tick = 0u;
    while (i < size) {
        const uint8_t op = data[i++];
        const size_t left = size - i;
        switch (op % 6u) {
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
        case 4u: { /* a raw reception: rssi channel dt, then up to 47 frame bytes (op >> 3) */
            if (left < 3u) {
                return 0;
            }
            tick += data[i + 2u];
            const pfdoa_rx_t rx = {tick, (int8_t)data[i], (uint8_t)(data[i + 1u] & 0x3Fu), data[i + 1u]};
            i += 3u;
            size_t n = (size_t)(op >> 3) + (((op & 4u) != 0u) ? 16u : 0u);
            if (n > size - i) {
                n = size - i;
            }
            int32_t rc;
            const unsigned which = (unsigned)data[i - 2u] >> 6;
            if (which == 0u) {
                rc = pfdoa_anchor_on_ble_pdu(&a, &rx, &data[i], n);
            } else if (which == 1u) {
                rc = pfdoa_anchor_on_802154(&a, &rx, &data[i], n);
            } else if (n >= PFDOA_BLE_ADV_A_LEN) {
                rc = pfdoa_anchor_on_ble_adv(&a, &rx, &data[i], &data[i + PFDOA_BLE_ADV_A_LEN], n - PFDOA_BLE_ADV_A_LEN);
            } else {
                rc = 0;
            }
            CHECK((rc == 0) || (rc == 1) || (rc == PFDOA_ERR_ARG));
            i += n;
            break;
        }
        case 5u: { /* a filter entry set locally: index, then the stored form */
            if (left < 1u + PFDOA_FILTER_ENTRY_LEN) {
                return 0;
            }
            pfdoa_beacon_filter_t f;
            pfdoa_beacon_filter_unpack(&data[i + 1u], &f);
            const int32_t rc = pfdoa_anchor_set_filter(&a, data[i], &f);
            CHECK(rc == (((data[i] < PFDOA_BEACON_SLOTS) && (pfdoa_beacon_filter_validate(&f) == PFDOA_OK))
                             ? PFDOA_ACK_OK : PFDOA_ACK_INVALID));
            i += 1u + PFDOA_FILTER_ENTRY_LEN;
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
        for (size_t k = 0u; k < PFDOA_BEACON_SLOTS; k++) {
            CHECK(a.slots[k].event.n <= PFDOA_BLE_EVENT_MAX_READINGS);
            CHECK(pfdoa_beacon_filter_validate(&a.filters[k]) == PFDOA_OK);
        }
        CHECK(pfdoa_anchor_filter_hash(&a) == pfdoa_beacon_filters_hash(a.filters));
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
