"""Where the emulated anchors' frames go: a pseudo-terminal, a CAN bus, or standard output.

* :class:`PtyTransport` - one pseudo-terminal that the gateway opens like a USB serial
  port (all anchors multiplexed, as behind a hub/concentrator). Optionally a stable
  symlink to it, which lets the port "disappear" (the link is removed and the pty
  closed, then a new one created behind the same link, as udev's /dev/serial/by-id links
  behave; a dangling link could lead a reader to another process's pty of the same number).
* :class:`SlcanPtyTransport` - a pseudo-terminal speaking the SLCAN (Lawicel) ASCII
  protocol (``tIIILDD..\\r``), for python-can's ``slcan`` interface in another process.
* :class:`CanVirtualTransport` - python-can's in-process ``virtual`` bus.
* :class:`StdoutTransport` - UART bytes on standard output, for pipes.
* :class:`TimedStreamTransport` - virtual time: every frame as a line of the gateway's
  capture format stamped with its arrival time (the simulated time it was sent plus a
  modelled transport latency), and the robot's odometry as ``O`` lines, on a pipe or a
  file: ``pfdoa gateway --replay-capture -`` runs its timers on those times, so its output
  is a function of the stream, however fast or loaded the machine.

UART transports take COBS frames (with their delimiter); CAN transports take (id, data).
Bytes that the gateway sends back (configuration) are returned by :meth:`poll_rx`.
"""

from __future__ import annotations

import errno
import heapq
import logging
import math
import os
import re
import select
import sys
import time
import tty
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from pfdoa.api import CAPTURE_V1, Chunk, OdomLine, capture_line
from pfdoasim.faults import FaultConfig, Frame

if TYPE_CHECKING:
    import can

log = logging.getLogger(__name__)



def can_id(f: Frame) -> int:
    """A CAN frame's identifier (the runner gives every frame of a CAN run one)."""
    if f.can_id is None:
        raise ValueError(f"anchor {f.anchor}: a UART frame on a CAN transport")
    return f.can_id

class Transport:
    """Base class. ``is_can`` tells the runner which framing the anchors must produce."""

    is_can = False
    name = "transport"

    def open(self) -> None:
        pass

    def paths(self) -> list[str]:
        """Paths (or channel names) a gateway opens; printed by ``pfdoa sim``."""
        return []

    def wait_reader(self, timeout_s: float) -> bool:
        """Block until a gateway has opened the port (True) or the timeout expires."""
        return True

    def has_reader(self) -> bool:
        """Whether a gateway holds the port open now (bytes sent otherwise go nowhere)."""
        return True

    def send(self, frames: list[Frame]) -> int:
        """Write frames; returns how many could not be written (port gone)."""
        raise NotImplementedError

    def poll_rx(self) -> bytes:
        return b""

    def poll_can_rx(self) -> list[tuple[int, bytes]]:
        """CAN frames from the host (CONFIG_SET), for CAN transports."""
        return []

    def set_port_up(self, up: bool) -> None:
        """Make the port disappear (False) and come back (True)."""

    def advance(self, t: float) -> None:
        """Simulated time reached ``t`` (before the frames of the beacon sent at ``t``)."""

    def odometry(self, t: float, dx: float, dy: float, dtheta: float) -> bool:
        """Carry one odometry increment; False when this transport does not (a FIFO does)."""
        return False

    def close(self) -> None:
        pass


def _make_pty() -> tuple[int, str]:
    master, slave = os.openpty()
    # Raw before any byte is written: the line discipline would otherwise translate CR/LF,
    # eat XON/XOFF and echo (toolchain notes section 5).
    tty.setraw(master)
    path = os.ttyname(slave)
    # Only the gateway holds the slave open: then POLLHUP on the master tells us whether it is.
    os.close(slave)
    os.set_blocking(master, False)
    return master, path


def _link(target: str, link: Path) -> None:
    tmp = link.with_name(link.name + ".tmp")
    try:
        tmp.unlink()
    except FileNotFoundError:
        pass
    os.symlink(target, tmp)
    os.replace(tmp, link)


