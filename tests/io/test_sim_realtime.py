"""Real time, as a robot runs it: the simulator serves a pseudo-terminal (or SLCAN over
one) at 10x real time and `pfdoa gateway` reads it on its wall clock. How the scheduler
interleaves the processes is not ours to fix, so these tests assert liveness and counters,
never accuracy (that is tests/sil/test_sim_e2e.py, in virtual time) - and that whatever the
live gateway made of it, its capture replays to exactly the same positions."""

import json
import subprocess
import sys

import pytest

PY = sys.executable


def run_realtime(tmp_path, *args, seconds=10):
    cmd = [PY, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--gateway", "--realtime", "--speed", "10",
           "--duration", str(seconds), "--seed", "5", "--out-dir", str(tmp_path), "--json", "--wait", "30", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    assert doc["gateway"] is not None, r.stderr[-3000:]
    return doc


@pytest.mark.parametrize("transport", ["pty", "slcan"])
def test_a_live_port_is_read_and_its_capture_replays_exactly(tmp_path, transport):
    cap = tmp_path / "live.cap"
    doc = run_realtime(tmp_path, "--transport", transport, "--odom", "--faults", "loss=0.02,dup=0.01",
                       "--gateway-arg=--capture", f"--gateway-arg={cap}")
    g, sim = doc["gateway"], doc["sim"]
    # Liveness: the gateway read the port and estimated most beacons (the first frames may
    # race its open; the last ones its stop).
    assert g["estimates"] >= 0.8 * sim["beacons"] and g["errors"] == {}
    assert g["odometry"]["lines"] >= 0.8 * sim["beacons"]
    for a, c in sim["faults"]["per_anchor"].items():
        assert g["anchors"][a]["received"] <= c["reports"] - c["dropped_reports"]
    replayed = tmp_path / "replayed.jsonl"
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(tmp_path / "site.toml"),
                        "--replay-capture", str(cap), "--seed", "5", "--out", str(replayed)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert replayed.read_bytes() == (tmp_path / "gateway.jsonl").read_bytes()
