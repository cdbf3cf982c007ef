/*
 * libFuzzer target: our authenticated beacon's parsers and verifier (SPEC 9, pfdoa_auth.h,
 * pfdoa_match_auth_*). Input: bytes 0..15 = a key; byte 16 = which parser (0 AdvData,
 * 1 advertising PDU, 2 IEEE 802.15.4 frame); the rest = a sequence of records
 * [tick delta u16 | kind u8 | length u8 | frame bytes], each frame exactly that long (ASan
 * sees a read past its end). Kind bit 0: the frame is the beacon's own advertisement for
 * (counter, seq) taken from its first 6 bytes (so valid payloads reach the window), else
 * the bytes as they are.
 *
 * Oracle, beyond no crash: a parser answers 0 or 1, and 1 points at 22 bytes inside the
 * frame starting 'P' 'A' (the PDU's answer is its AdvData's); the verifier answers one of
 * its five results; accept only with the tag an independent HMAC of the key gives for the
 * decrypted seq; the window's (counter, seq) never goes back; the beacon's own next
 * advertisement after every accepted one is accepted; SHA-256 of the input whole equals
 * it split at any point.
 */
#include <string.h>

#include "fuzz_common.h"
#include "pfdoa_auth.h"
#include "pfdoa_match.h"

#define KEY_LEN PFDOA_AUTH_KEY_LEN

static int32_t find(const int which, const uint8_t *f, const size_t n, const uint8_t **p)
{
    if (which == 0) {
        return pfdoa_match_auth_ble_adv(f, n, p);
    }
    if (which == 1) {
        return pfdoa_match_auth_ble_pdu(f, n, p);
    }
    return pfdoa_match_auth_802154(f, n, p);
}

/* The beacon's frame for (counter, seq) in the chosen format: AdvData, or a PDU / MPDU
 * written here from SPEC 9.3 (so the check does not lean on the beacon's builders). */
