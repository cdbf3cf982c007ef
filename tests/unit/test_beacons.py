"""The multi-beacon tracker: a grouper and an estimator per beacon, bounded, evicting, timing out."""

import numpy as np
import pytest

from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconsConfig, BeaconTracker, beacon_seed
from pfdoa.gateway.pipeline import make_grouper
from pfdoa.gateway.setup import beacon_localizers
from pfdoa.output import Record
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.readings.config import GatewayConfig
from pfdoa.readings.reassembly import Reading, SeqReassembler, WindowGrouper
from pfdoa.site import Anchor, Site

SITE = Site(PathLoss(-59.0, 2.7), tuple(Anchor(i, x, y) for i, (x, y) in
                                     enumerate([(0, 0), (0, 6), (8, 6), (8, 0)], start=1)))
IDS = SITE.anchor_ids


class SetLog:
    """A localizer that records the sets it gets and writes a record of each."""

    def __init__(self, beacon: str, log: list, writer) -> None:
        self.beacon, self.log, self.writer = beacon, log, writer

    def handle(self, s):
        self.log.append((self.beacon, s))
        self.writer.write(Record(t=s.t, x=float(len(s.rssi)), y=0.0, anchors=s.anchors, missing=s.missing))


def round_grouper(mode):
    """Rounds of one reading per anchor: a window leaves as soon as every anchor is in it."""
    if mode == "window":
        return lambda b: WindowGrouper(IDS, window_s=1.0, close_when_complete=True)
    return lambda b: make_grouper(IDS, GatewayConfig(mode=mode), mode)


def tracker(cfg=BeaconsConfig(), mode="window"):
    sets, records, gone = [], [], []
    t = BeaconTracker(IDS, round_grouper(mode), lambda b, w: SetLog(b, sets, w), cfg,
                      on_record=lambda b, r: records.append((b, r)), on_gone=lambda b, why: gone.append((b, why)))
    return t, sets, records, gone


def feed_round(t, beacon, t0, anchors=IDS, rssi=-70.0):
    for i, a in enumerate(anchors):
        t.push(beacon, Reading(a, rssi, t0 + 0.01 * i))


def test_each_beacon_has_its_own_grouper_and_records_name_their_beacon():
    t, sets, records, _ = tracker()
    for k in range(5):  # two beacons interleaved: one set per round each, never mixed
        feed_round(t, "a", k * 0.1, rssi=-60.0)
        feed_round(t, "b", k * 0.1 + 0.005, rssi=-80.0)
    assert len(t) == 2 and isinstance(t.grouper("a"), WindowGrouper) and t.grouper("a") is not t.grouper("b")
    assert [b for b, _ in records] == ["a", "b"] * 5
    for b, s in sets:
        assert s.reason == "complete" and set(s.rssi.values()) == {-60.0 if b == "a" else -80.0}
    assert t.counters.sets == 10 and t.counters.records == 10 and t.counters.created == 2


def test_beyond_max_beacons_a_new_beacon_goes_first_then_the_least_recently_heard():
    """With max_beacons tracked, a beacon not yet estimated (new: no set has left its
    grouper) makes room first, its readings counted and not estimated; only when every
    tracked beacon is being estimated does the least recently heard one go, its open
    window estimated first."""
    t, sets, records, gone = tracker(BeaconsConfig(max_beacons=3))
    for b in ("a", "b", "c"):
        feed_round(t, b, 0.0)  # each one estimated once
    t.push("a", Reading(1, -70.0, 0.5))  # "a" heard again, with an open window: "b" is now the oldest
    t.push("d", Reading(1, -70.0, 0.6))  # no new beacon to let go: "b", the least recently heard
    assert gone == [("b", "evicted")] and set(t.beacons) == {"a", "c", "d"}
    assert t.counters.evicted == 1 and len(t) == 3
    n = len(sets)
    for i in range(100):  # ids heard once: each takes the place of the previous new one
        t.push(f"x{i}", Reading(1 + i % 4, -70.0, 0.7 + 0.001 * i))
    assert set(t.beacons) == {"a", "c", "x99"} and len(sets) == n and gone == [("b", "evicted")]
    assert (t.counters.dropped_new, t.counters.dropped_readings, t.counters.evicted) == (100, 100, 1)
    t.push("c", Reading(2, -71.0, 0.9))  # "c" heard again: "a" is the least recently heard
    feed_round(t, "h", 1.0)  # lets "x99" go, then is estimated (its round is complete)
    assert set(t.beacons) == {"a", "c", "h"} and sets[-1][0] == "h"
    n = len(sets)
    feed_round(t, "i", 1.1)  # every tracked beacon estimated: "a", heard least recently, goes
    assert gone[-1] == ("a", "evicted") and set(t.beacons) == {"c", "h", "i"}
    assert [(b, sorted(s.rssi)) for b, s in sets[n:]] == [("a", [1]), ("i", [1, 2, 3, 4])]
    assert [b for b, _ in records[-2:]] == ["a", "i"]
    assert t.counters.created == 3 + 1 + 100 + 2


