# Unit tests of the anchor state machine (SPEC section 3) on the MicroPython unix port.
import struct

import micropython
import pfdoa_defs as D
import pfdoa_match as M
import pfdoa_wire as W
from pfdoa_anchor import TRANSPORT_CAN, Anchor, ReadingQueue, Tick32, default_config

BLE = D.RADIO_BLE
ZB = D.RADIO_IEEE802154


class Rig:
    """An anchor whose UART and CAN output is captured and decoded."""

    def __init__(self, aid=5, tick=0, store=None, config=None, uart=True, can=False):
        self.frames = []  # raw UART frames (with delimiter)
        self.can = []
        if store is None:
            store = _store_ok
        self.a = Anchor(aid, tick, uart_write=self._uart if uart else None,
                        can_send=self._can if can else None, store=store, config=config,
                        store_filters=store)

    def _uart(self, mv):
        self.frames.append(bytes(mv))

    def _can(self, cid, mv):
        self.can.append((cid, bytes(mv)))

    def msgs(self):
        """Decoded (type, anchor_id, payload) of every UART frame so far (SPEC 2.1,
        checked here by hand: COBS body, trailer CRC over the encoded bytes); clears."""
        out = []
        for f in self.frames:
            assert f[-1] == 0 and 0 not in f[:-1]
            e = len(f) - 1 - D.TRAILER_LEN
            raw = bytearray(len(f))
            n = W.cobs_decode(f, e, raw)
            assert n >= 3 and raw[0] == D.PROTO_VERSION
            t = raw[1]
            assert W.trailer_crc(f, e) == W.crc16_byte(W.crc16(f, 0, e), _EXTRA[t])
            out.append((t, raw[2], bytes(raw[3:n])))
        self.frames = []
        return out

    def reports_b(self):
        """(seq, tick, rssi_q8, raw, n, ch, flags, beacon) of reports; other frames dropped."""
        return [struct.unpack(D.MSG_RSSI_REPORT_FMT, p) for t, a, p in self.msgs()
                if t == D.MSG_RSSI_REPORT]

    def reports(self):
        """The same without the beacon entry, for reports of entry 0 (asserted)."""
        out = self.reports_b()
        assert all(r[7] == 0 for r in out)
        return [r[:7] for r in out]

    def statuses(self):
        return [struct.unpack(D.MSG_STATUS_FMT, p) for t, a, p in self.msgs()
                if t == D.MSG_STATUS]

    def ble(self, seq, rssi, tick, ch=37):
        self.a.reading(seq, rssi, ch, 0, BLE, tick)

    def config_set(self, token, offset=0, alpha=64, spike=12, mode=0, dec=1, aid=5):
        self.a.uart_rx(_frame(D.MSG_CONFIG_SET, aid,
                              struct.pack(D.MSG_CONFIG_SET_FMT, token, offset, alpha, spike, mode, dec)))

    def filter_set(self, token, index, entry, aid=5):
        self.a.uart_rx(_frame(D.MSG_FILTER_SET, aid, bytes((token, index)) + entry))


def _store_ok(cfg):
    return True


_EXTRA = {D.MSG_RSSI_REPORT: D.MSG_RSSI_REPORT_CRC_EXTRA, D.MSG_STATUS: D.MSG_STATUS_CRC_EXTRA,
          D.MSG_CONFIG_ACK: D.MSG_CONFIG_ACK_CRC_EXTRA, D.MSG_FILTER_ACK: D.MSG_FILTER_ACK_CRC_EXTRA,
          D.MSG_AUTH_REPORT: D.MSG_AUTH_REPORT_CRC_EXTRA, D.MSG_AUTH_STATUS: D.MSG_AUTH_STATUS_CRC_EXTRA}
_ENC_EXTRA = bytearray(256)
for _t, _x in ((D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_CRC_EXTRA), (D.MSG_FILTER_SET, D.MSG_FILTER_SET_CRC_EXTRA),
               (D.MSG_RSSI_REPORT, D.MSG_RSSI_REPORT_CRC_EXTRA)):
    _ENC_EXTRA[_t] = _x


