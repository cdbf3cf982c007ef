/*
 * fake_mcp2515.h - a register-level model of the MCP2515 (data sheet DS20001801) on the
 * fake SPIM: its SPI instruction set, register map, operating modes, acceptance filters
 * and masks with RXB0 -> RXB1 rollover, TX buffers sent in the chip's priority order,
 * error counters with EFLG, bus-off and its recovery, and the INT pin (on fake P1).
 */
#ifndef FAKE_MCP2515_H
#define FAKE_MCP2515_H

#include <stddef.h>
#include <stdint.h>

#define FAKE_MCP_LOG 64

typedef struct fake_mcp_frame {
    uint16_t id;
    uint8_t dlc;
    uint8_t data[8];
    uint8_t buffer;  /* TXB it left from */
} fake_mcp_frame_t;

typedef struct fake_mcp {
    uint8_t reg[128];
    int absent;             /* no chip: MISO floats high */
    int mode_stuck;         /* a mode request is never honoured */
    uint32_t resets;
    uint32_t instructions;
    fake_mcp_frame_t sent[FAKE_MCP_LOG];
    uint32_t n_sent;
    uint32_t aborted;       /* frames dropped by ABAT */
    int tec, rec;
    uint32_t int_pin;       /* P1 pin the INT output drives */
} fake_mcp_t;

/* Power-on state (configuration mode) and attaches it to the fake SPIM. */
void fake_mcp_init(fake_mcp_t *m, uint32_t int_pin);

/* The SPI side (nrf_fake.spi_device). */
void fake_mcp_spi(const uint8_t *tx, uint8_t *rx, size_t len, void *ctx);

/* A frame on the bus: through the filters into RXB0/RXB1, or dropped. Returns the buffer
 * it went to (0, 1), -1 filtered out, -2 overflow (RXnOVR set). */
int fake_mcp_bus_frame(fake_mcp_t *m, uint16_t id, int extended, int remote, uint8_t dlc, const uint8_t *data);

/* The bus takes up to n pending frames, in the chip's order (highest TXP, then highest
 * buffer number); returns how many went. Nothing goes while bus-off or not in normal
 * mode. */
uint32_t fake_mcp_bus_run(fake_mcp_t *m, uint32_t n);

/* Sets the error counters; EFLG and the error interrupt follow (TEC > 255: bus-off). */
void fake_mcp_set_errors(fake_mcp_t *m, int tec, int rec);

/* The 128 x 11 recessive bits have been seen: bus-off ends, TEC = REC = 0. */
void fake_mcp_bus_off_recovered(fake_mcp_t *m);

uint8_t fake_mcp_opmode(const fake_mcp_t *m);

#endif /* FAKE_MCP2515_H */
