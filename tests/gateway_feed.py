"""A separate process that plays the anchors for the gateway tests (not a test module).

    python gateway_feed.py uart FD[,FD...] SECONDS  write COBS report frames into pty master FD(s)
    python gateway_feed.py slcan FD SECONDS         play an SLCAN adapter on pty master FD
    python gateway_feed.py unplug LINK SECONDS      create a pty behind symlink LINK and write frames
                                                    until a line arrives on stdin; then drop the pty,
                                                    re-create it and write until the next line (at
                                                    most SECONDS), however long the gateway takes to
                                                    reopen it
    python gateway_feed.py udp HOST:PORT SECONDS    four Wi-Fi anchors: each anchor's frames as UDP
                                                    datagrams from a socket of its own; commands on
                                                    stdin: "restart A" (a new source port), "pause A"
                                                    (silent), "resume A" (the same port again), "stop"

Reports are noise-free RSSI from the radio model at TRUE_POS for the TEST_SITE anchors,
one beacon every 20 ms. Prints "ready" on stdout once the first pty exists.
"""

from __future__ import annotations

import os
import select
import sys
import time
import tty

import numpy as np

from pfdoa.protocol.can import encode_can
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart
from pfdoa.radio import PathLoss, mean_rssi

ANCHORS = {0: (0.0, 0.0), 1: (0.0, 4.0), 2: (4.0, 4.0), 3: (4.0, 0.0)}
RADIO = (-45.0, 2.0)
TRUE_POS = (1.0, 1.5)
TEST_SITE = "[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.0\n" + "".join(
    f"[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in ANCHORS.items()
)
PERIOD_S = 0.02


def reports(seq: int):
    rssi = mean_rssi(np.array(TRUE_POS), np.array(list(ANCHORS.values())), PathLoss(*RADIO))
    for (a, _), r in zip(ANCHORS.items(), rssi):
        q8 = int(round(float(r) * 256))
        yield a, RssiReport(seq & 0xFFFF, (1000 + 20 * seq) & 0xFFFFFFFF, q8, int(round(float(r))), 1, 37, 0)


def uart(fd: int | list[int], seconds: float, start_seq: int = 0, until_stdin: bool = False) -> int:
    """Reports on one pty, or spread over several (anchor a on fds[a % len(fds)])."""
    fds = fd if isinstance(fd, list) else [fd]
    seq = start_seq
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if until_stdin and select.select([sys.stdin], [], [], 0)[0]:
            sys.stdin.readline()
            break
        for i, port in enumerate(fds):
            data = b"".join(encode_uart(m, a) for a, m in reports(seq) if a % len(fds) == i)
            try:
                os.write(port, b"\x17garbage\x00" + data if seq % 10 == 0 else data)
            except OSError:
                pass  # nobody has the port open yet (EIO): keep going, like a real anchor
        seq += 1
        time.sleep(PERIOD_S)
    return seq


def slcan(fd: int, seconds: float) -> None:
    end = time.monotonic() + seconds
    buf = b""
    opened = False
    seq = 0
    next_t = time.monotonic()
    while time.monotonic() < end:
        r, _, _ = select.select([fd], [], [], 0.005)
        if r:
            try:
                buf += os.read(fd, 256)
            except OSError:
                buf = b""
            while b"\r" in buf:
                cmd, buf = buf.split(b"\r", 1)
                os.write(fd, b"\r")
                if cmd.startswith(b"O"):
                    opened = True
                elif cmd.startswith(b"C"):
                    opened = False
        if opened and time.monotonic() >= next_t:
            for a, m in reports(seq):
                for cid, data in encode_can(m, a):
                    os.write(fd, f"t{cid:03X}{len(data)}{data.hex().upper()}\r".encode())
            seq += 1
            next_t += PERIOD_S


def _new_pty(link: str) -> tuple[int, int]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    tmp = link + ".new"
    if os.path.lexists(tmp):
        os.unlink(tmp)
    os.symlink(os.ttyname(slave), tmp)
    os.replace(tmp, link)
    return master, slave


def unplug(link: str, seconds: float) -> None:
    master, slave = _new_pty(link)
    print("ready", flush=True)
    seq = uart(master, 3600.0, until_stdin=True)
    print(f"unplug {seq}", flush=True)
    # The adapter is pulled out: its device node goes first, as a USB serial port's does. A
    # link left to the closed pty names a /dev/pts number the kernel hands to the next pty
    # opened, and the gateway reopened that: another test's QEMU anchor's UART, whose bytes
    # it then read (both tests failed together in two full runs).
    os.unlink(link)
    os.close(master)
    os.close(slave)
    time.sleep(0.5)
    master, slave = _new_pty(link)
    uart(master, seconds, seq, until_stdin=True)
    os.close(master)
    os.close(slave)


def _udp_socket(port: int = 0):
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    return s


def udp(target: str, seconds: float) -> None:
    """Each anchor sends its reports (a garbage prefix every 10th beacon, as on the ptys) in
    one datagram per beacon from its own socket; says "ports P0 P1 P2 P3" and, on a
    restart, "port A P"; "ok CMD" after each command, once its next datagram is sent."""
    host, _, port = target.rpartition(":")
    dest = (host, int(port))
    socks: dict = {a: _udp_socket() for a in ANCHORS}
    print("ports " + " ".join(str(socks[a].getsockname()[1]) for a in ANCHORS), flush=True)
    paused: dict[int, int] = {}  # anchor -> its port while it is silent
    seq = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        said = None
        if select.select([sys.stdin], [], [], 0)[0]:
            cmd, _, arg = sys.stdin.readline().strip().partition(" ")
            if cmd in ("stop", ""):
                break
            a = int(arg)
            if cmd == "restart":
                socks[a].close()
                socks[a] = _udp_socket()
                print(f"port {a} {socks[a].getsockname()[1]}", flush=True)
            elif cmd == "pause":
                sock = socks[a]
                paused[a] = sock.getsockname()[1]
                sock.close()
                socks[a] = None
            elif cmd == "resume":
                socks[a] = _udp_socket(paused.pop(a))
            said = f"ok {cmd} {a}"
        for a, m in reports(seq):
            if socks.get(a) is not None:
                data = encode_uart(m, a)
                socks[a].sendto(b"\x17garbage\x00" + data if seq % 10 == 0 else data, dest)
        if said:
            print(said, flush=True)
        seq += 1
        time.sleep(PERIOD_S)


def main() -> None:
    mode, target, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    if mode == "uart":
        uart([int(fd) for fd in target.split(",")], seconds)
    elif mode == "slcan":
        slcan(int(target), seconds)
    elif mode == "unplug":
        unplug(target, seconds)
    elif mode == "udp":
        udp(target, seconds)
    else:
        raise SystemExit(f"unknown mode {mode}")


if __name__ == "__main__":
    main()
