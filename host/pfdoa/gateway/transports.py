"""Transports: where anchor bytes and CAN frames come from, behind one small interface.

Every transport (python-can ``BusABC`` style) has ``open()``, ``read(timeout)`` returning a
list of items (:class:`Chunk`, and from capture files also :class:`OdomLine` and
:class:`TimeMark`; empty on timeout), an idempotent ``close()`` and is a context manager.
``read`` raises :class:`TransportEOF` when a finite source (standard input, a capture file)
is exhausted and :class:`TransportError` when a device fails (unplugged serial adapter, CAN
interface down); the runner's reader (:mod:`pfdoa.gateway.runner`) reopens those with
backoff. A transport that cannot work at all (a malformed URL, a file that is not a
device) raises :class:`TransportFatal`, which is not retried.

Chunks are stamped with the injected clock (:mod:`pfdoa.clock`) when they are read. After
each ``read``, ``caught_up_to`` says up to which time everything that had arrived has been
returned (None: more is waiting, e.g. a full read buffer): the runner's timers never run
ahead of it, so input that merely waits in a kernel buffer cannot time out a set.

* :class:`SerialTransport` - anything pyserial's ``serial_for_url`` opens: ``/dev/ttyUSB0``,
  ``/dev/pts/3``, ``loop://``, ``socket://host:port``, ``rfc2217://host:port``. A baud
  rate may follow the URL after ``@`` (``/dev/ttyACM0@921600``).
* :class:`CanTransport` - python-can, from ``INTERFACE:CHANNEL[@BITRATE][,key=value...]``
  (``socketcan:can0``, ``slcan:/dev/ttyACM0@500000``, ``virtual:vc0``) or
  ``config[:PATH]`` for python-can's own configuration file. Acceptance filters pass only
  the identifiers of protocol/SPEC.md section 4 (anchor-to-host types).
* :class:`StdinTransport` - the byte stream on standard input.
* :class:`CaptureReader` / :class:`CaptureWriter` - capture files (below); ``-`` is
  standard input, so a timed stream can be piped into the gateway.

Capture format (text, one item per line, like candump's log format)::

    # pfdoa capture v2
    (1700000000.123456) serial0 S 0a0101...      # bytes read from a byte stream, hex
    (1700000000.124001) can0 C 101#0a00f0d9...   # a CAN frame: 11-bit id hex '#' data hex
    (1700000000.130017) odom O 1700000000.125,0.012,0,0.001   # an odometry increment
    (1700000000.150000) - T                      # the gateway's timers ran at this time

Fields: receive time (Unix seconds, or any seconds: a simulator's stream starts at 0),
source name (no spaces), kind, payload. ``#`` lines are comments. Times are written with
every digit a float needs (shortest exact form), so a replay sees the very stamps the live
gateway saw. Replaying a capture feeds the same decoders as live input, one decoder per
source name. The header says when the timers run: ``v2`` (what the gateway writes) has a
``T`` line wherever the live gateway polled its timers, and a replay polls there and only
there; in ``v1`` (a simulator's timed stream, older captures) the timers run at each
chunk's time, after it.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import select
import stat
import sys
import termios
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import IO, Union

import numpy as np

from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import InputError, PfdoaError

log = logging.getLogger(__name__)

MAX_DECODERS = 64  # byte-stream sources (ports, capture source names) decoded at once (pfdoa.gateway.decoding)
# A source's decoder may make room for a new source once nothing came from it for this long
# (chunk times; pfdoa.gateway.decoding.Gateway._make_room).
DECODER_IDLE_S = 30.0
READ_MAX = 4096  # bytes per read call; bounds every chunk
CAPTURE_MAX_LINE = 2 * READ_MAX + 256
# A capture's times come from one clock in processing order: a line more than this far
# before the previous one, or this far after it, did not (counted, the first few named).
CAPTURE_BACK_S = 1.0
CAPTURE_LEAP_S = 86400.0
CAPTURE_WARN_LINES = 5  # malformed lines and time jumps named on the log, per file and kind
CAPTURE_V1 = "# pfdoa capture v1"
CAPTURE_V2 = "# pfdoa capture v2"
CAPTURE_HEADER = CAPTURE_V2
TIMER_SOURCE = "-"  # source field of T lines
ODOM_SOURCE = "odom"  # source field of O lines


class TransportError(PfdoaError):
    """The device failed or vanished; the source may come back (reopen with backoff)."""


class TransportFatal(TransportError):
    """The source can never work as given (bad URL, not a device): not retried, exit 2."""

    exit_code = 2


class TransportAbsent(TransportError):
    """The device is not there at all (no such path, no such interface): one not yet seen
    is waited for (pfdoa.gateway.runner, ``--wait-for-device``); a one-shot command stops."""

    exit_code = 2

    def __init__(self, option: str, device: str) -> None:
        self.device = device
        super().__init__(f"{option} {device}: not present")


class TransportEOF(Exception):
    """A finite source ended (standard input closed, capture file fully read)."""


@dataclass(slots=True)
class Chunk:
    """Bytes from a byte stream (``can_id`` None) or one CAN frame's data."""

    source: str
    t: float  # receive time, host seconds
    data: bytes
    can_id: int | None = None


