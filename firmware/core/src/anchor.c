/* The anchor instance: events, reporting, configuration, status. See pfdoa_anchor.h. */
#include "pfdoa_anchor.h"

#include <string.h>

#include "pfdoa_le.h"

/* Host-to-anchor types this anchor handles; everything else is unknown_type. */
static const uint8_t anchor_rx_types[] = {
    PFDOA_MSG_CONFIG_SET,
    PFDOA_MSG_FILTER_SET,
#ifdef PFDOA_SIL_INJECT
    PFDOA_MSG_RADIO_INJECT,
    PFDOA_MSG_RADIO_INJECT_RAW,
#endif
};

static void sat_inc(uint16_t *const counter)
{
    if (*counter < UINT16_MAX) {
        (*counter)++;
    }
}

static int addressed_to(const pfdoa_anchor_t *const a, const uint8_t anchor_id)
{
    return (anchor_id == a->anchor_id) || (anchor_id == PFDOA_ANCHOR_BROADCAST);
}

static void count_rx_error(pfdoa_anchor_t *const a, const int32_t err)
{
    sat_inc(&a->rx_errors);
    if ((err < 0) && (err >= -PFDOA_ERR_COUNT)) {
        sat_inc(&a->rx_error_kind[(-err) - 1]);
    }
}

static void tx_result(pfdoa_anchor_t *const a, const int32_t rc)
{
    if (rc < 0) {
        a->tx_failures++;
    }
}

static void send_uart(pfdoa_anchor_t *const a, const uint8_t type, const uint8_t *const payload, const size_t len)
{
    if (a->hal.uart_write != NULL) {
        uint8_t wire[PFDOA_FRAME_WIRE_MAX];
        const int32_t n = pfdoa_frame_encode(type, a->anchor_id, payload, len, wire, sizeof wire);
        tx_result(a, (n > 0) ? a->hal.uart_write(a->hal.ctx, wire, (size_t)n) : n);
    }
}

static void send_can(pfdoa_anchor_t *const a, const pfdoa_can_frame_t *const f)
{
    if (a->hal.can_send != NULL) {
        tx_result(a, a->hal.can_send(a->hal.ctx, f->id, f->data, f->dlc));
    }
}

static int uart_enabled(const pfdoa_anchor_t *const a)
{
    return (a->transports & PFDOA_TRANSPORT_UART) != 0u;
}

static int can_enabled(const pfdoa_anchor_t *const a)
{
    return (a->transports & PFDOA_TRANSPORT_CAN) != 0u;
}

/* An AUTH_REPORT is an RSSI_REPORT's fields followed by the counter and the tag. */
typedef char auth_report_extends_rssi_report[(PFDOA_MSG_AUTH_REPORT_OFF_COUNTER == PFDOA_MSG_RSSI_REPORT_LEN) ? 1 : -1];

/* A report; a PFDOA_AUTH entry's (slot s) is an AUTH_REPORT on the UART (SPEC 9.5). */
static void send_report(pfdoa_anchor_t *const a, const pfdoa_rssi_report_t *const r, const pfdoa_slot_t *const s)
{
    uint8_t payload[PFDOA_MSG_AUTH_REPORT_LEN];
    pfdoa_msg_pack_rssi_report(r, payload);
    if (uart_enabled(a)) {
        if (s != NULL) {
            pfdoa_put_u32(&payload[PFDOA_MSG_AUTH_REPORT_OFF_COUNTER], s->ev_counter);
            (void)memcpy(&payload[PFDOA_MSG_AUTH_REPORT_OFF_TAG], s->ev_tag, PFDOA_AUTH_TAG_LEN);
            send_uart(a, PFDOA_MSG_AUTH_REPORT, payload, PFDOA_MSG_AUTH_REPORT_LEN);
        } else {
            send_uart(a, PFDOA_MSG_RSSI_REPORT, payload, PFDOA_MSG_RSSI_REPORT_LEN);
        }
    }
    if (can_enabled(a)) {
        pfdoa_can_frame_t f;
        pfdoa_can_encode_rssi_report(r, a->anchor_id, &f);
        send_can(a, &f);
    }
    a->reports_sent++;
}

static int has_auth_entry(const pfdoa_anchor_t *const a)
{
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        if (a->filters[i].kind == PFDOA_FILTER_PFDOA_AUTH) {
            return 1;
        }
    }
    return 0;
}

