/* The authenticated beacon's module (SPEC 9, pfdoa_auth.h): SHA-256 and HMAC-SHA-256
 * against FIPS 180-4 / RFC 4231 (protocol/vectors/auth.json), derivation, tags, payloads,
 * the verifier's counter window, and the arguments. */
#include "test_support.h"

#include "pfdoa_auth.h"
#include "vectors.h"

static void test_sha256_vectors_whole_and_in_pieces(void **state)
{
    (void)state;
    static uint8_t data[512];
    for (size_t i = 0u; i < VEC_SHA256_COUNT; i++) {
        const vec_sha256_t *const v = &vec_sha256[i];
        const size_t n = hex_to_bytes(v->data, data, sizeof data);
        uint8_t want[PFDOA_SHA256_LEN];
        uint8_t got[PFDOA_SHA256_LEN];
        (void)hex_to_bytes(v->digest, want, sizeof want);
        pfdoa_sha256_t s;
        pfdoa_sha256_init(&s);
        for (uint32_t r = 0u; r < v->repeat; r++) {
            pfdoa_sha256_update(&s, data, n);
        }
        pfdoa_sha256_final(&s, got);
        assert_memory_equal(got, want, sizeof want);
        if (v->repeat == 1u) {
            pfdoa_sha256(data, n, got);
            assert_memory_equal(got, want, sizeof want);
            /* Split at every byte: the partial block carries over. */
            for (size_t cut = 0u; cut <= n; cut++) {
                pfdoa_sha256_init(&s);
                pfdoa_sha256_update(&s, data, cut);
                pfdoa_sha256_update(&s, &data[cut], n - cut);
                pfdoa_sha256_final(&s, got);
                assert_memory_equal(got, want, sizeof want);
            }
        }
    }
    assert_true(VEC_SHA256_COUNT >= 10u);
}

static void test_hmac_vectors(void **state)
{
    (void)state;
    for (size_t i = 0u; i < VEC_HMAC_COUNT; i++) {
        const vec_hmac_t *const v = &vec_hmac[i];
        uint8_t key[160];
        uint8_t data[200];
        uint8_t want[PFDOA_SHA256_LEN];
        uint8_t got[PFDOA_SHA256_LEN];
        const size_t kn = hex_to_bytes(v->key, key, sizeof key);
        const size_t dn = hex_to_bytes(v->data, data, sizeof data);
        (void)hex_to_bytes(v->mac, want, sizeof want);
        pfdoa_hmac_key_t k;
        pfdoa_hmac_init(&k, kn > 0u ? key : NULL, kn);
        pfdoa_hmac(&k, dn > 0u ? data : NULL, dn, got);
        assert_memory_equal(got, want, sizeof want);
    }
    assert_true(VEC_HMAC_COUNT >= 6u);
}

static void test_derive_and_key_check_vectors(void **state)
{
    (void)state;
    for (size_t i = 0u; i < VEC_AUTH_DERIVE_COUNT; i++) {
        const vec_auth_derive_t *const v = &vec_auth_derive[i];
        uint8_t key[PFDOA_AUTH_KEY_LEN];
        uint8_t want[PFDOA_AUTH_CHECK_LEN];
        uint8_t got[PFDOA_AUTH_CHECK_LEN];
        (void)hex_to_bytes(v->key, key, sizeof key);
        pfdoa_hmac_key_t k;
        pfdoa_hmac_init(&k, key, sizeof key);
        pfdoa_auth_ids_t ids;
        pfdoa_auth_derive(&k, v->counter, &ids);
        (void)hex_to_bytes(v->rid, want, PFDOA_AUTH_RID_LEN);
        assert_memory_equal(ids.rid, want, PFDOA_AUTH_RID_LEN);
        (void)hex_to_bytes(v->adv_a, want, PFDOA_BLE_ADV_A_LEN);
        assert_memory_equal(ids.adv_a, want, PFDOA_BLE_ADV_A_LEN);
        assert_int_equal(ids.adv_a[5] & 0xC0u, 0u); /* non-resolvable private address */
        (void)hex_to_bytes(v->ext_addr, want, PFDOA_IEEE802154_EXT_ADDR_LEN);
        assert_memory_equal(ids.ext_addr, want, PFDOA_IEEE802154_EXT_ADDR_LEN);
        assert_int_equal(ids.ext_addr[7] & 0x03u, 0x02u); /* locally administered unicast */
        assert_int_equal(ids.pad, v->pad);
        (void)hex_to_bytes(v->key_check, want, sizeof want);
        pfdoa_auth_key_check(key, got);
        assert_memory_equal(got, want, sizeof want);
    }
}

