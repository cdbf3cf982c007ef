"""The per-anchor clock model: tick -> host time by the lower envelope of (tick, arrival),
robust to u32 wrap, reboots, jitter, batching and stalls; bounded memory."""

from __future__ import annotations

import numpy as np
import pytest

from pfdoa.gateway.anchorclock import MAX_SEGMENTS, AnchorClock, AnchorClocks

T0 = 1_700_000_000.0


def stream(ppm: float, jitter_ms: float, seconds: float = 60.0, hz: float = 10.0, seed: int = 0,
           boot: int | None = None, stall: tuple[float, float] | None = None):
    """(tick, arrival, true event time) of one anchor's reports: events at hz, the tick
    running ppm fast, delays 0..jitter_ms uniform, in order; a stall delivers late."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / hz) + 0.0008 + rng.uniform(0, 0.1)
    boot = int(rng.integers(0, 2**32)) if boot is None else boot
    ticks = (boot + np.floor(t * 1000.0 * (1 + ppm * 1e-6)).astype(np.int64)) & 0xFFFFFFFF
    arr = t + rng.uniform(0, jitter_ms / 1000.0, t.size)
    if stall:
        arr = np.where((arr >= stall[0]) & (arr < stall[1]), stall[1], arr)
    arr = np.maximum.accumulate(arr)
    return [int(x) for x in ticks], T0 + arr, T0 + t


def errors_ms(ticks, arrivals, truth, clock: AnchorClock | None = None) -> np.ndarray:
    c = clock or AnchorClock()
    return np.array([c.event_time(k, a) for k, a in zip(ticks, arrivals)]) * 1e3 - truth * 1e3


@pytest.mark.parametrize("ppm", [-100.0, 0.0, 100.0, 450.0])
def test_drift_is_followed_without_jitter(ppm):
    ticks, arr, truth = stream(ppm, 0.0)
    c = AnchorClock()
    e = errors_ms(ticks, arr, truth, c)
    assert np.abs(e[20:]).max() < 1.2  # the tick's own millisecond, and a little
    assert abs(c.drift_ppm - ppm) < 5.0


def test_fifty_ms_of_jitter_is_filtered_to_the_tick():
    """0..50 ms of delay per frame; after the window has filled, the mapped time of every
    report is within a few ms of the truth, the median far below a millisecond."""
    errs = []
    for seed in range(3):
        for ppm in (-100.0, 0.0, 100.0):
            ticks, arr, truth = stream(ppm, 50.0, seconds=90.0, seed=seed)
            errs.append(errors_ms(ticks, arr, truth)[300:])  # after 30 s
    e = np.abs(np.concatenate(errs))
    assert np.median(e) < 0.8 and np.percentile(e, 99) < 2.5, (np.median(e), np.percentile(e, 99))


def test_an_event_is_never_after_its_own_arrival_and_wraps_are_just_time():
    ticks, arr, truth = stream(80.0, 20.0, seconds=30.0, boot=2**32 - 10_000)  # wraps after 10 s
    assert any(b < a for a, b in zip(ticks, ticks[1:]))
    c = AnchorClock()
    mapped = np.array([c.event_time(k, a) for k, a in zip(ticks, arr)])
    assert (mapped <= arr).all() and c.resets == 0
    assert np.abs(mapped - truth)[100:].max() < 3e-3


def test_a_stall_that_delivers_seconds_at_once_does_not_move_the_map():
    ticks, arr, truth = stream(100.0, 5.0, seconds=60.0, stall=(30.0, 35.0))
    e = errors_ms(ticks, arr, truth)
    assert (arr - truth).max() > 4.9  # the stall's frames were that late
    assert np.abs(e[100:]).max() < 1.5  # their events were not


def test_reboot_restarts_the_model_once():
    c = AnchorClock()
    ticks, arr, truth = stream(50.0, 5.0, seconds=20.0, boot=500_000_000)
    for k, a in zip(ticks, arr):
        c.event_time(k, a)
    # Power cycle: the tick restarts at 0, far back (the tracker's reboot rule).
    ticks2, arr2, truth2 = stream(-50.0, 5.0, seconds=20.0, boot=0)
    c.event_time(ticks2[0], arr2[0] + 25.0)
    assert c.resets == 1
    c.reset()  # its STATUS (uptime back) then says the same: one reboot, one restart
    assert c.resets == 1
    e = errors_ms(ticks2[1:], arr2[1:] + 25.0, truth2[1:] + 25.0, c)
    assert np.abs(e[20:]).max() < 2.0
    # A reboot onto another tick base far *ahead* (the tick leaps forward) restarts it too.
    e = errors_ms([(k + 900_000_000) & 0xFFFFFFFF for k in ticks2], arr2 + 50.0, truth2 + 50.0, c)
    assert c.resets == 2 and np.abs(e[20:]).max() < 2.0


def test_reports_read_in_chunks_refit_once_a_segment_and_map_to_the_tick(monkeypatch):
    """A USB adapter or a bulk read hands the gateway many reports at one arrival: each is
    its segment's new lowest point. The newest segment then moves the offset alone and the
    rate is fitted once per segment (a refit per report was most of the gateway's time);
    the events still map to their tick."""
    ticks, _, truth = stream(100.0, 0.0, seconds=60.0, hz=50.0)
    # a chunk read every 37 ms, 2 ms after its end (a period the events' 20 ms do not
    # divide: some report arrives just after its event, as the envelope needs)
    arr = np.ceil((truth - T0) / 0.037) * 0.037 + T0 + 0.002
    fits = []
    orig = AnchorClock._fit
    monkeypatch.setattr(AnchorClock, "_fit", lambda self: fits.append(1) or orig(self))
    e = errors_ms(ticks, arr, truth)
    assert len(fits) <= 61  # one per segment (60 s of 1 s segments), not one per report (3000)
    assert abs(float(np.median(e[500:])) - 2.0) < 0.5  # the transport's constant 2 ms (module doc)
    assert np.ptp(e[500:]) < 2.5  # the tick's millisecond, nothing of the 37 ms batching


def test_memory_is_bounded_whatever_the_rate():
    c = AnchorClock()
    ticks, arr, _ = stream(10.0, 5.0, seconds=300.0, hz=200.0)
    for k, a in zip(ticks, arr):
        c.event_time(k, a)
    assert len(c._segs) <= MAX_SEGMENTS and c.points == len(ticks)


def test_anchors_without_a_tick_or_a_model_use_the_arrival():
    cl = AnchorClocks([1, 2])
    assert cl.event_time(1, None, 5.0) == 5.0  # CAN reports carry no tick
    assert cl.event_time(9, 1234, 5.0) == 5.0  # not a configured anchor
    assert cl.event_time(2, 1234, 5.0) <= 5.0
    assert set(cl.summary()) == {"1", "2"}