static void send_status(pfdoa_anchor_t *const a, const uint32_t tick_ms)
{
    pfdoa_status_t s;
    s.fw_major = PFDOA_FW_MAJOR;
    s.fw_minor = PFDOA_FW_MINOR;
    s.uptime_s = (uint32_t)(tick_ms - a->boot_tick) / 1000u;
    s.config_hash = a->config_hash;
    s.dropped_events = a->dropped_events;
    s.rx_errors = a->rx_errors;
    s.spikes = a->spikes;
    s.defs_hash = PFDOA_DEFS_HASH;
    s.filter_hash = a->filter_hash;
    s.filter_slots = PFDOA_BEACON_SLOTS;
    uint8_t payload[PFDOA_MSG_STATUS_LEN];
    pfdoa_msg_pack_status(&s, payload);
    if (uart_enabled(a)) {
        send_uart(a, PFDOA_MSG_STATUS, payload, sizeof payload);
    }
    if (can_enabled(a)) {
        pfdoa_can_frame_t f;
        pfdoa_can_encode_status_a(&s, a->anchor_id, &f);
        send_can(a, &f);
        pfdoa_can_encode_status_b(&s, a->anchor_id, &f);
        send_can(a, &f);
        pfdoa_can_encode_status_c(&s, a->anchor_id, &f);
        send_can(a, &f);
    }
    if (uart_enabled(a) && has_auth_entry(a)) {
        /* SPEC 9.5: the rejections of the PFDOA_AUTH entries' advertisements, UART only. */
        uint8_t auth[PFDOA_MSG_AUTH_STATUS_LEN];
        pfdoa_put_u16(&auth[PFDOA_MSG_AUTH_STATUS_OFF_AUTH_BAD_TAG], a->auth_rejected[0]);
        pfdoa_put_u16(&auth[PFDOA_MSG_AUTH_STATUS_OFF_AUTH_STALE], a->auth_rejected[1]);
        pfdoa_put_u16(&auth[PFDOA_MSG_AUTH_STATUS_OFF_AUTH_REPLAYED], a->auth_rejected[2]);
        send_uart(a, PFDOA_MSG_AUTH_STATUS, auth, sizeof auth);
    }
}

/* The ack goes out on the transport its CONFIG_SET came from (SPEC 3 Configuration). */
static void send_ack(pfdoa_anchor_t *const a, const uint8_t token, const uint8_t result, const uint8_t via)
{
    pfdoa_config_ack_t ack;
    ack.token = token;
    ack.result = result;
    ack.config_hash = a->config_hash;
    if (via == PFDOA_TRANSPORT_UART) {
        uint8_t payload[PFDOA_MSG_CONFIG_ACK_LEN];
        pfdoa_msg_pack_config_ack(&ack, payload);
        send_uart(a, PFDOA_MSG_CONFIG_ACK, payload, sizeof payload);
    } else {
        pfdoa_can_frame_t f;
        pfdoa_can_encode_config_ack(&ack, a->anchor_id, &f);
        send_can(a, &f);
    }
}

static void close_event(pfdoa_anchor_t *const a, const size_t index, const uint32_t tick_ms)
{
    pfdoa_slot_t *const s = &a->slots[index];
    pfdoa_rssi_report_t r;
    const int32_t rc = pfdoa_filter_close_event(&s->filter, &a->config, &s->event, tick_ms, &r);
    s->event.n = 0u;
    if (rc < 0) {
        return; /* no open event: nothing to close */
    }
    if (rc == 1) {
        sat_inc(&a->spikes);
    }
    r.beacon = (uint8_t)index;
    const pfdoa_slot_t *const auth = (a->filters[index].kind == PFDOA_FILTER_PFDOA_AUTH) ? s : NULL;
    if (a->config.report_mode == PFDOA_REPORT_EVERY) {
        send_report(a, &r, auth);
    } else if (a->config.report_mode == PFDOA_REPORT_DECIMATE) {
        /* The counter and accumulator exist only in mode 1 (SPEC 3.4 Reporting), per entry. */
        s->pending_flags = (uint8_t)(s->pending_flags | r.flags);
        s->decim_count++;
        if (s->decim_count >= a->config.decimation) {
            r.flags = s->pending_flags;
            s->pending_flags = 0u;
            s->decim_count = 0u;
            send_report(a, &r, auth);
        }
    } else {
        /* silent: status only */
    }
}

static uint8_t event_has_seq(const pfdoa_event_t *const ev)
{
    return ((ev->flags & PFDOA_FLAG_NO_SEQ) == 0u) ? 1u : 0u;
}

