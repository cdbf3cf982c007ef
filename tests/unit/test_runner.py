"""The runner's timer rule, back-pressure and capture, on a fake clock (no test sleeps past
a production timer; the only real waits are hang guards for the runner's own threads)."""

from __future__ import annotations

import queue
import threading
import time

import pytest

from pfdoa.clock import FakeClock
from pfdoa.gateway.decoding import Gateway
from pfdoa.gateway.inputs.capture import CaptureReader, CaptureWriter
from pfdoa.gateway.runner import WAITING_LINE_S, Runner
from pfdoa.gateway.transports import (
    Chunk,
    OdomLine,
    Transport,
    TransportAbsent,
    TransportEOF,
    TransportFatal,
)
from pfdoa.odometry import OdometryBuffer
from pfdoa.protocol.uart import encode_uart
from pfdoa.readings.config import GatewayConfig
from pfdoa.readings.grouping import make_grouper

import gateway_feed as feed

CFG = GatewayConfig(set_timeout_s=0.1, stale_after_s=0.25, health_interval_s=0.0, queue_size=16)
FRAMES = {a: encode_uart(m, a) for a, m in feed.reports(0)}
NEXT = b"".join(encode_uart(m, a) for a, m in feed.reports(1))  # the next beacon, all anchors


class Scripted(Transport):
    """Reads only what the test hands it: ``data(bytes, caught_up)`` or ``idle()`` (it
    looked and nothing was waiting). Without a step a read returns nothing *and* claims
    nothing (the reader did not get to look: a stalled process)."""

    def __init__(self, clock: FakeClock, finite: bool = False) -> None:
        super().__init__(clock)
        self.name = "scripted"
        self.finite = finite
        self.steps: queue.Queue = queue.Queue()

    def data(self, payload: bytes, caught_up: bool = True) -> None:
        self.steps.put(("data", payload, caught_up))

    def idle(self) -> None:
        self.steps.put(("idle",))

    def end(self) -> None:
        self.steps.put(("end",))

    def _open(self) -> None:
        pass

    def _read(self, timeout: float):
        try:
            step = self.steps.get(timeout=min(timeout, 0.01))
        except queue.Empty:
            return []
        now = self.clock.now()
        if step[0] == "end":
            raise TransportEOF(self.name)
        if step[0] == "idle":
            self.caught_up_to = now
            return []
        if step[2]:
            self.caught_up_to = now
        return [Chunk(self.name, now, step[1])]

    def _close(self) -> None:
        pass


def until(cond, what: str, hang_s: float = 20.0) -> None:
    end = time.monotonic() + hang_s
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f"hang guard: {what}")
        time.sleep(0.001)


@pytest.fixture
def rig():
    clock = FakeClock(start=1_700_000_000.0)
    sets = []
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), sets.append)
    src = Scripted(clock)
    runner = Runner([src], gw, CFG, clock=clock)
    th = threading.Thread(target=runner.run, daemon=True)
    th.start()
    yield clock, src, runner, gw, sets
    runner.stop.set()
    th.join(5.0)
    assert not th.is_alive()


def test_input_waiting_unread_never_times_a_set_out(rig):
    """Half a beacon's reports are read; then the process stalls for 10 s (far beyond
    set_timeout_s and stale_after_s) while the anchors go on sending into the kernel
    buffer; the reader then reads that backlog (more is waiting: not caught up), then the
    last bytes. Both sets leave complete, nothing turns stale: the timers never ran ahead of
    what had been read, although the backlog carries the stall in its stamps."""
    clock, src, runner, gw, sets = rig
    src.data(FRAMES[0] + FRAMES[1])
    until(lambda: gw.health.chunks == 1 and runner.timer == clock.now(), "first half")
    t0 = clock.now()
    clock.advance(10.0)  # the stall: nobody read anything, nothing was claimed
    src.data(FRAMES[2], caught_up=False)
    until(lambda: gw.health.chunks == 2, "backlog")
    assert runner.timer == t0 and sets == []
    src.data(FRAMES[3] + NEXT)
    until(lambda: len(sets) == 2, "the sets")
    assert [(s.seq, s.reason, s.stale) for s in sets] == [(0, "complete", ()), (1, "complete", ())]
    assert runner.timer == t0 + 10.0
    assert all(s.stale_events == 0 for s in gw.grouper.tracker.all_stats().values())
    assert gw.grouper.counters.timeouts == 0


