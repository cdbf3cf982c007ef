"""Convert the office of Feng, Nguyen & Luo's Wi-Fi RSS & RTT dataset to a pfdoa site folder:
five Wi-Fi access points (the anchors) around an office floor, a device at static reference
points, 60 scans at each.

Source: X. Feng, K. A. Nguyen, Z. Luo, "WiFi RSS & RTT dataset with different LOS conditions for
indoor positioning" (Zenodo 10.5281/zenodo.11558792, 2024; described in "A WiFi RSS-RTT indoor
positioning system using dynamic model switching algorithm", IEEE J-ISPIN 2024),
github.com/Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection at commit
48e41763ff1dc37aed1746be82f8d073531d9b82, released there under the MIT licence (its LICENSE,
copied into the site folder). Read: ``data/database_office_{train,test}.csv`` (``X,Y,AP1 RTT(mm)
.. AP5 RTT(mm),AP1 RSS(dBm) .. AP5 RSS(dBm),LOS APs``: one scan a line, -200 dBm where an AP was
not heard) and ``data/lecture theatre+office+corridor_AP_position.txt`` (the APs' x and y).

Coordinates, of the points and of the APs alike, are in grid cells of 0.6 m (the README's "Grid
size: 0.6 x 0.6 m2"), written here in metres. Checked against the RTT ranges, which the same
scans carry: every AP's ranges follow the distance from the point to its stated position
(correlation at least MIN_RTT_CORRELATION, and best for its own position of the five: no
column is another AP's), at RANGE_SLOPES metres of range per metre of distance (what a wrong
grid size would break); the figures are in anchors.json.

The site's two runs are the dataset's two sets of points, disjoint (the authors' split of the
room's 108 points): ``train`` (81 points) and ``test`` (27); each is calibrated on the other.
The scans carry no time: each point's scans in file order, one a second, the points one after
the other in file order (sorted by x, then y: not necessarily the order they were recorded in);
a scan's readings share its time, the point is the ground truth, APs not heard are dropped. The
radio values in site.toml are the neutral guess every converter here writes (-60 dBm at 1 m,
n = 2). The lecture theatre and the corridor of the same dataset are not converted.

    git clone https://github.com/Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection feng
    python tools/convert_feng_wifi.py feng host/pfdoa/data/feng_wifi_office
"""

from __future__ import annotations

import csv
import re
import sys
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run, write_site_folder

ROOM = "office"  # the room's name in the AP position file and in the data files' names
N_APS = 5
GRID_M = 0.6  # one coordinate unit, points and APs alike
RUNS = ("train", "test")  # data/database_office_<run>.csv
NOT_HEARD_DBM = -200.0
SCAN_S = 1.0  # made-up spacing of the scans (the data has no times)
MIN_RTT_CORRELATION = 0.8
RANGE_SLOPES = (0.7, 1.5)  # m of RTT range per m of distance, fitted with an offset
AP_FILE = "lecture theatre+office+corridor_AP_position.txt"
LICENSE_COPY = "LICENSE-WiFi_RSS_RTT_Dataset_for_Model_Selection"
COMMIT = "48e41763ff1dc37aed1746be82f8d073531d9b82"
SOURCE = ("X. Feng, K. A. Nguyen, Z. Luo, WiFi RSS & RTT dataset with different LOS conditions for indoor "
          "positioning (Zenodo 10.5281/zenodo.11558792), the office, as published in "
          f"github.com/Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection at {COMMIT}, "
          f"data/database_office_{{train,test}}.csv and data/{AP_FILE}")
LICENSE = f"MIT (the repository's LICENSE, copied here as {LICENSE_COPY})"
CITATION = ("Feng, X., Nguyen, K. A., & Luo, Z. (2024). WiFi RSS & RTT dataset with different LOS conditions for "
            "indoor positioning [Data set]. Zenodo. https://doi.org/10.5281/zenodo.11558792; Feng, Nguyen, Luo, "
            "A WiFi RSS-RTT indoor positioning system using dynamic model switching algorithm, IEEE Journal of "
            "Indoor and Seamless Positioning and Navigation, 2024")


def read_ap_positions(path: Path) -> list[tuple[float, float]]:
    """The room's APs, in grid units, from the position file (a room's name on a line, then
    ``AP X: x1,x2,...`` and ``AP Y: y1,y2,...``)."""
    lines = [ln.strip() for ln in path.read_text().splitlines()]
    if ROOM not in lines:
        raise ValueError(f"{path}: no section {ROOM!r}")
    got: dict[str, list[float]] = {}
    for ln in lines[lines.index(ROOM) + 1:]:
        m = re.fullmatch(r"AP ([XY])\s*:\s*(.*)", ln)
        if not m:
            break
        got[m.group(1)] = [float(v) for v in m.group(2).split(",")]
    xs, ys = got.get("X", []), got.get("Y", [])
    if len(xs) != N_APS or len(ys) != N_APS:
        raise ValueError(f"{path}: {ROOM} needs {N_APS} AP x and y values, found {len(xs)} and {len(ys)}")
    return list(zip(xs, ys))


def read_scans(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points n x 2, RSS n x N_APS dBm, RTT n x N_APS mm) of the file's scans, in file order."""
    pts, rss, rtt = [], [], []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            pts.append((float(row["X"]), float(row["Y"])))
            rss.append([float(row[f"AP{k} RSS(dBm)"]) for k in range(1, N_APS + 1)])
            rtt.append([float(row[f"AP{k} RTT(mm)"]) for k in range(1, N_APS + 1)])
    if not pts:
        raise ValueError(f"{path}: no scans")
    return np.array(pts), np.array(rss), np.array(rtt)


