# pfdoa anchor core for MicroPython: the fixed-point filter and state machine of
# protocol/SPEC.md section 3 (protocol version 2), byte-identical to the C core
# (firmware/core). Pure: no hardware access; ticks, output and storage come in through the
# API. Integer arithmetic only (// is floor division, as the SPEC requires).
import array
import struct

import pfdoa_defs as D
import pfdoa_match as M
import pfdoa_wire as W
from micropython import const

FW_MAJOR = const(1)  # firmware version reported in STATUS (independent of the protocol)
FW_MINOR = const(0)

TRANSPORT_UART = const(1)
TRANSPORT_CAN = const(2)

_M32 = const(0xFFFFFFFF)
_SAT16 = const(0xFFFF)
_Q8_MAX = const(32767)
_Q8_MIN = const(-32768)
_NS = D.BEACON_SLOTS
_AUTH_QUEUED = const(-2)  # a ReadingQueue entry holding an authenticated payload (SPEC 9)
_AL = D.AUTH_PAYLOAD_LEN

# Message types an anchor accepts (everything else is unknown_type, SPEC 2.3).
_RX_TYPES = ((D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_LEN), (D.MSG_FILTER_SET, D.MSG_FILTER_SET_LEN))
_RX_TYPES_SIL = ((D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_LEN),
                 (D.MSG_RADIO_INJECT_RAW, D.MSG_RADIO_INJECT_RAW_LEN))
_EXTRA = ((D.MSG_RSSI_REPORT, D.MSG_RSSI_REPORT_CRC_EXTRA),
          (D.MSG_AUTH_REPORT, D.MSG_AUTH_REPORT_CRC_EXTRA),
          (D.MSG_AUTH_STATUS, D.MSG_AUTH_STATUS_CRC_EXTRA),
          (D.MSG_STATUS, D.MSG_STATUS_CRC_EXTRA),
          (D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_CRC_EXTRA),
          (D.MSG_CONFIG_ACK, D.MSG_CONFIG_ACK_CRC_EXTRA),
          (D.MSG_FILTER_SET, D.MSG_FILTER_SET_CRC_EXTRA),
          (D.MSG_FILTER_ACK, D.MSG_FILTER_ACK_CRC_EXTRA),
          (D.MSG_RADIO_INJECT_RAW, D.MSG_RADIO_INJECT_RAW_CRC_EXTRA),
          (D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_CRC_EXTRA))


def fold_q8(total, n):
    """Mean of n readings summing to total dBm in Q7.8, rounded half up (SPEC 3 Fold)."""
    return (512 * total + n) // (2 * n)


def ema_step_q8(ema_q8, mean_q8, alpha_q8):
    """One EMA update, increment rounded half up to 1/256 dB (SPEC 3 EMA)."""
    return ema_q8 + (alpha_q8 * (mean_q8 - ema_q8) + 128) // 256


def default_config():
    return bytearray(D.CONFIG_DEFAULT)


def config_valid(alpha_q8, report_mode, decimation):
    return (D.VALID_ALPHA_Q8_MIN <= alpha_q8 <= D.VALID_ALPHA_Q8_MAX
            and D.VALID_REPORT_MODE_MIN <= report_mode <= D.VALID_REPORT_MODE_MAX
            and D.VALID_DECIMATION_MIN <= decimation <= D.VALID_DECIMATION_MAX)


def _channel_ok(radio, channel):
    if radio == D.RADIO_BLE:
        return D.CHANNEL_BLE_MIN <= channel <= D.CHANNEL_BLE_MAX
    if radio == D.RADIO_IEEE802154:
        return D.CHANNEL_IEEE802154_MIN <= channel <= D.CHANNEL_IEEE802154_MAX
    return False


# The anchor's own advertisement (SPEC 6.1): our beacon's frames with the magic 'P' 'N'.
PEER_FRAME_MAX = const(20)
_PEER_BLE_HEAD = bytes((D.BLE_PDU_ADV_NONCONN_IND | D.BLE_PDU_TXADD, D.BLE_ADV_A_LEN + 12, 2, D.BLE_AD_FLAGS,
                        D.BLE_FLAGS_GENERAL_NO_BREDR, 3 + D.BEACON_PAYLOAD_LEN, D.BLE_AD_MANUFACTURER,
                        D.BEACON_COMPANY_ID & 0xFF, D.BEACON_COMPANY_ID >> 8))
_PEER_FCF = (D.IEEE802154_FRAME_DATA | D.IEEE802154_FCF_PANID_COMP
             | (D.IEEE802154_ADDR_SHORT << D.IEEE802154_FCF_DST_MODE_SHIFT)
             | (D.IEEE802154_ADDR_EXT << D.IEEE802154_FCF_SRC_MODE_SHIFT))


