"""Several beacons at once: one grouper and one estimator per beacon, in bounded memory.

:class:`BeaconTracker` keys everything by a beacon identity (a string: an ESPresense
device id such as ``iBeacon:e2c5...-1-2``, or ``b3`` for beacon index 3 of our own
protocol's reports). Each beacon gets, when its first reading arrives,

* its own grouper, built by the caller's ``make_grouper(beacon)``: the
  :class:`~pfdoa.gateway.reassembly.WindowGrouper` for readings without a beacon sequence
  (ESPresense), the :class:`~pfdoa.gateway.reassembly.SeqReassembler` for our frames;
* its own localizer (estimator + record building), built by ``make_localizer(beacon, writer)``,
  e.g. :func:`localizer_factory` over :func:`pfdoa.gateway.setup.build_estimator` with a
  per-beacon seed (:func:`beacon_seed`).

Every record leaves through ``on_record(beacon, record)``; the beacon identity travels
beside the record (proposed output field: ``beacon``).

Memory is bounded: at most ``max_beacons`` beacons are tracked. A reading from a new
beacon beyond that evicts the least recently heard one (``evicted``, counted); a beacon
silent for ``idle_timeout_s`` is let go (``timed_out``). Either way its open sets are
flushed through its estimator first (no estimate that could be made is lost) and
``on_gone(beacon, reason)`` is called. Beacon ids longer than ``max_id_len`` characters
and readings from anchors not in the site are counted and dropped before they could
create a beacon. Per tracked beacon the cost is one grouper (bounded, see
:mod:`pfdoa.gateway.reassembly`) and one estimator (preallocated arrays).

The site file's optional table (parsed by :func:`beacons_config`)::

    [beacons]
    max_beacons = 32        # tracked at once; beyond, the least recently heard is evicted
    idle_timeout_s = 60.0   # a beacon silent this long is let go
"""

from __future__ import annotations

import logging
import math
import zlib
from collections import OrderedDict
from dataclasses import dataclass, fields
from typing import Any, Callable, Iterable, Protocol

from pfdoa.errors import ConfigError
from pfdoa.gateway.reassembly import AnchorSet, Reading
from pfdoa.output import Record

log = logging.getLogger(__name__)

MAX_ID_LEN = 128


class Grouper(Protocol):
    """What :mod:`pfdoa.gateway.reassembly`'s groupers have in common."""

    open_sets: int

    def push(self, r: Reading) -> list[AnchorSet]: ...

    def poll(self, now: float) -> list[AnchorSet]: ...

    def flush(self) -> list[AnchorSet]: ...


class SetHandler(Protocol):
    """Anchor sets in; records out through the ``writer`` it was made with
    (:class:`pfdoa.gateway.localizer.Localizer` is one: it may hold a set back until its
    odometry is there, so a record is not the return value of ``handle``)."""

    def handle(self, s: AnchorSet) -> None: ...


class RecordWriter(Protocol):
    def write(self, rec: Record) -> None: ...


@dataclass(frozen=True)
class BeaconsConfig:
    max_beacons: int = 32
    idle_timeout_s: float = 60.0


_RANGES = {"max_beacons": (1, 100_000), "idle_timeout_s": (0.1, 86400.0)}


def beacons_config(sections: dict[str, Any], source: str = "<site>") -> BeaconsConfig:
    """Validate the optional ``[beacons]`` table (missing -> defaults); ConfigError naming the key."""
    table = sections.get("beacons")
    if table is None:
        return BeaconsConfig()
    if not isinstance(table, dict):
        raise ConfigError(source, "beacons", "must be a table")
    defaults = {f.name: f.default for f in fields(BeaconsConfig)}
    values: dict[str, Any] = {}
    for key, v in table.items():
        where = f"beacons.{key}"
        if key not in defaults:
            raise ConfigError(source, where, f"unknown key (known: {', '.join(defaults)})")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(source, where, f"must be a number, got {v!r}")
        if isinstance(defaults[key], int) and not isinstance(v, int):
            raise ConfigError(source, where, f"must be an integer, got {v!r}")
        if not math.isfinite(float(v)):
            raise ConfigError(source, where, f"must be a finite number, got {v!r}")
        lo, hi = _RANGES[key]
        if not lo <= v <= hi:
            raise ConfigError(source, where, f"must be in [{lo}, {hi}], got {v}")
        values[key] = type(defaults[key])(v)
    return BeaconsConfig(**values)


def beacon_seed(seed: int | None, beacon: str) -> int | None:
    """A per-beacon estimator seed: reproducible, and different beacons differ."""
    if seed is None:
        return None
    return (int(seed) * 1_000_003 + zlib.crc32(beacon.encode("utf-8"))) & 0xFFFFFFFF


def localizer_factory(site, make_estimator: Callable[[str], Any],
                      health=None) -> Callable[[str, RecordWriter], SetHandler]:
    """``make_localizer`` for :class:`BeaconTracker`: a pipeline Localizer per beacon,
    writing its records to the tracker."""
    from pfdoa.gateway.localizer import Localizer

    return lambda beacon, writer: Localizer(site, make_estimator(beacon), writer=writer, health=health)


@dataclass(slots=True)
class BeaconReading:
    """A reading that names its beacon (ESPresense input; our frames once they carry one)."""

    beacon: str
    reading: Reading


