"""Anchor management (``pfdoa anchors``): which anchors answer, with their STATUS, and
setting their configuration (``CONFIG_SET``) and beacon filters (``FILTER_SET``), verified.

Everything runs over the gateway's own transports (:mod:`pfdoa.gateway.transports`) that
can send: serial ports (every anchor on a shared line hears every frame and answers the
ones addressed to it) and CAN buses (configuration only: ``FILTER_SET`` has no CAN
mapping, protocol/SPEC.md 4). Standard input and capture files cannot send.

What counts as done (protocol/SPEC.md 1.3-1.6 and 3.4):

* **configuration**: the anchor's ``CONFIG_ACK`` carries our token, result 0 and the hash
  of the configuration we sent; its next ``STATUS`` reports that hash; and its first
  report after the ack carries ``CALIBRATED`` exactly when the offset is not 0 (waited for
  up to ``status_timeout_s`` after the STATUS unless the anchor is set silent; an anchor
  that hears no beacon meanwhile is done without that check, and the message says so).
* **filters**: a ``FILTER_ACK`` with result 0 for every entry, the last one with the hash of
  the whole table; the next ``STATUS`` reports that hash.

An ack may be lost, or the frame that asked for it: an anchor that has not acked within
``reply_timeout_s`` is sent the same message again (the same token, so a late ack still
counts), ``retries`` times in all; the whole operation ends within ``total_timeout_s``.
Every deadline is on the injected clock (:mod:`pfdoa.clock`). Each target anchor ends with
an :class:`Outcome` whose ``message`` is one line.

Memory is bounded whatever arrives: one :class:`AnchorInfo` per anchor id (at most 127),
one partial frame per serial link, one half-joined CAN STATUS per anchor id.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Iterable, NamedTuple, Sequence

from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import InputError
from pfdoa.gateway.transports import Chunk, Transport, TransportEOF
from pfdoa.protocol import defs
from pfdoa.protocol.can import decode_can, encode_can
from pfdoa.protocol.config import AnchorConfig
from pfdoa.protocol.filters import BeaconFilter, table_hash
from pfdoa.protocol.messages import ConfigAck, ConfigSet, FilterAck, RssiReport, Status, StatusA, StatusB, StatusC
from pfdoa.protocol.uart import ANCHOR_TO_HOST, DecodeError, StreamDecoder, encode_uart

log = logging.getLogger(__name__)

# CONFIG_SET report_mode values in order (protocol/SPEC.md 1.3; messages.json names no
# constants for them, only the valid range).
REPORT_MODE_NAMES = ("every", "decimate", "silent")
I16_MIN, I16_MAX = -(1 << 15), (1 << 15) - 1  # offset_q8 is an i16
ACK_RESULTS = {defs.ACK_OK: "applied and stored", defs.ACK_INVALID: "refused: a value out of range",
               defs.ACK_STORE_FAILED: "applied but not stored: it reverts at the anchor's next boot"}


def describe_config(c: AnchorConfig) -> str:
    mode = REPORT_MODE_NAMES[c.report_mode] if 0 <= c.report_mode < len(REPORT_MODE_NAMES) else str(c.report_mode)
    if mode == "decimate":
        mode = f"every {c.decimation}th event"
    elif mode == "every":
        mode = "every event"
    return (f"offset {c.offset_q8 / 256.0:+.2f} dB, alpha {c.alpha_q8 / 256.0:.3f}, spike {c.spike_db} dB, "
            f"reports {mode}")


DEFAULT_CONFIG = AnchorConfig()  # the first-boot configuration (frozen: safe as a default)


def offset_q8(offset_db: float, what: str = "the offset") -> int:
    """An anchor's own offset (dB, added to its RSSI) as CONFIG_SET carries it: an i16 in
    1/256 dB, rounded to the nearest. The one check of its range, for ``anchors set
    --offset-db`` and ``anchors apply`` alike: InputError naming ``what`` (never clamped:
    an anchor told a different offset than the user gave reports wrong readings)."""
    q8 = int(round(float(offset_db) * 256.0)) if math.isfinite(offset_db) else None
    if q8 is None or not I16_MIN <= q8 <= I16_MAX:
        raise InputError(f"{what} must be in [{I16_MIN / 256:g}, {I16_MAX / 256:g}] dB, got {offset_db:g}")
    return q8


def offset_config(rssi_offset_db: float, base: AnchorConfig = DEFAULT_CONFIG,
                  what: str = "an anchor's offset (minus rssi_offset_db)") -> AnchorConfig:
    """The configuration that makes an anchor remove a site file's ``rssi_offset_db``
    itself (the site's model: the anchor reads that much high, pfdoa.radio), so that its
    reports follow the radio model with no offset (:func:`offset_q8`: InputError when the
    anchor cannot hold it)."""
    return replace(base, offset_q8=offset_q8(-float(rssi_offset_db), what))


@dataclass
class AnchorInfo:
    """What was heard from one anchor."""

    anchor_id: int
    link: str  # the transport it was heard on (the latest)
    first_t: float
    last_t: float
    status: Status | None = None  # the latest whole STATUS (on CAN joined from its parts)
    statuses: int = 0
    reports: int = 0
    beacons: set[int] = field(default_factory=set)  # filter entries its reports were about
    peers: set[int] = field(default_factory=set)  # the anchors it reported hearing (SPEC 3.5)
    last_flags: int | None = None

    @property
    def schema(self) -> str:
        if self.status is None:
            return "-"
        v = self.status.version
        return f"v{v}" if v is not None else f"unknown 0x{self.status.defs_hash:04x}"

    def as_dict(self) -> dict:
        s = self.status
        out: dict = {"anchor": self.anchor_id, "link": self.link, "reports": self.reports,
                     "beacons": sorted(self.beacons), "schema": self.schema, "status": None}
        if self.peers:
            out["peers"] = sorted(self.peers)
        if s is not None:
            out["status"] = {"firmware": f"{s.fw_major}.{s.fw_minor}", "uptime_s": s.uptime_s,
                             "config_hash": s.config_hash, "dropped_events": s.dropped_events,
                             "rx_errors": s.rx_errors, "spikes": s.spikes, "defs_hash": s.defs_hash,
                             "version": s.version, "filter_hash": s.filter_hash if s.filter_slots else None,
                             "filter_slots": s.filter_slots}
        return out


class Heard(NamedTuple):
    anchor_id: int
    message: object
    t: float
    link: str


class Link:
    """One transport: what arrives decoded (a UART stream decoder, or CAN frames with the
    parts of a STATUS joined), what we send encoded for it."""

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.name = transport.name
        self.can = transport.is_can
        self.decoder = StreamDecoder(types=ANCHOR_TO_HOST)
        self.errors: Counter = Counter()  # CAN decode errors (UART: the decoder's counters)
        self._status_a: dict[int, StatusA] = {}
        self._status_ab: dict[int, Status] = {}  # joined A+B, waiting for its C (version 2)
        self.ended = False  # a finite input (standard input) has ended

    @property
    def can_send(self) -> bool:
        return self.transport.bidirectional

    def send(self, msg, anchor_id: int) -> None:
        if self.can:
            for can_id, data in encode_can(msg, anchor_id):
                self.transport.send(data, can_id)
        else:
            self.transport.send(encode_uart(msg, anchor_id))

    def read(self, timeout: float) -> list[Heard]:
        out: list[Heard] = []
        if self.ended:
            return out
        try:
            items = self.transport.read(timeout)
        except TransportEOF:  # standard input ended: nothing more can come on this link
            self.ended = True
            return out
        for item in items:
            if not isinstance(item, Chunk):
                continue
            if item.can_id is None:
                for d in self.decoder.feed(item.data):
                    out.append(Heard(d.anchor_id, d.message, item.t, self.name))
                continue
            dc = decode_can(item.can_id, item.data)
            if isinstance(dc, (str, DecodeError)):
                self.errors[str(dc)] += 1
                continue
            m = self._join(dc.anchor_id, dc.message)
            if m is not None:
                out.append(Heard(dc.anchor_id, m, item.t, self.name))
        return out

    def _join(self, anchor: int, m):
        """CAN: a STATUS is STATUS_A, STATUS_B (and in version 2 STATUS_C), back to back."""
        if isinstance(m, StatusA):
            self._status_a[anchor] = m
            return None
        if isinstance(m, StatusB):
            a = self._status_a.pop(anchor, None)
            if a is None:
                return None
            s = Status.from_halves(a, m)
            self._status_ab[anchor] = s
            return s  # whole for the configuration; its C adds the filter table
        if isinstance(m, StatusC):
            ab = self._status_ab.pop(anchor, None)
            return None if ab is None else replace(ab, filter_hash=m.filter_hash, filter_slots=m.filter_slots)
        return m


@dataclass(frozen=True)
class Timing:
    reply_timeout_s: float = 1.0  # no ack this long after a send: send again
    retries: int = 3  # sends of one message at most
    status_timeout_s: float = 3.0  # after the last ack, the STATUS that confirms (one per STATUS_PERIOD_MS)
    total_timeout_s: float = 20.0  # the whole operation at most
    slice_s: float = 0.05  # one read of every link

    def __post_init__(self) -> None:
        for name in ("reply_timeout_s", "status_timeout_s", "total_timeout_s", "slice_s"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        if not 1 <= self.retries <= 100:
            raise ValueError(f"retries must be in 1..100, got {self.retries}")


@dataclass
class Outcome:
    anchor_id: int
    ok: bool
    message: str  # one line, starting with "anchor N:"
    sends: int = 0  # frames sent to it (retries included)
    acked_hash: int | None = None
    status_hash: int | None = None
    report_checked: bool = False  # a report after the change was checked (configuration)

    def as_dict(self) -> dict:
        return {"anchor": self.anchor_id, "ok": self.ok, "message": self.message, "sends": self.sends,
                "acked_hash": self.acked_hash, "status_hash": self.status_hash, "report_checked": self.report_checked}


class _Pending:
    __slots__ = ("msg", "sends", "sent_at")

    def __init__(self, msg) -> None:
        self.msg, self.sends, self.sent_at = msg, 0, -math.inf


class _Job:
    """One anchor's change: messages to get acked, then a STATUS to confirm it."""

    def __init__(self, anchor_id: int, what: str, expect_hash: int, messages: list) -> None:
        self.anchor_id = anchor_id
        self.what = what  # "configuration" / "filter table"
        self.expect_hash = expect_hash
        self.pending = {m.token: _Pending(m) for m in messages}
        self.sends = 0
        self.acked_at: float | None = None  # when the last ack arrived (then: wait for its STATUS)
        self.confirmed_at: float | None = None  # its STATUS confirmed it (then: wait for a report)
        self.status_hash: int | None = None
        self.acked_hash: int | None = None
        self.outcome: Outcome | None = None
        self.config: AnchorConfig | None = None
        self.report_checked = False

    def end(self, ok: bool, message: str, status_hash: int | None = None) -> None:
        self.outcome = Outcome(self.anchor_id, ok, f"anchor {self.anchor_id}: {message}", self.sends,
                               self.acked_hash, status_hash, self.report_checked)


def _ended(j: "_Job") -> Outcome:
    """A job's outcome once the loop is over (it ends every job: done, failed or timed out)."""
    if j.outcome is None:
        raise RuntimeError(f"anchor {j.anchor_id}: job left without an outcome")
    return j.outcome


class AnchorManager:
    """Listen to anchors and change them (see the module doc). Use as a context manager,
    or :meth:`open` / :meth:`close`."""

    def __init__(self, transports: Sequence[Transport], clock: Clock = SYSTEM, timing: Timing = Timing(),
                 stop: threading.Event | None = None) -> None:
        if not transports:
            raise ValueError("no transport")
        self.links = [Link(t) for t in transports]
        self.clock = clock
        self.timing = timing
        self.stop = stop if stop is not None else threading.Event()  # set: end what runs (SIGINT/SIGTERM)
        self.anchors: dict[int, AnchorInfo] = {}
        self._token = int(clock.now() * 1000.0) & 0xFF  # tokens differ from a previous run's

    def open(self) -> "AnchorManager":
        for link in self.links:
            link.transport.open()
        return self

    def close(self) -> None:
        for link in self.links:
            link.transport.close()

    def __enter__(self) -> "AnchorManager":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def decode_errors(self) -> dict[str, int]:
        out: Counter = Counter()
        for link in self.links:
            out.update(link.errors)
            out.update({k: v for k, v in link.decoder.counters.items() if k in defs.ERRORS and v})
        return dict(sorted(out.items()))

    # -- hearing ---------------------------------------------------------------------------
    @property
    def ended(self) -> bool:
        """Every link is a finite input that has ended: nothing more can be heard."""
        return all(link.ended for link in self.links)

    @property
    def stopping(self) -> bool:
        return self.stop.is_set() or self.ended

    def _read(self) -> list[Heard]:
        """One read of every link (``slice_s`` in all), noting what each anchor sent."""
        out: list[Heard] = []
        live = [link for link in self.links if not link.ended]
        if not live:
            return out
        each = self.timing.slice_s / len(live)
        for link in live:
            out += link.read(each)
        for h in out:
            a = self.anchors.get(h.anchor_id)
            if a is None:
                a = self.anchors[h.anchor_id] = AnchorInfo(h.anchor_id, h.link, h.t, h.t)
            a.link, a.last_t = h.link, h.t
            if isinstance(h.message, Status):
                a.status = h.message
                a.statuses += 1
            elif isinstance(h.message, RssiReport):
                a.reports += 1
                peer = h.message.peer
                if peer is not None:
                    a.peers.add(peer)
                else:
                    a.beacons.add(h.message.beacon)
                a.last_flags = h.message.flags
        return out

    def listen(self, seconds: float, until: Iterable[int] | None = None) -> dict[int, AnchorInfo]:
        """Every anchor heard within ``seconds``; with ``until``, stop as soon as each of
        those anchors has sent a whole STATUS."""
        want = set(until) if until is not None else None
        end = self.clock.monotonic() + seconds
        while self.clock.monotonic() < end and not self.stopping:
            self._read()
            if want is not None and all(a in self.anchors and self.anchors[a].status is not None for a in want):
                break
        return dict(sorted(self.anchors.items()))

    # -- changing --------------------------------------------------------------------------
    def _next_token(self) -> int:
        self._token = (self._token + 1) & 0xFF
        return self._token

    def configure(self, targets: dict[int, AnchorConfig]) -> dict[int, Outcome]:
        """Set each anchor's configuration; verified (see the module doc)."""
        jobs = {}
        for a, cfg in sorted(targets.items()):
            if not cfg.is_valid():
                raise ValueError(f"anchor {a}: invalid configuration ({describe_config(cfg)})")
            job = _Job(a, "configuration", cfg.hash, [ConfigSet(self._next_token(), *_config_fields(cfg))])
            job.config = cfg
            jobs[a] = job
        return self._run(jobs, can_ok=True)

    def set_filters(self, targets: dict[int, Sequence[BeaconFilter]]) -> dict[int, Outcome]:
        """Set each anchor's whole beacon filter table (every entry); verified."""
        jobs = {}
        for a, table in sorted(targets.items()):
            table = tuple(table)
            if len(table) != defs.BEACON_SLOTS or not all(f.is_valid() for f in table):
                raise ValueError(f"anchor {a}: a filter table is {defs.BEACON_SLOTS} valid entries")
            msgs = [f.set_message(self._next_token(), i) for i, f in enumerate(table)]
            jobs[a] = _Job(a, "filter table", table_hash(table), msgs)
        return self._run(jobs, can_ok=False)

    def _links_for(self, a: int, can_ok: bool) -> list[Link]:
        """Where anchor ``a`` was heard, else every link that can reach it."""
        usable = [ln for ln in self.links if ln.can_send and (can_ok or not ln.can)]
        info = self.anchors.get(a)
        if info is not None:
            heard = [ln for ln in usable if ln.name == info.link]
            if heard:
                return heard
        return usable

    def _run(self, jobs: dict[int, _Job], can_ok: bool) -> dict[int, Outcome]:
        t = self.timing
        start = self.clock.monotonic()
        for job in jobs.values():
            if not self._links_for(job.anchor_id, can_ok):
                job.end(False, "no link can reach it" + ("" if can_ok else " (FILTER_SET has no CAN mapping: "
                                                                          "use the anchor's UART)"))
        while True:
            now = self.clock.monotonic()
            open_jobs = [j for j in jobs.values() if j.outcome is None]
            if not open_jobs:
                break
            if now - start >= t.total_timeout_s or self.stopping:
                for j in open_jobs:
                    stage = "its STATUS" if j.acked_at is not None else "its acks"
                    why = ("stopped" if self.stop.is_set() else "the input ended" if self.ended else
                           f"not done within the total timeout ({t.total_timeout_s:g} s)")
                    j.end(False, f"{why}: waiting for {stage}")
                break
            for j in open_jobs:
                self._send_due(j, now, can_ok)
            for h in self._read():
                hit = jobs.get(h.anchor_id)
                if hit is not None and hit.outcome is None:
                    self._heard(hit, h.message, self.clock.monotonic())
        return {a: _ended(j) for a, j in jobs.items()}

    def _send_due(self, j: _Job, now: float, can_ok: bool) -> None:
        t = self.timing
        if j.confirmed_at is not None:
            if now - j.confirmed_at >= t.status_timeout_s:
                self._done(j, f", no report within {t.status_timeout_s:g} s to check")
            return
        if j.acked_at is not None:
            if now - j.acked_at >= t.status_timeout_s:
                j.end(False, f"acked, but sent no STATUS within {t.status_timeout_s:g} s to confirm the {j.what}")
            return
        for p in j.pending.values():
            if now - p.sent_at < t.reply_timeout_s:
                continue
            if p.sends >= t.retries:
                name = "CONFIG_ACK" if isinstance(p.msg, ConfigSet) else "FILTER_ACK"
                j.end(False, f"no {name} after {p.sends} tries ({p.sends * t.reply_timeout_s:g} s)")
                return
            for link in self._links_for(j.anchor_id, can_ok):
                link.send(p.msg, j.anchor_id)
            p.sends += 1
            p.sent_at = now
            j.sends += 1

    def _heard(self, j: _Job, m, now: float) -> None:
        if isinstance(m, (ConfigAck, FilterAck)) and m.token in j.pending and j.acked_at is None:
            sent = j.pending.pop(m.token).msg
            kind = "CONFIG_ACK" if isinstance(m, ConfigAck) else "FILTER_ACK"
            if m.result != defs.ACK_OK:
                what = ACK_RESULTS.get(m.result, f"result {m.result}")
                entry = f" of entry {sent.index}" if isinstance(m, FilterAck) else ""
                j.end(False, f"{kind}{entry}: {what}")
                return
            if isinstance(m, FilterAck) and m.index != sent.index:
                j.end(False, f"FILTER_ACK names entry {m.index}, we set entry {sent.index}")
                return
            new_hash = m.config_hash if isinstance(m, ConfigAck) else m.filter_hash
            if not j.pending:  # the last ack: the whole change is in
                j.acked_hash = new_hash
                if new_hash != j.expect_hash:
                    j.end(False, f"{kind} reports {j.what} hash 0x{new_hash:04x}, expected 0x{j.expect_hash:04x}")
                    return
                j.acked_at = now
            return
        if j.acked_at is None:
            return
        if isinstance(m, RssiReport) and j.config is not None and not j.report_checked:
            # In order on its link: sent after the ack, so made with the new offset.
            j.report_checked = True
            want = j.config.offset_q8 != 0
            if bool(m.flags & defs.FLAG_CALIBRATED) != want:
                j.end(False, f"its first report after the change has CALIBRATED={int(not want)}, expected {int(want)}")
            elif j.confirmed_at is not None:
                self._done(j, ", a report checked")
            return
        if isinstance(m, Status) and j.confirmed_at is None:
            got = m.config_hash if j.config is not None else m.filter_hash
            if j.config is None and m.filter_slots == 0:
                return  # a CAN STATUS without its third part, or a version-1 anchor: no table hash
            j.status_hash = got
            if got != j.expect_hash:
                j.end(False, f"its next STATUS reports {j.what} hash 0x{got:04x}, expected 0x{j.expect_hash:04x}",
                      got)
                return
            # The last report mode is "silent": nothing to wait for then.
            wait_report = j.config is not None and j.config.report_mode != defs.VALID_REPORT_MODE_MAX
            if wait_report and not j.report_checked:
                j.confirmed_at = now
            else:
                self._done(j, ", a report checked" if j.report_checked else "")

    @staticmethod
    def _done(j: _Job, tail: str) -> None:
        detail = describe_config(j.config) if j.config is not None else f"hash 0x{j.status_hash:04x}"
        j.end(True, f"{j.what} set ({detail}): acked and confirmed by its STATUS{tail}", j.status_hash)


def _config_fields(c: AnchorConfig) -> tuple[int, int, int, int, int]:
    return c.offset_q8, c.alpha_q8, c.spike_db, c.report_mode, c.decimation


__all__ = ["AnchorManager", "AnchorInfo", "Outcome", "Timing", "Link", "offset_config", "describe_config"]
