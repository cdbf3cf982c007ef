"""Convert floors of the SODIndoorLoc Wi-Fi dataset to pfdoa site folders (local sites: not committed):
the pre-installed Wi-Fi access points of a building's floor (the anchors, at their stated positions)
and a smartphone held by hand at static points, up to ten scans at each.

Source: J. Bi, Y. Wang, B. Yu et al., "Supplementary open dataset for WiFi indoor localization based
on received signal strength", Satellite Navigation 3, 25 (2022), doi 10.1186/s43020-022-00086-y;
github.com/renwudao24/SODIndoorLoc at commit bfe8f63f55957cc25b23ba91c408ae345a3fb0b7. The
repository states no licence: the converted runs are NOT redistributed here (not committed); convert
them from a checkout into build/sites (host/pfdoa/data/README.md, "Local sites").

Read: ``Information of pre-installed APs.xlsx`` (one sheet per building: ID, ECoord, NCoord, FloorID
and the MAC attribute and channel of the AP's 2.4 GHz and, where dual-band, 5 GHz radio) and the
scans, one a row (``MAC..`` RSS columns, 100 where not detected, then ECoord, NCoord, FloorID,
BuildingID, SceneID, UserID, PhoneID, SampleTimes): ``CETC331/{Training,Testing}_CETC331.csv``,
``HCXY/Training_HCXY_AP_30.csv`` and ``HCXY/Testing_HCXY_AP.csv``, ``SYL/Training_SYL_AP_30.csv``
and ``SYL/Testing_SYL_AP.csv`` (the "AP" sheets carry the pre-installed APs' columns of the "All"
sheets; the "Avg" sheets are averages, not scans, and are not read).

One site per floor, ``sod_<building>_<floor>`` (sod_cetc331_1 .. 3, sod_hcxy_4, sod_syl_4): by
default every floor where at least 4 APs with a stated position on that floor are heard at most
points; ``--building`` takes one building's, ``--floor`` (with it) one floor, refused if it does not
qualify. Each has two runs, the dataset's sheets: ``train`` (the training sheet's points of that
floor) and ``test`` (the testing sheet's). Every radio (MAC) of a floor's APs is one anchor,
renumbered 0..N-1 by AP ID and band: a dual-band AP gives two anchors at one position. Readings of
APs on other floors or without a stated position, and values not detected, are dropped (counted in
anchors.json).

The scans carry no time: each point's scans in file order, one a second, the points back to back
in file order. Every point is kept, with at most 10 scans (the first in file order; the training
sheets of HCXY and SYL hold 30 at each point). Positions are the dataset's local frame in metres,
points and APs alike. Checked: each radio's RSS against log10 of the distance from the point to its
AP's stated position; a radio whose RSS does not fall with distance (correlation above -0.3), or
heard at fewer than 5 points, is dropped with a line in anchors.json; a floor whose radios' median
correlation is above -0.5 (the positions do not fit the data) is refused. The radio values in
site.toml are the neutral guess of every converter here (-60 dBm at 1 m, n = 2). No heights are
written (the APs' are not given).

    git clone https://github.com/renwudao24/SODIndoorLoc
    python tools/convert_sodindoorloc.py SODIndoorLoc build/sites
"""

from __future__ import annotations

import csv
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run, write_site_folder