def peer_frame(radio, address, anchor_id, seq, out):
    """The advertisement of anchor_id with sequence number seq into out (PEER_FRAME_MAX
    bytes): over BLE an ADV_NONCONN_IND PDU from AdvA address[0:6] (Core Spec v5.3 Vol 6
    Part B 2.3), over IEEE 802.15.4 a data frame to the broadcast address of the broadcast
    PAN from the extended address address[0:8], no FCS (IEEE 802.15.4-2015 7.2). Returns its
    length. Allocation-free."""
    if radio == D.RADIO_BLE:
        h = _PEER_BLE_HEAD
        out[0], out[1] = h[0], h[1]
        for k in range(D.BLE_ADV_A_LEN):
            out[2 + k] = address[k]
        at = 2 + D.BLE_ADV_A_LEN
        for k in range(2, len(h)):
            out[at] = h[k]
            at += 1
    else:
        out[0], out[1], out[2] = _PEER_FCF & 0xFF, _PEER_FCF >> 8, seq & 0xFF
        for k in range(3, 7):
            out[k] = 0xFF  # destination PAN and short address: broadcast
        for k in range(D.IEEE802154_EXT_ADDR_LEN):
            out[7 + k] = address[k]
        at = 7 + D.IEEE802154_EXT_ADDR_LEN
    out[at] = D.BEACON_MAGIC0
    out[at + 1] = D.ANCHOR_MAGIC1
    out[at + 2] = seq & 0xFF
    out[at + 3] = (seq >> 8) & 0xFF
    out[at + 4] = anchor_id
    return at + D.BEACON_PAYLOAD_LEN


def _tables(sil_inject):
    plen = bytearray(b"\xff" * 256)  # 255: type unknown to the anchor
    extra = bytearray(256)
    to_host = bytearray(256)  # the anchor accepts no anchor-to-host type
    for t, x in _EXTRA:
        extra[t] = x
    for t, n in _RX_TYPES + (_RX_TYPES_SIL if sil_inject else ()):
        plen[t] = n
    return plen, extra, to_host


