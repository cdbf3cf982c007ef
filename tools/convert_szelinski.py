"""Convert Szelinski & Nikodem's multi-channel BLE points (the PF-DOA paper's Dataset 2) to a
pfdoa site folder: four BLE anchors at the corners of a 10 x 10 m area, a tag at static points
along each diagonal, every reading on one of the 40 BLE channels.

Source: Szelinski & Nikodem, "Multi-channel BLE RSSI measurements for indoor localization"
(IEEE DataPort), as copied in the PF-DOA authors' repository,
github.com/herolab-uga/pf-doa-localization at commit f852403ce5dfca5d0b98d35270d69b63ff5d0948,
``dataset2/measurements/{diag0,diag1}/s0..s3.csv`` (``anchor;x;y;distance;distance_cm;channel;
rssi``, one file per anchor; ``.csv.gz`` is read too), released there under the MIT licence
(host/pfdoa/data/LICENSE-herolab-pf-doa-localization). Anchors s0..s3 at (0,0), (10,0), (10,10),
(0,10) m: checked here against every reading's distance column (the points of both diagonals
tell s1 from s3).

The readings carry no time and the anchors measured separately, so an observation pairs the
middle reading of each anchor at one point and channel (as ``pfdoa eval``'s Dataset 2 block
does for channels 0-39): a tag standing at a point for 40 s, one observation a second, channels
0..39 in turn, then carried to the next point. The site's two runs are the dataset's two
collections, one per diagonal: ``diag0`` (x = y, 11 points) and ``diag1`` (x + y = 10, 11
points); each is calibrated on the other, so a calibration never saw the places it is scored at.
The radio values in site.toml are the neutral guess every converter here writes (-60 dBm at
1 m, n = 2).

    git clone https://github.com/herolab-uga/pf-doa-localization herolab
    python tools/convert_szelinski.py herolab/dataset2/measurements host/pfdoa/data
"""

from __future__ import annotations

import csv
import gzip
import math
import sys
from pathlib import Path

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run, write_site_folder

NAME = "szelinski_ble_diag"
ANCHORS = ((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0))  # s0..s3
CHANNELS = range(40)
SOURCE = ("Szelinski & Nikodem, Multi-channel BLE RSSI measurements for indoor localization (IEEE DataPort), "
          "the points of both diagonals, as copied in github.com/herolab-uga/pf-doa-localization at "
          "f852403ce5dfca5d0b98d35270d69b63ff5d0948, dataset2/measurements/diag0, diag1")
LICENSE = "MIT (the herolab-uga/pf-doa-localization copy; host/pfdoa/data/LICENSE-herolab-pf-doa-localization)"
RUNS = ("diag0", "diag1")  # the dataset's two collections, one per diagonal
MAX_DISTANCE_ERROR_M = 0.01  # the distance column against the anchor positions above


def read_anchor(folder: Path, a: int) -> dict[tuple[float, float, int], list[float]]:
    """{(x, y, channel): readings in file order} of anchor ``a``'s file in ``folder``; ValueError
    where the file's distance column disagrees with the anchor's position."""
    path = folder / f"s{a}.csv"
    if not path.is_file() and (folder / f"s{a}.csv.gz").is_file():
        path = folder / f"s{a}.csv.gz"
    out: dict[tuple[float, float, int], list[float]] = {}
    ax, ay = ANCHORS[a]
    with (gzip.open(path, "rt", newline="") if path.suffix == ".gz" else open(path, newline="")) as fh:
        for row in csv.DictReader(fh, delimiter=";"):
            x, y = float(row["x"]), float(row["y"])
            if abs(math.hypot(x - ax, y - ay) - float(row["distance"])) > MAX_DISTANCE_ERROR_M:
                raise ValueError(f"{path}: distance {row['distance']} at ({x}, {y}) is not the distance to "
                                 f"anchor s{a} at ({ax}, {ay})")
            out.setdefault((x, y, int(row["channel"])), []).append(float(row["rssi"]))
    if not out:
        raise ValueError(f"{path}: no readings")
    return out


def observations(tables: list[dict]) -> list[tuple[tuple[float, float], list[tuple[int, float]]]]:
    """(point, [(anchor, RSSI)]) per observation: points in diagonal order, channels 0..39 at each,
    the middle reading of every anchor with one there (all anchors' counts' minimum decides it)."""
    points = sorted({(x, y) for t in tables for x, y, _c in t})
    out = []
    for p in points:
        for ch in CHANNELS:
            got = [t.get((p[0], p[1], ch), []) for t in tables]
            m = min(len(g) for g in got)
            if m:
                out.append((p, [(a, g[m // 2]) for a, g in enumerate(got)]))
    return out


def convert(src: Path, out: Path) -> None:
    # Everything read (and checked) before anything is written.
    runs = {run: observations([read_anchor(src / run, a) for a in range(len(ANCHORS))]) for run in RUNS}
    site = out / NAME
    site.mkdir(parents=True, exist_ok=True)
    for run, obs in runs.items():
        # an observation a second, its readings at that time, the point as ground truth
        write_run(site / f"{run}.csv.gz", ((float(k), a, r, p[0], p[1]) for k, (p, readings) in enumerate(obs)
                                           for a, r in readings))
        print(f"{NAME}/{run}: {len({p for p, _r in obs})} points, {len(obs)} observations")
    meta = {"source": SOURCE, "license": LICENSE, "technology": "ble",
            "target": "tag at static points", "anchors": [list(a) for a in ANCHORS],
            "anchor_ids_in_source": ["s0", "s1", "s2", "s3"], "runs": list(RUNS),
            "run_names": "diag0: the points on x = y; diag1: the points on x + y = 10 (the dataset's folders)",
            "caveats": [
                "The readings have no time and each anchor measured on its own: an observation pairs the anchors' "
                "middle readings at one point and channel; times are made up (one observation a second).",
                "The points of each diagonal in order of x; the dataset's inside and perimeter collections are "
                "not in this copy.",
                "Heights are not given; every position is 2-D.",
            ]}
    write_site_folder(site, ANCHORS, [
        "Four BLE anchors at the corners of a 10 x 10 m area; a tag at static points on the diagonal, 40 channels.",
        f"{LICENSE}: {SOURCE}.",
        "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the other."], meta)


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path, help="the dataset2/measurements/ folder of herolab-uga/pf-doa-localization")
    ap.add_argument("out", type=Path, help="where the site folder goes (host/pfdoa/data)")
    args = ap.parse_args(argv)
    return run_converter("convert_szelinski", lambda: convert(args.source, args.out))


if __name__ == "__main__":
    sys.exit(main())
