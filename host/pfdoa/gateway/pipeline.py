"""The gateway pipeline: chunks -> decoded messages -> readings -> anchor sets -> estimates.

* :class:`Localizer` turns anchor sets into estimates and output records (shared by
  ``pfdoa gateway`` and ``pfdoa replay``), composing the odometry received in between.
* :class:`Gateway` decodes chunks (one protocol ``StreamDecoder`` per byte-stream source,
  ``decode_can`` per CAN frame), feeds the reassembler, and counts everything in
  :class:`~pfdoa.gateway.health.Health`.
* :class:`Runner` reads every transport in its own thread into one bounded queue
  (excess chunks are dropped and counted), reopens failed devices with exponential
  backoff, polls the reassembler's timers, prints the health line, and stops cleanly on
  SIGINT/SIGTERM or when every finite source has ended.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from typing import Callable, Iterable, Sequence

import numpy as np

from pfdoa.estimators.base import Estimator, Observation, Odometry
from pfdoa.gateway.config import GatewayConfig
from pfdoa.gateway.health import Health
from pfdoa.gateway.reassembly import AnchorSet, Reading, SeqReassembler, WindowGrouper
from pfdoa.gateway.transports import Chunk, CaptureWriter, Transport, TransportEOF, TransportError
from pfdoa.odometry import compose
from pfdoa.output import Record, Writer

log = logging.getLogger(__name__)

MAX_DECODERS = 64  # byte-stream sources (ports, capture source names) decoded at once
ODOM_QUEUE = 10000  # live odometry increments waiting for the next estimate
ODOM_FRESH_S = 1.0  # odometry silent longer than this is gone: estimate without it
QUEUE_WAIT_S = 0.05  # the main loop's longest wait for a chunk
# Off the CPU this much longer than the loop's own waits: the process was not scheduled.
STALL_S = 0.05


def make_grouper(anchor_ids: Sequence[int], cfg: GatewayConfig, mode: str | None = None,
                 window_s: float | None = None, live: bool = True):
    """The reassembler for ``mode`` ("seq" or "window"; default from the config)."""
    mode = mode or cfg.mode
    if mode == "seq":
        return SeqReassembler(anchor_ids, set_timeout_s=cfg.set_timeout_s, max_open_sets=cfg.max_open_sets,
                              stale_after_s=cfg.stale_after_s)
    return WindowGrouper(anchor_ids, window_s=window_s or cfg.window_s, stale_after_s=cfg.stale_after_s)


class ArrayOdometry:
    """Recorded increments (t, dx, dy, dtheta arrays): ``take(t)`` composes those with time <= t."""

    def __init__(self, t: np.ndarray, dx: np.ndarray, dy: np.ndarray, dtheta: np.ndarray) -> None:
        self.t, self.dx, self.dy, self.dth = t, dx, dy, dtheta
        self.i = 0

    def take(self, t: float) -> Odometry | None:
        j = int(np.searchsorted(self.t, t, side="right"))
        if j <= self.i:
            return None
        total = Odometry()
        for k in range(self.i, j):
            total = compose(total, Odometry(float(self.dx[k]), float(self.dy[k]), float(self.dth[k])))
        self.i = j
        return total


class LiveOdometry:
    """Increments arriving as ``t,dx,dy,dtheta`` text lines from a file, FIFO or pipe.

    A reader thread parses lines into a bounded queue; ``take`` composes everything
    received since the previous call. A regular file is followed as it grows (like
    ``tail -f``); a FIFO is reopened when its writer closes it. Bad lines are counted and
    skipped; increments beyond the queue bound are dropped and counted.

    Odometry and RSSI arrive on separate channels, read by separate threads, so whether a
    set finds the increment sent just before its reports is up to the scheduler. While
    the stream is alive (a line within ``fresh_s``), ``take`` therefore returns zero
    motion rather than None when nothing new has arrived: the increment still in flight
    is composed into the next set's, and the estimator keeps its odometry motion model
    instead of switching to the one without odometry for that step.
    """

    def __init__(self, path: str, fresh_s: float = ODOM_FRESH_S) -> None:
        import os
        import stat

        from pfdoa.errors import InputError

        self.path = path
        self.fresh_s = float(fresh_s)
        self._last_line = -math.inf  # time.monotonic() of the newest increment
        try:
            self._follow = stat.S_ISREG(os.stat(path).st_mode)
        except OSError as exc:
            raise InputError(f"--odom {path}: cannot read: {exc.strerror or exc}") from None
        self._q: deque[Odometry] = deque()
        self._lock = threading.Lock()
        self.bad_lines = 0
        self.lines = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._run, name="odom", daemon=True)
        self._thread.start()

    def _parse(self, line: str) -> None:
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("t,"):
            return
        try:
            _, dx, dy, dth = (float(v) for v in s.split(",")[:4])
            if not all(math.isfinite(v) for v in (dx, dy, dth)):
                raise ValueError
        except ValueError:
            self.bad_lines += 1
            return
        with self._lock:
            self.lines += 1
            self._last_line = time.monotonic()
            if len(self._q) >= ODOM_QUEUE:
                self.dropped += 1
                self._q.popleft()
            self._q.append(Odometry(dx, dy, dth))

    def _run(self) -> None:
        while True:
            try:
                fh = open(self.path, encoding="utf-8", errors="replace")
            except OSError as exc:
                log.warning("--odom %s: %s", self.path, exc)
                return
            with fh:
                partial = ""
                while True:
                    line = fh.readline(4096)
                    if not line:
                        if not self._follow:
                            break  # FIFO writer closed: reopen and wait for the next one
                        time.sleep(0.05)
                        continue
                    if not line.endswith("\n") and len(line) < 4096:
                        partial += line  # a line still being written
                        continue
                    self._parse(partial + line)
                    partial = ""

    def take(self, t: float) -> Odometry | None:
        with self._lock:
            items = list(self._q)
            self._q.clear()
            alive = time.monotonic() - self._last_line <= self.fresh_s
        if not items:
            return Odometry() if alive else None
        total = Odometry()
        for inc in items:
            total = compose(total, inc)
        return total


class Localizer:
    """Anchor sets -> estimator -> output records."""

    def __init__(self, site, estimator: Estimator, writer: Writer | None, odometry=None,
                 health: Health | None = None, tolerate_errors: bool = True) -> None:
        self.anchor_ids = site.anchor_ids
        self.tolerate_errors = tolerate_errors  # live: count and go on; offline: raise
        self.estimator = estimator
        self.writer = writer
        self.odometry = odometry
        self.health = health or Health()
        self.records: list[Record] | None = None  # set to a list to keep records (tests)

    def handle(self, s: AnchorSet) -> Record | None:
        obs = Observation(s.t, s.vector(self.anchor_ids), s.count_vector(self.anchor_ids))
        odom = self.odometry.take(s.t) if self.odometry is not None else None
        try:
            est = self.estimator.step(obs, odom)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            if not self.tolerate_errors:
                raise
            # One bad set must not stop a live gateway; count it and go on.
            self.health.estimator_errors += 1
            log.warning("estimator failed on set at t=%.3f: %s", s.t, exc)
            return None
        self.health.estimates += 1
        rec = Record(
            t=s.t, x=est.x, y=est.y, sigma=est.sigma, doa=est.doa, seq=s.seq,
            anchors=est.anchors_used or s.anchors, missing=s.missing, stale=s.stale, rebooted=s.rebooted,
            r95=est.r95, cov=est.cov, lost=est.lost,
        )
        if self.writer is not None:
            self.writer.write(rec)
        if self.records is not None:
            self.records.append(rec)
        return rec

    def handle_all(self, sets: Iterable[AnchorSet]) -> None:
        for s in sets:
            self.handle(s)


class Gateway:
    """Decode chunks and reassemble; hand finished sets to a callback."""

    def __init__(self, grouper, on_set: Callable[[AnchorSet], object], health: Health | None = None,
                 capture: CaptureWriter | None = None) -> None:
        from pfdoa.protocol import defs, messages
        from pfdoa.protocol.can import decode_can
        from pfdoa.protocol.uart import ANCHOR_TO_HOST, StreamDecoder

        self._msgs = messages
        self._defs_hash = defs.DEFS_HASH
        self._errors = frozenset(defs.ERRORS)
        self._decode_can = decode_can
        self._new_decoder = lambda: StreamDecoder(types=ANCHOR_TO_HOST)
        self.grouper = grouper
        self.on_set = on_set
        self.health = health or Health()
        self.capture = capture
        self._decoders: dict[str, object] = {}
        self._dec_errors: dict[str, dict[str, int]] = {}
        self._status_a: dict[int, object] = {}  # CAN STATUS_A waiting for its STATUS_B

    def _decoder(self, source: str):
        dec = self._decoders.get(source)
        if dec is None and len(self._decoders) < MAX_DECODERS:
            dec = self._decoders[source] = self._new_decoder()
            self._dec_errors[source] = {}
        return dec

    def feed(self, chunk: Chunk) -> None:
        h = self.health
        h.chunks += 1
        h.bytes += len(chunk.data)
        if self.capture is not None:
            self.capture.write(chunk)
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
            d = self._decode_can(chunk.can_id, chunk.data)
            if isinstance(d, str):
                h.error(d)
            else:
                self._message(d.anchor_id, d.message, chunk.t)

    def _sync_errors(self, source: str, dec) -> None:
        prev = self._dec_errors[source]
        # Every error the StreamDecoder counts discards at least one byte, so while
        # bytes_discarded stands still there is nothing new to copy (the common case: this
        # runs once per chunk, and scanning every counter was ~20 % of the UART path).
        discarded = dec.counters["bytes_discarded"]
        if discarded == prev.get("bytes_discarded", 0):
            return
        prev["bytes_discarded"] = discarded
        for kind, n in dec.counters.items():
            if kind in self._errors and n != prev.get(kind, 0):
                self.health.error(kind, n - prev.get(kind, 0))
                prev[kind] = n

    def _message(self, anchor_id: int, m, t: float) -> None:
        p = self._msgs
        h = self.health
        h.frames += 1
        if isinstance(m, p.RssiReport):
            h.reports += 1
            r = Reading(anchor_id, m.rssi_q8 / 256.0, t, m.seq, m.tick_ms, m.flags)
            for s in self.grouper.push(r):
                self.on_set(s)
        elif isinstance(m, (p.Status, p.StatusA, p.StatusB)):
            h.status += 1
            if isinstance(m, (p.Status, p.StatusA)) and self.grouper.tracker.known(anchor_id):
                self.grouper.tracker.uptime(anchor_id, m.uptime_s, t)
            if isinstance(m, (p.Status, p.StatusB)) and m.defs_hash != self._defs_hash:
                if anchor_id not in h.schema_mismatch:
                    h.schema_mismatch.add(anchor_id)
                    log.warning("anchor %d: message definitions differ (defs_hash 0x%04x, ours 0x%04x)",
                                anchor_id, m.defs_hash, self._defs_hash)
        elif isinstance(m, p.ConfigAck):
            h.acks += 1
            log.info("anchor %d: config ack token=%d result=%d", anchor_id, m.token, m.result)

    def resume(self, now: float) -> None:
        """We were stalled until ``now`` (see :meth:`AnchorTracker.resume`)."""
        self.grouper.tracker.resume(now)

    def poll(self, now: float) -> None:
        for s in self.grouper.poll(now):
            self.on_set(s)

    def finish(self) -> None:
        for s in self.grouper.flush():
            self.on_set(s)


class _Reader(threading.Thread):
    """Reads one transport into the shared queue; reopens it with backoff when it fails."""

    def __init__(self, transport: Transport, out: "queue.Queue", health: Health, stop: threading.Event,
                 backoff: tuple[float, float]) -> None:
        super().__init__(name=f"read:{transport.name}", daemon=True)
        self.transport = transport
        self.out = out
        self.health = health
        self.stop = stop
        self.backoff = backoff
        self.done = False

    def _put(self, item) -> None:
        try:
            self.out.put_nowait(item)
        except queue.Full:
            self.health.queue_drops += 1

    def run(self) -> None:
        t = self.transport
        delay = self.backoff[0]
        opened_once = False
        try:
            while not self.stop.is_set():
                if not t.is_open:
                    try:
                        t.open()
                    except TransportError as exc:
                        if t.finite:
                            log.error("%s", exc)
                            return
                        log.warning("%s; retrying in %.1f s", exc, delay)
                        self.stop.wait(delay)
                        delay = min(delay * 2, self.backoff[1])
                        continue
                    if opened_once:
                        self.health.reconnects[t.name] += 1
                        log.info("%s: reopened", t.name)
                    opened_once = True
                    delay = self.backoff[0]
                try:
                    for c in t.read(0.2):
                        self._put(c)
                except TransportEOF:
                    return
                except TransportError as exc:
                    log.warning("%s; closing and reopening", exc)
                    t.close()
        finally:
            t.close()
            self.done = True
            # The sentinel must arrive even when the queue is full.
            while True:
                try:
                    self.out.put(None, timeout=0.1)
                    break
                except queue.Full:
                    if self.stop.is_set():
                        break


class Runner:
    """Run transports through a :class:`Gateway` until stopped or all finite sources end."""

    def __init__(self, transports: list[Transport], gateway: Gateway, cfg: GatewayConfig,
                 health_out: Callable[[str], None] | None = None, clock: Callable[[], float] = time.time,
                 replay_clock: bool = False) -> None:
        self.transports = transports
        self.gateway = gateway
        self.cfg = cfg
        self.health_out = health_out
        self.clock = clock
        self.replay_clock = replay_clock  # timers follow chunk times (capture replay)
        self.stop = threading.Event()
        self.queue: queue.Queue = queue.Queue(maxsize=cfg.queue_size)

    def run(self) -> None:
        h = self.gateway.health
        readers = [
            _Reader(t, self.queue, h, self.stop, (self.cfg.reconnect_min_s, self.cfg.reconnect_max_s))
            for t in self.transports
        ]
        for r in readers:
            r.start()
        running = len(readers)
        period = self.cfg.health_interval_s
        next_health = time.monotonic() + period if period > 0 else math.inf
        # Capture replay: the timers run on the recorded times, from the first chunk on.
        now = -math.inf if self.replay_clock else self.clock()
        h.start(time.monotonic())
        wall, cpu = time.monotonic(), time.thread_time()
        try:
            while running and not self.stop.is_set():
                try:
                    item = self.queue.get(timeout=QUEUE_WAIT_S)
                except queue.Empty:
                    item = ...
                if item is None:
                    running -= 1
                elif item is not ...:
                    self.gateway.feed(item)
                    if self.replay_clock:
                        now = max(now, item.t)
                if not self.replay_clock:
                    now = self.clock()
                    # A scheduler stall (a loaded machine, a suspended process) left the
                    # readers' bytes unread in the kernel: the timers must not take it for
                    # silence, or every open set times out and every anchor turns stale.
                    w, c = time.monotonic(), time.thread_time()
                    if (w - wall) - (c - cpu) > QUEUE_WAIT_S + STALL_S:
                        self.gateway.resume(now)
                    wall, cpu = w, c
                if now > -math.inf:
                    self.gateway.poll(now)
                if time.monotonic() >= next_health:
                    next_health = time.monotonic() + period
                    if self.health_out:
                        self.health_out(h.line(time.monotonic(), self.gateway.grouper))
        finally:
            self.stop.set()
            # Drain what the readers already queued so a capture replay is complete.
            while True:
                try:
                    item = self.queue.get_nowait()
                except queue.Empty:
                    break
                if item is not None and item is not ...:
                    self.gateway.feed(item)
            for r in readers:
                r.join(timeout=2.0)
            self.gateway.finish()