static int reading_valid(const int8_t rssi_dbm, const uint8_t channel, const uint8_t radio)
{
    if (rssi_dbm == PFDOA_RSSI_INVALID) {
        return 0;
    }
    if (radio == PFDOA_RADIO_BLE) {
        return channel <= PFDOA_CHANNEL_BLE_MAX;
    }
    if (radio == PFDOA_RADIO_IEEE802154) {
        return (channel >= PFDOA_CHANNEL_IEEE802154_MIN) && (channel <= PFDOA_CHANNEL_IEEE802154_MAX);
    }
    return 0;
}

/* A peer reading (SPEC 3.5): one report of its own, calibrated, not filtered. Taken from
 * the reception itself, without a pfdoa_radio_reading_t: the raw entry points' path to a
 * beacon's report is the deepest stack (firmware/README.md), and this keeps it as it was. */
static int32_t take_peer(pfdoa_anchor_t *const a, const pfdoa_match_t *const m, const pfdoa_rx_t *const rx,
                         const uint8_t radio)
{
    if (m->peer == a->anchor_id) {
        return 0; /* another anchor with our id: not a peer, ignored */
    }
    if (reading_valid(rx->rssi_dbm, rx->channel, radio) == 0) {
        sat_inc(&a->dropped_events);
        return PFDOA_ERR_ARG;
    }
    pfdoa_rssi_report_t rep;
    rep.flags = (radio == PFDOA_RADIO_IEEE802154) ? (uint8_t)PFDOA_FLAG_ZIGBEE : 0u;
    rep.raw_dbm = pfdoa_clamp_dbm(rx->rssi_dbm, &rep.flags);
    int32_t q8 = (256 * (int32_t)rep.raw_dbm) + a->config.offset_q8;
    if ((q8 > INT16_MAX) || (q8 < INT16_MIN)) {
        q8 = (q8 > INT16_MAX) ? INT16_MAX : INT16_MIN;
        rep.flags |= PFDOA_FLAG_SATURATED;
    }
    if (a->config.offset_q8 != 0) {
        rep.flags |= PFDOA_FLAG_CALIBRATED;
    }
    rep.seq = m->seq;
    rep.tick_ms = rx->tick_ms;
    rep.rssi_q8 = (int16_t)q8;
    rep.n_readings = 1u;
    rep.channel = rx->channel;
    rep.beacon = (uint8_t)(PFDOA_PEER_BEACON_BASE + m->peer);
    if (a->config.report_mode != PFDOA_REPORT_SILENT) {
        send_report(a, &rep, NULL);
    }
    return 1;
}

/* Sends the anchor's own advertisement when it is due (SPEC 3.5): the first ANCHORS entry's period. */
static void poll_peer(pfdoa_anchor_t *const a, const uint32_t tick_ms)
{
    if (a->peer_radio.send == NULL) {
        return;
    }
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        if (a->filters[i].kind == PFDOA_FILTER_ANCHORS) {
            if ((a->peer_sent == 0u) || ((uint32_t)(tick_ms - a->peer_tick) >= a->filters[i].period_ms)) {
                uint8_t frame[PFDOA_PEER_FRAME_MAX];
                const int32_t n = pfdoa_peer_frame(a->peer_radio.radio, a->peer_radio.address, a->anchor_id,
                                                   a->peer_seq, frame, sizeof frame);
                tx_result(a, (n > 0) ? a->peer_radio.send(a->peer_radio.ctx, frame, (size_t)n) : n);
                a->peer_sent = 1u;
                a->peer_tick = tick_ms;
                a->peer_seq++;
            }
            return;
        }
    }
}

/* One reading of filter entry `index` (SPEC 3.4 Readings and Events); r->seq is ignored
 * when has_seq is 0 (the entry numbers its events itself). A PFDOA_AUTH entry's reading is
 * its verified advertisement (the slot's `verified`): its counter is part of the event's
 * identity (only verify_auth makes readings of such an entry). */
