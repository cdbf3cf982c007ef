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
  points, 5 readings a second, two runs;
* the walls (``--walls``): rooms whose every anchor also has a place-fixed deviation, the
  same in every run (:func:`_shadowing`: 3-5 dB, correlated over 2-3 m, Gudmundson's
  shadowing), which no calibration walk removes where it did not pass and which a tag that
  stands still cannot average: ``static4_walls``, ``static8_walls``, ``static12_walls`` (4, 8
  and 12 anchors about circles of 8, 12 and 16 m, each moved off it by 1-sigma 10 % of the
  span, a tag standing 20 s at each of random points),
  ``walk4_walls`` and ``walk8_walls`` (a tag walking a loop at 0.5 and 1 m/s), three runs
  each, two draws of each (suffixes ``_a``, ``_b``);
* the surveys (``--survey``): long floors (40 x 16, 60 x 20 and 30 x 12 m) with 12, 14 and 8
  anchors in two rows along their long sides, walls of 4 dB, a phone held at points drawn
  anywhere on the floor, one scan a second: ``run0`` 90 points of 3.3 s, ``run1`` 30 of 10 s.
  The next point is often tens of metres away, as in the static-point datasets whose points
  are listed in survey order (SODIndoorLoc's): ``survey12_40``, ``survey14_60``, ``survey8_30``.

Usage: .venv/bin/python tools/synthetic_sites.py OUT_DIR [--seed 1] [--walls | --survey]
then:  .venv/bin/pfdoa eval --sites OUT_DIR --calibration walk --jobs 2 --out report.md
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pfdoa.evaluation.sites import write_run, write_site_folder
from pfdoa.radio import PathLoss, mean_rssi

MODEL = PathLoss(-62.0, 2.2)  # the truth; the site files say the neutral -60 dBm, n = 2
TARGET_Z = 1.0


def _circle(n: int, span: float) -> np.ndarray:
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.column_stack([span / 2 * (1 + np.cos(ang)), span / 2 * (1 + np.sin(ang))])


def _write_site(folder: Path, anchors: np.ndarray, z: np.ndarray, target: str) -> None:
    # As the converters write theirs: the neutral radio guess, heights as placed (to the cm).
    write_site_folder(folder, np.round(anchors, 2), ["Synthetic (tools/synthetic_sites.py): the neutral radio "
                                                     "model, anchor heights as placed."],
                      {"source": "tools/synthetic_sites.py", "license": "generated", "technology": "simulated",
                       "target": target, "model": [MODEL.rssi_at_1m_dbm, MODEL.path_loss_exponent]},
                      heights=(np.round(z, 2).tolist(), TARGET_Z))


def _write_run(path: Path, t: np.ndarray, truth: np.ndarray, anchors: np.ndarray, z: np.ndarray,
               offsets: np.ndarray, noise_db: float, rate_hz: float, rng: np.random.Generator,
               sensitivity_dbm: float = -math.inf, shadow=None) -> None:
    rss = mean_rssi(truth, anchors, MODEL, offsets, z - TARGET_Z)
    if shadow is not None:
        rss = rss + shadow(truth)
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


def _anchored_site(folder: Path, anchors: np.ndarray, rng: np.random.Generator, shadow_db: float,
                   shadow_m: float, target: str) -> tuple[np.ndarray, np.ndarray, Callable | None]:
    """``folder`` written for ``anchors`` (heights 1.2-2.6 m, offsets 1-sigma 2 dB; with
    ``shadow_db``, each anchor's place-fixed deviation, :func:`_shadowing`): returns the
    heights, the offsets and the deviations' field (None without)."""
    folder.mkdir(parents=True, exist_ok=True)
    n_anchors = len(anchors)
    z = rng.uniform(1.2, 2.6, n_anchors)
    offsets = rng.normal(0.0, 2.0, n_anchors)
    shadow = _shadowing(n_anchors, shadow_db, shadow_m, rng) if shadow_db > 0.0 else None
    _write_site(folder, anchors, z, target + (f", walls of {shadow_db:g} dB" if shadow_db > 0.0 else ""))
    return z, offsets, shadow


def _site(out: Path, name: str, n_anchors: int, span: float, rate_hz: float, duration_s: float, runs: int,
          path, rng: np.random.Generator, sensitivity_dbm: float = -math.inf, shadow_db: float = 0.0,
          shadow_m: float = 2.0, target: str = "tag walking a loop", jitter: float = 0.0) -> None:
    """A site of ``n_anchors`` on a circle of ``span`` m (heights 1.2-2.6 m, offsets 1-sigma
    2 dB) and ``runs`` runs whose truth is ``path(t, run)``, 4 dB noise per reading; with
    ``shadow_db``, each anchor's place-fixed deviation (:func:`_shadowing`)."""
    anchors = _circle(n_anchors, span)
    if jitter > 0.0:  # off the circle: else a point and its inversion in it read alike (docs/estimator.md)
        anchors = anchors + rng.normal(0.0, jitter * span, anchors.shape)
    folder = out / name
    z, offsets, shadow = _anchored_site(folder, anchors, rng, shadow_db, shadow_m, target)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    for run in range(runs):
        _write_run(folder / f"run{run}.csv", t, path(t, run), anchors, z, offsets, 4.0, rate_hz, rng,
                   sensitivity_dbm, shadow)


def _shadowing(n_anchors: int, sigma_db: float, length_m: float, rng: np.random.Generator, features: int = 64):
    """Per anchor a stationary Gaussian field over the floor, 1-sigma ``sigma_db``, correlation
    ``exp(-d^2 / (2 length_m^2))`` (random Fourier features): the walls and furniture between
    the tag and each anchor, fixed in place. Returns the field: (k, 2) positions -> (k, n_anchors) dB."""
    omega = rng.normal(0.0, 1.0 / length_m, (n_anchors, features, 2))
    phase = rng.uniform(0.0, 2.0 * np.pi, (n_anchors, features))
    amp = sigma_db * math.sqrt(2.0 / features)

    def field(xy: np.ndarray) -> np.ndarray:
        return amp * np.cos(np.einsum("kd,afd->kaf", xy, omega) + phase[None]).sum(axis=2)

    return field


def _loop(t: np.ndarray, run: int) -> np.ndarray:
    return np.column_stack([15.0 + 10.5 * np.cos(t / 20 + run), 15.0 + 10.5 * np.sin(t / 13 + run)])


def hall12(out: Path, rng: np.random.Generator) -> None:
    _site(out, "hall12", 12, 30.0, 20.0, 300.0, 3, _loop, rng)


def hall12_deaf(out: Path, rng: np.random.Generator) -> None:
    _site(out, "hall12_deaf", 12, 30.0, 20.0, 300.0, 3, _loop, rng, sensitivity_dbm=-88.0)


def _points(span: float, rng: np.random.Generator):
    """A tag standing 20 s at each of random points in the middle 60 % of the span."""
    def points(t: np.ndarray, run: int) -> np.ndarray:
        at = rng.uniform(0.2 * span, 0.8 * span, (int(t[-1] // 20) + 1, 2))
        return at[(t // 20).astype(int)]

    return points


def _walk(span: float, speed: float):
    """A loop through the middle 70 % of the span at about ``speed`` m/s."""
    r = 0.35 * span

    def path(t: np.ndarray, run: int) -> np.ndarray:
        return np.column_stack([span / 2 + r * np.cos(0.7 * speed * t / r + run),
                                span / 2 + r * np.sin(0.45 * speed * t / r + run)])

    return path


def static8(out: Path, rng: np.random.Generator) -> None:
    _site(out, "static8", 8, 12.0, 5.0, 200.0, 2, _points(12.0, rng), rng, target="tag at static points")


def walls(out: Path, rng: np.random.Generator) -> list[str]:
    """The rooms with place-fixed deviations (module doc), two draws of each."""
    names = []
    for draw in "ab":
        for name, n, span, path, db, length in (
                ("static4_walls", 4, 8.0, _points(8.0, rng), 4.0, 2.0),
                ("static8_walls", 8, 12.0, _points(12.0, rng), 4.0, 2.0),
                ("static12_walls", 12, 16.0, _points(16.0, rng), 5.0, 3.0),
                ("walk4_walls", 4, 8.0, _walk(8.0, 0.5), 3.0, 2.0),
                ("walk8_walls", 8, 12.0, _walk(12.0, 1.0), 4.0, 2.0)):
            _site(out, f"{name}_{draw}", n, span, 5.0, 200.0, 3, path, rng, shadow_db=db, shadow_m=length,
                  target="tag at static points" if name.startswith("static") else "tag walking a loop", jitter=0.1)
            names.append(f"{name}_{draw}")
    return names


def _survey(out: Path, name: str, n_anchors: int, length: float, width: float, rng: np.random.Generator) -> None:
    """A floor of ``length`` x ``width`` m, its anchors in two jittered rows along the long
    sides (heights 1.2-2.6 m, offsets 1-sigma 2 dB, walls of 4 dB correlated over 2.5 m), and
    two surveys of points drawn anywhere on it (module doc), one scan a second, 4 dB noise."""
    k = n_anchors // 2
    xs = np.linspace(0.1 * length, 0.9 * length, k)
    anchors = np.vstack([np.column_stack([xs, np.full(k, 0.15 * width)]),
                         np.column_stack([xs + length / (2 * k), np.full(k, 0.85 * width)])])
    anchors = anchors + rng.normal(0.0, 0.5, anchors.shape)
    folder = out / name
    z, offsets, shadow = _anchored_site(folder, anchors, rng, 4.0, 2.5, "phone held at points anywhere on a floor")
    for run, (points, dwell) in enumerate(((90, 10.0 / 3.0), (30, 10.0))):
        at = np.column_stack([rng.uniform(0.02 * length, 0.98 * length, points),
                              rng.uniform(0.05 * width, 0.95 * width, points)])
        t = np.arange(0.0, points * dwell, 1.0)
        truth = at[np.minimum((t // dwell).astype(int), points - 1)]
        _write_run(folder / f"run{run}.csv", t, truth, anchors, z, offsets, 4.0, 1.0, rng, shadow=shadow)


def surveys(out: Path, rng: np.random.Generator) -> list[str]:
    """The survey floors (module doc)."""
    names = []
    for n, length, width in ((12, 40.0, 16.0), (14, 60.0, 20.0), (8, 30.0, 12.0)):
        names.append(f"survey{n}_{length:g}")
        _survey(out, names[-1], n, length, width, rng)
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n", 2)[2])
    ap.add_argument("out", type=Path, help="folder to write the site folders into")
    ap.add_argument("--seed", type=int, default=1, help="the data's random seed (default 1)")
    kind = ap.add_mutually_exclusive_group()
    kind.add_argument("--walls", action="store_true", help="write the rooms with place-fixed deviations instead")
    kind.add_argument("--survey", action="store_true", help="write the survey floors (points anywhere) instead")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    if args.walls:
        names = walls(args.out, rng)
    elif args.survey:
        names = surveys(args.out, rng)
    else:
        hall12(args.out, rng)
        static8(args.out, rng)
        hall12_deaf(args.out, rng)
        names = ["hall12", "static8", "hall12_deaf"]
    print(f"wrote {', '.join(names)} in {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
