# The board glue (board_ble.py, main.py) needs a radio, so it does not run here: it is
# compiled to check its syntax, and its pure parts run against stand-in modules.
import sys

import struct

import pfdoa_defs as D
import pfdoa_match as M
import pfdoa_wire as W
from pfdoa_anchor import ReadingQueue


def _src(name):
    import run_tests
    with open(run_tests._MPY + "/" + name) as f:
        return f.read()


def test_glue_compiles():
    for name in ("board_ble.py", "main.py", "pfdoa_anchor.py", "pfdoa_wire.py", "pfdoa_match.py",
                 "pfdoa_beacon.py", "beacon_ble.py", "beacon_main.py", "anchor_script.py"):
        compile(_src(name), name, "exec")


class _FakeBLE:
    def __init__(self):
        self.scans = []
        self.adverts = []

    def active(self, on):
        self.on = on

    def irq(self, handler):
        self.handler = handler

    def gap_scan(self, *args):
        self.scans.append(args)

    def config(self, name):
        assert name == "mac"
        return (1, b"\xc5\x01\x02\x03\x04\x05")  # most significant byte first

    def gap_advertise(self, interval_us, adv_data=None, connectable=True):
        self.adverts.append((interval_us, bytes(adv_data), connectable))


class _FakeBluetooth:
    BLE = _FakeBLE


def _board():
    sys.modules["bluetooth"] = _FakeBluetooth
    try:
        import board_ble
    finally:
        del sys.modules["bluetooth"]
    return board_ble


def _adv(seq, bid=0, company=0xFFFF, magic=b"PF", prefix=b"\x02\x01\x06"):
    body = bytes((0xFF, company & 0xFF, company >> 8)) + magic + bytes((seq & 0xFF, seq >> 8, bid))
    return prefix + bytes((len(body),)) + body


def test_scan_irq_matches_against_the_anchors_table_and_queues():
    b = _board()
    q = ReadingQueue(8)
    table = M.default_table()
    tag = b"\xa1\xb2\xc3\xd4\xe5\xf6"  # as MicroPython gives it: most significant byte first
    air = bytes(tag[5 - i] for i in range(6))  # on-air order in the table (SPEC 3.1)
    table[D.FILTER_ENTRY_LEN:2 * D.FILTER_ENTRY_LEN] = struct.pack(D.FILTER_ENTRY_FMT, D.FILTER_MAC48, 10, air)
    s = b.BleScanner(q, table)
    s.start()
    ble = s._ble
    assert ble.on and len(ble.scans) == 1
    ble.handler(5, (0, b"\x01" * 6, 0, -61, memoryview(_adv(42))))
    ble.handler(5, (0, b"\x01" * 6, 0, -61, memoryview(_adv(42, company=1))))  # nobody's
    ble.handler(5, (0, b"\x01" * 6, 0, -62, memoryview(_adv(43, bid=1))))  # another id
    ble.handler(5, (0, tag, 0, -70, memoryview(b"\x02\x01\x06")))  # the tag, by address
    ble.handler(6, None)  # scan ended: restarted
    assert len(ble.scans) == 2
    assert q._head == 2 and q._rssi[0] == -61 and q._rssi[1] == -70
    assert q._code[0] == (1 << 16) | 42 and q._code[1] == (1 << 17)  # entry 0 with seq; entry 1
    assert q._chan[0] == b.BLE_CHANNEL and D.CHANNEL_BLE_MIN <= b.BLE_CHANNEL <= D.CHANNEL_BLE_MAX


def test_scan_irq_queues_authenticated_advertisements_only_with_an_auth_entry():
    import pfdoa_auth as A
    import pfdoa_beacon as B
    b = _board()
    key = bytes(range(16))
    k = A.Key(key)
    adv = bytes(B.auth_adv_data(k, A.derive(k, 5), 5, 1))
    q = ReadingQueue(8)
    table = M.default_table()
    s = b.BleScanner(q, table)
    s._ble.handler(5, (1, b"\x03" * 6, 3, -65, memoryview(adv)))
    assert q._head == 0  # no PFDOA_AUTH entry: nobody's
    table[D.FILTER_ENTRY_LEN:2 * D.FILTER_ENTRY_LEN] = struct.pack(D.FILTER_ENTRY_FMT, D.FILTER_PFDOA_AUTH, 0,
                                                                   key + bytes(D.FILTER_MATCH_LEN - 16))
    s._ble.handler(5, (1, b"\x03" * 6, 3, -65, memoryview(adv)))
    s._ble.handler(5, (0, b"\x01" * 6, 0, -61, memoryview(_adv(42))))  # ours, static: matched as before
    assert q._head == 2 and q._code[0] == -2 and q._code[1] == (1 << 16) | 42
    at = M.auth_adv(adv, 0, len(adv))
    assert bytes(q._auth[:D.AUTH_PAYLOAD_LEN]) == adv[at:at + D.AUTH_PAYLOAD_LEN]


