"""Several beacons at once: one grouper and one estimator per beacon, in bounded memory.

:class:`BeaconTracker` keys everything by a beacon identity (a string: an ESPresense
device id such as ``iBeacon:e2c5...-1-2``, or ``b3`` for beacon index 3 of our own
protocol's reports). Each beacon gets, when its first reading arrives,

* its own grouper, built by the caller's ``make_grouper(beacon)``: the
  :class:`~pfdoa.readings.reassembly.WindowGrouper` for readings without a beacon sequence
  (ESPresense), the :class:`~pfdoa.readings.reassembly.SeqReassembler` for our frames;
* its own localizer (estimator + record building), built by ``make_localizer(beacon, writer)``,
  e.g. :func:`pfdoa.gateway.setup.beacon_localizers` (a per-beacon seed, :func:`beacon_seed`).
  :func:`pfdoa.gateway.setup.build_named_tracker` builds the whole tracker of named
  beacons (ESPresense devices, a trace's beacon column) in one place.

Every record leaves through ``on_record(beacon, record)``; the beacon identity travels
beside the record (the output writes it in its ``beacon`` field).

Memory is bounded: at most ``max_beacons`` beacons are tracked, each costing at most
:data:`MAX_BEACON_BYTES` (one grouper, bounded by :mod:`pfdoa.readings.reassembly`, and one
estimator, preallocated arrays), and nothing is kept of a beacon once it is let go (its
counts join the ``retired`` totals). Its estimator is built when its first set leaves its
grouper (a passer-by heard once costs a grouper, not an estimator). A beacon is *new*
until a set of at least two anchors' readings has left its grouper. A reading from a
beacon not tracked, with ``max_beacons`` tracked, makes room:

1. the *new* beacon heard least often (of those, the least recently heard) is let go, its
   readings not estimated (counted: ``dropped_new``, ``dropped_readings``): a flood of ids
   heard once each (a busy street, a forged burst) never takes the place of a beacon that
   is being estimated, nor of a new one heard more often (a device whose first window is
   still open);
2. else the least recently heard beacon (``evicted``).

A beacon silent for ``idle_timeout_s`` is let go (``timed_out``). An evicted or timed-out
beacon's open sets are flushed through its estimator first (no estimate that could be
made is lost) and ``on_gone(beacon, reason)`` is called. Beacon ids longer than
``max_id_len`` characters and readings from anchors not in the site are counted and
dropped before they could create a beacon; so are readings whose message time the
gateway found implausible (:meth:`BeaconTracker.refuse`, counted per beacon:
:mod:`pfdoa.gateway.msgtime`).

Beacons added with :meth:`BeaconTracker.add` before their first reading are **pinned**:
never evicted nor timed out (our own frames' beacons: at most ``BEACON_SLOTS`` of them,
one per filter table entry of the anchors).

:class:`FrameBeacons` routes our frames' reports by their beacon index (protocol/SPEC.md
1.1) to the tracker: a configured entry by its name, grouped by sequence (``PFDOA`` kind)
or by time window (kinds without a sequence number, whose reports carry ``NO_SEQ``).

The site file's optional ``beacons`` (parsed by :func:`beacons_config`) is either a table
of limits, for ESPresense input::

    [beacons]
    max_beacons = 32        # tracked at once; beyond, the least recently heard is evicted
    idle_timeout_s = 60.0   # a beacon silent this long is let go

or an array of the beacons the anchors listen to, one per filter table entry (the same
table ``pfdoa anchors filters`` / ``apply`` sets in the anchors)::

    [[beacons]]
    name = "robot1"         # the output's ``beacon`` field (default "b<index>")
    kind = "pfdoa"          # our beacon (protocol/SPEC.md 6), with a sequence number
    id = 0                  # its beacon id byte (default 0)

    [[beacons]]
    name = "tag7"
    kind = "ibeacon"        # also eddystone_uid, altbeacon, mac48, mac64 (no sequence number)
    uuid = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"
    major = 1
    minor = 2
    period_ms = 100         # the anchor's event window for it (default 100)
    window_s = 0.1          # the gateway's grouping window (default period_ms / 1000)

    [[beacons]]
    name = "robot2"
    kind = "pfdoa_auth"     # our authenticated rolling beacon (protocol/SPEC.md 9)
    key_file = "robot2.key" # its secret key, a file of its own (mode 0600; relative to this file)

Optional in every entry: ``index`` (the filter table entry, default its position in the
list), ``odometry = true`` on the one beacon the robot's odometry belongs to (default:
the first entry) and ``target_z`` (m: this beacon's height, in place of ``[site] target_z``;
:func:`beacon_site`). A ``pfdoa_auth`` beacon's reports are verified again here
(:mod:`pfdoa.gateway.auth`); its key goes to the anchors in their filter table
(``pfdoa anchors filters``), never into a log, the health or an output.

One entry may be ``kind = "anchors"``: the anchors hear each other (their peer readings,
protocol/SPEC.md 3.5), for the gateway's live calibration (:mod:`pfdoa.gateway.peers`:
``period_ms``, ``refit_s``, ``apply``). It is an entry of the filter table (default index
the last), not a beacon: no estimator is made for it. Alone it stands beside the
first-boot table (our beacon in entry 0).
"""