def test_idle_beacons_time_out_with_their_open_sets_emitted():
    t, sets, records, gone = tracker(BeaconsConfig(idle_timeout_s=10.0))
    feed_round(t, "a", 0.0)
    t.push("a", Reading(1, -70.0, 1.0))  # an open window
    feed_round(t, "b", 5.0)
    t.poll(10.5)
    assert gone == [] and len(t) == 2
    t.poll(11.5)
    assert gone == [("a", "timed_out")] and t.beacons == ("b",) and t.counters.timed_out == 1
    assert sets[-1][0] == "a" and set(sets[-1][1].rssi) == {1}
    t.poll(15.5)
    assert gone[-1] == ("b", "timed_out") and len(t) == 0
    feed_round(t, "a", 20.0)  # it comes back: tracked again, counted as created
    assert t.counters.created == 3 and t.beacons == ("a",)


def test_bad_ids_and_unknown_anchors_never_create_a_beacon():
    t, _, _, _ = tracker()
    t.push("", Reading(1, -70.0, 0.0))
    t.push("x" * (MAX_ID_LEN + 1), Reading(1, -70.0, 0.0))
    t.push(None, Reading(1, -70.0, 0.0))  # type: ignore[arg-type]
    t.push("new", Reading(99, -70.0, 0.0))
    assert len(t) == 0 and t.counters.bad_id == 3 and t.counters.unknown_anchor == 1
    assert t.counters.readings == 4


def test_memory_stays_bounded_under_a_flood_of_device_ids():
    """5,000 ids heard once each, with a beacon that is being estimated among them: at most
    max_beacons tracked, the flood's ids let go unestimated (never announced as gone), the
    estimated beacon keeps its place and gets every one of its sets."""
    t, sets, records, gone = tracker(BeaconsConfig(max_beacons=16))
    rounds = 0
    for i in range(5000):
        if i % 100 == 0:
            feed_round(t, "robot", i * 0.001)
            rounds += 1
        t.push(f"phone-{i}", Reading(1 + i % 4, -70.0, i * 0.001 + 0.0005))
        assert len(t) <= 16
    assert len(t) == 16 and "robot" in t and t.counters.evicted == 0 and gone == []
    assert t.counters.dropped_new == 5000 - 15 and t.counters.dropped_readings == 5000 - 15
    assert [b for b, _ in records] == ["robot"] * rounds and len(t.summary()["beacons"]) == 16
    # Nothing of a beacon let go stays behind: every localizer made is one of a tracked beacon.
    assert all(b.localizer is None or b.id == "robot" for b in t._beacons.values())


def test_seq_reassembler_per_beacon_for_our_frames():
    t, sets, records, _ = tracker(mode="seq")
    for seq in range(3):
        for a in IDS:
            t.push("b0", Reading(a, -70.0, seq * 0.1, seq=seq))
            t.push("b1", Reading(a, -75.0, seq * 0.1, seq=seq))
    assert isinstance(t.grouper("b0"), SeqReassembler)
    assert [(b, s.seq, s.reason) for b, s in sets] == [(b, q, "complete") for q in range(3) for b in ("b0", "b1")]


def test_beacon_seeds_are_reproducible_and_distinct():
    assert beacon_seed(1, "a") == beacon_seed(1, "a") != beacon_seed(1, "b") != beacon_seed(2, "a")
    assert beacon_seed(None, "a") is None


def test_with_real_estimators_two_beacons_are_localized_apart():
    """pf-doa per beacon (beacon_localizers: build_estimator, per-beacon seeds): two beacons standing in
    opposite corners, noise-free readings from the radio model."""
    truth = {"left": np.array([1.5, 1.5]), "right": np.array([6.5, 4.5])}
    out: dict[str, list] = {"left": [], "right": []}
    t = BeaconTracker(IDS, round_grouper("window"),
                      beacon_localizers(SITE, GatewayConfig(), method="pf-doa", seed=7),
                      on_record=lambda b, r: out[b].append((r.x, r.y)))
    rng = np.random.default_rng(3)
    for k in range(60):
        for b, p in truth.items():
            rssi = mean_rssi(p, SITE.positions, PathLoss.from_site(SITE)) + rng.normal(0, 1.0, 4)
            for i, a in enumerate(IDS):
                t.push(b, Reading(a, float(rssi[i]), k * 0.1 + 0.01 * i))
    for b, p in truth.items():
        assert len(out[b]) == 60
        err = np.hypot(*(np.array(out[b][-20:]) - p).T)
        assert err.mean() < 0.6, (b, err.mean())


