"""Odometry sources: increments ``t,dx,dy,dtheta`` for the localizer's odometry buffer.

* :class:`OdometryReader` - live (``pfdoa gateway --odom PATH``): text lines from a FIFO, a
  pipe or a regular file that is followed as it grows (like ``tail -f``; a FIFO is reopened
  when its writer closes it). It is a transport read by the runner like the others: each
  line becomes an :class:`~pfdoa.gateway.transports.OdomLine` stamped with its arrival, in
  the one queue, so a capture records where it arrived among the chunks. Bad lines and
  lines longer than ``MAX_LINE`` are counted (once each) and skipped; no more than
  ``MAX_LINE`` bytes of an unfinished line are ever held.
* :func:`load_odometry` - a whole odometry CSV into an ended buffer (``pfdoa replay``, and
  ``pfdoa gateway --replay-capture`` with ``--odom``: a replay must not depend on how fast a
  file is read).

``t`` is on the gateway's host clock (Unix seconds live; the stream's seconds in a replay or
a simulation), the clock its sets are stamped with; odometry on another clock never
overlaps the sets and is not used (a warning says so).
"""

from __future__ import annotations

import logging
import math
import os
import select
import stat

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.transports import Item, OdomLine, Transport, TransportError
from pfdoa.odometry import OdometryBuffer

log = logging.getLogger(__name__)

MAX_LINE = 4096  # characters per odometry line; longer ones are skipped, counted
FOLLOW_POLL_S = 0.05  # a followed file is looked at again this often when it has not grown


def parse_odometry_line(line: str) -> tuple[float, float, float, float] | None:
    """``t,dx,dy,dtheta`` -> floats; None for blank, comment and header lines; ValueError if bad."""
    s = line.strip()
    if not s or s.startswith("#") or s.startswith("t,"):
        return None
    parts = s.split(",")
    if len(parts) < 4:
        raise ValueError("expected t,dx,dy,dtheta")
    vals = tuple(float(v) for v in parts[:4])
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("not finite")
    return vals  # type: ignore[return-value]


class OdometryReader(Transport):
    """Live odometry lines as :class:`OdomLine` items (see the module doc)."""

    finite = False
    # Its inbox is the pipe's or the file's (bounded by the kernel, or on disk): the runner's
    # reader waits for the loop rather than drop increments of a burst.
    buffered = True

    def __init__(self, path: str, clock: Clock | None = None) -> None:
        super().__init__(clock)
        self.path = path
        self.name = f"odom:{path}"
        try:
            mode = os.stat(path).st_mode
        except OSError as exc:
            raise InputError(f"--odom {path}: cannot read: {exc.strerror or exc}") from None
        if stat.S_ISDIR(mode):  # opening works, every read fails: it would be retried for ever
            raise InputError(f"--odom {path}: is a directory (a file, FIFO or pipe of t,dx,dy,dtheta lines)")
        self._follow = stat.S_ISREG(mode)
        self._fd = -1
        self._buf = b""
        self._skipping = False  # inside an overlong line, until its newline
        self.lines = 0
        self.bad_lines = 0

    def _open(self) -> None:
        # A FIFO's open blocks until a writer opens it: that is this reader thread's wait.
        try:
            self._fd = os.open(self.path, os.O_RDONLY)
        except OSError as exc:
            raise TransportError(f"--odom {self.path}: {exc.strerror or exc}") from None
        os.set_blocking(self._fd, False)
        self._buf = b""
        self._skipping = False

    def _read(self, timeout: float) -> list[Item]:
        if not self._follow and not select.select([self._fd], [], [], timeout)[0]:
            return []
        try:
            data = os.read(self._fd, 65536)
        except BlockingIOError:
            return []
        except OSError as exc:
            raise TransportError(f"--odom {self.path}: {exc.strerror or exc}") from None
        if not data:
            if self._follow:  # a regular file that has not grown: look again shortly
                _sleep_io(min(timeout, FOLLOW_POLL_S))
                return []
            raise TransportError(f"--odom {self.path}: writer closed")  # a FIFO: reopen for the next one
        out: list[Item] = []
        if self._skipping:  # inside a line already counted as too long: drop it up to its newline
            nl = data.find(b"\n")
            if nl < 0:
                return out
            data = data[nl + 1:]
            self._skipping = False
        lines = (self._buf + data).split(b"\n")
        self._buf = lines.pop()
        if len(self._buf) > MAX_LINE:  # a line still growing past the bound: counted once, skipped to its end
            self._buf = b""
            self._skipping = True
            self.bad_lines += 1
        for raw in lines:
            if len(raw) > MAX_LINE:
                self.bad_lines += 1
                continue
            try:
                vals = parse_odometry_line(raw.decode("utf-8", errors="replace"))
            except ValueError:
                self.bad_lines += 1
                continue
            if vals is not None:
                self.lines += 1
                out.append(OdomLine(self.clock.now(), *vals))
        return out

    def _close(self) -> None:
        fd, self._fd = self._fd, -1
        if fd >= 0:
            os.close(fd)


def _sleep_io(seconds: float) -> None:
    """Polling a growing file for input: a real wait for bytes, not a timer."""
    import time

    time.sleep(seconds)


def load_odometry(path: str) -> OdometryBuffer:
    """A whole odometry CSV (``pfdoa.trace.read_odometry``: InputError on a bad row) -> ended buffer."""
    from pfdoa.trace import read_odometry

    return odometry_buffer(read_odometry(path))


def odometry_buffer(od) -> OdometryBuffer:
    """An :class:`~pfdoa.trace.OdometryTrace` read whole -> an ended buffer."""
    buf = OdometryBuffer(max_len=max(len(od.t), 1))
    for t, dx, dy, dth in zip(od.t.tolist(), od.dx.tolist(), od.dy.tolist(), od.dtheta.tolist()):
        buf.add(t, dx, dy, dth)
    buf.end()
    return buf
