"""Gateway health: counters from every stage, rates, and the line printed on stderr.

One :class:`Health` object is shared by the pipeline stages. ``line(now)`` formats the
periodic report (rates since the previous report)::

    health: 203.1 frames/s 50.8 sets/s 50.8 est/s | errors bad_crc=3 overlong=1 | \
loss a0=0.0% a1=1.2% a2=0.0% a3=0.0% | stale 3 | open sets 2

``summary()`` is the dictionary printed as the final counters.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


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
    reconnects: Counter = field(default_factory=Counter)  # per source name
    schema_mismatch: set = field(default_factory=set)  # anchors whose defs_hash differs
    estimates: int = 0
    estimator_errors: int = 0
    _last: tuple[float, int, int, int] | None = None

    def start(self, now: float) -> None:
        """Rates in the first health line count from here."""
        self._last = (now, self.frames, 0, self.estimates)

    def error(self, kind: str, n: int = 1) -> None:
        self.errors[kind] += n

    def line(self, now: float, grouper) -> str:
        """The periodic health line; ``grouper`` is the SeqReassembler or WindowGrouper."""
        c = grouper.counters
        prev = self._last or (now, self.frames, c.sets, self.estimates)
        dt = max(now - prev[0], 1e-9)
        self._last = (now, self.frames, c.sets, self.estimates)
        parts = [
            f"health: {(self.frames - prev[1]) / dt:.1f} frames/s "
            f"{(c.sets - prev[2]) / dt:.1f} sets/s {(self.estimates - prev[3]) / dt:.1f} est/s"
        ]
        errs = dict(self.errors)
        for k in ("duplicates", "late", "unknown_anchor", "evicted"):
            if getattr(c, k):
                errs[k] = getattr(c, k)
        if self.queue_drops:
            errs["queue_drops"] = self.queue_drops
        parts.append("errors " + (" ".join(f"{k}={v}" for k, v in sorted(errs.items())) or "none"))
        loss = []
        for a, s in grouper.tracker.all_stats().items():
            total = s.received + s.lost
            loss.append(f"a{a}={100.0 * s.lost / total:.1f}%" if total else f"a{a}=-")
        parts.append("loss " + " ".join(loss))
        stale = grouper.tracker.stale_ids()
        parts.append("stale " + (",".join(str(a) for a in stale) if stale else "none"))
        parts.append(f"open sets {grouper.open_sets}")
        if self.reconnects:
            parts.append("reconnects " + " ".join(f"{k}={v}" for k, v in sorted(self.reconnects.items())))
        return " | ".join(parts)

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
        }
