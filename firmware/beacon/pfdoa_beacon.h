/*
 * pfdoa_beacon.h - the beacon on the robot (protocol/SPEC.md section 6): one advertisement
 * every interval_ms with a 16-bit sequence number, over BLE and/or IEEE 802.15.4.
 *
 * Like the anchor core: one pfdoa_beacon_t the caller allocates, no global state, no heap,
 * no floating point, error codes from pfdoa_defs.h. The frame builders are pure functions
 * (byte-identical to the MicroPython beacon and pfdoa.protocol.beacons: the golden vectors
 * protocol/vectors/beacon.json "builds" check all three), so a board may also use them
 * without the instance.
 *
 * Layouts written from the specifications: the advertising PDU from the Bluetooth Core
 * Specification v5.3, Vol 6 Part B 2.3 (ADV_NONCONN_IND, 2.3.1.3), AD structures from
 * Vol 3 Part C 11 and the Core Specification Supplement Part A (Flags 1.3, manufacturer
 * specific data 1.4); the IEEE 802.15.4 data frame from IEEE 802.15.4-2015, 7.2 and 7.3.2.
 *
 * Our authenticated rolling beacon (SPEC 9; cfg.auth = 1 and cfg.auth_key): every advertisement
 * carries the period's rolling identifier, the sequence number hidden by the period's pad,
 * and a tag from the secret key; the BLE address and the 802.15.4 extended address change
 * with the period (pfdoa_auth.h derives them). It needs the time: pfdoa_beacon_set_time()
 * with the site's counter (floor(Unix time ms / 4096)); until then it sends nothing.
 *
 * Use:
 *     pfdoa_beacon_config_defaults(&cfg); cfg.beacon_id = 2; cfg.adv_a = ...;
 *     pfdoa_beacon_init(&b, &hal, &cfg);
 *     pfdoa_beacon_start(&b);              -> hal.timer_start(interval): call
 *                                            pfdoa_beacon_on_timer() from its expiry
 *     or, without a timer: for (;;) pfdoa_beacon_poll(&b, now_ms());
 */
#ifndef PFDOA_BEACON_H
#define PFDOA_BEACON_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_auth.h"
#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Radio bits of pfdoa_beacon_config_t.radios. */
#define PFDOA_BEACON_BLE      0x01u
#define PFDOA_BEACON_802154   0x02u

/* Sizes of what the builders write. AdvData: Flags AD (3) + manufacturer data AD (2 +
 * company id 2 + payload). PDU: header, AdvA, AdvData. MPDU: FCF (2), MAC seq (1), dst PAN
 * (2), dst short address (2), src extended address (8), payload; without the FCS, which
 * the radio appends. */
#define PFDOA_BEACON_ADV_DATA_LEN (3u + 4u + PFDOA_BEACON_PAYLOAD_LEN)
#define PFDOA_BEACON_PDU_LEN      (PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN + PFDOA_BEACON_ADV_DATA_LEN)
#define PFDOA_BEACON_MPDU_LEN                                                                                     \
    (PFDOA_IEEE802154_FCF_LEN + 1u + PFDOA_IEEE802154_PAN_ID_LEN + PFDOA_IEEE802154_SHORT_ADDR_LEN +                \
     PFDOA_IEEE802154_EXT_ADDR_LEN + PFDOA_BEACON_PAYLOAD_LEN)
/* Where the AdvData starts in the PDU, for boards whose BLE stack takes AdvData only. */
#define PFDOA_BEACON_ADV_DATA_OFFSET (PFDOA_BLE_PDU_HEADER_LEN + PFDOA_BLE_ADV_A_LEN)
/* The authenticated beacon's frames (SPEC 9.3): the 22-byte payload in place of ours. */
#define PFDOA_BEACON_AUTH_ADV_DATA_LEN (3u + 4u + PFDOA_AUTH_PAYLOAD_LEN)
#define PFDOA_BEACON_AUTH_PDU_LEN      (PFDOA_BEACON_ADV_DATA_OFFSET + PFDOA_BEACON_AUTH_ADV_DATA_LEN)
#define PFDOA_BEACON_AUTH_MPDU_LEN     (PFDOA_BEACON_MPDU_LEN - PFDOA_BEACON_PAYLOAD_LEN + PFDOA_AUTH_PAYLOAD_LEN)

