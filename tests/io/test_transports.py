"""Transports against real endpoints: pyserial (loop://, a pseudo-terminal), python-can
(virtual bus, SLCAN over a pseudo-terminal), standard input, capture files."""

import os
import threading
import time
import tty

import can
import pytest

from pfdoa.errors import InputError
from pfdoa.gateway.inputs.can import CanTransport, parse_can_spec
from pfdoa.gateway.inputs.capture import CaptureReader, CaptureWriter
from pfdoa.gateway.inputs.serial import SerialTransport, split_baud
from pfdoa.gateway.inputs.stdin import StdinTransport
from pfdoa.gateway.transports import Chunk, TransportEOF, TransportError
from pfdoa.protocol.can import decode_can, encode_can
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import StreamDecoder, encode_uart


def report(seq, anchor=0):
    return RssiReport(seq, 1000 + seq, -60 * 256, -60, 1, 37, 0)


def read_until(t, n_bytes, timeout=3.0):
    got = b""
    end = time.monotonic() + timeout
    while len(got) < n_bytes and time.monotonic() < end:
        for c in t.read(0.1):
            got += c.data
    return got


def test_split_baud():
    assert split_baud("/dev/ttyUSB0@921600", 115200) == ("/dev/ttyUSB0", 921600)
    assert split_baud("socket://h:4000", 115200) == ("socket://h:4000", 115200)
    assert split_baud("/dev/ttyUSB0", 9600) == ("/dev/ttyUSB0", 9600)


def test_serial_loop_url_round_trip_and_idempotent_close():
    t = SerialTransport("loop://", 115200, name="loop")
    with t:
        frame = encode_uart(report(1), 3)
        t._port.write(frame)
        got = read_until(t, len(frame))
        assert got == frame
        assert [d.anchor_id for d in StreamDecoder().feed(got)] == [3]
    t.close()
    t.close()
    assert not t.is_open


def _pty():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def test_serial_pty_frames_from_another_thread_then_eof_is_an_error():
    master, slave, path = _pty()
    t = SerialTransport(path, 115200)
    t.open()  # open before sending: pyserial flushes input on open
    os.close(slave)
    data = b"".join(encode_uart(report(s), 1) for s in range(20))
    w = threading.Thread(target=os.write, args=(master, data))
    w.start()
    got = read_until(t, len(data))
    w.join()
    assert got == data
    os.close(master)  # the device vanishes
    with pytest.raises(TransportError):
        for _ in range(20):
            t.read(0.05)
    t.close()


def test_serial_missing_device_is_transport_error():
    with pytest.raises(TransportError):
        SerialTransport("/dev/does-not-exist-pfdoa").open()


def test_parse_can_spec():
    assert parse_can_spec("socketcan:can0") == {"interface": "socketcan", "channel": "can0"}
    assert parse_can_spec("slcan:/dev/ttyACM0@500000") == {"interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 500000}
    assert parse_can_spec("virtual:vc0,receive_own_messages=true,tty_baudrate=9600") == {
        "interface": "virtual", "channel": "vc0", "receive_own_messages": True, "tty_baudrate": 9600}
    for bad in ("can0", "socketcan:", ":can0", "virtual:vc0,oops"):
        with pytest.raises(InputError):
            parse_can_spec(bad)


def test_parse_can_spec_config_file(tmp_path):
    p = tmp_path / "can.ini"
    p.write_text("[default]\ninterface = virtual\nchannel = cfgchan\nbitrate = 250000\n")
    kw = parse_can_spec(f"config:{p}")
    assert kw["interface"] == "virtual" and kw["channel"] == "cfgchan" and kw["bitrate"] == 250000
    with pytest.raises(InputError):
        parse_can_spec(f"config:{tmp_path / 'missing.ini'}")


def test_can_virtual_bus_with_acceptance_filters():
    t = CanTransport("virtual:pfdoa_test_vc")
    with t, can.Bus(interface="virtual", channel="pfdoa_test_vc") as tx:
        frames = encode_can(report(5), 2)
        for cid, data in frames:
            tx.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
        tx.send(can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False))  # not ours
        tx.send(can.Message(arbitration_id=0x185, data=bytes(8), is_extended_id=False))  # CONFIG_SET
        tx.send(can.Message(arbitration_id=0x102, data=b"\x00", is_extended_id=True))  # extended
        last = encode_can(report(6), 2)  # ours again: once it is here, everything before it was seen
        for cid, data in last:
            tx.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
        got = []
        end = time.monotonic() + 20.0
        while len(got) < len(frames) + len(last):
            assert time.monotonic() < end, "hang guard"
            got += t.read(0.1)
    assert [(c.can_id, c.data) for c in got] == frames + last
    d = decode_can(got[0].can_id, got[0].data)
    assert d.anchor_id == 2 and d.message.seq == 5