static int32_t take_reading(pfdoa_anchor_t *const a, const size_t index, const uint8_t has_seq,
                            const pfdoa_radio_reading_t *const r)
{
    if (reading_valid(r->rssi_dbm, r->channel, r->radio) == 0) {
        sat_inc(&a->dropped_events);
        return PFDOA_ERR_ARG;
    }
    pfdoa_slot_t *const s = &a->slots[index];
    pfdoa_event_t *const ev = &s->event;
    const pfdoa_auth_verdict_t *const auth =
        (a->filters[index].kind == PFDOA_FILTER_PFDOA_AUTH) ? &s->verified : NULL;
    if ((ev->n > 0u) &&
        ((ev->radio != r->radio) || (event_has_seq(ev) != has_seq) ||
         ((auth != NULL) && (s->ev_counter != auth->counter)) ||
         ((has_seq != 0u) ? (ev->seq != r->seq)
                          : ((uint32_t)(r->tick_ms - ev->first_tick) >= a->filters[index].period_ms)))) {
        close_event(a, index, r->tick_ms);
    }
    if (ev->n == 0u) {
        if (auth != NULL) {
            s->ev_counter = auth->counter;
            (void)memcpy(s->ev_tag, auth->tag, PFDOA_AUTH_TAG_LEN);
        }
        pfdoa_radio_reading_t first = *r;
        if (has_seq == 0u) {
            first.seq = s->noseq_next;
            s->noseq_next++;
        }
        pfdoa_event_open(ev, &first);
        if (has_seq == 0u) {
            ev->flags |= PFDOA_FLAG_NO_SEQ;
        }
    } else {
        pfdoa_event_add(ev, r);
    }
    if ((ev->radio == PFDOA_RADIO_IEEE802154) || (ev->n >= PFDOA_BLE_EVENT_MAX_READINGS)) {
        close_event(a, index, r->tick_ms);
    }
    return PFDOA_OK;
}

/* Applies a CONFIG_SET payload (already checked to be addressed here) and acks it. */
static void handle_config_set(pfdoa_anchor_t *const a, const uint8_t payload[PFDOA_MSG_CONFIG_SET_LEN],
                              const uint8_t via)
{
    uint8_t token = 0u;
    pfdoa_config_t cfg;
    uint8_t result = PFDOA_ACK_INVALID;
    if (pfdoa_msg_unpack_config_set(payload, &token, &cfg) == PFDOA_OK) {
        /* Whole configuration at once; the filter state of every entry is kept. */
        a->config = cfg;
        for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
            a->slots[i].decim_count = 0u;
            a->slots[i].pending_flags = 0u;
        }
        a->config_hash = pfdoa_config_hash(&cfg);
        uint8_t stored[PFDOA_CONFIG_LEN];
        pfdoa_config_pack(&cfg, stored);
        result = ((a->hal.config_store != NULL) && (a->hal.config_store(a->hal.ctx, stored) >= 0))
                     ? (uint8_t)PFDOA_ACK_OK
                     : (uint8_t)PFDOA_ACK_STORE_FAILED;
    }
    send_ack(a, token, result, via);
}

/* Replaces filter entry `index` (SPEC 3.4 Filter entries); returns the FILTER_ACK result. */
static uint8_t apply_filter(pfdoa_anchor_t *const a, const uint8_t index, const pfdoa_beacon_filter_t *const f)
{
    if ((index >= PFDOA_BEACON_SLOTS) || (pfdoa_beacon_filter_validate(f) != PFDOA_OK)) {
        return PFDOA_ACK_INVALID;
    }
    a->filters[index] = *f;
    (void)memset(&a->slots[index], 0, sizeof a->slots[index]); /* a new beacon starts afresh */
    if (f->kind == PFDOA_FILTER_PFDOA_AUTH) {
        pfdoa_auth_state_init(&a->slots[index].auth, f->match);
    }
    a->peer_sent = 0u; /* the advertisement's schedule restarts (SPEC 3.5) */
    a->filter_hash = pfdoa_beacon_filters_hash(a->filters);
    uint8_t table[PFDOA_FILTER_TABLE_LEN];
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        pfdoa_beacon_filter_pack(&a->filters[i], &table[i * PFDOA_FILTER_ENTRY_LEN]);
    }
    const pfdoa_filter_storage_t *const st = &a->filter_storage;
    return ((st->store != NULL) && (st->store(st->ctx, table) >= 0))
               ? (uint8_t)PFDOA_ACK_OK
               : (uint8_t)PFDOA_ACK_STORE_FAILED;
}

/* A FILTER_SET payload addressed here: apply and ack on the UART (its only transport). */
static void handle_filter_set(pfdoa_anchor_t *const a, const uint8_t payload[PFDOA_MSG_FILTER_SET_LEN])
{
    pfdoa_filter_ack_t ack;
    pfdoa_beacon_filter_t f;
    (void)pfdoa_msg_unpack_filter_set(payload, &ack.token, &ack.index, &f);
    ack.result = apply_filter(a, ack.index, &f);
    ack.filter_hash = a->filter_hash;
    uint8_t out[PFDOA_MSG_FILTER_ACK_LEN];
    pfdoa_msg_pack_filter_ack(&ack, out);
    send_uart(a, PFDOA_MSG_FILTER_ACK, out, sizeof out);
}

/* The stored table replaces the active one if every entry is valid (SPEC 3.1). Checked
 * entry by entry in place (one entry on the stack, not a second table: the key schedules
 * below need the stack). */