from __future__ import annotations

import logging
import math
import zlib
from collections import Counter, OrderedDict
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Protocol

from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.gateway.auth import AuthCounters, AuthGuard, load_key_file
from pfdoa.output import Record
from pfdoa.protocol import defs
from pfdoa.protocol.filters import BeaconFilter, default_table, table_hash
from pfdoa.readings.reassembly import (
    MAX_UNKNOWN_IDS,
    AnchorSet,
    AnchorStats,
    AnchorTracker,
    GroupCounters,
    Reading,
    WindowGrouper,
)
from pfdoa.site import Site
from pfdoa.trace import DEFAULT_WINDOW_S, MAX_BEACON_ID

log = logging.getLogger(__name__)

MAX_ID_LEN = MAX_BEACON_ID  # one bound for the tracker and the trace files
# What one tracked beacon may hold: its grouper and its estimator, with pf-doa (its default
# particles; ~0.7 MiB on a 16-anchor site) and the other particle or geometric methods. The
# grid methods (drssi, markov) hold a grid of the site per beacon: more on a large site
# (docs/fleet.md, "Bounds"). tests/unit/test_beacons.py measures them.
MAX_BEACON_BYTES = 1 << 20
MAX_NAMED_REFUSED = 256  # beacons not tracked whose refused readings are counted by id


class Grouper(Protocol):
    """What :mod:`pfdoa.readings.reassembly`'s groupers have in common."""

    counters: GroupCounters
    tracker: AnchorTracker

    @property
    def open_sets(self) -> int: ...

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
class BeaconSpec:
    """One configured beacon of our anchors: its filter table entry and how it is grouped."""

    name: str
    index: int  # the anchors' filter table entry (the reports' beacon index)
    filter: BeaconFilter
    window_s: float | None = None  # grouping window (kinds without a sequence number)
    odometry: bool = False  # the robot's odometry belongs to this beacon
    target_z: float | None = None  # its height (m), in place of [site] target_z

    @property
    def has_seq(self) -> bool:
        return self.filter.has_seq


PEER_PERIOD_MS = 1000  # the anchors' own advertisement period by default (ms)
DEFAULT_REFIT_S = 60.0  # the gateway's live refit period by default (s)


@dataclass(frozen=True)
class PeersConfig:
    """The ``[[beacons]]`` entry of kind ``anchors`` (:mod:`pfdoa.gateway.peers`)."""

    index: int  # the anchors' filter table entry
    period_ms: int = PEER_PERIOD_MS
    refit_s: float = DEFAULT_REFIT_S
    apply: bool = True
    name: str = "anchors"


@dataclass(frozen=True)
class BeaconsConfig:
    max_beacons: int = 32
    idle_timeout_s: float = 60.0
    entries: tuple[BeaconSpec, ...] = ()  # the [[beacons]] array's beacons; () = not configured
    peers: PeersConfig | None = None  # its entry of kind "anchors" (the anchors hear each other)

    def table(self) -> tuple[BeaconFilter, ...] | None:
        """The filter table the entries make (unused entries NONE; with the anchors' entry alone,
        the first-boot table beside it); None when not configured."""
        if not self.entries and self.peers is None:
            return None
        table = list(default_table()) if not self.entries else [BeaconFilter.none()] * defs.BEACON_SLOTS
        for e in self.entries:
            table[e.index] = e.filter
        if self.peers is not None:
            table[self.peers.index] = BeaconFilter.anchors(self.peers.period_ms)
        return tuple(table)

    @property
    def filter_hash(self) -> int | None:
        """The ``filter_hash`` anchors set to this table report (None: not configured)."""
        t = self.table()
        return None if t is None else table_hash(t)

    def primary(self) -> BeaconSpec | None:
        """The beacon the odometry belongs to (the one marked, else the first entry)."""
        if not self.entries:
            return None
        return next((e for e in self.entries if e.odometry), self.entries[0])

    def primary_name(self) -> str:
        """The primary beacon's name in the records (``b<index>`` when none is configured)."""
        p = self.primary()
        return p.name if p is not None else f"b{defs.FILTER_DEFAULT_INDEX}"


KINDS = {"pfdoa": defs.FILTER_PFDOA, "ibeacon": defs.FILTER_IBEACON, "eddystone_uid": defs.FILTER_EDDYSTONE_UID,
         "altbeacon": defs.FILTER_ALTBEACON, "mac48": defs.FILTER_MAC48, "mac64": defs.FILTER_MAC64,
         "pfdoa_auth": defs.FILTER_PFDOA_AUTH}