@pytest.mark.parametrize("bad", [0, -1])
def test_tracker_config_is_checked(bad):
    from pfdoa.errors import ConfigError
    from pfdoa.gateway.beacons import beacons_config

    with pytest.raises(ConfigError):
        beacons_config({"beacons": {"max_beacons": bad}})


def test_pinned_beacons_are_never_evicted_nor_timed_out():
    t, sets, records, gone = tracker(BeaconsConfig(max_beacons=2, idle_timeout_s=10.0))
    t.add("ours")
    feed_round(t, "ours", 0.0)
    feed_round(t, "a", 1.0)
    feed_round(t, "b", 2.0)  # evicts "a", the least recently heard one that is not pinned
    assert gone == [("a", "evicted")] and set(t.beacons) == {"ours", "b"}
    t.poll(100.0)  # everything is idle: only "b" goes
    assert gone[-1] == ("b", "timed_out") and t.beacons == ("ours",)
    feed_round(t, "ours", 101.0)
    assert [b for b, _ in records].count("ours") == 2
    t2, _, _, gone2 = tracker(BeaconsConfig(max_beacons=1))
    t2.add("p")
    feed_round(t2, "q", 0.0)  # no room: every tracked beacon is pinned
    assert t2.beacons == ("p",) and t2.counters.refused == 4 and gone2 == []
    with pytest.raises(ValueError):
        t2.add("p")


def test_health_counts_named_beacons_readings_per_second_and_the_trackers_counters():
    """The health snapshot (line and JSON) of a gateway with named beacons: their readings
    per second beside our frames/s, and tracked / evicted / timed out; without a tracker
    the snapshot is as before."""
    from pfdoa.gateway.beacons import GrouperTotals
    from pfdoa.gateway.health import Health

    t, _sets, _records, _gone = tracker(BeaconsConfig(max_beacons=2))
    h = Health()
    # As the gateway gives it: the tracked beacons' groupers and those let go, as totals.
    totals = GrouperTotals(lambda: [t.grouper(b) for b in t.beacons] + [t.retired])
    sampler = h.sampler(totals, t)
    sampler.start(0.0)
    h.frames = 5  # our frames, counted apart
    for k, b in enumerate(("a", "b", "c")):  # 12 readings; "c" evicts "a"
        feed_round(t, b, 0.1 * k)
    snap = sampler.sample(2.0, 2.0)
    assert snap.named_per_s == 6.0 and snap.frames_per_s == 2.5
    assert snap.sets == 3 and snap.sets_per_s == 1.5  # "a"'s set too: totals never go back on an eviction
    assert sum(a.received for a in snap.anchors.values()) == 12
    assert snap.named_beacons == {"readings": 12, "tracked": 2, "peak": 2, "created": 3, "evicted": 1, "timed_out": 0,
                                  "refused": 0, "bad_id": 0, "unknown_anchor": 0, "dropped_new": 0,
                                  "dropped_readings": 0, "time_ahead": 0, "time_behind": 0}
    line = snap.line()
    assert line.startswith("health: 2.5 frames/s 6.0 named/s ") and line.endswith("| beacons 2 evicted 1 timed out 0")
    t.refuse("b", "time_ahead")  # readings refused for their message time: per beacon, tracked or not
    t.refuse("zz", "time_behind")
    t.refuse("zz", "time_behind")
    snap = sampler.sample(2.5, 2.5)
    assert (snap.named_beacons["time_ahead"], snap.named_beacons["time_behind"]) == (1, 2)
    assert snap.named_beacons["bad_time_by_beacon"] == {"zz": 2, "b": 1} and snap.line().endswith("bad time 3")
    assert t.summary()["beacons"]["b"]["refused"] == 1 and t.summary()["refused_untracked"] == {"zz": 2}
    js = snap.to_json()
    assert js["named_per_s"] == 6.0 and js["named_beacons"]["evicted"] == 1
    feed_round(t, "b", 1.0)  # the next period counts its own readings only
    assert sampler.sample(3.0, 3.0).named_per_s == 8.0  # 4 readings in 0.5 s
    plain = h.sampler(totals).sample(4.0, 4.0)
    assert plain.named_per_s is None and "named" not in plain.line() and "named_per_s" not in plain.to_json()