static void load_filters(pfdoa_anchor_t *const a)
{
    const pfdoa_filter_storage_t *const st = &a->filter_storage;
    uint8_t table[PFDOA_FILTER_TABLE_LEN];
    if ((st->load == NULL) || (st->load(st->ctx, table) < 0)) {
        return;
    }
    int valid = 1;
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        pfdoa_beacon_filter_t f;
        pfdoa_beacon_filter_unpack(&table[i * PFDOA_FILTER_ENTRY_LEN], &f);
        if (pfdoa_beacon_filter_validate(&f) != PFDOA_OK) {
            valid = 0;
        }
    }
    if (valid != 0) {
        (void)memset(a->slots, 0, sizeof a->slots); /* new beacons start afresh */
        for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
            pfdoa_beacon_filter_unpack(&table[i * PFDOA_FILTER_ENTRY_LEN], &a->filters[i]);
            if (a->filters[i].kind == PFDOA_FILTER_PFDOA_AUTH) {
                pfdoa_auth_state_init(&a->slots[i].auth, a->filters[i].match);
            }
        }
        a->peer_sent = 0u;
        a->filter_hash = pfdoa_beacon_filters_hash(a->filters);
    }
    (void)memset(table, 0, sizeof table); /* keys do not linger on the stack */
}

int32_t pfdoa_anchor_use_filter_storage(pfdoa_anchor_t *const anchor, const pfdoa_filter_storage_t *const storage)
{
    if (anchor == NULL) {
        return PFDOA_ERR_ARG;
    }
    if (storage != NULL) {
        anchor->filter_storage = *storage;
        load_filters(anchor);
    } else {
        (void)memset(&anchor->filter_storage, 0, sizeof anchor->filter_storage);
    }
    return PFDOA_OK;
}

int32_t pfdoa_anchor_use_peer_radio(pfdoa_anchor_t *const anchor, const pfdoa_peer_radio_t *const radio)
{
    if ((anchor == NULL) ||
        ((radio != NULL) && (radio->radio != PFDOA_RADIO_BLE) && (radio->radio != PFDOA_RADIO_IEEE802154))) {
        return PFDOA_ERR_ARG;
    }
    if (radio != NULL) {
        anchor->peer_radio = *radio;
    } else {
        (void)memset(&anchor->peer_radio, 0, sizeof anchor->peer_radio);
    }
    return PFDOA_OK;
}

size_t pfdoa_anchor_sizeof(void)
{
    return sizeof(pfdoa_anchor_t);
}

int32_t pfdoa_anchor_init(pfdoa_anchor_t *const anchor, const pfdoa_hal_t *const hal, const uint8_t anchor_id,
                          const uint8_t transports)
{
    if ((anchor == NULL) || (anchor_id > PFDOA_ANCHOR_ID_MAX) || (transports == 0u) ||
        ((transports & (uint8_t)~(PFDOA_TRANSPORT_UART | PFDOA_TRANSPORT_CAN)) != 0u)) {
        return PFDOA_ERR_ARG;
    }
    (void)memset(anchor, 0, sizeof *anchor);
    if (hal != NULL) {
        anchor->hal = *hal;
    }
    anchor->anchor_id = anchor_id;
    anchor->transports = transports;
    pfdoa_decoder_init(&anchor->decoder, anchor_rx_types, sizeof anchor_rx_types);
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        pfdoa_filter_init(&anchor->slots[i].filter);
    }
    pfdoa_beacon_filters_default(anchor->filters);
    anchor->filter_hash = pfdoa_beacon_filters_hash(anchor->filters);
    pfdoa_config_defaults(&anchor->config);
    if (anchor->hal.config_load != NULL) {
        uint8_t stored[PFDOA_CONFIG_LEN];
        if (anchor->hal.config_load(anchor->hal.ctx, stored) >= 0) {
            /* An invalid stored configuration leaves the defaults in place. */
            (void)pfdoa_config_unpack(stored, &anchor->config);
        }
    }
    anchor->config_hash = pfdoa_config_hash(&anchor->config);
    anchor->boot_tick = (anchor->hal.tick_ms != NULL) ? anchor->hal.tick_ms(anchor->hal.ctx) : 0u;
    anchor->last_status_tick = anchor->boot_tick;
    return PFDOA_OK;
}

