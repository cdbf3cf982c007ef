#include "radio.h"

#include <string.h>

#include "cortexm.h"
#include "nrf52840.h"

#define Q_MASK (RADIO_QUEUE - 1u)
typedef char radio_queue_is_pow2[((RADIO_QUEUE & Q_MASK) == 0u) ? 1 : -1];

/* BLE (Core spec Vol 6 Part B 1.4.1, 2.3): channel 37 = 2402 MHz, 38 = 2426, 39 = 2480. */
#define BLE_CH_FIRST  37u
#define BLE_CH_LAST   39u
#define BLE_CRC_POLY  0x00065Bu
#define BLE_CRC_INIT  0x555555u
#define BLE_MAXLEN    255u
/* IEEE 802.15.4-2006 6.1.2.1: channel k (11..26) at 2405 + 5 (k - 11) MHz. */
#define IEEE_CH_FIRST 11u
#define IEEE_CH_LAST  26u
#define IEEE_CRC_POLY 0x011021u
#define IEEE_SFD      0xA7u
#define IEEE_MAXLEN   127u
#define IEEE_FCS_LEN  2u
#define IEEE_PHR_LEN_MASK 0x7Fu /* PHR: frame length in bits 0-6, bit 7 reserved */
#define DISABLE_SPINS 10000u

uint8_t radio_frequency(const radio_mode_t mode, const uint8_t channel)
{
    if (mode == RADIO_MODE_BLE) {
        switch (channel) {
        case 37u: return 2u;
        case 38u: return 26u;
        case 39u: return 80u;
        default: return 0xFFu;
        }
    }
    if (channel < IEEE_CH_FIRST || channel > IEEE_CH_LAST) {
        return 0xFFu;
    }
    return (uint8_t)(5u + 5u * (uint32_t)(channel - IEEE_CH_FIRST));
}

uint8_t radio_ble_next_channel(const uint8_t ch)
{
    return (ch >= BLE_CH_FIRST && ch < BLE_CH_LAST) ? (uint8_t)(ch + 1u) : (uint8_t)BLE_CH_FIRST;
}

int8_t radio_ieee802154_dbm(const uint8_t val)
{
    const int32_t dbm = RADIO_ED_RSSIOFFS + (int32_t)val;
    return (int8_t)((dbm > 126) ? 126 : dbm); /* 127 means "no RSSI" to the core */
}

uint8_t radio_ieee802154_lqi(const uint8_t val)
{
    const uint32_t lqi = (uint32_t)RADIO_ED_RSSISCALE * val;
    return (uint8_t)((lqi > 255u) ? 255u : lqi);
}

static void tune(radio_t *const r)
{
    if (r->mode == RADIO_MODE_BLE) {
        radio_ble_tune(r->channel);
    } else {
        NRF_RADIO->FREQUENCY = radio_frequency((radio_mode_t)r->mode, r->channel); /* MAP = 0 */
    }
}

static void clear_events(void)
{
    nrf_radio_t *const hw = NRF_RADIO;
    hw->EVENTS_READY = 0u;
    hw->EVENTS_ADDRESS = 0u;
    hw->EVENTS_END = 0u;
    hw->EVENTS_RSSIEND = 0u;
    hw->EVENTS_DISABLED = 0u;
    (void)hw->EVENTS_DISABLED; /* cleared before the interrupt returns */
}

/* Common start-up: radio off and on (a clean state), disabled, events clear. */
static void reset(radio_t *const r, const uint8_t mode, const uint8_t channel, const radio_hooks_t *const hooks)
{
    nrf_radio_t *const hw = NRF_RADIO;
    memset(r, 0, sizeof *r);
    r->mode = mode;
    r->channel = channel;
    if (hooks != NULL) {
        r->hooks = *hooks;
    }
    hw->POWER = 0u;
    hw->POWER = 1u;
    hw->INTENCLR = 0xFFFFFFFFu;
    hw->SHORTS = 0u;
    hw->TASKS_DISABLE = 1u;
    for (uint32_t i = 0u; i < DISABLE_SPINS && hw->STATE != NRF_RADIO_STATE_DISABLED; ++i) {
        NRF_SPIN();
    }
    clear_events();
    hw->MODECNF0 = NRF_RADIO_MODECNF0_RU_FAST; /* 40 us ramp-up instead of 140 */
    hw->PACKETPTR = NRF_DMA_ADDR(r->buf.bytes);
}

