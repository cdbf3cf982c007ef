#include "fake_mcp2515.h"

#include <string.h>

#include "fake_nrf.h"

#define CANSTAT 0x0Eu
#define CANCTRL 0x0Fu
#define TEC     0x1Cu
#define REC     0x1Du
#define CANINTE 0x2Bu
#define CANINTF 0x2Cu
#define EFLG    0x2Du
#define TXBCTRL(n) (0x30u + 0x10u * (n))
#define RXBCTRL(n) (0x60u + 0x10u * (n))
#define OPMOD_CONFIG 0x80u
#define OPMOD_NORMAL 0x00u
#define ABAT 0x10u
#define REG_ADDR_MASK 0x7Fu /* 128 registers (Table 11-1) */
#define TXREQ 0x08u
#define ABTF 0x40u

uint8_t fake_mcp_opmode(const fake_mcp_t *m)
{
    return m->reg[CANSTAT] & 0xE0u;
}

static void update_int(fake_mcp_t *m)
{
    const uint32_t bit = 1u << m->int_pin;
    if ((m->reg[CANINTF] & m->reg[CANINTE]) != 0u) {
        nrf_fake_p1.IN &= ~bit;
    } else {
        nrf_fake_p1.IN |= bit;
    }
}

static void power_on(fake_mcp_t *m)
{
    memset(m->reg, 0, sizeof m->reg);
    m->reg[CANSTAT] = OPMOD_CONFIG;
    m->reg[CANCTRL] = 0x87u; /* REQOP config, CLKEN, CLKPRE 1:8 */
    m->tec = 0;
    m->rec = 0;
    update_int(m);
}

void fake_mcp_init(fake_mcp_t *m, uint32_t int_pin)
{
    memset(m, 0, sizeof *m);
    m->int_pin = int_pin;
    power_on(m);
    nrf_fake.spi_device = fake_mcp_spi;
    nrf_fake.spi_ctx = m;
}

static int config_mode(const fake_mcp_t *m)
{
    return fake_mcp_opmode(m) == OPMOD_CONFIG;
}

/* One register write by WRITE / LOAD TX / BIT MODIFY, with the chip's write rules. */
static void write_reg(fake_mcp_t *m, uint8_t a, uint8_t v)
{
    a &= 0x7Fu;
    const uint8_t low = a & 0x0Fu;
    if (low == 0x0Eu) {
        return; /* CANSTAT is read-only at every mirror */
    }
    if (low == 0x0Fu) { /* CANCTRL (mirrored at x0F) */
        m->reg[CANCTRL] = v;
        if (!m->mode_stuck) {
            m->reg[CANSTAT] = (uint8_t)((m->reg[CANSTAT] & 0x1Fu) | (v & 0xE0u));
        }
        if ((v & ABAT) != 0u) {
            for (uint32_t b = 0u; b < 3u; ++b) {
                if ((m->reg[TXBCTRL(b)] & TXREQ) != 0u) {
                    m->reg[TXBCTRL(b)] = (uint8_t)((m->reg[TXBCTRL(b)] & ~TXREQ) | ABTF);
                    m->aborted++;
                }
            }
        }
        return;
    }
    if (a < 0x30u && !(a == CANINTE || a == CANINTF || a == EFLG)) {
        /* Filters, masks, CNF1..3: only in configuration mode (data sheet 11.1); TEC/REC
         * are read-only. */
        if (a == TEC || a == REC || !config_mode(m)) {
            return;
        }
    }
    if (a == EFLG) {
        v = (uint8_t)((m->reg[EFLG] & 0x3Fu) | (v & m->reg[EFLG] & 0xC0u)); /* only RXnOVR clear */
    }
    if (a == TXBCTRL(0) || a == TXBCTRL(1) || a == TXBCTRL(2)) {
        v = (uint8_t)((m->reg[a] & 0x70u) | (v & 0x0Bu)); /* TXREQ and TXP writable */
        if ((m->reg[CANCTRL] & ABAT) != 0u) {
            v &= (uint8_t)~TXREQ;
        }
    }
    m->reg[a] = v;
}

static uint8_t status_byte(const fake_mcp_t *m)
{
    const uint8_t f = m->reg[CANINTF];
    return (uint8_t)((f & 0x03u) | ((m->reg[TXBCTRL(0)] & TXREQ) ? 0x04u : 0u) | ((f & 0x04u) ? 0x08u : 0u)
                     | ((m->reg[TXBCTRL(1)] & TXREQ) ? 0x10u : 0u) | ((f & 0x08u) ? 0x20u : 0u)
                     | ((m->reg[TXBCTRL(2)] & TXREQ) ? 0x40u : 0u) | ((f & 0x10u) ? 0x80u : 0u));
}

