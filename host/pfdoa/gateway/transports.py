"""Transports: where anchor bytes and CAN frames come from, behind one small interface.

Every transport (python-can ``BusABC`` style) has ``open()``, ``read(timeout)`` returning a
list of :class:`Chunk` (empty on timeout), an idempotent ``close()`` and is a context
manager. ``read`` raises :class:`TransportEOF` when a finite source (standard input, a
capture file) is exhausted and :class:`TransportError` when a device fails (unplugged
serial adapter, CAN interface down); :class:`Source` reopens those with backoff.

* :class:`SerialTransport` - anything pyserial's ``serial_for_url`` opens: ``/dev/ttyUSB0``,
  ``/dev/pts/3``, ``loop://``, ``socket://host:port``, ``rfc2217://host:port``. A baud
  rate may follow the URL after ``@`` (``/dev/ttyACM0@921600``).
* :class:`CanTransport` - python-can, from ``INTERFACE:CHANNEL[@BITRATE][,key=value...]``
  (``socketcan:can0``, ``slcan:/dev/ttyACM0@500000``, ``virtual:vc0``) or
  ``config[:PATH]`` for python-can's own configuration file. Acceptance filters pass only
  the identifiers of protocol/SPEC.md section 4 (anchor-to-host types).
* :class:`StdinTransport` - the byte stream on standard input.
* :class:`CaptureReader` / :class:`CaptureWriter` - raw capture files (below).

Capture format (text, one chunk per line, like candump's log format)::

    # pfdoa capture v1
    (1700000000.123456) serial0 S 0a0101...      # bytes read from a byte stream, hex
    (1700000000.124001) can0 C 101#0a00f0d9...   # a CAN frame: 11-bit id hex '#' data hex

Fields: receive time (Unix seconds), source name (no spaces), kind (``S`` stream or ``C``
CAN), payload. ``#`` lines are comments. Replaying a capture feeds the same decoders as
live input, one decoder per source name.
"""

from __future__ import annotations

import logging
import os
import re
import select
import sys
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import IO

from pfdoa.errors import InputError

log = logging.getLogger(__name__)

READ_MAX = 4096  # bytes per read call; bounds every chunk
CAPTURE_MAX_LINE = 2 * READ_MAX + 256
CAPTURE_HEADER = "# pfdoa capture v1"


class TransportError(Exception):
    """The device failed or vanished; the source may come back (reopen with backoff)."""


class TransportEOF(Exception):
    """A finite source ended (standard input closed, capture file fully read)."""


@dataclass(slots=True)
class Chunk:
    """Bytes from a byte stream (``can_id`` None) or one CAN frame's data."""

    source: str
    t: float  # receive time, Unix seconds
    data: bytes
    can_id: int | None = None


class Transport(ABC):
    """One input. Subclasses implement ``_open``, ``_read``, ``_close``."""

    name: str = ""
    finite = False  # True: ends with TransportEOF and is not reopened

    def __init__(self) -> None:
        self._is_open = False

    def open(self) -> "Transport":
        if not self._is_open:
            self._open()
            self._is_open = True
        return self

    def read(self, timeout: float) -> list[Chunk]:
        if not self._is_open:
            raise TransportError(f"{self.name}: not open")
        return self._read(timeout)

    def close(self) -> None:
        if self._is_open:
            self._is_open = False
            try:
                self._close()
            except Exception as exc:  # closing a vanished device may fail; nothing to do
                log.debug("%s: close: %s", self.name, exc)

    @property
    def is_open(self) -> bool:
        return self._is_open

    def __enter__(self) -> "Transport":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _read(self, timeout: float) -> list[Chunk]: ...

    @abstractmethod
    def _close(self) -> None: ...


def split_baud(spec: str, default: int) -> tuple[str, int]:
    """``URL[@BAUD]`` -> (url, baud). Only a trailing all-digit ``@`` part is a baud rate."""
    m = re.fullmatch(r"(.+)@(\d+)", spec)
    if m:
        return m.group(1), int(m.group(2))
    return spec, default


