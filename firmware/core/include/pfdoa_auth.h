/*
 * pfdoa_auth.h - our authenticated rolling beacon (protocol/SPEC.md section 9): SHA-256
 * (FIPS 180-4), HMAC-SHA-256 (RFC 2104), what a beacon's key derives for a period (its
 * rolling identifier, BLE private address, IEEE 802.15.4 extended address, sequence pad),
 * an advertisement's tag, the payload, and the counter window a verifier keeps.
 *
 * Written from the standards, integer only, no heap, no global state: every function
 * works on caller-owned memory. The key schedule (pfdoa_hmac_key_t) holds the two SHA-256
 * states after the key's inner and outer pad blocks, so one HMAC of a short message costs
 * two compression rounds instead of four. Tags are compared in constant time
 * (pfdoa_auth_equal).
 *
 * Byte-identical to the Python reference (pfdoa.protocol.auth) and the MicroPython module
 * (pfdoa_auth.py): golden vectors protocol/vectors/auth.json, and tests/firmware/test_auth_diff.py
 * over 10,000 random keys and counters.
 *
 * A beacon: pfdoa_hmac_init(&k, key, 16); pfdoa_auth_derive(&k, counter, &ids) once a
 *           period; pfdoa_auth_payload(&k, &ids, counter, seq, payload) per advertisement.
 * A verifier: pfdoa_auth_state_init(&s, key); pfdoa_auth_verify(&s, payload, tick, &v)
 *           per received payload (pfdoa_match_auth_* find it in a reception).
 */
#ifndef PFDOA_AUTH_H
#define PFDOA_AUTH_H

#include <stddef.h>
#include <stdint.h>

#include "pfdoa_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

#define PFDOA_SHA256_LEN   32u
#define PFDOA_SHA256_BLOCK 64u

/* An incremental SHA-256. Messages up to 2^32 - 1 bytes (ours are a few bytes). */
typedef struct pfdoa_sha256 {
    uint32_t h[8];
    uint32_t total;                  /* bytes hashed so far */
    uint8_t buf[PFDOA_SHA256_BLOCK]; /* the partial block */
    uint8_t used;                    /* bytes in buf */
} pfdoa_sha256_t;

void pfdoa_sha256_init(pfdoa_sha256_t *s);
/* data may be NULL when len is 0. */
void pfdoa_sha256_update(pfdoa_sha256_t *s, const uint8_t *data, size_t len);
/* Pads, writes the digest, and leaves *s wiped (no message bytes stay behind). */
void pfdoa_sha256_final(pfdoa_sha256_t *s, uint8_t out[PFDOA_SHA256_LEN]);
void pfdoa_sha256(const uint8_t *data, size_t len, uint8_t out[PFDOA_SHA256_LEN]);

/* An HMAC-SHA-256 key schedule: the chaining values after (K ^ ipad) and (K ^ opad). */
typedef struct pfdoa_hmac_key {
    uint32_t inner[8];
    uint32_t outer[8];
} pfdoa_hmac_key_t;

/* Any key length (longer than a block: hashed first, RFC 2104). key may be NULL if len is 0. */
void pfdoa_hmac_init(pfdoa_hmac_key_t *k, const uint8_t *key, size_t len);
void pfdoa_hmac(const pfdoa_hmac_key_t *k, const uint8_t *msg, size_t len, uint8_t out[PFDOA_SHA256_LEN]);

/* What period `counter` shows of a beacon (SPEC 9.2), addresses in on-air order. */
typedef struct pfdoa_auth_ids {
    uint8_t rid[PFDOA_AUTH_RID_LEN];                  /* rolling identifier */
    uint8_t adv_a[PFDOA_BLE_ADV_A_LEN];               /* non-resolvable private address */
    uint8_t ext_addr[PFDOA_IEEE802154_EXT_ADDR_LEN];  /* locally administered EUI-64 */
    uint16_t pad;                                     /* eseq = seq ^ pad */
} pfdoa_auth_ids_t;

void pfdoa_auth_derive(const pfdoa_hmac_key_t *k, uint32_t counter, pfdoa_auth_ids_t *out);
void pfdoa_auth_tag(const pfdoa_hmac_key_t *k, uint32_t counter, uint16_t seq, uint8_t tag[PFDOA_AUTH_TAG_LEN]);
/* The key check value (SPEC 9.2): hashed into filter_hash in place of the key. */
void pfdoa_auth_key_check(const uint8_t key[PFDOA_AUTH_KEY_LEN], uint8_t out[PFDOA_AUTH_CHECK_LEN]);
/* The 22-byte payload: 'P' 'A' counter(LE32) eseq(LE16) rid tag. ids: derive(k, counter). */
void pfdoa_auth_payload(const pfdoa_hmac_key_t *k, const pfdoa_auth_ids_t *ids, uint32_t counter, uint16_t seq,
                        uint8_t out[PFDOA_AUTH_PAYLOAD_LEN]);
/* 1 when a[0..n) == b[0..n), else 0, in time that depends on n only. */
int pfdoa_auth_equal(const uint8_t *a, const uint8_t *b, size_t n);

/* A verifier's state for one beacon (SPEC 9.4): the last accepted counter and sequence
 * number and the tick of their first acceptance. */
typedef struct pfdoa_auth_window {
    uint32_t counter;
    uint32_t tick;
    uint16_t seq;
    uint8_t have;
} pfdoa_auth_window_t;

/* The verdict for an advertisement whose tag verified, at tick_ms: PFDOA_AUTH_ACCEPT (the
 * state moves on when it is newer; the last accepted one is accepted again for
 * PFDOA_EVENT_TIMEOUT_MS: the same advertising event on another channel),
 * PFDOA_AUTH_STALE or PFDOA_AUTH_REPLAYED. */
int32_t pfdoa_auth_window_check(pfdoa_auth_window_t *w, uint32_t counter, uint16_t seq, uint32_t tick_ms);

/* One PFDOA_AUTH filter entry's key and state, with the last period's identifiers cached. */
typedef struct pfdoa_auth_state {
    pfdoa_hmac_key_t key;
    pfdoa_auth_window_t window;
    uint32_t cache_counter;
    uint16_t cache_pad;
    uint8_t cache_rid[PFDOA_AUTH_RID_LEN];
    uint8_t cached;
} pfdoa_auth_state_t;

/* What a verified payload said. */
typedef struct pfdoa_auth_verdict {
    uint32_t counter;
    uint16_t seq;                       /* decrypted */
    uint8_t tag[PFDOA_AUTH_TAG_LEN];
} pfdoa_auth_verdict_t;

void pfdoa_auth_state_init(pfdoa_auth_state_t *s, const uint8_t key[PFDOA_AUTH_KEY_LEN]);

/*
 * A received 22-byte payload against one beacon's state at tick_ms (SPEC 9.4):
 * PFDOA_AUTH_NONE when it does not carry this beacon's rolling identifier for its counter,
 * else PFDOA_AUTH_BAD_TAG, or the window's verdict (PFDOA_AUTH_ACCEPT, _STALE,
 * _REPLAYED) with *out filled. PFDOA_ERR_ARG for NULL arguments or a payload without
 * the 'P' 'A' magic.
 */
int32_t pfdoa_auth_verify(pfdoa_auth_state_t *s, const uint8_t payload[PFDOA_AUTH_PAYLOAD_LEN], uint32_t tick_ms,
                          pfdoa_auth_verdict_t *out);

#ifdef __cplusplus
}
#endif

#endif /* PFDOA_AUTH_H */