static void listen(void)
{
    nrf_radio_t *const hw = NRF_RADIO;
    hw->INTENSET = NRF_RADIO_INT_DISABLED;
    hw->TASKS_RXEN = 1u;
}

void radio_ble_configure(void)
{
    nrf_radio_t *const hw = NRF_RADIO;
    hw->MODE = NRF_RADIO_MODE_BLE_1MBIT;
    /* On-air: preamble 1 B, access address 4 B, PDU header (S0 = 1 B, LENGTH 8 bits),
     * payload, CRC 3 B. In RAM: header byte, length byte, payload. */
    hw->PCNF0 = NRF_RADIO_PCNF0_LFLEN(8u) | NRF_RADIO_PCNF0_S0LEN(1u) | NRF_RADIO_PCNF0_PLEN_8BIT;
    hw->PCNF1 = NRF_RADIO_PCNF1_MAXLEN(BLE_MAXLEN) | NRF_RADIO_PCNF1_BALEN(3u) | NRF_RADIO_PCNF1_WHITEEN;
    /* Access address = prefix (its top byte) + 3-byte base (BALEN), as logical address 0. */
    hw->BASE0 = RADIO_BLE_ACCESS_ADDRESS << 8;
    hw->PREFIX0 = RADIO_BLE_ACCESS_ADDRESS >> 24;
    hw->TXADDRESS = 0u;
    hw->RXADDRESSES = 1u;
    hw->CRCCNF = NRF_RADIO_CRCCNF_LEN(3u) | NRF_RADIO_CRCCNF_SKIPADDR_SKIP;
    hw->CRCPOLY = BLE_CRC_POLY;
    hw->CRCINIT = BLE_CRC_INIT;
}

void radio_ble_tune(const uint8_t channel)
{
    nrf_radio_t *const hw = NRF_RADIO;
    hw->FREQUENCY = radio_frequency(RADIO_MODE_BLE, channel); /* MAP = 0 */
    hw->DATAWHITEIV = channel; /* whitening seeded with the channel index */
}

void radio_start_ble(radio_t *const r, const radio_hooks_t *const hooks)
{
    nrf_radio_t *const hw = NRF_RADIO;
    reset(r, RADIO_MODE_BLE, BLE_CH_FIRST, hooks);
    radio_ble_configure();
    hw->SHORTS = NRF_RADIO_SHORT_READY_START | NRF_RADIO_SHORT_END_DISABLE | NRF_RADIO_SHORT_ADDRESS_RSSISTART
               | NRF_RADIO_SHORT_DISABLED_RSSISTOP;
    tune(r);
    listen();
}

int32_t radio_start_ieee802154(radio_t *const r, const uint8_t channel, const radio_hooks_t *const hooks)
{
    if (radio_frequency(RADIO_MODE_IEEE802154, channel) == 0xFFu) {
        return -1;
    }
    nrf_radio_t *const hw = NRF_RADIO;
    reset(r, RADIO_MODE_IEEE802154, channel, hooks);
    hw->MODE = NRF_RADIO_MODE_IEEE802154_250KBIT;
    /* 32-bit zero preamble, SFD, PHR (8-bit length including the 2-byte FCS). */
    hw->PCNF0 = NRF_RADIO_PCNF0_LFLEN(8u) | NRF_RADIO_PCNF0_PLEN_32BIT_ZERO | NRF_RADIO_PCNF0_CRCINC;
    hw->PCNF1 = NRF_RADIO_PCNF1_MAXLEN(IEEE_MAXLEN);
    hw->SFD = IEEE_SFD;
    hw->CRCCNF = NRF_RADIO_CRCCNF_LEN(2u) | NRF_RADIO_CRCCNF_SKIPADDR_IEEE;
    hw->CRCPOLY = IEEE_CRC_POLY;
    hw->CRCINIT = 0u;
    hw->SHORTS = NRF_RADIO_SHORT_READY_START | NRF_RADIO_SHORT_END_DISABLE;
    tune(r);
    listen();
    return 0;
}

