/* SHA-256, HMAC-SHA-256 and our authenticated beacon (SPEC 9). See pfdoa_auth.h. */
#include "pfdoa_auth.h"

#include <string.h>

#include "pfdoa_le.h"

/* FIPS 180-4 4.2.2: the first 32 bits of the fractional parts of the cube roots of the
 * first 64 primes. */
static const uint32_t sha256_k[64] = {
    0x428a2f98u, 0x71374491u, 0xb5c0fbcfu, 0xe9b5dba5u, 0x3956c25bu, 0x59f111f1u, 0x923f82a4u, 0xab1c5ed5u,
    0xd807aa98u, 0x12835b01u, 0x243185beu, 0x550c7dc3u, 0x72be5d74u, 0x80deb1feu, 0x9bdc06a7u, 0xc19bf174u,
    0xe49b69c1u, 0xefbe4786u, 0x0fc19dc6u, 0x240ca1ccu, 0x2de92c6fu, 0x4a7484aau, 0x5cb0a9dcu, 0x76f988dau,
    0x983e5152u, 0xa831c66du, 0xb00327c8u, 0xbf597fc7u, 0xc6e00bf3u, 0xd5a79147u, 0x06ca6351u, 0x14292967u,
    0x27b70a85u, 0x2e1b2138u, 0x4d2c6dfcu, 0x53380d13u, 0x650a7354u, 0x766a0abbu, 0x81c2c92eu, 0x92722c85u,
    0xa2bfe8a1u, 0xa81a664bu, 0xc24b8b70u, 0xc76c51a3u, 0xd192e819u, 0xd6990624u, 0xf40e3585u, 0x106aa070u,
    0x19a4c116u, 0x1e376c08u, 0x2748774cu, 0x34b0bcb5u, 0x391c0cb3u, 0x4ed8aa4au, 0x5b9cca4fu, 0x682e6ff3u,
    0x748f82eeu, 0x78a5636fu, 0x84c87814u, 0x8cc70208u, 0x90befffau, 0xa4506cebu, 0xbef9a3f7u, 0xc67178f2u,
};

/* FIPS 180-4 5.3.3: the first 32 bits of the fractional parts of the square roots of the
 * first 8 primes. */
static const uint32_t sha256_h0[8] = {
    0x6a09e667u, 0xbb67ae85u, 0x3c6ef372u, 0xa54ff53au, 0x510e527fu, 0x9b05688cu, 0x1f83d9abu, 0x5be0cd19u,
};

#define HMAC_IPAD 0x36u
#define HMAC_OPAD 0x5cu

static uint32_t rotr(const uint32_t x, const unsigned n)
{
    return (x >> n) | (x << (32u - n));
}

static uint32_t get_be32(const uint8_t *const p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | (uint32_t)p[3];
}

static void put_be32(uint8_t *const p, const uint32_t v)
{
    p[0] = (uint8_t)(v >> 24);
    p[1] = (uint8_t)((v >> 16) & 0xFFu);
    p[2] = (uint8_t)((v >> 8) & 0xFFu);
    p[3] = (uint8_t)(v & 0xFFu);
}

/* FIPS 180-4 6.2.2: one block, as 16 big-endian words, into the chaining value h. w is
 * the message schedule's 16-word ring (W[t] needs W[t-2], W[t-7], W[t-15], W[t-16] only)
 * and is consumed; the working variables are scalars. The anchor's paths build their
 * blocks as words, so verifying takes a few hundred bytes of stack. */
static void compress_w(uint32_t h[8], uint32_t w[16])
{
    uint32_t a = h[0];
    uint32_t b = h[1];
    uint32_t c = h[2];
    uint32_t d = h[3];
    uint32_t e = h[4];
    uint32_t f = h[5];
    uint32_t g = h[6];
    uint32_t hh = h[7];
    for (unsigned t = 0u; t < 64u; t++) {
        uint32_t wt;
        if (t < 16u) {
            wt = w[t];
        } else {
            const uint32_t w15 = w[(t - 15u) & 15u];
            const uint32_t w2 = w[(t - 2u) & 15u];
            const uint32_t s0 = rotr(w15, 7u) ^ rotr(w15, 18u) ^ (w15 >> 3);
            const uint32_t s1 = rotr(w2, 17u) ^ rotr(w2, 19u) ^ (w2 >> 10);
            wt = w[t & 15u] + s0 + w[(t - 7u) & 15u] + s1;
            w[t & 15u] = wt;
        }
        const uint32_t t1 = hh + (rotr(e, 6u) ^ rotr(e, 11u) ^ rotr(e, 25u)) + ((e & f) ^ (~e & g)) + sha256_k[t] + wt;
        const uint32_t t2 = (rotr(a, 2u) ^ rotr(a, 13u) ^ rotr(a, 22u)) + ((a & b) ^ (a & c) ^ (b & c));
        hh = g;
        g = f;
        f = e;
        e = d + t1;
        d = c;
        c = b;
        b = a;
        a = t1 + t2;
    }
    h[0] += a;
    h[1] += b;
    h[2] += c;
    h[3] += d;
    h[4] += e;
    h[5] += f;
    h[6] += g;
    h[7] += hh;
}