def rtt_check(aps: np.ndarray, pts: np.ndarray, rss: np.ndarray, rtt: np.ndarray) -> list[dict]:
    """Per AP: the correlation of its RTT ranges with the distance to its stated position, and
    the fitted slope (m of range per m); ValueError where a position does not fit its column."""
    out = []
    for k in range(len(aps)):
        heard = rss[:, k] > NOT_HEARD_DBM
        rng = rtt[heard, k] / 1000.0
        corr = [float(np.corrcoef(np.hypot(*(pts[heard] - a).T), rng)[0, 1]) for a in aps]
        d = np.hypot(*(pts[heard] - aps[k]).T)
        slope = float(np.polyfit(d, rng, 1)[0])
        if corr[k] < MIN_RTT_CORRELATION or int(np.argmax(corr)) != k or not RANGE_SLOPES[0] <= slope <= RANGE_SLOPES[1]:
            raise ValueError(f"AP{k + 1}'s RTT ranges do not follow the distance to its stated position "
                             f"(correlation {corr[k]:.2f}, best for AP{int(np.argmax(corr)) + 1}'s position; "
                             f"slope {slope:.2f})")
        out.append({"ap": f"AP{k + 1}", "correlation": round(corr[k], 3), "range_per_m": round(slope, 3)})
    return out


def convert(src: Path, site: Path) -> None:
    # Everything read (and checked) before anything is written.
    licence = (src / "LICENSE").read_bytes()
    if b"MIT License" not in licence:
        raise ValueError(f"{src / 'LICENSE'}: not the MIT licence this conversion was made under")
    aps = np.round(np.array(read_ap_positions(src / "data" / AP_FILE)) * GRID_M, 6)
    runs = {}
    for run in RUNS:
        pts, rss, rtt = read_scans(src / "data" / f"database_{ROOM}_{run}.csv")
        runs[run] = (np.round(pts * GRID_M, 6), rss, rtt)
    pts, rss, rtt = (np.concatenate([r[i] for r in runs.values()]) for i in range(3))
    check = rtt_check(aps, pts, rss, rtt)
    site.mkdir(parents=True, exist_ok=True)
    stats = {}
    for run, (pts, rss, _rtt) in runs.items():
        k_scan, k_ap = np.nonzero(rss > NOT_HEARD_DBM)  # scan by scan, APs in order
        write_run(site / f"{run}.csv.gz", ((float(s) * SCAN_S, a, r, x, y) for s, a, r, (x, y) in
                                           zip(k_scan.tolist(), k_ap.tolist(), rss[k_scan, k_ap].tolist(),
                                               pts[k_scan].tolist())))
        n_points = len({tuple(p) for p in pts.tolist()})
        stats[run] = {"points": n_points, "scans": len(pts), "readings": len(k_scan),
                      "not_heard": int(rss.size - len(k_scan))}
        print(f"{site.name}/{run}: {n_points} points, {len(pts)} scans, {len(k_scan)} readings")
    (site / LICENSE_COPY).write_bytes(licence)
    meta = {
        "source": SOURCE, "license": LICENSE, "citation": CITATION, "technology": "wifi",
        "target": "device at static points",
        "anchors": aps.tolist(), "anchor_ids_in_source": [f"AP{k}" for k in range(1, N_APS + 1)],
        "runs": list(RUNS), "run_stats": stats,
        "run_names": "train, test: the dataset's two sets of the office's points (database_office_train.csv, "
                     "database_office_test.csv), disjoint",
        "grid_m": GRID_M, "rtt_check": check,
        "caveats": [
            "The scans carry no time: one a second is made up, each point's 60 scans in file order, the points "
            "back to back in file order (sorted by x, then y; the order they were recorded in is not given).",
            "Coordinates are the dataset's grid units times 0.6 m (its README's grid size), APs and points alike; "
            "the APs' RTT ranges agree (rtt_check: the fitted metres of range per metre of distance).",
            "The README calls the office mixed LOS-NLOS (its table's notes swap the office's and the corridor's); "
            "each scan's LOS APs column says which APs it saw in line of sight and is not carried over.",
            "APs not heard in a scan (-200 dBm in the data) are dropped: run_stats not_heard.",
            "The receiving device and the APs' heights are not given; every position is 2-D.",
            "The LICENSE's copyright line reads 'Copyright (c) 2014 davetaz' (a template's); the repository's owner "
            "published the data under it. The Zenodo record of the same data is cited above.",
        ],
    }
    write_site_folder(site, [tuple(a) for a in aps.tolist()], [
        f"{N_APS} Wi-Fi access points (the anchors) around an office (mixed LOS and NLOS); a device at static points, "
        "60 scans each.",
        f"{LICENSE}: {SOURCE}.",
        "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the other."], meta)


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path,
                    help="a checkout of Fx386483710/WiFi_RSS_RTT_Dataset_for_Model_Selection (LICENSE, data/)")
    ap.add_argument("out", type=Path, help="the site folder to write (host/pfdoa/data/feng_wifi_office)")
    args = ap.parse_args(argv)
    return run_converter("convert_feng_wifi", lambda: convert(args.source, args.out))


if __name__ == "__main__":
    sys.exit(main())