/* The packet now in buf (CRC already checked) into *pkt; 0 if its length is malformed or
 * more than a queue slot holds. */
static int take_packet(const radio_t *const r, radio_packet_t *const pkt)
{
    nrf_radio_t *const hw = NRF_RADIO;
    const uint8_t *const b = r->buf.bytes;
    const uint8_t *src;
    size_t n;
    memset(pkt, 0, sizeof *pkt);
    pkt->mode = r->mode;
    pkt->channel = r->channel;
    if (r->mode == RADIO_MODE_BLE) {
        n = 2u + (size_t)b[1];              /* header + length byte + payload */
        src = b;
        pkt->rssi_dbm = (hw->EVENTS_RSSIEND != 0u) ? (int8_t)(-(int32_t)(hw->RSSISAMPLE & NRF_RADIO_RSSISAMPLE_MASK))
                                                   : (int8_t)RADIO_RSSI_NONE;
    } else {
        const size_t phr = (size_t)(b[0] & IEEE_PHR_LEN_MASK);
        if (phr <= IEEE_FCS_LEN) {
            return 0;
        }
        n = phr - IEEE_FCS_LEN;             /* MPDU without the FCS */
        src = &b[1];
        const uint8_t val = b[phr - 1u];    /* the LQI byte, in the first FCS byte's place */
        pkt->rssi_dbm = radio_ieee802154_dbm(val);
        pkt->lqi = radio_ieee802154_lqi(val);
    }
    if (n > RADIO_PKT_MAX) {
        return 0;
    }
    pkt->len = (uint8_t)n;
    memcpy(pkt->data, src, n);
    pkt->tick_ms = (r->hooks.now_ms != NULL) ? r->hooks.now_ms(r->hooks.ctx) : 0u;
    return 1;
}

/* The packet that ended: 1 when the accept hook took it (a hit, queued or not). */
static int on_end(radio_t *const r)
{
    if (NRF_RADIO->CRCSTATUS == 0u) {
        r->crc_errors = r->crc_errors + 1u;
        return 0;
    }
    r->packets = r->packets + 1u;
    const uint32_t head = r->q_head;
    radio_packet_t *const slot = &r->queue[head & Q_MASK];
    radio_packet_t pkt;
    if (take_packet(r, &pkt) == 0 || (r->hooks.accept != NULL && r->hooks.accept(&pkt, r->hooks.ctx) == 0)) {
        r->rejected = r->rejected + 1u;
        return 0;
    }
    if (head - r->q_tail >= RADIO_QUEUE) {
        r->queue_full = r->queue_full + 1u;
        return 1;
    }
    *slot = pkt;
    r->q_head = head + 1u;
    return 1;
}

/* The next transmission of the frame: BLE on tx_channel, 802.15.4 on the channel listened to. */
static void start_tx(radio_t *const r)
{
    nrf_radio_t *const hw = NRF_RADIO;
    const uint8_t ch = (r->mode == RADIO_MODE_BLE) ? r->tx_channel : r->channel;
    hw->PACKETPTR = NRF_DMA_ADDR(r->tx.bytes);
    hw->FREQUENCY = radio_frequency((radio_mode_t)r->mode, ch);
    if (r->mode == RADIO_MODE_BLE) {
        hw->DATAWHITEIV = ch;
    }
    r->txing = 1u;
    hw->TASKS_TXEN = 1u;
}