@dataclass(slots=True, frozen=True)
class OdomLine:
    """One odometry increment as received (capture ``O`` line): its arrival time ``t`` and
    the increment ``(t_odom, dx, dy, dtheta)``."""

    t: float
    t_odom: float
    dx: float
    dy: float
    dtheta: float


@dataclass(slots=True, frozen=True)
class TimeMark:
    """Capture ``T`` line: the gateway's timers ran at ``t``."""

    t: float


Item = Union[Chunk, OdomLine, TimeMark]


def format_time(t: float) -> str:
    """Seconds with every digit the float needs and no exponent (round-trips exactly)."""
    return np.format_float_positional(float(t), unique=True, trim="-")


class Transport(ABC):
    """One input. Subclasses implement ``_open``, ``_read``, ``_close``; bidirectional ones
    (serial ports, CAN buses: ``pfdoa anchors`` sends on them) also ``_send``."""

    name: str = ""
    finite = False  # True: ends with TransportEOF and is not reopened
    # True: a live input with its own bounded inbox that counts what it drops (the MQTT
    # inputs): the runner's reader may wait for the pipeline, since the loss, if any, is
    # counted there per message rather than here per read.
    buffered = False
    bidirectional = False  # True: send() reaches the anchors
    is_can = False  # True: CAN frames (send with a can_id), else a byte stream

    def __init__(self, clock: Clock | None = None) -> None:
        self._is_open = False
        self.clock = clock or SYSTEM
        # After read(): everything that arrived before this time has been returned; None
        # when more is known to be waiting (see the module doc).
        self.caught_up_to: float | None = None

    def open(self) -> "Transport":
        if not self._is_open:
            self._open()
            self._is_open = True
        return self

    def read(self, timeout: float) -> list[Item]:
        if not self._is_open:
            raise TransportError(f"{self.name}: not open")
        self.caught_up_to = None
        return self._read(timeout)

    def lost(self, item: Item) -> None:  # noqa: B027 (optional hook: most inputs keep no such count)
        """An item this input returned that the pipeline never got (the reader's queue was
        full, or the run stopped while it waited): for the input's own counters."""

    def close(self) -> None:
        if self._is_open:
            self._is_open = False
            try:
                self._close()
            except Exception as exc:  # closing a vanished device may fail; nothing to do
                log.debug("%s: close: %s", self.name, exc)

    def send(self, data: bytes, can_id: int | None = None) -> None:
        """Send to the anchors: UART bytes (``can_id`` None) or one CAN frame. Raises
        TransportFatal on an input that cannot send, TransportError when the device fails."""
        if not self.bidirectional:
            raise TransportFatal(f"{self.name}: cannot send to the anchors (this input is not bidirectional)")
        if not self._is_open:
            raise TransportError(f"{self.name}: not open")
        self._send(data, can_id)

    def _send(self, data: bytes, can_id: int | None) -> None:
        raise NotImplementedError

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
    def _read(self, timeout: float) -> list[Item]: ...

    @abstractmethod
    def _close(self) -> None: ...


def split_baud(spec: str, default: int) -> tuple[str, int]:
    """``URL[@BAUD]`` -> (url, baud). Only a trailing all-digit ``@`` part is a baud rate."""
    m = re.fullmatch(r"(.+)@(\d+)", spec)
    if m:
        return m.group(1), int(m.group(2))
    return spec, default


