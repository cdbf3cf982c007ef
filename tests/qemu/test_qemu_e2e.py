"""End to end with the real Cortex-M3 firmware image: four QEMU mps2-an385 anchors, each on
its own pseudo-terminal, fed RADIO_INJECT (and RADIO_INJECT_RAW) frames from the simulator's radio model, in
virtual time: the simulator collects each injection's output (exactly the bytes a shadow
host-build core sends for it: a barrier, and a live byte-identity check) into the timed
stream that `pfdoa gateway` (a separate process) localizes from. Held to the accuracy
bounds of the host-build SIL test (tests/sil/test_sim_e2e.py); a function of the seed."""

import json
import subprocess
import sys

from qemu_support import build_qemu_images


def run_qemu_sim(tmp_path, *extra, scenario="demo", duration=20, seed=3, backend="qemu"):
    build_qemu_images()
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", scenario, "--anchor-backend", backend,
           "--gateway", "--duration", str(duration), "--seed", str(seed), "--out-dir", str(tmp_path), "--json",
           *extra]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    assert doc["gateway"] is not None, r.stderr[-3000:]
    return doc


def test_four_qemu_anchors_localize_within_the_host_sil_bounds(tmp_path):
    doc = run_qemu_sim(tmp_path, "--odom")
    sim, gw, s = doc["sim"], doc["gateway"], doc["score"]

    # Every reading went into a QEMU anchor; every anchor's reports reached the gateway.
    injected = sim["qemu"]["injected"]
    assert set(injected) == set(gw["anchors"]) == {"1", "2", "3", "4"}
    assert sum(injected.values()) == sim["radio"]["readings"] > 0
    # Every byte the firmware image sent equals the host build's for the same injection.
    assert sim["qemu"]["byte_mismatches"] == 0 and min(sim["qemu"]["bytes_compared"].values()) > 4000
    for a, g in gw["anchors"].items():
        assert g["received"] == sim["beacons"] and g["lost"] == 0 and g["duplicates"] == 0, (a, g)
    assert gw["errors"] == {}
    assert gw["status"] >= 4 * 19  # STATUS once a second of injected time, per anchor

    # The same bounds as the host SIL end-to-end test (which also has link faults).
    assert s["coverage"] > 0.85
    assert s["median_m"] < 0.8 and s["p95_m"] < 1.6 and s["rmse_m"] < 1.0, s
    assert len(sim["qemu"]["positions"]) >= 4


def test_two_beacons_on_qemu_anchors_raw_injections_byte_identical(tmp_path):
    """The two-beacons scenario (our beacon and an iBeacon, protocol v2): the iBeacon's
    advertisements go in as RADIO_INJECT_RAW frames that the firmware matches against the
    filter table its "flash" holds (filters=), both beacons are localized, every byte equals
    the host build's, and the gateway's output is the c backend's for the same seed."""
    from pfdoa.gateway.beacons import beacons_config
    from pfdoa.site import load_site

    doc = run_qemu_sim(tmp_path / "qemu", scenario="two-beacons", duration=10, seed=4)
    sim, gw = doc["sim"], doc["gateway"]
    injected = sim["qemu"]["injected"]
    assert set(injected) == set(gw["anchors"]) == {"1", "2", "3", "4"}
    assert sum(injected.values()) == sim["radio"]["readings"] > 0  # ours and the iBeacon's, all injected
    assert sim["qemu"]["byte_mismatches"] == 0 and min(sim["qemu"]["bytes_compared"].values()) > 4000
    g = gw["beacons"]
    assert g["tracked"] == 2 and g["unknown_beacon"] == 0 and g["kind_mismatch"] == 0 and gw["errors"] == {}
    # The anchors' STATUS carries the scenario's table: the firmware loaded filters=.
    assert g["filter_mismatch"] == [] and g["filter_hash"] == beacons_config(
        load_site(tmp_path / "qemu" / "site.toml").sections).filter_hash
    assert g["beacons"]["ibeacon"]["sets"] == sim["other_beacons"]["ibeacon"] > 0
    for name, s in doc["beacons"].items():
        assert s["coverage"] >= 0.95 and s["mean_m"] < 1.2, (name, s)
    host = run_qemu_sim(tmp_path / "c", scenario="two-beacons", duration=10, seed=4, backend="c")
    assert (tmp_path / "qemu" / "gateway.jsonl").read_bytes() == (tmp_path / "c" / "gateway.jsonl").read_bytes()
    assert host["beacons"] == doc["beacons"]


def test_a_qemu_anchor_powered_off_and_rebooted(tmp_path):
    # Anchor 2 is off from 8 s to 12 s (no readings injected), then boots again: a warm
    # reset of its QEMU (QMP system_reset). The firmware restarts its uptime, and the
    # gateway must see the reboot and the 40 missing reports, and keep localizing.
    doc = run_qemu_sim(tmp_path, "--odom", "--faults", "reboot=1,silence=2@8+4,drift_ppm=100,jitter=10")
    sim, gw, s = doc["sim"], doc["gateway"], doc["score"]
    assert sim["faults"]["reboots"] == 1 and sim["qemu"]["byte_mismatches"] == 0
    a = gw["anchors"]
    assert a["2"]["reboots"] == 1 and a["2"]["lost"] == 40 and a["2"]["received"] == sim["beacons"] - 40
    for other in ("1", "3", "4"):
        assert a[other]["reboots"] == 0 and a[other]["lost"] == 0, (other, a[other])
    assert gw["errors"] == {}
    assert s["coverage"] > 0.85 and s["median_m"] < 0.8 and s["p95_m"] < 1.8, s
