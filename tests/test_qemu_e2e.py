"""End to end with the real Cortex-M3 firmware image: four QEMU mps2-an385 anchors, each on
its own pseudo-terminal, fed RADIO_INJECT frames from the simulator's radio model; `pfdoa
gateway --serial A --serial B --serial C --serial D` (a separate process) localizes from
them. Held to the accuracy bounds of the host-build SIL test (tests/test_sim_e2e.py)."""

import json
import subprocess
import sys

from qemu_support import build_qemu_images


def test_four_qemu_anchors_localize_within_the_host_sil_bounds(tmp_path):
    build_qemu_images()
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--anchor-backend", "qemu",
           "--gateway", "--odom", "--speed", "3", "--duration", "20", "--seed", "3", "--out-dir", str(tmp_path),
           "--json", "--wait", "15"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    sim, gw, s = doc["sim"], doc["gateway"], doc["score"]
    assert gw is not None, r.stderr[-3000:]

    # Every reading went into a QEMU anchor; every anchor's reports reached the gateway.
    injected = sim["qemu"]["injected"]
    assert set(injected) == set(gw["anchors"]) == {"1", "2", "3", "4"}
    assert sum(injected.values()) == sim["radio"]["readings"] > 0
    for a, g in gw["anchors"].items():
        assert g["received"] == sim["beacons"] and g["lost"] == 0 and g["duplicates"] == 0, (a, g)
    assert gw["errors"] == {}
    assert gw["status"] >= 4 * 19  # STATUS once a second of injected time, per anchor

    # The same bounds as the host SIL end-to-end test (which also has link faults).
    assert s["coverage"] > 0.85
    assert s["median_m"] < 0.8 and s["p95_m"] < 1.6 and s["rmse_m"] < 1.0, s
    assert len(sim["qemu"]["positions"]) >= 4
