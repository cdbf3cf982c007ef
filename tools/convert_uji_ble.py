"""Convert the UJI BLE RSS database to pfdoa site folders (the copy in host/pfdoa/data).

Source: G. M. Mendoza-Silva, M. Matey-Sanz, J. Torres-Sospedra, J. Huerta, "BLE RSS
measurements database and supporting materials", Universitat Jaume I, 2018, Zenodo
10.5281/zenodo.1618692, data under CC BY 4.0. Read from its ``data/`` folder (``rss/<zone>_{rss,
tms,crd,ids}.csv``, ``dep/<zone>.csv``) as published; the committed copy was converted from
github.com/Kassiopeia14/IndoorPositioning ``UJI_BLE_DB/data`` at commit ea387895e7301154c14438e534676b27bf1a7d5f.

A phone held at reference points collects one scan a second, several scans per point, then
is carried to the next point; the beacons are the anchors. Each (phone,
transmit power, campaign) set becomes one run, in collection order: a reading per detected
beacon per scan at the scan's own time for that beacon, the point's coordinates as ground
truth. An id's digits are phone (10^7), power (10^6), campaign (10^5), point (10^2) and
scan, as the database's own loading functions read them. Beacons are renumbered 0..N-1 in
the deployment file's order (their ids in the database are kept in anchors.json).

    python tools/convert_uji_ble.py UJI_BLE_DB/data host/pfdoa/data
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import converter_parser, run_converter, write_run, write_site_folder

ZONES = {
    "lib": ("uji_ble_library", "a zone of a university library (its shelves and pillars outlined in the database's obs/lib.csv)"),
    "geo": ("uji_ble_lab", "an office space, the Geotec lab (its obstacles outlined in the database's obs/geo.csv)"),
}
PHONES = {1: "a5", 2: "bq", 3: "s6"}  # the phones the database names A5, Bq and S6 (its filter definitions)
POWERS = {1: "m04", 2: "m12", 3: "m20"}  # beacon transmit power -4, -12, -20 dBm
CAMPAIGNS = {1: "c1", 2: "c1", 3: "c4"}  # the library's campaigns c1 and c4 are coded 2 and 3; the lab's c1 is 1
NOT_SEEN = 100  # the database's RSS for a beacon a scan did not detect
SOURCE = "G. M. Mendoza-Silva, M. Matey-Sanz, J. Torres-Sospedra, J. Huerta, BLE RSS measurements database (UJI, 2018)"
LICENSE = "CC-BY-4.0 (Zenodo 10.5281/zenodo.1618692; the database's data/Readme.txt)"


def convert_zone(src: Path, zone: str, out: Path) -> list[str]:
    name, what = ZONES[zone]
    ids = np.loadtxt(src / "rss" / f"{zone}_ids.csv", dtype=np.int64, ndmin=1)
    crd = np.loadtxt(src / "rss" / f"{zone}_crd.csv", delimiter=",", ndmin=2)
    tms = np.loadtxt(src / "rss" / f"{zone}_tms.csv", delimiter=",", dtype=np.int64, ndmin=2)
    rss = np.loadtxt(src / "rss" / f"{zone}_rss.csv", delimiter=",", ndmin=2)
    dep = [line.split(",") for line in (src / "dep" / f"{zone}.csv").read_text().split()[1:]]
    if not (len(ids) == len(crd) == len(tms) == len(rss)) or rss.shape[1] != len(dep) or tms.shape != rss.shape:
        raise SystemExit(f"{src}: {zone}'s files do not line up")
    site = out / name
    site.mkdir(parents=True, exist_ok=True)
    anchors = [(float(x), float(y)) for _id, x, y in dep]
    phone, power, campaign = ids // 10**7, (ids // 10**6) % 10, (ids // 10**5) % 10
    runs = []
    for key in sorted(set(zip(phone.tolist(), power.tolist(), campaign.tolist()))):
        scans = np.flatnonzero((phone == key[0]) & (power == key[1]) & (campaign == key[2]))
        k_scan, k_anchor = np.nonzero((rss[scans] != NOT_SEEN) & (tms[scans] > 0))
        rows = scans[k_scan]
        t_ns = tms[rows, k_anchor]
        order = np.lexsort((k_anchor, t_ns))
        rows, k_anchor, t_ns = rows[order], k_anchor[order], t_ns[order]
        t = (t_ns - t_ns[0]) / 1e9  # the phone's elapsed-time clock, from the run's first reading
        run = f"{PHONES[key[0]]}_{POWERS[key[1]]}_{CAMPAIGNS[key[2]]}"
        write_run(site / f"{run}.csv.gz", ((tt, a, r, x, y) for tt, a, r, (x, y) in  # a scan's readings: its point
                                           zip(t.tolist(), k_anchor.tolist(), rss[rows, k_anchor].tolist(),
                                               crd[rows].tolist())))
        runs.append(run)
        print(f"{name}/{run}: {len(t)} readings, {len(np.unique(ids[scans] // 100 % 1000))} points, {t[-1]:.0f} s")
    meta = {
        "source": f"{SOURCE}, data/rss/{zone}_*.csv and data/dep/{zone}.csv",
        "license": LICENSE,
        "technology": "ble",
        "anchors": [list(a) for a in anchors],
        "anchor_ids_in_source": [d[0] for d in dep],
        "runs": runs,
        "run_names": "<phone>_<power>_<campaign>: phone a5/bq/s6 (named A5, Bq, S6 in the database), the beacons' "
                     "transmit power m04/m12/m20 = -4/-12/-20 dBm, collection campaign c1/c4",
        "caveats": [
            "The roles are reversed: the beacons transmit and the phone receives; RSSI is the phone's.",
            "The phone stands still at each reference point for its scans (about one a second), then is carried "
            "to the next point with no reading on the way: a stop-and-go walk whose ground truth is the points.",
            "Phones differ in receive gain, and the lab's runs in the beacons' transmit power: calibrate per run.",
            "Anchor heights are not given; every position is 2-D.",
            "The beacons are iBKS 105, advertising every 200 ms (the database's data descriptor: Mendoza-Silva et al., "
            "Data 4(1):12, 2019).",
        ],
    }
    comments = [f"{len(anchors)} BLE beacons (the anchors) in {what}; a phone held at reference points.",
                f"{LICENSE}: {SOURCE}.",
                "Radio values are a neutral guess: fit them with `pfdoa calibrate` on one run, score the others."]
    write_site_folder(site, anchors, comments, meta)
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = converter_parser(__doc__)
    ap.add_argument("source", type=Path, help="the database's data/ folder (rss/, dep/)")
    ap.add_argument("out", type=Path, help="where the site folders go (host/pfdoa/data)")
    args = ap.parse_args(argv)
    return run_converter("convert_uji_ble", lambda: [convert_zone(args.source, zone, args.out) for zone in ZONES])


if __name__ == "__main__":
    sys.exit(main())