def test_timers_follow_the_clock_only_while_caught_up(rig):
    """Caught up and idle, the timers follow the clock: half a set times out exactly once
    set_timeout_s has passed on it, and the anchors turn stale after stale_after_s."""
    clock, src, runner, gw, sets = rig
    src.data(FRAMES[0] + FRAMES[1])
    until(lambda: gw.health.chunks == 1, "half a set")
    t0 = clock.now()
    clock.advance(0.09)
    src.idle()
    until(lambda: runner.timer == t0 + 0.09, "idle mark")
    assert sets == []  # 90 ms < set_timeout_s
    clock.advance(0.02)
    src.idle()
    until(lambda: bool(sets), "timeout")
    assert runner.timer == pytest.approx(t0 + 0.11) and sets[0].reason == "timeout" and sets[0].missing == (2, 3)
    assert gw.grouper.tracker.stale_ids() == ()
    clock.advance(0.2)  # 0.31 s since the last report > stale_after_s
    src.idle()
    until(lambda: gw.grouper.tracker.stale_ids() == (0, 1, 2, 3), "stale")


def test_a_finite_input_is_never_dropped():
    """10,000 chunks through a 16-item queue: the reader waits for the loop (back-pressure)."""
    clock = FakeClock()
    src = Scripted(clock, finite=True)
    for k in range(10_000):
        src.data(FRAMES[k % 4])
    src.end()
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), lambda s: None)
    Runner([src], gw, CFG, clock=clock).run()
    assert gw.health.chunks == 10_000 and gw.health.queue_drops == 0 and gw.health.reports == 10_000


class Burst(Transport):
    """A live device: one chunk, then (once the loop is busy with it) a burst of chunks."""

    finite = False

    def __init__(self, clock, busy: threading.Event, n: int) -> None:
        super().__init__(clock)
        self.name = "burst"
        self.busy = busy
        self.n = n
        self.reads = 0

    def _open(self) -> None:
        pass

    def _read(self, timeout: float):
        self.reads += 1
        if self.reads == 1:
            return [Chunk(self.name, self.clock.now(), FRAMES[0])]
        if self.reads == 2:
            until(self.busy.is_set, "loop busy")
            return [Chunk(self.name, self.clock.now(), FRAMES[1]) for _ in range(self.n)]
        time.sleep(0.001)
        return []

    def _close(self) -> None:
        pass


def test_a_live_device_sheds_load_counted():
    """While the loop is busy, a live device's chunks beyond the queue are dropped and
    counted: exactly the burst minus what the queue holds."""
    clock = FakeClock()
    busy, go = threading.Event(), threading.Event()

    class SlowGateway(Gateway):
        def feed(self, chunk):
            if not busy.is_set():
                busy.set()
                until(go.is_set, "released")
            super().feed(chunk)

    gw = SlowGateway(make_grouper(tuple(feed.ANCHORS), CFG), lambda s: None)
    src = Burst(clock, busy, 100)
    runner = Runner([src], gw, CFG, clock=clock)
    th = threading.Thread(target=runner.run, daemon=True)
    th.start()
    until(lambda: src.reads >= 3, "burst read")
    go.set()
    until(lambda: gw.health.chunks == 1 + CFG.queue_size, "queue drained")
    runner.stop.set()
    th.join(5.0)
    assert gw.health.queue_drops == 100 - CFG.queue_size


class OdomBurst(Transport):
    """A live odometry input with its own bounded inbox (``buffered``, as the ROS 2
    subscription): ``n`` increments in reads of 50, as fast as the reader takes them."""

    finite = False
    buffered = True

    def __init__(self, clock, n: int) -> None:
        super().__init__(clock)
        self.name = "odom-burst"
        self.n = n
        self.sent = 0
        self.lost_items = 0

    def _open(self) -> None:
        pass

    def _read(self, timeout: float):
        if self.sent >= self.n:
            time.sleep(0.001)
            return []
        k = range(self.sent, min(self.sent + 50, self.n))
        self.sent = k.stop
        return [OdomLine(self.clock.now(), 100.0 + 0.01 * i, 0.001, 0.0, 0.0) for i in k]

    def lost(self, item) -> None:
        self.lost_items += 1

    def _close(self) -> None:
        pass


class OdomOnly:
    """The localizer's part the runner drives with odometry: its buffer."""

    def __init__(self) -> None:
        self.odometry = OdometryBuffer()
        self.now = 0.0
        self.stamp_t = 0.0

    def release(self, now: float) -> None:
        pass

    def finish(self) -> None:
        pass

    def summary(self) -> dict:
        return {"lines": self.odometry.lines}


