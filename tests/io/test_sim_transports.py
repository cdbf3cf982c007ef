"""Transports without a gateway: bytes through a pty (pyserial), SLCAN (python-can), virtual CAN."""

import os
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import serial

from pfdoa.protocol.cobs import cobs_decode
from pfdoasim.backends.py_mean import MeanAnchor
from pfdoasim.faults import parse_faults
from pfdoasim.runner import Simulation
from pfdoasim.scenario import build
from pfdoasim.transports import CanVirtualTransport, PtyTransport, SlcanPtyTransport, slcan_line


class SerialReader(threading.Thread):
    """Reads a serial path until stopped; reopens it when the port disappears. ``opened``
    is set once pyserial's open (which flushes pending input) has returned."""

    def __init__(self, path):
        super().__init__(daemon=True)
        self.path, self.data, self.stop, self.reopens = path, bytearray(), threading.Event(), 0
        self.opened = threading.Event()

    def run(self):
        while not self.stop.is_set():
            try:
                with serial.Serial(self.path, 115200, timeout=0.01) as s:
                    self.opened.set()
                    while not self.stop.is_set():
                        self.data += s.read(4096)
            except (serial.SerialException, OSError):
                self.reopens += 1
                time.sleep(0.02)

    def wait_for(self, n_bytes: int, hang_s: float = 20.0) -> None:
        self.wait_until(lambda data: len(data) >= n_bytes, hang_s)

    def wait_until(self, cond, hang_s: float = 20.0) -> None:
        end = time.monotonic() + hang_s
        while not cond(bytes(self.data)):
            assert time.monotonic() < end, f"hang guard ({len(self.data)} bytes read)"
            time.sleep(0.005)


def reports(data: bytes) -> list[tuple[int, int]]:
    from pfdoa.protocol import RssiReport, decode_frame

    out = []
    for piece in bytes(data).split(b"\x00"):
        if piece:
            d = decode_frame(piece)
            if isinstance(d.message, RssiReport):
                out.append((d.anchor_id, d.message.seq))
    return out


def test_pty_carries_every_frame_byte_exact(tmp_path):
    sc = build("demo", seed=2, duration_s=3.0)
    tr = PtyTransport(link=tmp_path / "tty")
    tr.open()
    rd = SerialReader(str(tmp_path / "tty"))
    rd.start()
    try:
        # The reader has the port open and pyserial has flushed it: from here every byte counts
        # (waiting only for the slave to be opened lost the first frames to that flush).
        assert rd.opened.wait(20.0)
        summary = Simulation(sc, tr, MeanAnchor, speed=0, trace_out=tmp_path / "t.csv").run()
        rd.wait_for(tr.bytes_written)
    finally:
        rd.stop.set()
        rd.join()
        tr.close()
    got = reports(rd.data)
    n = summary["beacons"]
    assert n == 31
    assert sorted(got) == sorted((a, k) for a in (1, 2, 3, 4) for k in range(n))
    assert not (tmp_path / "tty").exists()


def test_port_drop_closes_the_pty_and_reopens_it_behind_the_link(tmp_path):
    sc = replace(build("demo", seed=2, duration_s=4.0), faults=parse_faults("portdrop=1+1"))
    tr = PtyTransport(link=tmp_path / "tty")
    tr.open()
    assert os.readlink(tmp_path / "tty") == tr.path
    rd = SerialReader(str(tmp_path / "tty"))
    rd.start()
    try:
        assert rd.opened.wait(20.0)
        summary = Simulation(sc, tr, MeanAnchor, speed=10.0).run()
        last = (4, summary["beacons"] - 1)  # the last frame written
        rd.wait_until(lambda data: last in reports(data[: data.rfind(b"\0") + 1]))
    finally:
        rd.stop.set()
        rd.join()
        tr.close()
    f = summary["faults"]
    assert f["port_drops"] == 1 and tr.reopens == 1 and rd.reopens >= 1
    lost = f["total"]["port_down_reports"]
    assert lost == 4 * 10  # 1 s of 10 Hz beacons from 4 anchors
    got = reports(rd.data)
    # Nothing from the outage arrives (real time: how soon the reader reads and reopens is
    # up to the scheduler, so only liveness and order are asserted): before it, every beacon
    # up to what was still unread at the hang-up; after it, every beacon from the first one
    # the reopened reader got.
    assert not any(10 <= k < 20 for _, k in got)
    seqs = {k for _, k in got}
    # The reader reads in order: what the hang-up took is what it had not read yet, a tail.
    before = sorted(k for k in seqs if k < 10)
    assert before and before == list(range(len(before)))
    back = min(k for k in seqs if k >= 20)
    assert seqs >= set(range(back, summary["beacons"]))
    assert len(got) == len(set(got))


