/*
 * uarte.h - UARTE0 to the host (PS v1.7, chapter "UARTE - Universal asynchronous
 * receiver/transmitter with EasyDMA"): 115200 8N1, no flow control.
 *
 * TX: each frame the core hands over is copied into one of UARTE_TX_SLOTS slots and sent
 * whole by EasyDMA (TXD.PTR/MAXCNT, STARTTX; ENDTX starts the next slot, STOPTX after the
 * last one to save power). A frame that finds every slot full is dropped and counted, and
 * uarte_write says so, so the core counts a tx failure (the HAL contract: take the whole
 * frame or drop it).
 *
 * RX: EasyDMA fills a UARTE_RX_CHUNK-byte buffer; ENDRX moves what it holds (RXD.AMOUNT)
 * into a ring the main loop drains, and restarts reception. A chunk that is not full is
 * collected when the line has been quiet for UARTE_RX_IDLE_MS: STOPRX -> ENDRX (the bytes
 * so far) -> RXTO -> FLUSHRX (what the RX FIFO still holds) -> ENDRX -> STARTRX again.
 * Bytes that find the ring full are lost and counted (rx_lost); line errors (ERRORSRC:
 * overrun, parity, framing, break) are counted (rx_line_errors). Nothing grows.
 */
#ifndef NRF_UARTE_H
#define NRF_UARTE_H

#include <stddef.h>
#include <stdint.h>

#define UARTE_TX_SLOTS    4u
#define UARTE_TX_SLOT_MAX 66u   /* PFDOA_FRAME_WIRE_MAX: one whole frame with its delimiter */
#define UARTE_RX_CHUNK    16u
#define UARTE_RX_RING     256u  /* power of two */
#define UARTE_RX_IDLE_MS  2u    /* ~23 byte times at 115200 */

typedef enum uarte_rx_state {
    UARTE_RX_RUN = 0,   /* receiving into the chunk */
    UARTE_RX_STOPPING,  /* STOPRX given: waiting for ENDRX then RXTO */
    UARTE_RX_FLUSHING   /* FLUSHRX given: waiting for its ENDRX */
} uarte_rx_state_t;

typedef struct uarte {
    uint8_t tx[UARTE_TX_SLOTS][UARTE_TX_SLOT_MAX];
    uint8_t tx_len[UARTE_TX_SLOTS];
    volatile uint32_t tx_head;     /* slots queued (main loop) */
    volatile uint32_t tx_tail;     /* slots sent (ISR) */
    volatile uint8_t tx_busy;      /* a DMA transfer is running */
    uint8_t rx_chunk[UARTE_RX_CHUNK];
    uint8_t rx_ring[UARTE_RX_RING];
    volatile uint32_t rx_head;     /* written by the ISR */
    volatile uint32_t rx_tail;     /* written by the main loop */
    volatile uint8_t rx_state;     /* uarte_rx_state_t */
    volatile uint8_t rx_activity;  /* RXDRDY since the main loop last looked */
    volatile uint8_t rx_dirty;     /* bytes may sit in the chunk or the FIFO */
    uint32_t rx_quiet_since;       /* main loop: last tick with RX activity */
    volatile uint32_t rx_lost;        /* bytes dropped: the ring was full */
    volatile uint32_t rx_line_errors; /* ERROR events */
    uint32_t tx_dropped;              /* frames refused: too long or every slot busy */
} uarte_t;

/* Configures UARTE0 on the given PSEL values (NRF_PSEL(port, pin)) and starts reception.
 * The caller enables the NVIC line. */
void uarte_init(uarte_t *u, uint32_t psel_txd, uint32_t psel_rxd);

/* Queues one whole frame (1..UARTE_TX_SLOT_MAX bytes). Returns len, or -1 (dropped). */
int32_t uarte_write(uarte_t *u, const uint8_t *data, size_t len);

/* Moves up to cap received bytes to out; returns the count. */
size_t uarte_read(uarte_t *u, uint8_t *out, size_t cap);

/* Main loop: collects a partly filled chunk once the line has been quiet. */
void uarte_poll(uarte_t *u, uint32_t now_ms);

/* True when received bytes wait in the ring. */
int uarte_rx_available(const uarte_t *u);

/* True while bytes may wait in the chunk or the FIFO, not yet collected (the main loop
 * then wakes up soon enough to collect them). */
int uarte_rx_pending(const uarte_t *u);

/* True while frames are queued or being sent. */
int uarte_tx_busy(const uarte_t *u);

/* Body of UARTE0_UART0_IRQHandler. */
void uarte_isr(uarte_t *u);

#endif /* NRF_UARTE_H */
