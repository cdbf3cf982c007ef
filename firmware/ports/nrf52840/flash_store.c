#include "flash_store.h"

#include <string.h>

#include "nrf52840.h"
#include "pfdoa_crc16.h"

#define ERASED     0xFFFFFFFFu
#define DATA_MAX   FLASH_STORE_FILTERS_MAX /* the larger of the two logs */

/* One log: its page, the magic its records start with, and the data words per record. */
typedef struct log_desc {
    uint32_t page;       /* NRF_STORE_PAGE index */
    uint32_t magic;
    uint32_t data_words;
} log_desc_t;

static const log_desc_t logs[FLASH_STORE_LOGS] = {
    [FLASH_LOG_CONFIG] = { 0u, 0x50464431u /* "PFD1" */, FLASH_STORE_CONFIG_MAX / 4u },
    [FLASH_LOG_FILTERS] = { 1u, 0x50464631u /* "PFF1" */, FLASH_STORE_FILTERS_MAX / 4u },
};
typedef char flash_store_sizes_are_words[((FLASH_STORE_CONFIG_MAX % 4u) == 0u && (FLASH_STORE_FILTERS_MAX % 4u) == 0u
                                          && FLASH_STORE_CONFIG_MAX <= DATA_MAX && DATA_MAX < 256u) ? 1 : -1];

/* magic, data words, length/CRC word */
static uint32_t record_words(const log_desc_t *const d)
{
    return 2u + d->data_words;
}

static uint32_t records(const log_desc_t *const d)
{
    return (NRF_FLASH_PAGE_SIZE / 4u) / record_words(d);
}

uint32_t flash_store_records(const flash_log_t log)
{
    return ((uint32_t)log < FLASH_STORE_LOGS) ? records(&logs[log]) : 0u;
}

static const volatile uint32_t *record(const log_desc_t *const d, const uint32_t i)
{
    return &NRF_STORE_PAGE(d->page)[i * record_words(d)];
}

static uint16_t record_crc(const uint8_t *const data, const uint32_t len)
{
    const uint8_t l = (uint8_t)len;
    return pfdoa_crc16_update(pfdoa_crc16_update(0xFFFFu, &l, 1u), data, len);
}

/* The data of a valid record into out (the log's data_words * 4 bytes): its length, or -1. */
static int32_t read_record(const log_desc_t *const d, const uint32_t i, uint8_t *const out)
{
    const volatile uint32_t *const r = record(d, i);
    if (r[0] != d->magic) {
        return -1;
    }
    const uint32_t max = 4u * d->data_words;
    for (uint32_t k = 0u; k < max; ++k) {
        out[k] = (uint8_t)(r[1u + k / 4u] >> (8u * (k % 4u)));
    }
    const uint32_t last = r[1u + d->data_words];
    const uint32_t len = (last >> 16) & 0xFFu;
    if (len == 0u || len > max || (last & 0xFFFFu) != record_crc(out, len)) {
        return -1;
    }
    return (int32_t)len;
}

static int is_erased(const log_desc_t *const d, const uint32_t i)
{
    const volatile uint32_t *const r = record(d, i);
    for (uint32_t k = 0u; k < record_words(d); ++k) {
        if (r[k] != ERASED) {
            return 0;
        }
    }
    return 1;
}

/* The last valid record's index and data, or -1; *free_slot gets the first erased slot
 * after everything written (records(d) when the page is full). */
static int32_t find_last(const log_desc_t *const d, uint8_t out[DATA_MAX], int32_t *const len,
                         uint32_t *const free_slot)
{
    int32_t last = -1;
    uint32_t i = 0u;
    for (; i < records(d) && !is_erased(d, i); ++i) {
        uint8_t tmp[DATA_MAX];
        const int32_t n = read_record(d, i, tmp);
        if (n > 0) {
            last = (int32_t)i;
            *len = n;
            memcpy(out, tmp, (size_t)n);
        }
    }
    *free_slot = i;
    return last;
}

int32_t flash_store_load(const flash_log_t log, uint8_t *const out, const size_t len)
{
    uint8_t data[DATA_MAX];
    int32_t n = 0;
    uint32_t free_slot;
    if ((uint32_t)log >= FLASH_STORE_LOGS || out == NULL || find_last(&logs[log], data, &n, &free_slot) < 0
        || (size_t)n != len) {
        return -1;
    }
    memcpy(out, data, len);
    return 0;
}

static int wait_ready(void)
{
    for (uint32_t i = 0u; i < FLASH_STORE_SPINS; ++i) {
        NRF_SPIN();
        if (NRF_NVMC->READY != 0u) {
            return 1;
        }
    }
    return 0;
}

static int32_t erase_page(const log_desc_t *const d)
{
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_EEN;
    NRF_NVMC->ERASEPAGE = NRF_DMA_ADDR(NRF_STORE_PAGE(d->page));
    const int ok = wait_ready();
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_REN;
    return ok ? 0 : FLASH_STORE_ERR_TIMEOUT;
}

static int32_t write_words(const log_desc_t *const d, const uint32_t slot, const uint32_t *const words)
{
    const volatile uint32_t *const r = record(d, slot);
    int ok = 1;
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_WEN;
    for (uint32_t k = 0u; k < record_words(d) && ok; ++k) {
        NRF_FLASH_WRITE(&r[k], words[k]); /* the length/CRC word last */
        ok = wait_ready();
    }
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_REN;
    return ok ? 0 : FLASH_STORE_ERR_TIMEOUT;
}

int32_t flash_store_save(const flash_log_t log, const uint8_t *const data, const size_t len)
{
    if ((uint32_t)log >= FLASH_STORE_LOGS || data == NULL || len == 0u || len > 4u * logs[log].data_words) {
        return FLASH_STORE_ERR_ARG;
    }
    const log_desc_t *const d = &logs[log];
    uint8_t last[DATA_MAX];
    int32_t last_len = 0;
    uint32_t slot;
    if (find_last(d, last, &last_len, &slot) >= 0 && (size_t)last_len == len && memcmp(last, data, len) == 0) {
        return 0; /* already stored: no wear */
    }
    if (slot >= records(d)) {
        const int32_t rc = erase_page(d);
        if (rc != 0) {
            return rc;
        }
        slot = 0u;
    }
    uint8_t padded[DATA_MAX];
    memset(padded, 0xFF, sizeof padded);
    memcpy(padded, data, len);
    uint32_t words[2u + DATA_MAX / 4u];
    memset(words, 0, sizeof words);
    words[0] = d->magic;
    for (uint32_t k = 0u; k < 4u * d->data_words; ++k) {
        words[1u + k / 4u] |= (uint32_t)padded[k] << (8u * (k % 4u));
    }
    words[1u + d->data_words] = 0xFF000000u | ((uint32_t)len << 16) | record_crc(padded, (uint32_t)len);
    return write_words(d, slot, words);
}
