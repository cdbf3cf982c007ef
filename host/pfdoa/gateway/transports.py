"""The inputs' small base class and what they deliver: where anchor bytes, CAN frames and
beacon readings come from, behind one interface.

Every input (python-can ``BusABC`` style) has ``open()``, ``read(timeout)`` returning a list
of items (:class:`Chunk`, and from capture files also :class:`OdomLine` and
:class:`TimeMark`; empty on timeout), an idempotent ``close()`` and is a context manager;
a subclass implements ``_open``, ``_read``, ``_close`` (and ``_send`` when it can reach the
anchors). ``read`` raises :class:`TransportEOF` when a finite source (standard input, a
capture file) is exhausted and :class:`TransportError` when a device fails (unplugged serial
adapter, CAN interface down); the runner's reader (:mod:`pfdoa.gateway.runner`) reopens
those with backoff. An input that cannot work at all (a malformed URL, a file that is not a
device) raises :class:`TransportFatal`, which is not retried.

The inputs themselves are one module each in :mod:`pfdoa.gateway.inputs` (serial ports,
CAN buses, standard input, capture files, MQTT, UDP), made from one spec syntax by its
registry (:func:`pfdoa.gateway.inputs.make_input`).

Chunks are stamped with the injected clock (:mod:`pfdoa.clock`) when they are read. After
each ``read``, ``caught_up_to`` says up to which time everything that had arrived has been
returned (None: more is waiting, e.g. a full read buffer): the runner's timers never run
ahead of it, so input that merely waits in a kernel buffer cannot time out a set. An input
that keeps counters (rejections, what a file held that was wrong) returns them from
``counters()``: they go into every health snapshot and the final counters (``inputs``).
"""

from __future__ import annotations

import errno
import logging
import os
import stat
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Union

import numpy as np

from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import PfdoaError

log = logging.getLogger(__name__)

MAX_DECODERS = 64  # byte-stream sources (ports, capture source names) decoded at once (pfdoa.gateway.decoding)
# A source's decoder may make room for a new source once nothing came from it for this long
# (chunk times; pfdoa.gateway.decoding.Gateway._make_room).
DECODER_IDLE_S = 30.0
READ_MAX = 4096  # bytes per read call; bounds every chunk


class TransportError(PfdoaError):
    """The device failed or vanished; the source may come back (reopen with backoff)."""


class TransportFatal(TransportError):
    """The source can never work as given (bad URL, not a device): not retried, exit 2."""

    exit_code = 2


class TransportAbsent(TransportError):
    """The device is not there at all (no such path, no such interface): one not yet seen
    is waited for (pfdoa.gateway.runner, ``--wait-for-device``); a one-shot command stops."""

    exit_code = 2

    def __init__(self, option: str, device: str, where: str | None = None) -> None:
        self.device = device
        super().__init__(f"{where or f'{option} {device}'}: not present")


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
    # How the user named this input, for messages ("--serial /dev/ttyACM0", "--input udp:5000").
    where: str = ""
    # What the commands check before anything opens (pfdoa.gateway.inputs):
    decoder_sources = 0  # byte-stream sources it feeds the gateway's decoder table (a serial port: 1)
    carries_frames = True  # our protocol's frames (the site's anchor ids must be wire ids)
    reads_stdin = False  # reads standard input (which can be read once)
    files: tuple[str, ...] = ()  # files it reads (no output may be one of them)

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

    def counters(self) -> dict:
        """What this input counts (rejections, what a file held that was wrong): for every
        health snapshot and the final counters; empty when there is nothing to say."""
        return {}

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


def open_error(option: str, device: str, exc: BaseException, local: bool, where: str | None = None) -> TransportError:
    """What opening a device failed with: for ever (exit 2), not there (waited for), or for
    now. ``where`` (default ``OPTION DEVICE``) names it as the user did."""
    said = where or f"{option} {device}"
    n = _errno(exc)
    if _not_a_terminal(exc):  # /dev/null, /dev/zero: a device, but never a serial port
        return TransportFatal(f"{said}: not a serial device ({exc})")
    if n in (errno.EACCES, errno.EPERM):
        return TransportFatal(f"{said}: permission denied (this user may not open it: for a serial "
                              "port, the dialout group)")
    if n == errno.EAFNOSUPPORT:
        return TransportFatal(f"{said}: this system's kernel does not support it ({exc})")
    if (local and n == errno.ENOENT) or n == errno.ENODEV:
        return TransportAbsent(option, device, where)
    return TransportError(f"{device}: {exc}")


def is_char_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False
