"""tools/convert_sodindoorloc.py on a tiny made-up source in the dataset's layout (the AP .xlsx, the
scan sheets of three buildings): one site per qualifying floor, each MAC an anchor renumbered by AP
and band, a scan a second, at most 10 scans per point, undetected values and other floors' APs
dropped, an AP whose RSS rises with distance dropped; bad inputs refused with exit 2 before anything
is written; the same bytes every time. No network, no snapshot."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa.site import load_site
from pfdoa.trace import read_trace

pytestmark = pytest.mark.unit

INFO = ["ECoord", "NCoord", "FloorID", "BuildingID", "SceneID", "UserID", "PhoneID", "SampleTimes"]
AP_HEADER = ["ID", "ECoord", "NCoord", "FloorID", "Attribute_2.4", "Frequency_2.4", "Attribute_5", "Frequency_5"]
# CETC331 (dual-band): floor 1 has APs 1-4 at a 10 m square's corners and AP 5, whose RSS rises with
# distance; floor 2 has AP 6 alone (fewer than 4 APs heard: not a site). AP n's MACs: MAC<2n-1>, MAC<2n>.
CETC = [(1, 0.0, 0.0, 1), (2, 10.0, 0.0, 1), (3, 10.0, 10.0, 1), (4, 0.0, 10.0, 1), (5, 5.0, 20.0, 1), (6, 5.0, 5.0, 2)]
# HCXY (single-band) and SYL (dual-band): four APs on floor 4, around 900 m in HCXY's frame
HCXY = [(1, 900.0, 900.0, 4), (2, 912.0, 900.0, 4), (3, 912.0, 906.0, 4), (4, 900.0, 906.0, 4)]
SYL = [(1, 20.0, 2.0, 4), (2, 40.0, 2.0, 4), (3, 40.0, 14.0, 4), (4, 20.0, 14.0, 4)]


def _xlsx(path: Path, sheets: dict[str, list[list]]) -> None:
    """A minimal .xlsx as Excel writes it: text in the shared strings, numbers inline, an empty
    cell left out."""
    strings: list[str] = []

    def cell(ref: str, v) -> str:
        if v is None:
            return ""
        if isinstance(v, str):
            strings.append(v)
            return f'<c r="{ref}" t="s"><v>{len(strings) - 1}</v></c>'
        return f'<c r="{ref}"><v>{v!r}</v></c>'

    ns = 'xmlns="http://schemas.openxmlformats.org/spreadsheetml/2006/main"'
    rel = 'xmlns:r="http://schemas.openxmlformats.org/officeDocument/2006/relationships"'
    with zipfile.ZipFile(path, "w") as z:
        for k, rows in enumerate(sheets.values(), start=1):
            xml = "".join(f'<row r="{i}">' + "".join(cell(f"{'ABCDEFGH'[j]}{i}", v) for j, v in enumerate(row))
                          + "</row>" for i, row in enumerate(rows, start=1))
            z.writestr(f"xl/worksheets/sheet{k}.xml", f"<worksheet {ns}><sheetData>{xml}</sheetData></worksheet>")
        z.writestr("xl/workbook.xml", f"<workbook {ns} {rel}><sheets>" + "".join(
            f'<sheet name="{name}" sheetId="{k}" r:id="rId{k}"/>' for k, name in enumerate(sheets, start=1))
            + "</sheets></workbook>")
        z.writestr("xl/_rels/workbook.xml.rels", '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/'
                   'relationships">' + "".join(f'<Relationship Id="rId{k}" Target="worksheets/sheet{k}.xml"/>'
                                               for k in range(1, len(sheets) + 1)) + "</Relationships>")
        z.writestr("xl/sharedStrings.xml", f"<sst {ns}>" + "".join(f"<si><t>{escape(s)}</t></si>" for s in strings)
                   + "</sst>")


def _macs(aps, dual: bool) -> dict[int, list[str]]:
    return {ap: ([f"MAC{2 * ap - 1}", f"MAC{2 * ap}"] if dual else [f"MAC{100 + ap}"]) for ap, *_ in aps}


def _rss(ap, mac_k: int, x: float, y: float, scan: int) -> float:
    """The made-up RSS: -40 dB at 1 m, n = 2 (5 GHz 6 dB lower); AP 5 of CETC331 the other way;
    100 (not detected) beyond 25 m, and where a scan's number picks it out."""
    n, ax, ay, _floor = ap
    d = max(float(np.hypot(x - ax, y - ay)), 0.5)
    if d > 25.0 or (scan + n) % 7 == 0:
        return 100.0
    slope = 20.0 if n == 5 and ax == 5.0 else -20.0
    return float(round(-40.0 + slope * np.log10(d) - 6.0 * mac_k - (scan % 3)))