class Anchor:
    """One anchor. Feed it reading() (entry 0, seq matched by the board), ble_adv(),
    ble_pdu() and ieee802154() (raw receptions matched against the filter table), poll(),
    uart_rx() and can_rx(); it emits frames as they happen through uart_write(memoryview)
    and can_send(can_id, memoryview), which must consume the buffer before returning (it
    is reused).

    transports: TRANSPORT_UART | TRANSPORT_CAN bits that carry reports and STATUS
    (default: every transport with a callback). A CONFIG_ACK goes out on the transport
    its CONFIG_SET came from, a FILTER_ACK on the UART. config: 7 stored bytes (None or
    invalid: defaults); store(config_bytes) -> bool persists an applied configuration.
    filters: the stored filter table (None or invalid: the default table);
    store_filters(table_bytes) -> bool persists it.
    sil_inject: accept RADIO_INJECT and RADIO_INJECT_RAW frames (test builds, SPEC 1.7).
    peer_send(memoryview) -> bool sends the anchor's own advertisement on peer_radio
    (D.RADIO_BLE: its AdvA is peer_address[0:6]; D.RADIO_IEEE802154: its extended address
    peer_address[0:8]) when an ANCHORS entry is in the table (SPEC 3.5); None: it sends none."""

    def __init__(self, anchor_id, tick_ms, uart_write=None, can_send=None, transports=0,
                 config=None, store=None, sil_inject=False, fw=(FW_MAJOR, FW_MINOR),
                 filters=None, store_filters=None, peer_send=None, peer_radio=0, peer_address=None):
        if not 0 <= anchor_id <= D.ANCHOR_ID_MAX:
            raise ValueError("anchor id")
        self.anchor_id = anchor_id
        self._fw_major, self._fw_minor = fw
        self._uart_write = uart_write
        self._can_send = can_send
        if not transports:
            transports = ((TRANSPORT_UART if uart_write else 0)
                          | (TRANSPORT_CAN if can_send else 0))
        self._to_uart = bool(transports & TRANSPORT_UART) and uart_write is not None
        self._to_can = bool(transports & TRANSPORT_CAN) and can_send is not None
        self._store = store
        self._store_filters = store_filters
        plen, extra, to_host = _tables(sil_inject)
        self._enc = W.FrameEncoder(extra)
        self._dec = W.FrameDecoder(plen, extra, to_host, self._on_frame, self._on_rx_error)
        self._can_buf = bytearray(8)
        self._can_mv = memoryview(self._can_buf)
        self._can_mv_report = self._can_mv[:D.CAN_RSSI_REPORT_DLC]
        self._can_mv_ack = self._can_mv[:D.CAN_CONFIG_ACK_DLC]
        self._can_mv_c = self._can_mv[:D.CAN_STATUS_C_DLC]
        self._cfg = bytearray(D.CONFIG_LEN)
        self.filters = M.default_table()
        self.rx_error_kinds = bytearray(D.ERR_COUNT)
        # Per filter entry (SPEC 3.4): the filter state, the open event, mode-1 state.
        self._ema = array.array("i", bytes(4 * _NS))
        self._have_ema = bytearray(_NS)
        self._spike_run = bytearray(_NS)
        self._ev_open = bytearray(_NS)
        self._ev_seq = array.array("H", bytes(2 * _NS))
        self._ev_has_seq = bytearray(_NS)
        self._ev_radio = bytearray(_NS)
        self._ev_n = bytearray(_NS)
        self._ev_sum = array.array("i", bytes(4 * _NS))
        self._ev_first = [0] * _NS
        self._ev_raw = array.array("b", bytes(_NS))
        self._ev_channel = bytearray(_NS)
        self._ev_flags = bytearray(_NS)
        self._dec_count = bytearray(_NS)
        self._dec_flags = bytearray(_NS)
        self._noseq_next = array.array("H", bytes(2 * _NS))
        # PFDOA_AUTH entries (SPEC 9.4): a pfdoa_auth.Verifier each, and the open event's
        # counter and tag for its AUTH_REPORT.
        self._auth = [None] * _NS
        self._ev_counter = [0] * _NS
        self._ev_tag = [b""] * _NS
        self.auth_rejected = [0, 0, 0]  # bad tag, stale, replayed (saturating u16)
        if peer_send is not None and not (
                (peer_radio == D.RADIO_BLE and len(peer_address) == D.BLE_ADV_A_LEN)
                or (peer_radio == D.RADIO_IEEE802154 and len(peer_address) == D.IEEE802154_EXT_ADDR_LEN)):
            raise ValueError("peer radio")
        self._peer_send = peer_send
        self._peer_radio = peer_radio
        self._peer_address = bytes(peer_address) if peer_send is not None else b""
        self._peer_buf = bytearray(PEER_FRAME_MAX)
        self._peer_mv = memoryview(self._peer_buf)
        self.reset(tick_ms, config, filters)

    def reset(self, tick_ms, config=None, filters=None):
        """State as after power-up at tick_ms (config, filters: stored bytes or None)."""
        self._cfg[:] = default_config()
        if config is not None and len(config) == D.CONFIG_LEN:
            offset, alpha, spike, mode, dec = struct.unpack_from(D.CONFIG_FMT, config, 0)
            if config_valid(alpha, mode, dec):
                self._cfg[:] = config
        self._load_config()
        self.filters[:] = D.FILTER_TABLE_DEFAULT
        if filters is not None and M.table_valid(filters):  # one invalid entry: the default table
            self.filters[:] = filters
        self.filter_hash = M.table_hash(self.filters)
        self._dec.reset()
        self.boot_tick = tick_ms & _M32
        self._status_sent = False
        self._last_status = 0
        self.dropped_events = 0
        self.rx_errors = 0
        self.spikes = 0
        for i in range(3):
            self.auth_rejected[i] = 0
        self._peer_sent = False  # False: the next poll sends the advertisement (SPEC 3.5)
        self._peer_tick = 0
        self.peer_seq = 0
        for i in range(D.ERR_COUNT):
            self.rx_error_kinds[i] = 0
        for i in range(_NS):
            self._reset_slot(i)

    def _reset_slot(self, i):
        self._ema[i] = 0
        self._have_ema[i] = 0
        self._spike_run[i] = 0
        self._ev_open[i] = 0
        self._ev_seq[i] = 0
        self._ev_has_seq[i] = 0
        self._ev_radio[i] = 0
        self._ev_n[i] = 0
        self._ev_sum[i] = 0
        self._ev_first[i] = 0
        self._ev_raw[i] = 0
        self._ev_channel[i] = 0
        self._ev_flags[i] = 0
        self._dec_count[i] = 0
        self._dec_flags[i] = 0
        self._noseq_next[i] = 0
        self._auth[i] = None
        if M.kind(self.filters, i) == D.FILTER_PFDOA_AUTH:
            import pfdoa_auth  # only anchors with an authenticated beacon need it
            e = i * D.FILTER_ENTRY_LEN + 3
            self._auth[i] = pfdoa_auth.Verifier(self.filters[e:e + D.AUTH_KEY_LEN])

    def _load_config(self):
        (self.offset_q8, self.alpha_q8, self.spike_db, self.report_mode,
         self.decimation) = struct.unpack_from(D.CONFIG_FMT, self._cfg, 0)
        self.config_hash = W.crc16(self._cfg)

    @property
    def config(self):
        return bytes(self._cfg)

    # Entry 0's filter state, for inspection (tests, a board's debug console).
    @property
    def ema_q8(self):
        return self._ema[0]

    @property
    def have_ema(self):
        return bool(self._have_ema[0])

    @property
    def spike_run(self):
        return self._spike_run[0]

    # ---- radio path -------------------------------------------------------------

    def reading(self, seq, rssi_dbm, channel, lqi, radio, tick_ms):
        """One reading of filter entry 0 with its sequence number, as the radio driver saw
        it at tick_ms (the board matched our beacon itself). Dropped when entry 0 is an
        authenticated beacon (SPEC 9.4: a board cannot vouch for it)."""
        if self._auth[0] is not None:
            self.reading_lost()
            return False
        return self._reading(0, 1, seq, rssi_dbm, channel, radio, tick_ms)

    def ble_adv(self, adv_a, adv_data, rssi_dbm, channel, tick_ms):
        """A BLE advertisement as AdvA (6 bytes) + AdvData, matched against the table.
        True when it matched an entry and was used, False when not (or dropped). Our
        authenticated beacon goes to the PFDOA_AUTH entries first (SPEC 9.4)."""
        if self._has_auth and len(adv_a) == D.BLE_ADV_A_LEN:
            r = self._take_auth(adv_data, M.auth_adv(adv_data, 0, len(adv_data)), rssi_dbm, channel,
                                D.RADIO_BLE, tick_ms)
            if r is not None:
                return r
        return self._matched(M.match_adv(self.filters, adv_a, 0, adv_data, 0, len(adv_data)),
                             rssi_dbm, channel, D.RADIO_BLE, tick_ms)

    def ble_pdu(self, pdu, n, rssi_dbm, channel, tick_ms):
        """A raw BLE advertising PDU pdu[0:n], matched against the table."""
        if self._has_auth:
            r = self._take_auth(pdu, M.auth_pdu(pdu, n), rssi_dbm, channel, D.RADIO_BLE, tick_ms)
            if r is not None:
                return r
        return self._matched(M.match_pdu(self.filters, pdu, n), rssi_dbm, channel, D.RADIO_BLE, tick_ms)

    def ieee802154(self, mpdu, n, rssi_dbm, channel, lqi, tick_ms):
        """A raw IEEE 802.15.4 MAC frame mpdu[0:n] (no FCS), matched against the table."""
        if self._has_auth:
            r = self._take_auth(mpdu, M.auth_802154(mpdu, n), rssi_dbm, channel, D.RADIO_IEEE802154, tick_ms)
            if r is not None:
                return r
        return self._matched(M.match_802154(self.filters, mpdu, n), rssi_dbm, channel,
                             D.RADIO_IEEE802154, tick_ms)

    @property
    def _has_auth(self):
        for v in self._auth:
            if v is not None:
                return True
        return False

    def _take_auth(self, buf, at, rssi_dbm, channel, radio, tick_ms):
        """Our authenticated payload buf[at:at+22] (at < 0: none), offered to the
        PFDOA_AUTH entries in index order: the first whose rolling identifier it carries
        decides (SPEC 9.4). None when no entry claims it."""
        if at < 0:
            return None
        tick_ms &= _M32
        for i in range(_NS):
            v = self._auth[i]
            if v is None:
                continue
            res = v.verify(buf, at, tick_ms)
            if res == D.AUTH_NONE:
                continue
            if res == D.AUTH_ACCEPT:
                return self._reading(i, 1, v.seq, rssi_dbm, channel, radio, tick_ms, v.counter, v.tag)
            k = res - D.AUTH_BAD_TAG
            if self.auth_rejected[k] < _SAT16:
                self.auth_rejected[k] += 1
            return False
        return None

    def auth_payload(self, buf, at, rssi_dbm, channel, radio, tick_ms):
        """Our authenticated beacon's 22-byte payload buf[at:at+22], found in a reception
        by pfdoa_match.auth_* (e.g. in a scan IRQ, queued with ReadingQueue.put_auth):
        verified by the PFDOA_AUTH entries (SPEC 9.4). True when it became a reading."""
        return self._take_auth(buf, at, rssi_dbm, channel, radio, tick_ms) is True

    def _matched(self, m, rssi_dbm, channel, radio, tick_ms):
        if m < 0:
            return False  # not a configured beacon: ignored, not counted
        if m >> 19:
            return self._peer((m >> 19) - 1, m & 0xFFFF, rssi_dbm, channel, radio, tick_ms)
        return self._reading((m >> 17) & 3, (m >> 16) & 1, m & 0xFFFF, rssi_dbm, channel, radio, tick_ms)

    def _peer(self, peer, seq, rssi_dbm, channel, radio, tick_ms):
        """A peer reading (SPEC 3.5): one report of its own, calibrated, not filtered."""
        if peer == self.anchor_id:
            return False  # another anchor with our id: not a peer, ignored
        if rssi_dbm == D.RSSI_INVALID or not _channel_ok(radio, channel):
            if self.dropped_events < _SAT16:
                self.dropped_events += 1
            return False
        flags = D.FLAG_ZIGBEE if radio == D.RADIO_IEEE802154 else 0
        if rssi_dbm > D.RSSI_MAX_DBM:
            rssi_dbm = D.RSSI_MAX_DBM
            flags |= D.FLAG_SATURATED
        out = self._calibrated(256 * rssi_dbm, flags)
        if self.report_mode != D.REPORT_SILENT:
            self._send(seq, tick_ms & _M32, out >> 8, rssi_dbm, 1, channel, out & 0xFF, D.PEER_BEACON_BASE + peer)
        return True

    def _calibrated(self, q8, flags):
        """The reported value of q8 (SPEC 3.4 Calibration and output) and its flags, as one
        small int, (out << 8) | flags: a tuple would allocate."""
        out = q8 + self.offset_q8
        if out > _Q8_MAX:
            out = _Q8_MAX
            flags |= D.FLAG_SATURATED
        elif out < _Q8_MIN:
            out = _Q8_MIN
            flags |= D.FLAG_SATURATED
        if self.offset_q8:
            flags |= D.FLAG_CALIBRATED
        return (out << 8) | flags

    def matched(self, m, rssi_dbm, channel, radio, tick_ms):
        """A reception already matched with pfdoa_match (m >= 0: its result), e.g. by a
        scan IRQ, which then only queues the result (see ReadingQueue.put_match)."""
        return self._matched(m, rssi_dbm, channel, radio, tick_ms)

    def _reading(self, i, has_seq, seq, rssi_dbm, channel, radio, tick_ms, counter=-1, tag=None):
        if rssi_dbm == D.RSSI_INVALID or not _channel_ok(radio, channel):
            if self.dropped_events < _SAT16:
                self.dropped_events += 1
            return False
        tick_ms &= _M32
        flags = 0
        if rssi_dbm > D.RSSI_MAX_DBM:
            rssi_dbm = D.RSSI_MAX_DBM
            flags = D.FLAG_SATURATED
        elif rssi_dbm < D.RSSI_MIN_DBM:
            rssi_dbm = D.RSSI_MIN_DBM
            flags = D.FLAG_SATURATED
        if self._ev_open[i] and (self._ev_radio[i] != radio or self._ev_has_seq[i] != has_seq
                                 or (tag is not None and self._ev_counter[i] != counter)
                                 or (self._ev_seq[i] != seq if has_seq else
                                     ((tick_ms - self._ev_first[i]) & _M32) >= M.period(self.filters, i))):
            self._close(i, tick_ms)
        if not self._ev_open[i]:
            self._ev_open[i] = 1
            if tag is not None:
                self._ev_counter[i] = counter
                self._ev_tag[i] = tag
            if not has_seq:
                seq = self._noseq_next[i]
                self._noseq_next[i] = (seq + 1) & 0xFFFF
            self._ev_seq[i] = seq
            self._ev_has_seq[i] = has_seq
            self._ev_radio[i] = radio
            self._ev_n[i] = 0
            self._ev_sum[i] = 0
            self._ev_first[i] = tick_ms
            self._ev_flags[i] = 0 if has_seq else D.FLAG_NO_SEQ
        self._ev_n[i] += 1
        self._ev_sum[i] += rssi_dbm
        self._ev_raw[i] = rssi_dbm
        self._ev_channel[i] = channel
        self._ev_flags[i] |= flags
        if radio == D.RADIO_IEEE802154 or self._ev_n[i] >= D.BLE_EVENT_MAX_READINGS:
            self._close(i, tick_ms)
        return True

    def reading_lost(self):
        """A reading the board lost before the core (queue full): counts as dropped."""
        if self.dropped_events < _SAT16:
            self.dropped_events += 1

    def poll(self, tick_ms):
        """Periodic work: event timeouts in entry order, then STATUS when due (SPEC 1.2, 3)."""
        tick_ms &= _M32
        for i in range(_NS):
            if self._ev_open[i]:
                timeout = D.EVENT_TIMEOUT_MS if self._ev_has_seq[i] else M.period(self.filters, i)
                if ((tick_ms - self._ev_first[i]) & _M32) >= timeout:
                    self._close(i, tick_ms)
        if not self._status_sent or ((tick_ms - self._last_status) & _M32) >= D.STATUS_PERIOD_MS:
            self._status_sent = True
            self._last_status = tick_ms
            self._send_status(tick_ms)
        if self._peer_send is not None:
            for i in range(_NS):
                if M.kind(self.filters, i) == D.FILTER_ANCHORS:
                    if not self._peer_sent or ((tick_ms - self._peer_tick) & _M32) >= M.period(self.filters, i):
                        self._peer_sent = True
                        self._peer_tick = tick_ms
                        n = peer_frame(self._peer_radio, self._peer_address, self.anchor_id, self.peer_seq,
                                       self._peer_buf)
                        self._peer_send(self._peer_mv[:n])
                        self.peer_seq = (self.peer_seq + 1) & 0xFFFF
                    break

    def _close(self, i, tick_ms):
        self._ev_open[i] = 0
        mean = fold_q8(self._ev_sum[i], self._ev_n[i])
        flags = self._ev_flags[i]
        if self._ev_radio[i] == D.RADIO_IEEE802154:
            flags |= D.FLAG_ZIGBEE
        ema = self._ema[i]
        reinit = not self._have_ema[i]
        if not reinit and self.spike_db and abs(mean - ema) > 256 * self.spike_db:
            if self._spike_run[i] >= D.SPIKE_RUN_RESET:
                reinit = True  # a real level change, not a spike
            else:
                self._spike_run[i] += 1
                if self.spikes < _SAT16:
                    self.spikes += 1
                flags |= D.FLAG_SPIKE
        elif not reinit:
            self._spike_run[i] = 0
            self._ema[i] = ema_step_q8(ema, mean, self.alpha_q8)
        if reinit:
            self._ema[i] = mean
            self._have_ema[i] = 1
            self._spike_run[i] = 0
            flags |= D.FLAG_RESET
        out = self._calibrated(self._ema[i], flags)
        flags = out & 0xFF
        out >>= 8
        mode = self.report_mode
        if mode == D.REPORT_EVERY:
            self._send_report(i, tick_ms, out, flags)
        elif mode == D.REPORT_DECIMATE:
            self._dec_flags[i] |= flags
            self._dec_count[i] += 1
            if self._dec_count[i] >= self.decimation:
                flags = self._dec_flags[i]
                self._dec_count[i] = 0
                self._dec_flags[i] = 0
                self._send_report(i, tick_ms, out, flags)

    # ---- host input ---------------------------------------------------------------

    def uart_rx(self, data):
        """Bytes from the host UART, in any chunking."""
        self._dec.feed(data)

    def can_rx(self, can_id, data):
        """One received CAN frame; the anchor's acceptance filter is applied here."""
        if can_id != W.can_id(D.CAN_CONFIG_SET, self.anchor_id) and \
                can_id != W.can_id(D.CAN_CONFIG_SET, D.ANCHOR_BROADCAST):
            return  # not for this anchor: never seen, not counted
        if len(data) != D.CAN_CONFIG_SET_DLC:
            self._on_rx_error(D.ERR_BAD_LENGTH)
            return
        self._config_set(data, True)

    def _on_rx_error(self, err):
        if self.rx_errors < _SAT16:
            self.rx_errors += 1
        k = self.rx_error_kinds
        i = -1 - err  # ERR_* are -1..-ERR_COUNT
        if k[i] < 255:
            k[i] += 1

    def _on_frame(self, msg_type, anchor_id, payload, n):
        if anchor_id != self.anchor_id and anchor_id != D.ANCHOR_BROADCAST:
            return  # for another anchor: ignored, not counted
        if msg_type == D.MSG_CONFIG_SET:
            self._config_set(payload, False)
        elif msg_type == D.MSG_FILTER_SET:
            self._filter_set(payload)
        elif msg_type == D.MSG_RADIO_INJECT:
            seq, tick, rssi, ch, lqi, radio = struct.unpack_from(D.MSG_RADIO_INJECT_FMT, payload, 0)
            self.reading(seq, rssi, ch, lqi, radio, tick)
        elif msg_type == D.MSG_RADIO_INJECT_RAW:
            tick, rssi, ch, lqi, radio, length, _ = struct.unpack_from(D.MSG_RADIO_INJECT_RAW_FMT, payload, 0)
            frame = payload[D.MSG_RADIO_INJECT_RAW_OFF_FRAME:]
            if length > D.MSG_RADIO_INJECT_RAW_FRAME_LEN:
                return  # more than the frame holds: ignored (SPEC 1.7)
            if radio == D.RADIO_BLE:
                self.ble_pdu(frame, length, rssi, ch, tick)
            elif radio == D.RADIO_IEEE802154:
                self.ieee802154(frame, length, rssi, ch, lqi, tick)

    def _config_set(self, p, via_can):
        token = p[0]
        offset, alpha, spike, mode, dec = struct.unpack_from(D.CONFIG_FMT, p, 1)
        if not config_valid(alpha, mode, dec):
            result = D.ACK_INVALID  # nothing changes
        else:
            # The whole configuration at once; the filter state of every entry is kept,
            # a new decimation cycle starts.
            for i in range(D.CONFIG_LEN):
                self._cfg[i] = p[1 + i]
            self._load_config()
            for i in range(_NS):
                self._dec_count[i] = 0
                self._dec_flags[i] = 0
            result = D.ACK_OK
            if self._store is None or not self._store(self._cfg):
                result = D.ACK_STORE_FAILED
        self._send_ack(token, result, via_can)

    def set_filter(self, index, entry, at=0):
        """Filter entry `index` from its stored form entry[at:at+FILTER_ENTRY_LEN], as a
        FILTER_SET would (the entry's state restarts, the table is stored). Returns the
        FILTER_ACK result."""
        if index >= _NS or not M.entry_valid(entry, at):
            return D.ACK_INVALID
        base = index * D.FILTER_ENTRY_LEN
        for k in range(D.FILTER_ENTRY_LEN):
            self.filters[base + k] = entry[at + k]
        self.filter_hash = M.table_hash(self.filters)
        self._reset_slot(index)  # a new beacon starts afresh
        self._peer_sent = False  # the advertisement's schedule restarts (SPEC 3.5)
        if self._store_filters is None or not self._store_filters(self.filters):
            return D.ACK_STORE_FAILED
        return D.ACK_OK

    def _filter_set(self, p):
        token = p[D.MSG_FILTER_SET_OFF_TOKEN]
        index = p[D.MSG_FILTER_SET_OFF_INDEX]
        # kind, period_ms and match follow in the order of the stored entry
        result = self.set_filter(index, p, D.MSG_FILTER_SET_OFF_KIND)
        if self._uart_write is not None:
            struct.pack_into(D.MSG_FILTER_ACK_FMT, self._enc.payload, 0, token, result, index,
                             self.filter_hash)
            self._uart_write(self._enc.finish(D.MSG_FILTER_ACK, self.anchor_id, D.MSG_FILTER_ACK_LEN))

    # ---- output -------------------------------------------------------------------

    def _send_report(self, i, tick_ms, out, flags):
        self._send(self._ev_seq[i], tick_ms, out, self._ev_raw[i], self._ev_n[i], self._ev_channel[i], flags, i,
                   self._auth[i] is not None)

    def _send(self, seq, tick_ms, out, raw, n, channel, flags, beacon, auth=False):
        # auth: entry `beacon` is a PFDOA_AUTH entry, an AUTH_REPORT on the UART (SPEC 9.5)
        if self._to_uart and auth:
            struct.pack_into(D.MSG_AUTH_REPORT_FMT, self._enc.payload, 0, seq, tick_ms, out, raw, n, channel,
                             flags, beacon, self._ev_counter[beacon], self._ev_tag[beacon])
            self._uart_write(self._enc.finish(D.MSG_AUTH_REPORT, self.anchor_id, D.MSG_AUTH_REPORT_LEN))
        elif self._to_uart:
            struct.pack_into(D.MSG_RSSI_REPORT_FMT, self._enc.payload, 0, seq, tick_ms, out, raw, n, channel,
                             flags, beacon)
            self._uart_write(self._enc.finish(D.MSG_RSSI_REPORT, self.anchor_id,
                                              D.MSG_RSSI_REPORT_LEN))
        if self._to_can:
            struct.pack_into(D.CAN_RSSI_REPORT_FMT, self._can_buf, 0, seq, out, raw, flags, beacon)
            self._can_send(W.can_id(D.CAN_RSSI_REPORT, self.anchor_id), self._can_mv_report)

    def _send_ack(self, token, result, via_can):
        if via_can:
            if self._can_send is not None:
                struct.pack_into(D.MSG_CONFIG_ACK_FMT, self._can_buf, 0, token, result,
                                 self.config_hash)
                self._can_send(W.can_id(D.CAN_CONFIG_ACK, self.anchor_id), self._can_mv_ack)
        elif self._uart_write is not None:
            struct.pack_into(D.MSG_CONFIG_ACK_FMT, self._enc.payload, 0, token, result,
                             self.config_hash)
            self._uart_write(self._enc.finish(D.MSG_CONFIG_ACK, self.anchor_id,
                                              D.MSG_CONFIG_ACK_LEN))

    def _send_status(self, tick_ms):
        up = ((tick_ms - self.boot_tick) & _M32) // 1000
        if self._to_uart:
            struct.pack_into(D.MSG_STATUS_FMT, self._enc.payload, 0, self._fw_major,
                             self._fw_minor, up, self.config_hash, self.dropped_events,
                             self.rx_errors, self.spikes, D.DEFS_HASH, self.filter_hash, _NS)
            self._uart_write(self._enc.finish(D.MSG_STATUS, self.anchor_id, D.MSG_STATUS_LEN))
        if self._to_can:
            struct.pack_into(D.CAN_STATUS_A_FMT, self._can_buf, 0, self._fw_major,
                             self._fw_minor, up, self.config_hash)
            self._can_send(W.can_id(D.CAN_STATUS_A, self.anchor_id), self._can_mv)
            struct.pack_into(D.CAN_STATUS_B_FMT, self._can_buf, 0, self.dropped_events,
                             self.rx_errors, self.spikes, D.DEFS_HASH)
            self._can_send(W.can_id(D.CAN_STATUS_B, self.anchor_id), self._can_mv)
            struct.pack_into(D.CAN_STATUS_C_FMT, self._can_buf, 0, self.filter_hash, _NS)
            self._can_send(W.can_id(D.CAN_STATUS_C, self.anchor_id), self._can_mv_c)
        if self._to_uart and self._has_auth:
            # SPEC 9.5: rejections by reason, UART only, after the STATUS (and its CAN
            # frames, in the C core's order)
            r = self.auth_rejected
            struct.pack_into(D.MSG_AUTH_STATUS_FMT, self._enc.payload, 0, r[0], r[1], r[2])
            self._uart_write(self._enc.finish(D.MSG_AUTH_STATUS, self.anchor_id, D.MSG_AUTH_STATUS_LEN))