/* One block of bytes (the streaming SHA-256 and the general key schedule). */
static void compress(uint32_t h[8], const uint8_t block[PFDOA_SHA256_BLOCK])
{
    uint32_t w[16];
    for (unsigned t = 0u; t < 16u; t++) {
        w[t] = get_be32(&block[4u * t]);
    }
    compress_w(h, w);
}

/* The last block of a message of `total` bytes whose final n (< 56) bytes are tail: tail,
 * 0x80, zeros, the length in bits (FIPS 180-4 5.1.1), as words. */
static void last_words(uint32_t w[16], const uint8_t *const tail, const size_t n, const uint32_t total)
{
    (void)memset(w, 0, 16u * sizeof w[0]);
    for (size_t i = 0u; i <= n; i++) {
        const uint32_t byte = (i < n) ? tail[i] : 0x80u;
        w[i / 4u] |= byte << (24u - (8u * (unsigned)(i % 4u)));
    }
    w[14] = total >> 29;
    w[15] = total << 3;
}

/* A 16-byte key padded to a block and xored with a pad byte, as words. */
static void key_words(uint32_t w[16], const uint8_t key[PFDOA_AUTH_KEY_LEN], const uint8_t pad)
{
    const uint32_t p = (uint32_t)pad * 0x01010101u;
    for (unsigned i = 0u; i < 16u; i++) {
        w[i] = p ^ ((i < (PFDOA_AUTH_KEY_LEN / 4u)) ? get_be32(&key[4u * i]) : 0u);
    }
}

static void put_state(uint8_t *const out, const uint32_t h[8], const size_t n_bytes)
{
    for (size_t i = 0u; i < (n_bytes / 4u); i++) {
        put_be32(&out[4u * i], h[i]);
    }
}

/* The outer hash's last block: the inner digest (8 words), then padding; 64 + 32 bytes. */
static void digest_words(uint32_t w[16], const uint32_t digest[8])
{
    (void)memset(w, 0, 16u * sizeof w[0]);
    (void)memcpy(w, digest, 8u * sizeof w[0]);
    w[8] = 0x80000000u;
    w[15] = (PFDOA_SHA256_BLOCK + PFDOA_SHA256_LEN) * 8u;
}

/* HMAC from the key schedule for a message of at most 55 bytes (ours are 1 to 7): one
 * block each for the inner and the outer hash, in one frame (no SHA-256 context). */
static void hmac_short(const pfdoa_hmac_key_t *const k, const uint8_t *const msg, const size_t len,
                       uint8_t out[PFDOA_SHA256_LEN])
{
    uint32_t st[8];
    uint32_t w[16];
    (void)memcpy(st, k->inner, sizeof st);
    last_words(w, msg, len, (uint32_t)(PFDOA_SHA256_BLOCK + len));
    compress_w(st, w);
    digest_words(w, st);
    (void)memcpy(st, k->outer, sizeof st);
    compress_w(st, w);
    put_state(out, st, PFDOA_SHA256_LEN);
}

/* The key schedule from a key block already padded to 64 bytes (the block is consumed). */
static void schedule(pfdoa_hmac_key_t *const k, uint8_t block[PFDOA_SHA256_BLOCK])
{
    for (unsigned i = 0u; i < PFDOA_SHA256_BLOCK; i++) {
        block[i] ^= HMAC_IPAD;
    }
    (void)memcpy(k->inner, sha256_h0, sizeof k->inner);
    compress(k->inner, block);
    for (unsigned i = 0u; i < PFDOA_SHA256_BLOCK; i++) {
        block[i] ^= (uint8_t)(HMAC_IPAD ^ HMAC_OPAD);
    }
    (void)memcpy(k->outer, sha256_h0, sizeof k->outer);
    compress(k->outer, block);
    (void)memset(block, 0, PFDOA_SHA256_BLOCK);
}

