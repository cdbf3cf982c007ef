"""The gateway's event times against the simulator's true event times (virtual time).

Every anchor's tick runs at -100, 0 or +100 ppm against the host clock (``skew``), and every
frame arrives 0..50 ms late (uniform, ``jitter=50``), on its own serial link. The gateway
maps each anchor's ticks to its clock (pfdoa.gateway.anchorclock) and stamps a set with the
median of its reports' mapped times; the truth is the median of the same reports' true
event times (trace.reports.csv). Figures in docs/gateway.md (command there).

Seeds 2 and 3: the model's constants were chosen on seed-1 streams.
"""

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.sil

SECONDS = 120


def run(tmp_path, faults: str, seed: int, *extra) -> dict:
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--gateway", "--duration", str(SECONDS),
           "--seed", str(seed), "--faults", faults, "--out-dir", str(tmp_path), "--json", "--gateway-arg=--method",
           "--gateway-arg=wcl", *extra]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    return doc


@pytest.mark.parametrize("ppm", [-100, 0, 100])
@pytest.mark.parametrize("seed", [2, 3])
def test_event_times_within_2_ms_with_drift_and_50_ms_of_jitter(tmp_path, ppm, seed):
    faults = "jitter=50," + ",".join(f"skew={a}@{ppm}" for a in (1, 2, 3, 4))
    doc = run(tmp_path, faults, seed)
    e = doc["score"]["event_time"]
    print(ppm, seed, e)
    assert e["warm_n"] >= 10 * (SECONDS - 10) - 1
    # From 10 s on (the fit has seen 100 reports per anchor): p99 within 2 ms.
    assert e["warm_p99_ms"] <= 2.0, e
    # From the start (2 s on, as scored): bounded by the early fit (few reports yet).
    assert e["p99_ms"] <= 4.0 and e["max_ms"] <= 6.0, e
    print({a: c["drift_ppm"] for a, c in doc["gateway"]["clock"].items()})  # fitted (shrunk to 0 by the jitter)


def test_mixed_clocks_and_a_stall(tmp_path):
    """Anchors at -100, 0, +100 and 0 ppm; a 3 s stall at 60 s (nothing delivered, then
    everything at once). The stall's frames arrive seconds late; their events do not move,
    and no timer fired while they were on their way."""
    faults = "jitter=30,stall=60+3,skew=1@-100,skew=2@0,skew=3@100,skew=4@0"
    doc = run(tmp_path, faults, 2)
    e = doc["score"]["event_time"]
    print(e)
    assert e["warm_p99_ms"] <= 2.0 and e["max_ms"] <= 6.0, e
    g = doc["gateway"]
    assert g["timeouts"] == 0 and g["late"] == 0 and g["complete"] == g["sets"]


def test_a_constant_latency_is_not_seen(tmp_path):
    """A USB adapter handing frames over every 4 ms: here the beacons' events always fall at
    the same phase of the 4 ms period, so every frame waits at least the same 3.2 ms - a
    constant latency, which no envelope can see (docs/gateway.md, failure modes). The times
    are late by it, and only by it."""
    doc = run(tmp_path, "batch=4,skew=1@-100,skew=3@100", 2)
    e = doc["score"]["event_time"]
    print(e)
    assert 3.0 <= e["warm_p50_ms"] <= 3.3 and e["warm_max_ms"] <= 4.5, e
