"""What every sink gets, and the base class of the sinks.

A sink consumes the gateway's (or replay's) output through three calls, all made from the
thread that runs the pipeline, in time order:

* ``reading(r)`` - every RSSI reading handed to the reassembler (the raw input);
* ``write(record)`` - every output record (:class:`pfdoa.output.Record`);
* ``health(snapshot)`` - every health period, a :class:`HealthSnapshot`.

A sink never blocks the pipeline for long: file sinks write and flush, the live view only
swaps its latest state. :class:`Fanout` is itself a sink that hands each call to several
sinks; a sink whose file fails (disk full, pipe closed) is logged, counted and dropped, and
the others go on. It also has the ``write``/``close`` of :class:`pfdoa.output.Writer`, so
the :class:`~pfdoa.gateway.pipeline.Localizer` can take it as its writer.

:class:`HealthSampler` takes the snapshot from the gateway's
:class:`~pfdoa.gateway.health.Health` and reassembler: rates since the previous snapshot,
errors by kind, per-anchor counts and levels. Its :meth:`HealthSnapshot.line` is the human
health line, character for character the one ``Health.line`` prints, so the JSON records
and the line carry the same numbers from the same snapshot.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Mapping

log = logging.getLogger(__name__)

# Per-anchor levels (the names of diagnostic_msgs/DiagnosticStatus levels).
OK, WARN, ERROR, STALE = "OK", "WARN", "ERROR", "STALE"
# An anchor that lost at least this share of its reports in one period is WARN.
WARN_PERIOD_LOSS = 0.10
# Counters of the reassembler that the health line lists among the errors.
GROUPER_ERRORS = ("duplicates", "late", "unknown_anchor", "evicted")


@dataclass(frozen=True)
class AnchorHealth:
    """One anchor in a snapshot: totals since the start and what changed in the period."""

    received: int
    lost: int
    duplicates: int
    late: int
    reboots: int
    stale: bool
    period_received: int
    period_lost: int
    period_reboots: int
    schema_mismatch: bool = False

    @property
    def loss(self) -> float | None:
        """Share of reports lost since the start (None before the first report)."""
        total = self.received + self.lost
        return self.lost / total if total else None

    @property
    def level(self) -> str:
        """STALE (silent), ERROR (other message definitions), WARN (rebooted or lossy in
        this period), else OK."""
        if self.stale:
            return STALE
        if self.schema_mismatch:
            return ERROR
        period_total = self.period_received + self.period_lost
        if self.period_reboots or (period_total and self.period_lost / period_total >= WARN_PERIOD_LOSS):
            return WARN
        return OK


@dataclass(frozen=True)
class HealthSnapshot:
    """The numbers of one health period (see :class:`HealthSampler`)."""

    t: float  # Unix time of the snapshot (s)
    period_s: float
    frames_per_s: float
    sets_per_s: float
    estimates_per_s: float
    errors: Mapping[str, int]  # by kind, totals since the start (as the health line)
    anchors: Mapping[int, AnchorHealth]  # site order
    open_sets: int
    frames: int
    sets: int
    estimates: int
    estimator_errors: int = 0
    reconnects: Mapping[str, int] = field(default_factory=dict)

    @property
    def stale(self) -> tuple[int, ...]:
        return tuple(a for a, h in self.anchors.items() if h.stale)

    def line(self) -> str:
        """The human health line (the format of ``Health.line``)."""
        parts = [
            f"health: {self.frames_per_s:.1f} frames/s {self.sets_per_s:.1f} sets/s "
            f"{self.estimates_per_s:.1f} est/s"
        ]
        parts.append("errors " + (" ".join(f"{k}={v}" for k, v in sorted(self.errors.items())) or "none"))
        loss = []
        for a, h in self.anchors.items():
            loss.append(f"a{a}={100.0 * h.loss:.1f}%" if h.loss is not None else f"a{a}=-")
        parts.append("loss " + " ".join(loss))
        stale = self.stale
        parts.append("stale " + (",".join(str(a) for a in stale) if stale else "none"))
        parts.append(f"open sets {self.open_sets}")
        if self.reconnects:
            parts.append("reconnects " + " ".join(f"{k}={v}" for k, v in sorted(self.reconnects.items())))
        return " | ".join(parts)

    def to_json(self) -> dict[str, Any]:
        """A JSON-serialisable dict (anchor ids as strings, loss in percent, NaN-free)."""
        anchors = {}
        for a, h in self.anchors.items():
            d = asdict(h)
            d["loss_pct"] = None if h.loss is None else round(100.0 * h.loss, 3)
            d["level"] = h.level
            anchors[str(a)] = d
        return {
            "t": round(self.t, 6),
            "period_s": round(self.period_s, 6),
            "frames_per_s": round(self.frames_per_s, 3),
            "sets_per_s": round(self.sets_per_s, 3),
            "estimates_per_s": round(self.estimates_per_s, 3),
            "errors": dict(sorted(self.errors.items())),
            "anchors": anchors,
            "stale": list(self.stale),
            "open_sets": self.open_sets,
            "frames": self.frames,
            "sets": self.sets,
            "estimates": self.estimates,
            "estimator_errors": self.estimator_errors,
            "reconnects": dict(sorted(self.reconnects.items())),
        }


class HealthSampler:
    """Snapshots of a gateway's :class:`~pfdoa.gateway.health.Health` and reassembler.

    ``sample(now, t)``: ``now`` is the clock the rates are measured on (the one given to
    :meth:`start`), ``t`` the Unix time stamped on the snapshot. Rates count from the
    previous sample (the first one from :meth:`start`, as ``Health.line`` does).
    """

    def __init__(self, health, grouper) -> None:
        self.health = health
        self.grouper = grouper
        self._prev: tuple[float, int, int, int] | None = None
        self._prev_anchor: dict[int, tuple[int, int, int]] = {}

    def start(self, now: float) -> None:
        self._prev = (now, self.health.frames, 0, self.health.estimates)

    def sample(self, now: float, t: float) -> HealthSnapshot:
        h, c = self.health, self.grouper.counters
        prev = self._prev or (now, h.frames, c.sets, h.estimates)
        dt = max(now - prev[0], 1e-9)
        self._prev = (now, h.frames, c.sets, h.estimates)
        errors: dict[str, int] = dict(h.errors)
        for k in GROUPER_ERRORS:
            if getattr(c, k):
                errors[k] = getattr(c, k)
        if h.queue_drops:
            errors["queue_drops"] = h.queue_drops
        anchors = {}
        for a, s in self.grouper.tracker.all_stats().items():
            r0, l0, b0 = self._prev_anchor.get(a, (0, 0, 0))
            anchors[a] = AnchorHealth(
                received=s.received, lost=s.lost, duplicates=s.duplicates, late=s.late, reboots=s.reboots,
                stale=bool(s.stale), period_received=s.received - r0, period_lost=max(0, s.lost - l0),
                period_reboots=s.reboots - b0, schema_mismatch=a in h.schema_mismatch,
            )
            self._prev_anchor[a] = (s.received, s.lost, s.reboots)
        return HealthSnapshot(
            t=float(t), period_s=now - prev[0],
            frames_per_s=(h.frames - prev[1]) / dt, sets_per_s=(c.sets - prev[2]) / dt,
            estimates_per_s=(h.estimates - prev[3]) / dt, errors=errors, anchors=anchors,
            open_sets=int(self.grouper.open_sets), frames=h.frames, sets=c.sets, estimates=h.estimates,
            estimator_errors=h.estimator_errors, reconnects=dict(h.reconnects),
        )


def record_cov(record) -> tuple[float, float, float] | None:
    """The record's position covariance ``[xx, xy, yy]`` (m^2), or None when it has none.

    Records carry ``cov`` once the estimators report it; before that (and for methods
    without one) the isotropic covariance implied by ``sigma`` (sqrt(var_x + var_y)) is
    used.
    """
    cov = getattr(record, "cov", None)
    if cov is not None:
        xx, xy, yy = (float(v) for v in cov)
        if all(math.isfinite(v) for v in (xx, xy, yy)):
            return xx, xy, yy
    sigma = getattr(record, "sigma", None)
    if sigma is not None and math.isfinite(float(sigma)):
        v = float(sigma) ** 2 / 2.0
        return v, 0.0, v
    return None


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

    def reading(self, r) -> None:
        """An RSSI reading as handed to the reassembler (:class:`~pfdoa.gateway.reassembly.Reading`)."""

    def write(self, record) -> None:
        """An output record."""

    def health(self, snapshot: HealthSnapshot) -> None:
        """A health period."""

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

    def _each(self, method: str, arg) -> None:
        for s in tuple(self.sinks):
            try:
                getattr(s, method)(arg)
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

    def reading(self, r) -> None:
        self._each("reading", r)

    def write(self, record) -> None:
        self._each("write", record)

    def health(self, snapshot: HealthSnapshot) -> None:
        self._each("health", snapshot)

    def flush(self) -> None:
        """(For :class:`~pfdoa.gateway.pipeline.Localizer`'s writer interface.)"""
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


def open_text_target(target: str, what: str):
    """``-`` is standard output; any other string a file created (truncated) for writing.

    Raises :class:`~pfdoa.errors.InputError` naming the option when it cannot be created.
    """
    import sys

    from pfdoa.errors import InputError

    if target == "-":
        return sys.stdout
    try:
        return open(target, "w", encoding="utf-8", newline="")
    except OSError as exc:
        raise InputError(f"{what} {target}: cannot write: {exc.strerror or exc}") from None