int32_t pfdoa_anchor_on_radio(pfdoa_anchor_t *const anchor, const pfdoa_radio_reading_t *const reading)
{
    if ((anchor == NULL) || (reading == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (anchor->filters[0].kind == PFDOA_FILTER_PFDOA_AUTH) {
        /* SPEC 9.4: a board cannot vouch for an authenticated beacon: dropped, counted. */
        sat_inc(&anchor->dropped_events);
        return PFDOA_ERR_ARG;
    }
    return take_reading(anchor, 0u, 1u, reading); /* the board matched our beacon: entry 0 */
}

/* A matched (rc 1) reception becomes a reading of its entry; a PFDOA_AUTH entry's carries
 * its verified advertisement (the slot's `verified`). */
static int32_t take_match(pfdoa_anchor_t *const a, const int32_t rc, const pfdoa_match_t *const m,
                          const pfdoa_rx_t *const rx, const uint8_t radio)
{
    if (rc <= 0) {
        return rc;
    }
    if (m->peer != PFDOA_ANCHOR_BROADCAST) {
        return take_peer(a, m, rx, radio);
    }
    pfdoa_radio_reading_t r;
    r.tick_ms = rx->tick_ms;
    r.seq = m->seq;
    r.rssi_dbm = rx->rssi_dbm;
    r.channel = rx->channel;
    r.lqi = rx->lqi;
    r.radio = radio;
    return (take_reading(a, m->index, m->has_seq, &r) == PFDOA_OK) ? 1 : PFDOA_ERR_ARG;
}

/* verify_auth's answer when no PFDOA_AUTH entry claims the payload. */
#define AUTH_UNCLAIMED 2

/* Our authenticated beacon's payload (SPEC 9.4), offered to the PFDOA_AUTH entries in index
 * order: the first whose rolling identifier it carries decides. 1 accepted (*m names the
 * entry; its slot's `verified` holds what was verified), 0 rejected (counted),
 * AUTH_UNCLAIMED. */
static int32_t verify_auth(pfdoa_anchor_t *const a, const uint8_t *const payload, const uint32_t tick_ms,
                           pfdoa_match_t *const m)
{
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        if (a->filters[i].kind != PFDOA_FILTER_PFDOA_AUTH) {
            continue;
        }
        pfdoa_slot_t *const s = &a->slots[i];
        const int32_t res = pfdoa_auth_verify(&s->auth, payload, tick_ms, &s->verified);
        if (res == PFDOA_AUTH_ACCEPT) {
            m->index = (uint8_t)i;
            m->has_seq = 1u;
            m->seq = s->verified.seq;
            m->peer = PFDOA_ANCHOR_BROADCAST;
            return 1;
        }
        if ((res >= PFDOA_AUTH_BAD_TAG) && (res <= PFDOA_AUTH_REPLAYED)) {
            sat_inc(&a->auth_rejected[res - PFDOA_AUTH_BAD_TAG]);
            return 0;
        }
    }
    return AUTH_UNCLAIMED;
}

int32_t pfdoa_anchor_on_ble_adv(pfdoa_anchor_t *const anchor, const pfdoa_rx_t *const rx, const uint8_t adv_a[6],
                                const uint8_t *const adv_data, const size_t len)
{
    if ((anchor == NULL) || (rx == NULL)) {
        return PFDOA_ERR_ARG;
    }
    pfdoa_match_t m;
    const uint8_t *payload = NULL;
    if ((adv_a != NULL) && (pfdoa_match_auth_ble_adv(adv_data, len, &payload) == 1)) {
        const int32_t done = verify_auth(anchor, payload, rx->tick_ms, &m);
        if (done != AUTH_UNCLAIMED) {
            return take_match(anchor, done, &m, rx, PFDOA_RADIO_BLE);
        }
    }
    const int32_t rc = pfdoa_match_ble_adv(anchor->filters, PFDOA_BEACON_SLOTS, adv_a, adv_data, len, &m);
    return take_match(anchor, rc, &m, rx, PFDOA_RADIO_BLE);
}

int32_t pfdoa_anchor_on_ble_pdu(pfdoa_anchor_t *const anchor, const pfdoa_rx_t *const rx, const uint8_t *const pdu,
                                const size_t len)
{
    if ((anchor == NULL) || (rx == NULL)) {
        return PFDOA_ERR_ARG;
    }
    pfdoa_match_t m;
    const uint8_t *payload = NULL;
    if (pfdoa_match_auth_ble_pdu(pdu, len, &payload) == 1) {
        const int32_t done = verify_auth(anchor, payload, rx->tick_ms, &m);
        if (done != AUTH_UNCLAIMED) {
            return take_match(anchor, done, &m, rx, PFDOA_RADIO_BLE);
        }
    }
    const int32_t rc = pfdoa_match_ble_pdu(anchor->filters, PFDOA_BEACON_SLOTS, pdu, len, &m);
    return take_match(anchor, rc, &m, rx, PFDOA_RADIO_BLE);
}

int32_t pfdoa_anchor_on_802154(pfdoa_anchor_t *const anchor, const pfdoa_rx_t *const rx, const uint8_t *const mpdu,
                               const size_t len)
{
    if ((anchor == NULL) || (rx == NULL)) {
        return PFDOA_ERR_ARG;
    }
    pfdoa_match_t m;
    const uint8_t *payload = NULL;
    if (pfdoa_match_auth_802154(mpdu, len, &payload) == 1) {
        const int32_t done = verify_auth(anchor, payload, rx->tick_ms, &m);
        if (done != AUTH_UNCLAIMED) {
            return take_match(anchor, done, &m, rx, PFDOA_RADIO_IEEE802154);
        }
    }
    const int32_t rc = pfdoa_match_802154(anchor->filters, PFDOA_BEACON_SLOTS, mpdu, len, &m);
    return take_match(anchor, rc, &m, rx, PFDOA_RADIO_IEEE802154);
}

int32_t pfdoa_anchor_note_dropped(pfdoa_anchor_t *const anchor, const uint16_t count)
{
    if (anchor == NULL) {
        return PFDOA_ERR_ARG;
    }
    const uint32_t sum = (uint32_t)anchor->dropped_events + count;
    anchor->dropped_events = (sum > UINT16_MAX) ? (uint16_t)UINT16_MAX : (uint16_t)sum;
    return PFDOA_OK;
}

int32_t pfdoa_anchor_poll(pfdoa_anchor_t *const anchor, const uint32_t tick_ms)
{
    if (anchor == NULL) {
        return PFDOA_ERR_ARG;
    }
    for (size_t i = 0u; i < PFDOA_BEACON_SLOTS; i++) {
        const pfdoa_event_t *const ev = &anchor->slots[i].event;
        const uint32_t timeout = (event_has_seq(ev) != 0u) ? PFDOA_EVENT_TIMEOUT_MS : anchor->filters[i].period_ms;
        if ((ev->n > 0u) && ((uint32_t)(tick_ms - ev->first_tick) >= timeout)) {
            close_event(anchor, i, tick_ms);
        }
    }
    if ((anchor->status_sent == 0u) || ((uint32_t)(tick_ms - anchor->last_status_tick) >= PFDOA_STATUS_PERIOD_MS)) {
        anchor->status_sent = 1u;
        anchor->last_status_tick = tick_ms;
        send_status(anchor, tick_ms);
    }
    poll_peer(anchor, tick_ms);
    return PFDOA_OK;
}

/* A checked frame from the UART. Returns 1 if handled, 0 if addressed elsewhere. */
static int32_t handle_frame(pfdoa_anchor_t *const a, const pfdoa_frame_t *const f)
{
    if (addressed_to(a, f->anchor_id) == 0) {
        return 0;
    }
    if (f->type == PFDOA_MSG_CONFIG_SET) {
        handle_config_set(a, f->payload, PFDOA_TRANSPORT_UART);
    } else if (f->type == PFDOA_MSG_FILTER_SET) {
        handle_filter_set(a, f->payload);
    } else {
        /* a SIL type, below */
    }
#ifdef PFDOA_SIL_INJECT
    if (f->type == PFDOA_MSG_RADIO_INJECT) {
        pfdoa_radio_reading_t r;
        pfdoa_msg_unpack_radio_inject(f->payload, &r);
        (void)pfdoa_anchor_on_radio(a, &r);
    }
    if (f->type == PFDOA_MSG_RADIO_INJECT_RAW) {
        /* One received frame through the raw entry points, as the radio driver would. */
        const uint8_t *const p = f->payload;
        pfdoa_rx_t rx;
        rx.tick_ms = pfdoa_get_u32(&p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_TICK_MS]);
        rx.rssi_dbm = pfdoa_i8_from_u8(p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RSSI_DBM]);
        rx.channel = p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_CHANNEL];
        rx.lqi = p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LQI];
        const uint8_t radio = p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_RADIO];
        const size_t n = p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_LENGTH];
        const uint8_t *const frame = &p[PFDOA_MSG_RADIO_INJECT_RAW_OFF_FRAME];
        if (n > PFDOA_MSG_RADIO_INJECT_RAW_FRAME_LEN) {
            /* more than the frame holds: ignored (SPEC 1.7) */
        } else if (radio == PFDOA_RADIO_BLE) {
            (void)pfdoa_anchor_on_ble_pdu(a, &rx, frame, n);
        } else if (radio == PFDOA_RADIO_IEEE802154) {
            (void)pfdoa_anchor_on_802154(a, &rx, frame, n);
        } else {
            /* no such radio: ignored */
        }
    }