class SerialTransport(Transport):
    bidirectional = True

    def __init__(self, url: str, baudrate: int = 115200, name: str | None = None,
                 clock: Clock | None = None) -> None:
        super().__init__(clock)
        self.url = url
        self.baudrate = baudrate
        self.name = name or url
        self._port = None
        self._failed: Exception | None = None

    def _open(self) -> None:
        import serial

        self._failed = None
        local = "://" not in self.url
        if local and os.path.exists(self.url) and not _is_char_device(self.url):
            raise TransportFatal(f"--serial {self.url}: not a serial device (a regular file or directory)")
        if local and not os.path.exists(self.url):
            raise TransportAbsent("--serial", self.url)
        try:
            # exclusive: a second reader on the same tty would steal bytes.
            kw = {"exclusive": True} if local else {}
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.1, **kw)
        except ValueError as exc:  # a malformed URL or parameter: retrying cannot help
            raise TransportFatal(f"--serial {self.url}: {exc}") from None
        except (serial.SerialException, OSError) as exc:
            raise _open_error("--serial", self.url, exc, local) from None

    def _read(self, timeout: float) -> list[Item]:
        import serial

        port = self._port
        if self._failed is not None:  # the device failed after the bytes it still delivered
            exc, self._failed = self._failed, None
            raise TransportError(f"{self.url}: {exc}")
        data = b""
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            data = port.read(1)
            if data:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, READ_MAX - 1))
            # Stamp, then look: if nothing is waiting now, nothing arrived before the stamp
            # that we have not read (a stamp taken after the look could hide a byte).
            t = self.clock.now()
            if not port.in_waiting:
                self.caught_up_to = t
        except (serial.SerialException, OSError) as exc:
            if not data:
                raise TransportError(f"{self.url}: {exc}") from None
            self._failed = exc  # deliver what was read; the error comes with the next read
            t = self.clock.now()
        return [Chunk(self.name, t, bytes(data))] if data else []

    def _send(self, data: bytes, can_id: int | None) -> None:
        import serial

        if can_id is not None:
            raise TransportFatal(f"{self.name}: a serial port carries UART frames, not CAN frames")
        try:
            self._port.write(data)
            self._drain()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise TransportError(f"{self.url}: {exc}") from None

    def _drain(self) -> None:
        """Wait until the frame has left (pyserial's flush: tcdrain). A signal there (its
        handler has run: pfdoa.signals) makes tcdrain fail with EINTR, which the termios
        module does not retry: drain on."""
        while True:
            try:
                self._port.flush()
                return
            except termios.error as exc:
                if not (exc.args and exc.args[0] == errno.EINTR):
                    raise

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            port.close()


# Anchor-to-host CAN identifiers (protocol/SPEC.md section 4).
def _default_can_filters() -> list[dict]:
    from pfdoa.protocol.can import GATEWAY_CAN_FILTERS

    return [dict(f) for f in GATEWAY_CAN_FILTERS]


def _not_a_terminal(exc: BaseException) -> bool:
    """pyserial could open the device but not configure it as a terminal (ENOTTY)."""
    for e in (exc, exc.__context__, exc.__cause__):
        if e is not None and (getattr(e, "errno", None) == errno.ENOTTY or (e.args and e.args[0] == errno.ENOTTY)):
            return True
    return False


def _errno(exc: BaseException) -> int | None:
    for e in (exc, exc.__context__, exc.__cause__):
        if e is None:
            continue
        n = getattr(e, "errno", None)
        if n is None and e.args and isinstance(e.args[0], int):
            n = e.args[0]
        if n is not None:
            return int(n)
    return None


def _open_error(option: str, device: str, exc: BaseException, local: bool) -> TransportError:
    """What opening a device failed with: for ever (exit 2), not there (waited for), or for now."""
    n = _errno(exc)
    if _not_a_terminal(exc):  # /dev/null, /dev/zero: a device, but never a serial port
        return TransportFatal(f"{option} {device}: not a serial device ({exc})")
    if n in (errno.EACCES, errno.EPERM):
        return TransportFatal(f"{option} {device}: permission denied (this user may not open it: for a serial "
                              "port, the dialout group)")
    if n == errno.EAFNOSUPPORT:
        return TransportFatal(f"{option} {device}: this system's kernel does not support it ({exc})")
    if (local and n == errno.ENOENT) or n == errno.ENODEV:
        return TransportAbsent(option, device)
    return TransportError(f"{device}: {exc}")


