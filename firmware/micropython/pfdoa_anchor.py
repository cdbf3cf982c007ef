# pfdoa anchor core for MicroPython: the fixed-point filter and state machine of
# protocol/SPEC.md section 3, byte-identical to the C core (firmware/core). Pure: no
# hardware access; time, output and config storage come in through the constructor.
# Integer arithmetic only (// is floor division, as the SPEC requires).
from micropython import const
import struct
import pfdoa_defs as D
import pfdoa_wire as W

FW_MAJOR = const(1)  # firmware version reported in STATUS (independent of the protocol)
FW_MINOR = const(0)

_M32 = const(0xFFFFFFFF)
_SAT16 = const(0xFFFF)
_CONFIG_FMT = "<hHBBB"  # offset_q8, alpha_q8, spike_db, report_mode, decimation (SPEC 1.3)

# Message types this receiver accepts (everything else is unknown_type).
_RX_TYPES = ((D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_LEN),)
_RX_TYPES_SIL = ((D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_LEN),)
_TX_EXTRA = ((D.MSG_RSSI_REPORT, D.MSG_RSSI_REPORT_CRC_EXTRA),
             (D.MSG_STATUS, D.MSG_STATUS_CRC_EXTRA),
             (D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_CRC_EXTRA),
             (D.MSG_CONFIG_ACK, D.MSG_CONFIG_ACK_CRC_EXTRA),
             (D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_CRC_EXTRA))


def default_config():
    c = bytearray(D.CONFIG_LEN)
    struct.pack_into(_CONFIG_FMT, c, 0, D.DEFAULT_OFFSET_Q8, D.DEFAULT_ALPHA_Q8,
                     D.DEFAULT_SPIKE_DB, D.DEFAULT_REPORT_MODE, D.DEFAULT_DECIMATION)
    return c


def config_valid(alpha_q8, report_mode, decimation):
    return (D.VALID_ALPHA_Q8_MIN <= alpha_q8 <= D.VALID_ALPHA_Q8_MAX
            and D.VALID_REPORT_MODE_MIN <= report_mode <= D.VALID_REPORT_MODE_MAX
            and D.VALID_DECIMATION_MIN <= decimation <= D.VALID_DECIMATION_MAX)


def _tables(sil_inject):
    plen = bytearray(b"\xff" * 256)
    extra = bytearray(256)
    to_host = bytearray(256)  # the anchor accepts no anchor-to-host type
    for t, x in _TX_EXTRA:
        extra[t] = x
    for t, n in _RX_TYPES + (_RX_TYPES_SIL if sil_inject else ()):
        plen[t] = n
    return plen, extra, to_host


def _channel_ok(radio, channel):
    if radio == D.RADIO_BLE:
        return D.CHANNEL_BLE_MIN <= channel <= D.CHANNEL_BLE_MAX
    if radio == D.RADIO_IEEE802154:
        return D.CHANNEL_IEEE802154_MIN <= channel <= D.CHANNEL_IEEE802154_MAX
    return False


