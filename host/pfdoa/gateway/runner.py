"""The runner: every input in its own reader thread, one queue, one loop that drives the gateway.

:class:`Runner` reads each transport in a :class:`_Reader` thread into one bounded queue,
reopens failed devices with exponential backoff, feeds chunks to the
:class:`~pfdoa.gateway.decoding.Gateway` and odometry increments to the localizer's
:class:`~pfdoa.odometry.OdometryBuffer`, runs the timers, writes the capture, prints the
health line, and stops cleanly on SIGINT/SIGTERM (``stop``), after ``duration_s``, or when
every finite input has ended.

**When the timers run.** Timers (set timeouts, staleness, the wait for odometry) must never
fire because input is merely waiting: in the queue, in a kernel buffer, or because this
process was not scheduled. So timer time advances only with input that has been
processed. Live (``stream_timers=False``), each reader reports with what it puts in the
queue the time up to which it has read everything that arrived (the transport's
``caught_up_to``: stamped before it looked and found nothing more waiting); timer time is
the least of those over the running inputs, taken as the loop processes them. A lossless,
in-order stream therefore never times a set out, however slow the machine. A reader whose
device is gone says so every ``IDLE_S`` (a vanished port holds nothing back).

**Devices that are not there.** A device that was open and fails (a cable pulled) is
reopened with exponential backoff, each attempt on the log. A device that this run has not
opened yet and that is not present at all (:class:`TransportAbsent`: no such path, no such
interface) is waited for: its open is retried with the same backoff, and "waiting for
DEVICE (not present)" is said once every ``WAITING_LINE_S``; after ``wait_for_device_s``
(``pfdoa gateway --wait-for-device``; 0: at once) the run ends with that error (exit 2).

From a capture or a simulator's timed stream (``stream_timers=True``) timer time is the
stream's: the ``T`` lines of a v2 capture (where the live gateway ran them), or each
chunk's time after it in a v1 stream. The output is then a function of the stream alone.

Readings that name their beacon (ESPresense nodes over MQTT: batches of
:class:`~pfdoa.gateway.beacons.BeaconReading`, one queue item per read) go to the
gateway's tracker of named beacons (``Gateway.push_beacon``). Their input's
``caught_up_to`` is its receive time like any live input's, unless the input carries
**message time** (``message_time``: the publisher put a time into every message, as the
fleet simulator does): then the timers run to each reading's time right after it, as
for a v1 stream, and the estimates are a function of the messages and their order alone,
not of when they arrived. Only plausible times count: a reading far from the gateway's
clock of admitted message times is refused and counted per device, and moves nothing
(:mod:`pfdoa.gateway.msgtime`). Message time is not mixed with live inputs on the host clock
(``pfdoa gateway`` refuses the combination).

**What is lost.** A finite input (a file, a pipe, standard input, a capture) is never
dropped: its reader blocks when the queue is full. So does the reader of a live input
with its own bounded inbox (``buffered``: the MQTT inputs, the odometry inputs), which then counts per message
what it could not hold. Only a live device's reader drops chunks when the loop falls
behind (a device cannot be paused); they are counted (``queue_drops``) and said once on
the log. Whatever an input returned that the pipeline never got is told to it
(``Transport.lost``), so its counters hold every loss.

The capture (``--capture``) records every item the loop processes, in order, and a ``T``
line wherever the timers ran, so replaying it applies the same timer rule to the same
stamps and reproduces the output exactly. The ``sinks`` (``--record`` and the other robot
outputs, :mod:`pfdoa.sinks`) are told the same: every odometry increment the localizer
gets and every time the timers run (readings and records reach them through the gateway
and the localizer).

**Health.** One :class:`~pfdoa.gateway.health.HealthSampler` takes a snapshot every
``health_interval_s`` (on the clock's monotonic time): its line goes to ``health_out``
and the snapshot to the sinks (health JSON, the live view, the recording's diagnostics),
so all of them carry the same numbers (with the counters of the sinks that keep some while
running, ``outputs``, the localizer's odometry counters, and every input's own counters,
``inputs``); one more snapshot is taken at the end. With
``health_interval_s`` 0 no line is printed, but sinks still get a snapshot every
``SINK_HEALTH_S``. A snapshot is stamped with the host clock live, and with the stream's
time (the last item processed) from a capture or timed stream.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
from typing import Callable

from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import PfdoaError
from pfdoa.gateway.beacons import BeaconBatch, BeaconReading
from pfdoa.gateway.decoding import Gateway
from pfdoa.gateway.inputs.capture import CaptureWriter
from pfdoa.gateway.localizer import Localizer
from pfdoa.gateway.msgtime import MessageClock
from pfdoa.gateway.transports import (
    Chunk,
    OdomLine,
    TimeMark,
    Transport,
    TransportAbsent,
    TransportEOF,
    TransportError,
    TransportFatal,
)
from pfdoa.readings.config import GatewayConfig

log = logging.getLogger(__name__)

IDLE_S = 0.05  # a reader's longest read: an idle input says "nothing new" this often
WAITING_LINE_S = 60.0  # "waiting for DEVICE (not present)" is said this often (the open is retried meanwhile)
# Reads of a buffered input (its own bounded inbox) waiting in the queue at most: the
# backlog stays in the inbox, where it is bounded and counted per message, instead of
# filling the queue with queue_size batches of readings (tens of megabytes).
BUFFERED_AHEAD = 4
SINK_HEALTH_S = 1.0  # health period for the sinks when no health line is printed
_END = object()  # a reader's last item


class _Reader(threading.Thread):
    """Reads one transport into the shared queue; reopens it with backoff when it fails.

    Items are ``(index, item, caught_up_to)``; ``item`` None carries only the time, and
    ``_END`` is the reader's last. ``blocking``: the queue's back-pressure holds the reader
    (finite inputs); otherwise a full queue drops chunks, counted.
    """

    def __init__(self, index: int, transport: Transport, out: "queue.Queue", health, stop: threading.Event,
                 backoff: tuple[float, float], clock: Clock, blocking: bool, wait_for_device_s: float = math.inf
                 ) -> None:
        """A buffered transport's reader holds at most BUFFERED_AHEAD reads in the queue
        (``ahead``: the loop releases one for each it takes)."""
        super().__init__(name=f"read:{transport.name}", daemon=True)
        self.ahead = threading.Semaphore(BUFFERED_AHEAD) if transport.buffered else None
        self.index = index
        self.transport = transport
        self.out = out
        self.health = health
        self.stop = stop
        self.backoff = backoff
        self.clock = clock
        self.blocking = blocking
        self.wait_for_device_s = wait_for_device_s
        self.fatal: TransportError | None = None
        self._warned_drop = False

    def _put(self, item, mark: float | None) -> None:
        entry = (self.index, item, mark)
        if self.ahead is not None and item is not None:
            while not self.ahead.acquire(timeout=0.1):
                if self.stop.is_set():
                    self.transport.lost(item)  # the run stopped while it waited
                    return
        if self.blocking:
            while not self.stop.is_set():
                try:
                    self.out.put(entry, timeout=0.1)
                    return
                except queue.Full:
                    pass
            if item is not None:
                self.transport.lost(item)  # the run stopped while it waited
            return
        try:
            self.out.put_nowait(entry)
        except queue.Full:
            if item is not None:
                self.transport.lost(item)
                self.health.queue_drops += 1
                if not self._warned_drop:
                    self._warned_drop = True
                    log.warning("%s: the gateway falls behind this live input: chunks dropped (queue_drops)",
                                self.transport.name)

    def _idle(self, seconds: float) -> None:
        """Wait (the device is gone), saying every IDLE_S that nothing is held back."""
        end = self.clock.monotonic() + seconds
        while not self.stop.is_set():
            self._put(None, self.clock.now())
            left = end - self.clock.monotonic()
            if left <= 0:
                return
            self.clock.wait(self.stop, min(left, IDLE_S))

    def run(self) -> None:
        t = self.transport
        delay = self.backoff[0]
        opened_once = t.is_open
        absent_since: float | None = None  # never opened yet, its device not there: since when
        said = -math.inf
        try:
            while not self.stop.is_set():
                if not t.is_open:
                    try:
                        t.open()
                    except TransportFatal as exc:
                        self.fatal = exc
                        return
                    except TransportAbsent as exc:
                        if opened_once:  # it was there and went (a cable pulled): retried as below
                            log.warning("%s; retrying in %.1f s", exc, delay)
                            self._idle(delay)
                            delay = min(delay * 2, self.backoff[1])
                            continue
                        now = self.clock.monotonic()
                        absent_since = now if absent_since is None else absent_since
                        waited = now - absent_since
                        if waited >= self.wait_for_device_s:
                            self.fatal = TransportFatal(f"{exc} (--wait-for-device {self.wait_for_device_s:g})")
                            return
                        if now - said >= WAITING_LINE_S:
                            said = now
                            log.warning("waiting for %s (not present)", exc.device)
                        self._idle(min(delay, self.wait_for_device_s - waited))
                        delay = min(delay * 2, self.backoff[1])
                        continue
                    except TransportError as exc:
                        if t.finite:
                            self.fatal = exc
                            return
                        log.warning("%s; retrying in %.1f s", exc, delay)
                        self._idle(delay)
                        delay = min(delay * 2, self.backoff[1])
                        continue
                    if opened_once:
                        self.health.reconnects[t.name] += 1
                        log.info("%s: reopened", t.name)
                    opened_once = True
                    delay = self.backoff[0]
                try:
                    items = t.read(IDLE_S)
                except TransportEOF:
                    return
                except TransportFatal as exc:
                    self.fatal = exc
                    return
                except TransportError as exc:
                    log.warning("%s; closing and reopening", exc)
                    t.close()
                    continue
                mark = t.caught_up_to
                for i, it in enumerate(items):
                    self._put(it, mark if i == len(items) - 1 else None)
                if not items and mark is not None:
                    self._put(None, mark)
        finally:
            t.close()
            # The last item must arrive even when the queue is full.
            while True:
                try:
                    self.out.put((self.index, _END, None), timeout=0.1)
                    break
                except queue.Full:
                    if self.stop.is_set():
                        break


class Runner:
    """Run transports through a :class:`Gateway` until stopped or all finite inputs end."""

    def __init__(self, transports: list[Transport], gateway: Gateway, cfg: GatewayConfig, *,
                 localizer: Localizer | None = None, clock: Clock = SYSTEM,
                 health_out: Callable[[str], None] | None = None, stream_timers: bool = False,
                 capture: CaptureWriter | None = None, odometry: Transport | None = None,
                 duration_s: float | None = None, sinks=None, stop: threading.Event | None = None,
                 wait_for_device_s: float = math.inf) -> None:
        self.transports = transports
        self.gateway = gateway
        self.cfg = cfg
        self.localizer = localizer
        self.clock = clock
        self.health_out = health_out
        self.stream_timers = stream_timers
        # v2 captures say when the timers ran; chunks of other streams drive them.
        self.explicit_timers = stream_timers and bool(transports) and all(
            getattr(t, "explicit_timers", False) for t in transports)
        # Inputs stamped by their publisher (see the module doc): timers on those stamps, as
        # far as they are plausible (pfdoa.gateway.msgtime).
        self.message_time = not stream_timers and any(getattr(t, "message_time", False) for t in transports)
        if self.message_time and gateway.message_clock is None:
            gateway.message_clock = MessageClock(monotonic=clock.monotonic)
        self.capture = capture
        self.odometry = odometry
        self.duration_s = duration_s
        self.sinks = sinks  # a pfdoa.sinks Sink (Fanout), or None
        self.stop = stop if stop is not None else threading.Event()  # set: stop (SIGINT/SIGTERM, pfdoa.signals)
        self.wait_for_device_s = wait_for_device_s
        self.queue: queue.Queue = queue.Queue(maxsize=cfg.queue_size)
        self.timer = -math.inf  # timer time (see the module doc)
        self.error: PfdoaError | None = None  # a permanent input (or sink) error, raised by run()
        self.timer_polls = 0
        self.last_t = -math.inf  # time of the last item processed (a stream's time)
        # Over every beacon's grouper; named beacons' readings and tracker counters too.
        self.sampler = gateway.health.sampler(gateway.totals, getattr(gateway, "named", None))

    # -- the loop -------------------------------------------------------------------------
    def run(self) -> None:
        h = self.gateway.health
        backoff = (self.cfg.reconnect_min_s, self.cfg.reconnect_max_s)
        readers = [_Reader(i, t, self.queue, h, self.stop, backoff, self.clock, blocking=t.finite or t.buffered,
                           wait_for_device_s=self.wait_for_device_s)
                   for i, t in enumerate(self.transports)]
        odom_reader = None
        if self.odometry is not None:
            # An odometry input with its own inbox (a pipe, the ROS 2 subscription's bounded
            # history) waits for the loop, instead of losing increments of a burst.
            odom_reader = _Reader(len(readers), self.odometry, self.queue, h, self.stop, backoff, self.clock,
                                  blocking=self.odometry.finite or self.odometry.buffered)
        every = readers + ([odom_reader] if odom_reader else [])
        for r in every:
            r.start()
        running = {r.index for r in readers}
        marks: dict[int, float] = {}
        period = self.cfg.health_interval_s
        if not period > 0 and self.sinks is not None:
            period = SINK_HEALTH_S  # sampled for the sinks, not printed
        t0 = self.clock.monotonic()
        next_health = t0 + period if period > 0 else math.inf
        end = t0 + self.duration_s if self.duration_s else math.inf
        next_check = t0
        h.start(t0)
        self.sampler.start(t0)
        try:
            while running and not self.stop.is_set():
                try:
                    idx, item, mark = self.queue.get(timeout=IDLE_S)
                except queue.Empty:
                    idx = item = mark = None
                if item is _END:
                    if odom_reader is not None and idx == odom_reader.index:
                        self._odometry_ended()
                    else:
                        running.discard(idx)
                        marks.pop(idx, None)
                        fatal = readers[idx].fatal
                        if fatal is not None:
                            self.error = fatal
                            break
                elif item is not None:
                    self._taken(every, idx)
                    self._process(item)
                if not self.stream_timers:
                    if mark is not None and idx in running:
                        marks[idx] = max(marks.get(idx, -math.inf), mark)
                    if running and len(marks) == len(running):
                        self._advance(min(marks.values()))
                now = self.clock.monotonic()
                if now >= next_check:  # a sink's error that retrying cannot change ends the run
                    next_check = now + IDLE_S
                    fatal = getattr(self.sinks, "fatal", lambda: None)()
                    if fatal is not None:
                        self.error = fatal
                        break
                if now >= next_health:
                    next_health = now + period
                    self._health(now)
                if now >= end:
                    break
        finally:
            self.stop.set()
            # What the readers already queued is processed (all of it, for a finite input),
            # without running the timers: a replay of the capture does the same.
            self._drain(every)
            for r in every:
                r.join(timeout=2.0)
            self._drain(every)  # what a reader put between the first drain and its end
            getattr(self.sinks, "inputs_ended", lambda: None)()  # (a recording marks it)
            self.gateway.finish()
            if self.localizer is not None:
                self.localizer.finish()
            self._health(self.clock.monotonic())  # the last period, up to the end
        if self.error is not None:
            raise self.error

    def _drain(self, readers: list[_Reader]) -> None:
        while True:
            try:
                idx, item, _ = self.queue.get_nowait()
            except queue.Empty:
                return
            if item is not None and item is not _END:
                self._taken(readers, idx)
                self._process(item, drained=True)

    @staticmethod
    def _taken(readers: list[_Reader], idx: int) -> None:
        """The loop took one of reader ``idx``'s reads: a buffered one may put another."""
        ahead = readers[idx].ahead
        if ahead is not None:
            ahead.release()

    def _health(self, now: float) -> None:
        """One snapshot: its line to ``health_out`` (when lines are on), it to the sinks."""
        on_stream = self.stream_timers or self.message_time
        stamp = self.last_t if on_stream and math.isfinite(self.last_t) else self.clock.now()
        snap = self.sampler.sample(now, stamp)
        # sinks sit above the gateway: asked by duck typing (an object without the call has none)
        outputs: dict = getattr(self.sinks, "health_outputs", dict)()
        odometry = self.localizer.summary() if self.localizer is not None else {}
        inputs = {t.name: c for t in self.transports if (c := t.counters())}
        if outputs or odometry or inputs:
            snap = dataclasses.replace(snap, outputs=outputs, odometry=odometry, inputs=inputs)
        if self.health_out and self.cfg.health_interval_s > 0:
            self.health_out(snap.line())
        if self.sinks is not None:
            self.sinks.health(snap)

    def _process(self, item, drained: bool = False) -> None:
        if not self.message_time:  # on message time: the admitted times only (below)
            self.last_t = max(self.last_t, item.t)
        if self.localizer is not None:
            self.localizer.stamp_t = item.t
        if isinstance(item, Chunk):
            if self.capture is not None:
                self.capture.write(item)
            self.gateway.feed(item)
            if self.stream_timers and not self.explicit_timers and not drained:
                self._advance(item.t)
        elif isinstance(item, OdomLine):
            if self.capture is not None:
                self.capture.write(item)
            loc = self.localizer
            if loc is not None and loc.odometry is not None:
                if self.sinks is not None:
                    self.sinks.odometry(item)
                loc.odometry.add(item.t_odom, item.dx, item.dy, item.dtheta)
                loc.release(loc.now)
        elif isinstance(item, TimeMark):
            if self.explicit_timers and not drained:
                self._advance(item.t)
        elif isinstance(item, (BeaconBatch, BeaconReading)):
            batch = item.readings if isinstance(item, BeaconBatch) else [item]
            clock = self.gateway.message_clock
            for br in batch:
                self.gateway.push_beacon(br)
                if clock is not None and clock.now is not None:
                    # The timers follow the clock of admitted times, not each reading's own
                    # (an implausible one moved nothing); set back, they follow it back.
                    if clock.moved_back:
                        self.timer = -math.inf
                    self.last_t = clock.now if clock.moved_back else max(self.last_t, clock.now)
                    if not drained:
                        self._advance(clock.now)

    def _advance(self, t: float) -> None:
        """Run the timers at ``t`` (never backwards); recorded in the capture."""
        if not t > self.timer:
            return
        self.timer = t
        self.timer_polls += 1
        if self.capture is not None:
            self.capture.write(TimeMark(t))
        if self.sinks is not None:
            self.sinks.timer(t)
        if self.localizer is not None:
            self.localizer.stamp_t = t
            self.localizer.now = max(self.localizer.now, t)
        self.gateway.poll(t)
        if self.localizer is not None:
            self.localizer.release(t)

    def _odometry_ended(self) -> None:
        loc = self.localizer
        if loc is not None and loc.odometry is not None and self.odometry is not None and self.odometry.finite:
            loc.odometry.end()
            loc.release(loc.now)