static void test_tag_and_payload_vectors(void **state)
{
    (void)state;
    for (size_t i = 0u; i < VEC_AUTH_BUILD_COUNT; i++) {
        const vec_auth_build_t *const v = &vec_auth_build[i];
        uint8_t key[PFDOA_AUTH_KEY_LEN];
        uint8_t want[PFDOA_AUTH_PAYLOAD_LEN];
        uint8_t got[PFDOA_AUTH_PAYLOAD_LEN];
        (void)hex_to_bytes(v->key, key, sizeof key);
        pfdoa_hmac_key_t k;
        pfdoa_hmac_init(&k, key, sizeof key);
        pfdoa_auth_tag(&k, v->counter, v->seq, got);
        (void)hex_to_bytes(v->tag, want, PFDOA_AUTH_TAG_LEN);
        assert_memory_equal(got, want, PFDOA_AUTH_TAG_LEN);
        pfdoa_auth_ids_t ids;
        pfdoa_auth_derive(&k, v->counter, &ids);
        pfdoa_auth_payload(&k, &ids, v->counter, v->seq, got);
        assert_int_equal(hex_to_bytes(v->payload, want, sizeof want), sizeof want);
        assert_memory_equal(got, want, sizeof want);
    }
}

static void test_verifier_window_steps(void **state)
{
    (void)state;
    for (size_t i = 0u; i < VEC_AUTH_VERIFY_COUNT; i++) {
        const vec_auth_verify_t *const v = &vec_auth_verify[i];
        uint8_t key[PFDOA_AUTH_KEY_LEN];
        (void)hex_to_bytes(v->key, key, sizeof key);
        pfdoa_auth_state_t s;
        pfdoa_auth_state_init(&s, key);
        for (size_t k = 0u; k < v->n_steps; k++) {
            const vec_auth_step_t *const st = &v->steps[k];
            uint8_t p[PFDOA_AUTH_PAYLOAD_LEN];
            (void)hex_to_bytes(st->payload, p, sizeof p);
            pfdoa_auth_verdict_t out;
            const int32_t res = pfdoa_auth_verify(&s, p, st->tick, &out);
            if (res != st->result) {
                fail_msg("%s step %u: result %d, want %d", v->name, (unsigned)k, (int)res, (int)st->result);
            }
            if (res != PFDOA_AUTH_NONE) {
                assert_int_equal(out.seq, st->seq);
                assert_int_equal(out.counter, st->counter);
            }
        }
    }
    assert_true(VEC_AUTH_VERIFY_COUNT >= 1u);
}

static void test_equal_is_exact_at_every_byte(void **state)
{
    (void)state;
    uint8_t a[PFDOA_AUTH_TAG_LEN] = {1, 2, 3, 4, 5, 6, 7, 8};
    uint8_t b[PFDOA_AUTH_TAG_LEN];
    (void)memcpy(b, a, sizeof b);
    assert_int_equal(pfdoa_auth_equal(a, b, sizeof a), 1);
    for (size_t i = 0u; i < sizeof a; i++) {
        for (unsigned bit = 0u; bit < 8u; bit++) {
            b[i] ^= (uint8_t)(1u << bit);
            assert_int_equal(pfdoa_auth_equal(a, b, sizeof a), 0);
            b[i] ^= (uint8_t)(1u << bit);
        }
    }
    assert_int_equal(pfdoa_auth_equal(a, b, 0u), 1);
    assert_int_equal(pfdoa_auth_equal(NULL, b, 1u), 0);
}