/* The key schedule of a beacon key (16 bytes), built as words. */
static void schedule_key(pfdoa_hmac_key_t *const k, const uint8_t key[PFDOA_AUTH_KEY_LEN])
{
    uint32_t w[16];
    key_words(w, key, HMAC_IPAD);
    (void)memcpy(k->inner, sha256_h0, sizeof k->inner);
    compress_w(k->inner, w);
    key_words(w, key, HMAC_OPAD);
    (void)memcpy(k->outer, sha256_h0, sizeof k->outer);
    compress_w(k->outer, w);
}

void pfdoa_sha256_init(pfdoa_sha256_t *const s)
{
    if (s != NULL) {
        (void)memset(s, 0, sizeof *s);
        (void)memcpy(s->h, sha256_h0, sizeof s->h);
    }
}

void pfdoa_sha256_update(pfdoa_sha256_t *const s, const uint8_t *const data, const size_t len)
{
    if ((s == NULL) || (data == NULL)) {
        return;
    }
    for (size_t i = 0u; i < len; i++) {
        s->buf[s->used] = data[i];
        s->used++;
        if (s->used == PFDOA_SHA256_BLOCK) {
            compress(s->h, s->buf);
            s->used = 0u;
        }
    }
    s->total += (uint32_t)len;
}

void pfdoa_sha256_final(pfdoa_sha256_t *const s, uint8_t out[PFDOA_SHA256_LEN])
{
    if ((s == NULL) || (out == NULL)) {
        return;
    }
    /* FIPS 180-4 5.1.1: a 1 bit, zeros, the message length in bits as a big-endian u64. */
    const uint32_t bits_hi = s->total >> 29;
    const uint32_t bits_lo = s->total << 3;
    s->buf[s->used] = 0x80u;
    s->used++;
    if (s->used > (PFDOA_SHA256_BLOCK - 8u)) {
        (void)memset(&s->buf[s->used], 0, PFDOA_SHA256_BLOCK - s->used);
        compress(s->h, s->buf);
        s->used = 0u;
    }
    (void)memset(&s->buf[s->used], 0, PFDOA_SHA256_BLOCK - 8u - s->used);
    put_be32(&s->buf[PFDOA_SHA256_BLOCK - 8u], bits_hi);
    put_be32(&s->buf[PFDOA_SHA256_BLOCK - 4u], bits_lo);
    compress(s->h, s->buf);
    for (unsigned i = 0u; i < 8u; i++) {
        put_be32(&out[4u * i], s->h[i]);
    }
    (void)memset(s, 0, sizeof *s);
}

void pfdoa_sha256(const uint8_t *const data, const size_t len, uint8_t out[PFDOA_SHA256_LEN])
{
    pfdoa_sha256_t s;
    pfdoa_sha256_init(&s);
    pfdoa_sha256_update(&s, data, len);
    pfdoa_sha256_final(&s, out);
}

/* A SHA-256 that continues from a chaining value after one whole block. */
static void resume(pfdoa_sha256_t *const s, const uint32_t h[8])
{
    (void)memset(s, 0, sizeof *s);
    (void)memcpy(s->h, h, sizeof s->h);
    s->total = PFDOA_SHA256_BLOCK;
}

void pfdoa_hmac_init(pfdoa_hmac_key_t *const k, const uint8_t *const key, const size_t len)
{
    if ((k == NULL) || ((key == NULL) && (len > 0u))) {
        return;
    }
    /* RFC 2104 2: K padded with zeros to the block; a longer key is hashed first. */
    uint8_t block[PFDOA_SHA256_BLOCK] = {0};
    if (len > PFDOA_SHA256_BLOCK) {
        pfdoa_sha256(key, len, block);
    } else if (len > 0u) {
        (void)memcpy(block, key, len);
    } else {
        /* an empty key: all zeros */
    }
    schedule(k, block);
}

void pfdoa_hmac(const pfdoa_hmac_key_t *const k, const uint8_t *const msg, const size_t len,
                uint8_t out[PFDOA_SHA256_LEN])
{
    if ((k == NULL) || (out == NULL)) {
        return;
    }
    /* H((K ^ opad) || H((K ^ ipad) || msg)), each from its key block's chaining value. */
    pfdoa_sha256_t s;
    uint8_t inner[PFDOA_SHA256_LEN];
    resume(&s, k->inner);
    pfdoa_sha256_update(&s, msg, len);
    pfdoa_sha256_final(&s, inner);
    resume(&s, k->outer);
    pfdoa_sha256_update(&s, inner, sizeof inner);
    pfdoa_sha256_final(&s, out);
}

