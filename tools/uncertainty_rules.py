#!/usr/bin/env python3
"""Rules for pf-doa's uncertainty factors across runs, on the robot's development runs only.

For every ordered pair (calibration run c, scored run s) of herolab_wifi_robot's development
runs (pfdoa.evaluation.sites.PROTOCOLS; held-out runs are never loaded), pf-doa runs without
factors (``pfdoa.calibrate.score_uncertainty``, seeds 0..UNCERTAINTY_SEEDS-1) on every run
calibrated on c; the factors only multiply what is reported, so each rule is scored post hoc:
factors from the runs that are neither c nor s, then the share of s's estimates whose truth
lies within the scaled r95 / cov ellipse. Rules: ``pooled`` (the 95 % quantile of the other
runs' pooled ratios: learn_uncertainty's), ``max`` (the largest of their own 95 % quantiles).
docs/estimator-study.md, "Uncertainty factors measured across runs", quotes its output.

Usage: .venv/bin/python tools/uncertainty_rules.py
"""

from __future__ import annotations

import itertools

import numpy as np

from pfdoa.calibrate import score_uncertainty
from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation.experiments import calibrated_site
from pfdoa.evaluation.sites import PROTOCOLS, committed_sites

SITE = "herolab_wifi_robot"
LOW, HIGH = 88.0, 98.0


def main() -> None:
    (ts,) = [t for t in committed_sites() if t.name == SITE]
    dev = list(PROTOCOLS[SITE].develop)
    scores = {}
    for c in dev:
        fitted = calibrated_site(ts, c)
        for r in dev:
            if r != c:
                _, trace_path, odo_path = ts.run(r)
                trace, odo = ds.trace_cached(trace_path), ds.odometry_cached(odo_path)
                for m in (False, True):
                    scores[(c, r, m)] = score_uncertainty(trace, fitted, odo if m else None, ts.window_s).ratios()
    print(f"{SITE}: {len(dev)} development runs, {len(dev) * (len(dev) - 1)} ordered pairs")
    for m in (False, True):
        for rule in ("pooled", "max"):
            in_r95, in_cov = [], []
            for c, s in itertools.permutations(dev, 2):
                others = [scores[(c, r, m)] for r in dev if r not in (c, s)]
                if rule == "pooled":
                    f_r95 = np.quantile(np.concatenate([o[0] for o in others]), 0.95)
                    f_d2 = np.quantile(np.concatenate([o[1] for o in others]), 0.95)
                else:
                    f_r95 = max(np.quantile(o[0], 0.95) for o in others)
                    f_d2 = max(np.quantile(o[1], 0.95) for o in others)
                ratio, d2 = scores[(c, s, m)]
                in_r95.append(100.0 * np.mean(ratio <= f_r95))
                in_cov.append(100.0 * np.mean(d2 <= f_d2))
            p95, pcov = np.array(in_r95), np.array(in_cov)
            band = lambda a: int(np.sum((a >= LOW) & (a <= HIGH)))  # noqa: E731
            print(f"{'odometry' if m else 'no odometry':12s} {rule:7s} in r95 {p95.mean():.1f} %, "
                  f"in cov {pcov.mean():.1f} %; pairs in band {band(p95)} / {band(pcov)}, "
                  f"below {int(np.sum(p95 < LOW))} / {int(np.sum(pcov < LOW))}, "
                  f"above {int(np.sum(p95 > HIGH))} / {int(np.sum(pcov > HIGH))} (of {len(p95)})")


if __name__ == "__main__":
    main()