def test_a_named_beacons_record_is_stamped_when_its_set_was_released():
    """stamp = the gateway's time that released the set (the closing reading, or the
    timers), t = its last reading's: stamp - t is the wait for the window's end."""
    out = []
    t = BeaconTracker(IDS, lambda b: WindowGrouper(IDS, window_s=1.0),
                      beacon_localizers(SITE, GatewayConfig(), method="wcl", seed=None),
                      on_record=lambda b, r: out.append(r))
    feed_round(t, "a", 0.0)            # readings at 0.00-0.03: the window [0, 1) is open
    t.poll(0.5)
    assert out == []
    t.push("a", Reading(1, -70.0, 1.2))  # a reading past its end closes it
    t.poll(2.6)                          # the timers close the next one
    assert [(r.t, r.stamp) for r in out] == [(0.03, 1.2), (1.2, 2.6)]


def test_build_named_tracker_makes_window_groupers_and_per_beacon_seeded_estimators():
    """The one builder of the named-beacon tracker: each beacon gets a window grouper
    (window_s, else the gateway's), a Localizer over build_estimator seeded by beacon_seed,
    and the options reach every Localizer."""
    from pfdoa.gateway.setup import build_estimator, build_named_tracker

    made: dict[str, object] = {}
    gcfg = GatewayConfig(mode="seq", window_s=0.4)
    for window_s, expected in ((None, 0.4), (0.7, 0.7)):
        t = build_named_tracker(SITE, gcfg, BeaconsConfig(max_beacons=3), method="pf-doa", seed=5,
                                window_s=window_s, on_record=lambda b, r: None, frame_id="odom")
        for b in ("a", "b"):
            t.push(b, Reading(1, -60.0, 0.0))
            assert t._beacons[b].localizer is None  # a new beacon: no estimator until its first set
            t.push(b, Reading(2, -60.0, 1.5))  # closes the first window
            g = t.grouper(b)
            assert isinstance(g, WindowGrouper) and g.window_s == expected
            loc = t._beacons[b].localizer
            assert loc.frame_id == "odom" and loc.odometry is None
            made[b] = loc.estimator
        assert t.cfg.max_beacons == 3
    # Seeded per beacon: the same draws as build_estimator with beacon_seed, different beacons differ.
    for b in ("a", "b"):
        ref = build_estimator(SITE, "pf-doa", beacon_seed(5, b))
        assert made[b].rng.bit_generator.state == ref.rng.bit_generator.state
    assert made["a"].rng.bit_generator.state != made["b"].rng.bit_generator.state


@pytest.mark.parametrize("method", ["pf-doa", "pf-doa-paper", "trilateration", "wcl"])
def test_a_tracked_beacon_holds_at_most_the_documented_bytes(method):
    """What one tracked (estimated) beacon costs, measured with tracemalloc on a 16-anchor,
    10 x 10 m site: at most MAX_BEACON_BYTES (docs/fleet.md states the same number), and
    nothing of it stays once it is let go."""
    import gc
    import tracemalloc

    from pfdoa.gateway.beacons import MAX_BEACON_BYTES
    from pfdoa.gateway.setup import build_named_tracker

    site = Site(PathLoss(-59.0, 2.7), tuple(Anchor(i, 10.0 * (i % 4) / 3, 10.0 * (i // 4) / 3) for i in range(16)))
    t = build_named_tracker(site, GatewayConfig(mode="window", window_s=0.3), BeaconsConfig(max_beacons=64),
                            method=method, seed=1, on_record=lambda b, r: None)

    def estimated(beacon: str, t0: float) -> None:
        for a in site.anchor_ids:
            t.push(beacon, Reading(a, -70.0 - a, t0 + 0.001 * a))
        t.push(beacon, Reading(0, -70.0, t0 + 1.0))  # closes the first window: an estimate
        assert t._beacons[beacon].localizer is not None

    estimated("warm-up", 0.0)
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        for i in range(8):
            estimated(f"d{i}", 2.0 + i)
        gc.collect()
        per_beacon = (tracemalloc.get_traced_memory()[0] - base) / 8
        t.poll(1e6)  # all of them let go (idle)
        gc.collect()
        left = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    assert 0 < per_beacon <= MAX_BEACON_BYTES, (method, per_beacon)
    assert left < per_beacon, (method, left)  # not one beacon's worth left behind
