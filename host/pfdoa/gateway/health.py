"""Gateway health: counters from every stage, snapshots of a period, and the line on stderr.

One :class:`Health` object is shared by the pipeline stages. A :class:`HealthSampler`
takes a :class:`HealthSnapshot` of it and the reassembler once per health period: rates
since the previous snapshot, errors by kind, per-anchor totals, what changed in the period
and a level per anchor. Everything that reports health uses one snapshot: its
:meth:`HealthSnapshot.line` is the periodic line on stderr::

    health: 203.1 frames/s 50.8 sets/s 50.8 est/s | errors bad_crc=3 overlong=1 | \
loss a0=0.0% a1=1.2% a2=0.0% a3=0.0% | stale 3 | open sets 2

and :meth:`HealthSnapshot.to_json` the record of ``--health-json`` (and the live view's,
and the recording's diagnostics), so the numbers are the same everywhere.
``Health.summary()`` is the dictionary printed as the final counters.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

from pfdoa.gateway.auth import AuthCounters

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

    t: float  # time of the snapshot on the gateway's host clock (s)
    period_s: float
    frames_per_s: float
    sets_per_s: float
    estimates_per_s: float
    errors: Mapping[str, int]  # by kind, totals since the start
    anchors: Mapping[int, AnchorHealth]  # site order
    open_sets: int
    frames: int
    sets: int
    estimates: int
    estimator_errors: int = 0
    reconnects: Mapping[str, int] = field(default_factory=dict)
    # Beacons that their readings name (ESPresense devices), when the gateway tracks them:
    # their accepted readings (one per ESPresense message) per second, and the tracker's
    # counters (readings taken so far, tracked, peak, created, evicted, timed_out, refused,
    # bad_id, unknown_anchor, dropped_new, dropped_readings, time_ahead, time_behind;
    # bad_time_by_beacon: the beacons with the most readings refused for their message time,
    # when there are any).
    named_per_s: float | None = None
    named_beacons: Mapping[str, Any] = field(default_factory=dict)
    # Counters of the outputs that keep some while running (by sink name: the ROS 2 output's
    # published, dropped, matched), and the localizer's odometry counters (lines, waited, ...).
    outputs: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    odometry: Mapping[str, int] = field(default_factory=dict)
    # Every input's own counters, by input name (what it rejected: a UDP input's oversized
    # datagrams and bad frames per sender, a capture's bad lines; Transport.counters()).
    inputs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    # Our authenticated beacons (pfdoa.gateway.auth): the gateway's rejections by reason, the
    # anchors' (their last AUTH_STATUS, as anchor_<reason>), relay suspicions; empty without one.
    auth: Mapping[str, int] = field(default_factory=dict)
    # The live peer calibration (pfdoa.gateway.peers.LivePeers.to_json), when the site has it.
    peers: Mapping[str, Any] | None = None
    peers_line: str = ""

    @property
    def stale(self) -> tuple[int, ...]:
        return tuple(a for a, h in self.anchors.items() if h.stale)

    def line(self) -> str:
        """The human health line."""
        named = "" if self.named_per_s is None else f"{self.named_per_s:.1f} named/s "
        parts = [
            f"health: {self.frames_per_s:.1f} frames/s {named}{self.sets_per_s:.1f} sets/s "
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
        if self.named_per_s is not None:
            nb = self.named_beacons
            bad_time = nb.get("time_ahead", 0) + nb.get("time_behind", 0)
            parts.append(f"beacons {nb.get('tracked', 0)} evicted {nb.get('evicted', 0)} "
                         f"timed out {nb.get('timed_out', 0)}" + (f" bad time {bad_time}" if bad_time else ""))
        for name, counters in self.outputs.items():
            parts.append(f"{name} " + " ".join(f"{k}={v}" for k, v in counters.items() if isinstance(v, int)))
        rejected = {name: n for name, c in self.inputs.items() if (n := _total(c.get("rejected")))}
        if rejected:  # what the inputs refused (the JSON has each input's counters)
            parts.append("inputs rejected " + " ".join(f"{k}={v}" for k, v in rejected.items()))
        if self.auth:  # the gateway's rejections + the anchors', by reason; relay suspicions
            au = self.auth
            parts.append("auth rejected " + " ".join(f"{r}={au.get(r, 0)}+{au.get('anchor_' + r, 0)}"
                                                     for r in ("bad_tag", "stale", "replayed"))
                         + f" relay {au.get('relay_pattern', 0)}/{au.get('relay_jump', 0)}")
        if self.peers_line:
            parts.append(self.peers_line)
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
            **({} if self.named_per_s is None else {"named_per_s": round(self.named_per_s, 3),
                                                    "named_beacons": dict(self.named_beacons)}),
            **({"outputs": {k: dict(v) for k, v in self.outputs.items()}} if self.outputs else {}),
            **({"odometry": dict(self.odometry)} if self.odometry else {}),
            **({"inputs": {k: dict(v) for k, v in self.inputs.items()}} if self.inputs else {}),
            **({"auth": dict(self.auth)} if self.auth else {}),
            **({} if self.peers is None else {"peers": dict(self.peers)}),
        }


def _total(v: Any) -> int:
    """A count, or the sum of counts by kind (a ``rejected`` entry of an input's counters)."""
    if isinstance(v, Mapping):
        return sum(_total(x) for x in v.values())
    return v if isinstance(v, int) and not isinstance(v, bool) else 0


class HealthSampler:
    """Snapshots of a gateway's :class:`Health` and reassembler.

    ``sample(now, t)``: ``now`` is the clock the rates are measured on (the one given to
    :meth:`start`), ``t`` the host time stamped on the snapshot. Rates count from the
    previous sample (the first one from :meth:`start`). ``named``: the gateway's tracker
    of named beacons (:class:`pfdoa.gateway.beacons.BeaconTracker`), or None.
    """

    def __init__(self, health: "Health", grouper, named=None) -> None:
        self.health = health
        self.grouper = grouper
        self.named = named
        self._prev: tuple[float, int, int, int] | None = None
        self._prev_anchor: dict[int, tuple[int, int, int]] = {}
        self._prev_named = 0

    def _named_readings(self) -> int:
        return self.named.counters.readings if self.named is not None else 0

    def start(self, now: float, frames: int | None = None, estimates: int | None = None) -> None:
        """Rates of the first sample count from ``now`` (and these totals at ``now``: the
        health's current ones by default)."""
        h = self.health
        self._prev = (now, h.frames if frames is None else frames, 0, h.estimates if estimates is None else estimates)
        self._prev_named = self._named_readings() if frames is None else 0

    def sample(self, now: float, t: float) -> HealthSnapshot:
        h, c = self.health, self.grouper.counters
        prev = self._prev or (now, h.frames, c.sets, h.estimates)
        dt = max(now - prev[0], 1e-9)
        self._prev = (now, h.frames, c.sets, h.estimates)
        named_per_s, named_beacons = None, {}
        if self.named is not None:
            n = self._named_readings()
            named_per_s, self._prev_named = (n - self._prev_named) / dt, n
            nc = self.named.counters
            named_beacons = {"readings": nc.readings, "tracked": len(self.named), "peak": nc.peak,
                             "created": nc.created, "evicted": nc.evicted,
                             "timed_out": nc.timed_out, "refused": nc.refused, "bad_id": nc.bad_id,
                             "unknown_anchor": nc.unknown_anchor, "dropped_new": nc.dropped_new,
                             "dropped_readings": nc.dropped_readings, "time_ahead": nc.time_ahead,
                             "time_behind": nc.time_behind}
            if nc.time_ahead or nc.time_behind:
                named_beacons["bad_time_by_beacon"] = self.named.refused_by_beacon()
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
            named_per_s=named_per_s, named_beacons=named_beacons,
            auth=h.auth.snapshot() if h.auth.active else {},
            peers=h.peers.to_json() if h.peers is not None else None,
            peers_line=h.peers.line() if h.peers is not None else "",
        )