COMMIT = "bfe8f63f55957cc25b23ba91c408ae345a3fb0b7"
REPO = "github.com/renwudao24/SODIndoorLoc"
AP_FILE = "Information of pre-installed APs.xlsx"
# building -> (its BuildingID in the sheets, {run: sheet})
BUILDINGS = {
    "CETC331": (1, {"train": "CETC331/Training_CETC331.csv", "test": "CETC331/Testing_CETC331.csv"}),
    "HCXY": (2, {"train": "HCXY/Training_HCXY_AP_30.csv", "test": "HCXY/Testing_HCXY_AP.csv"}),
    "SYL": (3, {"train": "SYL/Training_SYL_AP_30.csv", "test": "SYL/Testing_SYL_AP.csv"}),
}
RUNS = ("train", "test")
SCAN_COLUMNS = ("ECoord", "NCoord", "FloorID", "BuildingID", "SceneID", "UserID", "PhoneID", "SampleTimes")
NOT_DETECTED = 100.0  # the sheets' value of a MAC not detected in a scan
RSS_RANGE = (-110.0, 0.0)  # dBm, what a detected value may be (the data: -104 .. -5)
SCAN_S = 1.0  # made-up spacing of the scans (the data has no times)
MAX_SCANS_PER_POINT = 10
MIN_APS = 4  # APs (positions) heard at a point, at more than half the points, for a floor to qualify
MAX_AP_CORRELATION = -0.3  # a radio whose RSS correlates worse with log10 distance is dropped
MAX_MEDIAN_CORRELATION = -0.5  # a floor whose radios' median is worse does not fit its stated positions
MIN_POINTS = 5  # a radio heard at fewer points (or one value only): the correlation cannot tell, it is dropped
NEAR_M = 0.5  # distances below this count as this in log10(distance) (points under an AP)
# Table VII of the dataset's description (PDF): UserID -> height of the phone in the user's hand, cm
PHONE_HEIGHT_CM = {1: 109, 2: 132, 3: 123, 4: 116, 5: 101, 6: 125, 7: 127, 8: 125, 9: 134, 10: 131}
LICENSE = "no licence stated: not redistributed (convert from a checkout; not committed)"
CITATION = ("Bi, J., Wang, Y., Yu, B. et al. Supplementary open dataset for WiFi indoor localization based on received "
            "signal strength. Satellite Navigation 3, 25 (2022). https://doi.org/10.1186/s43020-022-00086-y")

_XLSX = "{http://schemas.openxmlformats.org/spreadsheetml/2006/main}"
_REL_ID = "{http://schemas.openxmlformats.org/officeDocument/2006/relationships}id"


@dataclass(frozen=True)
class Radio:
    """One MAC of a pre-installed AP (an anchor), as the AP sheet states it."""
    ap: int  # the AP's ID in its building's sheet
    mac: str  # the MAC's attribute name in the scan sheets (MAC<k>)
    band_ghz: str  # "2.4" or "5"
    frequency_mhz: float
    x: float  # ECoord, m
    y: float  # NCoord, m
    floor: int


@dataclass(frozen=True)
class Sheet:
    """A scan sheet: one row a scan, in file order."""
    name: str
    macs: tuple[str, ...]
    rss: np.ndarray  # (scans, macs) dBm, NaN where not detected
    info: dict[str, np.ndarray]  # SCAN_COLUMNS -> (scans,)


@dataclass
class Floor:
    """A converted floor, everything computed before anything is written."""
    name: str
    anchors: list[Radio]
    runs: dict[str, list[tuple[float, int, float, float, float]]]  # run -> (t, anchor, rssi, gt_x, gt_y)
    meta: dict
    comments: list[str]  # site.toml's


