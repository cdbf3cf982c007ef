/*
 * SPIM2 and the MCP2515 driver against the fake SPIM with the register-level MCP2515
 * model on it: bit timing, reset and configuration, acceptance filters, TX buffer order
 * and the full-buffers path, error counters, error-passive, bus-off and its recovery.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "fake_mcp2515.h"
#include "fake_nrf.h"
#include "mcp2515.h"
#include "pfdoa_defs.h"
#include "spim.h"

/* CAN ids as the core uses them (SPEC 4): the can_type above the anchor id. */
#define CAN_ID(type, anchor) ((uint16_t)(((uint32_t)(type) << PFDOA_CAN_ANCHOR_BITS) | (uint32_t)(anchor)))
#define CFG(anchor)    CAN_ID(PFDOA_CAN_CONFIG_SET, anchor)
#define REPORT(anchor) CAN_ID(PFDOA_CAN_RSSI_REPORT, anchor)

#define INT_PIN 11u
#define CS_PIN 12u

static fake_mcp_t chip;
static spim_t spi;
static mcp2515_t can;
static mcp2515_timing_t timing;
static const uint16_t ids[2] = { CFG(5u), CFG(PFDOA_ANCHOR_BROADCAST) }; /* CONFIG_SET to anchor 5, and to all */

static int setup(void **state)
{
    (void)state;
    nrf_fake_reset();
    fake_mcp_init(&chip, INT_PIN);
    nrf_fake.spi_cs_mask = 1u << CS_PIN;
    spim_init(&spi, NRF_PSEL(1, 15), NRF_PSEL(1, 13), NRF_PSEL(1, 14), NRF_P1, CS_PIN);
    assert_int_equal(mcp2515_bit_timing(16000000u, 500000u, &timing), MCP2515_OK);
    return 0;
}

static void init_can(void)
{
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, ids, 2u), MCP2515_OK);
}

static int int_low(void)
{
    return (nrf_fake_p1.IN & (1u << INT_PIN)) == 0u;
}

/* ---------------------------------------------------------------- bit timing */

static void test_bit_timing_all_rates(void **state)
{
    (void)state;
    static const uint32_t osc[] = { 8000000u, 16000000u };
    static const uint32_t rate[] = { 125000u, 250000u, 500000u, 1000000u };
    for (uint32_t o = 0u; o < 2u; ++o) {
        for (uint32_t r = 0u; r < 4u; ++r) {
            mcp2515_timing_t t;
            const int32_t rc = mcp2515_bit_timing(osc[o], rate[r], &t);
            if (osc[o] == 8000000u && rate[r] == 1000000u) {
                assert_int_equal(rc, MCP2515_ERR_TIMING); /* 4 TQ at most: below the 8 TQ minimum */
                continue;
            }
            assert_int_equal(rc, MCP2515_OK);
            /* Exact bit rate, and the data sheet's constraints (section 5.3). */
            assert_int_equal(osc[o] % (2u * (t.brp + 1u) * t.tq_per_bit), 0u);
            assert_int_equal(osc[o] / (2u * (t.brp + 1u) * t.tq_per_bit), rate[r]);
            assert_int_equal(1u + t.prop + t.ps1 + t.ps2, t.tq_per_bit);
            assert_in_range(t.tq_per_bit, 8u, 25u);
            assert_in_range(t.prop, 1u, 8u);
            assert_in_range(t.ps1, 1u, 8u);
            assert_in_range(t.ps2, 2u, 8u);
            assert_true(t.prop + t.ps1 >= t.ps2);
            assert_in_range(t.sjw, 1u, 4u);
            assert_true(t.sjw < t.ps2);
            assert_in_range(t.sample_permille, 750u, 875u);
            assert_int_equal(t.sample_permille, 1000u * (t.tq_per_bit - t.ps2) / t.tq_per_bit);
            /* The registers say the same. */
            assert_int_equal(t.cnf1 & 0x3Fu, t.brp);
            assert_int_equal((t.cnf1 >> 6) + 1u, t.sjw);
            assert_int_equal(t.cnf2 & 0x80u, 0x80u); /* PS2 from CNF3 */
            assert_int_equal(((t.cnf2 >> 3) & 7u) + 1u, t.ps1);
            assert_int_equal((t.cnf2 & 7u) + 1u, t.prop);
            assert_int_equal((t.cnf3 & 7u) + 1u, t.ps2);
        }
    }
    /* The worked example of mcp2515.h. */
    mcp2515_timing_t t;
    assert_int_equal(mcp2515_bit_timing(16000000u, 500000u, &t), MCP2515_OK);
    assert_int_equal(t.cnf1, 0x00u);
    assert_int_equal(t.cnf2, 0xB5u);
    assert_int_equal(t.cnf3, 0x01u);
    assert_int_equal(t.sample_permille, 875u);
    /* 1 Mbit/s from 16 MHz: 8 TQ, the sample point at 75 %. */
    assert_int_equal(mcp2515_bit_timing(16000000u, 1000000u, &t), MCP2515_OK);
    assert_int_equal(t.tq_per_bit, 8u);
    assert_int_equal(t.sample_permille, 750u);
    assert_int_equal(mcp2515_bit_timing(16000000u, 0u, &t), MCP2515_ERR_ARG);
    assert_int_equal(mcp2515_bit_timing(16000000u, 333333u, &t), MCP2515_ERR_TIMING);
}