def _frame(msg_type, aid, payload):
    """A whole version-2 frame with its delimiter, through the wire module's encoder."""
    enc = W.FrameEncoder(_ENC_EXTRA)
    enc.payload[:len(payload)] = payload
    return bytes(enc.finish(msg_type, aid, len(payload)))


def _entry(kind, period, match):
    return struct.pack(D.FILTER_ENTRY_FMT, kind, period, match)


def _ours_adv(seq, bid):
    """Our beacon's AdvData (SPEC 6), written out from the SPEC."""
    return bytes((2, D.BLE_AD_FLAGS, D.BLE_FLAGS_GENERAL_NO_BREDR, 8, D.BLE_AD_MANUFACTURER, 0xFF, 0xFF,
                  D.BEACON_MAGIC0, D.BEACON_MAGIC1, seq & 0xFF, seq >> 8, bid))


def _fold(readings):
    s = sum(readings)
    n = len(readings)
    return (512 * s + n) // (2 * n)


def test_fold_round_half_up_with_floor_division():
    for rs in ((-60,), (-60, -61), (-60, -60, -61), (-61, -61, -60), (-1, -2),
               (-128, -128, -127), (20, 19, 19), (0, -1, -1)):
        r = Rig()
        for i, x in enumerate(rs):
            r.ble(1, x, i)
        r.ble(2, -50, 10)
        rep = r.reports()
        assert len(rep) == 1 and rep[0][2] == _fold(rs), (rs, rep)
        assert rep[0][4] == len(rs)
    # exact halves go up: -60.5 dB * 256 = -15488 exactly; -1.5 dB -> -384
    assert _fold((-60, -61)) == -15488 and _fold((-1, -2)) == -384
    # 256 * -181 / 3 = -15445.33 -> -15445
    assert _fold((-60, -60, -61)) == -15445


def test_ble_event_closes_on_three_readings_at_third_tick():
    r = Rig()
    r.ble(7, -60, 100, ch=37)
    r.ble(7, -62, 101, ch=38)
    assert r.reports() == []
    r.ble(7, -64, 102, ch=39)
    assert r.reports() == [(7, 102, -62 * 256, -64, 3, 39, D.FLAG_RESET)]


def test_new_seq_closes_old_event_at_new_reading_tick():
    r = Rig()
    r.ble(1, -70, 10)
    r.ble(2, -70, 15)
    assert r.reports() == [(1, 15, -70 * 256, -70, 1, 37, D.FLAG_RESET)]


def test_timeout_closes_at_poll_tick_wrap_safe():
    t0 = 0xFFFFFFF0
    r = Rig(tick=t0)
    r.a.poll(t0)
    r.msgs()
    r.ble(3, -50, t0 + 1)
    r.a.poll((t0 + 20) & 0xFFFFFFFF)  # 19 ms after the first reading
    assert r.reports() == []
    r.a.poll((t0 + 21) & 0xFFFFFFFF)
    assert r.reports() == [(3, 5, -50 * 256, -50, 1, 37, D.FLAG_RESET)]


def test_zigbee_event_closes_at_once_and_radio_change_closes():
    r = Rig()
    r.ble(9, -40, 1)
    r.a.reading(9, -41, 15, 200, ZB, 2)  # other radio closes the BLE event first
    rep = r.reports()
    assert [x[0] for x in rep] == [9, 9]
    assert rep[0][6] & D.FLAG_ZIGBEE == 0 and rep[0][1] == 2 and rep[0][4] == 1
    assert rep[1][6] & D.FLAG_ZIGBEE and rep[1][5] == 15 and rep[1][4] == 1


