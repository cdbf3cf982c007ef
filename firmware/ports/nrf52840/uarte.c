#include "uarte.h"

#include <string.h>

#include "cortexm.h"
#include "nrf52840.h"

#define RING_MASK (UARTE_RX_RING - 1u)

typedef char uarte_ring_is_pow2[((UARTE_RX_RING & RING_MASK) == 0u) ? 1 : -1];

static void rx_start(uarte_t *const u)
{
    nrf_uarte_t *const r = NRF_UARTE0;
    r->RXD_PTR = NRF_DMA_ADDR(u->rx_chunk);
    r->RXD_MAXCNT = UARTE_RX_CHUNK;
    u->rx_state = UARTE_RX_RUN;
    r->TASKS_STARTRX = 1u;
}

/* A PSEL value's GPIO port (PORT bit 5) and pin (bits 0-4). */
static nrf_gpio_t *psel_port(const uint32_t psel)
{
    return (((psel >> 5) & 1u) != 0u) ? NRF_P1 : NRF_P0;
}

void uarte_init(uarte_t *const u, const uint32_t psel_txd, const uint32_t psel_rxd)
{
    nrf_uarte_t *const r = NRF_UARTE0;
    memset(u, 0, sizeof *u);
    r->ENABLE = 0u;
    /* The pins as the PS's UARTE "Pin configuration" table wants them before the UARTE is
     * enabled: TXD an output at 1, RXD an input. RXD is pulled up too: the DK's interface
     * MCU tri-states its UART lines while no terminal has the virtual COM port open (with
     * DTR), and a floating RXD would read as line noise (line errors, rx_errors). */
    nrf_gpio_t *const tx = psel_port(psel_txd);
    tx->OUTSET = 1u << (psel_txd & 31u);
    tx->PIN_CNF[psel_txd & 31u] = NRF_GPIO_CNF_OUTPUT;
    psel_port(psel_rxd)->PIN_CNF[psel_rxd & 31u] = NRF_GPIO_CNF_INPUT | NRF_GPIO_CNF_PULLUP;
    r->PSEL_TXD = psel_txd;
    r->PSEL_RXD = psel_rxd;
    r->PSEL_RTS = NRF_PSEL_DISCONNECTED;
    r->PSEL_CTS = NRF_PSEL_DISCONNECTED;
    r->BAUDRATE = NRF_UARTE_BAUD_115200;
    r->CONFIG = 0u; /* no flow control, no parity, one stop bit */
    r->SHORTS = 0u;
    r->EVENTS_ENDRX = 0u;
    r->EVENTS_ENDTX = 0u;
    r->EVENTS_RXTO = 0u;
    r->EVENTS_ERROR = 0u;
    r->EVENTS_RXDRDY = 0u;
    r->INTENSET = NRF_UARTE_INT_RXDRDY | NRF_UARTE_INT_ENDRX | NRF_UARTE_INT_ENDTX
                | NRF_UARTE_INT_ERROR | NRF_UARTE_INT_RXTO;
    r->ENABLE = NRF_UARTE_ENABLE;
    rx_start(u);
}

/* Starts the DMA of the oldest queued slot. Interrupts masked or in the ISR. */
static void tx_start(uarte_t *const u)
{
    nrf_uarte_t *const r = NRF_UARTE0;
    const uint32_t slot = u->tx_tail % UARTE_TX_SLOTS;
    r->TXD_PTR = NRF_DMA_ADDR(u->tx[slot]);
    r->TXD_MAXCNT = u->tx_len[slot];
    r->EVENTS_ENDTX = 0u;
    u->tx_busy = 1u;
    r->TASKS_STARTTX = 1u;
}

int32_t uarte_write(uarte_t *const u, const uint8_t *const data, const size_t len)
{
    if (data == NULL || len == 0u || len > UARTE_TX_SLOT_MAX) {
        u->tx_dropped++;
        return -1;
    }
    const uint32_t primask = cm_irq_save();
    if (u->tx_head - u->tx_tail >= UARTE_TX_SLOTS) {
        cm_irq_restore(primask);
        u->tx_dropped++;
        return -1;
    }
    const uint32_t slot = u->tx_head % UARTE_TX_SLOTS;
    memcpy(u->tx[slot], data, len);
    u->tx_len[slot] = (uint8_t)len;
    u->tx_head = u->tx_head + 1u;
    if (u->tx_busy == 0u) {
        tx_start(u);
    }
    cm_irq_restore(primask);
    return (int32_t)len;
}