def _sheet(path: Path, aps, macs: dict[int, list[str]], building_id: int, points: list[tuple[float, float, int, int]],
           order: list[str] | None = None) -> None:
    """A scan sheet: ``points`` (x, y, floor, scans) in order, every AP's MACs heard on every floor."""
    cols = order or [m for ap, *_ in aps for m in macs[ap]]
    by_mac = {m: (ap, k) for ap in aps for k, m in enumerate(macs[ap[0]])}
    lines = [",".join(cols + INFO)]
    for x, y, floor, scans in points:
        for s in range(scans):
            rss = [_rss(*by_mac[m], x, y, s) for m in cols]
            lines.append(",".join([f"{v:g}" for v in rss] + [f"{x:g}", f"{y:g}", str(floor), str(building_id), "1", "4",
                                                               "3", str(s + 1)]))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def _ap_rows(aps, macs, dual: bool) -> list[list]:
    return [AP_HEADER] + [[ap, x, y, f, macs[ap][0], 2412] + ([macs[ap][1], 5745] if dual else [None, None])
                          for ap, x, y, f in aps]


def _source(src: Path, cetc=CETC) -> None:
    """The three buildings: CETC331 floor 1 a 3 x 3 grid, one scan a point (training) and two
    points of 12 scans (testing), floor 2 three points; HCXY and SYL four points of 12 scans
    (training) and two of 10 (testing)."""
    mc, mh, ms = _macs(cetc, True), _macs(HCXY, False), _macs(SYL, True)
    src.mkdir(parents=True, exist_ok=True)
    _xlsx(src / "Information of pre-installed APs.xlsx",
          {"CETC331": _ap_rows(cetc, mc, True), "HCXY": _ap_rows(HCXY, mh, False), "SYL": _ap_rows(SYL, ms, True)})
    grid = [(float(x), float(y), 1, 1) for x in (1, 5, 9) for y in (1, 5, 9)]
    _sheet(src / "CETC331/Training_CETC331.csv", CETC, mc, 1, grid + [(4.0, 4.0, 2, 1), (6.0, 6.0, 2, 1)])
    _sheet(src / "CETC331/Testing_CETC331.csv", CETC, mc, 1, [(2.0, 3.0, 1, 12), (7.0, 8.0, 1, 12), (5.0, 6.0, 2, 10)])
    for name, bid, aps, macs in (("HCXY", 2, HCXY, mh), ("SYL", 3, SYL, ms)):
        (x0, y0), (x1, y1) = (aps[0][1], aps[0][2]), (aps[2][1], aps[2][2])
        pts = [(x0 + (x1 - x0) * fx, y0 + (y1 - y0) * fy, 4, 12)
               for fx, fy in ((0.2, 0.3), (0.8, 0.5), (0.5, 0.9), (0.1, 0.8), (0.6, 0.2), (0.4, 0.6))]
        order = [m for ap, *_ in reversed(aps) for m in macs[ap]]  # the sheets' own column order, not the AP file's
        _sheet(src / name / f"Training_{name}_AP_30.csv", aps, macs, bid, pts[:4], order)
        _sheet(src / name / f"Testing_{name}_AP.csv", aps, macs, bid, [p[:3] + (10,) for p in pts[4:]], order)


@pytest.fixture(scope="module")
def tool():
    with tool_module("convert_sodindoorloc") as module:
        yield module


