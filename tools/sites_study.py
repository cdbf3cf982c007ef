#!/usr/bin/env python3
"""Estimator study on the real development sites: development scorings only, never held-out ones.

Runs the evaluation harness of ``pfdoa eval`` (same windows, calibrations, seeds and
statistics) on the development sites: the committed ones and the local ones in ``--local``
(build/sites: converted from datasets that state no licence, see host/pfdoa/data/README.md).
Held-out sites (pfdoa.evaluation.sites.PROTOCOLS, recognised by their runs' contents) are
refused, and held-out runs of development sites are never scored, so no decision taken with
this tool looks at them.

``--protocol walk`` (default): the deployment protocol of ``make eval-sites`` (each run
calibrated on one other run alone, every ordered pair, and each run uncalibrated); prints per
site the pooled RMSE (mean over seeds, max - min), the ratio to the best other method, how
often the truth lies within r95 (all estimates, and the worst quarter of errors) of every
method and every pf-doa variant, then the worst and the mean ratio over sites (decisions: the
worst first, then the mean). ``--protocol auto``: the committed sites' development pairs as
``pfdoa eval`` scores them (uncertainty factors measured on the other development runs).

Variants are ``name:key=value,key=value`` (``--variant "t2:tail_dof=2"``), options of
pf-doa unless ``method=...`` is among them.

Usage: .venv/bin/python tools/sites_study.py [--seeds 3] [--sites kolakowski_ble_dev,...]
       [--methods pf-doa,wcl,markov] [--variant ...] [--jobs 2] [--local build/sites]
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
                c = Cell(errors=[r.errors], trials=[trial], in_cov=[r.in_cov], lost=[r.lost], r95_m=[r.r95_m])
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


def _sites(args, ap) -> tuple:
    """The development sites to score: committed and local, held-out ones refused."""
    found = sites_mod.development_sites(args.local, odometry=not args.no_odom_only)
    development = {ts.name for ts in found}
    wanted = set(args.sites.split(",")) - {""} if args.sites else development
    if wanted - development:
        ap.error(f"--sites: not development sites: {', '.join(sorted(wanted - development))}")
    return tuple(ts for ts in found if ts.name in wanted)


def _print_auto(res, sites, seeds: int) -> None:
    for ts in sites:
        for role in site_roles(res, ts.name):
            assert role not in sites_mod.HELD_OUT_ROLES
            print(f"\n## {ts.name} ({role}, seeds 0-{seeds - 1})\n")
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


def _print_walk(res, sites, seeds: int, candidates: list[str]) -> None:
    from pfdoa.evaluation import deployment as dep

    scores = [s for ts in sites for s in dep.site_scores(res, ts)]
    assert not any(s.held_out for s in scores)
    per: dict[str, dict[bool, list[tuple[float, str]]]] = {c: {True: [], False: []} for c in candidates}
    for s in dep.worst_first(scores):
        print(f"\n## {s.site} (one walk: {s.pairs} pairs; uncalibrated: {s.runs} runs; seeds 0-{seeds - 1})\n")
        print("| variant | mode | RMSE | max-min | ratio | in r95 | worst quarter | r95 tracks error | uncal. RMSE | "
              "uncal. ratio | uncal. in r95 | uncal. worst quarter |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for mode in dep.modes(s.has_odometry):
            for c in candidates:
                cal = dep.compare(s.rows["calibrated"], mode, s.has_odometry, c)
                unc = dep.compare(s.rows["uncalibrated"], mode, s.has_odometry, c)
                if cal is None and unc is None:
                    continue
                if mode == s.headline:
                    for calibrated, comp in ((True, cal), (False, unc)):
                        if comp is not None:
                            per[c][calibrated].append((comp.ratio, s.site))
                f = lambda v: "-" if v is None else v  # noqa: E731
                st = cal.ours.stats if cal is not None else None
                print(f"| {c} | {mode} | {f(st and f'{st.rmse:.3f}')} | {f(st and f'{st.rmse_spread:.3f}')} | "
                      f"{f(cal and f'{cal.ratio:.3f}')} | {f(st and f'{100 * st.in_r95:.1f}')} | "
                      f"{f(cal and f'{100 * cal.ours.worst_quarter:.1f}')} | {f(cal and f'{cal.ours.tracks:.2f}')} | "
                      f"{f(unc and f'{unc.ours.stats.rmse:.3f}')} | {f(unc and f'{unc.ratio:.3f}')} | "
                      f"{f(unc and f'{100 * unc.ours.stats.in_r95:.1f}')} | "
                      f"{f(unc and f'{100 * unc.ours.worst_quarter:.1f}')} |")
        for mode in dep.modes(s.has_odometry):
            cal = dep.compare(s.rows["calibrated"], mode, s.has_odometry)
            if cal is not None:
                print(f"\nbest comparison method ({mode}): {cal.best.label} {cal.best.stats.rmse:.3f}")
    print("\n## Over sites (headline: with odometry where a site has it)\n")
    print("| variant | worst ratio (site) | mean ratio | uncal. worst (site) | uncal. mean |")
    print("|---|---|---|---|---|")
    for c in candidates:
        cells = []
        for calibrated in (True, False):
            v = per[c][calibrated]
            cells += [f"{max(v)[0]:.3f} ({max(v)[1]})", f"{sum(r for r, _s in v) / len(v):.3f}"] if v else ["-", "-"]
        print(f"| {c} | " + " | ".join(cells) + " |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--protocol", choices=("walk", "auto"), default="walk",
                    help="walk: one calibration walk per pair and uncalibrated (make eval-sites); auto: the committed "
                         "sites' development pairs as pfdoa eval scores them")
    ap.add_argument("--sites", default="", help="comma list of development sites (default: all; held-out sites are "
                                               "refused)")
    ap.add_argument("--local", default="build/sites", help="folder of local site folders, used if present "
                                                           "(default %(default)s)")
    ap.add_argument("--methods", default="all", help="comma list of methods, 'all' or 'none'")
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--no-odom-only", action="store_true", help="skip the rows with odometry")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--cache", default="build/eval-cache", help="keep the comparison methods' results here by "
                                                                "content (pfdoa eval --cache; '' for none)")
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
    sites = _sites(args, ap)
    walk = args.protocol == "walk"
    roles = (sites_mod.ONE_WALK, sites_mod.UNCALIBRATED) if walk else (sites_mod.DEVELOPMENT, sites_mod.CROSS)
    cfg = EvalConfig(methods=tuple(methods) or ("pf-doa",), sites=sites, site_seeds=args.seeds, table1=False,
                     sweeps=False, site_roles=roles, site_variants=tuple(variants), jobs=args.jobs,
                     calibration="walk" if walk else "auto", cache_dir=args.cache or None)
    res = run_all(cfg, progress=False)
    if walk:
        _print_walk(res, sites, args.seeds, [label for label, _m, _o in rows if label not in METHODS or label == "pf-doa"])
    else:
        _print_auto(res, sites, args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
