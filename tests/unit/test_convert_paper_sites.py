"""tools/convert_pachos.py and tools/convert_szelinski.py on tiny inputs written here: the runs
they write (points as ground truth, readings per point, the test points' x and y read swapped,
the anchors' middle readings per point and channel) read back by pfdoa's own trace reader, and
bad inputs refused with exit 2 before anything is written."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa.site import load_site
from pfdoa.trace import read_trace

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def pachos():
    with tool_module("convert_pachos") as module:
        yield module


@pytest.fixture(scope="module")
def szelinski():
    with tool_module("convert_szelinski") as module:
        yield module


def test_pachos_writes_a_site_per_radio_with_its_two_collections(pachos, tmp_path):
    src, out = tmp_path / "dataset1", tmp_path / "out"
    src.mkdir()
    for tech in ("wifi", "ble", "zigbee"):
        (src / f"{tech}-dataset1.csv").write_text("x,y,RSSI A,RSSI B,RSSI C\n0.5,0.5,75,93,87\n0.5,1,70,88,85\n")
        (src / f"{tech}-testdata.csv").write_text("Point,x,y,RSSI A,RSSI B,RSSI C\n1,1,0,72,85,87\n")
    assert pachos.main([str(src), str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["pachos_ble", "pachos_wifi", "pachos_zigbee"]
    grid = read_trace(out / "pachos_zigbee" / "fingerprints.csv.gz")
    np.testing.assert_allclose(grid.t, [0, 0, 0, 1, 1, 1])  # a point a second, its readings together
    assert grid.anchor.tolist() == [0, 1, 2] * 2 and grid.rssi_dbm.tolist() == [-75, -93, -87, -70, -88, -85]
    assert grid.gt_x is not None and grid.gt_y is not None
    np.testing.assert_allclose(np.column_stack([grid.gt_x, grid.gt_y]), [[0.5, 0.5]] * 3 + [[0.5, 1.0]] * 3)
    tests = read_trace(out / "pachos_zigbee" / "tests.csv.gz")
    assert tests.gt_x is not None and tests.gt_y is not None
    assert (tests.gt_x[0], tests.gt_y[0]) == (0.0, 1.0)  # stored transposed: read swapped
    site = load_site(out / "pachos_zigbee" / "site.toml")
    assert site.positions.tolist() == [[0, 0], [0, 4], [4, 0]] and site.radio.rssi_at_1m_dbm == -60.0
    meta = json.loads((out / "pachos_zigbee" / "anchors.json").read_text())
    assert meta["technology"] == "zigbee" and meta["license"].startswith("MIT") and meta["runs"] == ["fingerprints", "tests"]


def test_pachos_refuses_a_missing_file_and_writes_nothing(pachos, tmp_path, capsys):
    (tmp_path / "dataset1").mkdir()
    assert pachos.main([str(tmp_path / "dataset1"), str(tmp_path / "out")]) == 2
    assert "wifi-dataset1.csv" in capsys.readouterr().err and not (tmp_path / "out").exists()


def _anchor_file(folder: Path, a: int, points, anchor_xy, rows_per=3, distance_offset=0.0) -> None:
    lines = ["anchor;x;y;distance;distance_cm;channel;rssi"]
    for (x, y) in points:
        d = float(np.hypot(x - anchor_xy[0], y - anchor_xy[1])) + distance_offset
        for ch in (0, 1):
            lines += [f"s{a};{x};{y};{d};{round(d * 100)};{ch};{-40 - a - 10 * ch - j}" for j in range(rows_per)]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"s{a}.csv").write_text("\n".join(lines) + "\n")


def test_szelinski_pairs_the_anchors_middle_readings_per_point_and_channel(szelinski, tmp_path):
    src, out = tmp_path / "measurements", tmp_path / "out"
    for run, pts in (("diag0", [(1, 1), (2, 2)]), ("diag1", [(1, 9)])):
        for a, xy in enumerate(szelinski.ANCHORS):
            _anchor_file(src / run, a, pts, xy)
    with gzip.open(src / "diag1" / "s3.csv.gz", "wt") as fh:  # gzipped files are read too
        fh.write((src / "diag1" / "s3.csv").read_text())
    (src / "diag1" / "s3.csv").unlink()
    assert szelinski.main([str(src), str(out)]) == 0
    tr = read_trace(out / "szelinski_ble_diag" / "diag0.csv.gz")
    # 2 points x 2 channels: 4 observations a second apart, each of the 4 anchors' middle reading (j = 1)
    np.testing.assert_allclose(tr.t, np.repeat([0, 1, 2, 3], 4))
    assert tr.rssi_dbm[:8].tolist() == [-41, -42, -43, -44, -51, -52, -53, -54]
    assert tr.gt_x is not None and tr.gt_x.tolist() == [1.0] * 8 + [2.0] * 8
    assert len(read_trace(out / "szelinski_ble_diag" / "diag1.csv.gz").t) == 2 * 4


def test_szelinski_refuses_an_anchor_whose_distances_do_not_match_its_position(szelinski, tmp_path, capsys):
    src = tmp_path / "measurements"
    for run in ("diag0", "diag1"):
        for a, xy in enumerate(szelinski.ANCHORS):
            _anchor_file(src / run, a, [(1, 9)], xy, distance_offset=0.5 if (run, a) == ("diag1", 1) else 0.0)
    assert szelinski.main([str(src), str(tmp_path / "out")]) == 2
    assert "is not the distance to anchor s1" in capsys.readouterr().err and not (tmp_path / "out").exists()
