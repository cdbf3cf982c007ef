#!/usr/bin/env python3
"""Synthetic site folders of the kinds we have no real data for, for ``pfdoa eval --sites``.

The project is judged on real sites it has never seen: halls of tens of metres, tens of
readings per anchor a second, static points. This writes such sites as the converters write
theirs (:func:`pfdoa.evaluation.sites.write_site_folder` and ``write_run``: site.toml with
anchor heights, anchors.json, runs ``t,anchor,rssi_dbm,gt_x,gt_y``) from the radio model
every method inverts (:func:`pfdoa.radio.mean_rssi`: log-distance in 3-D, per-anchor
offsets), with Gaussian noise per reading rounded to whole dB as receivers report it. They
test the deployment protocol and the filter's failure modes, not its accuracy on real rooms:
the model is exact here.

* ``hall12``: twelve anchors on a circle of 30 m (so the search box's corners lie beyond
  them), 1.2-2.6 m high, a tag at 1 m walking a Lissajous loop, 20 readings per anchor a
  second with 4 dB noise, three 5-minute runs;
* ``hall12_deaf``: the same layout and walks (its own heights and offsets), whose receivers
  report nothing below -88 dBm (a BLE receiver's sensitivity): the far anchors fall silent,
  and those heard near the limit are the readings that happened to come out strong;
* ``static8``: eight anchors on a circle of 12 m, a tag standing 20 s at each of random
  points, 5 readings a second, two runs.

Usage: .venv/bin/python tools/synthetic_sites.py OUT_DIR [--seed 1]
then:  .venv/bin/pfdoa eval --sites OUT_DIR --calibration walk --jobs 2 --out report.md
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import write_run, write_site_folder
from pfdoa.radio import PathLoss, mean_rssi

MODEL = PathLoss(-62.0, 2.2)  # the truth; the site files say the neutral -60 dBm, n = 2
TARGET_Z = 1.0


def _circle(n: int, span: float) -> np.ndarray:
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.column_stack([span / 2 * (1 + np.cos(ang)), span / 2 * (1 + np.sin(ang))])


def _write_site(folder: Path, anchors: np.ndarray, z: np.ndarray) -> None:
    # As the converters write theirs: the neutral radio guess, heights as placed (to the cm).
    write_site_folder(folder, np.round(anchors, 2), ["Synthetic (tools/synthetic_sites.py): the neutral radio "
                                                     "model, anchor heights as placed."],
                      {"source": "tools/synthetic_sites.py", "licence": "generated", "model": [MODEL.rssi_at_1m_dbm,
                       MODEL.path_loss_exponent]}, heights=(np.round(z, 2).tolist(), TARGET_Z))


def _write_run(path: Path, t: np.ndarray, truth: np.ndarray, anchors: np.ndarray, z: np.ndarray,
               offsets: np.ndarray, noise_db: float, rate_hz: float, rng: np.random.Generator,
               sensitivity_dbm: float = -math.inf) -> None:
    rss = mean_rssi(truth, anchors, MODEL, offsets, z - TARGET_Z)
    rss = np.round(rss + noise_db * rng.standard_normal(rss.shape))
    # each anchor's readings at its own instants within the reading period
    when = t[:, None] + rng.uniform(0.0, 1.0 / rate_hz, rss.shape)
    order = np.argsort(when, axis=None, kind="stable")
    when = np.round(when, 3)  # to the ms, as receivers stamp them
    rows, cols = np.unravel_index(order, rss.shape)
    gt = np.round(truth, 3)
    heard = rss >= sensitivity_dbm
    write_run(path, ((when[r, c], c, rss[r, c], gt[r, 0], gt[r, 1])
                     for r, c in zip(rows.tolist(), cols.tolist()) if heard[r, c]))


def _site(out: Path, name: str, n_anchors: int, span: float, rate_hz: float, duration_s: float, runs: int,
          path, rng: np.random.Generator, sensitivity_dbm: float = -math.inf) -> None:
    """A site of ``n_anchors`` on a circle of ``span`` m (heights 1.2-2.6 m, offsets 1-sigma
    2 dB) and ``runs`` runs whose truth is ``path(t, run)``, 4 dB noise per reading."""
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    anchors = _circle(n_anchors, span)
    z = rng.uniform(1.2, 2.6, n_anchors)
    offsets = rng.normal(0.0, 2.0, n_anchors)
    _write_site(folder, anchors, z)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    for run in range(runs):
        _write_run(folder / f"run{run}.csv", t, path(t, run), anchors, z, offsets, 4.0, rate_hz, rng,
                   sensitivity_dbm)


def _loop(t: np.ndarray, run: int) -> np.ndarray:
    return np.column_stack([15.0 + 10.5 * np.cos(t / 20 + run), 15.0 + 10.5 * np.sin(t / 13 + run)])


def hall12(out: Path, rng: np.random.Generator) -> None:
    _site(out, "hall12", 12, 30.0, 20.0, 300.0, 3, _loop, rng)


def hall12_deaf(out: Path, rng: np.random.Generator) -> None:
    _site(out, "hall12_deaf", 12, 30.0, 20.0, 300.0, 3, _loop, rng, sensitivity_dbm=-88.0)


def static8(out: Path, rng: np.random.Generator) -> None:
    def points(t: np.ndarray, run: int) -> np.ndarray:
        at = rng.uniform(0.2 * 12.0, 0.8 * 12.0, (int(t[-1] // 20) + 1, 2))  # 20 s at each
        return at[(t // 20).astype(int)]

    _site(out, "static8", 8, 12.0, 5.0, 200.0, 2, points, rng)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n", 2)[2])
    ap.add_argument("out", type=Path, help="folder to write the site folders into")
    ap.add_argument("--seed", type=int, default=1, help="the data's random seed (default 1)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    hall12(args.out, rng)
    static8(args.out, rng)
    hall12_deaf(args.out, rng)
    print(f"wrote {args.out}/hall12, static8 and hall12_deaf", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