typedef struct pfdoa_beacon_hal {
    void *ctx;
    /* Transmit one frame now at tx_power_dbm: radio PFDOA_RADIO_BLE gets an advertising PDU
     * (one advertising event: the board sends it on the advertising channels it uses),
     * PFDOA_RADIO_IEEE802154 a MAC frame without FCS. Negative on failure (counted). */
    int32_t (*radio_send)(void *ctx, uint8_t radio, int8_t tx_power_dbm, const uint8_t *frame, size_t len);
    /* Milliseconds, wrapping u32. The authenticated beacon reads it at each timer expiry
     * (required then); otherwise used by pfdoa_beacon_poll's callers only and may be NULL. */
    uint32_t (*tick_ms)(void *ctx);
    /* Start a periodic timer of period_ms whose expiry calls pfdoa_beacon_on_timer (from
     * the main loop or an interrupt that does not preempt other beacon calls). NULL: the
     * board polls. Negative on failure. */
    int32_t (*timer_start)(void *ctx, uint32_t period_ms);
} pfdoa_beacon_hal_t;

typedef struct pfdoa_beacon_config {
    uint8_t adv_a[PFDOA_BLE_ADV_A_LEN]; /* BLE AdvA, on-air order (a random static address) */
    uint8_t ext_addr[PFDOA_IEEE802154_EXT_ADDR_LEN]; /* IEEE 802.15.4 extended source address, on-air order */
    uint16_t interval_ms;               /* PFDOA_BEACON_INTERVAL_MS_MIN..MAX */
    uint16_t pan_id;                    /* IEEE 802.15.4 destination PAN */
    int8_t tx_power_dbm;                /* handed to radio_send */
    uint8_t beacon_id;                  /* tells several beacons apart (SPEC 3.1, 6); unused with auth */
    uint8_t radios;                     /* non-empty subset of PFDOA_BEACON_BLE | _802154 */
    uint8_t auth;                       /* 1: the authenticated rolling beacon (SPEC 9), 0: SPEC 6 */
    uint8_t auth_key[PFDOA_AUTH_KEY_LEN]; /* its secret key (adv_a and ext_addr are then derived) */
} pfdoa_beacon_config_t;

/* Opaque in spirit: use the functions below. */
typedef struct pfdoa_beacon {
    pfdoa_beacon_hal_t hal;
    pfdoa_beacon_config_t config;
    uint32_t next_tick;     /* when poll sends next (valid once polled) */
    uint32_t sent;          /* advertisements sent (each radio counts once); wraps */
    uint32_t send_failures; /* radio_send calls that failed; wraps */
    uint16_t seq;           /* sequence number of the next advertisement */
    uint8_t polled;         /* 0 until the first poll */
    /* The authenticated beacon (SPEC 9): key schedule, the counter and the tick its period
     * began, the identifiers of that period. */
    uint8_t time_set;       /* 0 until pfdoa_beacon_set_time */
    uint32_t counter;
    uint32_t period_tick;
    uint32_t ids_counter;   /* the period ids was derived for (valid once time_set) */
    uint8_t ids_valid;
    pfdoa_hmac_key_t key;
    pfdoa_auth_ids_t ids;
} pfdoa_beacon_t;

/* Defaults from messages.json: BLE only, interval and TX power defaults, PAN 0xFFFF,
 * beacon id 0, addresses zero (set them). NULL is ignored. */
void pfdoa_beacon_config_defaults(pfdoa_beacon_config_t *config);

/* PFDOA_OK or PFDOA_ERR_ARG (NULL, interval out of range, radios empty or unknown). */
int32_t pfdoa_beacon_config_validate(const pfdoa_beacon_config_t *config);

/* Initialises *beacon (seq 0). hal is copied; a NULL hal or radio_send is PFDOA_ERR_ARG, as
 * is an invalid config or an authenticated beacon without hal->tick_ms (instance untouched
 * on error). The key is kept as its HMAC key schedule only. */
int32_t pfdoa_beacon_init(pfdoa_beacon_t *beacon, const pfdoa_beacon_hal_t *hal, const pfdoa_beacon_config_t *config);

/* Starts the HAL's periodic timer at the configured interval. PFDOA_OK, PFDOA_ERR_ARG (NULL,
 * or a HAL without timer_start: poll instead), or the HAL's negative error. */
int32_t pfdoa_beacon_start(pfdoa_beacon_t *beacon);

