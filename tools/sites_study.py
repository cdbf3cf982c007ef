#!/usr/bin/env python3
"""Estimator study on the real development sites: development runs only, never held-out ones.

Runs the evaluation harness of ``pfdoa eval`` (same windows, calibrations, seeds and
statistics) on the committed sites' DEVELOPMENT pairs (pfdoa.evaluation.sites.PROTOCOLS:
for a site with held-out runs only the development runs are scored; a two-run site is
cross-calibrated both ways) and prints, per site, the pooled RMSE (mean over seeds, max -
min), median, p90 and the uncertainty checks of every method and every pf-doa variant.
Held-out runs are never scored here, so no decision taken with this tool looks at them.

Variants are ``name:key=value,key=value`` (``--variant "t2:tail_dof=2"``), options of
pf-doa unless ``method=...`` is among them.

Usage: .venv/bin/python tools/sites_study.py [--seeds 3] [--sites kolakowski_ble_dev,...]
       [--methods pf-doa,wcl,markov] [--variant ...] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys

from pfdoa.estimators import METHODS
from pfdoa.evaluation import sites as sites_mod
from pfdoa.evaluation.experiments import EvalConfig, run_all, seed_stats
from pfdoa.evaluation.report import COMPARISON_EXCLUDE, site_cells, site_roles
from pfdoa.evaluation.runner import Variant, parse_variant


def _sim(variants: list[Variant], trials: int) -> None:
    """Dataset 0 at 2 dB, the three paths, as pfdoa eval runs it (same seeds)."""
    from pfdoa.evaluation import datasets as ds
    from pfdoa.evaluation.experiments import Cell, Job, execute

    cfg = EvalConfig(methods=("pf-doa",), sites=(), table1=False, sweeps=False)
    cells: dict[str, list[tuple[str, Cell]]] = {}  # per variant label: (path, cell) of each trial
    for path in ds.D0_PATHS:
        for trial in range(trials):
            job = Job("dataset0", f"{path}@2dB", trial, (path, 2.0, ds.D0_PATH_LOSS_EXPONENT), tuple(variants))
            for label, r in execute(cfg, job).results.items():
                c = Cell(errors=[r.errors], trials=[trial], in_r95=[r.in_r95], in_cov=[r.in_cov], lost=[r.lost])
                c.trial_rmse.append(float((r.errors ** 2).mean() ** 0.5))
                cells.setdefault(label, []).append((path, c))
    print(f"\n## Dataset 0, 2 dB, {trials} trials per path\n")
    print("| variant | " + " | ".join(ds.D0_PATHS) + " | mean | in r95 | in cov | lost |")
    print("|---|---|---|---|---|---|---|---|")
    for label, pcs in cells.items():
        per = [sum(c.trial_rmse[0] for p, c in pcs if p == path) / trials for path in ds.D0_PATHS]
        st = seed_stats([c for _p, c in pcs])
        assert st is not None  # every cell above has one trial and no failure
        print(f"| {label} | " + " | ".join(f"{v:.3f}" for v in per) + f" | {sum(per) / 3:.3f} | "
              f"{100 * st.in_r95:.1f} | {100 * st.in_cov:.1f} | {100 * st.lost:.1f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--sites", default=",".join(sites_mod.DEVELOPMENT_SITES),
                    help="comma list of development sites (held-out sites are refused)")
    ap.add_argument("--methods", default="all", help="comma list of methods, 'all' or 'none'")
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--no-odom-only", action="store_true", help="skip the rows with odometry")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--sim", type=int, default=0, metavar="TRIALS",
                    help="also Dataset 0 at 2 dB (three paths) with this many noise draws")
    args = ap.parse_args()
    methods = list(METHODS) if args.methods == "all" else [m for m in args.methods.split(",") if m and m != "none"]
    rows = [(m, m, ()) for m in methods] + [(n, m, tuple(o.items())) for n, m, o in map(parse_variant, args.variant)]
    variants = []
    for label, method, opts in rows:
        if args.no_odom_only:
            variants.append(Variant(label, method, False, opts))
            continue
        variants.append(Variant(label, method, True, opts))
        variants.append(Variant(f"{label} (no odom)", method, False, opts))
    if args.sim:
        _sim(variants, args.sim)
    wanted = set(args.sites.split(",")) - {""}
    if wanted - set(sites_mod.DEVELOPMENT_SITES):
        ap.error(f"--sites: not development sites: {', '.join(sorted(wanted - set(sites_mod.DEVELOPMENT_SITES)))}")
    sites = tuple(ts for ts in sites_mod.committed_sites() if ts.name in wanted)
    cfg = EvalConfig(methods=tuple(methods) or ("pf-doa",), sites=sites, site_seeds=args.seeds, table1=False,
                     sweeps=False, site_roles=(sites_mod.DEVELOPMENT, sites_mod.CROSS),
                     site_variants=tuple(variants), jobs=args.jobs)
    res = run_all(cfg, progress=False)
    for ts in sites:
        for role in site_roles(res, ts.name):
            assert role != sites_mod.HELD_OUT
            print(f"\n## {ts.name} ({role}, seeds 0-{args.seeds - 1})\n")
            print("| variant | RMSE | max-min | p50 | p90 | in r95 | in cov | lost |")
            print("|---|---|---|---|---|---|---|---|")
            best_other = min((st.rmse for lab in res.variants["sites"]
                              if lab.split(" ")[0] not in COMPARISON_EXCLUDE and lab.split(":")[0] in METHODS
                              for st in [seed_stats(site_cells(res, ts.name, role, lab))] if st), default=float("nan"))
            for lab in res.variants["sites"]:
                st = seed_stats(site_cells(res, ts.name, role, lab))
                if st is None:
                    continue
                print(f"| {lab} | {st.rmse:.3f} | {st.rmse_spread:.3f} | {st.median:.2f} | {st.p90:.2f} | "
                      f"{100 * st.in_r95:.1f} | {100 * st.in_cov:.1f} | {100 * st.lost:.1f} |")
            if best_other == best_other:  # not NaN: a comparison method was run (--methods none runs none)
                print(f"\nbest comparison method: {best_other:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
