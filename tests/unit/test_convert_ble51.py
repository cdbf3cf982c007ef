"""tools/convert_ble51.py: the waypoint ground truth (stops held), the readings kept and dropped,
and its runs read back by pfdoa's own trace reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa.trace import read_trace


@pytest.fixture(scope="module")
def tool():
    with tool_module("convert_ble51") as module:
        yield module


def _room(tool, src: Path):
    """A two-anchor room in the Byongho96 layout: one file per anchor, waypoints in cm and ms,
    a stop at (300, 0) from 12 s to 15 s."""
    (src / "gt").mkdir(parents=True)
    (src / "gt" / "walk.csv").write_text(
        "StartTimeISO,StartTimestamp,EndTimeISO,EndTimestamp,X,Y,Z\n"
        "a,10000,,,100,0,140\n"
        "b,12000,c,15000.0,300,0,140\n"
        "d,16000,,,300,200,140\n")
    for k, aid in enumerate(("AA", "BB"), start=1):
        lines = ["Timestamp,Tag,RSSI,Azimuth,Elevation,Channel,Anchor,Sequence"]
        # 9.5 s (before the first waypoint) and 16.5 s (after the last) are dropped
        lines += [f"{ms},T,{-50 - k - i},0,0,37,{aid},{i}" for i, ms in enumerate((9500, 11000, 13500, 15500, 16500))]
        (src / f"anchor{k}.csv").write_text("\n".join(lines) + "\n")
    run = tool.Run("walk", "gt/walk.csv", ("anchor1.csv", "anchor2.csv"))
    return tool.Room("room", "a test room", ((0.0, 0.0), (5.0, 0.0)), ("AA", "BB"), (run,), ()), run


@pytest.mark.unit
def test_a_converted_run_holds_the_stops_and_drops_readings_outside_the_walk(tool, tmp_path: Path) -> None:
    room, run = _room(tool, tmp_path / "src")
    out = tmp_path / "out"
    out.mkdir()
    assert tool.write_run(tmp_path / "src", room, run, out) == 6  # 3 times x 2 anchors
    tr = read_trace(out / "walk.csv")
    np.testing.assert_allclose(tr.t, [1.0, 1.0, 3.5, 3.5, 5.5, 5.5])  # from the first waypoint
    assert tr.anchor.tolist() == [0, 1, 0, 1, 0, 1]  # renumbered in the room's order
    assert tr.rssi_dbm.tolist() == [-52.0, -53.0, -53.0, -54.0, -54.0, -55.0]
    assert tr.gt_x is not None and tr.gt_y is not None
    # halfway to the stop; inside the stop (held at 3 m, 0); halfway from its end to the last point
    np.testing.assert_allclose(tr.gt_x, [2.0, 2.0, 3.0, 3.0, 3.0, 3.0])
    np.testing.assert_allclose(tr.gt_y, [0.0, 0.0, 0.0, 0.0, 1.0, 1.0])


@pytest.mark.unit
def test_an_anchor_the_room_does_not_name_is_refused_by_name(tool, tmp_path: Path) -> None:
    room, run = _room(tool, tmp_path / "src")
    other = tool.Room(room.name, room.what, room.anchors, ("AA", "CC"), room.runs, ())
    with pytest.raises(ValueError, match="'BB' is not one of the room's AA, CC"):
        tool.write_run(tmp_path / "src", other, run, tmp_path)


@pytest.mark.unit
def test_a_folder_without_the_dataset_is_refused_with_exit_2(tool, tmp_path: Path, capsys) -> None:
    assert tool.main([str(tmp_path), str(tmp_path / "out")]) == 2
    assert "no dataset/ folder" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.unit
def test_a_room_whose_source_gives_both_heights_carries_them_in_its_site_file(tool, tmp_path: Path, monkeypatch) -> None:
    from pfdoa.site import load_site

    two, _run = _room(tool, tmp_path / "src")
    room = tool.Room(two.name, two.what, two.anchors + ((2.5, 4.0),), two.source_ids + ("CC",), two.runs, ())
    high = tool.Room(room.name, room.what, room.anchors, room.source_ids, room.runs, (), "a person", (2.5, 1.0))
    monkeypatch.setattr(tool, "ROOMS", (lambda: high,))
    assert tool.convert(tmp_path / "src", tmp_path / "out") == ["room"]
    site = load_site(tmp_path / "out" / "room" / "site.toml")
    assert site.target_z == 1.0 and site.heights.tolist() == [1.5, 1.5, 1.5]
    monkeypatch.setattr(tool, "ROOMS", (lambda: room,))  # no heights given: none written
    tool.convert(tmp_path / "src", tmp_path / "flat")
    assert load_site(tmp_path / "flat" / "room" / "site.toml").heights.tolist() == [0.0, 0.0, 0.0]