int pfdoa_auth_equal(const uint8_t *const a, const uint8_t *const b, const size_t n)
{
    if ((a == NULL) || (b == NULL)) {
        return 0;
    }
    uint8_t diff = 0u;
    for (size_t i = 0u; i < n; i++) {
        diff = (uint8_t)(diff | (a[i] ^ b[i]));
    }
    return diff == 0u;
}

void pfdoa_auth_derive(const pfdoa_hmac_key_t *const k, const uint32_t counter, pfdoa_auth_ids_t *const out)
{
    if ((k == NULL) || (out == NULL)) {
        return;
    }
    uint8_t msg[1u + 4u];
    uint8_t b[PFDOA_SHA256_LEN];
    msg[0] = PFDOA_AUTH_DOMAIN_IDS;
    pfdoa_put_u32(&msg[1], counter);
    hmac_short(k, msg, sizeof msg, b);
    size_t at = 0u;
    (void)memcpy(out->rid, &b[at], PFDOA_AUTH_RID_LEN);
    at += PFDOA_AUTH_RID_LEN;
    (void)memcpy(out->adv_a, &b[at], PFDOA_BLE_ADV_A_LEN);
    at += PFDOA_BLE_ADV_A_LEN;
    /* Core Spec Vol 6 Part B 1.3.2.2: a non-resolvable private address has its two most
     * significant bits 0b00 (the last byte on air) and 46 random bits not all 0 or all 1. */
    out->adv_a[5] &= 0x3Fu;
    uint8_t ones = out->adv_a[5] == 0x3Fu;
    uint8_t zeros = out->adv_a[5] == 0u;
    for (unsigned i = 0u; i < 5u; i++) {
        ones = (uint8_t)(ones & (out->adv_a[i] == 0xFFu));
        zeros = (uint8_t)(zeros & (out->adv_a[i] == 0u));
    }
    if ((ones | zeros) != 0u) {
        out->adv_a[0] ^= 0x01u;
    }
    (void)memcpy(out->ext_addr, &b[at], PFDOA_IEEE802154_EXT_ADDR_LEN);
    at += PFDOA_IEEE802154_EXT_ADDR_LEN;
    /* IEEE 802 EUI-64, most significant octet last on air: locally administered (U/L 1),
     * unicast (I/G 0). */
    out->ext_addr[7] = (uint8_t)((out->ext_addr[7] | 0x02u) & 0xFEu);
    out->pad = pfdoa_get_u16(&b[at]);
    (void)memset(b, 0, sizeof b);
}

void pfdoa_auth_tag(const pfdoa_hmac_key_t *const k, const uint32_t counter, const uint16_t seq,
                    uint8_t tag[PFDOA_AUTH_TAG_LEN])
{
    if ((k == NULL) || (tag == NULL)) {
        return;
    }
    uint8_t msg[1u + 4u + 2u];
    uint8_t b[PFDOA_SHA256_LEN];
    msg[0] = PFDOA_AUTH_DOMAIN_TAG;
    pfdoa_put_u32(&msg[1], counter);
    pfdoa_put_u16(&msg[5], seq);
    hmac_short(k, msg, sizeof msg, b);
    (void)memcpy(tag, b, PFDOA_AUTH_TAG_LEN);
}

void pfdoa_auth_key_check(const uint8_t key[PFDOA_AUTH_KEY_LEN], uint8_t out[PFDOA_AUTH_CHECK_LEN])
{
    if ((key == NULL) || (out == NULL)) {
        return;
    }
    /* HMAC(K, 0x00) block by block (the filter table's hash computes it inside the
     * FILTER_SET path): the outer key block first, then the inner hash, then the outer's
     * last block. */
    const uint8_t msg[1] = {PFDOA_AUTH_DOMAIN_CHECK};
    uint32_t outer[8];
    uint32_t inner[8];
    uint32_t w[16];
    key_words(w, key, HMAC_OPAD);
    (void)memcpy(outer, sha256_h0, sizeof outer);
    compress_w(outer, w);
    key_words(w, key, HMAC_IPAD);
    (void)memcpy(inner, sha256_h0, sizeof inner);
    compress_w(inner, w);
    last_words(w, msg, sizeof msg, (uint32_t)(PFDOA_SHA256_BLOCK + sizeof msg));
    compress_w(inner, w);
    digest_words(w, inner);
    compress_w(outer, w);
    put_state(out, outer, PFDOA_AUTH_CHECK_LEN);
    (void)memset(inner, 0, sizeof inner);
    (void)memset(outer, 0, sizeof outer);
}

