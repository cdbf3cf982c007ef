#include "mcp2515.h"

#include <string.h>

/* SPI instructions (DS20001801 Table 12-1). */
#define INS_RESET       0xC0u
#define INS_READ        0x03u
#define INS_WRITE       0x02u
#define INS_BIT_MODIFY  0x05u
#define INS_READ_STATUS 0xA0u
#define INS_READ_RXB(n) (0x90u | ((uint32_t)(n) << 2)) /* from RXBnSIDH; clears RXnIF */
#define INS_RTS(n)      (0x80u | (1u << (n)))
/* Registers (Table 11-1). */
#define REG_RXF0SIDH    0x00u
#define REG_RXF3SIDH    0x10u
#define REG_CANSTAT     0x0Eu
#define REG_CANCTRL     0x0Fu
#define REG_TEC         0x1Cu
#define REG_RXM0SIDH    0x20u
#define REG_CNF3        0x28u
#define REG_CANINTF     0x2Cu
#define REG_EFLG        0x2Du
#define REG_TXBCTRL(n)  (0x30u + 0x10u * (n))
#define REG_RXB0CTRL    0x60u
#define REG_RXB1CTRL    0x70u
/* Bits. */
#define CANSTAT_OPMOD_MASK 0xE0u
#define OPMOD_NORMAL    0x00u
#define OPMOD_CONFIG    0x80u
#define CANCTRL_ABAT    0x10u
#define INT_RX0         0x01u
#define INT_RX1         0x02u
#define INT_ERR         0x20u
#define INT_MERR        0x80u
#define EFLG_RXEP       0x08u
#define EFLG_TXEP       0x10u
#define EFLG_TXBO       0x20u
#define EFLG_RX0OVR     0x40u
#define EFLG_RX1OVR     0x80u
#define STATUS_RX0IF    0x01u
#define STATUS_RX1IF    0x02u
#define STATUS_TXREQ(n) (0x04u << (2u * (n))) /* READ STATUS bits 2, 4, 6 */
#define RXB_BUKT        0x04u
#define SIDL_IDE        0x08u
#define SIDL_SRR        0x10u                 /* standard frame remote request */
#define CNF2_BTLMODE    0x80u
#define TXB_COUNT       3u
#define TXP_MAX         3u
#define STD_ID_MAX      0x7FFu

/* ---- bit timing ---- */

int32_t mcp2515_bit_timing(const uint32_t osc_hz, const uint32_t bitrate, mcp2515_timing_t *const out)
{
    if (out == NULL || bitrate == 0u || osc_hz == 0u) {
        return MCP2515_ERR_ARG;
    }
    int found = 0;
    uint32_t best_dist = 0u;
    for (uint32_t brp = 0u; brp < 64u; ++brp) {
        const uint64_t per_bit = 2ull * (brp + 1u) * bitrate; /* F_OSC / TQs per bit */
        if ((uint64_t)osc_hz % per_bit != 0u) {
            continue;
        }
        const uint32_t n = (uint32_t)((uint64_t)osc_hz / per_bit);
        if (n < 8u || n > 25u) {
            continue;
        }
        /* The shortest PS2 that keeps the sample point at or below 87.5 %: ceil(n / 8). */
        uint32_t ps2 = (n + 7u) / 8u;
        if (ps2 < 2u) {
            ps2 = 2u;
        }
        const uint32_t rest = n - 1u - ps2; /* PropSeg + PS1 */
        uint32_t ps1 = (rest + 1u) / 2u;
        uint32_t prop = rest - ps1;
        if (prop > 8u) {
            prop = 8u;
            ps1 = rest - 8u;
        }
        if (ps1 < 1u || ps1 > 8u || prop < 1u || ps2 > 8u || rest < ps2) {
            continue;
        }
        const uint32_t sp = 1000u * (n - ps2) / n;
        if (sp < 750u) {
            continue;
        }
        const uint32_t dist = 875u - sp;
        if (found != 0 && dist > best_dist) {
            continue;
        }
        if (found != 0 && dist == best_dist && n <= out->tq_per_bit) {
            continue; /* equal sample points: keep the finer time quantum */
        }
        uint32_t sjw = ps2 - 1u;
        if (sjw > 4u) {
            sjw = 4u;
        }
        if (sjw > ps1) {
            sjw = ps1;
        }
        found = 1;
        best_dist = dist;
        out->brp = (uint8_t)brp;
        out->tq_per_bit = (uint8_t)n;
        out->prop = (uint8_t)prop;
        out->ps1 = (uint8_t)ps1;
        out->ps2 = (uint8_t)ps2;
        out->sjw = (uint8_t)sjw;
        out->sample_permille = (uint16_t)sp;
        out->cnf1 = (uint8_t)(((sjw - 1u) << 6) | brp);
        out->cnf2 = (uint8_t)(CNF2_BTLMODE | ((ps1 - 1u) << 3) | (prop - 1u));
        out->cnf3 = (uint8_t)(ps2 - 1u);
    }
    return found ? MCP2515_OK : MCP2515_ERR_TIMING;
}