size_t uarte_read(uarte_t *const u, uint8_t *const out, const size_t cap)
{
    size_t n = 0u;
    uint32_t tail = u->rx_tail;
    const uint32_t head = u->rx_head;
    while (n < cap && tail != head) {
        out[n++] = u->rx_ring[tail & RING_MASK];
        ++tail;
    }
    u->rx_tail = tail;
    return n;
}

void uarte_poll(uarte_t *const u, const uint32_t now_ms)
{
    if (u->rx_activity != 0u) {
        u->rx_activity = 0u;
        u->rx_quiet_since = now_ms;
        return;
    }
    if (u->rx_dirty == 0u || (uint32_t)(now_ms - u->rx_quiet_since) < UARTE_RX_IDLE_MS) {
        return;
    }
    const uint32_t primask = cm_irq_save();
    if (u->rx_state == UARTE_RX_RUN) {
        u->rx_dirty = 0u; /* a byte arriving from here on sets it again */
        u->rx_state = UARTE_RX_STOPPING;
        NRF_UARTE0->TASKS_STOPRX = 1u;
    }
    cm_irq_restore(primask);
}

int uarte_rx_available(const uarte_t *const u)
{
    return u->rx_head != u->rx_tail;
}

int uarte_rx_pending(const uarte_t *const u)
{
    return u->rx_dirty != 0u || u->rx_state != UARTE_RX_RUN;
}

int uarte_tx_busy(const uarte_t *const u)
{
    return u->tx_busy != 0u;
}

/* ENDRX: RXD.AMOUNT bytes of the chunk are valid. */
static void rx_take(uarte_t *const u)
{
    uint32_t amount = NRF_UARTE0->RXD_AMOUNT;
    if (amount > UARTE_RX_CHUNK) {
        amount = UARTE_RX_CHUNK;
    }
    uint32_t head = u->rx_head;
    for (uint32_t i = 0u; i < amount; ++i) {
        if (head - u->rx_tail >= UARTE_RX_RING) {
            u->rx_lost = u->rx_lost + (amount - i);
            break;
        }
        u->rx_ring[head & RING_MASK] = u->rx_chunk[i];
        ++head;
    }
    u->rx_head = head;
}

void uarte_isr(uarte_t *const u)
{
    nrf_uarte_t *const r = NRF_UARTE0;
    if (r->EVENTS_ERROR != 0u) {
        r->EVENTS_ERROR = 0u;
        const uint32_t src = r->ERRORSRC;
        r->ERRORSRC = src; /* write 1 to clear the bits that are set */
        u->rx_line_errors = u->rx_line_errors + 1u;
    }
    if (r->EVENTS_RXDRDY != 0u) {
        r->EVENTS_RXDRDY = 0u;
        u->rx_activity = 1u;
        u->rx_dirty = 1u;
    }
    if (r->EVENTS_ENDRX != 0u) {
        r->EVENTS_ENDRX = 0u;
        rx_take(u);
        if (u->rx_state == UARTE_RX_RUN || u->rx_state == UARTE_RX_FLUSHING) {
            rx_start(u); /* chunk full, or the flush after a stop is done */
        }
    }
    if (r->EVENTS_RXTO != 0u) {
        r->EVENTS_RXTO = 0u;
        if (u->rx_state == UARTE_RX_STOPPING) {
            /* The FIFO may still hold bytes received after the stop: into the chunk. */
            u->rx_state = UARTE_RX_FLUSHING;
            r->RXD_PTR = NRF_DMA_ADDR(u->rx_chunk);
            r->RXD_MAXCNT = UARTE_RX_CHUNK;
            r->TASKS_FLUSHRX = 1u;
        }
    }
    if (r->EVENTS_ENDTX != 0u) {
        r->EVENTS_ENDTX = 0u;
        u->tx_tail = u->tx_tail + 1u;
        if (u->tx_tail != u->tx_head) {
            tx_start(u);
        } else {
            u->tx_busy = 0u;
            r->TASKS_STOPTX = 1u; /* the transmitter draws current until stopped */
        }
    }
}
