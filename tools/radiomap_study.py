#!/usr/bin/env python3
"""The radio map's choices on the development sites: development runs only, never held-out ones.

For every development pair (calibration run c, scored run s) of the committed sites
(pfdoa.evaluation.sites.PROTOCOLS; kolakowski both ways), at kernel lengths 0.5, 1 and 2 m:

* the map's trust on c alone (pfdoa.radiomap.trust_of: the 30 s block cross-validation);
* its explained share of s's differential residuals at s's true positions (how well a map
  of c transfers to another run; uses s's ground truth, so it is analysis, not the method);
* pf-doa's pooled RMSE on s with that map and without (seeds 0..--seeds-1, no odometry).

docs/archive/estimator-study.md, "Radio map from the calibration trace", quotes its output.

Usage: .venv/bin/python tools/radiomap_study.py [--seeds 4] [--lengths 0.5,1,2]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math

import numpy as np

from pfdoa.api import calibrate_traces
from pfdoa.estimators import Observation, make_estimator
from pfdoa.estimators.pf_doa import MAX_EXPONENT, MIN_EXPONENT
from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation.sites import DEVELOPMENT_SITES, PROTOCOLS, committed_sites
from pfdoa.radiomap import MapLookup, fit_radio_map, residuals
from pfdoa.trace import group_by_window


def pairs(ts) -> list[tuple[str, str]]:
    runs = PROTOCOLS[ts.name].develop if ts.name in PROTOCOLS else ts.run_names
    return list(itertools.permutations(runs, 2))


def rmse(site, windows, seeds) -> float:
    errs = []
    for seed in seeds:
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
        for w in windows:
            e = est.step(Observation(w.t, w.rssi, w.count))
            if w.gt is not None:
                errs.append(math.hypot(w.gt[0] - e.x, w.gt[1] - e.y))
    return float(np.sqrt(np.mean(np.square(errs))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--lengths", default="0.5,1,2")
    args = ap.parse_args()
    lengths = [float(v) for v in args.lengths.split(",")]
    seeds = range(args.seeds)
    for ts in (t for t in committed_sites() if t.name in DEVELOPMENT_SITES):  # never a held-out site
        site0 = ds.load_site_cached(ts.site_path)
        base_all: list[float] = []
        map_all: dict[float, list[float]] = {length: [] for length in lengths}  # per length scale: RMSE per pair
        print(f"## {ts.name}")
        for c, s in pairs(ts):
            fitted = calibrate_traces([ds.trace_cached(ts.run(c)[1])], site0, robust=True, radio_map=False,
                                      window_s=ts.window_s).apply(site0)
            exponent = min(max(fitted.radio.path_loss_exponent, MIN_EXPONENT), MAX_EXPONENT)
            cal = list(group_by_window(ds.trace_cached(ts.run(c)[1]), fitted, ts.window_s))
            scored = list(group_by_window(ds.trace_cached(ts.run(s)[1]), fitted, ts.window_s))
            xy_s, r_s, _ = residuals(fitted, scored, exponent)
            base = rmse(fitted, scored, seeds)
            base_all.append(base)
            cells = []
            for length in lengths:
                rmap = fit_radio_map(fitted, [cal], exponent, length_m=length)
                if rmap is None:
                    cells.append(f"L={length:g}: trust 0, no map")
                    map_all[length].append(base)
                    continue
                full = dataclasses.replace(rmap, trust=1.0)  # the map itself, for the transfer check
                pred = MapLookup(full, fitted.anchor_ids, 1).at(xy_s)
                ok = np.isfinite(r_s)
                share = 1.0 - float(np.sum((r_s - pred)[ok] ** 2)) / float(np.sum(r_s[ok] ** 2))
                with_map = dataclasses.replace(fitted, sections={**fitted.sections, "radio_map": rmap.to_section()})
                r = rmse(with_map, scored, seeds)
                map_all[length].append(r)
                cells.append(f"L={length:g}: trust {rmap.trust:.2f}, transfer {share:+.3f}, RMSE {r:.3f}")
            print(f"{c} -> {s}: without map {base:.3f}; " + "; ".join(cells))
        # Pooled over pairs as the mean of per-pair RMSEs (equal-length pairs: close to the pooled figure).
        print(f"mean over pairs: without map {np.mean(base_all):.3f}; "
              + "; ".join(f"L={length:g} {np.mean(v):.3f}" for length, v in map_all.items()) + "\n")


if __name__ == "__main__":
    main()
