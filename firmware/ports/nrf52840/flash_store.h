/*
 * flash_store.h - the anchor's configuration in the last 4 KB flash page, through the NVMC
 * (PS v1.7, chapter "NVMC - Non-volatile memory controller").
 *
 * The page is a log of 16-byte records (magic, 8 data bytes, then a word with the length
 * and a CRC-16 written last): a store appends, a load takes the last record whose CRC
 * holds. A power cut in the middle of a store leaves a record without its last word, which
 * does not count. The page is erased only when it is full (256 stores per erase, against
 * the flash's 10,000 erase cycles), and an unchanged configuration is not written again.
 *
 * While the NVMC erases (about 85 ms) or writes (about 41 us a word) the CPU stalls and
 * the radio's interrupts wait: a CONFIG_SET can cost the packets of that time.
 */
#ifndef NRF_FLASH_STORE_H
#define NRF_FLASH_STORE_H

#include <stddef.h>
#include <stdint.h>

#define FLASH_STORE_DATA_MAX 8u
#define FLASH_STORE_RECORDS  (4096u / 16u)
#define FLASH_STORE_SPINS    4000000u /* NVMC READY polls: > an 85 ms page erase */
#define FLASH_STORE_ERR_ARG     -1
#define FLASH_STORE_ERR_TIMEOUT -2

/* Reads the stored data (exactly len bytes) into out. Returns 0, or -1 when nothing valid
 * of that length is stored. */
int32_t flash_store_load(uint8_t *out, size_t len);

/* Stores len (1..FLASH_STORE_DATA_MAX) bytes. Returns 0 or a negative FLASH_STORE_ERR_*. */
int32_t flash_store_save(const uint8_t *data, size_t len);

#endif /* NRF_FLASH_STORE_H */
