"""What every sink gets, and the base class of the sinks.

A sink consumes the gateway's (or replay's) output through these calls, all made from the
thread that runs the pipeline, in the order the pipeline processed things:

* ``reading(r, beacon)`` - every RSSI reading handed to the reassembler (the raw input);
  ``beacon`` is the id of the beacon the reading names (an ESPresense device), None for
  readings of our frames (their beacon is the configured one);
* ``odometry(inc)`` - every odometry increment handed to the localizer
  (:class:`~pfdoa.gateway.transports.OdomLine`: its arrival time and the increment);
* ``timer(t)`` - the gateway's timers ran at ``t`` (set timeouts, staleness, the wait for
  odometry: what a capture's ``T`` lines say);
* ``write(record)`` - every output record (:class:`pfdoa.output.Record`);
* ``health(snapshot)`` - every health period, a
  :class:`~pfdoa.gateway.health.HealthSnapshot` (the numbers of the health line);
* ``beacon_gone(beacon, reason)`` - the gateway stopped tracking a beacon that its
  readings named (an ESPresense device): ``timed_out`` or ``evicted``;
* ``inputs_ended()`` - no more readings, odometry or timer marks: what follows are the
  estimates of the sets still open (a recording marks the point, :mod:`pfdoa.sinks.mcap`).

Readings, odometry and timer times in their order are what the estimates are a function
of: a recording of them (:mod:`pfdoa.sinks.mcap`) replays to the same estimates.

A sink never blocks the pipeline for long: file sinks write and flush, the live view only
swaps its latest state. :class:`Fanout` is itself a sink that hands each call to several
sinks; a sink whose file fails (disk full, pipe closed) is logged, counted and dropped, and
the others go on.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from typing import Iterable

from pfdoa.gateway.health import HealthSnapshot  # the health numbers' one place
from pfdoa.types import position_cov as record_cov  # noqa: F401  (the sinks' name for it)

log = logging.getLogger(__name__)


def record_heading(record) -> tuple[float, float] | None:
    """(heading rad, variance rad^2) when the record carries a heading, else None."""
    heading = getattr(record, "heading", None)
    if heading is None or not math.isfinite(float(heading)):
        return None
    var = getattr(record, "heading_var", None)
    var = float(var) if var is not None and math.isfinite(float(var)) and float(var) >= 0.0 else math.nan
    return float(heading), var


class Sink:
    """Base class: every call is optional; ``close`` runs ``_close`` once."""

    name = ""
    closed = False

    def reading(self, r, beacon: str | None = None) -> None:
        """An RSSI reading as handed to the reassembler (:class:`~pfdoa.readings.reassembly.Reading`),
        with the beacon id it names (None: not a named beacon's)."""

    def odometry(self, inc) -> None:
        """An odometry increment as handed to the localizer (:class:`~pfdoa.gateway.transports.OdomLine`)."""

    def timer(self, t: float) -> None:
        """The gateway's timers ran at ``t``."""

    def write(self, record) -> None:
        """An output record."""

    def health(self, snapshot: HealthSnapshot) -> None:
        """A health period."""

    def beacon_gone(self, beacon: str, reason: str) -> None:
        """The gateway let a beacon go (``timed_out``, ``evicted``)."""

    def inputs_ended(self) -> None:
        """The inputs ended; the estimates of the sets still open follow."""

    def counters(self) -> dict | None:
        """What the sink counts for the command's final counters (None: nothing)."""
        return None

    def health_counters(self) -> dict | None:
        """What the sink counts for every health snapshot (``outputs.<name>``; None: nothing)."""
        return None

    def health_outputs(self) -> dict:
        """Its health counters by its name (``HealthSnapshot.outputs``; the runner asks)."""
        c = self.health_counters()
        return {self.name or type(self).__name__: c} if c else {}

    def fatal(self):
        """An error that retrying cannot change and that should end the run (a
        :class:`~pfdoa.errors.PfdoaError`: the broker refused the credentials), else None.
        The gateway's runner asks between items."""
        return None

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close()

    def _close(self) -> None:
        pass

    def __enter__(self) -> "Sink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class WriterSink(Sink):
    """A :class:`pfdoa.output.Writer` (JSON lines / CSV) as a sink."""

    name = "output"

    def __init__(self, writer) -> None:
        self.writer = writer

    def write(self, record) -> None:
        self.writer.write(record)

    def _close(self) -> None:
        self.writer.close()


class Fanout(Sink):
    """Hands every call to each of ``sinks``; a sink that fails with OSError is dropped."""

    name = "fanout"

    def __init__(self, sinks: Iterable[Sink] = ()) -> None:
        self.sinks: list[Sink] = list(sinks)
        self.failed: Counter = Counter()  # sink name -> failures (each drops the sink)

    def add(self, sink: Sink) -> Sink:
        self.sinks.append(sink)
        return sink

    def _each(self, method: str, *args) -> None:
        for s in tuple(self.sinks):
            try:
                getattr(s, method)(*args)
            except OSError as exc:
                self._drop(s, exc)

    def _drop(self, s: Sink, exc: BaseException) -> None:
        log.error("%s: %s; no more output to it", s.name or type(s).__name__, exc)
        self.failed[s.name or type(s).__name__] += 1
        self.sinks.remove(s)
        try:
            s.close()
        except OSError:
            pass

    def reading(self, r, beacon: str | None = None) -> None:
        if beacon is None:
            self._each("reading", r)
        else:
            self._each("reading", r, beacon)

    def odometry(self, inc) -> None:
        self._each("odometry", inc)

    def timer(self, t: float) -> None:
        self._each("timer", t)

    def write(self, record) -> None:
        self._each("write", record)

    def health(self, snapshot: HealthSnapshot) -> None:
        self._each("health", snapshot)

    def beacon_gone(self, beacon: str, reason: str) -> None:
        self._each("beacon_gone", beacon, reason)

    def collect(self, method: str) -> dict:
        """``method()`` of each sink that has something to say (not None), by sink name."""
        out = {}
        for s in self.sinks:
            c = getattr(s, method)()
            if c is not None:
                out[s.name] = c
        return out

    def health_counters(self) -> dict:
        """Its sinks' health counters, by sink name."""
        return self.collect("health_counters")

    def health_outputs(self) -> dict:
        return self.health_counters()

    def inputs_ended(self) -> None:
        self._each("inputs_ended")

    def fatal(self):
        return next((e for e in (s.fatal() for s in self.sinks) if e is not None), None)

    def flush(self) -> None:
        for s in self.sinks:
            f = getattr(s, "flush", None)
            if f is not None:
                f()

    def _close(self) -> None:
        for s in tuple(self.sinks):
            try:
                s.close()
            except OSError as exc:
                log.error("%s: %s while closing", s.name or type(s).__name__, exc)
                self.failed[s.name or type(s).__name__] += 1

    def __len__(self) -> int:
        return len(self.sinks)


def open_text_target(target: str, what: str, existing: str = "replace"):
    """``-`` is standard output; any other string a file of JSON lines opened by
    :func:`pfdoa.outfiles.open_stream` (``existing="keep"``: appended to when it holds JSON
    lines). Raises :class:`~pfdoa.errors.OutputError` naming the option when it cannot be opened.
    """
    import sys

    from pfdoa.errors import InputError
    from pfdoa.outfiles import open_stream

    if target == "-":
        if sys.stdout is None:
            raise InputError(f"{what} -: standard output is closed")
        return sys.stdout
    return open_stream(target, what, existing=existing, same_kind=lambda first: first.startswith(b"{"))[0]
