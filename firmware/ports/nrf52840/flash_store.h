/*
 * flash_store.h - what the anchor keeps across power cycles, in the last two 4 KB flash
 * pages through the NVMC (PS v1.7, chapter "NVMC - Non-volatile memory controller"):
 *
 *   FLASH_LOG_CONFIG   the 7-byte configuration (CONFIG_SET),   last page 0xFF000
 *   FLASH_LOG_FILTERS  the 92-byte beacon filter table (FILTER_SET), page 0xFE000
 *
 * Each page is a log of records (magic, the data words, then a word with the length and a
 * CRC-16 written last): a store appends, a load takes the last record whose CRC holds. A
 * power cut in the middle of a store leaves a record without its last word, which does not
 * count. A page is erased only when it is full (the configuration: 256 stores per erase,
 * 16-byte records; the filter table: 40 stores per erase, 100-byte records; the flash takes
 * 10,000 erase cycles), and unchanged data is not written again. One page per log, so
 * erasing one (a power cut then loses it) never touches the other.
 *
 * While the NVMC erases (about 85 ms) or writes (about 41 us a word) the CPU stalls and
 * the radio's interrupts wait: a CONFIG_SET or FILTER_SET can cost the packets of that
 * time (a filter-table record is 25 words, about 1 ms).
 */
#ifndef NRF_FLASH_STORE_H
#define NRF_FLASH_STORE_H

#include <stddef.h>
#include <stdint.h>

typedef enum flash_log {
    FLASH_LOG_CONFIG = 0,
    FLASH_LOG_FILTERS = 1
} flash_log_t;

#define FLASH_STORE_LOGS         2u
#define FLASH_STORE_CONFIG_MAX   8u   /* data bytes of a configuration record */
#define FLASH_STORE_FILTERS_MAX  92u  /* data bytes of a filter-table record (PFDOA_FILTER_TABLE_LEN) */
#define FLASH_STORE_SPINS        4000000u /* NVMC READY polls: > an 85 ms page erase */
#define FLASH_STORE_ERR_ARG      -1
#define FLASH_STORE_ERR_TIMEOUT  -2

/* Records one page of the log holds (records per erase). */
uint32_t flash_store_records(flash_log_t log);

/* Reads the stored data (exactly len bytes) of a log into out. Returns 0, or -1 when
 * nothing valid of that length is stored (or log is unknown). */
int32_t flash_store_load(flash_log_t log, uint8_t *out, size_t len);

/* Stores len (1..the log's maximum) bytes. Returns 0 or a negative FLASH_STORE_ERR_*. */
int32_t flash_store_save(flash_log_t log, const uint8_t *data, size_t len);

#endif /* NRF_FLASH_STORE_H */