def test_a_buffered_odometry_input_waits_for_a_slow_loop_and_loses_nothing():
    """500 increments through a 16-item queue while every one is slow to process (a
    recording sink): the reader waits; every increment reaches the buffer, none is dropped."""
    clock = FakeClock()

    class SlowSink(Recorder):
        def odometry(self, inc):
            time.sleep(0.0005)
            super().odometry(inc)

    loc, sink = OdomOnly(), SlowSink()
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), lambda s: None)
    src = Scripted(clock)
    odom = OdomBurst(clock, 500)
    runner = Runner([src], gw, CFG, clock=clock, localizer=loc, odometry=odom, sinks=sink)
    th = threading.Thread(target=runner.run, daemon=True)
    th.start()
    until(lambda: loc.odometry.lines == 500 or odom.lost_items, "every increment or a loss")
    runner.stop.set()
    th.join(5.0)
    assert not th.is_alive()
    assert (loc.odometry.lines, odom.lost_items, gw.health.queue_drops) == (500, 0, 0)
    assert len(sink.of("odometry")) == 500


class Broken(Transport):
    def __init__(self) -> None:
        super().__init__()
        self.name = "nonsense://x"
        self.opens = 0

    def _open(self) -> None:
        self.opens += 1
        raise TransportFatal("--serial nonsense://x: invalid URL")

    def _read(self, timeout):
        return []

    def _close(self) -> None:
        pass


def test_a_permanent_input_error_is_raised_not_retried():
    src = Broken()
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), lambda s: None)
    with pytest.raises(TransportFatal, match="invalid URL"):
        Runner([src], gw, CFG).run()
    assert src.opens == 1


def test_the_capture_replays_the_very_same_timer_runs(tmp_path):
    """A live run on the fake clock (sets completed, timed out, an anchor turning stale)
    writes a capture; replaying it runs the timers exactly where they ran live."""
    cap = tmp_path / "live.cap"
    clock = FakeClock()
    live_sets = []
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), live_sets.append)
    src = Scripted(clock, finite=True)
    runner = Runner([src], gw, CFG, clock=clock, capture=CaptureWriter(str(cap)))
    th = threading.Thread(target=runner.run, daemon=True)
    th.start()
    n = 0
    for seq in range(30):
        for a, m in feed.reports(seq):
            if a == 3 and seq >= 10:
                continue  # anchor 3 falls silent: timeouts, then stale
            src.data(encode_uart(m, a), caught_up=(a != 1))
            n += 1
            until(lambda: gw.health.chunks == n, "chunk")  # noqa: B023 (called in this iteration)
            clock.advance(0.005)
        src.idle()
        until(lambda: runner.timer == clock.now(), "idle")
        clock.advance(0.03)
    src.end()
    th.join(5.0)
    runner.capture.close()
    assert gw.grouper.counters.timeouts > 0 and any(s.stale for s in live_sets)

    replay_sets = []
    gw2 = Gateway(make_grouper(tuple(feed.ANCHORS), CFG), replay_sets.append)
    r = CaptureReader(str(cap))
    r.open()
    assert r.explicit_timers
    Runner([r], gw2, CFG, stream_timers=True).run()
    key = lambda s: (s.seq, s.t, s.reason, s.missing, s.stale, tuple(sorted(s.rssi.items())))  # noqa: E731
    assert [key(s) for s in replay_sets] == [key(s) for s in live_sets]