/* ---------------------------------------------------------------- SPIM */

static void test_spim_setup_and_transfer(void **state)
{
    (void)state;
    assert_int_equal(nrf_fake_spim2.PSEL_SCK, NRF_PSEL(1, 15));
    assert_int_equal(nrf_fake_spim2.PSEL_MOSI, NRF_PSEL(1, 13));
    assert_int_equal(nrf_fake_spim2.PSEL_MISO, NRF_PSEL(1, 14));
    assert_int_equal(nrf_fake_spim2.FREQUENCY, NRF_SPIM_FREQ_4M);
    assert_int_equal(nrf_fake_spim2.CONFIG, 0u); /* mode 0, MSB first */
    assert_int_equal(nrf_fake_spim2.ENABLE, 7u);
    assert_int_equal(nrf_fake_p1.PIN_CNF[CS_PIN], NRF_GPIO_CNF_OUTPUT);
    assert_int_equal(nrf_fake_p1.OUTSET, 1u << CS_PIN); /* CS idles high */
    /* READ CANSTAT: the model answers 0x80 (configuration mode after power-on). */
    const uint8_t tx[3] = { 0x03, 0x0E, 0x00 };
    uint8_t rx[3];
    assert_int_equal(spim_xfer(&spi, tx, rx, 3u), SPIM_OK);
    assert_int_equal(rx[2], 0x80u);
    assert_int_equal(nrf_fake.spi_transfers, 1u);
    assert_int_equal(nrf_fake.spi_without_cs, 0u);
    assert_int_equal(nrf_fake_p1.OUTSET, 1u << CS_PIN); /* released */
    assert_int_equal(spim_xfer(&spi, tx, rx, 0u), SPIM_ERR_ARG);
    assert_int_equal(spim_xfer(&spi, tx, rx, SPIM_MAX_XFER + 1u), SPIM_ERR_ARG);
    nrf_fake.spim_stuck = 1;
    assert_int_equal(spim_xfer(&spi, tx, rx, 3u), SPIM_ERR_TIMEOUT);
    assert_int_equal(nrf_fake_spim2.TASKS_STOP, 1u);
    assert_int_equal(spi.timeouts, 1u);
}

/* ---------------------------------------------------------------- init */

static void test_init_configures_chip(void **state)
{
    (void)state;
    init_can();
    assert_int_equal(chip.resets, 1u);
    assert_int_equal(fake_mcp_opmode(&chip), 0x00u); /* normal */
    assert_int_equal(chip.reg[0x2A], timing.cnf1);
    assert_int_equal(chip.reg[0x29], timing.cnf2);
    assert_int_equal(chip.reg[0x28], timing.cnf3);
    assert_int_equal(chip.reg[0x2B], 0x23u);          /* RX0IE, RX1IE, ERRIE */
    assert_int_equal(chip.reg[0x20], 0xFFu);          /* RXM0: all 11 id bits */
    assert_int_equal(chip.reg[0x21], 0xE0u);
    assert_int_equal(chip.reg[0x24], 0xFFu);          /* RXM1 */
    assert_int_equal(chip.reg[0x00], CFG(5u) >> 3);                     /* RXF0 = own CONFIG_SET id */
    assert_int_equal(chip.reg[0x01], (CFG(5u) & 7u) << 5);
    assert_int_equal(chip.reg[0x04], CFG(PFDOA_ANCHOR_BROADCAST) >> 3); /* RXF1 = broadcast */
    assert_int_equal(chip.reg[0x60] & 0x64u, 0x04u);  /* filters on, BUKT */
    assert_int_equal(nrf_fake.spi_without_cs, 0u);
    assert_false(int_low());
}