/* Sends the advertisement with the current sequence number on each configured radio, then
 * advances it (wrapping). Returns the number of frames the radios accepted (0..2) or
 * PFDOA_ERR_ARG. An authenticated beacon whose time is not set sends nothing (0) and keeps
 * its sequence number. */
int32_t pfdoa_beacon_on_timer(pfdoa_beacon_t *beacon);

/* The authenticated beacon's clock (SPEC 9.1): at tick_ms the counter is `counter`, its
 * period having begun phase_ms ago (0..PFDOA_AUTH_PERIOD_MS-1). PFDOA_OK, or PFDOA_ERR_ARG
 * (NULL, phase out of range, not an authenticated beacon). Call it again to resynchronise. */
int32_t pfdoa_beacon_set_time(pfdoa_beacon_t *beacon, uint32_t counter, uint32_t phase_ms, uint32_t tick_ms);

/* The authenticated beacon's counter at tick_ms (its clock moved on; 0 before set_time). */
uint32_t pfdoa_beacon_counter(pfdoa_beacon_t *beacon, uint32_t tick_ms);

/* For boards without a timer: sends at the first call and then whenever interval_ms have
 * passed since the last send (wrap-safe; after a long stall it sends once and restarts the
 * interval from now, no burst). Returns 1 when it sent, 0 when not due, PFDOA_ERR_ARG. */
int32_t pfdoa_beacon_poll(pfdoa_beacon_t *beacon, uint32_t tick_ms);

/* Counters and the next sequence number (NULL gives 0). */
uint16_t pfdoa_beacon_seq(const pfdoa_beacon_t *beacon);
uint32_t pfdoa_beacon_sent(const pfdoa_beacon_t *beacon);
uint32_t pfdoa_beacon_send_failures(const pfdoa_beacon_t *beacon);

/*
 * The builders. Each writes its frame into out (cap bytes) and returns its length, or
 * PFDOA_ERR_ARG (NULL) / PFDOA_ERR_CAPACITY (cap too small; nothing written).
 *   adv_data: Flags (LE General Discoverable, BR/EDR not supported) + manufacturer data
 *             company 0xFFFF, 'P' 'F', seq (LE), beacon id;
 *   adv_pdu:  ADV_NONCONN_IND with TxAdd = random, AdvA, that AdvData;
 *   mpdu:     data frame, PAN ID Compression, frame version 0, to the broadcast short
 *             address on pan_id from ext_addr, MAC sequence number seq & 0xFF, payload
 *             'P' 'F' seq (LE) beacon id.
 */
int32_t pfdoa_beacon_adv_data(uint16_t seq, uint8_t beacon_id, uint8_t *out, size_t cap);
int32_t pfdoa_beacon_adv_pdu(const uint8_t adv_a[PFDOA_BLE_ADV_A_LEN], uint16_t seq, uint8_t beacon_id, uint8_t *out,
                             size_t cap);
int32_t pfdoa_beacon_mpdu(const uint8_t ext_addr[PFDOA_IEEE802154_EXT_ADDR_LEN], uint16_t pan_id, uint16_t seq, uint8_t beacon_id, uint8_t *out,
                          size_t cap);

/*
 * The authenticated beacon's builders (SPEC 9.3), same conventions; k is the key schedule,
 * ids what pfdoa_auth_derive(k, counter) gave:
 *   auth_adv_data: Flags + manufacturer data company 0xFFFF with the 22-byte payload;
 *   auth_adv_pdu:  ADV_NONCONN_IND from the period's private address ids->adv_a;
 *   auth_mpdu:     the 802.15.4 data frame from ids->ext_addr, MAC sequence number = the
 *                  low byte of the hidden seq (eseq), payload the 22 bytes.
 */
int32_t pfdoa_beacon_auth_adv_data(const pfdoa_hmac_key_t *k, const pfdoa_auth_ids_t *ids, uint32_t counter,
                                   uint16_t seq, uint8_t *out, size_t cap);
int32_t pfdoa_beacon_auth_adv_pdu(const pfdoa_hmac_key_t *k, const pfdoa_auth_ids_t *ids, uint32_t counter,
                                  uint16_t seq, uint8_t *out, size_t cap);
int32_t pfdoa_beacon_auth_mpdu(const pfdoa_hmac_key_t *k, const pfdoa_auth_ids_t *ids, uint32_t counter, uint16_t seq,
                               uint16_t pan_id, uint8_t *out, size_t cap);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_BEACON_H */
