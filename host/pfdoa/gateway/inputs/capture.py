"""``capture:FILE``: capture files, the gateway's record of every input it processed, replayed.

:class:`CaptureWriter` writes one (``pfdoa gateway --capture``), :class:`CaptureReader`
replays one (``capture:FILE``, ``--replay-capture FILE``; ``-`` is standard input, so a timed
stream can be piped into the gateway). A replay runs on the capture's recorded times: it
cannot be mixed with live inputs. With ``realtime`` (``--realtime``) items are paced by
their recorded times on the injected clock.

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

import logging
import os
import re
import stat
import sys
from typing import IO

import numpy as np

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import (
    READ_MAX,
    Chunk,
    Item,
    OdomLine,
    TimeMark,
    Transport,
    TransportEOF,
    TransportFatal,
    format_time,
)

log = logging.getLogger(__name__)

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

    def __init__(self, path: str, realtime: bool = False, name: str | None = None, clock: Clock | None = None,
                 where: str | None = None) -> None:
        super().__init__(clock)
        self.path = path
        self.where = where or f"--replay-capture {path}"
        self.reads_stdin = path == "-"
        self.files = () if path == "-" else (path,)
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

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "CaptureReader":
        if not spec.arg:
            raise InputError(f"{spec.where()}: expected capture:FILE ('-': standard input)")
        return cls(spec.arg, realtime=ctx.realtime, clock=ctx.clock,
                   where=None if spec.option == "--replay-capture" else spec.where())

    def counters(self) -> dict:
        """For the final counters: what the file held that was not as it should be."""
        return {"bad_lines": self.bad_lines, "time_jumps": self.time_jumps}

    def _open(self) -> None:
        try:
            if self.path == "-":
                if sys.stdin is None:  # started with standard input closed (`<&-`)
                    raise TransportFatal(f"{self.where}: standard input is closed")
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
        fh = self._fh
        assert fh is not None  # open
        while True:
            if self._first is not None:
                line, self._first = self._first, None
            else:
                line = fh.readline(CAPTURE_MAX_LINE)
                self._lineno += 1
            if not line:
                return None
            if len(line) >= CAPTURE_MAX_LINE and not line.endswith("\n"):
                self._bad(f"longer than {CAPTURE_MAX_LINE} characters")
                while line and not line.endswith("\n"):  # skip the rest of the overlong line
                    line = fh.readline(CAPTURE_MAX_LINE)
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


def capture_chunks(path: str, bad_lines: list[int] | None = None):
    """The chunks of a capture file, in order (its odometry and timer lines left out);
    ``bad_lines[0]`` gets the malformed lines added. InputError when it cannot be read."""
    reader = CaptureReader(path)
    reader.open()
    try:
        while True:
            try:
                items = reader.read(0.0)
            except TransportEOF:
                return
            for item in items:
                if isinstance(item, Chunk):
                    yield item
    finally:
        reader.close()
        if bad_lines is not None:
            bad_lines[0] += reader.bad_lines
