/* SPEC section 3 arithmetic: floor division, fold, EMA, spikes, saturation, calibration. */
#include "pfdoa_filter.h"
#include "test_support.h"

static pfdoa_config_t cfg_with(const int16_t offset, const uint16_t alpha, const uint8_t spike)
{
    pfdoa_config_t c;
    pfdoa_config_defaults(&c);
    c.offset_q8 = offset;
    c.alpha_q8 = alpha;
    c.spike_db = spike;
    return c;
}

/* One single-reading BLE event through the filter. */
static int32_t feed(pfdoa_filter_t *const f, const pfdoa_config_t *const c, const int8_t dbm,
                    pfdoa_rssi_report_t *const out)
{
    pfdoa_event_t ev;
    const pfdoa_radio_reading_t r = {100u, 1u, dbm, 37u, 0u, PFDOA_RADIO_BLE};
    pfdoa_event_open(&ev, &r);
    return pfdoa_filter_close_event(f, c, &ev, 100u, out);
}

static void test_floor_div_negative_ties(void **state)
{
    (void)state;
    assert_int_equal(pfdoa_floor_div(7, 2), 3);
    assert_int_equal(pfdoa_floor_div(-7, 2), -4); /* C '/' gives -3 */
    assert_int_equal(pfdoa_floor_div(-6, 2), -3);
    assert_int_equal(pfdoa_floor_div(-1, 256), -1);
    assert_int_equal(pfdoa_floor_div(0, 5), 0);
    assert_int_equal(pfdoa_floor_div(-256, 256), -1);
    assert_int_equal(pfdoa_floor_div(-257, 256), -2);
    assert_int_equal(pfdoa_floor_div(5, 0), 0);
    /* Exhaustive check against the definition q*b <= a < (q+1)*b. */
    for (int32_t a = -3000; a <= 3000; a++) {
        for (int32_t b = 1; b <= 7; b++) {
            const int32_t q = pfdoa_floor_div(a, b);
            assert_true((q * b <= a) && (a < (q + 1) * b));
        }
    }
}

static void test_fold_round_half_up(void **state)
{
    (void)state;
    /* mean of -60, -61 = -60.5 dB = -15488/256 exactly */
    assert_int_equal(pfdoa_fold_mean_q8(-121, 2), -15488);
    /* -1/3 dB = -85.33/256 -> -85; -2/3 = -170.67 -> -171; ties go up: -0.5/256 never occurs
     * with n <= 3, but (512*sum + n) / 2n is the half-up rule for any n. */
    assert_int_equal(pfdoa_fold_mean_q8(-1, 3), -85);
    assert_int_equal(pfdoa_fold_mean_q8(-2, 3), -171);
    assert_int_equal(pfdoa_fold_mean_q8(1, 3), 85);
    assert_int_equal(pfdoa_fold_mean_q8(2, 3), 171);
    assert_int_equal(pfdoa_fold_mean_q8(-384, 3), -32768);
    assert_int_equal(pfdoa_fold_mean_q8(60, 3), 5120);
    assert_int_equal(pfdoa_fold_mean_q8(5, 0), 0);
    /* Exhaustive: |256*sum/n - mean| <= 1/2, ties upward. */
    for (uint8_t n = 1u; n <= 3u; n++) {
        for (int32_t sum = -128 * (int32_t)n; sum <= 20 * (int32_t)n; sum++) {
            const int32_t m = pfdoa_fold_mean_q8(sum, n);
            const int32_t twice_err = (2 * m * (int32_t)n) - (512 * sum); /* 2n(m - 256 sum / n) */
            assert_true((twice_err > -(int32_t)n - 1) && (twice_err <= (int32_t)n));
        }
    }
}

static void test_ema_negative_tie_rounding(void **state)
{
    (void)state;
    /* Increment alpha*diff/256 = -0.5 (1/256 units) rounds half up to 0; -1.5 to -1. */
    assert_int_equal(pfdoa_ema_step_q8(0, -128, 1), 0);
    assert_int_equal(pfdoa_ema_step_q8(0, -128, 3), -1);
    assert_int_equal(pfdoa_ema_step_q8(0, 128, 1), 1);   /* +0.5 -> +1 */
    assert_int_equal(pfdoa_ema_step_q8(0, -384, 1), -1); /* -1.5 -> -1 */
    /* alpha 256 follows the mean exactly. */
    assert_int_equal(pfdoa_ema_step_q8(-15360, 5120, 256), 5120);
    assert_int_equal(pfdoa_ema_step_q8(5120, -32768, 256), -32768);
}

static void test_first_event_resets_then_ema(void **state)
{
    (void)state;
    pfdoa_filter_t f;
    pfdoa_filter_init(&f);
    const pfdoa_config_t c = cfg_with(0, 64, 12);
    pfdoa_rssi_report_t out;
    assert_int_equal(feed(&f, &c, -60, &out), 0);
    assert_int_equal(out.flags, PFDOA_FLAG_RESET);
    assert_int_equal(out.rssi_q8, -60 * 256);
    assert_int_equal(feed(&f, &c, -64, &out), 0);
    /* -15360 + floor((64 * -1024 + 128) / 256) = -15360 - 256 */
    assert_int_equal(out.rssi_q8, -15616);
    assert_int_equal(out.flags, 0);
    assert_int_equal(out.n_readings, 1);
    assert_int_equal(out.raw_dbm, -64);
    assert_int_equal(out.channel, 37);
}