/* A transmission ended: the next channel's, or back to listening where the radio was. */
static void tx_done(radio_t *const r)
{
    nrf_radio_t *const hw = NRF_RADIO;
    r->txing = 0u;
    r->sent = r->sent + 1u;
    r->tx_left = (uint8_t)(r->tx_left - 1u);
    if (r->tx_left != 0u) {
        r->tx_channel = radio_ble_next_channel(r->tx_channel);
        start_tx(r);
        return;
    }
    hw->PACKETPTR = NRF_DMA_ADDR(r->buf.bytes);
    if (r->hop_pending != 0u) {
        r->hop_pending = 0u;
        r->channel = radio_ble_next_channel(r->channel);
        r->hops = r->hops + 1u;
    }
    tune(r);
    hw->TASKS_RXEN = 1u;
}

int32_t radio_send(radio_t *const r, const uint8_t *const frame, const size_t len)
{
    const int ble = r->mode == RADIO_MODE_BLE;
    if (frame == NULL || r->tx_left != 0u || NRF_RADIO->POWER == 0u
        || (ble ? (len < 2u || len > RADIO_TX_MAX || (size_t)frame[1] != len - 2u)
                : (len == 0u || len > RADIO_TX_MAX - 1u))) {
        return -1;
    }
    if (ble) {
        memcpy(r->tx.bytes, frame, len); /* S0 = header, LENGTH, payload: the PDU as it is */
        r->tx_channel = BLE_CH_FIRST;
    } else {
        r->tx.bytes[0] = (uint8_t)(len + IEEE_FCS_LEN); /* PHR: the length with the FCS */
        memcpy(&r->tx.bytes[1], frame, len);
    }
    /* Under PRIMASK: the RADIO interrupt must not start the frame between the flag and the
     * DISABLE below (a DISABLE during its ramp-up would cut it). */
    const uint32_t primask = cm_irq_save();
    r->tx_left = ble ? 3u : 1u;
    if (r->txing == 0u && NRF_RADIO->EVENTS_ADDRESS == 0u) {
        NRF_RADIO->TASKS_DISABLE = 1u; /* listening: stop now, the DISABLED interrupt sends */
    }
    cm_irq_restore(primask);
    return 0;
}

void radio_isr(radio_t *const r)
{
    nrf_radio_t *const hw = NRF_RADIO;
    if (hw->EVENTS_DISABLED == 0u) {
        return;
    }
    if (r->txing != 0u) {
        clear_events();
        tx_done(r);
        return;
    }
    int hit = 0;
    if (hw->EVENTS_END != 0u) {
        hit = on_end(r) && r->mode == RADIO_MODE_BLE; /* on the channel it was received on, before any hop */
    }
    clear_events();
    if (r->hop_pending != 0u || hit) {
        r->hop_pending = 0u;
        r->channel = radio_ble_next_channel(r->channel);
        r->hops = r->hops + 1u;
        tune(r);
    }
    if (r->tx_left != 0u) {
        start_tx(r); /* the frame radio_send handed over, then listening again (tx_done) */
    } else {
        hw->TASKS_RXEN = 1u;
    }
    if (hit) {
        /* After RXEN: the radio ramps up while the hook re-arms the dwell timer. */
        r->hit_hops = r->hit_hops + 1u;
        if (r->hooks.hopped != NULL) {
            r->hooks.hopped(r->hooks.ctx);
        }
    }
}

void radio_hop(radio_t *const r)
{
    nrf_radio_t *const hw = NRF_RADIO;
    if (r->mode != RADIO_MODE_BLE || r->hop_pending != 0u) {
        return;
    }
    r->hop_pending = 1u;
    if (r->txing != 0u || r->tx_left != 0u) {
        return; /* sending (or about to): the hop follows it (tx_done) */
    }
    /* Listening (no address yet): stop now; the DISABLED interrupt retunes. Receiving: the
     * packet's END disables the radio (END_DISABLE), and the hop follows it. */
    if (hw->EVENTS_ADDRESS == 0u) {
        hw->TASKS_DISABLE = 1u;
    }
}

int radio_pop(radio_t *const r, radio_packet_t *const out)
{
    const uint32_t tail = r->q_tail;
    if (tail == r->q_head) {
        return 0;
    }
    *out = r->queue[tail & Q_MASK];
    r->q_tail = tail + 1u;
    return 1;
}

int radio_pending(const radio_t *const r)
{
    return r->q_tail != r->q_head;
}