static void test_init_errors(void **state)
{
    (void)state;
    chip.absent = 1;
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, ids, 2u), MCP2515_ERR_NO_DEVICE);
    chip.absent = 0;
    chip.mode_stuck = 1;
    chip.reg[0x0E] = 0x80u;
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, ids, 2u), MCP2515_ERR_MODE);
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, ids, 0u), MCP2515_ERR_ARG);
    const uint16_t bad[1] = { 0x800u };
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, bad, 1u), MCP2515_ERR_ARG);
    nrf_fake.spim_stuck = 1;
    chip.mode_stuck = 0;
    assert_int_equal(mcp2515_init(&can, spim_xfer, &spi, &timing, ids, 2u), MCP2515_ERR_SPI);
}

/* ---------------------------------------------------------------- RX */

static void test_filters_pass_only_config_set_ids(void **state)
{
    (void)state;
    init_can();
    const uint8_t d[8] = { 1, 2, 3, 4, 5, 6, 7, 8 };
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(6u), 0, 0, 8u, d), -1); /* another anchor's */
    assert_int_equal(fake_mcp_bus_frame(&chip, REPORT(5u), 0, 0, 8u, d), -1); /* a report id */
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 1, 0, 8u, d), -1); /* extended */
    assert_false(int_low());
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 0, 0, 8u, d), 0);
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(PFDOA_ANCHOR_BROADCAST), 0, 0, 3u, d), 1); /* rolled over to RXB1 */
    assert_true(int_low());
    mcp2515_frame_t f;
    assert_int_equal(mcp2515_receive(&can, &f), 1);
    assert_int_equal(f.id, CFG(5u));
    assert_int_equal(f.dlc, 8u);
    assert_memory_equal(f.data, d, 8u);
    assert_int_equal(mcp2515_receive(&can, &f), 1);
    assert_int_equal(f.id, CFG(PFDOA_ANCHOR_BROADCAST));
    assert_int_equal(f.dlc, 3u);
    assert_int_equal(mcp2515_receive(&can, &f), 0);
    assert_false(int_low()); /* READ RX BUFFER cleared the flags */
    assert_int_equal(can.rx_frames, 2u);
}

static void test_remote_frame_ignored_and_overflow_counted(void **state)
{
    (void)state;
    init_can();
    const uint8_t d[8] = { 0 };
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 0, 1, 0u, d), 0); /* remote request */
    mcp2515_frame_t f;
    assert_int_equal(mcp2515_receive(&can, &f), 0);
    assert_int_equal(can.rx_ignored, 1u);
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 0, 0, 8u, d), 0);
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 0, 0, 8u, d), 1);
    assert_int_equal(fake_mcp_bus_frame(&chip, CFG(5u), 0, 0, 8u, d), -2); /* both full */
    assert_int_equal(mcp2515_service(&can, 0u), MCP2515_OK);
    assert_int_equal(can.rx_overflows, 1u);
    assert_int_equal(chip.reg[0x2D] & 0xC0u, 0u); /* RXnOVR cleared */
}

/* ---------------------------------------------------------------- TX */

static int32_t mcp2515_pump_ok(void)
{
    return mcp2515_tx_pump(&can);
}

static void send_id(uint16_t id, int32_t want)
{
    const uint8_t d[8] = { (uint8_t)id, 0, 0, 0, 0, 0, 0, 0 };
    assert_int_equal(mcp2515_send(&can, id, d, 8u), want);
}