def test_ema_update_floor():
    r = Rig()
    r.ble(1, -60, 0)
    r.ble(2, -70, 5)  # diff 10 dB < 12: not a spike
    r.ble(3, -70, 6)
    rep = r.reports()
    # ema = -15360 + floor((64 * -2560 + 128) / 256) = -15360 - 640
    assert rep[1][2] == -16000 and rep[1][6] == 0
    e = -16000
    m = -70 * 256
    assert r.a.ema_q8 == e
    r.ble(4, -70, 7)
    assert r.reports()[0][2] == e + (64 * (m - e) + 128) // 256


def test_spikes_then_reinit_after_run_of_three():
    r = Rig()
    r.ble(1, -60, 0)
    for s in (2, 3, 4, 5, 6):
        r.ble(s, -80, s)
    rep = r.reports()
    assert rep[0][6] == D.FLAG_RESET
    for k in (1, 2, 3):  # spikes: EMA unchanged
        assert rep[k][6] == D.FLAG_SPIKE and rep[k][2] == -60 * 256
    assert rep[4][6] == D.FLAG_RESET and rep[4][2] == -80 * 256  # 4th: real change
    assert r.a.spikes == 3 and r.a.spike_run == 0
    r.a.poll(100)
    assert r.statuses()[0][6] == 3


def test_spike_run_resets_on_normal_event_and_threshold_is_strict():
    r = Rig()
    r.ble(1, -60, 0)
    r.ble(2, -80, 1)  # spike
    r.ble(3, -72, 2)  # exactly 12 dB: not a spike
    r.ble(4, -100, 3)
    r.ble(5, -100, 4)
    rep = r.reports()
    assert rep[1][6] == D.FLAG_SPIKE and rep[2][6] == 0
    assert rep[3][6] == D.FLAG_SPIKE and r.a.spike_run == 1


def test_spike_db_zero_disables():
    r = Rig()
    r.config_set(1, spike=0)
    r.ble(1, -20, 0)
    r.ble(2, -120, 1)
    r.ble(3, -120, 2)
    rep = r.reports()
    assert rep[1][6] == 0 and r.a.spikes == 0


def test_clamp_and_invalid_readings():
    r = Rig()
    r.ble(1, 127, 0)  # not available
    r.ble(1, -60, 0, ch=40)  # bad BLE channel
    r.a.reading(1, -60, 10, 0, ZB, 0)  # bad 802.15.4 channel
    r.a.reading(1, -60, 11, 0, 2, 0)  # unknown radio
    assert r.a.dropped_events == 4
    r.ble(1, 21, 1)
    r.ble(1, -128, 2)
    r.ble(1, 126, 3)
    rep = r.reports()
    assert rep == [(1, 3, _fold((20, -128, 20)), 20, 3, 37, D.FLAG_SATURATED | D.FLAG_RESET)]
    r.ble(2, -128, 4)
    r.ble(3, 0, 5)
    assert r.reports()[0][6] & D.FLAG_SATURATED == 0  # -128 itself is in range


def test_dropped_counter_saturates():
    r = Rig()
    for _ in range(65540):
        r.ble(1, 127, 0)
    assert r.a.dropped_events == 65535


def test_calibration_and_output_saturation():
    r = Rig()
    r.config_set(1, offset=-512)
    r.msgs()
    r.ble(1, -60, 0)
    r.ble(2, -60, 1)
    assert r.reports()[0][2:] == (-60 * 256 - 512, -60, 1, 37, D.FLAG_CALIBRATED | D.FLAG_RESET)
    r.config_set(2, offset=-32768)
    r.ble(3, -60, 2)
    rep = r.reports()
    assert rep[0][2] == -32768
    assert rep[0][6] == D.FLAG_SATURATED | D.FLAG_CALIBRATED
    r.config_set(3, offset=32767)
    r.ble(4, -60, 3)
    assert r.reports()[0][2] == 32767 - 60 * 256