def _is_char_device(path: str) -> bool:
    import stat

    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


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
    bidirectional = True
    is_can = True

    def __init__(self, spec: str, name: str | None = None, filters: list[dict] | None = None,
                 clock: Clock | None = None) -> None:
        super().__init__(clock)
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

    def counters(self) -> dict:
        """For the final counters: frames ignored (error, remote, extended id)."""
        return {"ignored": self.ignored} if self.ignored else {}

    def _open(self) -> None:
        import can

        iface = self.kwargs.get("interface")
        if iface is not None and iface not in can.VALID_INTERFACES:
            raise TransportFatal(f"--can {self.spec}: unknown interface {iface!r} "
                                 f"(python-can knows: {', '.join(sorted(can.VALID_INTERFACES))})")
        channel = str(self.kwargs.get("channel", ""))
        if iface == "slcan" and "://" not in channel and channel and not os.path.exists(channel.split("@")[0]):
            raise TransportAbsent("--can", self.spec)  # the adapter's serial port is not plugged in
        try:
            self._bus = can.Bus(can_filters=self.filters, **self.kwargs)
        except (ValueError, ImportError) as exc:  # bad parameters or a missing driver: permanent
            raise TransportFatal(f"--can {self.spec}: {exc}") from None
        except (can.CanError, OSError) as exc:
            raise _open_error("--can", self.spec, exc, local=iface == "slcan") from None
        except TypeError as exc:  # unknown keyword option
            raise TransportFatal(f"--can {self.spec}: {exc}") from None

    def _read(self, timeout: float) -> list[Item]:
        import can

        out: list[Item] = []
        try:
            msg = self._bus.recv(timeout)
            while True:
                if msg is None:
                    t = self.clock.now()  # stamp, then look (see SerialTransport._read)
                    msg = self._bus.recv(0.0)
                    if msg is None:
                        self.caught_up_to = t
                        return out
                if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                    self.ignored += 1
                else:
                    out.append(Chunk(self.name, self.clock.now(), bytes(msg.data), msg.arbitration_id))
                    if len(out) >= 256:
                        return out  # more may be waiting: caught_up_to stays None
                msg = self._bus.recv(0.0)
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None

    def _send(self, data: bytes, can_id: int | None) -> None:
        import can

        if can_id is None:
            raise TransportFatal(f"{self.name}: a CAN bus carries CAN frames, not UART bytes")
        try:
            self._bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


class StdinTransport(Transport):
    """The raw byte stream on standard input (or any readable file descriptor)."""

    finite = True

    def __init__(self, fd: int | None = None, name: str = "stdin", clock: Clock | None = None) -> None:
        super().__init__(clock)
        self.fd = (sys.stdin.fileno() if sys.stdin is not None else -1) if fd is None else fd
        self.name = name

    def _open(self) -> None:
        if self.fd < 0:  # started with standard input closed (`<&-`)
            raise TransportFatal("--stdin: standard input is closed; pipe the anchors' byte stream in")
        if os.isatty(self.fd):
            # A terminal in cooked mode would edit and echo the bytes: anchors' frames are binary.
            raise TransportFatal("--stdin is a terminal; pipe the anchors' byte stream in "
                                 "(e.g. some-anchor-sim | pfdoa gateway ... --stdin)")

    def _read(self, timeout: float) -> list[Item]:
        r, _, _ = select.select([self.fd], [], [], timeout)
        data = b""
        if r:
            try:
                data = os.read(self.fd, READ_MAX)
            except OSError as exc:
                if exc.errno == 5:  # EIO: the other side of a pty closed
                    raise TransportEOF(self.name) from None
                raise TransportError(f"{self.name}: {exc}") from None
            if not data:
                raise TransportEOF(self.name)
        t = self.clock.now()  # stamp, then look (see SerialTransport._read)
        if not select.select([self.fd], [], [], 0)[0]:
            self.caught_up_to = t
        return [Chunk(self.name, t, data)] if data else []

    def _close(self) -> None:
        pass


_CAPTURE_RE = re.compile(r"\((\d+(?:\.\d*)?)\) (\S+) (S|C|O|T)(?: (\S*))?")