class _FakeUart:
    def __init__(self):
        self.inbox = b""
        self.sent = []

    def any(self):
        return len(self.inbox)

    def readinto(self, buf):
        n = min(len(buf), len(self.inbox))
        buf[:n] = self.inbox[:n]
        self.inbox = self.inbox[n:]
        return n

    def write(self, mv):
        self.sent.append(bytes(mv))


def _config_set_frame(aid, token, alpha):
    extra = bytearray(256)
    extra[D.MSG_CONFIG_SET] = D.MSG_CONFIG_SET_CRC_EXTRA
    enc = W.FrameEncoder(extra)
    struct.pack_into(D.MSG_CONFIG_SET_FMT, enc.payload, 0, token, 0, alpha, 12, 0, 1)
    return bytes(enc.finish(D.MSG_CONFIG_SET, aid, D.MSG_CONFIG_SET_LEN))


def test_node_main_loop_with_stand_ins():
    b = _board()
    period = 1 << 30
    now = [period - 5]  # the port's tick wraps during the test

    def ticks_ms():
        return now[0]

    def ticks_diff(x, y):
        return ((x - y + period // 2) & (period - 1)) - period // 2

    stored = []
    uart = _FakeUart()
    node = b.Node(7, uart, ticks_ms=ticks_ms, ticks_diff=ticks_diff, load=lambda: None,
                  store=lambda c: stored.append(bytes(c)) or True, load_table=lambda: None,
                  store_table=lambda t: True)
    node.start()
    node.step()  # first poll: STATUS
    assert len(uart.sent) == 1
    irq = node.scanner._ble.handler
    for i in range(3):
        now[0] = (now[0] + 2) & (period - 1)
        irq(5, (0, b"\x02" * 6, 0, -70 - i, memoryview(_adv(500))))
    uart.inbox = _config_set_frame(7, 9, 128)
    node.step()
    msgs = []
    for f in uart.sent[1:]:
        raw = bytearray(len(f))
        n = W.cobs_decode(f, len(f) - 1 - D.TRAILER_LEN, raw)
        msgs.append((raw[1], bytes(raw[3:n])))
    assert [m[0] for m in msgs] == [D.MSG_RSSI_REPORT, D.MSG_CONFIG_ACK]
    seq, tick, q8, raw_dbm, n, ch, flags, beacon = struct.unpack(D.MSG_RSSI_REPORT_FMT, msgs[0][1])
    assert (seq, tick, q8, raw_dbm, n, ch, beacon) == (500, 6, -71 * 256, -72, 3, b.BLE_CHANNEL, 0)
    assert msgs[1][1][:2] == bytes((9, D.ACK_OK)) and len(stored) == 1
    assert node.anchor.alpha_q8 == 128


def test_node_advertises_itself_with_an_anchors_entry():
    b = _board()
    now = [0]
    uart = _FakeUart()
    table = M.default_table()
    at = (D.BEACON_SLOTS - 1) * D.FILTER_ENTRY_LEN
    table[at:at + D.FILTER_ENTRY_LEN] = struct.pack(D.FILTER_ENTRY_FMT, D.FILTER_ANCHORS, 2000, b"")
    node = b.Node(9, uart, ticks_ms=lambda: now[0], ticks_diff=lambda x, y: x - y, load=lambda: None,
                  store=lambda c: True, load_table=lambda: table, store_table=lambda t: True)
    node.start()
    ble = node.scanner._ble
    for t in (0, 1000, 1999, 2000):
        now[0] = t
        node.step()
    # the AdvData of SPEC 6.1 (Flags, FF FF FF 'P' 'N' seq id), non-connectable, at the entry's period
    assert ble.adverts == [(2000000, bytes.fromhex("02010608ffffff504e000009"), False),
                           (2000000, bytes.fromhex("02010608ffffff504e010009"), False)]
    # and another anchor's advertisement, heard by the scan, is a peer reading (beacon 128 + 4)
    ble.handler(5, (0, b"\x02" * 6, 0, -66, memoryview(bytes.fromhex("02010608ffffff504e070004"))))
    node.step()
    f = uart.sent[-1]
    raw = bytearray(len(f))
    n = W.cobs_decode(f, len(f) - 1 - D.TRAILER_LEN, raw)
    seq, _, q8, _, _, _, _, beacon = struct.unpack(D.MSG_RSSI_REPORT_FMT, bytes(raw[3:n]))
    assert (raw[1], seq, q8, beacon) == (D.MSG_RSSI_REPORT, 7, -66 * 256, D.PEER_BEACON_BASE + 4)


class _FakeAdvertiser:
    def __init__(self, txpower_ok=True):
        self.ads = []
        self.txpower = None
        self._ok = txpower_ok

    def active(self, on):
        self.on = on

    def config(self, **kw):
        if not self._ok:
            raise ValueError("unknown config param")
        if "addr_mode" in kw:
            self.ads.append(("addr_mode", kw["addr_mode"]))
            return
        self.txpower = kw["txpower"]

    def gap_advertise(self, interval_us, adv_data=None, connectable=True):
        self.ads.append((interval_us, None if adv_data is None else bytes(adv_data), connectable))


def _beacon_glue():
    sys.modules["bluetooth"] = _FakeBluetooth
    try:
        import beacon_ble
    finally:
        del sys.modules["bluetooth"]
    return beacon_ble


def test_ble_beacon_advertises_each_sequence_number_at_its_interval():
    import pfdoa_beacon as B
    g = _beacon_glue()
    ble = _FakeAdvertiser()
    bb = g.BleBeacon(beacon_id=7, interval_ms=50, tx_power_dbm=-8, ble=ble)
    assert ble.txpower == -8 and bb.tx_power_applied and ble.on
    sent = [t for t in range(0, 260) if bb.step(t)]
    assert sent == [0, 50, 100, 150, 200, 250]
    # Polled 23 ms late: the cadence holds (next at 350); after a stall it restarts.
    assert not bb.step(299) and bb.step(323) and not bb.step(349) and bb.step(350)
    assert bb.step(1000) and not bb.step(1049) and bb.step(1050)
    assert [a[0] for a in ble.ads] == [50000] * 10 and not any(a[2] for a in ble.ads)
    assert [a[1] for a in ble.ads] == [bytes(B.adv_data(s, 7)) for s in range(10)]
    assert g.BleBeacon(ble=_FakeAdvertiser(txpower_ok=False)).tx_power_applied is False
    bb.stop()
    assert ble.ads[-1][1] is None


def test_ble_beacon_authenticated_rolls_its_address_with_the_period():
    import pfdoa_auth as A
    import pfdoa_match as M2
    g = _beacon_glue()
    ble = _FakeAdvertiser()
    key = bytes(range(16))
    bb = g.BleBeacon(interval_ms=1000, ble=ble, key=key)
    bb.step(0)
    assert ble.ads == []  # no time: nothing on the air (the next try in an interval)
    bb.set_time(432900000 * 4096 + 2000, 0)  # 2 s into a period: the next begins at 2096
    for t in range(0, 7001, 500):
        bb.step(t)
    ads = [a for a in ble.ads if a[0] != "addr_mode" and a[1] is not None]
    rolls = [i for i, a in enumerate(ble.ads) if a == ("addr_mode", 3)]
    assert len(ads) == 7 and len(rolls) == 3  # periods 432900000, +1 and +2
    # Every roll is made with advertising stopped, before the period's first advertisement.
    assert all(ble.ads[i - 1][1] is None for i in rolls)
    v = A.Verifier(key)
    counters = []
    for a in ads:
        at = M2.auth_adv(a[1], 0, len(a[1]))
        assert v.verify(a[1], at, 0) == 1  # AUTH_ACCEPT
        counters.append(v.counter)
    assert counters == [432900000] * 2 + [432900001] * 4 + [432900002]
    # A port without addr_mode: still advertises, says its address does not roll.
    ble2 = _FakeAdvertiser(txpower_ok=False)
    bb2 = g.BleBeacon(ble=ble2, key=key)
    bb2.set_time(4096 * 7, 0)
    assert bb2.step(0) and not bb2.address_rolls