/* ---- SPI helpers ---- */

static int32_t xfer(const mcp2515_t *const m, const uint8_t *const tx, uint8_t *const rx, const size_t len)
{
    return (m->xfer(m->bus, tx, rx, len) == 0) ? MCP2515_OK : MCP2515_ERR_SPI;
}

static int32_t write_regs(const mcp2515_t *const m, const uint8_t addr, const uint8_t *const data, const size_t n)
{
    uint8_t tx[2u + 16u];
    if (n > 16u) {
        return MCP2515_ERR_ARG;
    }
    tx[0] = INS_WRITE;
    tx[1] = addr;
    memcpy(&tx[2], data, n);
    return xfer(m, tx, NULL, 2u + n);
}

static int32_t read_regs(const mcp2515_t *const m, const uint8_t addr, uint8_t *const out, const size_t n)
{
    uint8_t tx[2u + 14u] = { INS_READ, addr };
    uint8_t rx[2u + 14u];
    if (n > 14u) {
        return MCP2515_ERR_ARG;
    }
    const int32_t rc = xfer(m, tx, rx, 2u + n);
    if (rc == MCP2515_OK) {
        memcpy(out, &rx[2], n);
    }
    return rc;
}

static int32_t bit_modify(const mcp2515_t *const m, const uint8_t addr, const uint8_t mask, const uint8_t value)
{
    const uint8_t tx[4] = { INS_BIT_MODIFY, addr, mask, value };
    return xfer(m, tx, NULL, sizeof tx);
}

static int32_t read_status(const mcp2515_t *const m, uint8_t *const status)
{
    const uint8_t tx[2] = { INS_READ_STATUS, 0u };
    uint8_t rx[2];
    const int32_t rc = xfer(m, tx, rx, sizeof tx);
    *status = rx[1];
    return rc;
}

/* Requests an operating mode and waits (bounded) until CANSTAT shows it. */
static int32_t set_mode(const mcp2515_t *const m, const uint8_t mode)
{
    const uint8_t ctrl = mode; /* ABAT, OSM, CLKOUT off */
    int32_t rc = write_regs(m, REG_CANCTRL, &ctrl, 1u);
    for (uint32_t i = 0u; rc == MCP2515_OK && i < MCP2515_MODE_SPINS; ++i) {
        uint8_t stat;
        rc = read_regs(m, REG_CANSTAT, &stat, 1u);
        if (rc == MCP2515_OK && (stat & CANSTAT_OPMOD_MASK) == mode) {
            return MCP2515_OK;
        }
    }
    return (rc == MCP2515_OK) ? MCP2515_ERR_MODE : rc;
}

/* A standard id in filter/mask register layout: SIDH, SIDL (EXIDE = 0), EID8, EID0. */
static void std_id_regs(const uint16_t id, uint8_t out[4])
{
    out[0] = (uint8_t)(id >> 3);
    out[1] = (uint8_t)((id & 7u) << 5);
    out[2] = 0u;
    out[3] = 0u;
}

/* The frames waiting for a TX buffer are dropped (bus-off, reset). */
static void drop_queue(mcp2515_t *const m)
{
    m->tx_aborted += m->txq_n;
    m->txq_head = 0u;
    m->txq_n = 0u;
}