@dataclass
class BeaconCounters:
    readings: int = 0
    created: int = 0  # beacons that started being tracked (again)
    evicted: int = 0  # let go because max_beacons were tracked and a new one came
    timed_out: int = 0  # let go after idle_timeout_s of silence
    bad_id: int = 0  # empty, non-text or longer than MAX_ID_LEN
    unknown_anchor: int = 0  # readings from anchors not in the site (no beacon created)
    sets: int = 0
    records: int = 0


class _Beacon:
    __slots__ = ("id", "grouper", "localizer", "last_t", "readings", "records")

    def __init__(self, beacon: str, grouper: Grouper, t: float) -> None:
        self.id = beacon
        self.grouper = grouper
        self.localizer: SetHandler | None = None  # made with a writer that knows this beacon
        self.last_t = t
        self.readings = 0
        self.records = 0


class _ToTracker:
    """The writer a beacon's localizer gets: its records go to the tracker, named."""

    __slots__ = ("tracker", "beacon")

    def __init__(self, tracker: "BeaconTracker", beacon: _Beacon) -> None:
        self.tracker, self.beacon = tracker, beacon

    def write(self, rec: Record) -> None:
        self.tracker._record(self.beacon, rec)


class BeaconTracker:
    """Track several beacons (see the module doc)."""

    def __init__(self, anchor_ids: Iterable[int], make_grouper: Callable[[str], Grouper],
                 make_localizer: Callable[[str, RecordWriter], SetHandler], cfg: BeaconsConfig = BeaconsConfig(),
                 on_record: Callable[[str, Record], None] | None = None,
                 on_gone: Callable[[str, str], None] | None = None) -> None:
        self.anchor_ids = frozenset(anchor_ids)
        self.make_grouper = make_grouper
        self.make_localizer = make_localizer
        self.cfg = cfg
        self.on_record = on_record
        self.on_gone = on_gone
        self.counters = BeaconCounters()
        self._beacons: OrderedDict[str, _Beacon] = OrderedDict()  # least recently heard first

    def __len__(self) -> int:
        return len(self._beacons)

    def __contains__(self, beacon: str) -> bool:
        return beacon in self._beacons

    @property
    def beacons(self) -> tuple[str, ...]:
        return tuple(self._beacons)

    def grouper(self, beacon: str) -> Grouper | None:
        b = self._beacons.get(beacon)
        return b.grouper if b is not None else None

    def push(self, beacon: str, r: Reading) -> None:
        c = self.counters
        c.readings += 1
        b = self._beacons.get(beacon)
        if b is None:
            if not isinstance(beacon, str) or not beacon or len(beacon) > MAX_ID_LEN:
                c.bad_id += 1
                return
            if r.anchor_id not in self.anchor_ids:
                c.unknown_anchor += 1
                return
            if len(self._beacons) >= self.cfg.max_beacons:
                self._let_go(next(iter(self._beacons)), "evicted")
            b = self._beacons[beacon] = _Beacon(beacon, self.make_grouper(beacon), r.t)
            b.localizer = self.make_localizer(beacon, _ToTracker(self, b))
            c.created += 1
            log.info("tracking beacon %s (%d tracked)", beacon, len(self._beacons))
        else:
            self._beacons.move_to_end(beacon)
            if r.t > b.last_t:
                b.last_t = r.t
        b.readings += 1
        for s in b.grouper.push(r):
            self._handle(b, s)

    def push_reading(self, br: BeaconReading) -> None:
        self.push(br.beacon, br.reading)

    def poll(self, now: float) -> None:
        """Time passes: idle beacons are let go, due sets released (groupers' timers)."""
        limit = now - self.cfg.idle_timeout_s
        while self._beacons:
            b = next(iter(self._beacons.values()))
            if b.last_t > limit:
                break
            self._let_go(b.id, "timed_out")
        for b in self._beacons.values():
            if b.grouper.open_sets:
                for s in b.grouper.poll(now):
                    self._handle(b, s)

    def flush(self) -> None:
        """End of input: every open set of every beacon goes through its estimator."""
        for b in self._beacons.values():
            for s in b.grouper.flush():
                self._handle(b, s)

    def _handle(self, b: _Beacon, s: AnchorSet) -> None:
        self.counters.sets += 1
        b.localizer.handle(s)

    def _record(self, b: _Beacon, rec: Record) -> None:
        b.records += 1
        self.counters.records += 1
        if self.on_record is not None:
            self.on_record(b.id, rec)

    def _let_go(self, beacon: str, reason: str) -> None:
        b = self._beacons[beacon]
        for s in b.grouper.flush():
            self._handle(b, s)
        del self._beacons[beacon]
        setattr(self.counters, reason, getattr(self.counters, reason) + 1)
        log.info("beacon %s %s after %d readings", beacon, reason.replace("_", " "), b.readings)
        if self.on_gone is not None:
            self.on_gone(beacon, reason)

    def summary(self) -> dict:
        """Counters and the tracked beacons (at most max_beacons entries)."""
        out: dict[str, Any] = dict(self.counters.__dict__)
        out["tracked"] = len(self._beacons)
        out["beacons"] = {b.id: {"readings": b.readings, "records": b.records, "last_t": b.last_t,
                                 "open_sets": b.grouper.open_sets} for b in self._beacons.values()}
        return out
