"""Two beacons in one site through one gateway (issue 16's must-show), in virtual time: our
beacon (entry 0 of the anchors' filter tables, by sequence number) and an iBeacon (entry
1, no sequence number: events formed by time on the anchors, NO_SEQ, grouped by time in
the gateway), each localized about as well as our beacon alone on the same walk: ours within
1.2 times, the iBeacon (its own walk, its readings grouped by time) within 1.3 times (measured
over these seeds: 1.05 and 1.26 now, 1.04 and 1.25 before the jump test's gate counted the
noise scale, 1.09 and 1.20 with leaps at 0.1). A
function of the seeds: nothing here depends on the machine's speed. The published figures
over ten seeds are docs/beacons-accuracy.md (tools/beacons_accuracy.py)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pfdoa.gateway.beacons import beacons_config
from pfdoa.site import load_site

# The published figures' seeds and length (docs/beacons-accuracy.md): over three 40 s runs
# one iBeacon walk (seed 2, 0.67-0.73 m) decided the comparison.
SEEDS = tuple(range(1, 11))
DURATION_S = 60


def run_sim(tmp_path, scenario, seed, *args, duration=40):
    out = tmp_path / f"{scenario}-{seed}"
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", scenario, "--gateway", "--duration",
           str(duration), "--seed", str(seed), "--out-dir", str(out), "--json", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    assert doc["gateway"] is not None, r.stderr[-3000:]
    return doc, out


@pytest.mark.slow
def test_two_beacons_are_each_localized_as_well_as_one_beacon_alone(tmp_path):
    alone, ours, tag = [], [], []
    for seed in SEEDS:
        one, _ = run_sim(tmp_path, "demo", seed, duration=DURATION_S)
        two, out = run_sim(tmp_path, "two-beacons", seed, duration=DURATION_S)
        alone.append(one["score"]["mean_m"])
        b = two["beacons"]
        assert b["ours"] == two["score"]  # our beacon's figures, scored by sequence number
        for s in b.values():
            assert s["coverage"] >= 0.95, b
        ours.append(b["ours"]["mean_m"])
        tag.append(b["ibeacon"]["mean_m"])
        # What the gateway made of the reports: two beacons, each grouped its way, every
        # anchor holding the site's filter table.
        g = two["gateway"]["beacons"]
        assert g["tracked"] == 2 and g["unknown_beacon"] == 0 and g["kind_mismatch"] == 0
        assert g["filter_mismatch"] == [] and g["filter_hash"] == beacons_config(
            load_site(out / "site.toml").sections).filter_hash
        assert g["beacons"]["ours"]["grouping"] == "seq" and g["beacons"]["ibeacon"]["grouping"] == "window"
        assert g["beacons"]["ours"]["sets"] == two["sim"]["beacons"]
        assert g["beacons"]["ibeacon"]["sets"] == two["sim"]["other_beacons"]["ibeacon"]
    print(f"mean error over seeds {SEEDS}: one beacon {np.mean(alone):.3f} m, two beacons: ours "
          f"{np.mean(ours):.3f} m, iBeacon {np.mean(tag):.3f} m")
    assert np.mean(ours) <= 1.2 * np.mean(alone) and np.mean(tag) <= 1.3 * np.mean(alone)
    assert max(ours + tag) < 0.8  # every run: a 6 x 6 m room, where a mixed-up beacon is off by metres


def test_two_beacons_over_can_and_with_the_micropython_anchor(tmp_path):
    """The 7-byte CAN reports carry the beacon entry too; the MicroPython anchor matches the
    iBeacon exactly as the C core does (the gateway's output is the same, byte for byte)."""
    c, c_out = run_sim(tmp_path / "c", "two-beacons", 4, duration=10)
    mpy, mpy_out = run_sim(tmp_path / "mpy", "two-beacons", 4, "--anchor-backend", "mpy", duration=10)
    assert (c_out / "gateway.jsonl").read_bytes() == (mpy_out / "gateway.jsonl").read_bytes()
    can, _ = run_sim(tmp_path / "can", "two-beacons", 4, "--transport", "slcan", duration=10)
    for doc in (c, can):
        assert {n: s["coverage"] >= 0.95 for n, s in doc["beacons"].items()} == {"ours": True, "ibeacon": True}
        assert doc["gateway"]["errors"] == {} and doc["gateway"]["beacons"]["kind_mismatch"] == 0