void fake_mcp_spi(const uint8_t *tx, uint8_t *rx, size_t len, void *ctx)
{
    fake_mcp_t *const m = ctx;
    memset(rx, 0xFF, len);
    if (m->absent || len == 0u) {
        return;
    }
    m->instructions++;
    const uint8_t ins = tx[0];
    if (ins == 0xC0u) {
        m->resets++;
        power_on(m);
    } else if (ins == 0x03u && len >= 2u) {
        for (size_t i = 2u; i < len; ++i) {
            rx[i] = m->reg[(tx[1] + (i - 2u)) & REG_ADDR_MASK];
        }
    } else if (ins == 0x02u && len >= 2u) {
        for (size_t i = 2u; i < len; ++i) {
            write_reg(m, (uint8_t)(tx[1] + (i - 2u)), tx[i]);
        }
    } else if (ins == 0x05u && len >= 4u) {
        const uint8_t a = tx[1] & REG_ADDR_MASK;
        /* BIT MODIFY works on the bit-modifiable registers only; others take a WRITE of
         * 0xFF mask (data sheet 12.10). */
        write_reg(m, a, (uint8_t)((m->reg[a] & ~tx[2]) | (tx[3] & tx[2])));
    } else if (ins == 0xA0u) {
        for (size_t i = 1u; i < len; ++i) {
            rx[i] = status_byte(m);
        }
    } else if ((ins & 0xF9u) == 0x90u) {
        const uint32_t n = (ins >> 2) & 1u;
        const uint32_t start = RXBCTRL(n) + 1u + (((ins >> 1) & 1u) ? 5u : 0u);
        for (size_t i = 1u; i < len; ++i) {
            rx[i] = m->reg[(start + (i - 1u)) & REG_ADDR_MASK];
        }
        m->reg[CANINTF] &= (uint8_t)~(1u << n); /* cleared when CS rises */
    } else if ((ins & 0xF8u) == 0x80u) {
        for (uint32_t b = 0u; b < 3u; ++b) {
            if ((ins & (1u << b)) != 0u && (m->reg[CANCTRL] & ABAT) == 0u) {
                m->reg[TXBCTRL(b)] |= TXREQ;
            }
        }
    } else if ((ins & 0xF8u) == 0x40u) {
        const uint32_t b = (ins >> 1) & 3u;
        const uint32_t start = TXBCTRL(b) + 1u + ((ins & 1u) ? 5u : 0u);
        for (size_t i = 1u; i < len; ++i) {
            write_reg(m, (uint8_t)(start + (i - 1u)), tx[i]);
        }
    }
    update_int(m);
}

/* Data sheet 4.5: a standard frame matches filter f under mask k when every mask bit
 * agrees; a filter with EXIDE = 1 takes extended frames only. */
static int matches(const fake_mcp_t *m, uint32_t f, uint32_t k, uint16_t id, int extended)
{
    static const uint8_t faddr[6] = { 0x00u, 0x04u, 0x08u, 0x10u, 0x14u, 0x18u };
    const uint8_t *fr = &m->reg[faddr[f]];
    const uint8_t *mr = &m->reg[0x20u + 4u * k];
    if (((fr[1] & 0x08u) != 0u) != (extended != 0)) {
        return 0;
    }
    const uint16_t fid = (uint16_t)((fr[0] << 3) | (fr[1] >> 5));
    const uint16_t mid = (uint16_t)((mr[0] << 3) | (mr[1] >> 5));
    return ((fid ^ id) & mid) == 0u;
}

static void store(fake_mcp_t *m, uint32_t n, uint16_t id, int extended, int remote, uint8_t dlc, const uint8_t *data)
{
    uint8_t *const r = &m->reg[RXBCTRL(n) + 1u];
    r[0] = (uint8_t)(id >> 3);
    r[1] = (uint8_t)(((id & 7u) << 5) | (extended ? 0x08u : 0u) | ((remote && !extended) ? 0x10u : 0u));
    r[2] = 0u;
    r[3] = 0u;
    r[4] = (uint8_t)((dlc & 0x0Fu) | ((remote && extended) ? 0x40u : 0u));
    memset(&r[5], 0, 8u);
    memcpy(&r[5], data, (dlc > 8u) ? 8u : dlc);
    m->reg[CANINTF] |= (uint8_t)(1u << n);
}