# A [[beacons]] entry's keys, types, ranges and defaults, by kind: pfdoa.schema.
DEFAULT_PERIOD_MS = schema.row("beacons", "period_ms", array=True, kind="ibeacon").default
MAX_NAME_LEN = 64


def _value(source: str, where: str, kind: str, e: dict[str, Any], key: str, default: Any = None) -> Any:
    """``e[key]`` checked by the schema's row for a ``kind`` entry; absent: the row's default
    (else ``default``)."""
    spec = schema.row("beacons", key, array=True, kind=kind)
    if key not in e:
        return spec.default if spec.default is not None else default
    return schema.check_value(source, f"{where}.{key}", spec, e[key])


def _beacon_filter(source: str, where: str, kind: str, e: dict[str, Any]) -> BeaconFilter:
    """The filter an entry describes (ConfigError naming the key that is wrong)."""
    if kind == "pfdoa":
        return BeaconFilter.pfdoa(_value(source, where, kind, e, "id"))
    if kind == "pfdoa_auth":
        if "key_file" not in e:
            raise ConfigError(source, f"{where}.key_file", "missing key (a pfdoa_auth beacon's key is in a file "
                              "of its own: pfdoa anchors keygen FILE writes one)")
        path = Path(_value(source, where, kind, e, "key_file"))
        if not path.is_absolute() and not source.startswith("<"):
            path = Path(source).parent / path
        return BeaconFilter.pfdoa_auth(load_key_file(path, source, f"{where}.key_file"))
    needs = [k.key for k in schema.keys_of("beacons", array=True, kind=kind) if k.required and k.kinds]
    for key in needs:
        if key not in e:
            raise ConfigError(source, f"{where}.{key}", f"missing key (a {kind} beacon needs {', '.join(needs)})")
    period = _value(source, where, kind, e, "period_ms")
    key = needs[0]
    try:
        if kind == "ibeacon":
            major = _value(source, where, kind, e, "major")
            minor = _value(source, where, kind, e, "minor")
            return BeaconFilter.ibeacon(_value(source, where, kind, e, "uuid"), major, minor, period)
        if kind == "eddystone_uid":
            ns = _value(source, where, kind, e, "namespace")
            inst = _value(source, where, kind, e, "instance")
            return BeaconFilter.eddystone_uid(ns, inst, period)
        if kind == "altbeacon":
            return BeaconFilter.altbeacon(_value(source, where, kind, e, "beacon_id"), period)
        address = _value(source, where, kind, e, "address")
        return (BeaconFilter.mac48 if kind == "mac48" else BeaconFilter.mac64)(address, period)
    except ValueError as exc:  # bad hex or the wrong length
        raise ConfigError(source, f"{where}.{key}", str(exc)) from None


def _peers_entry(source: str, where: str, e: dict[str, Any]) -> PeersConfig:
    """The entry of kind "anchors" (ConfigError naming the key)."""
    schema.check_keys(source, where, e, schema.names_of("beacons", array=True, kind="anchors"),
                      "for the anchors' entry")
    kind = "anchors"
    index = _value(source, where, kind, e, "index", defs.BEACON_SLOTS - 1)
    return PeersConfig(index, _value(source, where, kind, e, "period_ms"), _value(source, where, kind, e, "refit_s"),
                       _value(source, where, kind, e, "apply"), _value(source, where, kind, e, "name", "anchors"))


