# pfdoa anchor core for MicroPython: the fixed-point filter and state machine of
# protocol/SPEC.md section 3, byte-identical to the C core (firmware/core). Pure: no
# hardware access; ticks, output and config storage come in through the API.
# Integer arithmetic only (// is floor division, as the SPEC requires).
from micropython import const
import array
import struct
import pfdoa_defs as D
import pfdoa_wire as W

FW_MAJOR = const(1)  # firmware version reported in STATUS (independent of the protocol)
FW_MINOR = const(0)

TRANSPORT_UART = const(1)
TRANSPORT_CAN = const(2)

_M32 = const(0xFFFFFFFF)
_SAT16 = const(0xFFFF)
_Q8_MAX = const(32767)
_Q8_MIN = const(-32768)

# Message types an anchor accepts (everything else is unknown_type, SPEC 2.3).
_RX_TYPES = ((D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_LEN),)
_RX_TYPES_SIL = ((D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_LEN),)
_EXTRA = ((D.MSG_RSSI_REPORT, D.MSG_RSSI_REPORT_CRC_EXTRA),
          (D.MSG_STATUS, D.MSG_STATUS_CRC_EXTRA),
          (D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_CRC_EXTRA),
          (D.MSG_CONFIG_ACK, D.MSG_CONFIG_ACK_CRC_EXTRA),
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
    """One anchor. Feed it reading(), poll(), uart_rx() and can_rx(); it emits frames as
    they happen through uart_write(memoryview) and can_send(can_id, memoryview), which
    must consume the buffer before returning (it is reused).

    transports: TRANSPORT_UART | TRANSPORT_CAN bits that carry reports and STATUS
    (default: every transport with a callback). A CONFIG_ACK goes out on the transport
    its CONFIG_SET came from. config: 7 stored bytes (None or invalid: defaults);
    store(config_bytes) -> bool persists an applied configuration.
    sil_inject: accept RADIO_INJECT frames (test builds only, SPEC 1.5)."""

    def __init__(self, anchor_id, tick_ms, uart_write=None, can_send=None, transports=0,
                 config=None, store=None, sil_inject=False, fw=(FW_MAJOR, FW_MINOR)):
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
        plen, extra, to_host = _tables(sil_inject)
        self._enc = W.FrameEncoder(extra)
        self._dec = W.FrameDecoder(plen, extra, to_host, self._on_frame, self._on_rx_error)
        self._can_buf = bytearray(D.CAN_RSSI_REPORT_DLC)
        self._can_mv = memoryview(self._can_buf)
        self._can_mv_ack = self._can_mv[:D.CAN_CONFIG_ACK_DLC]
        self._cfg = bytearray(D.CONFIG_LEN)
        self.rx_error_kinds = bytearray(D.ERR_COUNT)
        self.reset(tick_ms, config)

    def reset(self, tick_ms, config=None):
        """State as after power-up at tick_ms (config: stored bytes or None)."""
        self._cfg[:] = default_config()
        if config is not None and len(config) == D.CONFIG_LEN:
            offset, alpha, spike, mode, dec = struct.unpack_from(D.CONFIG_FMT, config, 0)
            if config_valid(alpha, mode, dec):
                self._cfg[:] = config
        self._load_config()
        self._dec.reset()
        self.boot_tick = tick_ms & _M32
        self._status_sent = False
        self._last_status = 0
        self.dropped_events = 0
        self.rx_errors = 0
        self.spikes = 0
        for i in range(D.ERR_COUNT):
            self.rx_error_kinds[i] = 0
        # filter
        self.ema_q8 = 0
        self.have_ema = False
        self.spike_run = 0
        # open event (the last closed one's fields stay for mode-1 reports)
        self._ev_open = False
        self._ev_seq = 0
        self._ev_radio = 0
        self._ev_n = 0
        self._ev_sum = 0
        self._ev_first = 0
        self._ev_raw = 0
        self._ev_channel = 0
        self._ev_flags = 0
        # mode-1 counter and flag accumulator
        self._dec_count = 0
        self._dec_flags = 0

    def _load_config(self):
        (self.offset_q8, self.alpha_q8, self.spike_db, self.report_mode,
         self.decimation) = struct.unpack_from(D.CONFIG_FMT, self._cfg, 0)
        self.config_hash = W.crc16(self._cfg)

    @property
    def config(self):
        return bytes(self._cfg)

    # ---- radio path -------------------------------------------------------------

    def reading(self, seq, rssi_dbm, channel, lqi, radio, tick_ms):
        """One radio reading, as the radio driver saw it at tick_ms."""
        if rssi_dbm == D.RSSI_INVALID or not _channel_ok(radio, channel):
            if self.dropped_events < _SAT16:
                self.dropped_events += 1
            return
        tick_ms &= _M32
        flags = 0
        if rssi_dbm > D.RSSI_MAX_DBM:
            rssi_dbm = D.RSSI_MAX_DBM
            flags = D.FLAG_SATURATED
        elif rssi_dbm < D.RSSI_MIN_DBM:
            rssi_dbm = D.RSSI_MIN_DBM
            flags = D.FLAG_SATURATED
        if self._ev_open and (self._ev_seq != seq or self._ev_radio != radio):
            self._close(tick_ms)
        if not self._ev_open:
            self._ev_open = True
            self._ev_seq = seq
            self._ev_radio = radio
            self._ev_n = 0
            self._ev_sum = 0
            self._ev_first = tick_ms
            self._ev_flags = 0
        self._ev_n += 1
        self._ev_sum += rssi_dbm
        self._ev_raw = rssi_dbm
        self._ev_channel = channel
        self._ev_flags |= flags
        if radio == D.RADIO_IEEE802154 or self._ev_n >= D.BLE_EVENT_MAX_READINGS:
            self._close(tick_ms)

    def reading_lost(self):
        """A reading the board lost before the core (queue full): counts as dropped."""
        if self.dropped_events < _SAT16:
            self.dropped_events += 1

    def poll(self, tick_ms):
        """Periodic work: event timeout first, then STATUS when due (SPEC 1.2, 3)."""
        tick_ms &= _M32
        if self._ev_open and ((tick_ms - self._ev_first) & _M32) >= D.EVENT_TIMEOUT_MS:
            self._close(tick_ms)
        if not self._status_sent or ((tick_ms - self._last_status) & _M32) >= D.STATUS_PERIOD_MS:
            self._status_sent = True
            self._last_status = tick_ms
            self._send_status(tick_ms)

    def _close(self, tick_ms):
        self._ev_open = False
        mean = fold_q8(self._ev_sum, self._ev_n)
        flags = self._ev_flags
        if self._ev_radio == D.RADIO_IEEE802154:
            flags |= D.FLAG_ZIGBEE
        ema = self.ema_q8
        reinit = not self.have_ema
        if not reinit and self.spike_db and abs(mean - ema) > 256 * self.spike_db:
            if self.spike_run >= D.SPIKE_RUN_RESET:
                reinit = True  # a real level change, not a spike
            else:
                self.spike_run += 1
                if self.spikes < _SAT16:
                    self.spikes += 1
                flags |= D.FLAG_SPIKE
        elif not reinit:
            self.spike_run = 0
            self.ema_q8 = ema_step_q8(ema, mean, self.alpha_q8)
        if reinit:
            self.ema_q8 = mean
            self.have_ema = True
            self.spike_run = 0
            flags |= D.FLAG_RESET
        out = self.ema_q8 + self.offset_q8
        if out > _Q8_MAX:
            out = _Q8_MAX
            flags |= D.FLAG_SATURATED
        elif out < _Q8_MIN:
            out = _Q8_MIN
            flags |= D.FLAG_SATURATED
        if self.offset_q8:
            flags |= D.FLAG_CALIBRATED
        mode = self.report_mode
        if mode == D.REPORT_EVERY:
            self._send_report(tick_ms, out, flags)
        elif mode == D.REPORT_DECIMATE:
            self._dec_flags |= flags
            self._dec_count += 1
            if self._dec_count >= self.decimation:
                flags = self._dec_flags
                self._dec_count = 0
                self._dec_flags = 0
                self._send_report(tick_ms, out, flags)

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
        elif msg_type == D.MSG_RADIO_INJECT:
            seq, tick, rssi, ch, lqi, radio = struct.unpack_from(D.MSG_RADIO_INJECT_FMT, payload, 0)
            self.reading(seq, rssi, ch, lqi, radio, tick)

    def _config_set(self, p, via_can):
        token = p[0]
        offset, alpha, spike, mode, dec = struct.unpack_from(D.CONFIG_FMT, p, 1)
        if not config_valid(alpha, mode, dec):
            result = D.ACK_INVALID  # nothing changes
        else:
            # The whole configuration at once; the filter state is kept, a new
            # decimation cycle starts.
            for i in range(D.CONFIG_LEN):
                self._cfg[i] = p[1 + i]
            self._load_config()
            self._dec_count = 0
            self._dec_flags = 0
            result = D.ACK_OK
            if self._store is None or not self._store(self._cfg):
                result = D.ACK_STORE_FAILED
        self._send_ack(token, result, via_can)

    # ---- output -------------------------------------------------------------------

    def _send_report(self, tick_ms, out, flags):
        if self._to_uart:
            struct.pack_into(D.MSG_RSSI_REPORT_FMT, self._enc.payload, 0, self._ev_seq, tick_ms,
                             out, self._ev_raw, self._ev_n, self._ev_channel, flags)
            self._uart_write(self._enc.finish(D.MSG_RSSI_REPORT, self.anchor_id,
                                              D.MSG_RSSI_REPORT_LEN))
        if self._to_can:
            struct.pack_into(D.CAN_RSSI_REPORT_FMT, self._can_buf, 0, self._ev_seq, out,
                             self._ev_raw, self._ev_n, self._ev_channel, flags)
            self._can_send(W.can_id(D.CAN_RSSI_REPORT, self.anchor_id), self._can_mv)

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
                             self.rx_errors, self.spikes, D.DEFS_HASH)
            self._uart_write(self._enc.finish(D.MSG_STATUS, self.anchor_id, D.MSG_STATUS_LEN))
        if self._to_can:
            struct.pack_into(D.CAN_STATUS_A_FMT, self._can_buf, 0, self._fw_major,
                             self._fw_minor, up, self.config_hash)
            self._can_send(W.can_id(D.CAN_STATUS_A, self.anchor_id), self._can_mv)
            struct.pack_into(D.CAN_STATUS_B_FMT, self._can_buf, 0, self.dropped_events,
                             self.rx_errors, self.spikes, D.DEFS_HASH)
            self._can_send(W.can_id(D.CAN_STATUS_B, self.anchor_id), self._can_mv)


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
    main loop, so the core never runs inside an interrupt. put() never allocates."""

    def __init__(self, size=32):
        self._size = size
        self._seq = array.array("H", bytes(2 * size))
        self._rssi = array.array("b", bytes(size))
        self._chan = bytearray(size)
        self._raw_tick = array.array("i", bytes(4 * size))  # port ticks_ms(), < 2**30
        self._head = 0  # written by the producer only
        self._tail = 0  # written by the consumer only
        self.lost = 0  # readings refused because the ring was full

    def put(self, seq, rssi_dbm, channel, raw_tick):
        h = self._head
        nxt = h + 1 if h + 1 < self._size else 0
        if nxt == self._tail:
            self.lost += 1
            return False
        self._seq[h] = seq & 0xFFFF
        self._rssi[h] = rssi_dbm
        self._chan[h] = channel
        self._raw_tick[h] = raw_tick
        self._head = nxt
        return True

    def drain(self, anchor, radio, tick32):
        """Feeds every queued reading to anchor, then reports lost ones as dropped."""
        t = self._tail
        while t != self._head:
            anchor.reading(self._seq[t], self._rssi[t], self._chan[t], 0, radio,
                           tick32.at(self._raw_tick[t]))
            t = t + 1 if t + 1 < self._size else 0
            self._tail = t
        while self.lost:
            self.lost -= 1
            anchor.reading_lost()
