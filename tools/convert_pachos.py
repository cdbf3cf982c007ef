"""Convert scenario 1 of Pachos et al.'s RSSI dataset (the PF-DOA paper's Dataset 1) to three
pfdoa site folders: the same room measured with Wi-Fi, BLE and Zigbee (IEEE 802.15.4).

Source: S. Sadowski, P. Spachos, K. N. Plataniotis, "Memoryless Techniques and Wireless
Technologies for Indoor Localization with the Internet of Things" (IEEE Internet of Things
Journal, 2020) and github.com/pspachos/RSSI-Dataset-for-Indoor-Localization-Fingerprinting
(scenario 1: a 6.0 x 5.5 m meeting room cleared of other transmitters, three transmitters 4 m
apart in a triangle, a receiver on a table at each point). That repository states no licence;
the per-point values used here are the copy in the PF-DOA authors' repository,
github.com/herolab-uga/pf-doa-localization at commit f852403ce5dfca5d0b98d35270d69b63ff5d0948,
``dataset1/{wifi,ble,zigbee}-{dataset1,testdata}.csv``, released there under the MIT licence
(host/pfdoa/data/LICENSE-herolab-pf-doa-localization). One RSSI per transmitter and point,
stored as a positive number meaning negative dBm.

Each technology becomes a site with two runs, the dataset's own two collections: ``fingerprints``
(the 49 points of the 0.5 m grid, in file order) and ``tests`` (the 10 points chosen at random
for testing, whose x and y are stored transposed relative to the grid file: read swapped, see
``D1_TESTDATA_TRANSPOSED`` in pfdoa.evaluation.datasets). A point is one observation, the next
one a second later (the paper reads the points as a trajectory in this order); its three
readings share that time and the point is the ground truth. The radio values in site.toml are
the neutral guess every converter here writes (-60 dBm at 1 m, n = 2), not the paper's fits.

    git clone https://github.com/herolab-uga/pf-doa-localization herolab
    python tools/convert_pachos.py herolab/dataset1 host/pfdoa/data
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run, write_site_folder

TECHS = {"wifi": "Wi-Fi (IEEE 802.11n, 2.4 GHz; Raspberry Pi 3)", "ble": "BLE (Gimbal Series 10 beacons)",
         "zigbee": "Zigbee, IEEE 802.15.4 (Series 2 XBee)"}
ANCHORS = ((0.0, 0.0), (0.0, 4.0), (4.0, 0.0))  # transmitters A, B, C
SOURCE = ("S. Sadowski, P. Spachos, K. N. Plataniotis, RSSI dataset for indoor localization fingerprinting, scenario 1 "
          "(github.com/pspachos/RSSI-Dataset-for-Indoor-Localization-Fingerprinting), as copied in "
          "github.com/herolab-uga/pf-doa-localization at f852403ce5dfca5d0b98d35270d69b63ff5d0948, dataset1/")
LICENSE = "MIT (the herolab-uga/pf-doa-localization copy; host/pfdoa/data/LICENSE-herolab-pf-doa-localization)"
RUNS = {"fingerprints": ("dataset1", False), "tests": ("testdata", True)}  # run: (file part, x and y swapped)


def read_points(path: Path, swapped: bool) -> list[tuple[float, float, tuple[float, float, float]]]:
    """(x, y, (RSSI A, B, C) dBm) of every point, in file order."""
    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            x, y = float(row["x"]), float(row["y"])
            if swapped:
                x, y = y, x
            out.append((x, y, tuple(-float(row[f"RSSI {c}"]) for c in "ABC")))
    if not out:
        raise ValueError(f"{path}: no points")
    return out  # type: ignore[return-value]


def convert(src: Path, out: Path) -> list[str]:
    # Everything read before anything is written: a missing file leaves no half-converted site.
    data = {(tech, run): read_points(src / f"{tech}-{part}.csv", swapped)
            for tech in TECHS for run, (part, swapped) in RUNS.items()}
    made = []
    for tech, what in TECHS.items():
        name = f"pachos_{tech}"
        site = out / name
        site.mkdir(parents=True, exist_ok=True)
        for run in RUNS:
            points = data[(tech, run)]
            # a point a second, its three readings at that time, the point as ground truth
            write_run(site / f"{run}.csv.gz", ((float(k), a, r, x, y) for k, (x, y, rssi) in enumerate(points)
                                               for a, r in enumerate(rssi)))
            print(f"{name}/{run}: {len(points)} points")
        meta = {"source": SOURCE, "license": LICENSE, "technology": tech,
                "target": "receiver at static points", "anchors": [list(a) for a in ANCHORS],
                "anchor_ids_in_source": ["A", "B", "C"], "runs": list(RUNS),
                "caveats": [
                    "One RSSI per transmitter and point (the source's raw files hold about 300 readings per point; "
                    "the copy used here has one value per point).",
                    "The roles are reversed: the transmitters are the anchors and the receiver is located.",
                    "tests: the 10 test points, x and y read swapped (stored transposed relative to the grid file).",
                    "The points are read as a trajectory in file order, one a second, as the PF-DOA paper does.",
                    "Heights are not given (every device on a table); every position is 2-D.",
                ]}
        write_site_folder(site, ANCHORS, [
            f"Three {what} transmitters 4 m apart in a 6.0 x 5.5 m meeting room; a receiver at static points.",
            f"{LICENSE}: {SOURCE}.",
            "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the other."], meta)
        made.append(name)
    return made


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path, help="the dataset1/ folder of herolab-uga/pf-doa-localization")
    ap.add_argument("out", type=Path, help="where the site folders go (host/pfdoa/data)")
    args = ap.parse_args(argv)
    return run_converter("convert_pachos", lambda: convert(args.source, args.out))


if __name__ == "__main__":
    sys.exit(main())
