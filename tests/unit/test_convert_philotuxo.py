"""tools/convert_philotuxo.py on a tiny track written here: time order (an instant's readings in
sensor order), sensors renumbered as cnf/tetam.dev lists them, each reading its own annotation,
impossible readings dropped; read back by pfdoa's own trace reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tools_support import tool_module

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
