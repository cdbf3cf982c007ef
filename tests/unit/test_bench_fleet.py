"""bench/fleet.py's offline part on a tiny run: what it counts is exact (no timing asserted)."""

from bench.fleet import ANCHORS, BEACONS, RATE_HZ, markdown, offline
from pfdoasim.fleet import FLEET_WINDOW_S


def test_offline_counts_every_reading_and_estimate():
    r = offline(duration_s=4.0, base_s=2.0, pin=False)
    assert r["readings"] == BEACONS * ANCHORS * RATE_HZ * 4.0  # two replays of 2 s
    assert r["records"] == r["estimates"] == r["latency_ms"]["n"] and r["estimator_errors"] == 0
    assert r["records"] >= BEACONS * (4.0 / FLEET_WINDOW_S) - 2 * BEACONS  # ~one estimate per beacon per window
    la = r["latency_ms"]
    assert 0 < la["p50"] <= la["p99"] <= la["max"] and r["cpu"] is None and r["simulated_s"] == 4.0
    assert any("reading -> estimate" in line for line in markdown({"offline": r}))