def _number(text: str | None, where: str) -> float:
    try:
        value = float(text if text is not None else "")
    except ValueError:
        raise ValueError(f"{where}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise ValueError(f"{where}: {text!r} is not a finite number")
    return value


def read_xlsx_sheet(path: Path, sheet: str) -> list[dict[str, str]]:
    """The rows of one sheet of an .xlsx file, as {header: cell text}, header from the first row
    (a stdlib reader: shared strings, inline strings and numbers; enough for the AP file)."""
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            strings = []
            if "xl/sharedStrings.xml" in names:
                root = ElementTree.fromstring(z.read("xl/sharedStrings.xml"))
                strings = ["".join(t.text or "" for t in si.iter(f"{_XLSX}t")) for si in root.findall(f"{_XLSX}si")]
            rels = {r.get("Id"): r.get("Target", "") for r in ElementTree.fromstring(z.read("xl/_rels/workbook.xml.rels"))}
            sheets = ElementTree.fromstring(z.read("xl/workbook.xml")).find(f"{_XLSX}sheets")
            target = next((rels.get(s.get(_REL_ID)) for s in (sheets if sheets is not None else [])
                           if s.get("name") == sheet), None)
            if target is None:
                raise ValueError(f"{path}: no sheet {sheet!r}")
            member = target.lstrip("/") if target.startswith("/") else f"xl/{target}"
            data = ElementTree.fromstring(z.read(member)).find(f"{_XLSX}sheetData")
    except (zipfile.BadZipFile, KeyError, ElementTree.ParseError) as exc:
        raise ValueError(f"{path}: not a readable .xlsx file ({exc})") from None
    table = []
    for row in data if data is not None else []:
        cells = {}
        for c in row.findall(f"{_XLSX}c"):
            col = "".join(ch for ch in c.get("r", "") if ch.isalpha())
            v, kind = c.find(f"{_XLSX}v"), c.get("t")
            if kind == "inlineStr":
                cells[col] = "".join(t.text or "" for t in c.iter(f"{_XLSX}t"))
            elif v is not None and v.text is not None:
                cells[col] = strings[int(v.text)] if kind == "s" else v.text
        table.append(cells)
    if not table:
        return []
    header = {col: text.strip() for col, text in table[0].items()}
    return [{header[col]: text.strip() for col, text in cells.items() if col in header} for cells in table[1:]
            if any(text.strip() for text in cells.values())]


def read_radios(path: Path, building: str) -> list[Radio]:
    """The building's pre-installed APs' radios, from its sheet of the AP file."""
    rows = read_xlsx_sheet(path, building)
    radios = []
    for k, row in enumerate(rows, start=2):
        where = f"{path.name}, sheet {building}, row {k}"
        for col in ("ID", "ECoord", "NCoord", "FloorID", "Attribute_2.4"):
            if not row.get(col):
                raise ValueError(f"{where}: no {col}")
        ap, x, y, floor = (_number(row[c], f"{where}, {c}") for c in ("ID", "ECoord", "NCoord", "FloorID"))
        for band in ("2.4", "5"):
            mac = row.get(f"Attribute_{band}")
            if mac:
                freq = _number(row.get(f"Frequency_{band}"), f"{where}, Frequency_{band}")
                radios.append(Radio(int(ap), mac, band, freq, x, y, int(floor)))
    if not radios:
        raise ValueError(f"{path.name}: sheet {building} states no AP positions")
    macs = [r.mac for r in radios]
    if len(set(macs)) != len(macs):
        raise ValueError(f"{path.name}: sheet {building} names a MAC twice")
    return radios


def read_sheet(path: Path, building_id: int) -> Sheet:
    """A scan sheet, every value checked (a number; an RSS in RSS_RANGE or NOT_DETECTED)."""
    with open(path, newline="") as fh:
        rows = csv.reader(fh)
        header = [h.strip().lstrip("\ufeff") for h in next(rows, [])]
        n = len(header) - len(SCAN_COLUMNS)
        if n < 1 or tuple(header[n:]) != SCAN_COLUMNS or not all(h.startswith("MAC") for h in header[:n]):
            raise ValueError(f"{path}: the header is not MAC.., {', '.join(SCAN_COLUMNS)}")
        values = []
        for line, row in enumerate(rows, start=2):
            if not row:
                continue
            if len(row) != len(header):
                raise ValueError(f"{path}, line {line}: {len(row)} values, the header has {len(header)}")
            values.append([_number(v, f"{path}, line {line}, {h}") for h, v in zip(header, row)])
    if not values:
        raise ValueError(f"{path}: no scans")
    table = np.array(values)
    rss = table[:, :n]
    bad = ~((rss == NOT_DETECTED) | ((rss >= RSS_RANGE[0]) & (rss <= RSS_RANGE[1])))
    if bad.any():
        i, j = (int(v[0]) for v in np.nonzero(bad))
        raise ValueError(f"{path}, line {i + 2}, {header[j]}: {rss[i, j]:g} is neither an RSS in dBm "
                         f"({RSS_RANGE[0]:g} .. {RSS_RANGE[1]:g}) nor {NOT_DETECTED:g} (not detected)")
    info = {c: table[:, n + k] for k, c in enumerate(SCAN_COLUMNS)}
    if np.any(info["BuildingID"] != building_id):
        raise ValueError(f"{path}: a scan of BuildingID {int(info['BuildingID'][info['BuildingID'] != building_id][0])}, "
                         f"this building's is {building_id}")
    return Sheet(path.name, tuple(header[:n]), np.where(rss == NOT_DETECTED, np.nan, rss), info)


def points(sheet: Sheet, floor: int) -> list[np.ndarray]:
    """The floor's points in file order: runs of consecutive scans at the same coordinates."""
    rows = np.flatnonzero(sheet.info["FloorID"] == floor)
    if rows.size == 0:
        return []
    xy = np.column_stack([sheet.info["ECoord"][rows], sheet.info["NCoord"][rows]])
    starts = np.flatnonzero(np.r_[True, np.any(xy[1:] != xy[:-1], axis=1)])
    return np.split(rows, starts[1:])


def _correlation(pts: np.ndarray, at: np.ndarray, rss: np.ndarray) -> float | None:
    """The correlation of ``rss`` with log10 of the distance from ``pts`` to ``at``; None where
    heard at fewer than MIN_POINTS points or all one value."""
    if len({tuple(q) for q in pts.tolist()}) < MIN_POINTS or np.ptp(rss) == 0:
        return None
    d = np.maximum(np.hypot(*(pts - at).T), NEAR_M)
    return float(np.corrcoef(np.log10(d), rss)[0, 1])


@dataclass(frozen=True)
class FloorScans:
    """One run's kept scans of a floor: at most MAX_SCANS_PER_POINT per point, in file order."""
    rows: np.ndarray  # the kept scans' rows in the sheet
    sizes: list[int]  # scans kept per point, the points in file order
    pts: np.ndarray  # (scans, 2) m
    rss: np.ndarray  # (scans, the floor's radios) dBm, NaN where not detected


def floor_scans(sheet: Sheet, groups: list[np.ndarray], own: list[Radio], placed: set[str],
                dropped: dict[str, int]) -> FloorScans:
    """The floor's kept scans of one sheet, counting into ``dropped`` what is left out."""
    rows = np.concatenate([g[:MAX_SCANS_PER_POINT] for g in groups])
    dropped["scans_over_cap"] += sum(max(len(g) - MAX_SCANS_PER_POINT, 0) for g in groups)
    col = {m: k for k, m in enumerate(sheet.macs)}
    rss = np.column_stack([sheet.rss[rows, col[r.mac]] if r.mac in col else np.full(rows.size, np.nan) for r in own])
    heard = ~np.isnan(sheet.rss[rows])
    own_macs = {r.mac for r in own}
    dropped["other_floor_ap_readings"] += int(heard[:, [m in placed and m not in own_macs for m in sheet.macs]].sum())
    dropped["no_position_readings"] += int(heard[:, [m not in placed for m in sheet.macs]].sum())
    dropped["not_detected"] += int(np.isnan(rss).sum())
    pts = np.column_stack([sheet.info["ECoord"][rows], sheet.info["NCoord"][rows]])
    return FloorScans(rows, [min(len(g), MAX_SCANS_PER_POINT) for g in groups], pts, rss)


def position_check(own: list[Radio], pts: np.ndarray, rss: np.ndarray) -> tuple[list[float | None], dict]:
    """Per radio, the correlation of its RSS with log10 of the distance to its AP's stated
    position (None: too few points to tell); and the figures of the floor's check."""
    where = {r.ap: np.array((r.x, r.y)) for r in own}  # the floor's APs' positions
    corr: list[float | None] = []
    others: list[float] = []  # per radio checked: its median correlation with the other APs' positions
    ranks: list[int] = []  # per radio checked: its own position's rank among the floor's APs' (1: the best fit)
    for k, r in enumerate(own):
        h = ~np.isnan(rss[:, k])
        c = _correlation(pts[h], where[r.ap], rss[h, k])
        corr.append(c)
        if c is not None:
            alt = [a for a in (_correlation(pts[h], at, rss[h, k]) for ap, at in where.items() if ap != r.ap)
                   if a is not None]
            others.append(float(np.median(alt)) if alt else 0.0)
            ranks.append(1 + sum(a < c for a in alt))
    checked = [c for c in corr if c is not None]
    figures = {
        "what": "per radio: the correlation of its RSS with log10 of the distance from the point to its AP's stated "
                f"position (distances below {NEAR_M} m as {NEAR_M} m), both runs' kept scans pooled",
        "median_correlation": round(float(np.median(checked)), 3) if checked else None,
        "radios_checked": len(checked),
        "median_correlation_with_other_aps_positions": round(float(np.median(others)), 3) if others else None,
        "own_position_fits_best": sum(k == 1 for k in ranks),
        "median_rank_of_own_position": float(np.median(ranks)) if ranks else None,
        "other_aps": "per radio, its RSS against the distance to each other AP's position on the floor (the median over "
                     "radios of their median), and its own position's rank among all the floor's APs' (1: the most "
                     "negative correlation; a neighbouring AP's position fits nearly as well)",
        "refused_if_median_above": MAX_MEDIAN_CORRELATION, "radio_dropped_if_above": MAX_AP_CORRELATION}
    return corr, figures


def convert_floor(building: str, floor: int, radios: list[Radio], sheets: dict[str, Sheet]) -> Floor | str:
    """The floor's site, or why it does not qualify (a string); ValueError where the stated
    positions do not fit the floor's RSS."""
    name = f"sod_{building.lower()}_{floor}"
    own = sorted((r for r in radios if r.floor == floor), key=lambda r: (r.ap, r.band_ghz != "2.4"))
    if not own:
        return f"{name}: no AP with a stated position on floor {floor}"
    groups = {run: points(sheet, floor) for run, sheet in sheets.items()}
    if any(not g for g in groups.values()):
        return f"{name}: no scans on floor {floor} in " + ", ".join(sheets[r].name for r, g in groups.items() if not g)
    dropped = {"scans_over_cap": 0, "not_detected": 0, "other_floor_ap_readings": 0, "no_position_readings": 0}
    placed = {r.mac for r in radios}
    scans = {run: floor_scans(sheet, groups[run], own, placed, dropped) for run, sheet in sheets.items()}
    rss = np.concatenate([s.rss for s in scans.values()])
    corr, check = position_check(own, np.concatenate([s.pts for s in scans.values()]), rss)
    median = check["median_correlation"]
    if median is None:
        return f"{name}: no AP of floor {floor} heard at {MIN_POINTS} points"
    if median > MAX_MEDIAN_CORRELATION:
        raise ValueError(f"{building} floor {floor}: the APs' stated positions do not fit the RSS (median correlation "
                         f"of RSS with log10 distance {median:.2f} over {check['radios_checked']} radios, at most "
                         f"{MAX_MEDIAN_CORRELATION} expected)")
    keep = [k for k, c in enumerate(corr) if c is not None and c <= MAX_AP_CORRELATION]
    readings = (~np.isnan(rss)).sum(axis=0)
    dropped_radios = []
    for k, r in enumerate(own):
        c = corr[k]
        if k not in keep:
            dropped_radios.append({
                "ap": f"AP{r.ap}", "mac": r.mac, "band_ghz": r.band_ghz, "readings": int(readings[k]),
                "correlation": None if c is None else round(c, 3),
                "why": f"heard at fewer than {MIN_POINTS} points or one value only: its position cannot be checked"
                       if c is None else f"its RSS does not fall with the distance to its stated position "
                                         f"(correlation {c:.2f} > {MAX_AP_CORRELATION})"})
    # Qualifying: at least MIN_APS APs (positions) heard at more than half the points.
    ap_of = np.array([own[k].ap for k in keep])
    n_points = n_ok = 0
    for s in scans.values():
        for block in np.split(s.rss[:, keep], np.cumsum(s.sizes)[:-1]):
            n_ok += len(set(ap_of[~np.isnan(block).all(axis=0)].tolist())) >= MIN_APS
            n_points += 1
    if n_ok * 2 <= n_points:
        return (f"{name}: {MIN_APS} or more APs heard at {n_ok} of {n_points} points, not most "
                f"({len(set(ap_of.tolist()))} APs kept)")
    anchors = [own[k] for k in keep]
    runs, stats = {}, {}
    for run, s in scans.items():
        kept = s.rss[:, keep]
        k_scan, k_anchor = np.nonzero(~np.isnan(kept))  # scan by scan, anchors in order
        runs[run] = [(float(t) * SCAN_S, int(a), float(v), float(x), float(y)) for t, a, v, (x, y) in
                     zip(k_scan.tolist(), k_anchor.tolist(), kept[k_scan, k_anchor].tolist(), s.pts[k_scan].tolist())]
        info = sheets[run].info
        users = sorted({int(u) for u in info["UserID"][s.rows]})
        stats[run] = {"sheet": sheets[run].name, "points": len(s.sizes), "scans": len(s.rows),
                      "scans_in_sheet": sum(len(g) for g in groups[run]), "readings": len(runs[run]),
                      "dropped_radio_readings": int((~np.isnan(s.rss)).sum()) - len(runs[run]),
                      "users": users, "phone_height_cm": {str(u): PHONE_HEIGHT_CM.get(u) for u in users},
                      "phones": sorted({int(v) for v in info["PhoneID"][s.rows]}),
                      "scenes": sorted({int(v) for v in info["SceneID"][s.rows]})}
    def ids(column: str) -> list[int]:  # the values of a column over both runs' kept scans
        return sorted({int(v) for run, s in scans.items() for v in sheets[run].info[column][s.rows]})

    cm = sorted(PHONE_HEIGHT_CM.get(u, 0) for u in ids("UserID"))
    heights = f"{cm[0]}-{cm[-1]} cm" if cm[0] > 0 else "a height not given"
    user_ids, phone_ids, scene_ids = (", ".join(map(str, ids(c))) for c in ("UserID", "PhoneID", "SceneID"))
    details = [{"anchor": i, "ap": f"AP{r.ap}", "mac": r.mac, "band_ghz": r.band_ghz, "frequency_mhz": r.frequency_mhz,
                "readings": int(readings[k]), "correlation": round(float(corr[k] or 0.0), 3)}
               for i, (k, r) in enumerate(zip(keep, anchors))]
    meta = {
        "source": f"{REPO} at {COMMIT}: {AP_FILE} (sheet {building}), "
                  + ", ".join(sheets[run].name for run in RUNS) + f"; {building} floor {floor}",
        "repo": REPO, "commit": COMMIT, "license": LICENSE, "citation": CITATION, "technology": "wifi",
        "target": "smartphone held in the hand at static points",
        "anchors": [[r.x, r.y] for r in anchors],
        "anchor_ids_in_source": [f"AP{r.ap} {r.mac} ({r.band_ghz} GHz)" for r in anchors],
        "anchor_sources": details,
        "runs": list(RUNS), "run_stats": stats,
        "run_names": f"train, test: the floor's points in the dataset's training and testing sheets "
                     f"({sheets['train'].name}, {sheets['test'].name})",
        "position_check": check,
        "dropped": {**dropped, "radios": dropped_radios},
        "caveats": [
            "The scans carry no time: one a second is made up, each point's scans in file order, the points back to "
            "back in file order (the order they were recorded in is not given).",
            f"At most {MAX_SCANS_PER_POINT} scans per point, the first in file order (run_stats scans of "
            "scans_in_sheet; dropped scans_over_cap): every point is kept.",
            "Each MAC of an AP is one anchor: a dual-band AP gives two anchors at the same position (its 2.4 GHz and "
            "5 GHz radios, whose path loss differs).",
            "Only the floor's own APs are anchors: readings of APs stated on other floors are dropped "
            "(dropped other_floor_ap_readings), as are MACs without a stated position and values not detected (100).",
            "Positions are the dataset's local frame in metres, transformed for privacy (not the CAD drawings' frame).",
            "The APs' heights are not given (the dataset's description: 'the height can be customized'); the phone "
            f"is held in the hand at {heights} (its Table VII, by user: run_stats phone_height_cm). "
            "No heights are written: a target_z without the APs' z would put the APs on the floor.",
            f"Scans by user(s) {user_ids} with phone(s) {phone_ids} (PhoneID; phones' RSS offsets differ), at points "
            f"of SceneID {scene_ids} (1 corridor or hall, "
            "2 office room, 3 meeting room).",
            "The Avg sheets (averages of the 30 scans) are not used; the AP sheets hold the All sheets' values for "
            "the pre-installed APs' MACs." if sheets["train"].name.endswith("_30.csv") else
            "The building has one training and one testing sheet, every column a pre-installed AP's MAC.",
        ] + [f"The {run} sheet holds one scan per point: the ground truth moves to the next point every second."
             for run, s in scans.items() if max(s.sizes) == 1],
    }
    comments = [f"{len(anchors)} Wi-Fi radios of {len({r.ap for r in anchors})} pre-installed access points (the "
                f"anchors) on floor {floor} of building {building} (SODIndoorLoc); a smartphone held in the hand at "
                f"static points, up to {MAX_SCANS_PER_POINT} scans each.",
                f"{LICENSE}: {REPO} at {COMMIT}.",
                "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the other."]
    return Floor(name, anchors, runs, meta, comments)


def convert(src: Path, out: Path, building: str | None = None, floor: int | None = None) -> list[str]:
    """Write the chosen floors' site folders into ``out``; returns the sites written."""
    if floor is not None and building is None:
        raise ValueError("--floor needs --building (FloorIDs are a building's)")
    if building is not None and building.upper() not in BUILDINGS:
        raise ValueError(f"no building {building!r}: one of {', '.join(BUILDINGS)}")
    chosen = [b for b in BUILDINGS if building is None or b == building.upper()]
    floors: list[Floor] = []
    for b in chosen:  # everything read and checked before anything is written
        building_id, files = BUILDINGS[b]
        radios = read_radios(src / AP_FILE, b)
        sheets = {run: read_sheet(src / files[run], building_id) for run in RUNS}
        ids = sorted({int(f) for s in sheets.values() for f in s.info["FloorID"]})
        if floor is not None:
            if floor not in ids:
                raise ValueError(f"{b} has no floor {floor} (its floors: {', '.join(map(str, ids))})")
            ids = [floor]
        for f in ids:
            got = convert_floor(b, f, radios, sheets)
            if isinstance(got, str):
                if floor is not None:
                    raise ValueError(f"does not qualify: {got}")
                print(f"skipped {got}")
                continue
            floors.append(got)
    if not floors:
        raise ValueError("no floor qualifies")
    for fl in floors:
        site = out / fl.name
        site.mkdir(parents=True, exist_ok=True)
        for run, rows in fl.runs.items():
            write_run(site / f"{run}.csv.gz", rows)
            s = fl.meta["run_stats"][run]
            print(f"{fl.name}/{run}: {s['points']} points, {s['scans']} scans, {s['readings']} readings")
        write_site_folder(site, [(r.x, r.y) for r in fl.anchors], fl.comments, fl.meta)
    return [fl.name for fl in floors]


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("snapshot", type=Path,
                    help=f"a checkout of renwudao24/SODIndoorLoc (commit {COMMIT[:8]}: {AP_FILE}, CETC331/, HCXY/, SYL/)")
    ap.add_argument("out", type=Path, help="the folder to write the site folders sod_<building>_<floor> into "
                                           "(build/sites)")
    ap.add_argument("--building", help=f"only this building ({', '.join(BUILDINGS)}); default: every one")
    ap.add_argument("--floor", type=int, help="with --building, only this FloorID (CETC331: 1-3, HCXY and SYL: 4), "
                                              "refused if it does not qualify; default: every floor that qualifies")
    args = ap.parse_args(argv)
    return run_converter("convert_sodindoorloc", lambda: convert(args.snapshot, args.out, args.building, args.floor))


if __name__ == "__main__":
    sys.exit(main())
