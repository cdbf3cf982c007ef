#include "flash_store.h"

#include <string.h>

#include "nrf52840.h"
#include "pfdoa_crc16.h"

#define MAGIC       0x50464431u /* "PFD1" */
#define ERASED      0xFFFFFFFFu
#define WORDS       4u

static const volatile uint32_t *record(const uint32_t i)
{
    return &NRF_CONFIG_PAGE[i * WORDS];
}

static uint16_t record_crc(const uint8_t data[FLASH_STORE_DATA_MAX], const uint32_t len)
{
    const uint8_t l = (uint8_t)len;
    return pfdoa_crc16_update(pfdoa_crc16_update(0xFFFFu, &l, 1u), data, len);
}

/* The data of a valid record into out (FLASH_STORE_DATA_MAX bytes): its length, or -1. */
static int32_t read_record(const uint32_t i, uint8_t out[FLASH_STORE_DATA_MAX])
{
    const volatile uint32_t *const r = record(i);
    if (r[0] != MAGIC) {
        return -1;
    }
    for (uint32_t k = 0u; k < FLASH_STORE_DATA_MAX; ++k) {
        out[k] = (uint8_t)(r[1u + k / 4u] >> (8u * (k % 4u)));
    }
    const uint32_t len = (r[3] >> 16) & 0xFFu;
    if (len == 0u || len > FLASH_STORE_DATA_MAX || (r[3] & 0xFFFFu) != record_crc(out, len)) {
        return -1;
    }
    return (int32_t)len;
}

static int is_erased(const uint32_t i)
{
    const volatile uint32_t *const r = record(i);
    return r[0] == ERASED && r[1] == ERASED && r[2] == ERASED && r[3] == ERASED;
}

/* The last valid record's index and data, or -1; *free_slot gets the first erased slot
 * after everything written (FLASH_STORE_RECORDS when the page is full). */
static int32_t find_last(uint8_t out[FLASH_STORE_DATA_MAX], int32_t *const len, uint32_t *const free_slot)
{
    int32_t last = -1;
    uint32_t i = 0u;
    for (; i < FLASH_STORE_RECORDS && !is_erased(i); ++i) {
        uint8_t tmp[FLASH_STORE_DATA_MAX];
        const int32_t n = read_record(i, tmp);
        if (n > 0) {
            last = (int32_t)i;
            *len = n;
            memcpy(out, tmp, sizeof tmp);
        }
    }
    *free_slot = i;
    return last;
}

int32_t flash_store_load(uint8_t *const out, const size_t len)
{
    uint8_t data[FLASH_STORE_DATA_MAX];
    int32_t n = 0;
    uint32_t free_slot;
    if (out == NULL || find_last(data, &n, &free_slot) < 0 || (size_t)n != len) {
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

static int32_t erase_page(void)
{
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_EEN;
    NRF_NVMC->ERASEPAGE = NRF_DMA_ADDR(NRF_CONFIG_PAGE);
    const int ok = wait_ready();
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_REN;
    return ok ? 0 : FLASH_STORE_ERR_TIMEOUT;
}

static int32_t write_words(const uint32_t slot, const uint32_t words[WORDS])
{
    const volatile uint32_t *const r = record(slot);
    int ok = 1;
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_WEN;
    for (uint32_t k = 0u; k < WORDS && ok; ++k) {
        NRF_FLASH_WRITE(&r[k], words[k]); /* the length/CRC word last */
        ok = wait_ready();
    }
    NRF_NVMC->CONFIG = NRF_NVMC_CONFIG_REN;
    return ok ? 0 : FLASH_STORE_ERR_TIMEOUT;
}

int32_t flash_store_save(const uint8_t *const data, const size_t len)
{
    if (data == NULL || len == 0u || len > FLASH_STORE_DATA_MAX) {
        return FLASH_STORE_ERR_ARG;
    }
    uint8_t last[FLASH_STORE_DATA_MAX];
    int32_t last_len = 0;
    uint32_t slot;
    if (find_last(last, &last_len, &slot) >= 0 && (size_t)last_len == len && memcmp(last, data, len) == 0) {
        return 0; /* already stored: no wear */
    }
    if (slot >= FLASH_STORE_RECORDS) {
        const int32_t rc = erase_page();
        if (rc != 0) {
            return rc;
        }
        slot = 0u;
    }
    uint8_t padded[FLASH_STORE_DATA_MAX];
    memset(padded, 0xFF, sizeof padded);
    memcpy(padded, data, len);
    uint32_t words[WORDS] = { MAGIC, 0u, 0u, 0u };
    for (uint32_t k = 0u; k < FLASH_STORE_DATA_MAX; ++k) {
        words[1u + k / 4u] |= (uint32_t)padded[k] << (8u * (k % 4u));
    }
    words[3] = 0xFF000000u | ((uint32_t)len << 16) | record_crc(padded, (uint32_t)len);
    return write_words(slot, words);
}