def test_a_dropped_port_takes_its_link_with_it(tmp_path):
    """Unplugging removes the stable link before the pty's number is freed: a reader
    retrying the link must never open a /dev/pts number that another process's new pty
    has taken over (two test runs once read each other's streams that way)."""
    link = tmp_path / "tty"
    tr = PtyTransport(link=link)
    tr.open()
    try:
        tr.set_port_up(False)
        assert not os.path.lexists(link)
        tr.set_port_up(True)
        assert os.readlink(link) == tr.path and os.path.exists(tr.path)
    finally:
        tr.close()
    assert not os.path.lexists(link)


def test_frames_nobody_reads_are_counted_unread():
    """With no reader on the port (a gateway yet to reopen it after a drop) frames go
    nowhere and are counted as such, however long the reader takes."""
    sc = build("demo", seed=2, duration_s=1.0)
    tr = PtyTransport()
    tr.open()
    try:
        summary = Simulation(sc, tr, MeanAnchor, speed=0).run()
    finally:
        tr.close()
    t = summary["faults"]["total"]
    assert t["sent"] == 0 and t["unread"] == t["frames"] and t["unread_reports"] == t["reports"] > 0


def test_a_stuck_reader_loses_whole_frames_only(tmp_path):
    """When the reader stops draining the pty, frames that do not fit are lost whole; one
    cut part-way is completed first on the next write, so the stream stays frame-aligned
    and the loss is exactly what send() reports."""
    from pfdoa.protocol.cobs import cobs_encode
    from pfdoasim.faults import Frame

    tr = PtyTransport()
    tr.open()
    reader = serial.Serial(tr.path, 115200, timeout=0)
    frames = [Frame(1, cobs_encode(bytes([0, 1, 1]) + k.to_bytes(2, "little") + bytes(40)) + b"\0", True)
              for k in range(4000)]
    try:
        lost = tr.send(frames)  # far more than a pty buffers: the tail cannot be written
        assert 0 < lost < len(frames)
        got = bytearray()
        while chunk := reader.read(65536):
            got += chunk
        assert tr.send(frames[:1]) == 0  # completes the cut frame, then a whole one
        end = time.monotonic() + 20.0
        while not got.endswith(frames[0].data):
            assert time.monotonic() < end, "hang guard"
            got += reader.read(65536)
    finally:
        reader.close()
        tr.close()
    pieces = bytes(got).split(b"\0")
    assert pieces[-1] == b""
    seqs = [int.from_bytes(cobs_decode(p)[3:5], "little") for p in pieces[:-1]]
    assert seqs == list(range(len(frames) - lost)) + [0]


def test_slcan_lines_reach_python_can(tmp_path):
    can = pytest.importorskip("can")
    assert slcan_line(0x123, bytes.fromhex("deadbeef")) == b"t1234DEADBEEF\r"
    sc = build("demo", seed=3, duration_s=2.0)
    tr = SlcanPtyTransport()
    tr.open()
    bus = can.Bus(interface="slcan", channel=tr.path, bitrate=500000, sleep_after_open=0)
    try:
        assert tr.wait_reader(5.0)
        summary = Simulation(sc, tr, MeanAnchor, speed=0).run()
        msgs = []
        while (m := bus.recv(0.3)) is not None:
            msgs.append(m)
    finally:
        bus.shutdown()
        tr.close()
    assert len(msgs) == 4 * summary["beacons"]
    assert {m.arbitration_id for m in msgs} == {0x100 | a for a in (1, 2, 3, 4)}
    from pfdoa.protocol import defs
    assert all(m.dlc == defs.CAN_RSSI_REPORT_DLC for m in msgs)