def test_decimation_mode_accumulates_flags():
    r = Rig()
    r.config_set(1, mode=1, dec=3)
    r.msgs()
    r.ble(1, -60, 0)
    r.ble(2, -90, 1)  # closes 1 (RESET)
    r.ble(3, -60, 2)  # closes 2 (SPIKE)
    assert r.reports() == []
    r.ble(4, -61, 3, ch=38)  # closes 3
    rep = r.reports()
    assert rep == [(3, 3, -60 * 256, -60, 1, 37, D.FLAG_RESET | D.FLAG_SPIKE)]
    for s in (5, 6, 7):
        r.ble(s, -61, 3 + s)
    rep = r.reports()
    assert len(rep) == 1 and rep[0][0] == 6 and rep[0][6] == 0


def test_silent_mode_only_status():
    r = Rig()
    r.config_set(1, mode=2)
    r.msgs()
    for s in range(10):
        r.ble(s, -60, s)
    r.a.poll(50)
    m = r.msgs()
    assert [t for t, a, p in m] == [D.MSG_STATUS]


def test_status_timing_and_contents():
    r = Rig(tick=1000)
    r.a.poll(1000)
    st = r.statuses()
    assert st == [(1, 0, 0, W.crc16(default_config()), 0, 0, 0, D.DEFS_HASH,
                   M.table_hash(M.default_table()), D.BEACON_SLOTS)]
    r.a.poll(1999)
    assert r.statuses() == []
    r.a.poll(2000)
    r.a.poll(2500)
    r.a.poll(2999)
    assert [s[2] for s in r.statuses()] == [1]
    r.a.poll(3499)  # the period restarts at the tick of the last STATUS (3499 - 2000)
    r.a.poll(4000)
    r.a.poll(4498)
    assert [s[2] for s in r.statuses()] == [2]
    r.a.poll(4499)
    assert [s[2] for s in r.statuses()] == [3]
    # uptime across the u32 wrap
    r = Rig(tick=0xFFFFF000)
    r.a.poll(0x00001000)
    assert r.statuses()[0][2] == 0x2000 // 1000


def test_status_after_timeout_report_in_same_poll():
    r = Rig()
    r.ble(1, -60, 0)
    r.a.poll(30)
    assert [t for t, a, p in r.msgs()] == [D.MSG_RSSI_REPORT, D.MSG_STATUS]


def test_config_set_ack_and_hash():
    stored = []
    r = Rig(store=lambda c: stored.append(bytes(c)) or True)
    r.config_set(42, offset=-300, alpha=256, spike=3, mode=1, dec=255)
    new = struct.pack(D.CONFIG_FMT, -300, 256, 3, 1, 255)
    m = r.msgs()
    assert m == [(D.MSG_CONFIG_ACK, 5, struct.pack(D.MSG_CONFIG_ACK_FMT, 42, D.ACK_OK, W.crc16(new)))]
    assert stored == [new] and r.a.config == new
    for bad in (dict(alpha=0), dict(alpha=257), dict(mode=3), dict(dec=0)):
        r.config_set(43, **bad)
        assert r.msgs() == [(D.MSG_CONFIG_ACK, 5, struct.pack(D.MSG_CONFIG_ACK_FMT, 43, D.ACK_INVALID,
                                                               W.crc16(new)))]
    assert r.a.config == new and len(stored) == 1


def test_config_set_addressing():
    r = Rig(aid=5)
    r.config_set(1, aid=6)  # another anchor: ignored, not counted
    assert r.msgs() == []
    r.config_set(2, aid=127, alpha=100)
    m = r.msgs()
    assert len(m) == 1 and m[0][0] == D.MSG_CONFIG_ACK and m[0][1] == 5
    assert r.a.alpha_q8 == 100 and r.a.rx_errors == 0


def test_config_store_failure_still_applies():
    r = Rig(store=lambda c: False)
    r.config_set(7, alpha=10)
    assert r.msgs()[0][2][:2] == bytes((7, D.ACK_STORE_FAILED))
    assert r.a.alpha_q8 == 10


def test_no_store_means_store_failed():
    r = Rig()
    r.a._store = None
    r.config_set(7, alpha=10)
    assert r.msgs()[0][2][:2] == bytes((7, D.ACK_STORE_FAILED))


