/*
 * mcp2515.h - Microchip MCP2515 stand-alone CAN controller over SPI (written from the
 * MCP2515 data sheet, DS20001801: SPI instruction set (Table 12-1), register map
 * (Table 11-1), bit timing (section 5), error handling (section 10)).
 *
 * - Bit timing from the crystal: mcp2515_bit_timing() picks BRP and the segment lengths
 *   for an exact bit rate with the sample point as close to 87.5 % as the constraints
 *   allow (never below 75 %). Constraints (data sheet 5.3): 8..25 TQ per bit, TQ =
 *   2 (BRP + 1) / F_OSC, SyncSeg 1 TQ, PropSeg and PS1 1..8 TQ, PS2 2..8 TQ,
 *   PropSeg + PS1 >= PS2, SJW 1..4 and SJW < PS2.
 *   Worked example, 16 MHz / 500 kbit/s: 16e6 / (2 * 500e3) = 16 TQ per bit with BRP = 0
 *   (TQ = 125 ns); PS2 = ceil(16 / 8) = 2 gives the sample point (16 - 2) / 16 = 87.5 %;
 *   the 13 TQ before it are SyncSeg 1 + PropSeg 6 + PS1 7; SJW = 1.
 *   -> CNF1 = 0x00, CNF2 = 0xB5 (BTLMODE, PS1 - 1 = 6, PropSeg - 1 = 5), CNF3 = 0x01.
 *   An 8 MHz crystal cannot make 1 Mbit/s: at most 8e6 / (2 * 1e6) = 4 TQ per bit.
 * - TX: three buffers TXB0..2. The chip sends the pending buffer with the highest TXP
 *   first, the highest-numbered one among equal TXP. mcp2515_send gives each new frame a
 *   (TXP, buffer) pair below every pending one, so frames leave in the order they were
 *   sent (a STATUS_A before its STATUS_B). When no such pair is free the frame waits in a
 *   queue of MCP2515_TXQ frames that mcp2515_tx_pump moves into the buffers as the bus
 *   takes them (a report and STATUS_A/B/C are four frames sent back to back); when that
 *   queue is full too the frame is refused (MCP2515_ERR_FULL) and the caller counts a tx
 *   failure.
 * - RX: only the ids given at init pass the acceptance filters (both masks 0x7FF, all six
 *   filters on those ids, standard frames only); RXB0 rolls over into RXB1 (BUKT).
 * - Errors: TEC/REC are read on every error interrupt; error-passive (TEC or REC >= 128)
 *   and bus-off (TEC > 255) are detected from EFLG and counted. Recovery from bus-off:
 *   pending frames (buffers and queue) are aborted (ABAT) and sends refused while the chip waits for the 128 x
 *   11 recessive bits after which it leaves bus-off by itself; then ABAT is cleared and
 *   sending resumes. A chip still bus-off after MCP2515_BUSOFF_RESET_MS is reset and
 *   configured again.
 */
#ifndef NRF_MCP2515_H
#define NRF_MCP2515_H

#include <stddef.h>
#include <stdint.h>

#define MCP2515_OK             0
#define MCP2515_ERR_ARG       -1
#define MCP2515_ERR_SPI       -2  /* the SPI transfer failed */
#define MCP2515_ERR_NO_DEVICE -3  /* no configuration mode after RESET: nothing answers */
#define MCP2515_ERR_MODE      -4  /* the requested mode was not entered */
#define MCP2515_ERR_TIMING    -5  /* no bit timing for this crystal and bit rate */
#define MCP2515_ERR_FULL      -6  /* no TX buffer can take the frame now */
#define MCP2515_ERR_BUS_OFF   -7  /* bus-off: not sending */

#define MCP2515_MAX_IDS        2u
#define MCP2515_TXQ            4u  /* frames waiting for a TX buffer */
#define MCP2515_BUSOFF_RESET_MS 1000u
#define MCP2515_MODE_SPINS     1000u