class Tick32:
    """The SPEC's u32 millisecond tick from a port's ticks_ms(), whose period is
    shorter (2**30 on most ports): accumulates ticks_diff() steps modulo 2**32.
    now() must run more often than half the port's tick period."""

    def __init__(self, ticks_ms, ticks_diff, start=0):
        self._ticks_ms = ticks_ms
        self._ticks_diff = ticks_diff
        self._raw = ticks_ms()
        self._t32 = start & _M32

    def now(self):
        raw = self._ticks_ms()
        self._t32 = (self._t32 + self._ticks_diff(raw, self._raw)) & _M32
        self._raw = raw
        return self._t32

    def at(self, raw):
        """The u32 tick of a raw ticks_ms() value taken near the last now()."""
        return (self._t32 + self._ticks_diff(raw, self._raw)) & _M32


class ReadingQueue:
    """Fixed-size single-producer single-consumer ring between the radio IRQ and the
    main loop, so the core never runs inside an interrupt. put(), put_match() and
    put_auth() never allocate. An entry is a match result (pfdoa_match: entry, has_seq,
    seq): put() queues a reading of entry 0 with its seq, put_match() whatever the IRQ
    matched, put_auth() a copy of our authenticated beacon's payload, which the core
    verifies when the queue is drained (the HMAC is no work for an interrupt)."""

    def __init__(self, size=32):
        self._size = size
        self._code = array.array("i", bytes(4 * size))
        self._rssi = array.array("b", bytes(size))
        self._chan = bytearray(size)
        self._raw_tick = array.array("i", bytes(4 * size))  # port ticks_ms(), < 2**30
        self._auth = bytearray(_AL * size)  # put_auth()'s payloads, one slot per entry
        self._head = 0  # written by the producer only
        self._tail = 0  # written by the consumer only
        self.lost = 0  # readings refused because the ring was full

    def put(self, seq, rssi_dbm, channel, raw_tick):
        return self.put_match((1 << 16) | (seq & 0xFFFF), rssi_dbm, channel, raw_tick)

    def put_match(self, code, rssi_dbm, channel, raw_tick):
        h = self._head
        nxt = h + 1 if h + 1 < self._size else 0
        if nxt == self._tail:
            self.lost += 1
            return False
        self._code[h] = code
        self._rssi[h] = rssi_dbm
        self._chan[h] = channel
        self._raw_tick[h] = raw_tick
        self._head = nxt
        return True

    def put_auth(self, buf, at, rssi_dbm, channel, raw_tick):
        h = self._head
        if (h + 1 if h + 1 < self._size else 0) == self._tail:
            self.lost += 1
            return False
        d = h * _AL
        for k in range(_AL):
            self._auth[d + k] = buf[at + k]
        return self.put_match(_AUTH_QUEUED, rssi_dbm, channel, raw_tick)

    def drain(self, anchor, radio, tick32):
        """Feeds every queued reading to anchor, then reports lost ones as dropped."""
        t = self._tail
        while t != self._head:
            if self._code[t] == _AUTH_QUEUED:
                anchor.auth_payload(self._auth, t * _AL, self._rssi[t], self._chan[t], radio,
                                    tick32.at(self._raw_tick[t]))
            else:
                anchor.matched(self._code[t], self._rssi[t], self._chan[t], radio,
                               tick32.at(self._raw_tick[t]))
            t = t + 1 if t + 1 < self._size else 0
            self._tail = t
        while self.lost:
            self.lost -= 1
            anchor.reading_lost()