class Recorder:
    """A sink that keeps every call, in order (pfdoa.sinks.base.Sink's calls)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, object]] = []

    def reading(self, r):
        self.calls.append(("reading", r))

    def odometry(self, inc):
        self.calls.append(("odometry", inc))

    def timer(self, t):
        self.calls.append(("timer", t))

    def write(self, record):
        self.calls.append(("write", record))

    def health(self, snap):
        self.calls.append(("health", snap))

    def of(self, kind: str) -> list:
        return [v for k, v in self.calls if k == kind]


def sink_rig(cfg: GatewayConfig):
    clock = FakeClock(start=1_700_000_000.0)
    sink, lines = Recorder(), []
    gw = Gateway(make_grouper(tuple(feed.ANCHORS), cfg), lambda s: None, on_reading=sink.reading)
    src = Scripted(clock)
    runner = Runner([src], gw, cfg, clock=clock, sinks=sink, health_out=lines.append)
    th = threading.Thread(target=runner.run, daemon=True)
    th.start()
    return clock, src, runner, gw, sink, lines, th


def test_sinks_get_readings_before_the_timer_runs_that_follow_them():
    clock, src, runner, gw, sink, lines, th = sink_rig(CFG)
    src.data(FRAMES[0] + FRAMES[1])
    until(lambda: sink.of("timer"), "timer mark")
    clock.advance(0.05)
    src.data(FRAMES[2] + FRAMES[3])
    until(lambda: len(sink.of("timer")) == 2, "second mark")
    runner.stop.set()
    th.join(5.0)
    kinds = [k for k, _ in sink.calls if k != "health"]
    assert kinds == ["reading", "reading", "timer", "reading", "reading", "timer"]
    assert sink.of("timer") == [1_700_000_000.0, 1_700_000_000.05]  # where the capture's T lines would be
    assert [r.anchor_id for r in sink.of("reading")] == [0, 1, 2, 3]


def test_without_a_health_line_the_sinks_still_get_snapshots():
    """health_interval_s 0: no line, but a snapshot every SINK_HEALTH_S of the runner's
    clock, and a last one when it stops; stamped with the host clock."""
    from pfdoa.gateway.runner import SINK_HEALTH_S

    clock, src, runner, gw, sink, lines, th = sink_rig(CFG)
    src.data(FRAMES[0])
    until(lambda: gw.health.chunks == 1, "chunk")
    assert sink.of("health") == []
    clock.advance(SINK_HEALTH_S)
    until(lambda: len(sink.of("health")) == 1, "a snapshot after SINK_HEALTH_S")
    snap = sink.of("health")[0]
    assert snap.t == clock.now() and snap.frames == 1 and snap.period_s == pytest.approx(SINK_HEALTH_S)
    src.data(FRAMES[1] + FRAMES[2])
    until(lambda: gw.health.chunks == 2, "chunk")
    runner.stop.set()
    th.join(5.0)
    assert lines == []
    last = sink.of("health")[-1]
    assert len(sink.of("health")) == 2 and last.frames == 3 and last.anchors[2].received == 1


def test_each_health_line_is_the_line_of_the_snapshot_the_sinks_get():
    cfg = GatewayConfig(set_timeout_s=0.1, stale_after_s=0.25, health_interval_s=2.0, queue_size=16)
    clock, src, runner, gw, sink, lines, th = sink_rig(cfg)
    for k in range(3):
        src.data(FRAMES[k])
        until(lambda k=k: gw.health.chunks == k + 1, "chunk")
        clock.advance(2.0)
        until(lambda k=k: len(lines) == k + 1, "health line")
    runner.stop.set()
    th.join(5.0)
    snaps = sink.of("health")
    assert len(lines) == len(snaps) == 4  # three periods and the last one
    assert lines == [s.line() for s in snaps]
    assert [s.frames for s in snaps] == [1, 2, 3, 3]
    assert snaps[0].frames_per_s == pytest.approx(0.5)


class _Absent(Transport):
    """A serial port that is not there (and never comes)."""

    name = "serial0"

    def __init__(self, clock: FakeClock) -> None:
        super().__init__(clock)
        self.opens = 0

    def _open(self) -> None:
        self.opens += 1
        raise TransportAbsent("--serial", "/dev/ttyACM9")

    def _read(self, timeout: float):
        return []

    def _close(self) -> None:
        pass


def test_a_device_not_present_is_waited_for_said_once_a_minute_then_given_up(caplog):
    """Not the unplugged cable's retry line at every attempt: one "waiting for" line a minute
    (WAITING_LINE_S) while its open is retried with backoff, and after --wait-for-device the
    run ends with the error (exit 2). Fake time: 150 s pass at once."""
    clock = FakeClock(auto_advance=True)
    src = _Absent(clock)
    runner = Runner([src], Gateway(make_grouper(tuple(feed.ANCHORS), CFG), lambda s: None), CFG, clock=clock,
                    wait_for_device_s=150.0)
    with pytest.raises(TransportFatal) as err:
        runner.run()
    assert str(err.value) == "--serial /dev/ttyACM9: not present (--wait-for-device 150)" and err.value.exit_code == 2
    said = [r.getMessage() for r in caplog.records if "not present" in r.getMessage()]
    assert said == ["waiting for /dev/ttyACM9 (not present)"] * 3 and WAITING_LINE_S == 60.0  # at 0, 60 and 120 s
    assert src.opens > 3 and not [r for r in caplog.records if "retrying" in r.getMessage()]
