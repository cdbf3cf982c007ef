"""Chunks -> decoded messages -> readings (with their event times) -> the reassembler.

:class:`Gateway` decodes chunks (one protocol ``StreamDecoder`` per byte-stream source,
at most ``MAX_DECODERS`` of them: an idle one, or one that never decoded a valid frame,
makes room for a new source; ``decode_can`` per CAN frame), maps every report's anchor tick to the host clock
(:class:`~pfdoa.gateway.anchorclock.AnchorClocks`), feeds the reassembler and counts
everything in :class:`~pfdoa.gateway.health.Health`. Finished sets go to a callback;
``on_reading`` (if given) sees every reading just before the reassembler does (the
``--record`` and ``--readings-out`` sinks), a named beacon's with its id
(``on_reading(reading, beacon)``), so that a recording replays to every beacon's estimates.

Values: an anchor reports an exponential average of its events (``rssi_q8``, alpha 0.25 by
default), which lags a walking target by about (1 - alpha) / alpha events. :class:`EventMeans`
recovers each event's own mean from two consecutive reports of an anchor whose configuration
is known, so the estimator gets unlagged readings (and does its own averaging over time).

Times: a reading's ``t`` is its chunk's receive time (the reassembler's timers run on
receive times, like the runner's), its ``event_t`` the time its anchor's tick says the
event happened; a set in "seq" mode is stamped with the median event time of its reports.
In "window" mode a reading's time is its event time (windows are spans of event time).
CAN reports carry no tick: their event time is their receive time.

Beacons: with a :class:`~pfdoa.gateway.beacons.FrameBeacons` (``pfdoa gateway``) every
report goes to the beacon its index names, each with its own grouper and estimator;
``NO_SEQ`` reports (beacons without a sequence number) carry no ``seq`` into their
grouper, which groups them by time. Without one, the gateway is single-beacon: reports
of entry 0 only (every version-1 report is), the others counted as ``unknown_beacon``.
Readings that name their beacon themselves (ESPresense nodes' messages:
:class:`~pfdoa.gateway.beacons.BeaconReading`, :meth:`Gateway.push_beacon`) go to the
``named`` :class:`~pfdoa.gateway.beacons.BeaconTracker`, one grouper and estimator per
beacon id, bounded by its ``max_beacons``; its groupers count in the health line. On
message time a :class:`~pfdoa.gateway.msgtime.MessageClock` refuses (and the tracker
counts, per beacon) readings whose time is implausible before anything sees them.

Schema: a STATUS whose ``defs_hash`` is neither version's is named in
``schema_mismatch``; a version-1 anchor reports version 1's and is not.

Peer readings (a report whose ``beacon`` is 128 + an anchor id, SPEC 3.5: one anchor
hearing another's own advertisement) are no beacon's: they go to ``peers``
(:class:`pfdoa.gateway.peers.LivePeers`, the live calibration; its ``poll`` runs with the
timers), as reported (the anchor's calibration offset applied, as for a beacon's report),
and are counted as ``peer_readings`` (``peer_readings_ignored`` without ``peers``).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from typing import Callable

from pfdoa.gateway.anchorclock import AnchorClocks
from pfdoa.gateway.beacons import BeaconBatch, BeaconReading, BeaconTracker, FrameBeacons, GrouperTotals
from pfdoa.gateway.health import Health
from pfdoa.gateway.msgtime import MessageClock
from pfdoa.gateway.transports import DECODER_IDLE_S, MAX_DECODERS, Chunk
from pfdoa.protocol import defs
from pfdoa.protocol.can import decode_can
from pfdoa.protocol.config import AnchorConfig
from pfdoa.protocol.messages import (
    AuthReport,
    AuthStatus,
    ConfigAck,
    FilterAck,
    RssiReport,
    Status,
    StatusA,
    StatusB,
    StatusC,
)
from pfdoa.protocol.uart import ANCHOR_TO_HOST, StreamDecoder
from pfdoa.readings.reassembly import AnchorSet, Reading, SeqReassembler, WindowGrouper

log = logging.getLogger(__name__)

_ERRORS = frozenset(defs.ERRORS)
KNOWN_SCHEMAS = frozenset((defs.DEFS_HASH, defs.V1_DEFS_HASH))  # the versions this gateway decodes


FIRMWARE_DEFAULTS = AnchorConfig()  # what an anchor runs until configured (frozen)


class EventMeans:
    """Each report's own event mean, recovered from the anchor's exponential average.

    The anchor updates ``ema += alpha * (mean - ema)`` per event (SPEC 3) and reports
    ``ema + offset``, so two consecutive reports ``y_{k-1}``, ``y_k`` of one (anchor, beacon)
    give the event's calibrated mean exactly: ``y_{k-1} + (y_k - y_{k-1}) / alpha`` (the
    anchor rounds each update to 1/256 dB: the mean is then within 0.5 / (256 alpha) dB).
    A ``RESET`` report's value is its event's mean. Everything else keeps the reported
    (filtered) value: a ``SPIKE`` (the anchor rejected the event, its average is unchanged),
    ``SATURATED``, the first report of a chain or one after a gap in ``seq`` (a lost report).

    Only for anchors known to run ``expected`` (default: the firmware's defaults) with one
    report per event: an anchor's ``STATUS`` carries its configuration hash, and until one
    has confirmed it (or after one contradicts it) that anchor's filtered values are used.
    ``expected`` None: every value stays as reported. Memory: one entry per (anchor,
    beacon) heard, at most 128 x 256.
    """

    def __init__(self, expected: AnchorConfig | None = FIRMWARE_DEFAULTS) -> None:
        usable = expected is not None and expected.report_mode == 0 and expected.is_valid()
        self.expected = expected if usable else None
        self._hash = self.expected.hash if self.expected is not None else None
        self._alpha = self.expected.alpha_q8 / 256.0 if self.expected is not None else 1.0
        self.confirmed: set[int] = set()
        self.contradicted: set[int] = set()
        self._prev: dict[tuple[int, int], tuple[int, int]] = {}  # (anchor, beacon) -> (seq, rssi_q8)
        self.recovered = 0  # readings given as their event's mean
        self.filtered = 0  # readings given as reported

    def status(self, anchor_id: int, config_hash: int) -> None:
        if self._hash is None:
            return
        if config_hash == self._hash:
            self.confirmed.add(anchor_id)
            self.contradicted.discard(anchor_id)
        elif anchor_id not in self.contradicted:
            self.confirmed.discard(anchor_id)
            self.contradicted.add(anchor_id)
            log.warning("anchor %d: configuration hash 0x%04x is not the expected 0x%04x: its filtered "
                        "values are used as reported (lagged)", anchor_id, config_hash, self._hash)

    def value(self, anchor_id: int, m: RssiReport) -> float:
        """dBm of this report's reading: its event's mean where it can be recovered."""
        key = (anchor_id, m.beacon)
        prev = self._prev.get(key)
        self._prev[key] = (m.seq, m.rssi_q8)
        if anchor_id in self.confirmed and not m.flags & (defs.FLAG_SPIKE | defs.FLAG_SATURATED):
            if m.flags & defs.FLAG_RESET:
                self.recovered += 1
                return m.rssi_q8 / 256.0
            if prev is not None and (m.seq - prev[0]) & 0xFFFF == 1:
                self.recovered += 1
                return (prev[1] + (m.rssi_q8 - prev[1]) / self._alpha) / 256.0
        self.filtered += 1
        return m.rssi_q8 / 256.0


class Gateway:
    """Decode chunks and reassemble; hand finished sets to a callback. Readings carry each
    event's mean where :class:`EventMeans` can recover it (``event_means`` None: the
    anchors' filtered values as reported)."""

    def __init__(self, grouper: SeqReassembler | WindowGrouper, on_set: Callable[[AnchorSet], object],
                 health: Health | None = None, beacons: FrameBeacons | None = None,
                 on_reading: Callable[..., object] | None = None,
                 event_means: EventMeans | None | bool = True, named: BeaconTracker | None = None,
                 peers=None) -> None:
        """``grouper``/``on_set``: the single beacon's (``beacons`` None), or the primary
        beacon's grouper when ``beacons`` routes every report (``on_set`` is then unused:
        each beacon's sets go to its own localizer). ``on_reading`` sees every reading as it
        enters a grouper (the recording and readings sinks). ``named``: the tracker of
        :meth:`push_beacon`'s readings (None: they are counted as ``unnamed_dropped``)."""
        self.grouper = grouper
        self.on_set = on_set
        self.on_reading = on_reading
        self.health = health or Health()
        self.beacons = beacons
        if beacons is not None:
            self.health.auth = beacons.auth  # one set of authenticated-beacon counts
        self.event_means = EventMeans() if event_means is True else (event_means or None)
        self.clocks = AnchorClocks(grouper.anchor_ids)
        self._window = isinstance(grouper, WindowGrouper)
        # One decoder per byte-stream source, least recently fed first (see _decoder).
        self._decoders: OrderedDict[str, StreamDecoder] = OrderedDict()
        self._dec_errors: dict[str, dict[str, int]] = {}
        self._dec_last: dict[str, float] = {}  # source -> time of its latest chunk
        self.unknown_beacon = 0  # single-beacon: reports about other entries
        self.named = named
        self.unnamed_dropped = 0  # push_beacon without a named tracker
        # On message time (the runner sets it): named readings whose time is implausible are
        # refused and counted per beacon before anything sees them (pfdoa.gateway.msgtime).
        self.message_clock: MessageClock | None = None
        self.peers = peers  # pfdoa.gateway.peers.LivePeers (or anything with add and poll), or None
        self.peer_readings = 0
        self.peer_readings_ignored = 0
        self._totals = GrouperTotals(self._groupers)

    def _groupers(self) -> list:
        out: list = list(self.beacons.groupers) if self.beacons is not None else [self.grouper]
        if self.named is not None:  # its beacons come and go: asked each time; those gone as totals
            out += [g for g in map(self.named.grouper, self.named.beacons) if g is not None]
            out.append(self.named.retired)
        return out

    @property
    def totals(self) -> GrouperTotals:
        """Every beacon's grouper seen as one, as beacons come and go (the health sampler's)."""
        return self._totals

    @property
    def groupers(self):
        """Every beacon's grouper seen as one (the health line and final counters read it);
        the grouper itself with one beacon."""
        return self.grouper if len(self._groupers()) == 1 else self._totals

    def _decoder(self, source: str, t: float) -> StreamDecoder | None:
        """The decoder of ``source`` (a chunk of it at time ``t`` has come), or None when
        the table is full and no decoder may be let go for it (see :meth:`_make_room`)."""
        dec = self._decoders.get(source)
        if dec is not None:
            self._decoders.move_to_end(source)
        else:
            if len(self._decoders) >= MAX_DECODERS and not self._make_room(source, t):
                return None
            dec = self._decoders[source] = StreamDecoder(types=ANCHOR_TO_HOST)
            self._dec_errors[source] = {}
        self._dec_last[source] = t
        return dec

    def _make_room(self, source: str, t: float) -> bool:
        """The decoder table is full and a new source has sent a chunk. Let go, in this order,

        1. the least recently fed decoder if nothing came for it for DECODER_IDLE_S (chunk
           times: the receive clock live, the recorded times in a replay);
        2. the least recently fed decoder that has never decoded a valid frame: a source
           of noise (64 one-off junk topics) never holds a place against one that works.

        Its partial frame (at most MAX_ENCODED bytes) goes with it; counted
        (``sources_evicted``) and said. None to let go: the new source's chunk is dropped
        (``sources_dropped``), and said."""
        h = self.health
        first = next(iter(self._decoders))
        if t - self._dec_last[first] >= DECODER_IDLE_S:
            victim, why = first, f"idle for {t - self._dec_last[first]:.0f} s"
        else:
            victim = next((name for name, d in self._decoders.items() if not d.counters["frames_ok"]), None)
            why = "it never sent a valid frame"
        if victim is None:
            log.warning("byte-stream source %r: not decoded: the decoder table holds %d sources, each sending "
                        "valid frames (sources_dropped)", source[:80], MAX_DECODERS)
            return False
        del self._decoders[victim], self._dec_errors[victim], self._dec_last[victim]
        h.sources_evicted += 1
        log.warning("byte-stream source %r: the decoder table is full (%d sources): %r let go for it (%s; "
                    "sources_evicted)", source[:80], MAX_DECODERS, victim[:80], why)
        return True

    def feed(self, chunk: Chunk) -> None:
        h = self.health
        h.chunks += 1
        h.bytes += len(chunk.data)
        if chunk.can_id is None:
            source, t = chunk.source, chunk.t
            dec = self._decoders.get(source)
            if dec is not None:  # a known source (_decoder's first case, inline: every chunk)
                self._decoders.move_to_end(source)
                self._dec_last[source] = t
            else:
                dec = self._decoder(source, t)
                if dec is None:
                    h.sources_dropped += 1
                    return
            decoded = dec.feed(chunk.data)
            # Every error the StreamDecoder counts discards at least one byte, so while
            # bytes_discarded stands still there is nothing new to copy (the common case:
            # this runs once per chunk; tested inline, without a call).
            if dec.counters["bytes_discarded"] != self._dec_errors[source].get("bytes_discarded", 0):
                self._sync_errors(source, dec)
            message, report = self._message, self._report
            for anchor_id, m in decoded:
                if m.__class__ is RssiReport:  # _message's first case, inline (nearly every frame)
                    h.frames += 1
                    h.reports += 1
                    report(anchor_id, m, t)
                else:
                    message(anchor_id, m, t)
        else:
            d = decode_can(chunk.can_id, chunk.data)
            if isinstance(d, str):
                h.error(d)
            else:
                self._message(d.anchor_id, d.message, chunk.t)

    def push_beacon(self, br: BeaconReading | BeaconBatch) -> None:
        """A reading that names its beacon (or a batch of them), to the ``named`` tracker."""
        if self.named is None:
            self.unnamed_dropped += len(br.readings) if isinstance(br, BeaconBatch) else 1
            return
        on_reading, clock, named = self.on_reading, self.message_clock, self.named
        for b in br.readings if isinstance(br, BeaconBatch) else (br,):
            if clock is not None:
                why = clock.admit(b.reading.t)
                if why is not None:
                    named.refuse(b.beacon, why)
                    continue
                if clock.moved_back and clock.now is not None:
                    named.rebase(clock.now)
            if on_reading is not None:
                on_reading(b.reading, b.beacon)
            named.push(b.beacon, b.reading)

    def _sync_errors(self, source: str, dec: StreamDecoder) -> None:
        prev = self._dec_errors[source]
        # Every error the StreamDecoder counts discards at least one byte, so while
        # bytes_discarded stands still there is nothing new to copy (the common case: this
        # runs once per chunk, and scanning every counter was ~20 % of the UART path).
        discarded = dec.counters["bytes_discarded"]
        if discarded == prev.get("bytes_discarded", 0):
            return
        prev["bytes_discarded"] = discarded
        for kind, n in dec.counters.items():
            if kind in _ERRORS and n != prev.get(kind, 0):
                self.health.error(kind, n - prev.get(kind, 0))
                prev[kind] = n

    def _message(self, anchor_id: int, m, t: float) -> None:
        h = self.health
        h.frames += 1
        if isinstance(m, RssiReport):
            h.reports += 1
            self._report(anchor_id, m, t)
        elif isinstance(m, (Status, StatusA, StatusB, StatusC)):
            if not isinstance(m, StatusC):  # the third CAN part of one STATUS
                h.status += 1
            if isinstance(m, (Status, StatusA)):
                if self.event_means is not None:
                    self.event_means.status(anchor_id, m.config_hash)
                self._uptime(anchor_id, m.uptime_s, t)
            if isinstance(m, (Status, StatusB)) and m.defs_hash not in KNOWN_SCHEMAS:
                if anchor_id not in h.schema_mismatch:
                    h.schema_mismatch.add(anchor_id)
                    log.warning("anchor %d: message definitions differ (defs_hash 0x%04x, ours 0x%04x, version 1's "
                                "0x%04x)", anchor_id, m.defs_hash, defs.DEFS_HASH, defs.V1_DEFS_HASH)
            if isinstance(m, (Status, StatusC)) and self.beacons is not None:
                self.beacons.check_status(anchor_id, m.filter_hash, m.filter_slots)
        elif isinstance(m, AuthStatus):  # the anchor's own rejections (SPEC 9.5)
            h.auth.anchor_status(anchor_id, m)
        elif isinstance(m, (ConfigAck, FilterAck)):
            h.acks += 1
            log.info("anchor %d: %s token=%d result=%d", anchor_id, m.NAME.lower().replace("_", " "), m.token,
                     m.result)

    def _report(self, anchor_id: int, m: RssiReport, t: float) -> None:
        peer = m.peer
        if peer is not None:  # another anchor's advertisement, heard: no beacon's reading
            if self.peers is None:
                self.peer_readings_ignored += 1
            else:
                self.peer_readings += 1
                self.peers.add(anchor_id, peer, m.rssi_q8 / 256.0, t)
            return
        has_seq = m.has_seq
        if self.beacons is None:
            if m.beacon != defs.FILTER_DEFAULT_INDEX:
                self.unknown_beacon += 1
                return
            if isinstance(m, AuthReport):
                self.health.auth.unverified += 1  # no [[beacons]], no key: the anchor's word
            grouper, event_time, beacon = self.grouper, self._window, ""
        else:
            route = self.beacons.route(m.beacon, has_seq)
            if route is None:
                return
            if route.guard is not None:
                if not route.guard.accept(anchor_id, m, t):
                    return  # rejected by the second verification (counted by reason)
            elif isinstance(m, AuthReport):
                self.health.auth.unverified += 1  # an authenticated beacon this gateway has no key for
            grouper, event_time, beacon = route.grouper, route.event_time, route.name
        tick = m.tick_ms
        event_t = self.clocks.event_time(anchor_id, tick, t)
        # A NO_SEQ report's seq is its anchor's own event count: no set key across anchors.
        # NO_SEQ beacons (grouped by time) keep the anchors' filtered values: with their raw
        # event means the two-beacon SIL run's iBeacon error rose (seeds 1-3: 0.54 -> 0.70 m).
        means = self.event_means if has_seq else None
        value = means.value(anchor_id, m) if means is not None else m.rssi_q8 / 256.0
        r = Reading(anchor_id, value, event_t if event_time else t, m.seq if has_seq else None, tick,
                    m.flags, event_t)
        if self.on_reading is not None:
            self.on_reading(r)
        if self.beacons is None:
            for s in grouper.push(r):
                self.on_set(s)
        else:
            self.beacons.tracker.push(beacon, r)

    def _uptime(self, anchor_id: int, uptime_s: int, t: float) -> None:
        """A STATUS uptime, to every beacon's tracker (an anchor's reboot restarts them all)."""
        rebooted = False
        for g in self._groupers():
            tracker = g.tracker
            if tracker.known(anchor_id):
                before = tracker.stats(anchor_id).reboots
                tracker.uptime(anchor_id, uptime_s, t)
                rebooted |= tracker.stats(anchor_id).reboots != before
        if rebooted:
            self.clocks.reset(anchor_id)  # its tick restarted with it

    def poll(self, now: float) -> None:
        """Timer time is ``now``: sets whose timeout expired leave, silent anchors turn stale;
        the live peer calibration refits when its period is up."""
        if self.peers is not None:
            self.peers.poll(now)
        if self.named is not None:
            self.named.poll(now)
        if self.beacons is not None:
            self.beacons.poll(now)
            return
        for s in self.grouper.poll(now):
            self.on_set(s)

    def finish(self) -> None:
        if self.peers is not None and hasattr(self.peers, "finish"):
            self.peers.finish()
        if self.named is not None:
            self.named.flush()
        if self.beacons is not None:
            self.beacons.flush()
            return
        for s in self.grouper.flush():
            self.on_set(s)

    def summary(self) -> dict:
        """The beacons' part of the final counters."""
        if self.beacons is not None:
            return self.beacons.summary()
        return {"unknown_beacon": self.unknown_beacon}

    def peers_summary(self) -> dict:
        """The peer readings' part of the final counters (empty when there were none)."""
        out: dict = {}
        if self.peer_readings or self.peers is not None:
            out["peer_readings"] = self.peer_readings
        if self.peer_readings_ignored:
            out["peer_readings_ignored"] = self.peer_readings_ignored
        if self.peers is not None and hasattr(self.peers, "to_json"):
            out["peers"] = self.peers.to_json()
        return out