def _beacon_entries(entries: list, source: str) -> tuple[tuple[BeaconSpec, ...], PeersConfig | None]:
    """The ``[[beacons]]`` array: names, kinds, filters, table indices (ConfigError naming
    the key); the beacons, and the anchors' entry (kind "anchors") if there is one."""
    if not entries:
        raise ConfigError(source, "beacons", "an empty array: list at least one [[beacons]] entry, or leave it out")
    if len(entries) > defs.BEACON_SLOTS:
        raise ConfigError(source, "beacons", f"at most {defs.BEACON_SLOTS} beacons (the anchors' filter table), "
                          f"got {len(entries)}")
    out: list[BeaconSpec] = []
    peers: PeersConfig | None = None
    for i, e in enumerate(entries):
        where = f"beacons[{i}]"
        if not isinstance(e, dict):
            raise ConfigError(source, where, "must be a table ([[beacons]])")
        kind = e.get("kind")
        if kind is None:
            raise ConfigError(source, f"{where}.kind", f"missing key (one of {', '.join(KINDS)}, anchors)")
        if kind == "anchors":
            if peers is not None:
                raise ConfigError(source, where, "only one entry of kind \"anchors\"")
            peers = _peers_entry(source, where, e)
            continue
        schema.check_value(source, f"{where}.kind", schema.row("beacons", "kind", array=True), kind)
        schema.check_keys(source, where, e, schema.names_of("beacons", array=True, kind=kind), f"for a {kind} beacon")
        index = _value(source, where, kind, e, "index", len(out))  # default: its place among the beacons
        name = _value(source, where, kind, e, "name", f"b{index}")
        if not name or len(name) > MAX_NAME_LEN or not name.isprintable():
            raise ConfigError(source, f"{where}.name", f"1 to {MAX_NAME_LEN} printable characters, got {name!r}")
        odometry = _value(source, where, kind, e, "odometry")
        flt = _beacon_filter(source, where, kind, e)
        target_z = _value(source, where, kind, e, "target_z")
        window = None if flt.has_seq else _value(source, where, kind, e, "window_s", flt.period_ms / 1000.0)
        for prev in out:
            if prev.index == index:
                raise ConfigError(source, f"{where}.index", f"entry {index} is also {prev.name!r}'s")
            if prev.name == name:
                raise ConfigError(source, f"{where}.name", f"duplicate beacon name {name!r}")
            if (prev.filter.kind, prev.filter.match) == (flt.kind, flt.match):
                raise ConfigError(source, where, f"the same beacon as {prev.name!r}")
            if prev.odometry and odometry:
                raise ConfigError(source, f"{where}.odometry", f"only one beacon carries the odometry "
                                  f"({prev.name!r} already does)")
        out.append(BeaconSpec(name, index, flt, window, odometry, target_z))
    if peers is not None and any(b.index == peers.index for b in out):
        raise ConfigError(source, "beacons", f"the anchors' entry and a beacon share filter table entry {peers.index}")
    if peers is not None and not out and peers.index == defs.FILTER_DEFAULT_INDEX:
        raise ConfigError(source, "beacons", f"the anchors' entry alone cannot take entry {peers.index}: the "
                          "first-boot table's beacon is there")
    return tuple(out), peers


def beacons_config(sections: dict[str, Any], source: str = "<site>") -> BeaconsConfig:
    """Validate the optional ``beacons`` table or array (missing -> defaults); ConfigError naming the key."""
    table = sections.get("beacons")
    if table is None:
        return BeaconsConfig()
    if isinstance(table, list):
        entries, peers = _beacon_entries(table, source)
        return BeaconsConfig(entries=entries, peers=peers)
    if not isinstance(table, dict):
        raise ConfigError(source, "beacons", "must be a table ([beacons]) or an array of tables ([[beacons]])")
    return BeaconsConfig(**schema.check_table(source, "beacons", table))


def beacon_site(site: Site, beacons: BeaconsConfig, beacon: str) -> Site:
    """``site`` as the estimator of ``beacon`` sees it: with the ``target_z`` of its entry in
    ``beacons`` (the site's validated ``[[beacons]]``), when it has one (a tag worn lower than
    the robot's beacon). Takes the parsed table: parsing again would read key files again."""
    for e in beacons.entries:
        if e.name == beacon and e.target_z is not None:
            return replace(site, target_z=e.target_z)
    return site


def _merge_stats(into: AnchorStats, s: AnchorStats) -> None:
    """One anchor's counts from another beacon's tracker: the counts add; a reboot or a
    stale spell is seen by every beacon's tracker, so the most any saw, not the sum."""
    into.received += s.received
    into.lost += s.lost
    into.duplicates += s.duplicates
    into.late += s.late
    into.reordered += s.reordered
    into.reboots = max(into.reboots, s.reboots)
    into.stale_events = max(into.stale_events, s.stale_events)
    if s.last_rx is not None and (into.last_rx is None or s.last_rx > into.last_rx):
        into.last_rx = s.last_rx


def beacon_seed(seed: int | None, beacon: str) -> int | None:
    """A per-beacon estimator seed: reproducible, and different beacons differ."""
    if seed is None:
        return None
    return (int(seed) * 1_000_003 + zlib.crc32(beacon.encode("utf-8"))) & 0xFFFFFFFF


@dataclass(slots=True)
class BeaconReading:
    """A reading that names its beacon (ESPresense input; our frames once they carry one)."""

    beacon: str
    reading: Reading

    @property
    def t(self) -> float:
        return self.reading.t


@dataclass(slots=True)
class BeaconBatch:
    """Beacon readings read at once from one input: one item of the gateway's reader queue
    (like a chunk of bytes), so that the queue's bound counts reads, not messages."""

    readings: list[BeaconReading]

    @property
    def t(self) -> float:
        """The latest reading's time (the readings are in arrival order)."""
        return max(br.reading.t for br in self.readings) if self.readings else -math.inf


@dataclass
class BeaconCounters:
    readings: int = 0
    created: int = 0  # beacons that started being tracked (again)
    evicted: int = 0  # let go because max_beacons were tracked and a new one came
    timed_out: int = 0  # let go after idle_timeout_s of silence
    bad_id: int = 0  # empty, non-text or longer than MAX_ID_LEN
    refused: int = 0  # a new beacon while max_beacons pinned ones are tracked
    unknown_anchor: int = 0  # readings from anchors not in the site (no beacon created)
    dropped_new: int = 0  # beacons let go before their first set, to make room (not estimated)
    dropped_readings: int = 0  # ... their readings
    time_ahead: int = 0  # readings refused: their message time far after the gateway's clock
    time_behind: int = 0  # ... far before it
    sets: int = 0
    records: int = 0
    peak: int = 0  # the most beacons tracked at once (never above max_beacons but for pinned ones)