def capture_line(item: Item) -> str:
    """The capture line of one item (with its newline)."""
    t = format_time(item.t)
    if isinstance(item, TimeMark):
        return f"({t}) {TIMER_SOURCE} T\n"
    if isinstance(item, OdomLine):
        vals = ",".join(format_time(v) for v in (item.t_odom, item.dx, item.dy, item.dtheta))
        return f"({t}) {ODOM_SOURCE} O {vals}\n"
    src = re.sub(r"\s", "_", item.source) or "-"
    if item.can_id is None:
        return f"({t}) {src} S {item.data.hex()}\n"
    return f"({t}) {src} C {item.can_id:03X}#{item.data.hex().upper()}\n"


class CaptureWriter:
    """Writes every input the gateway processes, in order, to a capture file (format in
    the module doc): chunks, odometry increments and the times its timers ran.

    The file is opened by :func:`pfdoa.outfiles.open_stream`; ``existing="keep"`` (the
    gateway) continues a capture that is there (a restarted gateway's: the header only into
    a new file; the new run's times follow the old ones, and its first line after them is
    a comment) and moves anything else aside."""

    def __init__(self, path: str, existing: str = "replace") -> None:
        from pfdoa.errors import OutputError
        from pfdoa.outfiles import open_fd

        self.path = path
        fresh = True
        try:
            if path == "-":  # standard output (the positions then go elsewhere: check_outputs)
                if sys.stdout is None:
                    raise InputError("--capture -: standard output is closed")
                self._fh: IO[str] | None = open(sys.stdout.fileno(), "w", encoding="ascii", closefd=False)
            else:
                fd, fresh = open_fd(path, "--capture", existing=existing,
                                    same_kind=lambda first: first == CAPTURE_HEADER.encode())
                self._fh = open(fd, "w", encoding="ascii")
        except ValueError as exc:  # a NUL in the path
            raise OutputError(f"--capture {path}: cannot write: {exc}") from None
        self._fh.write((CAPTURE_HEADER if fresh else f"# pfdoa: a new run at {self._started()}") + "\n")
        self.chunks = 0
        self.errors = 0

    @staticmethod
    def _started() -> str:
        import time

        return time.strftime("%Y-%m-%dT%H:%M:%S%z")

    def write(self, item: Item) -> None:
        if self._fh is None:
            return
        line = capture_line(item)
        self.chunks += isinstance(item, Chunk)
        try:
            self._fh.write(line)
        except OSError as exc:  # a full disk must not stop the gateway: stop capturing, say so
            self.errors += 1
            log.error("%s: capture stopped: %s", self.path, exc.strerror or exc)
            self.close()

    def close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            try:
                fh.close()
            except OSError as exc:
                self.errors += 1
                log.error("%s: closing the capture: %s", self.path, exc.strerror or exc)


def _odom_fields(text: str) -> tuple[float, float, float, float]:
    parts = text.split(",")
    if len(parts) != 4:
        raise ValueError("expected t,dx,dy,dtheta")
    vals = tuple(float(v) for v in parts)
    if not all(np.isfinite(vals)):
        raise ValueError("not finite")
    return vals  # type: ignore[return-value]