#endif
    return 1;
}

int32_t pfdoa_anchor_on_uart_rx(pfdoa_anchor_t *const anchor, const uint8_t *const bytes, const size_t len)
{
    if ((anchor == NULL) || ((bytes == NULL) && (len > 0u))) {
        return PFDOA_ERR_ARG;
    }
    int32_t accepted = 0;
    for (size_t i = 0u; i < len; i++) {
        pfdoa_frame_t f;
        const int32_t rc = pfdoa_decoder_push(&anchor->decoder, bytes[i], &f);
        if (rc == 1) {
            if ((handle_frame(anchor, &f) > 0) && (accepted < INT32_MAX)) {
                accepted++;
            }
        } else if (rc < 0) {
            count_rx_error(anchor, rc);
        } else {
            /* byte buffered */
        }
    }
    return accepted;
}

int32_t pfdoa_anchor_on_can_rx(pfdoa_anchor_t *const anchor, const uint16_t id, const uint8_t *const data,
                               const uint8_t dlc)
{
    if ((anchor == NULL) || ((data == NULL) && (dlc > 0u)) || (id > PFDOA_CAN_ID_MASK)) {
        return PFDOA_ERR_ARG;
    }
    /* The acceptance filter: (0x180 | own id) and the broadcast 0x1FF, exact match. Other
     * frames are not seen and not counted, as if the controller had dropped them. */
    if (((id >> PFDOA_CAN_ANCHOR_BITS) != PFDOA_CAN_CONFIG_SET) ||
        (addressed_to(anchor, (uint8_t)(id & PFDOA_CAN_ANCHOR_MASK)) == 0)) {
        return 0;
    }
    const int32_t rc = pfdoa_can_check(id, dlc);
    if (rc < 0) {
        count_rx_error(anchor, rc);
        return rc;
    }
    handle_config_set(anchor, data, PFDOA_TRANSPORT_CAN);
    return 1;
}

