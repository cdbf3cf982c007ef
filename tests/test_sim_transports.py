"""Transports without a gateway: bytes through a pty (pyserial), SLCAN (python-can), virtual CAN."""

import os
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import serial

from pfdoa.protocol.cobs import cobs_decode
from pfdoasim.anchors import MeanAnchor
from pfdoasim.faults import parse_faults
from pfdoasim.runner import Simulation
from pfdoasim.scenario import build
from pfdoasim.transports import CanVirtualTransport, PtyTransport, SlcanPtyTransport, slcan_line


class SerialReader(threading.Thread):
    """Reads a serial path until stopped; reopens it when the port disappears."""

    def __init__(self, path):
        super().__init__(daemon=True)
        self.path, self.data, self.stop, self.reopens = path, bytearray(), threading.Event(), 0

    def run(self):
        while not self.stop.is_set():
            try:
                with serial.Serial(self.path, 115200, timeout=0.01) as s:
                    while not self.stop.is_set():
                        self.data += s.read(4096)
            except (serial.SerialException, OSError):
                self.reopens += 1
                time.sleep(0.02)


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
        assert tr.wait_reader(5.0)
        summary = Simulation(sc, tr, MeanAnchor, speed=0, trace_out=tmp_path / "t.csv").run()
        time.sleep(0.2)
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
    first = os.readlink(tmp_path / "tty")
    rd = SerialReader(str(tmp_path / "tty"))
    rd.start()
    try:
        assert tr.wait_reader(5.0)
        summary = Simulation(sc, tr, MeanAnchor, speed=10.0).run()
        time.sleep(0.2)
    finally:
        rd.stop.set()
        rd.join()
        tr.close()
    f = summary["faults"]
    assert f["port_drops"] == 1 and tr.reopens == 1 and rd.reopens >= 1
    lost = f["total"]["port_down_reports"]
    assert lost == 4 * 10  # 1 s of 10 Hz beacons from 4 anchors
    got = reports(rd.data)
    # Nothing from the outage arrives. Around it, bytes unread at the hang-up and bytes
    # written before the reader reopened are lost too, as with a real unplugged adapter.
    assert not any(10 <= k < 20 for _, k in got)
    seqs = {k for _, k in got}
    assert len(seqs & set(range(10))) >= 5
    assert seqs >= set(range(28, summary["beacons"]))
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
        time.sleep(0.1)
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


@pytest.mark.parametrize("kind", ["pty", "slcan", "can-virtual"])
def test_host_config_set_reaches_the_c_anchors(tmp_path, kind):
    """A broadcast CONFIG_SET (report every 2nd event) from the host side of each transport
    reaches every emulated C core, which acks it and halves its report rate."""
    can = pytest.importorskip("can")
    from pfdoa.protocol.can import decode_can, encode_can
    from pfdoa.protocol.messages import ConfigAck, ConfigSet, RssiReport
    from pfdoa.protocol.uart import StreamDecoder, encode_uart
    from pfdoasim.anchors import anchor_factory

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

        Simulation(sc, tr, anchor_factory("c"), speed=20.0).run(on_beacon=on_beacon)
        time.sleep(0.1)
        collect()
    finally:
        (host.close if kind == "pty" else host.shutdown)()
        tr.close()
    msgs = []
    for how, item in received:
        d = item if how == "uart" else decode_can(item.arbitration_id, bytes(item.data))
        if not isinstance(d, str):
            msgs.append((d.anchor_id, d.message))
    acks = [(a, m) for a, m in msgs if isinstance(m, ConfigAck)]
    assert sorted(a for a, _ in acks) == [1, 2, 3, 4]
    assert all(m.token == 42 and m.result == 0 for _, m in acks)
    for a in (1, 2, 3, 4):
        seqs = [m.seq for aa, m in msgs if aa == a and isinstance(m, RssiReport)]
        before = [s for s in seqs if s <= 20]
        after = [s for s in seqs if s > 22]
        assert len(before) >= 20
        assert 8 <= len(after) <= 10  # 18 of the 4 s run's last beacons, every 2nd reported
