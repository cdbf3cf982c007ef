"""Convert three BLE 5.1 rooms of github.com/Byongho96/ble-localization to pfdoa site folders.

Rooms for scoring with ``pfdoa eval --sites`` (``make eval-sites`` takes them from
build/sites; since issue 47 all three are development sites: decisions looked at them). Their
runs are NOT committed: the repository states no licence and the original dataset's record
could not be read from here, so convert them from a checkout (read at commit
c90764cb9c06a0da20b2a1ebb35990202106bd99):

    git clone https://github.com/Byongho96/ble-localization
    python tools/convert_ble51.py ble-localization build/sites
    make eval-sites

* ``girolami_room``: ``dataset/mobility``, the mobility scenario of M. Girolami, F. Furfari,
  P. Barsocchi, F. Mavilia, "A Bluetooth 5.1 Dataset Based on Angle of Arrival and RSS for
  Indoor Localization" (2023, Zenodo 10.5281/zenodo.7759557): four anchors on tripods around a
  12 x 6 m room, a tag at the neck of a person walking three paths four times each (12 runs;
  the third path stops for 60 s at four points); the RSSI of the first polarisation (``1stP``).
* ``byongho_corner``: ``dataset/0421``, four anchors at the corners of a 6.3 m square, a tag
  carried through six to nine waypoints (16 runs; ``grid`` stops at nine points).
* ``byongho_edge``: ``dataset/0416``, the same kit with the anchors at the square's edge
  midpoints (5 runs; ``rectangular-mid-low`` and ``rectangular-mid-reverse`` name the same walk,
  their waypoint times 0.4 s apart: kept once, as ``mid_reverse``).

Anchor positions come from the repository's ``config.yml`` / ``collected-config.yml`` (cm).
Ground truth: linear between the waypoints' times, held from a stop's start to its end;
readings before the first waypoint or after the last are dropped; t counts from the first
waypoint. Anchors are renumbered 0..3 in the order below (their ids in the source are kept
in anchors.json).
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import converter_parser, run_converter, write_site_folder
from pfdoa.evaluation.sites import write_run as write_trace

SOURCE = "github.com/Byongho96/ble-localization at c90764cb9c06a0da20b2a1ebb35990202106bd99"
LICENSE = "none stated by the repository: not redistributable here, convert from a checkout"
SQUARE_M = 6.3


@dataclass(frozen=True)
class Run:
    name: str
    truth: str  # the waypoint file, relative to the checkout
    readings: tuple[str, ...]  # one file per anchor (byongho) or one file for all (girolami)


@dataclass(frozen=True)
class Room:
    name: str
    what: str
    anchors: tuple[tuple[float, float], ...]  # m
    source_ids: tuple[str, ...]  # the anchors' ids in the source, in the order above
    runs: tuple[Run, ...]
    caveats: tuple[str, ...]
    target: str = ""  # what carries the tag (the reports' "target")
    heights: tuple[float, float] | None = None  # (every anchor's z, the tag's target_z) m, where the source gives both


def _girolami() -> Room:
    runs = tuple(Run(f"uc{u}_run{k}", f"dataset/mobility/gt/use-case{u}/gt_mobility_use-case{u}_run{k}.csv",
                     (f"dataset/mobility/beacons/use-case{u}/beacons_mobility_use-case{u}_run{k}.csv",))
                 for u in (1, 2, 3) for k in (1, 2, 3, 4))
    return Room("girolami_room", "four BLE 5.1 anchors on tripods around a 12 x 6 m room, a tag worn by a walking person "
                "(Girolami et al. 2023, Zenodo 10.5281/zenodo.7759557, its mobility scenario)",
                ((0.0, 3.0), (6.0, 0.0), (12.0, 3.0), (6.0, 6.0)), ("6501", "6502", "6503", "6504"), runs,
                ("The RSSI is the first polarisation's (1stP); the anchors hop over three advertising channels.",
                 "The anchors stand at 2.30 m and the tag is at a person's neck, its height not given: no heights "
                 "are written (z without the tag's would be worse than none)."),
                "walking person (tag at the neck)")


def _byongho_runs(day: str, stems: dict[str, tuple[str, str]]) -> tuple[Run, ...]:
    """``stems``: run name -> (waypoint file stem, the anchors' readings file for it)."""
    return tuple(Run(name, f"dataset/{day}/gt/{gt}.csv", tuple(files.format(k=k) for k in (1, 2, 3, 4)))
                 for name, (gt, files) in stems.items())


BYONGHO_IDS = ("6C1DEBA09949", "CCF9579B236F", "6C1DEBA09A56", "6C1DEBA09A70")  # anchor1..anchor4
BYONGHO_TARGET = "tag carried through waypoints"
BYONGHO_HEIGHTS = (1.4, 1.4)  # the anchors' and, by the waypoint files' Z (cm), the tag's
BYONGHO_CAVEATS = ("A tag carried through waypoints; the anchors and, by the waypoint files, the tag at 1.40 m (the runs "
                   "named low may have carried it lower: the source does not say); site.toml carries those heights.",
                   "About 19 readings per anchor and second, each on one of the 40 BLE channels.")


def _byongho_corner() -> Room:
    files = {"": "dataset/0421/beacons/anchor{k}/diagonal.csv", "low": "dataset/0421/beacons/anchor{k}/diagonal-low.csv",
             "set": "dataset/0421/beacons/anchor{k}/diagonal-set.csv",
             "grid": "dataset/0421/beacons/anchor{k}/diagonal-grid.csv"}
    stems = {f"diagonal_{k}": (f"diagonal-{k}", files[""]) for k in (1, 2, 3, 4)}
    stems["low_1"] = ("low-1", files["low"])
    stems.update({f"set_{k}": (f"set-{k}", files["set"]) for k in (1, 2, 3, 4)})
    stems.update({f"set_low_{k}": (f"set-low-{k}", files["set"]) for k in (1, 2, 3)})
    stems.update({f"set_stop_{k}": (f"set-stop-{k}", files["set"]) for k in (1, 2, 3)})
    stems["grid"] = ("grid", files["grid"])
    s = SQUARE_M
    return Room("byongho_corner", f"four BLE 5.1 anchors at the corners of a {s} m square (Byongho96/ble-localization "
                "dataset/0421)", ((0.0, s), (s, s), (s, 0.0), (0.0, 0.0)), BYONGHO_IDS,
                _byongho_runs("0421", stems), BYONGHO_CAVEATS, BYONGHO_TARGET, BYONGHO_HEIGHTS)


def _byongho_edge() -> Room:
    edge, mid = "dataset/0416/beacons/rectangular-edge/anchor{k}.csv", "dataset/0416/beacons/rectangular-mid/anchor{k}.csv"
    stems = {"edge": ("rectangular-edge", edge), "edge_low": ("rectangular-edge-low", edge),
             "mid": ("rectangular-mid", mid), "mid_2": ("rectangular-mid-2", mid),
             "mid_reverse": ("rectangular-mid-reverse", mid)}
    s, h = SQUARE_M, SQUARE_M / 2
    return Room("byongho_edge", f"four BLE 5.1 anchors at the edge midpoints of a {s} m square "
                "(Byongho96/ble-localization dataset/0416)", ((h, s), (s, h), (h, 0.0), (0.0, h)), BYONGHO_IDS,
                _byongho_runs("0416", stems),
                BYONGHO_CAVEATS + ("rectangular-mid-low and rectangular-mid-reverse name the same walk: kept once.",),
                BYONGHO_TARGET, BYONGHO_HEIGHTS)


ROOMS = (_girolami, _byongho_corner, _byongho_edge)


def waypoints(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(times s, positions m (k, 2)) of a walk's knots: a waypoint with an end time (a stop)
    gives two knots at the same place."""
    t: list[float] = []
    xy: list[tuple[float, float]] = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            p = (float(row["X"]) / 100.0, float(row["Y"]) / 100.0)
            t.append(float(row["StartTimestamp"]) / 1000.0)
            xy.append(p)
            end = (row.get("EndTimestamp") or "").strip()
            if end and end.lower() != "nan":
                t.append(float(end) / 1000.0)
                xy.append(p)
    times = np.array(t)
    if times.size < 2 or np.any(np.diff(times) < 0.0):
        raise ValueError(f"{path}: waypoint times must be at least two and in order")
    return times, np.array(xy)


def readings(paths: list[Path], ids: tuple[str, ...]) -> np.ndarray:
    """(k, 3) rows of (time s, anchor index, RSSI dBm) of every file, in time order."""
    rows = []
    for path in paths:
        with open(path, newline="") as fh:
            for row in csv.DictReader(fh):
                if "1stP" in row:  # Girolami et al.: one file of every anchor, two polarisations
                    aid, rssi = row["AnchorID"], row["1stP"]
                else:  # Byongho96: one file per anchor
                    aid, rssi = row["Anchor"], row["RSSI"]
                if aid not in ids:
                    raise ValueError(f"{path}: anchor {aid!r} is not one of the room's {', '.join(ids)}")
                rows.append((float(row["Timestamp"]) / 1000.0, float(ids.index(aid)), float(rssi)))
    a = np.array(rows, dtype=float).reshape(-1, 3)
    return a[np.lexsort((a[:, 1], a[:, 0]))]


def write_run(src: Path, room: Room, run: Run, out: Path) -> int:
    t_knots, xy = waypoints(src / run.truth)
    r = readings([src / f for f in run.readings], room.source_ids)
    r = r[(r[:, 0] >= t_knots[0]) & (r[:, 0] <= t_knots[-1])]
    t0 = t_knots[0]
    t = np.round(r[:, 0] - t0, 3)  # from the first waypoint, to the millisecond
    gx = np.round(np.interp(t + t0, t_knots, xy[:, 0]), 3)  # to the millimetre
    gy = np.round(np.interp(t + t0, t_knots, xy[:, 1]), 3)
    return write_trace(out / f"{run.name}.csv", zip(t.tolist(), r[:, 1].astype(int).tolist(), r[:, 2].tolist(),
                                                       gx.tolist(), gy.tolist()))


def convert(src: Path, out: Path, rooms: tuple[str, ...] | None = None) -> list[str]:
    made = []
    for make in ROOMS:
        room = make()
        if rooms is not None and room.name not in rooms:
            continue
        site = out / room.name
        site.mkdir(parents=True, exist_ok=True)
        for run in room.runs:
            n = write_run(src, room, run, site)
            print(f"{room.name}/{run.name}: {n} readings")
        meta = {"source": SOURCE, "license": LICENSE, "technology": "ble", "target": room.target,
                "anchors": [list(a) for a in room.anchors], "anchor_ids_in_source": list(room.source_ids),
                "runs": [r.name for r in room.runs], "caveats": list(room.caveats)}
        heights = None if room.heights is None else ([room.heights[0]] * len(room.anchors), room.heights[1])
        write_site_folder(site, room.anchors, [
            f"{room.what}.", f"Source: {SOURCE}; licence: {LICENSE}.",
            "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the others."],
            meta, heights=heights)
        made.append(room.name)
    return made


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path, help="a checkout of github.com/Byongho96/ble-localization")
    ap.add_argument("out", type=Path, help="where the site folders go")
    names = [make().name for make in ROOMS]
    ap.add_argument("--rooms", default=",".join(names), help=f"comma list of rooms to convert (default: all, {', '.join(names)})")
    args = ap.parse_args(argv)
    rooms = tuple(r for r in args.rooms.split(",") if r)
    if not rooms or set(rooms) - set(names):
        print(f"convert_ble51: --rooms: choose from {', '.join(names)}", file=sys.stderr)
        return 2
    if not (args.source / "dataset").is_dir():
        print(f"convert_ble51: {args.source}: no dataset/ folder (a checkout of Byongho96/ble-localization?)",
              file=sys.stderr)
        return 2
    return run_converter("convert_ble51", lambda: convert(args.source, args.out, rooms))


if __name__ == "__main__":
    sys.exit(main())