static void test_tx_leaves_in_send_order(void **state)
{
    (void)state;
    init_can();
    /* A report, then STATUS_A, STATUS_B and STATUS_C: the bus must see them in this order.
     * Three go into the buffers, the fourth waits in the queue. */
    send_id(REPORT(5u), MCP2515_OK);
    send_id(CAN_ID(PFDOA_CAN_STATUS_A, 5u), MCP2515_OK);
    send_id(CAN_ID(PFDOA_CAN_STATUS_B, 5u), MCP2515_OK);
    send_id(CAN_ID(PFDOA_CAN_STATUS_C, 5u), MCP2515_OK);
    assert_int_equal(can.tx_frames, 3u);
    assert_int_equal(mcp2515_tx_waiting(&can), 1u);
    for (uint16_t id = REPORT(6u); id < REPORT(6u) + MCP2515_TXQ - 1u; ++id) {
        send_id(id, MCP2515_OK);                         /* the queue fills */
    }
    send_id(REPORT(100u), MCP2515_ERR_FULL);           /* buffers and queue full: refused */
    assert_int_equal(can.tx_full, 1u);
    assert_int_equal(mcp2515_pump_ok(), MCP2515_OK);     /* nothing freed yet: nothing moves */
    assert_int_equal(mcp2515_tx_waiting(&can), MCP2515_TXQ);
    assert_int_equal(fake_mcp_bus_run(&chip, 1u), 1u);
    send_id(REPORT(7u) + MCP2515_TXQ, MCP2515_ERR_FULL); /* a freed buffer does not let it jump the queue */
    assert_int_equal(mcp2515_pump_ok(), MCP2515_OK);     /* the oldest waiting one takes it */
    assert_int_equal(mcp2515_tx_waiting(&can), MCP2515_TXQ - 1u);
    send_id(REPORT(32u), MCP2515_OK);                  /* behind the others */
    for (uint32_t i = 0u; i < 10u && (mcp2515_tx_waiting(&can) > 0u || chip.n_sent < 8u); ++i) {
        (void)fake_mcp_bus_run(&chip, 2u);
        assert_int_equal(mcp2515_pump_ok(), MCP2515_OK);
    }
    (void)fake_mcp_bus_run(&chip, 10u);
    static const uint16_t want[] = { REPORT(5u), CAN_ID(PFDOA_CAN_STATUS_A, 5u), CAN_ID(PFDOA_CAN_STATUS_B, 5u),
                                     CAN_ID(PFDOA_CAN_STATUS_C, 5u), REPORT(6u), REPORT(7u), REPORT(8u), REPORT(32u) };
    assert_int_equal(chip.n_sent, sizeof want / sizeof want[0]);
    for (uint32_t k = 0u; k < chip.n_sent; ++k) {
        assert_int_equal(chip.sent[k].id, want[k]);
    }
    assert_int_equal(chip.sent[0].dlc, 8u);
    assert_int_equal(chip.sent[0].data[0], 0x05u);
    assert_int_equal(can.tx_frames, 8u);
    assert_int_equal(mcp2515_send(&can, 0x800u, NULL, 0u), MCP2515_ERR_ARG);
    assert_int_equal(mcp2515_send(&can, REPORT(0u), NULL, 9u), MCP2515_ERR_ARG);
    assert_int_equal(mcp2515_tx_pump(NULL), MCP2515_ERR_ARG);
}

static void test_tx_order_holds_under_steady_load(void **state)
{
    (void)state;
    init_can();
    /* Frames keep coming while the bus takes one to three at a time and the main loop
     * pumps: priorities step down, frames wait; when buffers and queue are full the send
     * is refused. Whatever is sent leaves in order. */
    uint16_t next = REPORT(0u);
    uint16_t expect = REPORT(0u);
    uint32_t refused = 0u;
    for (uint32_t i = 0u; i < 30u; ++i) { /* at most 60 frames: the model logs 64 */
        const uint8_t d[1] = { 0 };
        for (uint32_t k = 0u; k < 2u; ++k) {
            if (mcp2515_send(&can, next, d, 1u) == MCP2515_OK) {
                ++next;
            } else {
                ++refused;
            }
        }
        (void)fake_mcp_bus_run(&chip, (i % 3u == 2u) ? 3u : 1u);
        assert_int_equal(mcp2515_pump_ok(), MCP2515_OK);
    }
    for (uint32_t i = 0u; i < 10u; ++i) {
        (void)fake_mcp_bus_run(&chip, 10u);
        assert_int_equal(mcp2515_pump_ok(), MCP2515_OK);
    }
    for (uint32_t k = 0u; k < chip.n_sent; ++k) {
        assert_int_equal(chip.sent[k].id, expect++); /* never out of order */
    }
    assert_int_equal(chip.n_sent, (uint32_t)(next - REPORT(0u)));
    assert_int_equal(mcp2515_tx_waiting(&can), 0u);
    assert_true(chip.n_sent > 45u);
    assert_true(refused > 0u);
    assert_int_equal(refused, can.tx_full);
}

/* ---------------------------------------------------------------- errors */