def test_virtual_can_in_process():
    can = pytest.importorskip("can")
    sc = replace(build("demo", seed=4, duration_s=2.0), faults=parse_faults("loss=0.2"))
    tr = CanVirtualTransport("pfdoa-test-sim")
    rx = can.Bus(interface="virtual", channel="pfdoa-test-sim")
    tr.open()
    try:
        summary = Simulation(sc, tr, MeanAnchor, speed=0).run()
        msgs = []
        while (m := rx.recv(0.05)) is not None:
            msgs.append(m)
    finally:
        rx.shutdown()
        tr.close()
    t = summary["faults"]["total"]
    assert len(msgs) == t["sent"] == t["frames"] - t["dropped"] > 0
    seqs = {(m.arbitration_id & 0x7F, int.from_bytes(m.data[:2], "little")) for m in msgs}
    assert len(seqs) == len(msgs)
    assert np.isclose(t["dropped"] / t["frames"], 0.2, atol=0.1)


def _decoded(received) -> list:
    from pfdoa.protocol.can import decode_can

    msgs = []
    for how, item in received:
        d = item if how == "uart" else decode_can(item.arbitration_id, bytes(item.data))
        if not isinstance(d, str):
            msgs.append((d.anchor_id, d.message))
    return msgs


@pytest.mark.parametrize("kind", ["pty", "slcan", "can-virtual"])
def test_host_config_set_reaches_the_c_anchors(tmp_path, kind):
    """A broadcast CONFIG_SET (report every 2nd event) from the host side of each transport
    reaches every emulated C core, which acks it and halves its report rate."""
    can = pytest.importorskip("can")
    from pfdoa.protocol.can import encode_can
    from pfdoa.protocol.messages import ConfigAck, ConfigSet, RssiReport
    from pfdoa.protocol.uart import StreamDecoder, encode_uart
    from pfdoasim.backends import anchor_factory

    msg = ConfigSet(token=42, report_mode=1, decimation=2)
    sc = build("demo", seed=8, duration_s=4.0)
    if kind == "pty":
        tr = PtyTransport()
    elif kind == "slcan":
        tr = SlcanPtyTransport()
    else:
        tr = CanVirtualTransport("pfdoa-test-config")
    tr.open()
    if kind == "pty":
        host = serial.Serial(tr.path, 115200, timeout=0)
        send = lambda: host.write(encode_uart(msg, 127))  # noqa: E731
    elif kind == "slcan":
        host = can.Bus(interface="slcan", channel=tr.path, bitrate=500000, sleep_after_open=0)
    else:
        host = can.Bus(interface="virtual", channel="pfdoa-test-config")
    if kind != "pty":
        def send():
            for cid, data in encode_can(msg, 127):
                host.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
    received = []

    def collect():
        if kind == "pty":
            received.extend(("uart", d) for d in dec.feed(host.read(65536)))
        else:
            while (m := host.recv(0.0)) is not None:
                received.append(("can", m))

    dec = StreamDecoder()
    try:
        assert tr.wait_reader(5.0)

        def on_beacon(k, t):
            collect()
            if k == 20:
                send()

        summary = Simulation(sc, tr, anchor_factory("c"), speed=20.0).run(on_beacon=on_beacon)
        end = time.monotonic() + 20.0
        last = summary["beacons"] - 2  # with decimation 2, each anchor's last report is for one of the last two
        while not all(any(aa == a and isinstance(m, RssiReport) and m.seq >= last for aa, m in _decoded(received))
                      for a in (1, 2, 3, 4)):
            assert time.monotonic() < end, "hang guard"
            time.sleep(0.01)
            collect()
    finally:
        (host.close if kind == "pty" else host.shutdown)()
        tr.close()
    msgs = _decoded(received)
    acks = [(a, m) for a, m in msgs if isinstance(m, ConfigAck)]
    assert sorted(a for a, _ in acks) == [1, 2, 3, 4]
    assert all(m.token == 42 and m.result == 0 for _, m in acks)
    for a in (1, 2, 3, 4):
        seqs = [m.seq for aa, m in msgs if aa == a and isinstance(m, RssiReport)]
        before = [s for s in seqs if s <= 20]
        after = [s for s in seqs if s > 22]
        assert len(before) >= 20
        assert 8 <= len(after) <= 10  # 18 of the 4 s run's last beacons, every 2nd reported