class _Beacon:
    __slots__ = ("id", "grouper", "localizer", "last_t", "readings", "records", "pinned", "established", "refused")

    def __init__(self, beacon: str, grouper: Grouper, t: float, pinned: bool = False) -> None:
        self.id = beacon
        self.grouper = grouper
        self.localizer: SetHandler | None = None  # made with a writer that knows this beacon
        self.last_t = t
        self.readings = 0
        self.records = 0
        self.established = False  # a set of two anchors or more has left its grouper (else: new)
        self.refused = 0  # readings refused for their message time (time_ahead, time_behind)
        self.pinned = pinned  # never evicted nor timed out


class Retired:
    """The groupers of the beacons a tracker let go, kept as their totals: one
    :class:`GroupCounters` and one :class:`AnchorStats` per anchor (bounded however many
    beacons come and go). It stands beside the tracked beacons' groupers wherever the
    gateway adds them up (:class:`GrouperTotals`), so the totals (sets, readings per
    anchor, and the rates the health takes from them) never go back when a beacon leaves."""

    open_sets = 0

    def __init__(self) -> None:
        self.counters = GroupCounters()
        self.combined = 0
        self.dropped = 0
        self._stats: dict[int, AnchorStats] = {}
        self.tracker = self  # the per-anchor part (all_stats, stale_ids, known) is this object's

    _COUNTS = tuple(f.name for f in fields(GroupCounters) if f.name != "unknown_ids")

    def add(self, g: Grouper) -> None:
        c, out = g.counters, self.counters
        for name in self._COUNTS:  # once per beacon let go: a flood of ids lets many go
            setattr(out, name, getattr(out, name) + getattr(c, name))
        for a, n in c.unknown_ids.items():
            if a in out.unknown_ids or len(out.unknown_ids) < MAX_UNKNOWN_IDS:
                out.unknown_ids[a] = out.unknown_ids.get(a, 0) + n
        self.combined += getattr(g, "combined", 0)
        self.dropped += getattr(g, "dropped", 0)
        for a, s in g.tracker.all_stats().items():
            _merge_stats(self._stats.setdefault(a, AnchorStats(stale=True)), s)  # a beacon let go hears nothing

    def all_stats(self) -> dict[int, AnchorStats]:
        return {a: replace(s) for a, s in self._stats.items()}

    def stale_ids(self) -> tuple[int, ...]:
        return ()

    def known(self, anchor_id: int) -> bool:
        return False  # no live tracker here: an anchor's reboot concerns the tracked beacons


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
        self.on_set: Callable[[str, AnchorSet], None] | None = None  # sees each set before its estimator
        self.counters = BeaconCounters()
        self._beacons: OrderedDict[str, _Beacon] = OrderedDict()  # least recently heard first
        self.retired = Retired()  # the groupers of the beacons let go, as totals
        self.refused_ids: Counter[str] = Counter()  # refused readings of beacons not tracked (bounded)

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

    def localizers(self) -> list[tuple[str, SetHandler]]:
        """(beacon, localizer) of every tracked beacon, least recently heard first."""
        return [(b.id, b.localizer) for b in self._beacons.values() if b.localizer is not None]

    def add(self, beacon: str, grouper: Grouper | None = None,
            make_localizer: Callable[[str, RecordWriter], SetHandler] | None = None) -> SetHandler:
        """Track ``beacon`` from now on, before its first reading, pinned (never evicted nor
        timed out), with this grouper and localizer factory (default: the tracker's own).
        Returns its localizer. Pinned beacons are not bounded by ``max_beacons``: the caller
        adds a known, small number of them."""
        if not isinstance(beacon, str) or not beacon or len(beacon) > MAX_ID_LEN:
            raise ValueError(f"bad beacon id {beacon!r}")
        if beacon in self._beacons:
            raise ValueError(f"beacon {beacon!r} is tracked already")
        g = grouper if grouper is not None else self.make_grouper(beacon)
        b = self._beacons[beacon] = _Beacon(beacon, g, -math.inf, pinned=True)
        b.localizer = (make_localizer or self.make_localizer)(beacon, _ToTracker(self, b))
        self.counters.created += 1
        self.counters.peak = max(self.counters.peak, len(self._beacons))
        return b.localizer

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
            if len(self._beacons) >= self.cfg.max_beacons and not self._make_room():
                c.refused += 1  # every tracked beacon is pinned: the new one has no room
                return
            b = self._beacons[beacon] = _Beacon(beacon, self.make_grouper(beacon), r.t)
            c.created += 1
            c.peak = max(c.peak, len(self._beacons))
            log.info("tracking beacon %s (%d tracked)", beacon, len(self._beacons))
        else:
            self._beacons.move_to_end(beacon)
            if r.t > b.last_t:
                b.last_t = r.t
        b.readings += 1
        for s in b.grouper.push(r):
            self._handle(b, s, r.t)

    def refuse(self, beacon: str, kind: str) -> None:
        """A reading of ``beacon`` refused before it reached its grouper (``kind``: a counter,
        ``time_ahead`` or ``time_behind``): counted in total and per beacon (a beacon not
        tracked by its id, the first MAX_NAMED_REFUSED ids)."""
        c = self.counters
        c.readings += 1
        setattr(c, kind, getattr(c, kind) + 1)
        b = self._beacons.get(beacon)
        if b is not None:
            b.refused += 1
        elif beacon in self.refused_ids or len(self.refused_ids) < MAX_NAMED_REFUSED:
            self.refused_ids[beacon] += 1

    def _make_room(self) -> bool:
        """Let one beacon go for a new one (see the module doc); False if all are pinned."""
        oldest = new = None
        for v in self._beacons.values():  # least recently heard first
            if v.pinned:
                continue
            if not v.established:  # a new beacon: the one heard least often goes first, unestimated
                if new is None or v.readings < new.readings:
                    new = v
            elif oldest is None:
                oldest = v
        if new is not None:
            self.counters.dropped_new += 1
            self.counters.dropped_readings += new.readings
            self._let_go(new.id, "evicted", estimate=False)
            return True
        if oldest is None:
            return False
        self._let_go(oldest.id, "evicted")
        return True

    def rebase(self, now: float) -> None:
        """The gateway's message clock was set back to ``now`` (pfdoa.gateway.msgtime): beacons
        whose latest time lies after it (heard on the clock that was dropped) are let go."""
        for beacon in [k for k, v in self._beacons.items() if not v.pinned and v.last_t > now]:
            self._let_go(beacon, "timed_out")

    def poll(self, now: float) -> None:
        """Time passes: idle beacons are let go, due sets released (groupers' timers)."""
        limit = now - self.cfg.idle_timeout_s
        idle = []
        for b in self._beacons.values():  # least recently heard first
            if b.last_t > limit:
                break
            if not b.pinned:
                idle.append(b.id)
        for beacon in idle:
            self._let_go(beacon, "timed_out")
        for b in self._beacons.values():
            # A pinned beacon's grouper always sees the time (its anchors turn stale);
            # the others' only while they hold a set (many ESPresense devices).
            if b.pinned or b.grouper.open_sets:
                for s in b.grouper.poll(now):
                    self._handle(b, s, now)

    def flush(self) -> None:
        """End of input: every open set of every beacon goes through its estimator."""
        for b in self._beacons.values():
            for s in b.grouper.flush():
                self._handle(b, s)

    def _handle(self, b: _Beacon, s: AnchorSet, now: float | None = None) -> None:
        self.counters.sets += 1
        if self.on_set is not None:
            self.on_set(b.id, s)
        if len(s.rssi) >= 2:
            b.established = True
        if b.localizer is None:  # its first set: the estimator is built now (see the module doc)
            b.localizer = self.make_localizer(b.id, _ToTracker(self, b))
        if now is not None and not b.pinned and hasattr(b.localizer, "stamp_t"):
            # The record's stamp: the gateway's time when the set was released (the reading
            # that closed it, or the timers), as the runner stamps the primary localizer's.
            b.localizer.stamp_t = now
        b.localizer.handle(s)

    def _record(self, b: _Beacon, rec: Record) -> None:
        b.records += 1
        self.counters.records += 1
        if self.on_record is not None:
            self.on_record(b.id, rec)

    def _let_go(self, beacon: str, reason: str, estimate: bool = True) -> None:
        """Stop tracking ``beacon``: its open sets estimated first (``estimate``), its counts
        kept as totals, and nothing else of it kept (the beacon, its localizer and its writer
        refer to each other: the cycle is broken here, so its arrays are freed at once rather
        than whenever the garbage collector next runs, which a flood of new ids outpaced)."""
        b = self._beacons[beacon]
        if estimate:
            for s in b.grouper.flush():
                self._handle(b, s)
        self.retired.add(b.grouper)
        del self._beacons[beacon]
        b.localizer = None
        if estimate:
            setattr(self.counters, reason, getattr(self.counters, reason) + 1)
            log.info("beacon %s %s after %d readings", beacon, reason.replace("_", " "), b.readings)
        if self.on_gone is not None and estimate:
            self.on_gone(beacon, reason)

    def summary(self) -> dict:
        """Counters and the tracked beacons (at most max_beacons entries)."""
        out: dict[str, Any] = dict(self.counters.__dict__)
        out["tracked"] = len(self._beacons)
        out["beacons"] = {b.id: {"readings": b.readings, "records": b.records,
                                 "last_t": b.last_t if math.isfinite(b.last_t) else None,
                                 "open_sets": b.grouper.open_sets, **({"refused": b.refused} if b.refused else {})}
                          for b in self._beacons.values()}
        if self.refused_ids:
            out["refused_untracked"] = dict(self.refused_ids.most_common(16))
        return out

    def refused_by_beacon(self, n: int = 8) -> dict[str, int]:
        """The ``n`` beacons with the most refused readings (tracked or not), for the health."""
        both = Counter(self.refused_ids)
        for b in self._beacons.values():
            if b.refused:
                both[b.id] += b.refused
        return dict(both.most_common(n))