static void test_window_rules(void **state)
{
    (void)state;
    pfdoa_auth_window_t w;
    (void)memset(&w, 0, sizeof w);
    assert_int_equal(pfdoa_auth_window_check(NULL, 1u, 1u, 0u), PFDOA_ERR_ARG);
    /* The first verified advertisement is accepted whatever its counter (the anchor has no
     * time of its own); a later, older one only within the window and when newer. */
    assert_int_equal(pfdoa_auth_window_check(&w, 100u, 5u, 1000u), PFDOA_AUTH_ACCEPT);
    assert_int_equal(pfdoa_auth_window_check(&w, 100u, 5u, 1000u + PFDOA_EVENT_TIMEOUT_MS - 1u), PFDOA_AUTH_ACCEPT);
    assert_int_equal(pfdoa_auth_window_check(&w, 100u, 5u, 1000u + PFDOA_EVENT_TIMEOUT_MS), PFDOA_AUTH_REPLAYED);
    assert_int_equal(pfdoa_auth_window_check(&w, 98u, 6u, 1100u), PFDOA_AUTH_REPLAYED);
    assert_int_equal(pfdoa_auth_window_check(&w, 97u, 6u, 1100u), PFDOA_AUTH_STALE);
    /* Counters near 2^32 do not wrap into acceptance. */
    assert_int_equal(pfdoa_auth_window_check(&w, 0xFFFFFFFFu, 0u, 1200u), PFDOA_AUTH_ACCEPT);
    assert_int_equal(pfdoa_auth_window_check(&w, 0u, 1u, 1300u), PFDOA_AUTH_STALE);
    assert_int_equal(w.counter, 0xFFFFFFFFu);
}

static void test_arguments_and_wiping(void **state)
{
    (void)state;
    uint8_t key[PFDOA_AUTH_KEY_LEN] = {0};
    uint8_t p[PFDOA_AUTH_PAYLOAD_LEN] = {0};
    pfdoa_auth_state_t s;
    pfdoa_auth_verdict_t out;
    pfdoa_auth_state_init(&s, key);
    assert_int_equal(pfdoa_auth_verify(NULL, p, 0u, &out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_auth_verify(&s, NULL, 0u, &out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_auth_verify(&s, p, 0u, NULL), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_auth_verify(&s, p, 0u, &out), PFDOA_ERR_ARG); /* no 'P' 'A' */
    p[0] = PFDOA_BEACON_MAGIC0;
    p[1] = PFDOA_AUTH_MAGIC1;
    assert_int_equal(pfdoa_auth_verify(&s, p, 0u, &out), PFDOA_AUTH_NONE); /* zero rid: not this key's */
    /* NULL outputs are ignored, not written. */
    pfdoa_sha256(NULL, 0u, NULL);
    pfdoa_hmac(NULL, p, 1u, NULL);
    pfdoa_auth_derive(NULL, 0u, NULL);
    pfdoa_auth_tag(NULL, 0u, 0u, NULL);
    pfdoa_auth_key_check(NULL, NULL);
    pfdoa_auth_payload(NULL, NULL, 0u, 0u, NULL);
    pfdoa_auth_state_init(NULL, key);
    /* final() leaves no message bytes behind. */
    pfdoa_sha256_t sh;
    uint8_t d[PFDOA_SHA256_LEN];
    pfdoa_sha256_init(&sh);
    pfdoa_sha256_update(&sh, (const uint8_t *)"secret", 6u);
    pfdoa_sha256_final(&sh, d);
    const uint8_t zero[sizeof sh.buf] = {0};
    assert_memory_equal(sh.buf, zero, sizeof zero);
    assert_int_equal(sh.total, 0u);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sha256_vectors_whole_and_in_pieces),
        cmocka_unit_test(test_hmac_vectors),
        cmocka_unit_test(test_derive_and_key_check_vectors),
        cmocka_unit_test(test_tag_and_payload_vectors),
        cmocka_unit_test(test_verifier_window_steps),
        cmocka_unit_test(test_equal_is_exact_at_every_byte),
        cmocka_unit_test(test_window_rules),
        cmocka_unit_test(test_arguments_and_wiping),
    };
    return cmocka_run_group_tests_name("auth", tests, NULL, NULL);
}
