"""tools/convert_feng_wifi.py on tiny inputs written here (a scan a second, APs not heard dropped,
grid units read as 0.6 m, the APs checked against the RTT ranges, bad inputs refused with exit 2
before anything is written), and on a source rebuilt from the committed feng_wifi_office runs:
it writes those runs and that site file again byte for byte."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa.evaluation import sites
from pfdoa.site import load_site
from pfdoa.trace import read_trace

pytestmark = pytest.mark.unit

OFFICE_APS = ((1, 5), (11, -1), (15, 6), (20, -1), (25, 5))  # grid units, as the dataset states them
HEADER = (["X", "Y"] + [f"AP{k} RTT(mm)" for k in range(1, 6)] + [f"AP{k} RSS(dBm)" for k in range(1, 6)]
          + ["LOS APs"])


@pytest.fixture(scope="module")
def tool():
    with tool_module("convert_feng_wifi") as module:
        yield module


def _source(src: Path, scans: dict[str, list[tuple[float, float, list[float]]]], aps=OFFICE_APS,
            rtt_swap: tuple[int, int] | None = None) -> None:
    """A checkout: LICENSE, the AP file (three rooms) and the office's two files, one line per
    (x, y, RSS of the five APs) scan in grid units, RTT the distance in mm (columns ``rtt_swap``
    exchanged)."""
    (src / "data").mkdir(parents=True)
    (src / "LICENSE").write_text("The MIT License (MIT)\n\nCopyright (c) 2014 someone\n")
    xs, ys = (",".join(f"{v:g}" for v in c) for c in zip(*aps))
    (src / "data" / "lecture theatre+office+corridor_AP_position.txt").write_text(
        f"lecture theatre\nAP X: 3,10,18.8,3,19\nAP Y: 9,9,9,21,21\n\noffice\nAP X: {xs}\nAP Y: {ys}\n\n"
        "corridor\nAP X:2,17,38,48\nAP Y:7.5,6.8,9,5")
    for run, rows in scans.items():
        lines = [",".join(HEADER)]
        for x, y, rss in rows:
            rtt = [100000.0 if r <= -200 else round(float(np.hypot(x - ax, y - ay)) * 600.0) for r, (ax, ay)
                   in zip(rss, OFFICE_APS)]
            if rtt_swap:
                i, j = rtt_swap
                rtt[i], rtt[j] = rtt[j], rtt[i]
            lines.append(",".join([f"{x:.1f}", f"{y:.1f}"] + [f"{v:.1f}" for v in rtt] + [f"{v:.1f}" for v in rss]
                                  + ["1 2"]))
        (src / "data" / f"database_office_{run}.csv").write_text("\n".join(lines) + "\n")


def _grid_scans() -> dict[str, list[tuple[float, float, list[float]]]]:
    pts = {"train": [(x, y) for x in range(0, 28, 3) for y in range(0, 8, 2)], "test": [(1, 1), (13, 4), (26, 6)]}
    return {run: [(x, y, [-50.0 - k - s if (x, y, k) != (0, 0, 2) else -200.0 for k in range(5)])
                  for x, y in p for s in range(2)] for run, p in pts.items()}


def test_a_scan_a_second_in_metres_with_unheard_aps_dropped(tool, tmp_path):
    src, out = tmp_path / "src", tmp_path / "out" / "feng_wifi_office"
    _source(src, _grid_scans())
    assert tool.main([str(src), str(out)]) == 0
    tr = read_trace(out / "train.csv.gz")
    # point (0, 0), two scans: AP3 (index 2) not heard at it; then (0, 2): 0.6 x 2 = 1.2 m
    np.testing.assert_allclose(tr.t[:13], [0] * 4 + [1] * 4 + [2] * 5)
    assert tr.anchor[:8].tolist() == [0, 1, 3, 4] * 2
    assert tr.rssi_dbm[:4].tolist() == [-50, -51, -53, -54] and tr.rssi_dbm[4:8].tolist() == [-51, -52, -54, -55]
    assert tr.gt_x is not None and tr.gt_y is not None
    assert (tr.gt_x[8], tr.gt_y[8]) == (0.0, 1.2)
    assert len(read_trace(out / "test.csv.gz").t) == 3 * 2 * 5
    site = load_site(out / "site.toml")
    np.testing.assert_allclose(site.positions, np.array(OFFICE_APS) * 0.6)
    assert site.radio.rssi_at_1m_dbm == -60.0 and site.radio.path_loss_exponent == 2.0
    meta = json.loads((out / "anchors.json").read_text())
    assert meta["technology"] == "wifi" and meta["license"].startswith("MIT") and meta["runs"] == ["train", "test"]
    assert meta["run_stats"]["train"]["not_heard"] == 2 and all(c["correlation"] > 0.99 for c in meta["rtt_check"])
    assert (out / tool.LICENSE_COPY).read_text().startswith("The MIT License")


@pytest.mark.parametrize("case", ["rtt columns swapped", "an AP moved", "no AP file", "no licence"])
def test_bad_sources_are_refused_with_exit_2_and_nothing_written(tool, tmp_path, capsys, case):
    src, out = tmp_path / "src", tmp_path / "out"
    moved = ((1, 5), (11, -1), (15, 6), (20, -1), (5, 20))
    _source(src, _grid_scans(), aps=moved if case == "an AP moved" else OFFICE_APS,
            rtt_swap=(0, 1) if case == "rtt columns swapped" else None)
    if case == "no AP file":
        (src / "data" / "lecture theatre+office+corridor_AP_position.txt").unlink()
    if case == "no licence":
        (src / "LICENSE").unlink()
    assert tool.main([str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("convert_feng_wifi: ") and len(err.strip().splitlines()) == 1
    assert {"rtt columns swapped": "AP1's RTT ranges", "an AP moved": "AP5's RTT ranges",
            "no AP file": "AP_position.txt", "no licence": "LICENSE"}[case] in err
    assert not out.exists()


def test_the_committed_runs_come_back_byte_for_byte_from_a_source_rebuilt_from_them(tool, tmp_path):
    """The office's two files rebuilt from the committed runs (a time per scan, RSS -200 where an AP
    is missing, RTT the distance) convert to the committed runs and site file, byte for byte."""
    committed = sites.DATA_DIR / "feng_wifi_office"
    assert sites.PROTOCOLS["feng_wifi_office"].develop == ("train", "test")
    aps = load_site(committed / "site.toml").positions / 0.6
    scans = {}
    for run in ("train", "test"):
        tr = read_trace(committed / f"{run}.csv.gz")
        assert tr.gt_x is not None and tr.gt_y is not None
        rows = []
        for k in np.split(np.arange(len(tr.t)), np.flatnonzero(np.diff(tr.t)) + 1):  # scan by scan
            rss = [-200.0] * 5
            for a, r in zip(tr.anchor[k].tolist(), tr.rssi_dbm[k].tolist()):
                rss[a] = r
            rows.append((round(tr.gt_x[k[0]] / 0.6, 6), round(tr.gt_y[k[0]] / 0.6, 6), rss))
        scans[run] = rows
    src, out = tmp_path / "src", tmp_path / "feng_wifi_office"
    _source(src, scans, aps=[tuple(round(v, 6) for v in a) for a in aps.tolist()])
    assert tool.main([str(src), str(out)]) == 0
    for name in ("train.csv.gz", "test.csv.gz", "site.toml"):
        assert (out / name).read_bytes() == (committed / name).read_bytes(), name