static void test_error_passive_detected(void **state)
{
    (void)state;
    init_can();
    fake_mcp_set_errors(&chip, 130, 5);
    assert_true(int_low()); /* ERRIF */
    assert_int_equal(mcp2515_service(&can, 10u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_ERROR_PASSIVE);
    assert_int_equal(can.tec, 130u);
    assert_int_equal(can.rec, 5u);
    assert_int_equal(can.error_passive_events, 1u);
    assert_false(int_low()); /* ERRIF cleared */
    fake_mcp_set_errors(&chip, 20, 140);
    assert_int_equal(mcp2515_service(&can, 20u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_ERROR_PASSIVE);
    assert_int_equal(can.error_passive_events, 1u); /* still the same episode */
    fake_mcp_set_errors(&chip, 0, 0);
    assert_int_equal(mcp2515_service(&can, 30u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_ERROR_ACTIVE);
    send_id(REPORT(5u), MCP2515_OK);
}

static void test_bus_off_and_recovery(void **state)
{
    (void)state;
    init_can();
    for (uint16_t id = REPORT(1u); id <= REPORT(5u); ++id) {
        send_id(id, MCP2515_OK);                      /* three in the buffers, two waiting */
    }
    fake_mcp_set_errors(&chip, 256, 0);
    assert_int_equal(mcp2515_service(&can, 1000u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_BUS_OFF);
    assert_int_equal(can.bus_off_events, 1u);
    assert_int_equal(chip.aborted, 3u);               /* ABAT dropped what was pending */
    assert_int_equal(can.tx_aborted, 2u);             /* and the queue with it */
    assert_int_equal(mcp2515_tx_waiting(&can), 0u);
    assert_int_equal(chip.reg[0x0F] & 0x10u, 0x10u);
    send_id(REPORT(6u), MCP2515_ERR_BUS_OFF);         /* the core counts a tx failure */
    assert_int_equal(mcp2515_service(&can, 1500u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_BUS_OFF);     /* waiting for the recessive bits */
    fake_mcp_bus_off_recovered(&chip);
    assert_int_equal(mcp2515_service(&can, 1600u), MCP2515_OK);
    assert_int_equal(can.state, MCP2515_ERROR_ACTIVE);
    assert_int_equal(can.recoveries, 1u);
    assert_int_equal(chip.reg[0x0F] & 0x10u, 0u);     /* ABAT cleared: sending again */
    send_id(REPORT(7u), MCP2515_OK);
    assert_int_equal(fake_mcp_bus_run(&chip, 5u), 1u);
    assert_int_equal(chip.sent[0].id, REPORT(7u));
    assert_int_equal(can.resets, 0u);
}

static void test_bus_off_that_lasts_resets_the_controller(void **state)
{
    (void)state;
    init_can();
    fake_mcp_set_errors(&chip, 300, 0);
    assert_int_equal(mcp2515_service(&can, 5000u), MCP2515_OK);
    assert_int_equal(mcp2515_service(&can, 5000u + MCP2515_BUSOFF_RESET_MS - 1u), MCP2515_OK);
    assert_int_equal(chip.resets, 1u);
    assert_int_equal(mcp2515_service(&can, 5000u + MCP2515_BUSOFF_RESET_MS), MCP2515_OK);
    assert_int_equal(can.resets, 1u);
    assert_int_equal(chip.resets, 2u);                /* RESET and configured again */
    assert_int_equal(fake_mcp_opmode(&chip), 0x00u);
    assert_int_equal(chip.reg[0x2A], timing.cnf1);
    assert_int_equal(chip.reg[0x00], CFG(5u) >> 3);
    assert_int_equal(can.state, MCP2515_ERROR_ACTIVE);
    send_id(REPORT(5u), MCP2515_OK);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_bit_timing_all_rates, setup),
        cmocka_unit_test_setup(test_spim_setup_and_transfer, setup),
        cmocka_unit_test_setup(test_init_configures_chip, setup),
        cmocka_unit_test_setup(test_init_errors, setup),
        cmocka_unit_test_setup(test_filters_pass_only_config_set_ids, setup),
        cmocka_unit_test_setup(test_remote_frame_ignored_and_overflow_counted, setup),
        cmocka_unit_test_setup(test_tx_leaves_in_send_order, setup),
        cmocka_unit_test_setup(test_tx_order_holds_under_steady_load, setup),
        cmocka_unit_test_setup(test_error_passive_detected, setup),
        cmocka_unit_test_setup(test_bus_off_and_recovery, setup),
        cmocka_unit_test_setup(test_bus_off_that_lasts_resets_the_controller, setup),
    };
    return cmocka_run_group_tests_name("nrf52840 SPIM + MCP2515", tests, NULL, NULL);
}