def test_can_slcan_over_pty():
    """python-can's SLCAN driver on a pseudo-terminal; a thread plays the adapter."""
    master, slave, path = _pty()
    stop = threading.Event()
    frames = encode_can(report(9), 4)

    def adapter():
        import select

        buf = b""
        opened = False
        while not stop.is_set():
            r, _, _ = select.select([master], [], [], 0.05)
            if not r:
                continue
            try:
                buf += os.read(master, 256)
            except OSError:
                return
            while b"\r" in buf:
                cmd, buf = buf.split(b"\r", 1)
                os.write(master, b"\r")  # acknowledge every command (S6, O, C, ...)
                if cmd.startswith(b"O") and not opened:  # channel opened: the adapter forwards bus traffic
                    opened = True  # (python-can sends O twice; the bus traffic happens once)
                    for cid, data in frames:
                        os.write(master, f"t{cid:03X}{len(data)}{data.hex().upper()}\r".encode())

    th = threading.Thread(target=adapter, daemon=True)
    th.start()
    t = CanTransport(f"slcan:{path}@500000")
    try:
        t.open()
        got = []
        end = time.monotonic() + 3.0
        while time.monotonic() < end and not got:
            got += t.read(0.1)
    finally:
        t.close()
        stop.set()
        th.join(1.0)
        os.close(master)
        os.close(slave)
    assert [(c.can_id, c.data) for c in got] == frames


def test_stdin_transport_reads_until_eof():
    r, w = os.pipe()
    t = StdinTransport(fd=r, name="stdin")
    os.write(w, b"abc")
    os.close(w)
    got = b""
    with t:
        with pytest.raises(TransportEOF):
            for _ in range(10):
                for c in t.read(0.1):
                    got += c.data
    os.close(r)
    assert got == b"abc"


def test_capture_round_trip_and_bad_lines(tmp_path):
    p = tmp_path / "run.cap"
    w = CaptureWriter(str(p))
    chunks = [Chunk("serial0", 1700000000.25, b"\x01\x02\x00"), Chunk("can0", 1700000000.5, b"\xaa" * 8, 0x102),
              Chunk("my port", 1700000001.0, b"")]
    for c in chunks:
        w.write(c)
    w.close()
    with open(p, "a") as fh:
        fh.write("garbage line\n(1.0) x C 999#00\n(1.0) x S zz\n" + "(2.0) x S " + "00" * 9000 + "\n")
        fh.write("(3.0) last S ff\n")
    r = CaptureReader(str(p))
    got = []
    with r:
        with pytest.raises(TransportEOF):
            while True:
                got += r.read(0.1)
    assert [(c.source, c.t, c.data, c.can_id) for c in got] == [
        ("serial0", 1700000000.25, b"\x01\x02\x00", None), ("can0", 1700000000.5, b"\xaa" * 8, 0x102),
        ("my_port", 1700000001.0, b"", None), ("last", 3.0, b"\xff", None)]
    assert r.bad_lines == 4


def test_capture_from_a_pipe_hands_over_each_line_as_it_comes():
    """A live gateway's capture piped into `--replay-capture -`: an item is returned as soon as
    its line arrives, not once 63 more have (a regular file is still read in batches)."""
    rfd, wfd = os.pipe()
    got: list = []
    done = threading.Event()

    def reader():
        with CaptureReader(f"/proc/self/fd/{rfd}") as r:
            got.extend(r.read(0.1))
            done.set()
            with pytest.raises(TransportEOF):
                while True:
                    got.extend(r.read(0.1))

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    os.write(wfd, b"(1.0) serial0 S 0102\n")
    assert done.wait(60), "the first line was held back waiting for more"
    assert [(c.source, c.t, c.data) for c in got] == [("serial0", 1.0, b"\x01\x02")]
    os.write(wfd, b"(2.0) serial0 S 03\n")
    os.close(wfd)
    th.join(60)
    os.close(rfd)
    assert [c.t for c in got] == [1.0, 2.0]


def test_capture_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError):
        CaptureReader(str(tmp_path / "nope.cap")).open()


def test_serial_socket_url_and_disconnect():
    import socket

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    data = b"".join(encode_uart(report(s), 2) for s in range(5))

    opened = threading.Event()

    def serve():
        conn, _ = srv.accept()
        opened.wait(20)  # pyserial discards what is already buffered while it opens the socket
        conn.sendall(data)
        conn.close()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    t = SerialTransport(f"socket://127.0.0.1:{port}")
    t.open()
    opened.set()
    try:
        assert read_until(t, len(data)) == data
        with pytest.raises(TransportError):
            for _ in range(40):
                t.read(0.05)
    finally:
        t.close()
        srv.close()