class _Route:
    """Where one beacon index of our frames goes."""

    __slots__ = ("name", "index", "has_seq", "grouper", "event_time", "guard")

    def __init__(self, name: str, index: int, has_seq: bool, grouper: Grouper,
                 guard: AuthGuard | None = None) -> None:
        self.name, self.index, self.has_seq, self.grouper = name, index, has_seq, grouper
        self.guard = guard  # an authenticated beacon's second verification (pfdoa.gateway.auth)
        # Windows are spans of event time; sequence sets time out on receive time.
        self.event_time = isinstance(grouper, WindowGrouper)


class FrameBeacons:
    """Our frames' reports, by the beacon index they carry, into a :class:`BeaconTracker`.

    Configured (``[[beacons]]``): each entry is tracked from the start under its name; a
    report of another index is counted (``unknown_beacon``) and dropped, and so is a report
    whose ``NO_SEQ`` flag contradicts its entry's kind (``kind_mismatch``: the anchor's table
    is not the site's). Not configured: the anchors' first-boot table is assumed, entry 0
    our beacon (``b0``), and any other index below ``BEACON_SLOTS`` is tracked as
    ``b<index>`` from its first report on, grouped as that report says (by sequence, or by
    ``default_window_s`` windows for ``NO_SEQ``). Every beacon is pinned: at most
    ``BEACON_SLOTS`` of them. The primary beacon (the configured one with the odometry, or
    ``b0``) gets its localizer from ``make_primary`` (the caller keeps it: odometry, final
    counters); the others from ``make_localizer``. A version-1 anchor's reports are entry 0's.

    ``check_status`` compares a STATUS's ``filter_hash`` with the configured table's; the
    anchors that differ are named in ``filter_mismatch`` (their reports may be about other
    beacons than the names say: ``pfdoa anchors filters`` sets the table).

    An authenticated beacon (``pfdoa_auth``) gets an :class:`~pfdoa.gateway.auth.AuthGuard`
    from ``make_guard(key)`` (default: without the relay pattern check), counting into
    ``auth``: its reports are verified again before they reach its grouper, its sets and
    estimates are checked for a relay.
    """

    def __init__(self, anchor_ids: Iterable[int], cfg: BeaconsConfig,
                 make_grouper: Callable[[bool, float | None], Grouper],
                 make_localizer: Callable[[str, RecordWriter], SetHandler],
                 make_primary: Callable[[str, RecordWriter], SetHandler],
                 on_record: Callable[[str, Record], None] | None = None,
                 default_window_s: float = DEFAULT_WINDOW_S,
                 make_guard: Callable[[bytes], AuthGuard] | None = None,
                 auth: AuthCounters | None = None) -> None:
        self.cfg = cfg
        self.make_grouper = make_grouper
        self.default_window_s = float(default_window_s)
        self.auth = auth if auth is not None else AuthCounters()
        self.make_guard = make_guard or (lambda key: AuthGuard(key, self.auth))
        self._guards: dict[str, AuthGuard] = {}
        self._on_record = on_record
        self.tracker = BeaconTracker(anchor_ids, self._no_lazy_beacons, make_localizer, cfg,
                                     on_record=self._record if on_record is not None else None)
        self.tracker.on_set = self._check_set
        self.expected_hash = cfg.filter_hash
        self.unknown_beacon = 0
        self.kind_mismatch = 0
        self.filter_mismatch: set[int] = set()
        self._routes: dict[int, _Route] = {}
        primary = cfg.primary()
        if primary is None:
            self.primary = self._add(f"b{defs.FILTER_DEFAULT_INDEX}", defs.FILTER_DEFAULT_INDEX, True, None,
                                     make_primary)
        else:
            for e in cfg.entries:
                guard = None
                if e.filter.kind == defs.FILTER_PFDOA_AUTH:
                    guard = self._guards[e.name] = self.make_guard(e.filter.match[:defs.AUTH_KEY_LEN])
                r = self._add(e.name, e.index, e.has_seq, e.window_s, make_primary if e is primary else None, guard)
                if e is primary:
                    self.primary = r
        self.primary_localizer = self.tracker._beacons[self.primary.name].localizer

    @staticmethod
    def _no_lazy_beacons(beacon: str) -> Grouper:
        raise AssertionError("our frames' beacons are added by FrameBeacons, never lazily")

    def _add(self, name: str, index: int, has_seq: bool, window_s: float | None,
             make_localizer: Callable[[str, RecordWriter], SetHandler] | None, guard: AuthGuard | None = None) -> _Route:
        grouper = self.make_grouper(has_seq, window_s)
        self.tracker.add(name, grouper, make_localizer)
        r = self._routes[index] = _Route(name, index, has_seq, grouper, guard)
        return r

    def _check_set(self, name: str, s: AnchorSet) -> None:
        g = self._guards.get(name)
        if g is not None:
            g.check_set(s)

    def _record(self, name: str, rec: Record) -> None:
        g = self._guards.get(name)
        if g is not None:
            g.check_record(rec)
        if self._on_record is not None:
            self._on_record(name, rec)

    @property
    def groupers(self) -> list[Grouper]:
        return [r.grouper for r in self._routes.values()]

    def route(self, index: int, has_seq: bool) -> _Route | None:
        """The beacon a report of entry ``index`` (with or without a sequence) is about."""
        r = self._routes.get(index)
        if r is None:
            if self.cfg.entries or not 0 <= index < defs.BEACON_SLOTS:
                self.unknown_beacon += 1
                return None
            r = self._add(f"b{index}", index, has_seq, None if has_seq else self.default_window_s, None)
            log.info("reports about beacon entry %d: tracking it as %s", index, r.name)
        if r.has_seq != has_seq:
            self.kind_mismatch += 1
            return None
        return r

    def check_status(self, anchor_id: int, filter_hash: int, filter_slots: int) -> None:
        """A version-2 STATUS (``filter_slots`` > 0): does the anchor hold the site's table?"""
        if self.expected_hash is None or filter_slots == 0:
            return
        if filter_hash != self.expected_hash:
            if anchor_id not in self.filter_mismatch:
                self.filter_mismatch.add(anchor_id)
                log.warning("anchor %d: its beacon filter table (hash 0x%04x) is not the site's [[beacons]] "
                            "(0x%04x): pfdoa anchors filters sets it", anchor_id, filter_hash, self.expected_hash)
        elif anchor_id in self.filter_mismatch:
            self.filter_mismatch.discard(anchor_id)
            log.info("anchor %d: its beacon filter table is now the site's", anchor_id)

    def poll(self, now: float) -> None:
        self.tracker.poll(now)

    def flush(self) -> None:
        self.tracker.flush()

    def summary(self) -> dict:
        out = self.tracker.summary()
        for r in self._routes.values():
            g = r.grouper
            out["beacons"][r.name].update({"index": r.index, "grouping": "window" if r.event_time else "seq",
                                           "sets": g.counters.sets})
        out["unknown_beacon"] = self.unknown_beacon
        out["kind_mismatch"] = self.kind_mismatch
        out["filter_hash"] = self.expected_hash
        out["filter_mismatch"] = sorted(self.filter_mismatch)
        return out


