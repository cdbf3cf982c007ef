/* The beacon (SPEC 6): frame builders and the send schedule. See pfdoa_beacon.h. */
#include "pfdoa_beacon.h"

#include <string.h>

/* Frame Control of our IEEE 802.15.4 beacon (IEEE 802.15.4-2015 7.2.2): a data frame, no
 * security, no frame pending, no ack request, PAN ID Compression, short destination
 * address, frame version 0, extended source address. */
#define BEACON_FCF                                                                                                    \
    ((uint16_t)(PFDOA_IEEE802154_FRAME_DATA | PFDOA_IEEE802154_FCF_PANID_COMP |                                     \
                (PFDOA_IEEE802154_ADDR_SHORT << PFDOA_IEEE802154_FCF_DST_MODE_SHIFT) |                              \
                (PFDOA_IEEE802154_ADDR_EXT << PFDOA_IEEE802154_FCF_SRC_MODE_SHIFT)))

/* The sign bit of a u32 tick difference: "b is not after a" (wrap-safe comparison). */
#define TICK_NEGATIVE 0x80000000u

static void put_u16(uint8_t *const p, const uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

/* 'P' 'F' seq beacon_id: the payload of both radios. */
static void put_payload(uint8_t *const p, const uint16_t seq, const uint8_t beacon_id)
{
    p[0] = PFDOA_BEACON_MAGIC0;
    p[1] = PFDOA_BEACON_MAGIC1;
    put_u16(&p[2], seq);
    p[4] = beacon_id;
}

/* Flags, then the manufacturer data AD header for a payload of n bytes (7 bytes). */
static void put_adv_header(uint8_t *const out, const size_t n)
{
    /* Core Spec Vol 3 Part C 11: each AD structure is length (of what follows), AD type, data. */
    out[0] = 2u;
    out[1] = PFDOA_BLE_AD_FLAGS;
    out[2] = PFDOA_BLE_FLAGS_GENERAL_NO_BREDR;
    out[3] = (uint8_t)(1u + 2u + n); /* AD type, company id, payload */
    out[4] = PFDOA_BLE_AD_MANUFACTURER;
    put_u16(&out[5], PFDOA_BEACON_COMPANY_ID); /* CSS Part A 1.4: company identifier, LE */
}

int32_t pfdoa_beacon_adv_data(const uint16_t seq, const uint8_t beacon_id, uint8_t *const out, const size_t cap)
{
    if (out == NULL) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_ADV_DATA_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    put_adv_header(out, PFDOA_BEACON_PAYLOAD_LEN);
    put_payload(&out[7], seq, beacon_id);
    return (int32_t)PFDOA_BEACON_ADV_DATA_LEN;
}

/* The PDU header (ADV_NONCONN_IND, TxAdd random) and AdvA for AdvData of n bytes. */
static void put_pdu_header(uint8_t *const out, const uint8_t adv_a[PFDOA_BLE_ADV_A_LEN], const size_t n)
{
    /* Vol 6 Part B 2.3: header (PDU type, RFU, ChSel, TxAdd, RxAdd; Length), AdvA, AdvData. */
    out[0] = (uint8_t)(PFDOA_BLE_PDU_ADV_NONCONN_IND | PFDOA_BLE_PDU_TXADD);
    out[1] = (uint8_t)(PFDOA_BLE_ADV_A_LEN + n);
    (void)memcpy(&out[PFDOA_BLE_PDU_HEADER_LEN], adv_a, PFDOA_BLE_ADV_A_LEN);
}

int32_t pfdoa_beacon_adv_pdu(const uint8_t adv_a[PFDOA_BLE_ADV_A_LEN], const uint16_t seq, const uint8_t beacon_id,
                             uint8_t *const out, const size_t cap)
{
    if ((adv_a == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_PDU_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    put_pdu_header(out, adv_a, PFDOA_BEACON_ADV_DATA_LEN);
    return (pfdoa_beacon_adv_data(seq, beacon_id, &out[PFDOA_BEACON_ADV_DATA_OFFSET], PFDOA_BEACON_ADV_DATA_LEN) < 0)
               ? PFDOA_ERR_CAPACITY
               : (int32_t)PFDOA_BEACON_PDU_LEN;
}

/* IEEE 802.15.4-2015 7.2: FCF, sequence number, destination PAN and address, (source PAN
 * elided by PAN ID Compression) source address; fields little-endian. Returns where the
 * payload goes. */
static size_t put_mac_header(uint8_t *const out, const uint8_t ext_addr[PFDOA_IEEE802154_EXT_ADDR_LEN],
                             const uint16_t pan_id, const uint8_t mac_seq)
{
    size_t at = 0u;
    put_u16(&out[at], BEACON_FCF);
    at += PFDOA_IEEE802154_FCF_LEN;
    out[at++] = mac_seq;
    put_u16(&out[at], pan_id);
    at += PFDOA_IEEE802154_PAN_ID_LEN;
    put_u16(&out[at], PFDOA_IEEE802154_BROADCAST);
    at += PFDOA_IEEE802154_SHORT_ADDR_LEN;
    (void)memcpy(&out[at], ext_addr, PFDOA_IEEE802154_EXT_ADDR_LEN);
    return at + PFDOA_IEEE802154_EXT_ADDR_LEN;
}

int32_t pfdoa_beacon_mpdu(const uint8_t ext_addr[PFDOA_IEEE802154_EXT_ADDR_LEN], const uint16_t pan_id,
                          const uint16_t seq, const uint8_t beacon_id, uint8_t *const out, const size_t cap)
{
    if ((ext_addr == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_MPDU_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    put_payload(&out[put_mac_header(out, ext_addr, pan_id, (uint8_t)(seq & 0xFFu))], seq, beacon_id);
    return (int32_t)PFDOA_BEACON_MPDU_LEN;
}

int32_t pfdoa_beacon_auth_adv_data(const pfdoa_hmac_key_t *const k, const pfdoa_auth_ids_t *const ids,
                                   const uint32_t counter, const uint16_t seq, uint8_t *const out, const size_t cap)
{
    if ((k == NULL) || (ids == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_AUTH_ADV_DATA_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    put_adv_header(out, PFDOA_AUTH_PAYLOAD_LEN);
    pfdoa_auth_payload(k, ids, counter, seq, &out[7]);
    return (int32_t)PFDOA_BEACON_AUTH_ADV_DATA_LEN;
}

int32_t pfdoa_beacon_auth_adv_pdu(const pfdoa_hmac_key_t *const k, const pfdoa_auth_ids_t *const ids,
                                  const uint32_t counter, const uint16_t seq, uint8_t *const out, const size_t cap)
{
    if ((k == NULL) || (ids == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_AUTH_PDU_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    put_pdu_header(out, ids->adv_a, PFDOA_BEACON_AUTH_ADV_DATA_LEN);
    (void)pfdoa_beacon_auth_adv_data(k, ids, counter, seq, &out[PFDOA_BEACON_ADV_DATA_OFFSET],
                                     PFDOA_BEACON_AUTH_ADV_DATA_LEN);
    return (int32_t)PFDOA_BEACON_AUTH_PDU_LEN;
}

int32_t pfdoa_beacon_auth_mpdu(const pfdoa_hmac_key_t *const k, const pfdoa_auth_ids_t *const ids,
                               const uint32_t counter, const uint16_t seq, const uint16_t pan_id, uint8_t *const out,
                               const size_t cap)
{
    if ((k == NULL) || (ids == NULL) || (out == NULL)) {
        return PFDOA_ERR_ARG;
    }
    if (cap < PFDOA_BEACON_AUTH_MPDU_LEN) {
        return PFDOA_ERR_CAPACITY;
    }
    /* The MAC sequence number is the hidden seq's low byte: the clear seq would link periods. */
    const size_t at = put_mac_header(out, ids->ext_addr, pan_id, (uint8_t)((seq ^ ids->pad) & 0xFFu));
    pfdoa_auth_payload(k, ids, counter, seq, &out[at]);
    return (int32_t)PFDOA_BEACON_AUTH_MPDU_LEN;
}

void pfdoa_beacon_config_defaults(pfdoa_beacon_config_t *const config)
{
    if (config == NULL) {
        return;
    }
    (void)memset(config, 0, sizeof *config);
    config->interval_ms = PFDOA_BEACON_INTERVAL_MS_DEFAULT;
    config->pan_id = PFDOA_BEACON_PAN_ID_DEFAULT;
    config->tx_power_dbm = PFDOA_BEACON_TX_POWER_DBM_DEFAULT;
    config->radios = PFDOA_BEACON_BLE;
}

int32_t pfdoa_beacon_config_validate(const pfdoa_beacon_config_t *const config)
{
    if ((config == NULL) || (config->interval_ms < PFDOA_BEACON_INTERVAL_MS_MIN) ||
        (config->interval_ms > PFDOA_BEACON_INTERVAL_MS_MAX) || (config->radios == 0u) ||
        ((config->radios & (uint8_t)~(PFDOA_BEACON_BLE | PFDOA_BEACON_802154)) != 0u) || (config->auth > 1u)) {
        return PFDOA_ERR_ARG;
    }
    return PFDOA_OK;
}

int32_t pfdoa_beacon_init(pfdoa_beacon_t *const beacon, const pfdoa_beacon_hal_t *const hal,
                          const pfdoa_beacon_config_t *const config)
{
    if ((beacon == NULL) || (hal == NULL) || (hal->radio_send == NULL) ||
        (pfdoa_beacon_config_validate(config) != PFDOA_OK)) {
        return PFDOA_ERR_ARG;
    }
    if ((config->auth != 0u) && (hal->tick_ms == NULL)) {
        return PFDOA_ERR_ARG; /* the authenticated beacon keeps time */
    }
    (void)memset(beacon, 0, sizeof *beacon);
    beacon->hal = *hal;
    beacon->config = *config;
    if (config->auth != 0u) {
        pfdoa_hmac_init(&beacon->key, config->auth_key, PFDOA_AUTH_KEY_LEN);
        (void)memset(beacon->config.auth_key, 0, sizeof beacon->config.auth_key); /* the schedule suffices */
    }
    return PFDOA_OK;
}

int32_t pfdoa_beacon_set_time(pfdoa_beacon_t *const beacon, const uint32_t counter, const uint32_t phase_ms,
                              const uint32_t tick_ms)
{
    if ((beacon == NULL) || (beacon->config.auth == 0u) || (phase_ms >= PFDOA_AUTH_PERIOD_MS)) {
        return PFDOA_ERR_ARG;
    }
    beacon->counter = counter;
    beacon->period_tick = (uint32_t)(tick_ms - phase_ms);
    beacon->time_set = 1u;
    return PFDOA_OK;
}

uint32_t pfdoa_beacon_counter(pfdoa_beacon_t *const beacon, const uint32_t tick_ms)
{
    if ((beacon == NULL) || (beacon->time_set == 0u)) {
        return 0u;
    }
    /* Whole periods since the current one began: a shift, no division (M0+). */
    const uint32_t periods = (uint32_t)(tick_ms - beacon->period_tick) >> PFDOA_AUTH_PERIOD_SHIFT;
    beacon->counter += periods;
    beacon->period_tick += periods << PFDOA_AUTH_PERIOD_SHIFT;
    return beacon->counter;
}

int32_t pfdoa_beacon_start(pfdoa_beacon_t *const beacon)
{
    if ((beacon == NULL) || (beacon->hal.timer_start == NULL)) {
        return PFDOA_ERR_ARG;
    }
    const int32_t rc = beacon->hal.timer_start(beacon->hal.ctx, beacon->config.interval_ms);
    return (rc < 0) ? rc : PFDOA_OK;
}

static int32_t send(pfdoa_beacon_t *const b, const uint8_t radio, const uint8_t *const frame, const size_t len)
{
    if (b->hal.radio_send(b->hal.ctx, radio, b->config.tx_power_dbm, frame, len) < 0) {
        b->send_failures++;
        return 0;
    }
    b->sent++;
    return 1;
}

/* The authenticated beacon's advertisement (SPEC 9.3) on each configured radio. */
static int32_t send_auth(pfdoa_beacon_t *const b)
{
    if (b->time_set == 0u) {
        return 0; /* no time, no counter: nothing a verifier could accept */
    }
    const uint32_t counter = pfdoa_beacon_counter(b, b->hal.tick_ms(b->hal.ctx));
    if ((b->ids_valid == 0u) || (b->ids_counter != counter)) {
        pfdoa_auth_derive(&b->key, counter, &b->ids); /* once a period */
        b->ids_counter = counter;
        b->ids_valid = 1u;
    }
    uint8_t frame[(PFDOA_BEACON_AUTH_PDU_LEN > PFDOA_BEACON_AUTH_MPDU_LEN) ? PFDOA_BEACON_AUTH_PDU_LEN
                                                                          : PFDOA_BEACON_AUTH_MPDU_LEN];
    int32_t accepted = 0;
    if ((b->config.radios & PFDOA_BEACON_BLE) != 0u) {
        (void)pfdoa_beacon_auth_adv_pdu(&b->key, &b->ids, counter, b->seq, frame, sizeof frame);
        accepted += send(b, PFDOA_RADIO_BLE, frame, PFDOA_BEACON_AUTH_PDU_LEN);
    }
    if ((b->config.radios & PFDOA_BEACON_802154) != 0u) {
        (void)pfdoa_beacon_auth_mpdu(&b->key, &b->ids, counter, b->seq, b->config.pan_id, frame, sizeof frame);
        accepted += send(b, PFDOA_RADIO_IEEE802154, frame, PFDOA_BEACON_AUTH_MPDU_LEN);
    }
    b->seq = (uint16_t)(b->seq + 1u);
    return accepted;
}

int32_t pfdoa_beacon_on_timer(pfdoa_beacon_t *const beacon)
{
    if (beacon == NULL) {
        return PFDOA_ERR_ARG;
    }
    const pfdoa_beacon_config_t *const c = &beacon->config;
    if (c->auth != 0u) {
        return send_auth(beacon);
    }
    uint8_t frame[(PFDOA_BEACON_PDU_LEN > PFDOA_BEACON_MPDU_LEN) ? PFDOA_BEACON_PDU_LEN : PFDOA_BEACON_MPDU_LEN];
    int32_t accepted = 0;
    if ((c->radios & PFDOA_BEACON_BLE) != 0u) {
        (void)pfdoa_beacon_adv_pdu(c->adv_a, beacon->seq, c->beacon_id, frame, sizeof frame);
        accepted += send(beacon, PFDOA_RADIO_BLE, frame, PFDOA_BEACON_PDU_LEN);
    }
    if ((c->radios & PFDOA_BEACON_802154) != 0u) {
        (void)pfdoa_beacon_mpdu(c->ext_addr, c->pan_id, beacon->seq, c->beacon_id, frame, sizeof frame);
        accepted += send(beacon, PFDOA_RADIO_IEEE802154, frame, PFDOA_BEACON_MPDU_LEN);
    }
    beacon->seq = (uint16_t)(beacon->seq + 1u);
    return accepted;
}

int32_t pfdoa_beacon_poll(pfdoa_beacon_t *const beacon, const uint32_t tick_ms)
{
    if (beacon == NULL) {
        return PFDOA_ERR_ARG;
    }
    if ((beacon->polled != 0u) && (((uint32_t)(tick_ms - beacon->next_tick) & TICK_NEGATIVE) != 0u)) {
        return 0;
    }
    const uint32_t interval = beacon->config.interval_ms;
    /* On time (or a little late): keep the cadence; a stall of an interval or more: restart it. */
    beacon->next_tick = ((beacon->polled != 0u) && ((uint32_t)(tick_ms - beacon->next_tick) < interval))
                            ? (uint32_t)(beacon->next_tick + interval)
                            : (uint32_t)(tick_ms + interval);
    beacon->polled = 1u;
    (void)pfdoa_beacon_on_timer(beacon);
    return 1;
}

uint16_t pfdoa_beacon_seq(const pfdoa_beacon_t *const beacon)
{
    return (beacon != NULL) ? beacon->seq : 0u;
}

uint32_t pfdoa_beacon_sent(const pfdoa_beacon_t *const beacon)
{
    return (beacon != NULL) ? beacon->sent : 0u;
}

uint32_t pfdoa_beacon_send_failures(const pfdoa_beacon_t *const beacon)
{
    return (beacon != NULL) ? beacon->send_failures : 0u;
}