def test_ack_goes_out_on_the_transport_of_the_config_set():
    r = Rig(aid=9, uart=True, can=True)
    r.a = Anchor(9, 0, uart_write=r._uart, can_send=r._can, transports=TRANSPORT_CAN,
                 store=_store_ok)
    r.a.poll(0)
    r.config_set(1, aid=9)  # over UART: UART ack although reports go to CAN
    r.a.can_rx(W.can_id(D.CAN_CONFIG_SET, 9), struct.pack(D.MSG_CONFIG_SET_FMT, 2, 0, 128, 12, 0, 1))
    r.ble(1, -50, 1)
    r.ble(2, -50, 2)
    m = r.msgs()
    assert [x[0] for x in m] == [D.MSG_CONFIG_ACK]
    assert [c[0] for c in r.can] == [W.can_id(t, 9) for t in (D.CAN_STATUS_A, D.CAN_STATUS_B, D.CAN_STATUS_C,
                                                               D.CAN_CONFIG_ACK, D.CAN_RSSI_REPORT)]


def test_stored_config_loaded_and_invalid_ignored():
    cfg = struct.pack(D.CONFIG_FMT, 100, 32, 6, 2, 9)
    assert Rig(config=cfg).a.config == cfg
    bad = struct.pack(D.CONFIG_FMT, 100, 0, 6, 2, 9)
    assert Rig(config=bad).a.config == bytes(default_config())


def test_rx_errors_counted_in_status():
    r = Rig()
    r.a.uart_rx(b"\x05\x02\x81\x81\x81\x00")  # bad_cobs
    r.a.uart_rx(b"\x01" * 70 + b"\x00")  # overlong
    r.a.uart_rx(b"\x81\x81\x81\x00")  # truncated
    r.a.uart_rx(b"\x05\x01\x03\x05\x00")  # a version-1 frame: bad_version
    r.a.poll(0)
    assert r.statuses()[0][5] == 4
    for e in (D.ERR_OVERLONG, D.ERR_BAD_COBS, D.ERR_TRUNCATED, D.ERR_BAD_VERSION):
        assert r.a.rx_error_kinds[-1 - e] == 1


def test_rssi_report_type_is_unknown_to_the_anchor():
    r = Rig()
    r.a.uart_rx(_frame(D.MSG_RSSI_REPORT, 5, bytes(D.MSG_RSSI_REPORT_LEN)))
    assert r.a.rx_error_kinds[-1 - D.ERR_UNKNOWN_TYPE] == 1


def test_can_output_mapping():
    r = Rig(aid=9, uart=False, can=True)
    r.a.poll(0)
    r.ble(0x1234, -60, 1, ch=38)
    r.ble(0x1235, -60, 2)
    cid = W.can_id
    assert r.can[0] == (cid(D.CAN_STATUS_A, 9), bytes((1, 0, 0, 0, 0, 0)) + struct.pack("<H", r.a.config_hash))
    assert r.can[1] == (cid(D.CAN_STATUS_B, 9), struct.pack(D.CAN_STATUS_B_FMT, 0, 0, 0, D.DEFS_HASH))
    assert r.can[2] == (cid(D.CAN_STATUS_C, 9),
                        struct.pack(D.CAN_STATUS_C_FMT, M.table_hash(M.default_table()), D.BEACON_SLOTS))
    assert r.can[3] == (cid(D.CAN_RSSI_REPORT, 9),
                        struct.pack(D.CAN_RSSI_REPORT_FMT, 0x1234, -60 * 256, -60, D.FLAG_RESET, 0))
    r.can = []
    r.a.can_rx(cid(D.CAN_CONFIG_SET, 9), struct.pack(D.MSG_CONFIG_SET_FMT, 4, 0, 128, 12, 0, 1))
    r.a.can_rx(cid(D.CAN_CONFIG_SET, 10), struct.pack(D.MSG_CONFIG_SET_FMT, 5, 0, 128, 12, 0, 1))  # other anchor
    r.a.can_rx(cid(D.CAN_CONFIG_SET, D.ANCHOR_BROADCAST),
               struct.pack(D.MSG_CONFIG_SET_FMT, 6, 0, 0, 12, 0, 1))  # broadcast, invalid
    r.a.can_rx(cid(D.CAN_CONFIG_SET, 9), b"\x01\x02")  # wrong DLC
    assert r.can == [(cid(D.CAN_CONFIG_ACK, 9), struct.pack(D.MSG_CONFIG_ACK_FMT, 4, 0, r.a.config_hash)),
                     (cid(D.CAN_CONFIG_ACK, 9), struct.pack(D.MSG_CONFIG_ACK_FMT, 6, 1, r.a.config_hash))]
    assert r.a.rx_errors == 1