class Anchor:
    """One anchor. Feed it reading(), poll(), uart_rx() and can_rx(); it emits frames
    through uart_write(memoryview) and/or can_send(can_id, memoryview) as they happen.

    The memoryviews passed to the callbacks are only valid during the call.
    config: 7 stored bytes (None = defaults); store(config_bytes) -> bool persists."""

    def __init__(self, anchor_id, tick_ms, uart_write=None, can_send=None,
                 config=None, store=None, sil_inject=False, fw=(FW_MAJOR, FW_MINOR)):
        self.anchor_id = anchor_id
        self._fw_major, self._fw_minor = fw
        self._uart_write = uart_write
        self._can_send = can_send
        self._store = store
        plen, extra, to_host = _tables(sil_inject)
        self._enc = W.FrameEncoder(extra)
        self._dec = W.FrameDecoder(plen, extra, to_host, self._on_frame, self._on_rx_error)
        self._can_buf = bytearray(8)
        self._can_mv = memoryview(self._can_buf)
        self._can_mv4 = self._can_mv[:4]
        self._cfg = bytearray(D.CONFIG_LEN)
        self.reset(tick_ms, config)

    def reset(self, tick_ms, config=None):
        """State as after power-up at tick_ms (config: stored bytes or None)."""
        self._cfg[:] = default_config()
        if config is not None and len(config) == D.CONFIG_LEN:
            offset, alpha, spike, mode, dec = struct.unpack_from(_CONFIG_FMT, config, 0)
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
        self.rx_error_kinds = bytearray(W.N_ERRORS)
        # filter
        self.ema_q8 = 0
        self.have_ema = False
        self.spike_run = 0
        # open event
        self._ev_open = False
        self._ev_seq = 0
        self._ev_radio = 0
        self._ev_n = 0
        self._ev_sum = 0
        self._ev_first = 0
        self._ev_raw = 0
        self._ev_channel = 0
        self._ev_flags = 0
        # decimation (mode 1)
        self._dec_count = 0
        self._dec_flags = 0

    def _load_config(self):
        (self.offset_q8, self.alpha_q8, self.spike_db, self.report_mode,
         self.decimation) = struct.unpack_from(_CONFIG_FMT, self._cfg, 0)
        self.config_hash = W.crc16(self._cfg)

    @property
    def config(self):
        return bytes(self._cfg)

    # ---- radio path -------------------------------------------------------------

    def reading(self, seq, rssi_dbm, channel, lqi, radio, tick_ms):
        """One radio reading, as the radio driver saw it at tick_ms."""
        tick_ms &= _M32
        if rssi_dbm == D.RSSI_INVALID or not _channel_ok(radio, channel):
            if self.dropped_events < _SAT16:
                self.dropped_events += 1
            return
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
        if radio or self._ev_n >= D.BLE_EVENT_MAX_READINGS:
            self._close(tick_ms)

    def poll(self, tick_ms):
        """Periodic work: event timeout, then STATUS when due."""
        tick_ms &= _M32
        if self._ev_open and ((tick_ms - self._ev_first) & _M32) >= D.EVENT_TIMEOUT_MS:
            self._close(tick_ms)
        if not self._status_sent or ((tick_ms - self._last_status) & _M32) >= D.STATUS_PERIOD_MS:
            self._status_sent = True
            self._last_status = tick_ms
            self._send_status(tick_ms)

    def _close(self, tick_ms):
        self._ev_open = False
        n = self._ev_n
        mean = (512 * self._ev_sum + n) // (2 * n)
        flags = self._ev_flags
        if self._ev_radio:
            flags |= D.FLAG_ZIGBEE
        ema = self.ema_q8
        reinit = not self.have_ema
        if not reinit and self.spike_db and abs(mean - ema) > 256 * self.spike_db:
            if self.spike_run >= D.SPIKE_RUN_RESET:
                reinit = True
            else:
                self.spike_run += 1
                if self.spikes < _SAT16:
                    self.spikes += 1
                flags |= D.FLAG_SPIKE
        elif not reinit:
            self.spike_run = 0
            self.ema_q8 = ema + (self.alpha_q8 * (mean - ema) + 128) // 256
        if reinit:
            self.ema_q8 = mean
            self.have_ema = True
            self.spike_run = 0
            flags |= D.FLAG_RESET
        out = self.ema_q8 + self.offset_q8
        if out > 32767:
            out = 32767
            flags |= D.FLAG_SATURATED
        elif out < -32768:
            out = -32768
            flags |= D.FLAG_SATURATED
        if self.offset_q8:
            flags |= D.FLAG_CALIBRATED
        mode = self.report_mode
        if mode == 0:
            self._send_report(tick_ms, out, flags)
        elif mode == 1:
            self._dec_flags |= flags
            self._dec_count += 1
            if self._dec_count >= self.decimation:
                self._send_report(tick_ms, out, self._dec_flags)
                self._dec_count = 0
                self._dec_flags = 0

    # ---- host input ---------------------------------------------------------------

    def uart_rx(self, data):
        """Bytes from the host UART (any chunking)."""
        self._dec.feed(data)

    def can_rx(self, can_id, data):
        """One received classic CAN frame (already through the acceptance filter or not)."""
        if (can_id >> 7) != D.CAN_CONFIG_SET:
            return
        aid = can_id & 0x7F
        if aid != self.anchor_id and aid != D.ANCHOR_BROADCAST:
            return
        if len(data) != 8:
            self._on_rx_error(D.ERR_BAD_LENGTH)
            return
        self._config_set(data)

    def _on_rx_error(self, err):
        if self.rx_errors < _SAT16:
            self.rx_errors += 1
        k = self.rx_error_kinds
        i = -1 - err  # ERR_* are -1..-8
        if k[i] < 255:
            k[i] += 1

    def _on_frame(self, msg_type, anchor_id, payload, n):
        if anchor_id != self.anchor_id and anchor_id != D.ANCHOR_BROADCAST:
            return
        if msg_type == D.MSG_CONFIG_SET:
            self._config_set(payload)
        elif msg_type == D.MSG_RADIO_INJECT:
            seq, tick, rssi, ch, lqi, radio = struct.unpack_from("<HIbBBB", payload, 0)
            self.reading(seq, rssi, ch, lqi, radio, tick)

    def _config_set(self, p):
        token = p[0]
        offset, alpha, spike, mode, dec = struct.unpack_from(_CONFIG_FMT, p, 1)
        if not config_valid(alpha, mode, dec):
            result = D.ACK_INVALID
        else:
            self._cfg[:] = p[1:8]
            self._load_config()
            # A new configuration starts a new decimation cycle.
            self._dec_count = 0
            self._dec_flags = 0
            result = D.ACK_OK
            if self._store is not None and not self._store(self._cfg):
                result = D.ACK_STORE_FAILED
        self._send_ack(token, result)

    # ---- output -------------------------------------------------------------------

    def _send_report(self, tick_ms, out, flags):
        seq = self._ev_seq
        raw = self._ev_raw
        n = self._ev_n
        ch = self._ev_channel
        if self._uart_write is not None:
            struct.pack_into("<HIhbBBB", self._enc.payload, 0,
                             seq, tick_ms, out, raw, n, ch, flags)
            self._uart_write(self._enc.finish(D.MSG_RSSI_REPORT, self.anchor_id, 12))
        if self._can_send is not None:
            struct.pack_into("<HhbBBB", self._can_buf, 0, seq, out, raw, n, ch, flags)
            self._can_send((D.CAN_RSSI_REPORT << 7) | self.anchor_id, self._can_mv)

    def _send_ack(self, token, result):
        if self._uart_write is not None:
            struct.pack_into("<BBH", self._enc.payload, 0, token, result, self.config_hash)
            self._uart_write(self._enc.finish(D.MSG_CONFIG_ACK, self.anchor_id, 4))
        if self._can_send is not None:
            struct.pack_into("<BBH", self._can_buf, 0, token, result, self.config_hash)
            self._can_send((D.CAN_CONFIG_ACK << 7) | self.anchor_id, self._can_mv4)

    def _send_status(self, tick_ms):
        up = ((tick_ms - self.boot_tick) & _M32) // 1000
        if self._uart_write is not None:
            struct.pack_into("<BBIHHHHH", self._enc.payload, 0, self._fw_major, self._fw_minor, up,
                             self.config_hash, self.dropped_events, self.rx_errors,
                             self.spikes, D.DEFS_HASH)
            self._uart_write(self._enc.finish(D.MSG_STATUS, self.anchor_id, 16))
        if self._can_send is not None:
            struct.pack_into("<BBIH", self._can_buf, 0, self._fw_major, self._fw_minor, up,
                             self.config_hash)
            self._can_send((D.CAN_STATUS_A << 7) | self.anchor_id, self._can_mv)
            struct.pack_into("<HHHH", self._can_buf, 0, self.dropped_events,
                             self.rx_errors, self.spikes, D.DEFS_HASH)
            self._can_send((D.CAN_STATUS_B << 7) | self.anchor_id, self._can_mv)
