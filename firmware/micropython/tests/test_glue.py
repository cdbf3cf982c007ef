# The board glue (board_ble.py, main.py) needs a radio, so it does not run here: it is
# compiled to check its syntax, and its pure parts run against stand-in modules.
import sys

import pfdoa_defs as D
from pfdoa_anchor import ReadingQueue


def _src(name):
    import run_tests
    with open(run_tests._MPY + "/" + name) as f:
        return f.read()


def test_glue_compiles():
    for name in ("board_ble.py", "main.py", "pfdoa_anchor.py", "pfdoa_wire.py",
                 "anchor_script.py"):
        compile(_src(name), name, "exec")


class _FakeBLE:
    def __init__(self):
        self.scans = []

    def active(self, on):
        self.on = on

    def irq(self, handler):
        self.handler = handler

    def gap_scan(self, *args):
        self.scans.append(args)


class _FakeBluetooth:
    BLE = _FakeBLE


def _board():
    sys.modules["bluetooth"] = _FakeBluetooth
    try:
        import board_ble
    finally:
        del sys.modules["bluetooth"]
    return board_ble


def _adv(seq, company=0xFFFF, magic=b"PF", prefix=b"\x02\x01\x06"):
    body = bytes((0xFF, company & 0xFF, company >> 8)) + magic + bytes((seq & 0xFF, seq >> 8))
    return prefix + bytes((len(body),)) + body


def test_beacon_seq_parses_manufacturer_data():
    b = _board()
    assert b.beacon_seq(_adv(0x1234)) == 0x1234
    assert b.beacon_seq(_adv(7, prefix=b"")) == 7
    assert b.beacon_seq(_adv(7, company=0x004C)) == -1
    assert b.beacon_seq(_adv(7, magic=b"XX")) == -1
    assert b.beacon_seq(_adv(7)[:-1]) == -1  # truncated AD structure
    assert b.beacon_seq(b"") == -1 and b.beacon_seq(b"\x00\xff") == -1
    assert b.beacon_seq(b"\x02\x01\x06\x03\x03\xaa\xfe" + _adv(65535, prefix=b"")) == 65535


def test_scan_irq_queues_beacon_readings():
    b = _board()
    q = ReadingQueue(8)
    s = b.BleScanner(q)
    s.start()
    ble = s._ble
    assert ble.on and len(ble.scans) == 1
    ble.handler(5, (0, b"\x01" * 6, 0, -61, memoryview(_adv(42))))
    ble.handler(5, (0, b"\x01" * 6, 0, -61, memoryview(_adv(42, company=1))))  # not ours
    ble.handler(6, None)  # scan ended: restarted
    assert len(ble.scans) == 2
    assert q._head == 1 and q._seq[0] == 42 and q._rssi[0] == -61
    assert q._chan[0] == b.BLE_CHANNEL and D.CHANNEL_BLE_MIN <= b.BLE_CHANNEL <= D.CHANNEL_BLE_MAX


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
    import struct
    import pfdoa_wire as W
    raw = bytes((1, D.MSG_CONFIG_SET, aid)) + struct.pack(D.MSG_CONFIG_SET_FMT, token, 0, alpha,
                                                          12, 0, 1)
    c = W.crc16_byte(W.crc16(raw), D.MSG_CONFIG_SET_CRC_EXTRA)
    raw += bytes((c & 0xFF, c >> 8))
    enc = bytearray(len(raw) + 2)
    n = W.cobs_encode(raw, len(raw), enc)
    return bytes(enc[:n]) + b"\x00"


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
                  store=lambda c: stored.append(bytes(c)) or True)
    node.start()
    node.step()  # first poll: STATUS
    assert len(uart.sent) == 1
    irq = node.scanner._ble.handler
    for i in range(3):
        now[0] = (now[0] + 2) & (period - 1)
        irq(5, (0, b"\x02" * 6, 0, -70 - i, memoryview(_adv(500))))
    uart.inbox = _config_set_frame(7, 9, 128)
    node.step()
    import pfdoa_wire as W
    msgs = []
    for f in uart.sent[1:]:
        raw = bytearray(len(f))
        n = W.cobs_decode(f, len(f) - 1, raw)
        msgs.append((raw[1], bytes(raw[3:n - 2])))
    assert [m[0] for m in msgs] == [D.MSG_RSSI_REPORT, D.MSG_CONFIG_ACK]
    import struct
    seq, tick, q8, raw_dbm, n, ch, flags = struct.unpack(D.MSG_RSSI_REPORT_FMT, msgs[0][1])
    assert (seq, tick, q8, raw_dbm, n, ch) == (500, 6, -71 * 256, -72, 3, b.BLE_CHANNEL)
    assert msgs[1][1][:2] == bytes((9, D.ACK_OK)) and len(stored) == 1
    assert node.anchor.alpha_q8 == 128