typedef enum mcp2515_state {
    MCP2515_ERROR_ACTIVE = 0,
    MCP2515_ERROR_PASSIVE = 1,
    MCP2515_BUS_OFF = 2
} mcp2515_state_t;

typedef struct mcp2515_timing {
    uint8_t cnf1, cnf2, cnf3;
    uint8_t brp;             /* TQ = 2 (brp + 1) / F_OSC */
    uint8_t tq_per_bit;      /* 1 + prop + ps1 + ps2 */
    uint8_t prop, ps1, ps2, sjw;
    uint16_t sample_permille;
} mcp2515_timing_t;

typedef struct mcp2515_frame {
    uint16_t id;
    uint8_t dlc;             /* as received, 0..15 (more than 8 means 8 bytes) */
    uint8_t data[8];
} mcp2515_frame_t;

typedef struct mcp2515 {
    int32_t (*xfer)(void *bus, const uint8_t *tx, uint8_t *rx, size_t len);
    void *bus;
    mcp2515_timing_t timing;
    uint16_t ids[MCP2515_MAX_IDS];
    uint8_t n_ids;
    uint8_t txp[3];          /* TXP given to each buffer when it was loaded */
    mcp2515_frame_t txq[MCP2515_TXQ]; /* waiting for a buffer, oldest at txq_head */
    uint8_t txq_head, txq_n;
    uint8_t state;           /* mcp2515_state_t */
    uint8_t tec, rec;        /* last read */
    uint32_t bus_off_since_ms;
    uint32_t tx_frames;      /* loaded into a TX buffer */
    uint32_t tx_full;        /* refused: buffers and queue full */
    uint32_t tx_aborted;     /* dropped from the queue at bus-off (the chip's ABAT drops the buffers') */
    uint32_t rx_frames, rx_ignored, rx_overflows;
    uint32_t error_passive_events, bus_off_events, recoveries, resets;
} mcp2515_t;

/* Bit timing for an oscillator and bit rate (see above). Returns MCP2515_OK or
 * MCP2515_ERR_TIMING / MCP2515_ERR_ARG. */
int32_t mcp2515_bit_timing(uint32_t osc_hz, uint32_t bitrate, mcp2515_timing_t *out);

/* Resets the chip, sets bit timing, filters for ids (1..MCP2515_MAX_IDS standard ids) and
 * interrupts (RX, error), and enters normal mode. */
int32_t mcp2515_init(mcp2515_t *m, int32_t (*xfer)(void *, const uint8_t *, uint8_t *, size_t), void *bus,
                     const mcp2515_timing_t *timing, const uint16_t *ids, uint8_t n_ids);

/* Sends one classic frame (11-bit id, dlc 0..8): into a TX buffer, or behind the frames
 * already waiting. MCP2515_OK, MCP2515_ERR_FULL, MCP2515_ERR_BUS_OFF, MCP2515_ERR_ARG or
 * MCP2515_ERR_SPI. */
int32_t mcp2515_send(mcp2515_t *m, uint16_t id, const uint8_t *data, uint8_t dlc);

/* Moves waiting frames into the TX buffers the bus has freed, in order. Call from the main
 * loop while mcp2515_tx_waiting() > 0. MCP2515_OK or a negative error. */
int32_t mcp2515_tx_pump(mcp2515_t *m);

/* Frames waiting for a TX buffer. */
uint32_t mcp2515_tx_waiting(const mcp2515_t *m);

/* Takes one received frame: 1 with *out, 0 when none waits, or a negative error.
 * Extended and remote frames are taken out of the chip and ignored (rx_ignored). */
int32_t mcp2515_receive(mcp2515_t *m, mcp2515_frame_t *out);

/* Error handling: reads the interrupt and error flags, updates state and counters, runs
 * the bus-off recovery. Call when the INT pin is low and, while not error-active,
 * periodically. Returns MCP2515_OK or a negative error. */
int32_t mcp2515_service(mcp2515_t *m, uint32_t now_ms);

#endif /* NRF_MCP2515_H */