class SerialTransport(Transport):
    def __init__(self, url: str, baudrate: int = 115200, name: str | None = None) -> None:
        super().__init__()
        self.url = url
        self.baudrate = baudrate
        self.name = name or url
        self._port = None

    def _open(self) -> None:
        import serial

        try:
            # exclusive: a second reader on the same tty would steal bytes.
            kw = {"exclusive": True} if "://" not in self.url else {}
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.1, **kw)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(f"{self.url}: {exc}") from None

    def _read(self, timeout: float) -> list[Chunk]:
        import serial

        port = self._port
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            data = port.read(1)
            if not data:
                return []
            waiting = port.in_waiting
            if waiting:
                data += port.read(min(waiting, READ_MAX - 1))
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"{self.url}: {exc}") from None
        return [Chunk(self.name, time.time(), bytes(data))]

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            port.close()


# Anchor-to-host CAN identifiers (protocol/SPEC.md section 4).
def _default_can_filters() -> list[dict]:
    from pfdoa.protocol.can import GATEWAY_CAN_FILTERS

    return [dict(f) for f in GATEWAY_CAN_FILTERS]


def _coerce(value: str):
    low = value.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(value)
        except ValueError:
            pass
    return value


def parse_can_spec(spec: str) -> dict:
    """``INTERFACE:CHANNEL[@BITRATE][,key=value...]`` or ``config[:PATH]`` -> python-can kwargs."""
    head, *opts = spec.split(",")
    kwargs: dict = {}
    if head == "config" or head.startswith("config:"):
        from can.util import load_config

        path = head[len("config:"):] or None
        if path and not os.path.exists(path):
            raise InputError(f"--can {spec}: no such configuration file {path!r}")
        try:
            kwargs.update(load_config(path=path))
        except Exception as exc:  # python-can raises several types for bad files
            raise InputError(f"--can {spec}: {exc}") from None
    else:
        iface, sep, channel = head.partition(":")
        if not sep or not iface or not channel:
            raise InputError(
                f"--can {spec!r}: expected INTERFACE:CHANNEL[@BITRATE] (e.g. socketcan:can0, "
                "slcan:/dev/ttyACM0@500000, virtual:vc0) or config[:PATH]"
            )
        m = re.fullmatch(r"(.+)@(\d+)", channel)
        if m:
            channel, kwargs["bitrate"] = m.group(1), int(m.group(2))
        kwargs["interface"], kwargs["channel"] = iface, channel
    for opt in opts:
        key, sep, value = opt.partition("=")
        if not sep or not key:
            raise InputError(f"--can {spec!r}: option {opt!r} is not key=value")
        kwargs[key.strip()] = _coerce(value.strip())
    return kwargs