static size_t own_frame(const int which, const pfdoa_hmac_key_t *k, const uint32_t counter, const uint16_t seq,
                        uint8_t out[64])
{
    pfdoa_auth_ids_t ids;
    pfdoa_auth_derive(k, counter, &ids);
    uint8_t payload[PFDOA_AUTH_PAYLOAD_LEN];
    pfdoa_auth_payload(k, &ids, counter, seq, payload);
    static const uint8_t adv_head[7] = {2u, 1u, 6u, 25u, 0xFFu, 0xFFu, 0xFFu};
    static const uint8_t mac_head[7] = {0x41u, 0xC8u, 0u, 0xFFu, 0xFFu, 0xFFu, 0xFFu};
    size_t at = 0u;
    if (which == 1) {
        out[0] = 0x42u; /* ADV_NONCONN_IND, TxAdd */
        out[1] = 6u + 29u;
        memcpy(&out[2], ids.adv_a, 6u);
        at = 8u;
    }
    if (which == 2) {
        memcpy(out, mac_head, sizeof mac_head);
        out[2] = payload[6];
        memcpy(&out[7], ids.ext_addr, 8u);
        at = 15u;
    } else {
        memcpy(&out[at], adv_head, sizeof adv_head);
        at += sizeof adv_head;
    }
    memcpy(&out[at], payload, sizeof payload);
    return at + sizeof payload;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < KEY_LEN + 1u) {
        return 0;
    }
    pfdoa_auth_state_t s;
    pfdoa_auth_state_init(&s, data);
    pfdoa_hmac_key_t k;
    pfdoa_hmac_init(&k, data, KEY_LEN);
    const int which = data[KEY_LEN] % 3;
    uint32_t tick = 0u;

    /* SHA-256 split anywhere equals it whole. */
    uint8_t whole[PFDOA_SHA256_LEN];
    uint8_t parts[PFDOA_SHA256_LEN];
    pfdoa_sha256(data, size, whole);
    pfdoa_sha256_t sh;
    pfdoa_sha256_init(&sh);
    pfdoa_sha256_update(&sh, data, size / 3u);
    pfdoa_sha256_update(&sh, &data[size / 3u], size - size / 3u);
    pfdoa_sha256_final(&sh, parts);
    CHECK(memcmp(whole, parts, sizeof whole) == 0);

    size_t i = KEY_LEN + 1u;
    while (i + 4u <= size) {
        tick += (uint32_t)data[i] | ((uint32_t)data[i + 1u] << 8);
        const uint8_t kind = data[i + 2u];
        size_t n = data[i + 3u];
        i += 4u;
        if (n > size - i) {
            n = size - i;
        }
        uint8_t own[64];
        const uint8_t *frame = &data[i];
        uint8_t *copy = NULL;
        if (((kind & 1u) != 0u) && (n >= 6u)) {
            const uint32_t counter = (uint32_t)frame[0] | ((uint32_t)frame[1] << 8) | ((uint32_t)frame[2] << 16) |
                                     ((uint32_t)frame[3] << 24);
            const uint16_t seq = (uint16_t)(frame[4] | (frame[5] << 8));
            n = own_frame(which, &k, counter, seq, own);
            frame = own;
        } else {
            copy = (uint8_t *)malloc(n > 0u ? n : 1u); /* exactly n bytes: ASan sees overreads */
            CHECK(copy != NULL);
            memcpy(copy, frame, n);
            frame = copy;
        }
        i += (frame == own) ? 6u : n;
        const uint8_t *p = NULL;
        const int32_t rc = find(which, frame, n, &p);
        CHECK((rc == 0) || (rc == 1));
        if (rc == 1) {
            CHECK((p >= frame) && ((size_t)(p - frame) + PFDOA_AUTH_PAYLOAD_LEN <= n));
            CHECK((p[0] == PFDOA_BEACON_MAGIC0) && (p[1] == PFDOA_AUTH_MAGIC1));
            if (which == 1) {
                const uint8_t *q = NULL;
                CHECK(pfdoa_match_auth_ble_adv(&frame[8], (size_t)frame[1] - 6u, &q) == 1);
                CHECK(q == p);
            }
            const pfdoa_auth_window_t before = s.window;
            pfdoa_auth_verdict_t v;
            const int32_t res = pfdoa_auth_verify(&s, p, tick, &v);
            CHECK((res >= PFDOA_AUTH_NONE) && (res <= PFDOA_AUTH_REPLAYED));
            if (res == PFDOA_AUTH_ACCEPT) {
                uint8_t tag[PFDOA_AUTH_TAG_LEN];
                pfdoa_auth_tag(&k, v.counter, v.seq, tag);
                CHECK(memcmp(tag, v.tag, sizeof tag) == 0);
                CHECK(s.window.have == 1u);
                if (before.have != 0u) {
                    CHECK((s.window.counter > before.counter) ||
                          ((s.window.counter == before.counter) &&
                           ((s.window.seq == before.seq) || ((uint16_t)(s.window.seq - before.seq) < 0x8000u))));
                }
                /* The beacon's next advertisement is accepted. */
                uint8_t next[64];
                const uint16_t seq1 = (uint16_t)(v.seq + 1u);
                const size_t m = own_frame(which, &k, v.counter, seq1, next);
                const uint8_t *q = NULL;
                CHECK(find(which, next, m, &q) == 1);
                pfdoa_auth_verdict_t v1;
                CHECK(pfdoa_auth_verify(&s, q, tick, &v1) == PFDOA_AUTH_ACCEPT);
                CHECK((v1.seq == seq1) && (v1.counter == v.counter));
            } else {
                CHECK((before.have == s.window.have) && (before.counter == s.window.counter) &&
                      (before.seq == s.window.seq) && (before.tick == s.window.tick));
            }
        } else {
            CHECK(p == NULL);
        }
        free(copy);
    }
    return 0;
}