def test_a_site_per_qualifying_floor_each_mac_an_anchor_a_scan_a_second(tool, tmp_path, capsys):
    src, out = tmp_path / "src", tmp_path / "out"
    _source(src)
    assert tool.main([str(src), str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["sod_cetc331_1", "sod_hcxy_4", "sod_syl_4"]
    assert "skipped sod_cetc331_2" in capsys.readouterr().out
    site_dir = out / "sod_cetc331_1"
    assert sorted(p.name for p in site_dir.iterdir()) == ["anchors.json", "site.toml", "test.csv.gz", "train.csv.gz"]
    site = load_site(site_dir / "site.toml")
    # APs 1-4, each its 2.4 GHz then its 5 GHz MAC; AP 5 (RSS rising with distance) and AP 6 (floor 2) are not anchors
    np.testing.assert_allclose(site.positions, np.repeat([c[1:3] for c in CETC[:4]], 2, axis=0))
    assert site.radio.rssi_at_1m_dbm == -60.0 and site.radio.path_loss_exponent == 2.0 and site.target_z == 0.0
    train, test = read_trace(site_dir / "train.csv.gz"), read_trace(site_dir / "test.csv.gz")
    assert train.gt_x is not None and train.gt_y is not None and test.gt_x is not None and test.gt_y is not None
    # training: nine points, one scan each, a second apart; (1, 1) is 1.41 m from AP 1
    assert sorted(set(train.t.tolist())) == [float(k) for k in range(9)]
    first = train.t == 0.0
    assert train.anchor[first].tolist() == list(range(8))
    assert train.rssi_dbm[first].tolist()[:2] == [_rss(CETC[0], k, 1.0, 1.0, 0) for k in (0, 1)]
    assert (train.gt_x[first][0], train.gt_y[first][0]) == (1.0, 1.0)
    # testing: two points of 12 scans, the first 10 kept, t 0..19; a scan's undetected values dropped
    assert sorted(set(test.t.tolist())) == [float(k) for k in range(20)]
    assert (test.gt_x[test.t == 10.0][0], test.gt_y[test.t == 10.0][0]) == (7.0, 8.0)
    scan6 = test.anchor[test.t == 6.0].tolist()  # (6 + 1) % 7 == 0: AP 1 not detected in scan 6
    assert scan6 == [2, 3, 4, 5, 6, 7]
    meta = json.loads((site_dir / "anchors.json").read_text())
    assert meta["license"].startswith("no licence stated") and meta["commit"] == tool.COMMIT
    assert meta["anchor_ids_in_source"][:2] == ["AP1 MAC1 (2.4 GHz)", "AP1 MAC2 (5 GHz)"]
    assert [(r["ap"], r["mac"]) for r in meta["dropped"]["radios"]] == [("AP5", "MAC9"), ("AP5", "MAC10")]
    assert all(r["correlation"] > -0.3 for r in meta["dropped"]["radios"])
    assert meta["dropped"]["scans_over_cap"] == 4 and meta["dropped"]["other_floor_ap_readings"] > 0
    assert meta["position_check"]["median_correlation"] < -0.9
    assert meta["run_stats"]["test"]["scans"] == 20 and meta["run_stats"]["test"]["scans_in_sheet"] == 24
    # HCXY: single-band, its sheets' columns in their own order; 912 m etc. kept as given
    hcxy = load_site(out / "sod_hcxy_4" / "site.toml")
    np.testing.assert_allclose(hcxy.positions, [c[1:3] for c in HCXY])
    assert len(load_site(out / "sod_syl_4" / "site.toml").anchors) == 8
    assert len(set(read_trace(out / "sod_hcxy_4" / "train.csv.gz").t.tolist())) == 40  # 4 points x 10 of 12 scans


def test_two_conversions_give_the_same_bytes(tool, tmp_path):
    _source(tmp_path / "src")
    outs = [tmp_path / "a", tmp_path / "b"]
    for out in outs:
        assert tool.main([str(tmp_path / "src"), str(out), "--building", "cetc331"]) == 0
    files = sorted(p.relative_to(outs[0]) for p in outs[0].rglob("*") if p.is_file())
    assert len(files) == 4
    for f in files:
        assert (outs[0] / f).read_bytes() == (outs[1] / f).read_bytes(), f


def _bad(src: Path, case: str) -> list[str]:
    """Spoil the source; the arguments to convert it with."""
    args = ["--building", "CETC331"]
    if case == "missing file":
        (src / "CETC331" / "Testing_CETC331.csv").unlink()
    elif case == "unparsable number":
        path = src / "CETC331" / "Training_CETC331.csv"
        lines = path.read_text().splitlines()
        lines[3] = lines[3].replace("-", "-x", 1)
        path.write_text("\n".join(lines) + "\n")
    elif case == "no AP positions":
        _xlsx(src / "Information of pre-installed APs.xlsx", {"CETC331": [AP_HEADER], "HCXY": [AP_HEADER],
                                                              "SYL": [AP_HEADER]})
    elif case == "positions that do not fit":  # APs 1 and 3, 2 and 4 swapped: each stated across the square
        swapped = [(1, 10.0, 10.0, 1), (2, 0.0, 10.0, 1), (3, 0.0, 0.0, 1), (4, 10.0, 0.0, 1)] + CETC[4:]
        mc = _macs(swapped, True)
        _xlsx(src / "Information of pre-installed APs.xlsx", {"CETC331": _ap_rows(swapped, mc, True),
                                                              "HCXY": [AP_HEADER], "SYL": [AP_HEADER]})
    elif case == "a floor that does not qualify":
        args += ["--floor", "2"]
    return args


@pytest.mark.parametrize("case, says", [("missing file", "Testing_CETC331.csv"),
                                        ("unparsable number", "line 4, MAC"),
                                        ("no AP positions", "states no AP positions"),
                                        ("positions that do not fit", "stated positions do not fit"),
                                        ("a floor that does not qualify", "sod_cetc331_2")])
def test_bad_inputs_are_refused_with_one_line_exit_2_and_nothing_written(tool, tmp_path, capsys, case, says):
    src, out = tmp_path / "src", tmp_path / "out"
    _source(src)
    args = _bad(src, case)
    assert tool.main([str(src), str(out), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("convert_sodindoorloc: ") and len(err.strip().splitlines()) == 1, err
    assert says in err, err
    assert not out.exists()
