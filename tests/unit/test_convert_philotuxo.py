"""tools/convert_philotuxo.py on a tiny track written here: time order (an instant's readings in
sensor order), sensors renumbered as cnf/tetam.dev lists them, each reading its own annotation,
impossible readings dropped; read back by pfdoa's own trace reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa._toml import loads
from pfdoa.trace import read_trace

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def tool():
    with tool_module("convert_philotuxo") as module:
        yield module


def _dataset(src: Path) -> None:
    (src / "cnf").mkdir(parents=True)
    (src / "trk").mkdir()
    (src / "cnf" / "tetam.dev").write_text(
        'Dongles:{"bb": [[1.0, 2.0, 1.22], 1, "sensor10"], "aa": [[3.0, 4.0, 2.30], 2, "sensor11"]}\n'
        'Beacons:{"e7": [[], 1, "beacon1"] }\n')
    rot = ",1,0,0,0,1,0,0,0,1"
    (src / "trk" / "straight_02_all_sensors.mbd").write_text("\n".join([
        f"100.5004,aa,e7,-60,1.0004,1.0,1.8{rot}",
        f"100.5,aa,e7,-61,1.0,1.0,1.8{rot}",  # earlier than the line above: sorted
        f"100.5,bb,e7,-70,1.0,1.0006,1.8{rot}",  # same instant: sensor order (bb is sensor 0)
        f"101.25,bb,e7,42,2.0,2.0,1.8{rot}",  # an impossible reading: dropped
        f"101.7,aa,e7,-65,2.5,2.0,1.9{rot}",
    ]) + "\n")


def test_a_track_becomes_a_run_in_time_then_sensor_order_with_each_readings_annotation(tool, tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    _dataset(src)
    assert tool.main([str(src), str(out), "--tracks", "straight_02"]) == 0
    tr = read_trace(out / "straight_02.csv.gz")
    np.testing.assert_allclose(tr.t, [0.0, 0.0, 0.0, 1.2])  # from the first reading, to the millisecond
    assert tr.anchor.tolist() == [0, 1, 1, 1]
    assert tr.rssi_dbm.tolist() == [-70.0, -61.0, -60.0, -65.0]
    assert tr.gt_x is not None and tr.gt_y is not None
    np.testing.assert_allclose(tr.gt_x, [1.0, 1.0, 1.0, 2.5])
    np.testing.assert_allclose(tr.gt_y, [1.001, 1.0, 1.0, 2.0])  # each reading its own, to the millimetre


def test_unknown_tracks_and_folders_are_refused_with_exit_2(tool, tmp_path, capsys):
    assert tool.main([str(tmp_path), str(tmp_path / "out")]) == 2
    assert "no cnf/tetam.dev" in capsys.readouterr().err
    _dataset(tmp_path / "src")
    assert tool.main([str(tmp_path / "src"), str(tmp_path / "out"), "--tracks", "nope"]) == 2
    assert "choose from" in capsys.readouterr().err


def _points(src: Path) -> None:
    """Two sets of reference points: set_1 two points (the second recorded first), set_2 one."""
    for name, points in (("set_1", [((5.0, 6.0, 1.85), 1000.0), ((1.5, 2.5, 2.05), 100.0)]),
                         ("set_2", [((3.0, 3.0, 1.85), 5000.0)])):
        folder = src / "hst" / name
        folder.mkdir(parents=True)
        for (x, y, z), t0 in points:
            for alias, mac, rssi in (("sensor10", "bb", -70), ("sensor11", "aa", -60)):
                # a reading a second from t0 for 100 s; the kept ones: from 60 s for 20 s
                lines = [f"{t0 + k + (0.25 if mac == 'aa' else 0.0):.6f},{mac},e7,{rssi - k // 10}" for k in range(100)]
                lines.append(f"{t0 + 70.5:.6f},{mac},e7,29")  # impossible: dropped
                (folder / f"{alias}_{x:.2f}_{y:.2f}_{z:.2f}.mbd").write_text("\n".join(lines) + "\n")
    (src / "hst" / "set_1" / "tetam_multi_rssi.hst").write_text("Bins: []\n")  # not a point file: ignored


def test_reference_points_become_one_run_per_set_of_20_s_per_point_in_recorded_order(tool, tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    _dataset(src)
    _points(src)
    assert tool.main(["--points", str(src), str(out)]) == 0
    tr = read_trace(out / "set_1.csv.gz")
    assert tr.gt_x is not None and tr.gt_y is not None
    # the point recorded first (at t0 = 100 s) comes first: its seconds 60-79, both sensors
    first = tr.gt_x == 1.5
    assert first[:40].all() and not first[40:].any() and len(tr.t) == 80
    np.testing.assert_allclose(tr.t[:4], [0.0, 0.25, 1.0, 1.25])
    assert tr.anchor[:4].tolist() == [0, 1, 0, 1]
    assert tr.rssi_dbm[:2].tolist() == [-76.0, -66.0] and tr.rssi_dbm[38:40].tolist() == [-77.0, -67.0]  # seconds 60-79
    # the second point: its own 20 s, 900 s later, the gap kept
    np.testing.assert_allclose(tr.t[40], 900.0)
    assert set(zip(tr.gt_x[40:].tolist(), tr.gt_y[40:].tolist())) == {(5.0, 6.0)}
    assert tr.rssi_dbm.max() < -20.0  # the impossible readings dropped
    assert len(read_trace(out / "set_2.csv.gz").t) == 40
    site = loads((out / "site.toml").read_text())  # two sensors here: too few for load_site
    assert [(a["x"], a["y"], a["z"]) for a in site["anchors"]] == [(1.0, 2.0, 1.22), (3.0, 4.0, 2.3)]
    assert site["site"]["target_z"] == 1.85  # the median height of the three points


def test_points_without_their_sets_are_refused_with_exit_2(tool, tmp_path, capsys):
    _dataset(tmp_path / "src")
    assert tool.main(["--points", str(tmp_path / "src"), str(tmp_path / "out")]) == 2
    assert "convert_philotuxo:" in capsys.readouterr().err