class CanTransport(Transport):
    def __init__(self, spec: str, name: str | None = None, filters: list[dict] | None = None) -> None:
        super().__init__()
        self.spec = spec
        self.kwargs = parse_can_spec(spec)
        if self.kwargs.get("interface") == "slcan":
            # python-can waits 2 s after opening an SLCAN port by default; adapters that need
            # it can still ask with ",sleep_after_open=2".
            self.kwargs.setdefault("sleep_after_open", 0)
        self.filters = _default_can_filters() if filters is None else filters
        self.name = name or f"can:{self.kwargs.get('channel', 'config')}"
        self._bus = None
        self.ignored = 0  # error/remote/extended frames

    def _open(self) -> None:
        import can

        try:
            self._bus = can.Bus(can_filters=self.filters, **self.kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None
        except TypeError as exc:  # unknown keyword option
            raise InputError(f"--can {self.spec}: {exc}") from None

    def _read(self, timeout: float) -> list[Chunk]:
        import can

        out: list[Chunk] = []
        try:
            msg = self._bus.recv(timeout)
            while msg is not None and len(out) < 256:
                if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                    self.ignored += 1
                else:
                    out.append(Chunk(self.name, time.time(), bytes(msg.data), msg.arbitration_id))
                msg = self._bus.recv(0.0)
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None
        return out

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


class StdinTransport(Transport):
    """The raw byte stream on standard input (or any readable file descriptor)."""

    finite = True

    def __init__(self, fd: int | None = None, name: str = "stdin") -> None:
        super().__init__()
        self.fd = sys.stdin.fileno() if fd is None else fd
        self.name = name

    def _open(self) -> None:
        pass

    def _read(self, timeout: float) -> list[Chunk]:
        r, _, _ = select.select([self.fd], [], [], timeout)
        if not r:
            return []
        try:
            data = os.read(self.fd, READ_MAX)
        except OSError as exc:
            if exc.errno == 5:  # EIO: the other side of a pty closed
                raise TransportEOF(self.name) from None
            raise TransportError(f"{self.name}: {exc}") from None
        if not data:
            raise TransportEOF(self.name)
        return [Chunk(self.name, time.time(), data)]

    def _close(self) -> None:
        pass


_CAPTURE_RE = re.compile(r"\((\d+(?:\.\d*)?)\) (\S+) (S|C)(?: (\S*))?")


class CaptureWriter:
    """Appends every chunk it is given to a capture file (format in the module doc)."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._fh: IO[str] | None = open(path, "w", encoding="ascii")
        except OSError as exc:
            raise InputError(f"{path}: cannot write capture: {exc.strerror or exc}") from None
        self._fh.write(CAPTURE_HEADER + "\n")
        self.chunks = 0

    def write(self, c: Chunk) -> None:
        if self._fh is None:
            return
        src = re.sub(r"\s", "_", c.source) or "-"
        if c.can_id is None:
            line = f"({c.t:.6f}) {src} S {c.data.hex()}\n"
        else:
            line = f"({c.t:.6f}) {src} C {c.can_id:03X}#{c.data.hex().upper()}\n"
        self._fh.write(line)
        self.chunks += 1

    def close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            fh.close()


class CaptureReader(Transport):
    """Replays a capture file; ``realtime`` paces chunks by their recorded times."""

    finite = True

    def __init__(self, path: str, realtime: bool = False, name: str | None = None) -> None:
        super().__init__()
        self.path = path
        self.realtime = realtime
        self.name = name or path
        self.bad_lines = 0
        self._fh: IO[str] | None = None
        self._lineno = 0
        self._t0: tuple[float, float] | None = None  # (capture time, wall time) of the first chunk

    def _open(self) -> None:
        try:
            self._fh = open(self.path, encoding="ascii", errors="replace")
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read capture: {exc.strerror or exc}") from None

    def parse_line(self, line: str) -> Chunk | None:
        """One capture line -> chunk; None for comments, blank and malformed lines (counted)."""
        s = line.strip()
        if not s or s.startswith("#"):
            return None
        m = _CAPTURE_RE.fullmatch(s)
        try:
            if not m:
                raise ValueError("bad line")
            t, src, kind, payload = float(m.group(1)), m.group(2), m.group(3), m.group(4) or ""
            if t == float("inf"):  # 309+ digits: one such line would stall every replay timer
                raise ValueError("time out of range")
            if kind == "S":
                return Chunk(src, t, bytes.fromhex(payload))
            cid, sep, data = payload.partition("#")
            if not sep or len(data) > 16:
                raise ValueError("bad CAN frame")
            can_id = int(cid, 16)
            if not 0 <= can_id <= 0x7FF:
                raise ValueError("CAN id out of range")
            return Chunk(src, t, bytes.fromhex(data), can_id)
        except ValueError:
            self.bad_lines += 1
            if self.bad_lines <= 5:
                log.warning("%s:%d: malformed capture line skipped", self.path, self._lineno)
            return None

    def _next(self) -> Chunk | None:
        """The next chunk in the file, None at its end."""
        while True:
            line = self._fh.readline(CAPTURE_MAX_LINE)
            if not line:
                return None
            self._lineno += 1
            if len(line) >= CAPTURE_MAX_LINE and not line.endswith("\n"):
                self.bad_lines += 1
                while line and not line.endswith("\n"):  # skip the rest of the overlong line
                    line = self._fh.readline(CAPTURE_MAX_LINE)
                continue
            c = self.parse_line(line)
            if c is not None:
                return c

    def _read(self, timeout: float) -> list[Chunk]:
        out: list[Chunk] = []
        limit = 1 if self.realtime else 64
        while len(out) < limit:
            c = self._next()
            if c is None:
                if out:
                    return out
                raise TransportEOF(self.path)
            if self.realtime:
                if self._t0 is None:
                    self._t0 = (c.t, time.monotonic())
                delay = (c.t - self._t0[0]) - (time.monotonic() - self._t0[1])
                if delay > 0:
                    time.sleep(min(delay, 10.0))
            out.append(c)
        return out

    def _close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            fh.close()