/* RESET, then everything that is only writable in configuration mode, then normal mode. */
static int32_t configure(mcp2515_t *const m)
{
    const uint8_t reset = INS_RESET;
    int32_t rc = xfer(m, &reset, NULL, 1u);
    if (rc != MCP2515_OK) {
        return rc;
    }
    /* After RESET the chip is in configuration mode once its oscillator runs (128 OSC
     * cycles): CANSTAT says so. Nothing on the bus (MISO floating or stuck) reads as no
     * device. */
    uint8_t stat = 0u;
    uint32_t i = 0u;
    do {
        rc = read_regs(m, REG_CANSTAT, &stat, 1u);
    } while (rc == MCP2515_OK && (stat & CANSTAT_OPMOD_MASK) != OPMOD_CONFIG && ++i < MCP2515_MODE_SPINS);
    if (rc != MCP2515_OK) {
        return rc;
    }
    if ((stat & CANSTAT_OPMOD_MASK) != OPMOD_CONFIG) {
        return MCP2515_ERR_NO_DEVICE;
    }
    /* CNF3, CNF2, CNF1, CANINTE are consecutive (0x28..0x2B). */
    const uint8_t timing[4] = { m->timing.cnf3, m->timing.cnf2, m->timing.cnf1, INT_RX0 | INT_RX1 | INT_ERR };
    rc = write_regs(m, REG_CNF3, timing, sizeof timing);
    /* Filters RXF0..2 (0x00..0x0B) and RXF3..5 (0x10..0x1B): the accepted ids in turn, so
     * both buffers see every one. */
    uint8_t filt[12];
    for (uint32_t f = 0u; f < 3u; ++f) {
        std_id_regs(m->ids[f % m->n_ids], &filt[4u * f]);
    }
    if (rc == MCP2515_OK) {
        rc = write_regs(m, REG_RXF0SIDH, filt, sizeof filt);
    }
    for (uint32_t f = 0u; f < 3u; ++f) {
        std_id_regs(m->ids[(f + 3u) % m->n_ids], &filt[4u * f]);
    }
    if (rc == MCP2515_OK) {
        rc = write_regs(m, REG_RXF3SIDH, filt, sizeof filt);
    }
    /* Masks RXM0, RXM1: every standard id bit compared. */
    uint8_t masks[8];
    std_id_regs(STD_ID_MAX, &masks[0]);
    std_id_regs(STD_ID_MAX, &masks[4]);
    if (rc == MCP2515_OK) {
        rc = write_regs(m, REG_RXM0SIDH, masks, sizeof masks);
    }
    const uint8_t rxb0 = RXB_BUKT; /* RXM = 00: filters on; roll over into RXB1 */
    const uint8_t rxb1 = 0u;
    if (rc == MCP2515_OK) {
        rc = write_regs(m, REG_RXB0CTRL, &rxb0, 1u);
    }
    if (rc == MCP2515_OK) {
        rc = write_regs(m, REG_RXB1CTRL, &rxb1, 1u);
    }
    if (rc == MCP2515_OK) {
        rc = set_mode(m, OPMOD_NORMAL);
    }
    memset(m->txp, 0, sizeof m->txp);
    drop_queue(m);
    m->state = MCP2515_ERROR_ACTIVE;
    return rc;
}

int32_t mcp2515_init(mcp2515_t *const m, int32_t (*const xfer_fn)(void *, const uint8_t *, uint8_t *, size_t),
                     void *const bus, const mcp2515_timing_t *const timing, const uint16_t *const ids,
                     const uint8_t n_ids)
{
    if (m == NULL || xfer_fn == NULL || timing == NULL || ids == NULL || n_ids == 0u || n_ids > MCP2515_MAX_IDS) {
        return MCP2515_ERR_ARG;
    }
    for (uint32_t i = 0u; i < n_ids; ++i) {
        if (ids[i] > STD_ID_MAX) {
            return MCP2515_ERR_ARG;
        }
    }
    memset(m, 0, sizeof *m);
    m->xfer = xfer_fn;
    m->bus = bus;
    m->timing = *timing;
    memcpy(m->ids, ids, n_ids * sizeof ids[0]);
    m->n_ids = n_ids;
    return configure(m);
}

/* ---- TX ---- */