uint16_t pfdoa_anchor_dropped_events(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->dropped_events : 0u;
}

uint16_t pfdoa_anchor_rx_errors(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->rx_errors : 0u;
}

uint16_t pfdoa_anchor_spikes(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->spikes : 0u;
}

uint16_t pfdoa_anchor_auth_rejected(const pfdoa_anchor_t *const anchor, const int32_t reason)
{
    if ((anchor == NULL) || (reason < PFDOA_AUTH_BAD_TAG) || (reason > PFDOA_AUTH_REPLAYED)) {
        return 0u;
    }
    return anchor->auth_rejected[reason - PFDOA_AUTH_BAD_TAG];
}

uint16_t pfdoa_anchor_rx_error_count(const pfdoa_anchor_t *const anchor, const int32_t err)
{
    if ((anchor == NULL) || (err >= 0) || (err < -PFDOA_ERR_COUNT)) {
        return 0u;
    }
    return anchor->rx_error_kind[(-err) - 1];
}

uint32_t pfdoa_anchor_reports_sent(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->reports_sent : 0u;
}

uint32_t pfdoa_anchor_tx_failures(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->tx_failures : 0u;
}

uint16_t pfdoa_anchor_config_hash(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->config_hash : 0u;
}

int32_t pfdoa_anchor_get_config(const pfdoa_anchor_t *const anchor, pfdoa_config_t *const out)
{
    if ((anchor == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    *out = anchor->config;
    return PFDOA_OK;
}

uint16_t pfdoa_anchor_filter_hash(const pfdoa_anchor_t *const anchor)
{
    return (anchor != NULL) ? anchor->filter_hash : 0u;
}

int32_t pfdoa_anchor_set_filter(pfdoa_anchor_t *const anchor, const uint8_t index,
                                const pfdoa_beacon_filter_t *const filter)
{
    if ((anchor == NULL) || (filter == NULL)) {
        return PFDOA_ERR_ARG;
    }
    return (int32_t)apply_filter(anchor, index, filter);
}

int32_t pfdoa_anchor_get_filter(const pfdoa_anchor_t *const anchor, const uint8_t index,
                                pfdoa_beacon_filter_t *const out)
{
    if ((anchor == NULL) || (out == NULL) || (index >= PFDOA_BEACON_SLOTS)) {
        return PFDOA_ERR_ARG;
    }
    *out = anchor->filters[index];
    return PFDOA_OK;
}