@dataclass
class Health:
    bytes: int = 0
    chunks: int = 0
    frames: int = 0  # messages decoded (all types)
    reports: int = 0  # RSSI reports
    status: int = 0
    acks: int = 0
    errors: Counter = field(default_factory=Counter)  # decode errors by kind
    queue_drops: int = 0  # chunks dropped because the pipeline fell behind
    sources_dropped: int = 0  # chunks from sources beyond the decoder limit
    sources_evicted: int = 0  # decoders let go for a new source (idle, or never a valid frame)
    reconnects: Counter = field(default_factory=Counter)  # per source name
    schema_mismatch: set = field(default_factory=set)  # anchors whose defs_hash differs
    estimates: int = 0
    estimator_errors: int = 0
    auth: AuthCounters = field(default_factory=AuthCounters)  # our authenticated beacons (SPEC 9)
    peers: Any = None  # pfdoa.gateway.peers.LivePeers when the site has the anchors' entry
    _sampler: HealthSampler | None = field(default=None, repr=False, compare=False)
    _start: tuple[float, int, int] | None = field(default=None, repr=False, compare=False)

    def start(self, now: float) -> None:
        """Rates in the first :meth:`line` (and of samplers made later) count from here."""
        self._start = (now, self.frames, self.estimates)
        if self._sampler is not None:
            self._sampler.start(*self._start)

    def error(self, kind: str, n: int = 1) -> None:
        self.errors[kind] += n

    def sampler(self, grouper, named=None) -> HealthSampler:
        """A new sampler of this health and ``grouper`` (and ``named``, the tracker of named
        beacons), started where :meth:`start` was."""
        s = HealthSampler(self, grouper, named)
        if self._start is not None:
            s.start(*self._start)
        return s

    def line(self, now: float, grouper) -> str:
        """The periodic health line (rates since the previous call): the line of a snapshot
        from this object's own sampler. ``grouper`` is the SeqReassembler or WindowGrouper."""
        if self._sampler is None or self._sampler.grouper is not grouper:
            self._sampler = self.sampler(grouper)
        return self._sampler.sample(now, now).line()

    def summary(self, grouper) -> dict:
        """Final counters (a JSON-serialisable dict)."""
        c = grouper.counters
        return {
            "bytes": self.bytes,
            "chunks": self.chunks,
            "frames": self.frames,
            "reports": self.reports,
            "status": self.status,
            "acks": self.acks,
            "errors": dict(sorted(self.errors.items())),
            "queue_drops": self.queue_drops,
            "sources_dropped": self.sources_dropped,
            "sources_evicted": self.sources_evicted,
            "readings": c.readings,
            "duplicates": c.duplicates,
            "late": c.late,
            "unknown_anchor": c.unknown_anchor,
            "sets": c.sets,
            "complete": c.complete,
            "partial": c.partial,
            "timeouts": c.timeouts,
            "evicted": c.evicted,
            "seq_restarts": c.seq_restarts,
            "estimates": self.estimates,
            "estimator_errors": self.estimator_errors,
            "reconnects": dict(self.reconnects),
            "schema_mismatch": sorted(self.schema_mismatch),
            "anchors": {
                str(a): {
                    "received": s.received,
                    "lost": s.lost,
                    "duplicates": s.duplicates,
                    "late": s.late,
                    "reordered": s.reordered,
                    "reboots": s.reboots,
                    "stale": s.stale,
                }
                for a, s in grouper.tracker.all_stats().items()
            },
            **({"auth": self.auth.summary()} if self.auth.active else {}),
        }