/* Loads one frame into a TX buffer and requests its transmission, or MCP2515_ERR_FULL. */
static int32_t load(mcp2515_t *const m, const mcp2515_frame_t *const f)
{
    uint8_t status;
    int32_t rc = read_status(m, &status);
    if (rc != MCP2515_OK) {
        return rc;
    }
    /* Send order key of a buffer: TXP * 4 + buffer number (higher goes first). The new
     * frame needs a key below every pending one; take the highest such free pair. */
    uint32_t lowest = (TXP_MAX + 1u) * 4u;
    for (uint32_t b = 0u; b < TXB_COUNT; ++b) {
        if ((status & STATUS_TXREQ(b)) != 0u) {
            const uint32_t key = (uint32_t)m->txp[b] * 4u + b;
            if (key < lowest) {
                lowest = key;
            }
        }
    }
    int32_t buf = -1;
    uint32_t txp = 0u;
    for (uint32_t key = lowest; key-- > 0u;) {
        const uint32_t b = key % 4u;
        if (b < TXB_COUNT && (status & STATUS_TXREQ(b)) == 0u) {
            buf = (int32_t)b;
            txp = key / 4u;
            break;
        }
    }
    if (buf < 0) {
        return MCP2515_ERR_FULL;
    }
    /* TXBnCTRL (TXP, TXREQ clear), SIDH, SIDL, EID8, EID0, DLC, D0..D7 in one write. */
    uint8_t regs[6u + 8u] = { 0 };
    regs[0] = (uint8_t)txp;
    std_id_regs(f->id, &regs[1]);
    regs[5] = f->dlc;
    if (f->dlc > 0u) {
        memcpy(&regs[6], f->data, f->dlc);
    }
    rc = write_regs(m, (uint8_t)REG_TXBCTRL((uint32_t)buf), regs, 6u + f->dlc);
    if (rc == MCP2515_OK) {
        const uint8_t rts = (uint8_t)INS_RTS((uint32_t)buf);
        rc = xfer(m, &rts, NULL, 1u);
    }
    if (rc == MCP2515_OK) {
        m->txp[buf] = (uint8_t)txp;
        m->tx_frames++;
    }
    return rc;
}

int32_t mcp2515_send(mcp2515_t *const m, const uint16_t id, const uint8_t *const data, const uint8_t dlc)
{
    if (m == NULL || id > STD_ID_MAX || dlc > 8u || (data == NULL && dlc > 0u)) {
        return MCP2515_ERR_ARG;
    }
    if (m->state == MCP2515_BUS_OFF) {
        return MCP2515_ERR_BUS_OFF;
    }
    mcp2515_frame_t f;
    f.id = id;
    f.dlc = dlc;
    memset(f.data, 0, sizeof f.data);
    if (dlc > 0u) {
        memcpy(f.data, data, dlc);
    }
    if (m->txq_n == 0u) {
        const int32_t rc = load(m, &f);
        if (rc != MCP2515_ERR_FULL) {
            return rc;
        }
    }
    /* Behind the waiting ones (never ahead: the order is kept). */
    if (m->txq_n >= MCP2515_TXQ) {
        m->tx_full++;
        return MCP2515_ERR_FULL;
    }
    m->txq[(m->txq_head + m->txq_n) % MCP2515_TXQ] = f;
    m->txq_n++;
    return MCP2515_OK;
}

int32_t mcp2515_tx_pump(mcp2515_t *const m)
{
    if (m == NULL) {
        return MCP2515_ERR_ARG;
    }
    while (m->txq_n > 0u && m->state != MCP2515_BUS_OFF) {
        const int32_t rc = load(m, &m->txq[m->txq_head]);
        if (rc == MCP2515_ERR_FULL) {
            break;
        }
        if (rc != MCP2515_OK) {
            return rc;
        }
        m->txq_head = (uint8_t)((m->txq_head + 1u) % MCP2515_TXQ);
        m->txq_n--;
    }
    return MCP2515_OK;
}

uint32_t mcp2515_tx_waiting(const mcp2515_t *const m)
{
    return (m != NULL) ? m->txq_n : 0u;
}

/* ---- RX ---- */