class _PtyBase(Transport):
    def __init__(self, link: str | Path | None = None) -> None:
        self.link = Path(link) if link else None
        self.master = -1
        self.path = ""
        self.up = True
        self.reopens = 0
        self.write_errors = 0
        self.bytes_written = 0
        self._pending = b""

    def open(self) -> None:
        self.master, self.path = _make_pty()
        if self.link:
            _link(self.path, self.link)
        log.info("%s on %s%s", self.name, self.path, f" (link {self.link})" if self.link else "")

    def paths(self) -> list[str]:
        return [str(self.link) if self.link else self.path]

    def reader_present(self) -> bool:
        if self.master < 0:
            return False
        ev = select.poll()
        ev.register(self.master, select.POLLIN | select.POLLHUP)
        return not any(e & select.POLLHUP for _, e in ev.poll(0))

    def has_reader(self) -> bool:
        return self.reader_present()

    def wait_reader(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.reader_present():
                return True
            time.sleep(0.01)
        return False

    def _write(self, frames: list[bytes]) -> int:
        """Write whole frames (short waits while the gateway drains the pty buffer); returns
        how many were lost, counted from the end of ``frames``."""
        if not self.up or self.master < 0:
            return len(frames)
        head = len(self._pending)
        view = memoryview(self._pending + b"".join(frames))
        self._pending = b""
        done = 0
        deadline = time.monotonic() + 1.0
        while done < len(view):
            try:
                n = os.write(self.master, view[done:])
                done += n
                self.bytes_written += n
            except BlockingIOError:
                if time.monotonic() > deadline:
                    break
                select.select([], [self.master], [], 0.01)
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EBADF):
                    self.write_errors += 1
                    return len(frames)
                raise
        if done == len(view):
            return 0
        # The reader is stuck: frames not begun are lost, as on a real UART. A frame cut
        # part-way is finished first next time: a torn frame would corrupt its successor
        # too, and the lost ones would no longer be whole frames the injector can count.
        self.write_errors += 1
        end = head
        for i, f in enumerate(frames):
            start, end = end, end + len(f)
            if end > done:
                if start < done:
                    self._pending = bytes(view[done:end])
                    return len(frames) - i - 1
                return len(frames) - i
        return 0

    def poll_rx(self) -> bytes:
        if not self.up or self.master < 0:
            return b""
        out = bytearray()
        while len(out) < 65536:
            try:
                chunk = os.read(self.master, 4096)
            except BlockingIOError:
                break
            except OSError as exc:  # EIO: nobody holds the slave open
                if exc.errno == errno.EIO:
                    break
                raise
            if not chunk:
                break
            out += chunk
        return bytes(out)

    def set_port_up(self, up: bool) -> None:
        if up == self.up:
            return
        if not up:
            # The link goes first, as udev removes /dev/serial/by-id links on unplug: once
            # the master is closed its /dev/pts number is free for any process's next pty,
            # and a reader reopening a dangling link would get someone else's port.
            self._unlink()
            os.close(self.master)
            self.master = -1
            self._pending = b""
            self.up = False
            log.info("%s: port %s gone", self.name, self.path)
            return
        if self.link is None:
            raise RuntimeError("a port can only come back behind a link (--link)")
        self.open()
        self.up = True
        self.reopens += 1

    def _unlink(self) -> None:
        if self.link:
            try:
                if os.path.islink(self.link):
                    self.link.unlink()
            except OSError:
                pass

    def close(self) -> None:
        self._unlink()  # before the pty's number is freed (see set_port_up)
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


class PtyTransport(_PtyBase):
    name = "uart-pty"

    def send(self, frames: list[Frame]) -> int:
        if not frames:
            return 0
        return self._write([f.data for f in frames])


def slcan_line(can_id: int, data: bytes) -> bytes:
    """One SLCAN (Lawicel) standard-frame line: ``tIIILDD..\\r``."""
    if not 0 <= can_id <= 0x7FF or len(data) > 8:
        raise ValueError("classic 11-bit frame expected")
    return b"t%03X%d%s\r" % (can_id, len(data), data.hex().upper().encode())


SLCAN_FRAME = re.compile(rb"t([0-9A-Fa-f]{3})([0-8])([0-9A-Fa-f]*)")
SLCAN_LINE_MAX = 64


class SlcanPtyTransport(_PtyBase):
    """The adapter's side of SLCAN: frames out as ``t`` lines; from the host, ``t`` lines
    become CAN frames and commands (``C``, ``S6``, ``O``, ...) are accepted silently."""

    name = "slcan-pty"
    is_can = True

    def __init__(self, link: str | Path | None = None) -> None:
        super().__init__(link)
        self._line = b""
        self.bad_lines = 0

    def send(self, frames: list[Frame]) -> int:
        if not frames:
            return 0
        return self._write([slcan_line(can_id(f), f.data) for f in frames])

    def poll_can_rx(self) -> list[tuple[int, bytes]]:
        out = []
        lines = (self._line + self.poll_rx()).split(b"\r")
        self._line = lines.pop()[-SLCAN_LINE_MAX:]
        for line in lines:
            m = SLCAN_FRAME.fullmatch(line.strip())
            if m and len(m.group(3)) == 2 * int(m.group(2)):
                out.append((int(m.group(1), 16), bytes.fromhex(m.group(3).decode())))
            elif line.startswith(b"t"):
                self.bad_lines += 1
        return out


