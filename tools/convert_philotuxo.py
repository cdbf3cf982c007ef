"""Convert tracks of the Position-Annotated BLE RSSI dataset to runs of pfdoa's philotuxo site.

Source: F. S. Daniş, A. T. Naskali, A. T. Cemgil, C. Ersoy, "An Indoor Localization Dataset and
Data Collection Framework with High Precision Position Annotation" (Pervasive and Mobile
Computing, 2022), github.com/philotuxo/Position-Annotated-BLE-RSSI-Dataset at commit
77474b69dc7d73fc5b07b74d7b4b65f3235a663e, CC0-1.0 (its LICENSE.md). Twelve BLE sensors in a
20.7 x 17.6 m hall (``cnf/tetam.dev``: positions and heights) receive one beacon carried along
a path; every reading carries the camera/AR-marker system's position of the beacon.

A track ``trk/<name>_all_sensors.mbd`` (``time,sensor MAC,beacon MAC,RSSI,x,y,z,3x3 rotation``)
becomes ``<name>.csv.gz``: one reading per line, sorted by time (the merged file has a few
sub-millisecond inversions; readings of one instant in sensor order), t in seconds from its first reading (to the millisecond), the
sensor renumbered 0..11 in the order of ``cnf/tetam.dev``, the annotated x, y as ground truth
(to the millimetre; z, the beacon's height, is summed up in anchors.json), readings above -20 dBm dropped (two
impossible values, +29 and +42, in straight_05). Three tracks were committed before this tool
(rectangular_with_rotation, straight_01, zigzagging_with_rotation, from the project's shared
data folder, the same conversion written with three decimals: this tool gives the same times,
sensors, RSSI and positions for them); by default it writes the other six::

    git clone https://github.com/philotuxo/Position-Annotated-BLE-RSSI-Dataset philotuxo
    python tools/convert_philotuxo.py philotuxo host/pfdoa/data/philotuxo_ble_dev

``--points`` writes a site of the same hall from the stationary reference points instead
(``hst/set_1`` and ``hst/set_2``, recorded on different dates: 81 and 45 points, the beacon
held 30 minutes at each, every sensor a file ``<sensor>_<x>_<y>_<z>.mbd`` of
``time,sensor MAC,beacon MAC,RSSI``): one run per set, the points in the order they were
recorded, each point's readings from POINT_FROM_S to POINT_FROM_S + POINT_S after its first
reading (the setup had been left alone for a minute; a user stands that long, not half an
hour), at their own times (the gaps between points kept), the point's position as ground
truth; with the site file (neutral radio, the sensors' heights, the beacon's median height)
and anchors.json::

    python tools/convert_philotuxo.py --points philotuxo host/pfdoa/data/philotuxo_ble_points
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run

COMMITTED = ("rectangular_with_rotation", "straight_01", "zigzagging_with_rotation")
OTHERS = ("rectangular_without_rotation", "straight_02", "straight_03", "straight_04", "straight_05",
          "zigzagging_without_rotation")
MAX_RSSI_DBM = -20.0  # above: not a BLE reading (the source has +29 and +42)
SOURCE_COMMIT = "77474b69dc7d73fc5b07b74d7b4b65f3235a663e"
POINT_SETS = ("set_1", "set_2")
POINT_FROM_S = 60.0
POINT_S = 20.0
POINT_FILE = re.compile(r"(sensor\d+)_(-?[\d.]+)_(-?[\d.]+)_(-?[\d.]+)\.mbd$")


def sensors(src: Path) -> list[tuple[str, float, float, float]]:
    """(MAC, x, y, z) of each sensor, in the order of cnf/tetam.dev (the site's anchor order)."""
    text = (src / "cnf" / "tetam.dev").read_text()
    dongles = json.loads(text.split("Dongles:", 1)[1].split("Beacons:", 1)[0])
    return [(mac, float(p[0][0]), float(p[0][1]), float(p[0][2])) for mac, p in dongles.items()]


def mbd_lines(path: Path, macs: list[str], width: int):
    """The lines of an mbd file (``time,sensor MAC,beacon MAC,RSSI[,...]``) with at least
    ``width`` fields, each as (fields, the sensor's anchor index); an unknown sensor is an error."""
    for line in path.read_text().splitlines():
        f = line.split(",")
        if len(f) < width:
            continue
        if f[1] not in macs:
            raise ValueError(f"{path}: sensor {f[1]!r} is not in cnf/tetam.dev")
        yield f, macs.index(f[1])


def read_track(path: Path, macs: list[str]) -> np.ndarray:
    """(k, 6) rows of (time s, anchor index, RSSI dBm, x, y, z) in time order (stable)."""
    rows = [(float(f[0]), float(i), float(f[3]), float(f[4]), float(f[5]), float(f[6]))
            for f, i in mbd_lines(path, macs, 7)]
    a = np.array(rows, dtype=float).reshape(-1, 6)
    a = a[np.lexsort((a[:, 1], a[:, 0]))]  # readings of one instant in anchor order
    return a[a[:, 2] <= MAX_RSSI_DBM]


def write_track(rows: np.ndarray, out: Path) -> int:
    """One run in the common trace format: t from the first reading (to the millisecond), each
    reading its own annotation (to the millimetre: readings of one millisecond may differ)."""
    t = np.round(rows[:, 0] - rows[0, 0], 3)
    return write_run(out, zip(t.tolist(), rows[:, 1].astype(int).tolist(), rows[:, 2].tolist(),
                              np.round(rows[:, 3], 3).tolist(), np.round(rows[:, 4], 3).tolist()))


def read_points(folder: Path, macs: list[str]) -> tuple[np.ndarray, list[float]]:
    """One set of reference points as (k, 5) rows of (time s, anchor index, RSSI dBm, x, y) in
    time order, each point's readings from POINT_FROM_S for POINT_S after its first; and each
    point's height (its files name it)."""
    files: dict[tuple[float, float, float], list[Path]] = {}
    for path in sorted(folder.glob("*.mbd")):
        m = POINT_FILE.search(path.name)
        if m is None:
            raise ValueError(f"{path}: not <sensor>_<x>_<y>_<z>.mbd")
        files.setdefault((float(m[2]), float(m[3]), float(m[4])), []).append(path)
    if not files:
        raise ValueError(f"{folder}: no .mbd files")
    out, heights = [], []
    for (x, y, z), paths in files.items():
        rows = [(float(f[0]), float(i), float(f[3])) for path in paths for f, i in mbd_lines(path, macs, 4)]
        a = np.array(rows, dtype=float).reshape(-1, 3)
        if not a.size:  # a point no sensor heard: not a point of the run
            continue
        t0 = float(a[:, 0].min()) + POINT_FROM_S
        a = a[(a[:, 0] >= t0) & (a[:, 0] < t0 + POINT_S) & (a[:, 2] <= MAX_RSSI_DBM)]
        out.append(np.column_stack([a, np.full(len(a), x), np.full(len(a), y)]))
        heights.append(z)
    if not out:
        raise ValueError(f"{folder}: no readings")
    rows_all = np.concatenate(out)
    return rows_all[np.lexsort((rows_all[:, 1], rows_all[:, 0]))], heights


def convert_points(src: Path, out: Path) -> None:
    """The reference-point site (module doc): site.toml, anchors.json and a run per set."""
    from pfdoa.evaluation.sites import write_site_folder

    sens = sensors(src)
    macs = [s[0] for s in sens]
    heights: list[float] = []
    runs = {}
    for name in POINT_SETS:
        rows, set_heights = read_points(src / "hst" / name, macs)
        heights += set_heights
        points = len(set_heights)
        write_track(rows, out / f"{name}.csv.gz")
        runs[name] = {"points": points, "readings": int(len(rows)), "source_path": f"hst/{name}/*.mbd"}
        print(f"{name}: {points} points, {len(rows)} readings")
    write_site_folder(
        out, [(x, y) for _m, x, y, _z in sens],
        ["12 BLE receiving sensors in a 20.7 x 17.6 m hall, one beacon held still at reference points "
         "(CC0-1.0, philotuxo/Position-Annotated-BLE-RSSI-Dataset hst/set_1, set_2).",
         "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one set, score on the other.",
         "Heights (m): the sensors' z from cnf/tetam.dev; target_z the beacon's median height at the points."],
        {"source": "philotuxo/Position-Annotated-BLE-RSSI-Dataset hst/set_1/*.mbd, hst/set_2/*.mbd, cnf/tetam.dev",
         "source_commit": SOURCE_COMMIT, "license": "CC0-1.0 (LICENSE.md in the repository)", "technology": "ble",
         "target": "beacon held still at reference points",
         "notes": f"Each point's readings from {POINT_FROM_S:g} s after its first for {POINT_S:g} s; points in "
                  "the order recorded, the gaps between them kept.", "runs": runs},
        heights=([z for _m, _x, _y, z in sens], round(float(np.median(heights)), 2)))


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path, help="a checkout of philotuxo/Position-Annotated-BLE-RSSI-Dataset")
    ap.add_argument("out", type=Path, help="the site folder the runs go to (host/pfdoa/data/philotuxo_ble_dev)")
    ap.add_argument("--tracks", default=",".join(OTHERS), help="comma list of tracks (default: the six not "
                                                               "committed before this tool)")
    ap.add_argument("--points", action="store_true", help="write the reference-point site instead (module doc)")
    args = ap.parse_args(argv)
    tracks = [t for t in args.tracks.split(",") if t]
    if not (args.source / "cnf" / "tetam.dev").is_file():
        print(f"convert_philotuxo: {args.source}: no cnf/tetam.dev (a checkout of the dataset?)", file=sys.stderr)
        return 2
    if args.points:
        def points() -> None:
            args.out.mkdir(parents=True, exist_ok=True)
            convert_points(args.source, args.out)

        return run_converter("convert_philotuxo", points)
    unknown = set(tracks) - set(COMMITTED + OTHERS)
    if not tracks or unknown:
        print(f"convert_philotuxo: --tracks: choose from {', '.join(COMMITTED + OTHERS)}", file=sys.stderr)
        return 2
    def convert_tracks() -> None:
        macs = [s[0] for s in sensors(args.source)]
        args.out.mkdir(parents=True, exist_ok=True)
        for name in tracks:
            rows = read_track(args.source / "trk" / f"{name}_all_sensors.mbd", macs)
            write_track(rows, args.out / f"{name}.csv.gz")
            print(f"{name}: {len(rows)} readings, {rows[-1, 0] - rows[0, 0]:.1f} s, beacon height "
                  f"{np.median(rows[:, 5]):.2f} m (median)")

    return run_converter("convert_philotuxo", convert_tracks)


if __name__ == "__main__":
    sys.exit(main())
