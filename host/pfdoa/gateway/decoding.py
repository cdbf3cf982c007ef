"""Chunks -> decoded messages -> readings (with their event times) -> the reassembler.

:class:`Gateway` decodes chunks (one protocol ``StreamDecoder`` per byte-stream source,
``decode_can`` per CAN frame), maps every report's anchor tick to the host clock
(:class:`~pfdoa.gateway.anchorclock.AnchorClocks`), feeds the reassembler and counts
everything in :class:`~pfdoa.gateway.health.Health`. Finished sets go to a callback;
``on_reading`` (if given) sees every reading just before the reassembler does (the
``--record`` and ``--readings-out`` sinks).

Times: a reading's ``t`` is its chunk's receive time (the reassembler's timers run on
receive times, like the runner's), its ``event_t`` the time its anchor's tick says the
event happened; a set in "seq" mode is stamped with the median event time of its reports.
In "window" mode a reading's time is its event time (windows are spans of event time).
CAN reports carry no tick: their event time is their receive time.
"""

from __future__ import annotations

import logging
from typing import Callable, Sequence

from pfdoa.gateway.anchorclock import AnchorClocks
from pfdoa.gateway.config import GatewayConfig
from pfdoa.gateway.health import Health
from pfdoa.gateway.reassembly import AnchorSet, Reading, SeqReassembler, WindowGrouper
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol import defs
from pfdoa.protocol.can import decode_can
from pfdoa.protocol.messages import ConfigAck, RssiReport, Status, StatusA, StatusB
from pfdoa.protocol.uart import ANCHOR_TO_HOST, StreamDecoder

log = logging.getLogger(__name__)

MAX_DECODERS = 64  # byte-stream sources (ports, capture source names) decoded at once
_ERRORS = frozenset(defs.ERRORS)


def make_grouper(anchor_ids: Sequence[int], cfg: GatewayConfig, mode: str | None = None,
                 window_s: float | None = None) -> SeqReassembler | WindowGrouper:
    """The reassembler for ``mode`` ("seq" or "window"; default from the config)."""
    mode = mode or cfg.mode
    if mode == "seq":
        return SeqReassembler(anchor_ids, set_timeout_s=cfg.set_timeout_s, max_open_sets=cfg.max_open_sets,
                              stale_after_s=cfg.stale_after_s)
    # Windows close on time, live and in replay alike (the same sets from the same readings).
    return WindowGrouper(anchor_ids, window_s=window_s or cfg.window_s, stale_after_s=cfg.stale_after_s)


class Gateway:
    """Decode chunks and reassemble; hand finished sets to a callback."""

    def __init__(self, grouper: SeqReassembler | WindowGrouper, on_set: Callable[[AnchorSet], object],
                 health: Health | None = None, on_reading: Callable[[Reading], object] | None = None) -> None:
        self.grouper = grouper
        self.on_set = on_set
        self.on_reading = on_reading
        self.health = health or Health()
        self.clocks = AnchorClocks(grouper.anchor_ids)
        self._window = isinstance(grouper, WindowGrouper)
        self._decoders: dict[str, StreamDecoder] = {}
        self._dec_errors: dict[str, dict[str, int]] = {}

    def _decoder(self, source: str) -> StreamDecoder | None:
        dec = self._decoders.get(source)
        if dec is None and len(self._decoders) < MAX_DECODERS:
            dec = self._decoders[source] = StreamDecoder(types=ANCHOR_TO_HOST)
            self._dec_errors[source] = {}
        return dec

    def feed(self, chunk: Chunk) -> None:
        h = self.health
        h.chunks += 1
        h.bytes += len(chunk.data)
        if chunk.can_id is None:
            dec = self._decoder(chunk.source)
            if dec is None:
                h.sources_dropped += 1
                return
            decoded = dec.feed(chunk.data)
            self._sync_errors(chunk.source, dec)
            for d in decoded:
                self._message(d.anchor_id, d.message, chunk.t)
        else:
            d = decode_can(chunk.can_id, chunk.data)
            if isinstance(d, str):
                h.error(d)
            else:
                self._message(d.anchor_id, d.message, chunk.t)

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
        tracker = self.grouper.tracker
        if isinstance(m, RssiReport):
            h.reports += 1
            tick = getattr(m, "tick_ms", None)
            event_t = self.clocks.event_time(anchor_id, tick, t)
            r = Reading(anchor_id, m.rssi_q8 / 256.0, event_t if self._window else t, m.seq, tick, m.flags,
                        event_t=event_t)
            if self.on_reading is not None:
                self.on_reading(r)
            for s in self.grouper.push(r):
                self.on_set(s)
        elif isinstance(m, (Status, StatusA, StatusB)):
            h.status += 1
            if isinstance(m, (Status, StatusA)) and tracker.known(anchor_id):
                before = tracker.stats(anchor_id).reboots
                tracker.uptime(anchor_id, m.uptime_s, t)
                if tracker.stats(anchor_id).reboots != before:
                    self.clocks.reset(anchor_id)  # its tick restarted with it
            if isinstance(m, (Status, StatusB)) and m.defs_hash != defs.DEFS_HASH:
                if anchor_id not in h.schema_mismatch:
                    h.schema_mismatch.add(anchor_id)
                    log.warning("anchor %d: message definitions differ (defs_hash 0x%04x, ours 0x%04x)",
                                anchor_id, m.defs_hash, defs.DEFS_HASH)
        elif isinstance(m, ConfigAck):
            h.acks += 1
            log.info("anchor %d: config ack token=%d result=%d", anchor_id, m.token, m.result)

    def poll(self, now: float) -> None:
        """Timer time is ``now``: sets whose timeout expired leave, silent anchors turn stale."""
        for s in self.grouper.poll(now):
            self.on_set(s)

    def finish(self) -> None:
        for s in self.grouper.flush():
            self.on_set(s)