def test_hot_path_does_not_allocate():
    r = Rig()
    sink = bytearray(32)

    def write(mv):
        sink[0] = mv[0]

    r.a._uart_write = write
    r.ble(1, -60, 0)  # warm up (first frame of each length caches its view)
    r.ble(2, -60, 1)
    r.a.poll(10)
    micropython.heap_lock()
    try:
        for s in range(3, 40):
            r.ble(s, -60 - (s & 7), s)
            r.ble(s, -61, s)
            r.a.poll(s + 25)
        ok = True
    except MemoryError:
        ok = False
    finally:
        micropython.heap_unlock()
    assert ok, "reading()/poll() allocated on the heap"


def test_filter_set_acks_and_raw_receptions_form_events_per_entry():
    stored = []
    r = Rig(store=lambda t: stored.append(bytes(t)) or True)
    r.a.poll(0)
    st = r.statuses()[0]
    assert st[8:] == (M.table_hash(M.default_table()), D.BEACON_SLOTS)
    tag = b"\xa1\xb2\xc3\xd4\xe5\xf6"
    r.filter_set(1, 2, _entry(D.FILTER_MAC48, 50, tag))
    r.filter_set(2, 1, _entry(D.FILTER_PFDOA, 0, b"\x07"))
    r.filter_set(3, 4, _entry(D.FILTER_PFDOA, 0, b"\x07"))  # no entry 4
    r.filter_set(4, 1, _entry(D.FILTER_MAC48, 0, tag))  # a MAC entry needs a period
    acks = [struct.unpack(D.MSG_FILTER_ACK_FMT, p) for t, a, p in r.msgs()]
    assert [a[:3] for a in acks] == [(1, 0, 2), (2, 0, 1), (3, 1, 4), (4, 1, 1)]
    assert acks[-1][3] == r.a.filter_hash == M.table_hash(r.a.filters) and len(stored) == 2
    # Our beacon id 7 (entry 1, by seq) and the tag (entry 2, by time) interleaved.
    for k in range(3):
        r.a.ble_adv(b"\x01" * 6, _ours_adv(40, 7), -60, 37 + k, 10 + k)
        r.a.ble_adv(tag, b"", -80, 37 + k, 11 + k)
    assert not r.a.ble_adv(b"\x01" * 6, _ours_adv(40, 8), -60, 37, 20)  # id 8: nobody's
    r.a.poll(70)
    rep = r.reports_b()
    assert [(x[0], x[4], x[6], x[7]) for x in rep] == [
        (40, 3, D.FLAG_RESET, 1), (0, 3, D.FLAG_RESET | D.FLAG_NO_SEQ, 2)]
    # the tag again after its period: a new event, the entry's own count 1, closed by the poll
    r.a.ble_adv(tag, b"\x02\x01\x06", -81, 37, 100)
    r.a.poll(149)
    assert r.reports_b() == []
    r.a.poll(150)
    assert [(x[0], x[1], x[7]) for x in r.reports_b()] == [(1, 150, 2)]