static void test_spike_and_reinit(void **state)
{
    (void)state;
    pfdoa_filter_t f;
    pfdoa_filter_init(&f);
    const pfdoa_config_t c = cfg_with(0, 64, 12);
    pfdoa_rssi_report_t out;
    (void)feed(&f, &c, -60, &out);
    /* Three outliers are spikes: EMA unchanged. */
    for (int k = 1; k <= 3; k++) {
        assert_int_equal(feed(&f, &c, -80, &out), 1);
        assert_int_equal(out.flags, PFDOA_FLAG_SPIKE);
        assert_int_equal(out.rssi_q8, -60 * 256);
        assert_int_equal(f.spike_run, k);
    }
    /* The fourth re-initialises on the new level: RESET, not a spike, run cleared. */
    assert_int_equal(feed(&f, &c, -80, &out), 0);
    assert_int_equal(out.flags, PFDOA_FLAG_RESET);
    assert_int_equal(out.rssi_q8, -80 * 256);
    assert_int_equal(f.spike_run, 0);
    /* A spike then a normal event clears the run. */
    assert_int_equal(feed(&f, &c, -50, &out), 1);
    assert_int_equal(feed(&f, &c, -80, &out), 0);
    assert_int_equal(f.spike_run, 0);
}

static void test_spike_threshold_is_strict(void **state)
{
    (void)state;
    pfdoa_filter_t f;
    pfdoa_filter_init(&f);
    const pfdoa_config_t c = cfg_with(0, 256, 12);
    pfdoa_rssi_report_t out;
    (void)feed(&f, &c, -60, &out);
    assert_int_equal(feed(&f, &c, -72, &out), 0); /* exactly 12 dB: not a spike */
    assert_int_equal(feed(&f, &c, -59, &out), 1); /* 13 dB: a spike */
    const pfdoa_config_t off = cfg_with(0, 256, 0);
    assert_int_equal(feed(&f, &off, -128, &out), 0); /* disabled */
    assert_int_equal(out.rssi_q8, -128 * 256);
}

static void test_saturation_and_calibration(void **state)
{
    (void)state;
    pfdoa_filter_t f;
    pfdoa_filter_init(&f);
    uint8_t flags = 0u;
    assert_int_equal(pfdoa_clamp_dbm(21, &flags), 20);
    assert_int_equal(flags, PFDOA_FLAG_SATURATED);
    flags = 0u;
    assert_int_equal(pfdoa_clamp_dbm(-128, &flags), -128);
    assert_int_equal(pfdoa_clamp_dbm(20, &flags), 20);
    assert_int_equal(flags, 0);

    pfdoa_rssi_report_t out;
    const pfdoa_config_t lo = cfg_with(-1, 256, 0);
    (void)feed(&f, &lo, -128, &out); /* -32768 - 1 clamps */
    assert_int_equal(out.rssi_q8, INT16_MIN);
    assert_int_equal(out.flags, PFDOA_FLAG_RESET | PFDOA_FLAG_SATURATED | PFDOA_FLAG_CALIBRATED);
    const pfdoa_config_t hi = cfg_with(32767, 256, 0);
    (void)feed(&f, &hi, 100, &out); /* reading clamps to 20, output clamps too */
    assert_int_equal(out.rssi_q8, INT16_MAX);
    assert_int_equal(out.raw_dbm, 20);
    assert_int_equal(out.flags, PFDOA_FLAG_SATURATED | PFDOA_FLAG_CALIBRATED);
    const pfdoa_config_t cal = cfg_with(-384, 256, 0);
    (void)feed(&f, &cal, -60, &out);
    assert_int_equal(out.rssi_q8, -15360 - 384);
    assert_int_equal(out.flags, PFDOA_FLAG_CALIBRATED);
}

static void test_events(void **state)
{
    (void)state;
    pfdoa_event_t ev;
    const pfdoa_radio_reading_t a = {10u, 7u, -60, 37u, 0u, PFDOA_RADIO_BLE};
    const pfdoa_radio_reading_t b = {11u, 7u, 30, 38u, 0u, PFDOA_RADIO_BLE};
    pfdoa_event_open(&ev, &a);
    pfdoa_event_add(&ev, &b);
    pfdoa_event_add(&ev, &a);
    pfdoa_event_add(&ev, &a); /* a 4th is ignored: events hold at most 3 */
    assert_int_equal(ev.n, 3);
    assert_int_equal(ev.sum, -100);
    assert_int_equal(ev.flags, PFDOA_FLAG_SATURATED);
    assert_int_equal(ev.first_tick, 10);
    const pfdoa_radio_reading_t z = {10u, 7u, -60, 15u, 200u, PFDOA_RADIO_IEEE802154};
    pfdoa_event_open(&ev, &z);
    assert_int_equal(ev.flags, PFDOA_FLAG_ZIGBEE);
    pfdoa_filter_t f;
    pfdoa_filter_init(&f);
    pfdoa_rssi_report_t out;
    const pfdoa_config_t c = cfg_with(0, 64, 12);
    ev.n = 0u;
    assert_int_equal(pfdoa_filter_close_event(&f, &c, &ev, 0u, &out), PFDOA_ERR_ARG);
    assert_int_equal(pfdoa_filter_close_event(NULL, &c, &ev, 0u, &out), PFDOA_ERR_ARG);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_floor_div_negative_ties),
        cmocka_unit_test(test_fold_round_half_up),
        cmocka_unit_test(test_ema_negative_tie_rounding),
        cmocka_unit_test(test_first_event_resets_then_ema),
        cmocka_unit_test(test_spike_and_reinit),
        cmocka_unit_test(test_spike_threshold_is_strict),
        cmocka_unit_test(test_saturation_and_calibration),
        cmocka_unit_test(test_events),
    };
    return cmocka_run_group_tests_name("filter", tests, NULL, NULL);
}