class CaptureReader(Transport):
    """Replays a capture file (``-``: standard input); ``realtime`` paces items by their
    recorded times on the injected clock. ``explicit_timers``: the file is v2, its ``T``
    lines say when the timers ran (see the module doc)."""

    finite = True

    def __init__(self, path: str, realtime: bool = False, name: str | None = None, clock: Clock | None = None) -> None:
        super().__init__(clock)
        self.path = path
        self.realtime = realtime
        self.name = name or ("stdin" if path == "-" else path)
        self.bad_lines = 0
        self.time_jumps = 0  # lines whose time jumps (CAPTURE_BACK_S back, CAPTURE_LEAP_S ahead)
        self.explicit_timers = False
        self._fh: IO[str] | None = None
        self._lineno = 0
        self._last_t: float | None = None
        self._t0: tuple[float, float] | None = None  # (capture time, clock.monotonic()) of the first item
        self._first: str | None = None
        self._batch = 64  # items per read; 1 for a pipe or terminal (see _open)

    def counters(self) -> dict:
        """For the final counters: what the file held that was not as it should be."""
        return {"bad_lines": self.bad_lines, "time_jumps": self.time_jumps}

    def _open(self) -> None:
        try:
            if self.path == "-":
                if sys.stdin is None:  # started with standard input closed (`<&-`)
                    raise TransportFatal("--replay-capture -: standard input is closed")
                self._fh = open(sys.stdin.fileno(), encoding="ascii", errors="replace", closefd=False)
            else:
                self._fh = open(self.path, encoding="ascii", errors="replace")
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read capture: {exc.strerror or exc}") from None
        # A regular file is read in batches of 64 items; a pipe (a live `pfdoa gateway
        # --capture -` piped in) item by item, so no item waits for 63 more to arrive.
        self._batch = 64 if stat.S_ISREG(os.fstat(self._fh.fileno()).st_mode) else 1
        # The header decides the timer rule; read it now (a pipe's first line may take a while).
        first = self._fh.readline(CAPTURE_MAX_LINE)
        self._lineno = 1
        self.explicit_timers = first.strip() == CAPTURE_V2
        self._first = first  # parsed like any other line (a headerless capture is v1)

    def parse_line(self, line: str) -> Item | None:
        """One capture line -> item; None for comments, blank and malformed lines (counted)."""
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
            if kind == "T":
                if payload:
                    raise ValueError("payload on a T line")
                return TimeMark(t)
            if kind == "O":
                return OdomLine(t, *_odom_fields(payload))
            cid, sep, data = payload.partition("#")
            if not sep or len(data) > 16:
                raise ValueError("bad CAN frame")
            can_id = int(cid, 16)
            if not 0 <= can_id <= 0x7FF:
                raise ValueError("CAN id out of range")
            return Chunk(src, t, bytes.fromhex(data), can_id)
        except ValueError as exc:
            self._bad(str(exc))
            return None

    def _bad(self, why: str) -> None:
        self.bad_lines += 1
        if self.bad_lines <= CAPTURE_WARN_LINES:
            log.warning("%s:%d: malformed capture line skipped (%s)", self.path, self._lineno, why)
        elif self.bad_lines == CAPTURE_WARN_LINES + 1:
            log.warning("%s: more malformed lines; counting them silently (bad_lines)", self.path)

    def _check(self, item: Item) -> None:
        """Count (and name the first few of) times that jump; the items are replayed as they
        are (the live gateway saw them so). Sources beyond the gateway's decoder table are
        the gateway's to count and say (``sources_evicted``, ``sources_dropped``)."""
        last, self._last_t = self._last_t, item.t
        if last is not None and not last - CAPTURE_BACK_S <= item.t <= last + CAPTURE_LEAP_S:
            self.time_jumps += 1
            if self.time_jumps <= CAPTURE_WARN_LINES:
                log.warning("%s:%d: capture time jumps from %s to %s", self.path, self._lineno,
                            format_time(last), format_time(item.t))
            elif self.time_jumps == CAPTURE_WARN_LINES + 1:
                log.warning("%s: more capture times jump; counting them silently (time_jumps)", self.path)

    def _next(self) -> Item | None:
        """The next item in the file, None at its end."""
        while True:
            if self._first is not None:
                line, self._first = self._first, None
            else:
                line = self._fh.readline(CAPTURE_MAX_LINE)
                self._lineno += 1
            if not line:
                return None
            if len(line) >= CAPTURE_MAX_LINE and not line.endswith("\n"):
                self._bad(f"longer than {CAPTURE_MAX_LINE} characters")
                while line and not line.endswith("\n"):  # skip the rest of the overlong line
                    line = self._fh.readline(CAPTURE_MAX_LINE)
                continue
            c = self.parse_line(line)
            if c is not None:
                self._check(c)
                return c

    def _read(self, timeout: float) -> list[Item]:
        out: list[Item] = []
        limit = 1 if self.realtime else self._batch
        while len(out) < limit:
            c = self._next()
            if c is None:
                if out:
                    return out
                raise TransportEOF(self.path)
            if self.realtime:
                now = self.clock.monotonic()
                if self._t0 is None:
                    self._t0 = (c.t, now)
                delay = (c.t - self._t0[0]) - (now - self._t0[1])
                if delay > 0:
                    self.clock.sleep(min(delay, 10.0))
            out.append(c)
        return out

    def _close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            fh.close()