def test_raw_pdu_and_802154_frames_of_our_beacon():
    r = Rig()
    adv = _ours_adv(77, 0)
    pdu = bytes((D.BLE_PDU_ADV_NONCONN_IND | D.BLE_PDU_TXADD, 6 + len(adv))) + b"\x01" * 6 + adv
    assert r.a.ble_pdu(pdu, len(pdu), -55, 38, 5)
    assert not r.a.ble_pdu(pdu, len(pdu) - 1, -55, 38, 6)  # Length past the end: not a PDU
    # 802.15.4 data frame (SPEC 6): FCF 41 C8, seq, PAN, dst 0xFFFF, src ext, payload
    mpdu = b"\x41\xc8\x2c\xff\xff\xff\xff" + bytes(range(8)) + b"PF\x2c\x01\x00"
    assert r.a.ieee802154(mpdu, len(mpdu), -70, 15, 200, 30)
    rep = r.reports_b()
    assert [(x[0], x[4], x[5], x[6] & D.FLAG_ZIGBEE) for x in rep] == [(77, 1, 38, 0), (300, 1, 15, D.FLAG_ZIGBEE)]


def test_raw_reception_hot_path_does_not_allocate():
    r = Rig()
    sink = bytearray(32)

    def write(mv):
        sink[0] = mv[0]

    r.a._uart_write = write
    tag = b"\xa1\xb2\xc3\xd4\xe5\xf6"
    r.a.set_filter(1, _entry(D.FILTER_MAC48, 30, tag))
    pdus = [bytes((D.BLE_PDU_ADV_NONCONN_IND, 6 + 12)) + b"\x01" * 6 + _ours_adv(s, 0) for s in range(8)]
    r.a.ble_pdu(pdus[0], len(pdus[0]), -60, 37, 0)  # warm up the frame views
    r.a.ble_adv(tag, b"", -60, 37, 1)
    r.a.poll(100)
    micropython.heap_lock()
    try:
        for s in range(1, 200):
            p = pdus[s & 7]
            r.a.ble_pdu(p, len(p), -60 - (s & 7), 37, 100 + s)
            r.a.ble_adv(tag, b"", -70, 38, 100 + s)
            r.a.poll(130 + s)
        ok = True
    except MemoryError:
        ok = False
    finally:
        micropython.heap_unlock()
    assert ok, "ble_pdu()/ble_adv()/poll() allocated on the heap"


def test_reading_queue_carries_match_results_to_the_core():
    r = Rig()
    q = ReadingQueue(4)
    t = Tick32(lambda: 100, lambda a, b: a - b, start=1000)
    m = M.match_adv(r.a.filters, b"\x01" * 6, 0, _ours_adv(9, 0), 0, 12)
    assert m == (1 << 16) | 9  # entry 0, with seq 9
    assert q.put_match(m, -61, 37, 100)
    assert q.put(10, -62, 38, 101)
    q.drain(r.a, BLE, t)
    r.a.poll(1200)
    assert [(x[0], x[1]) for x in r.reports()] == [(9, 1001), (10, 1200)]


def _auth_rig():
    """A Rig whose entry 1 is an authenticated beacon with key 00 01 .. 0f (SPEC 9)."""
    r = Rig()
    key = bytes(range(16))
    entry = struct.pack(D.FILTER_ENTRY_FMT, D.FILTER_PFDOA_AUTH, 0, key + bytes(D.FILTER_MATCH_LEN - 16))
    assert r.a.set_filter(1, entry) == D.ACK_OK
    return r, key


