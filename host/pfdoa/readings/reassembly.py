"""Reassembly of anchor reports into synchronized anchor sets.

Two groupers with one interface (``push(reading)``, ``poll(now)``, ``flush()``, each
returning the :class:`AnchorSet` objects that became ready, in order):

* :class:`SeqReassembler` keys sets by the 16-bit beacon sequence number every anchor
  copies from the beacon it heard (protocol/SPEC.md 1.1). Sequence numbers are unwrapped
  with serial-number arithmetic (RFC 1982) into a monotonic 64-bit count. Sets leave in
  sequence order. The oldest open set leaves when it is complete, when each anchor it
  lacks has already reported a newer sequence (its report was lost: an anchor's reports
  arrive in order on its link) or is stale, when it has been open ``set_timeout_s``, or when more than
  ``max_open_sets`` sets are open (it is evicted, and counted).
* :class:`WindowGrouper` groups by receive time for anchors without a common beacon
  sequence (third-party anchors, recorded datasets). Same rule as
  :func:`pfdoa.trace.group_by_window`: a window takes every reading for ``window_s`` from
  its first one and then closes (on the next reading, or live on the timer), whatever the
  reporting rate; repeated readings of one anchor in it are combined into their median in
  dB, and the set carries how many readings each value combines. Opt-in
  (``close_when_complete``), for anchors that report at most once per window, a window also
  closes as soon as every anchor is in it.

Both track every anchor with :class:`AnchorTracker`: loss from sequence gaps (RTP style,
so a reordered report is not counted lost), duplicates, late reports, reboots (the
anchor's tick or uptime going backwards) and staleness (no report for ``stale_after_s``).

Memory is bounded whatever arrives: at most ``max_open_sets`` open sets of at most one
value per configured anchor, ``history`` remembered closed sets (a bitmask each), one open
window of at most ``MAX_READINGS_PER_WINDOW`` readings per configured anchor, one tracker
per configured anchor, and unknown anchor ids counted in a dict capped at 256 keys.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from pfdoa.trace import DEFAULT_WINDOW_S, MAX_READINGS_PER_WINDOW, combine_db, window_closed

log = logging.getLogger(__name__)

SEQ_MOD = 1 << 16
TICK_MOD = 1 << 32
# A tick that goes back by more than this is a reboot, not jitter between reports.
REBOOT_TICK_SLACK_MS = 1000
MAX_UNKNOWN_IDS = 256


def seq_diff(a: int, b: int) -> int:
    """Signed serial-number distance a - b modulo 2^16, in [-32768, 32767]."""
    return ((a - b + 0x8000) & 0xFFFF) - 0x8000


@dataclass(slots=True)
class Reading:
    """One RSSI reading from one anchor, whatever transport or file it came from."""

    anchor_id: int
    rssi_dbm: float
    t: float  # receive time (s) on the gateway clock (the timers' time), or the trace time
    seq: int | None = None  # beacon sequence (0..65535), when known
    tick_ms: int | None = None  # anchor tick (u32), when known
    flags: int = 0
    event_t: float | None = None  # when the anchor's clock says the event happened (host clock)


@dataclass
class AnchorSet:
    """A synchronized set: at most one RSSI per configured anchor."""

    t: float  # seq: median event time of its reports; window: time of its last reading
    rssi: dict[int, float]  # anchor id -> dBm
    missing: tuple[int, ...]  # configured anchors without a value
    stale: tuple[int, ...] = ()  # configured anchors currently silent for stale_after_s
    rebooted: tuple[int, ...] = ()  # anchors whose reboot was detected since the previous set
    seq: int | None = None
    reason: str = "complete"  # complete | lost | timeout | evicted | window | flush
    counts: dict[int, int] = field(default_factory=dict)  # readings averaged per anchor (absent: 1)

    @property
    def anchors(self) -> tuple[int, ...]:
        return tuple(sorted(self.rssi))

    def vector(self, anchor_ids: Sequence[int]) -> np.ndarray:
        """RSSI in the given (site) order, NaN where missing."""
        return np.array([self.rssi.get(a, math.nan) for a in anchor_ids], dtype=float)

    def count_vector(self, anchor_ids: Sequence[int]) -> np.ndarray:
        """Readings behind each value in the given (site) order, 0 where missing."""
        return np.array([self.counts.get(a, 1) if a in self.rssi else 0 for a in anchor_ids], dtype=np.int64)


@dataclass
class AnchorStats:
    received: int = 0  # unique reports (duplicates excluded)
    lost: int = 0  # from sequence gaps, net of reports that arrived reordered
    duplicates: int = 0
    late: int = 0  # arrived after its set had left
    reordered: int = 0
    reboots: int = 0
    stale: bool = False
    stale_events: int = 0
    last_rx: float | None = None


class _AnchorState:
    __slots__ = ("stats", "first_ext", "max_ext", "last_tick", "last_uptime", "lost_before", "epoch_seq")

    def __init__(self) -> None:
        self.stats = AnchorStats()
        self.first_ext: int | None = None  # unwrapped seq of the first report in this epoch
        self.max_ext = -1
        self.last_tick: int | None = None
        self.last_uptime: int | None = None
        self.lost_before = 0  # loss accumulated before the last sequence restart
        self.epoch_seq = 0  # received count in this epoch


class AnchorTracker:
    """Per-anchor health: loss, duplicates, late, reboots, staleness."""

    def __init__(self, anchor_ids: Iterable[int], stale_after_s: float) -> None:
        self.anchor_ids = tuple(anchor_ids)
        self.stale_after_s = float(stale_after_s)
        self._st = {a: _AnchorState() for a in self.anchor_ids}
        self._pending_reboot: set[int] = set()
        self.start: float | None = None
        # Until this time no anchor can turn stale (none is stale and every one has been
        # heard since): update_stale, called after every chunk, then has nothing to do.
        self._quiet_until = -math.inf

    def stats(self, anchor_id: int) -> AnchorStats:
        return self._st[anchor_id].stats

    def all_stats(self) -> dict[int, AnchorStats]:
        return {a: s.stats for a, s in self._st.items()}

    def known(self, anchor_id: int) -> bool:
        return anchor_id in self._st

    def seen(self, r: Reading) -> None:
        """Any report from the anchor (before classification): liveness and reboot checks."""
        s = self._st[r.anchor_id]
        if self.start is None:
            self.start = r.t
        s.stats.last_rx = r.t
        if r.t + self.stale_after_s < self._quiet_until:  # times need not be monotonic
            self._quiet_until = -math.inf
        if s.stats.stale:
            s.stats.stale = False
            log.info("anchor %d reporting again", r.anchor_id)
        if r.tick_ms is not None:
            tick = int(r.tick_ms) % TICK_MOD
            if s.last_tick is not None:
                back = (s.last_tick - tick) % TICK_MOD
                if REBOOT_TICK_SLACK_MS < back < TICK_MOD // 2:
                    self._reboot(r.anchor_id, f"tick went back {back} ms")
            s.last_tick = tick

    def uptime(self, anchor_id: int, uptime_s: int, now: float) -> None:
        """A STATUS message: uptime going backwards means the anchor rebooted."""
        s = self._st.get(anchor_id)
        if s is None:
            return
        if self.start is None:
            self.start = now
        s.stats.last_rx = now
        if now + self.stale_after_s < self._quiet_until:
            self._quiet_until = -math.inf
        if s.last_uptime is not None and uptime_s < s.last_uptime:
            self._reboot(anchor_id, f"uptime went back from {s.last_uptime} s to {uptime_s} s")
        s.last_uptime = uptime_s

    def _reboot(self, anchor_id: int, why: str) -> None:
        s = self._st[anchor_id]
        s.stats.reboots += 1
        # Both signals restart: one reboot seen by its tick and then by its uptime (or the
        # other way round) is one reboot, not two.
        s.last_tick = s.last_uptime = None
        self._pending_reboot.add(anchor_id)
        log.warning("anchor %d rebooted (%s)", anchor_id, why)

    def take_reboots(self) -> tuple[int, ...]:
        if not self._pending_reboot:  # (every set asks; a reboot is rare)
            return ()
        out = tuple(sorted(self._pending_reboot))
        self._pending_reboot.clear()
        return out

    def accepted(self, anchor_id: int, ext: int | None) -> None:
        """A unique report (not a duplicate) with unwrapped sequence ``ext``."""
        s = self._st[anchor_id]
        s.stats.received += 1
        if ext is None:
            return
        s.epoch_seq += 1
        if s.first_ext is None:
            s.first_ext = s.max_ext = ext
        elif ext > s.max_ext:
            s.max_ext = ext
        elif ext < s.first_ext:  # reordered before the first one we saw
            s.first_ext = ext
            s.stats.reordered += 1
        else:
            s.stats.reordered += 1
        s.stats.lost = s.lost_before + max(0, (s.max_ext - s.first_ext + 1) - s.epoch_seq)

    def newest(self, anchor_id: int) -> int:
        return self._st[anchor_id].max_ext

    def restart(self) -> None:
        """Sequence numbering restarted (beacon reboot): start a new loss epoch."""
        for s in self._st.values():
            s.lost_before = s.stats.lost
            s.first_ext, s.max_ext, s.epoch_seq = None, -1, 0

    def duplicate(self, anchor_id: int) -> None:
        self._st[anchor_id].stats.duplicates += 1

    def late(self, anchor_id: int) -> None:
        self._st[anchor_id].stats.late += 1

    def update_stale(self, now: float) -> tuple[int, ...]:
        """Mark anchors silent for ``stale_after_s`` (an anchor never heard counts from the
        first report or poll, whichever came first: the gateway's start, live)."""
        if self.start is None:
            self.start = now
            return ()
        if now < self._quiet_until:
            return ()
        out = []
        oldest = math.inf
        for a, s in self._st.items():
            last = s.stats.last_rx if s.stats.last_rx is not None else self.start
            oldest = min(oldest, last)
            if now - last > self.stale_after_s:
                if not s.stats.stale:
                    s.stats.stale = True
                    s.stats.stale_events += 1
                    log.warning("anchor %d stale: no report for %.1f s", a, now - last)
                out.append(a)
        # 1 ms short of the exact bound, so rounding can never skip a due check.
        self._quiet_until = -math.inf if out else oldest + self.stale_after_s - 1e-3
        return tuple(out)

    def is_stale(self, anchor_id: int) -> bool:
        return self._st[anchor_id].stats.stale

    def stale_ids(self) -> tuple[int, ...]:
        return tuple([a for a, s in self._st.items() if s.stats.stale])


@dataclass
class GroupCounters:
    readings: int = 0
    unknown_anchor: int = 0
    no_seq: int = 0
    duplicates: int = 0
    late: int = 0
    sets: int = 0
    complete: int = 0
    partial: int = 0
    evicted: int = 0
    timeouts: int = 0
    seq_restarts: int = 0
    unknown_ids: dict[int, int] = field(default_factory=dict)

    def unknown(self, anchor_id: int) -> None:
        self.unknown_anchor += 1
        if anchor_id in self.unknown_ids or len(self.unknown_ids) < MAX_UNKNOWN_IDS:
            self.unknown_ids[anchor_id] = self.unknown_ids.get(anchor_id, 0) + 1


class _Open:
    __slots__ = ("ext", "first_t", "events", "rssi", "mask")

    def __init__(self, ext: int, t: float) -> None:
        self.ext = ext
        self.first_t = t  # receive time of its first report: the set timeout counts from here
        self.events: list[float] = []  # its reports' event times
        self.rssi: dict[int, float] = {}
        self.mask = 0

    def event_time(self) -> float:
        """The median of its reports' event times: one anchor's clock error cannot move it far."""
        ev = sorted(self.events)
        n = len(ev)
        return ev[n // 2] if n % 2 else 0.5 * (ev[n // 2 - 1] + ev[n // 2])


class SeqReassembler:
    """Group readings by beacon sequence (see the module doc)."""

    def __init__(
        self,
        anchor_ids: Sequence[int],
        *,
        set_timeout_s: float = 0.25,
        max_open_sets: int = 64,
        stale_after_s: float = 3.0,
        history: int = 1024,
    ) -> None:
        if max_open_sets < 1 or history < 1:
            raise ValueError("max_open_sets and history must be >= 1")
        self.anchor_ids = tuple(anchor_ids)
        self._bit = {a: 1 << i for i, a in enumerate(self.anchor_ids)}
        self._full = (1 << len(self.anchor_ids)) - 1
        self.set_timeout_s = float(set_timeout_s)
        self.max_open_sets = int(max_open_sets)
        self.history = int(history)
        self.tracker = AnchorTracker(self.anchor_ids, stale_after_s)
        self.counters = GroupCounters()
        self._open: dict[int, _Open] = {}
        self._heap: list[int] = []
        self._closed: dict[int, int] = {}  # ext -> mask of anchors it had
        self._closed_order: deque[int] = deque()
        self._ref: int | None = None  # newest unwrapped sequence seen
        self._emitted = -1  # unwrapped sequence of the last set that left
        self._head: dict[int, tuple[int, int]] = {}  # anchor -> (newest ext, its tick)
        # Timer time: set only by poll(). A reading's own receive time never runs the set
        # timeout (a backlog read after a stall carries the stall in its stamp).
        self._now = -math.inf

    @property
    def open_sets(self) -> int:
        return len(self._open)

    def _unwrap(self, seq: int) -> int:
        if self._ref is None:
            self._ref = seq
            return seq
        return self._ref + seq_diff(seq, self._ref & 0xFFFF)

    def push(self, r: Reading) -> list[AnchorSet]:
        c = self.counters
        c.readings += 1
        bit = self._bit.get(r.anchor_id)
        if bit is None:
            c.unknown(r.anchor_id)
            return []
        anchor = r.anchor_id
        tracker = self.tracker
        stats = tracker._st[anchor].stats  # tracker.stats(): the anchor's one AnchorStats for good
        reboots = stats.reboots
        tracker.seen(r)
        if stats.reboots != reboots:
            self._head.pop(anchor, None)  # its tick restarted: older ticks mean nothing now
        if r.seq is None:
            c.no_seq += 1
            return []
        out: list[AnchorSet] = []
        seq = int(r.seq) & 0xFFFF
        ref = self._ref
        # _unwrap, inline: ref + seq_diff(seq, ref & 0xFFFF)
        ext = self._unwrap(seq) if ref is None else ref + (((seq - (ref & 0xFFFF) + 0x8000) & 0xFFFF) - 0x8000)
        head = self._head.get(anchor)
        # _seq_went_back only where it can be true (an older sequence than the anchor's newest).
        if ext <= self._emitted - self.history or (
                head is not None and ext < head[0] and self._seq_went_back(r, ext)):
            # The beacon restarted its numbering.
            out += self._restart(seq, r.t)
            ext = self._unwrap(seq)
            head = None  # _restart cleared every head
        if ext > self._ref:
            self._ref = ext
        tick = r.tick_ms
        if tick is not None and (head is None or ext > head[0]):
            self._head[anchor] = (ext, int(tick))
        if ext <= self._emitted:
            mask = self._closed.get(ext)
            if mask is not None and mask & bit:
                c.duplicates += 1
                self.tracker.duplicate(r.anchor_id)
            else:
                c.late += 1
                self.tracker.accepted(r.anchor_id, ext)
                self.tracker.late(r.anchor_id)
                if mask is not None:  # so a copy of this late report counts as a duplicate
                    self._closed[ext] = mask | bit
            return out
        o = self._open.get(ext)
        if o is None:
            o = self._open[ext] = _Open(ext, r.t)
            heapq.heappush(self._heap, ext)
        elif o.mask & bit:
            c.duplicates += 1
            self.tracker.duplicate(r.anchor_id)
            return out
        o.rssi[r.anchor_id] = float(r.rssi_dbm)
        o.mask |= bit
        o.events.append(r.t if r.event_t is None else r.event_t)
        self.tracker.accepted(r.anchor_id, ext)
        # Evict only once the reading is in its set: the new set may be the oldest one.
        if len(self._open) > self.max_open_sets:
            c.evicted += 1
            out.append(self._emit(self._open[self._heap[0]], "evicted"))
        out += self._drain(self._now)
        return out

    def _seq_went_back(self, r: Reading, ext: int) -> bool:
        """An anchor reports an older sequence than its newest with a tick later than that
        newest report's: a duplicate repeats an older tick and a reordered report has an
        older one, so the beacon restarted (within ``history``, where the distance test
        cannot see it; without this every report was a 'duplicate' until the new numbers
        passed the old ones)."""
        head = self._head.get(r.anchor_id)
        if r.tick_ms is None or head is None or ext >= head[0]:
            return False
        return 0 < (int(r.tick_ms) - head[1]) % TICK_MOD < TICK_MOD // 2

    def _restart(self, seq: int, now: float) -> list[AnchorSet]:
        self.counters.seq_restarts += 1
        log.warning("beacon sequence restarted (now %d); closing %d open set(s)", seq, len(self._open))
        out = [self._emit(self._open[self._heap[0]], "flush") for _ in range(len(self._open))]
        self._closed.clear()
        self._closed_order.clear()
        self._head.clear()
        nxt = self._emitted + 1
        self._ref = nxt + ((seq - nxt) & 0xFFFF)
        self.tracker.restart()
        return out

    def _ready(self, o: _Open, now: float) -> str | None:
        if o.mask == self._full:
            return "complete"
        if now - o.first_t >= self.set_timeout_s:
            return "timeout"
        # Waiting is pointless for an anchor that has moved past this sequence (its report
        # was lost), or that is stale (silent for stale_after_s) once a newer beacon has
        # been heard (after an outage of every anchor, the first set still waits for all).
        # (The tracker's newest() and is_stale() read in place: this runs for the oldest
        # open set after every reading and every poll.)
        states = self.tracker._st
        mask, ext = o.mask, o.ext
        newer = ext < self._ref
        for a, bit in self._bit.items():
            if not mask & bit:
                s = states[a]
                if s.max_ext <= ext and not (newer and s.stats.stale):
                    return None
        return "lost"

    def _drain(self, now: float) -> list[AnchorSet]:
        out = []
        while self._heap:
            o = self._open[self._heap[0]]
            why = "complete" if o.mask == self._full else self._ready(o, now)  # _ready's first test, inline
            if why is None:
                break
            if why == "timeout":
                self.counters.timeouts += 1
            out.append(self._emit(o, why))
        return out

    def _emit(self, o: _Open, reason: str) -> AnchorSet:
        heapq.heappop(self._heap)
        del self._open[o.ext]
        self._emitted = o.ext
        self._closed[o.ext] = o.mask
        self._closed_order.append(o.ext)
        if len(self._closed_order) > self.history:
            self._closed.pop(self._closed_order.popleft(), None)
        c = self.counters
        c.sets += 1
        if o.mask == self._full:
            c.complete += 1
        else:
            c.partial += 1
        missing = () if o.mask == self._full else tuple([a for a, b in self._bit.items() if not o.mask & b])
        return AnchorSet(
            t=o.event_time(),
            rssi=o.rssi,
            missing=missing,
            stale=self.tracker.stale_ids(),
            rebooted=self.tracker.take_reboots(),
            seq=o.ext & 0xFFFF,
            reason=reason,
        )

    def poll(self, now: float) -> list[AnchorSet]:
        """Timer time is ``now``: mark stale anchors and release sets whose timeout expired."""
        if now <= self._now and now < self.tracker._quiet_until:
            # Nothing to do (the Runner polls after every chunk, most of them at an unchanged
            # time): the timer time stays, update_stale would return at once (no anchor can
            # turn stale yet), and every push and poll ends with the oldest open set not ready
            # at self._now (tests/unit/test_bench_hotpaths.py checks this).
            return []
        self._now = max(self._now, now)
        self.tracker.update_stale(now)
        return self._drain(self._now)

    def flush(self) -> list[AnchorSet]:
        """Release every open set (end of input)."""
        return [self._emit(self._open[self._heap[0]], "flush") for _ in range(len(self._open))]


class WindowGrouper:
    """Group readings by time window (see the module doc); the window rule and the robust
    average are :func:`pfdoa.trace.window_closed` and :func:`pfdoa.trace.combine_db`."""

    def __init__(self, anchor_ids: Sequence[int], *, window_s: float = DEFAULT_WINDOW_S, stale_after_s: float = 3.0,
                 close_when_complete: bool = False) -> None:
        """``close_when_complete``: also close a window as soon as every configured anchor is
        in it. Only for anchors that report at most once per window (their period >= window_s):
        then the sets are the time rule's, sooner; faster anchors would get single readings."""
        if not window_s > 0.0:
            raise ValueError("window_s must be > 0")
        self.anchor_ids = tuple(anchor_ids)
        self.window_s = float(window_s)
        self.close_when_complete = close_when_complete
        self.tracker = AnchorTracker(self.anchor_ids, stale_after_s)
        self.counters = GroupCounters()
        self.combined = 0  # readings averaged with an earlier one of the same anchor and window
        self.dropped = 0  # beyond MAX_READINGS_PER_WINDOW for one anchor in one window
        self._values: dict[int, list[float]] = {a: [] for a in self.anchor_ids}
        self._open_t: float | None = None
        self._last_t = 0.0
        self._ref: int | None = None
        self._last_seq: dict[int, int] = {}

    @property
    def open_sets(self) -> int:
        return int(self._open_t is not None)

    def push(self, r: Reading) -> list[AnchorSet]:
        c = self.counters
        c.readings += 1
        values = self._values.get(r.anchor_id)
        if values is None:
            c.unknown(r.anchor_id)
            return []
        self.tracker.seen(r)
        ext = None
        if r.seq is not None:
            seq = int(r.seq) & 0xFFFF
            if self._last_seq.get(r.anchor_id) == seq:
                c.duplicates += 1
                self.tracker.duplicate(r.anchor_id)
                return []
            self._last_seq[r.anchor_id] = seq
            if self._ref is None:
                self._ref = seq
            ext = self._ref + seq_diff(seq, self._ref & 0xFFFF)
            self._ref = max(self._ref, ext)
        self.tracker.accepted(r.anchor_id, ext)
        out: list[AnchorSet] = []
        if self._open_t is not None and window_closed(self._open_t, r.t, self.window_s):
            out.append(self._emit("window"))
        if self._open_t is None:
            self._open_t = r.t
        if len(values) >= MAX_READINGS_PER_WINDOW:
            self.dropped += 1
        else:
            self.combined += bool(values)
            values.append(float(r.rssi_dbm))
        self._last_t = r.t
        if self.close_when_complete and all(self._values.values()):
            out.append(self._emit("complete"))
        return out

    def _emit(self, reason: str) -> AnchorSet:
        self._open_t = None
        rssi: dict[int, float] = {}
        counts: dict[int, int] = {}
        for a, v in self._values.items():
            if v:
                rssi[a] = combine_db(v)
                counts[a] = len(v)
                v.clear()
        c = self.counters
        c.sets += 1
        missing = tuple(a for a in self.anchor_ids if a not in rssi)
        if missing:
            c.partial += 1
        else:
            c.complete += 1
        return AnchorSet(
            t=self._last_t,
            rssi=rssi,
            missing=missing,
            stale=self.tracker.stale_ids(),
            rebooted=self.tracker.take_reboots(),
            seq=None,
            reason=reason,
            counts=counts,
        )

    def poll(self, now: float) -> list[AnchorSet]:
        """Live: close the window once its time has passed (no later reading can join it)."""
        self.tracker.update_stale(now)
        if self._open_t is not None and window_closed(self._open_t, now, self.window_s):
            self.counters.timeouts += 1
            return [self._emit("window")]
        return []

    def flush(self) -> list[AnchorSet]:
        return [self._emit("flush")] if self._open_t is not None else []
