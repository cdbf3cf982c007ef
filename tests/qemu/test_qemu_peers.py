"""Anchors that hear each other, on the Cortex-M3 firmware image: four QEMU anchors send
their own advertisements (RADIO_TX frames of the SIL image), the simulator delivers them to
the others (RADIO_INJECT_RAW), and `pfdoa sim --gateway --peers` gives the gateway their peer
readings; every byte equals the host build's, and the gateway's peer fit is the c backend's
for the same seed. The longer run's numbers: docs/peer-calibration.md (`--qemu`)."""

import json
import subprocess
import sys

from qemu_support import build_qemu_images


def sim(tmp_path, backend):
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--anchor-backend", backend,
           "--gateway", "--duration", "8", "--seed", "2", "--peers", "1000", "--out-dir", str(tmp_path), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    (doc,) = json.loads(r.stdout)
    assert doc["gateway"] is not None, r.stderr[-3000:]
    return doc


def test_qemu_anchors_send_and_report_peer_readings_as_the_host_build(tmp_path):
    build_qemu_images()
    q, c = sim(tmp_path / "qemu", "qemu"), sim(tmp_path / "c", "c")
    qs, gw = q["sim"], q["gateway"]
    assert qs["qemu"]["byte_mismatches"] == 0 and min(qs["qemu"]["bytes_compared"].values()) > 1000
    peers = qs["peers"]
    assert peers["sent"] >= 4 * 8 and peers["heard"] == 3 * 3 * peers["sent"]  # 3 others, 3 channels each
    assert gw["peer_readings"] == peers["heard"] == c["gateway"]["peer_readings"]
    fit = gw["peers"]["fit"]
    assert fit is not None and fit["links"] == 12
    assert fit == c["gateway"]["peers"]["fit"]  # the same readings: the same fit