def test_reading_queue_carries_authenticated_payloads_to_the_verifier():
    import pfdoa_auth as A
    import pfdoa_beacon as B
    r, key = _auth_rig()
    k = A.Key(key)
    ids = A.derive(k, 432900000)
    good = bytes(B.auth_adv_data(k, ids, 432900000, 7))
    at = M.auth_adv(good, 0, len(good))
    assert at > 0
    forged = bytearray(good)
    forged[-1] ^= 1
    q = ReadingQueue(4)
    t = Tick32(lambda: 100, lambda a, b: a - b, start=1000)
    micropython.heap_lock()  # the IRQ side copies the payload without allocating
    try:
        ok1 = q.put_auth(good, at, -61, 37, 100)
        ok2 = q.put_auth(forged, at, -61, 37, 101)
    finally:
        micropython.heap_unlock()
    assert ok1 and ok2
    q.drain(r.a, BLE, t)
    r.a.poll(1200)
    msgs = r.msgs()
    reps = [struct.unpack(D.MSG_AUTH_REPORT_FMT, p) for ty, a, p in msgs if ty == D.MSG_AUTH_REPORT]
    assert len(reps) == 1
    seq, tick, q8, raw, n, ch, flags, beacon, counter, tag = reps[0]
    assert (seq, tick, raw, n, beacon, counter) == (7, 1200, -61, 1, 1, 432900000)  # closed by the poll
    assert tag == good[at + 14:at + 22]
    assert r.a.auth_rejected[D.AUTH_BAD_TAG - D.AUTH_BAD_TAG] == 1
    # A full ring refuses and counts, as put() does.
    assert [q.put_auth(good, at, -60, 37, 200) for _ in range(4)] == [True, True, True, False]
    assert q.lost == 1


def test_tick32_extends_a_short_port_period():
    period = 1 << 30
    now = [period - 10]

    def ticks_ms():
        return now[0]

    def ticks_diff(a, b):  # MicroPython semantics for a 2**30 period
        return ((a - b + period // 2) & (period - 1)) - period // 2

    t = Tick32(ticks_ms, ticks_diff, start=0xFFFFFFF6)
    assert t.now() == 0xFFFFFFF6
    now[0] = 5  # both wrap: the port's tick and the u32 tick, +15 ms
    assert t.now() == 5
    assert t.at(3) == 3 and t.at(period - 2) == 0xFFFFFFFE  # readings just before
    for _ in range(10):  # many port periods later the u32 tick still counts on
        now[0] = (now[0] + (period // 2 - 1)) & (period - 1)
        t.now()
    assert t.now() == (5 + 10 * (period // 2 - 1)) & 0xFFFFFFFF


def test_reading_queue_fifo_overflow_counts_dropped():
    r = Rig()
    q = ReadingQueue(4)
    t = Tick32(lambda: 100, lambda a, b: a - b, start=1000)
    assert [q.put(s, -50 - s, 37, 100 + s) for s in range(5)] == [True, True, True, False, False]
    q.drain(r.a, BLE, t)
    assert r.a.dropped_events == 2
    r.a.poll(2000)
    rep = r.reports()
    assert [(x[0], x[1], x[3]) for x in rep] == [(0, 1001, -50), (1, 1002, -51), (2, 2000, -52)]
    assert q.put(9, -60, 38, 100)  # room again after draining


def test_reading_queue_put_does_not_allocate():
    q = ReadingQueue(8)
    micropython.heap_lock()
    try:
        for s in range(20):
            q.put(s, -70, 37, 123456)
        ok = True
    except MemoryError:
        ok = False
    finally:
        micropython.heap_unlock()
    assert ok and q.lost == 13


def test_untrusted_input_does_not_grow_memory():
    import gc
    import random
    random.seed(5)
    r = Rig()
    junk = bytes(random.getrandbits(8) | 1 for _ in range(4096))  # no delimiters
    mixed = bytes(random.getrandbits(8) for _ in range(4096))
    r.a.uart_rx(junk)
    r.a.uart_rx(mixed)
    gc.collect()
    before = gc.mem_alloc()
    for _ in range(25):  # 200 KB of garbage
        r.a.uart_rx(junk)
        r.a.uart_rx(mixed)
    r.frames = []
    gc.collect()
    assert gc.mem_alloc() <= before + 256, (before, gc.mem_alloc())
    assert r.a._dec._n <= D.MAX_ENCODED and r.a.rx_errors > 0