class _TrackerTotals:
    """Per-anchor statistics over several beacons' trackers (what the health line reads)."""

    def __init__(self, trackers: list) -> None:
        self.trackers = trackers

    def all_stats(self) -> dict[int, AnchorStats]:
        out: dict[int, AnchorStats] = {}
        for tr in self.trackers:
            for a, s in tr.all_stats().items():
                t = out.get(a)
                if t is None:
                    out[a] = AnchorStats(s.received, s.lost, s.duplicates, s.late, s.reordered, s.reboots, s.stale,
                                         s.stale_events, s.last_rx)
                    continue
                _merge_stats(t, s)
                t.stale = t.stale and s.stale  # silent for every beacon
        return out

    def stale_ids(self) -> tuple[int, ...]:
        return tuple(a for a, s in self.all_stats().items() if s.stale)


class GrouperTotals:
    """Several groupers seen as one for the health line and the final counters: counters
    summed, per-anchor link statistics summed (reboots: the most any beacon's tracker saw;
    stale: silent for every beacon), open sets summed."""

    def __init__(self, groupers: Callable[[], list[Grouper]]) -> None:
        self._groupers = groupers

    @property
    def counters(self) -> GroupCounters:
        out = GroupCounters()
        for g in self._groupers():
            c = g.counters
            for f in fields(GroupCounters):
                if f.name == "unknown_ids":
                    for a, n in c.unknown_ids.items():
                        out.unknown_ids[a] = out.unknown_ids.get(a, 0) + n
                else:
                    setattr(out, f.name, getattr(out, f.name) + getattr(c, f.name))
        return out

    @property
    def tracker(self) -> _TrackerTotals:
        return _TrackerTotals([g.tracker for g in self._groupers()])

    @property
    def open_sets(self) -> int:
        return sum(g.open_sets for g in self._groupers())
