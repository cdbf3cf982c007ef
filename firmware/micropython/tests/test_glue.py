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