int32_t mcp2515_receive(mcp2515_t *const m, mcp2515_frame_t *const out)
{
    if (m == NULL || out == NULL) {
        return MCP2515_ERR_ARG;
    }
    /* At most both buffers per call: an ignored frame in RXB0 lets RXB1's be taken. */
    for (uint32_t tries = 0u; tries < 2u; ++tries) {
        uint8_t status;
        int32_t rc = read_status(m, &status);
        if (rc != MCP2515_OK) {
            return rc;
        }
        uint32_t n;
        if ((status & STATUS_RX0IF) != 0u) {
            n = 0u;
        } else if ((status & STATUS_RX1IF) != 0u) {
            n = 1u;
        } else {
            return 0;
        }
        uint8_t tx[1u + 13u] = { (uint8_t)INS_READ_RXB(n) };
        uint8_t rx[1u + 13u];
        rc = xfer(m, tx, rx, sizeof tx);
        if (rc != MCP2515_OK) {
            return rc;
        }
        const uint8_t *const r = &rx[1]; /* SIDH SIDL EID8 EID0 DLC D0..D7 */
        if ((r[1] & (SIDL_IDE | SIDL_SRR)) != 0u) {
            m->rx_ignored++; /* extended or remote: never a CONFIG_SET */
            continue;
        }
        out->id = (uint16_t)(((uint16_t)r[0] << 3) | (r[1] >> 5));
        out->dlc = r[4] & 0x0Fu;
        memcpy(out->data, &r[5], 8u);
        m->rx_frames++;
        return 1;
    }
    return 0;
}

/* ---- errors ---- */

int32_t mcp2515_service(mcp2515_t *const m, const uint32_t now_ms)
{
    if (m == NULL) {
        return MCP2515_ERR_ARG;
    }
    uint8_t flags[2]; /* CANINTF, EFLG */
    int32_t rc = read_regs(m, REG_CANINTF, flags, sizeof flags);
    if (rc != MCP2515_OK) {
        return rc;
    }
    const uint8_t eflg = flags[1];
    if ((eflg & (EFLG_RX0OVR | EFLG_RX1OVR)) != 0u) {
        m->rx_overflows += (((eflg & EFLG_RX0OVR) != 0u) ? 1u : 0u) + (((eflg & EFLG_RX1OVR) != 0u) ? 1u : 0u);
        rc = bit_modify(m, REG_EFLG, EFLG_RX0OVR | EFLG_RX1OVR, 0u);
    }
    if (rc == MCP2515_OK && (flags[0] & (INT_ERR | INT_MERR)) != 0u) {
        rc = bit_modify(m, REG_CANINTF, INT_ERR | INT_MERR, 0u);
    }
    uint8_t counters[2];
    if (rc == MCP2515_OK) {
        rc = read_regs(m, REG_TEC, counters, sizeof counters);
    }
    if (rc != MCP2515_OK) {
        return rc;
    }
    m->tec = counters[0];
    m->rec = counters[1];
    const uint8_t before = m->state;
    if ((eflg & EFLG_TXBO) != 0u) {
        if (before != MCP2515_BUS_OFF) {
            m->state = MCP2515_BUS_OFF;
            m->bus_off_events++;
            m->bus_off_since_ms = now_ms;
            /* Drop what is pending: stale reports are worth less than fresh ones. */
            drop_queue(m);
            return bit_modify(m, REG_CANCTRL, CANCTRL_ABAT, CANCTRL_ABAT);
        }
        if ((uint32_t)(now_ms - m->bus_off_since_ms) >= MCP2515_BUSOFF_RESET_MS) {
            /* Still bus-off: start the controller over. */
            m->resets++;
            m->bus_off_since_ms = now_ms;
            rc = configure(m);
            if (rc != MCP2515_OK) {
                m->state = MCP2515_BUS_OFF;
            }
            return rc;
        }
        return MCP2515_OK;
    }
    if (before == MCP2515_BUS_OFF) {
        m->recoveries++; /* the chip has seen its 128 x 11 recessive bits */
        rc = bit_modify(m, REG_CANCTRL, CANCTRL_ABAT, 0u);
    }
    if ((eflg & (EFLG_TXEP | EFLG_RXEP)) != 0u) {
        if (m->state != MCP2515_ERROR_PASSIVE) {
            m->error_passive_events++;
        }
        m->state = MCP2515_ERROR_PASSIVE;
    } else {
        m->state = MCP2515_ERROR_ACTIVE;
    }
    return rc;
}