void pfdoa_auth_payload(const pfdoa_hmac_key_t *const k, const pfdoa_auth_ids_t *const ids, const uint32_t counter,
                        const uint16_t seq, uint8_t out[PFDOA_AUTH_PAYLOAD_LEN])
{
    if ((k == NULL) || (ids == NULL) || (out == NULL)) {
        return;
    }
    out[0] = PFDOA_BEACON_MAGIC0;
    out[1] = PFDOA_AUTH_MAGIC1;
    pfdoa_put_u32(&out[2], counter);
    pfdoa_put_u16(&out[6], (uint16_t)(seq ^ ids->pad));
    (void)memcpy(&out[8], ids->rid, PFDOA_AUTH_RID_LEN);
    pfdoa_auth_tag(k, counter, seq, &out[8u + PFDOA_AUTH_RID_LEN]);
}

/* seq after last in serial-number arithmetic on u16 (SPEC 4 Loss detection). */
static int seq_newer(const uint16_t seq, const uint16_t last)
{
    const uint16_t d = (uint16_t)(seq - last);
    return (d != 0u) && (d < 0x8000u);
}

int32_t pfdoa_auth_window_check(pfdoa_auth_window_t *const w, const uint32_t counter, const uint16_t seq,
                                const uint32_t tick_ms)
{
    if (w == NULL) {
        return PFDOA_ERR_ARG;
    }
    if (w->have != 0u) {
        const uint32_t elapsed = (uint32_t)(tick_ms - w->tick);
        /* 64-bit sums: counters near 2^32 never wrap into a wrong verdict. */
        const uint64_t expected = (uint64_t)w->counter + (uint64_t)(elapsed >> PFDOA_AUTH_PERIOD_SHIFT);
        if (((uint64_t)counter + PFDOA_AUTH_WINDOW) < expected) {
            return PFDOA_AUTH_STALE;
        }
        if ((counter == w->counter) && (seq == w->seq)) {
            return (elapsed < PFDOA_EVENT_TIMEOUT_MS) ? PFDOA_AUTH_ACCEPT : PFDOA_AUTH_REPLAYED;
        }
        if ((counter < w->counter) || ((counter == w->counter) && (seq_newer(seq, w->seq) == 0))) {
            return PFDOA_AUTH_REPLAYED;
        }
    }
    w->have = 1u;
    w->counter = counter;
    w->seq = seq;
    w->tick = tick_ms;
    return PFDOA_AUTH_ACCEPT;
}

void pfdoa_auth_state_init(pfdoa_auth_state_t *const s, const uint8_t key[PFDOA_AUTH_KEY_LEN])
{
    if ((s == NULL) || (key == NULL)) {
        return;
    }
    (void)memset(s, 0, sizeof *s);
    schedule_key(&s->key, key);
}

int32_t pfdoa_auth_verify(pfdoa_auth_state_t *const s, const uint8_t payload[PFDOA_AUTH_PAYLOAD_LEN],
                          const uint32_t tick_ms, pfdoa_auth_verdict_t *const out)
{
    if ((s == NULL) || (payload == NULL) || (out == NULL) || (payload[0] != PFDOA_BEACON_MAGIC0) ||
        (payload[1] != PFDOA_AUTH_MAGIC1)) {
        return PFDOA_ERR_ARG;
    }
    const uint32_t counter = pfdoa_get_u32(&payload[2]);
    if ((s->cached == 0u) || (s->cache_counter != counter)) {
        /* One derivation per period for the beacon itself; a payload claiming another
         * counter costs one more (bounded by what the radio can receive). */
        pfdoa_auth_ids_t ids;
        pfdoa_auth_derive(&s->key, counter, &ids);
        (void)memcpy(s->cache_rid, ids.rid, PFDOA_AUTH_RID_LEN);
        s->cache_pad = ids.pad;
        s->cache_counter = counter;
        s->cached = 1u;
    }
    if (pfdoa_auth_equal(&payload[8], s->cache_rid, PFDOA_AUTH_RID_LEN) == 0) {
        return PFDOA_AUTH_NONE;
    }
    const uint16_t seq = (uint16_t)(pfdoa_get_u16(&payload[6]) ^ s->cache_pad);
    uint8_t tag[PFDOA_AUTH_TAG_LEN];
    pfdoa_auth_tag(&s->key, counter, seq, tag);
    out->counter = counter;
    out->seq = seq;
    (void)memcpy(out->tag, &payload[8u + PFDOA_AUTH_RID_LEN], PFDOA_AUTH_TAG_LEN);
    if (pfdoa_auth_equal(tag, out->tag, PFDOA_AUTH_TAG_LEN) == 0) {
        return PFDOA_AUTH_BAD_TAG;
    }
    return pfdoa_auth_window_check(&s->window, counter, seq, tick_ms);
}