int fake_mcp_bus_frame(fake_mcp_t *m, uint16_t id, int extended, int remote, uint8_t dlc, const uint8_t *data)
{
    if (fake_mcp_opmode(m) != OPMOD_NORMAL) {
        return -1;
    }
    const int rxm0_any = (m->reg[RXBCTRL(0)] & 0x60u) == 0x60u;
    const int rxm1_any = (m->reg[RXBCTRL(1)] & 0x60u) == 0x60u;
    const int hit0 = rxm0_any || matches(m, 0u, 0u, id, extended) || matches(m, 1u, 0u, id, extended);
    int hit1 = rxm1_any;
    for (uint32_t f = 2u; f < 6u; ++f) {
        hit1 = hit1 || matches(m, f, 1u, id, extended);
    }
    int rc = -1;
    if (hit0) {
        if ((m->reg[CANINTF] & 1u) == 0u) {
            store(m, 0u, id, extended, remote, dlc, data);
            rc = 0;
        } else if ((m->reg[RXBCTRL(0)] & 0x04u) != 0u && (m->reg[CANINTF] & 2u) == 0u) {
            store(m, 1u, id, extended, remote, dlc, data); /* BUKT rollover */
            rc = 1;
        } else {
            m->reg[EFLG] |= 0x40u;
            m->reg[CANINTF] |= 0x20u;
            rc = -2;
        }
    } else if (hit1) {
        if ((m->reg[CANINTF] & 2u) == 0u) {
            store(m, 1u, id, extended, remote, dlc, data);
            rc = 1;
        } else {
            m->reg[EFLG] |= 0x80u;
            m->reg[CANINTF] |= 0x20u;
            rc = -2;
        }
    }
    update_int(m);
    return rc;
}

uint32_t fake_mcp_bus_run(fake_mcp_t *m, uint32_t n)
{
    uint32_t sent = 0u;
    while (sent < n && fake_mcp_opmode(m) == OPMOD_NORMAL && (m->reg[EFLG] & 0x20u) == 0u) {
        int best = -1;
        for (uint32_t b = 0u; b < 3u; ++b) {
            const uint8_t c = m->reg[TXBCTRL(b)];
            if ((c & TXREQ) == 0u) {
                continue;
            }
            /* Highest TXP first; among equal TXP the higher buffer number (data sheet 3.2). */
            if (best < 0 || (c & 3u) >= (m->reg[TXBCTRL((uint32_t)best)] & 3u)) {
                best = (int)b;
            }
        }
        if (best < 0 || m->n_sent >= FAKE_MCP_LOG) {
            break;
        }
        const uint8_t *const t = &m->reg[TXBCTRL((uint32_t)best) + 1u];
        fake_mcp_frame_t *const f = &m->sent[m->n_sent++];
        f->id = (uint16_t)((t[0] << 3) | (t[1] >> 5));
        f->dlc = t[4] & 0x0Fu;
        memcpy(f->data, &t[5], 8u);
        f->buffer = (uint8_t)best;
        m->reg[TXBCTRL((uint32_t)best)] &= (uint8_t)~TXREQ;
        m->reg[CANINTF] |= (uint8_t)(0x04u << best);
        ++sent;
    }
    update_int(m);
    return sent;
}

void fake_mcp_set_errors(fake_mcp_t *m, int tec, int rec)
{
    m->tec = tec;
    m->rec = rec;
    m->reg[TEC] = (uint8_t)((tec > 255) ? 255 : tec);
    m->reg[REC] = (uint8_t)((rec > 255) ? 255 : rec);
    uint8_t e = m->reg[EFLG] & 0xC0u;
    e |= (tec >= 96 || rec >= 96) ? 0x01u : 0u;  /* EWARN */
    e |= (rec >= 96) ? 0x02u : 0u;               /* RXWAR */
    e |= (tec >= 96) ? 0x04u : 0u;               /* TXWAR */
    e |= (rec >= 128) ? 0x08u : 0u;              /* RXEP */
    e |= (tec >= 128) ? 0x10u : 0u;              /* TXEP */
    e |= (tec > 255) ? 0x20u : 0u;               /* TXBO */
    if (e != m->reg[EFLG]) {
        m->reg[CANINTF] |= 0x20u; /* ERRIF */
    }
    m->reg[EFLG] = e;
    update_int(m);
}

void fake_mcp_bus_off_recovered(fake_mcp_t *m)
{
    fake_mcp_set_errors(m, 0, 0);
}