class CanVirtualTransport(Transport):
    name = "can-virtual"
    is_can = True

    def __init__(self, channel: str = "pfdoa-sim") -> None:
        self.channel = channel
        self.bus: can.BusABC | None = None

    def open(self) -> None:
        import can

        self.bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)

    def _bus(self) -> can.BusABC:
        if self.bus is None:
            raise RuntimeError("CanVirtualTransport used before open()")
        return self.bus

    def paths(self) -> list[str]:
        return [f"virtual:{self.channel}"]

    def wait_reader(self, timeout_s: float) -> bool:
        """Frames sent before the gateway's bus exists are lost: wait for a second bus."""
        from can.interfaces import virtual

        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with virtual.channels_lock:
                if len(virtual.channels.get(self.channel, ())) >= 2:
                    return True
            time.sleep(0.01)
        return False

    def send(self, frames: list[Frame]) -> int:
        import can

        bus = self._bus()
        for f in frames:
            bus.send(can.Message(arbitration_id=can_id(f), data=f.data, is_extended_id=False))
        return 0

    def poll_can_rx(self) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        bus = self._bus()
        while len(out) < 256 and (m := bus.recv(0.0)) is not None:
            if not (m.is_error_frame or m.is_remote_frame or m.is_extended_id):
                out.append((m.arbitration_id, bytes(m.data)))
        return out

    def close(self) -> None:
        if self.bus is not None:
            self.bus.shutdown()
            self.bus = None


class StdoutTransport(Transport):
    name = "stdout"

    def __init__(self, stream=None) -> None:
        self.stream = stream or sys.stdout.buffer

    def paths(self) -> list[str]:
        return ["-"]

    def send(self, frames: list[Frame]) -> int:
        self.stream.write(b"".join(f.data for f in frames))
        self.stream.flush()
        return 0


class TimedStreamTransport(Transport):
    """Virtual time: frames and odometry as a timed capture stream (see the module doc).

    A frame sent at simulated time ``t`` arrives at ``t`` plus 0..``jitter_ms`` (uniform),
    rounded up to the next ``batch_ms`` boundary, deferred to the end of any ``stall`` it
    falls in, and never before the frame sent before it on the same source (a byte stream
    or a CAN bus stays in order). Lines are written in arrival order (ties: in the order
    sent): the simulator calls :meth:`advance` at each beacon, and every line due by then
    goes out. ``sources`` names each anchor's port (default: one ``serial0``, or ``can0``).
    """

    name = "timed"

    def __init__(self, stream: BinaryIO, *, can: bool = False, faults: FaultConfig | None = None,
                 rng: np.random.Generator | None = None, sources: dict[int, str] | None = None,
                 odometry: bool = False) -> None:
        self.stream = stream
        self.carry_odometry = odometry
        self.is_can = can
        f = faults or FaultConfig()
        self.jitter_s = f.jitter_ms / 1000.0
        self.batch_s = f.batch_ms / 1000.0
        self.stalls = tuple((s.start_s, s.start_s + s.duration_s) for s in f.stall)
        self.rng = rng or np.random.default_rng(0)
        self.sources = dict(sources or {})
        self.default_source = "can0" if can else "serial0"
        self._last: dict[str, float] = {}
        self._heap: list[tuple[float, int, str]] = []
        self._n = 0
        self.lines = 0
        self.frames = 0
        self.broken = False  # the reader went away

    def open(self) -> None:
        self._write(CAPTURE_V1 + "\n")

    def paths(self) -> list[str]:
        return ["-"]

    def arrival(self, source: str, t: float) -> float:
        a = t + (float(self.rng.uniform(0.0, self.jitter_s)) if self.jitter_s else 0.0)
        if self.batch_s:
            a = math.ceil(a / self.batch_s - 1e-9) * self.batch_s
        for lo, hi in self.stalls:
            if lo <= a < hi:
                a = hi
        a = max(a, self._last.get(source, -math.inf))
        self._last[source] = a
        return a

    def send(self, frames: list[Frame]) -> int:
        for f in sorted(frames, key=lambda f: f.t):
            src = self.sources.get(f.anchor, self.default_source)
            a = self.arrival(src, f.t)
            item = Chunk(src, a, f.data, f.can_id if self.is_can else None)
            self._push(a, capture_line(item))
            self.frames += 1
        return 0

    def odometry(self, t: float, dx: float, dy: float, dtheta: float) -> bool:
        if self.carry_odometry:
            self._push(t, capture_line(OdomLine(t, t, dx, dy, dtheta)))
        return True

    def _push(self, t: float, line: str) -> None:
        heapq.heappush(self._heap, (t, self._n, line))
        self._n += 1

    def advance(self, t: float) -> None:
        out = []
        while self._heap and self._heap[0][0] <= t:
            out.append(heapq.heappop(self._heap)[2])
        if out:
            self._write("".join(out))

    def _write(self, text: str) -> None:
        if self.broken:
            return
        try:
            self.stream.write(text.encode("ascii"))
            self.lines += text.count("\n")
        except (BrokenPipeError, ValueError, OSError) as exc:
            self.broken = True
            log.warning("timed stream: the reader went away (%s)", exc)

    def close(self) -> None:
        self.advance(math.inf)
        if not self.broken:
            try:
                self.stream.flush()
            except (BrokenPipeError, ValueError, OSError):
                self.broken = True
