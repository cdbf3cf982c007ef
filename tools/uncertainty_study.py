#!/usr/bin/env python3
"""pf-doa's reported uncertainty on the development sites: record once, try multiples offline.

``record``: runs pf-doa (one calibration walk, every ordered pair, seeds 0..S-1, as ``make
eval-sites`` scores it; ``--role uncalibrated``: each run with its site file as given) on the
development sites only (held-out sites and the held-out runs of development sites are
refused, as in tools/sites_study.py), or on a folder's sites (``--sites``: the synthetic
rooms of tools/synthetic_sites.py, a new site; held-out ones refused), and saves per
estimate its error, the estimate, the reported r95 and the report's parts as the filter
computed them: the truncated, narrowed cloud's covariance (what ``report_cov`` was given),
the misfit's single-observation covariance (``Misfit.cov_at`` over ``MISFIT_SHARE``), the
anchors' weighted centroid, the residuals' persistence and the filter's estimate before the
pull towards that centroid (``centroid_cov``'s inputs), with the search box and the truth.
The point estimates are pf-doa's own: the recording only reads them.

``evaluate``: rebuilds the report from those parts with the filter's own functions
(``report_cov``, ``centroid_cov``, ``r95_of``) at several multiples of the misfit and of the
centroid's term, truncated to the box or not, over one or more recordings, and prints per
site how often the truth lies within r95 and the worst quarter of errors (per seed, pooled
over the pairs) does: the columns of docs/sites.md. ``evaluate --by-stop``: the reported r95's coverage per site by the estimates
since the truth last moved (the recording keeps the truth), which tells a standing target's
steady misses from those of the step after it moved. Earlier candidates and their figures
are in docs/estimator.md ("Uncertainty") and its archive.

Usage: .venv/bin/python tools/uncertainty_study.py record [--seeds 3] [--role walk|uncalibrated] [--sites DIR] [--out build/unc.pkl]
       .venv/bin/python tools/uncertainty_study.py evaluate [--in build/unc.pkl ...] [--by-stop]
"""

from __future__ import annotations

import argparse
import math
import pickle
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from pfdoa.estimators import pf_doa as pf_doa_mod
from pfdoa.estimators import pf_uncertainty as unc
from pfdoa.evaluation import sites as sites_mod
from pfdoa.evaluation.experiments import EvalConfig, _replay_rng, _sequences, build_jobs
from pfdoa.evaluation.runner import Variant

ROLES = {"walk": sites_mod.ONE_WALK, "uncalibrated": sites_mod.UNCALIBRATED}
NO_BOUND = (math.nan, math.nan, math.nan)  # Misfit.cov_at gave none (or the filter had no anchors)
# A recorded estimate's columns: error, x, y, r95, the cloud (xx, xy, yy), the misfit (xx, xy,
# yy), the truth (x, y), then the centroid (x, y), the persistence and the filter's estimate
# before the pull towards the centroid (x, y: where the model's terms are taken); recordings
# made before the truth, the centroid or the pull was kept stop at PARTS, CENTROID_X or MODEL_X.
ERR, R95, PARTS, TRUTH_X, TRUTH_Y, CENTROID_X, PERSISTENCE, MODEL_X = 0, 3, 10, 10, 11, 12, 14, 15
NO_CENTROID = (math.nan,) * 5  # no centroid yet: x, y, the persistence and the estimate's x, y


def record(seeds: int, out: str, local: str, role: str = "walk", folder: str = "") -> None:
    from pfdoa.estimators import make_estimator
    from pfdoa.estimators.base import Observation

    if folder:  # a folder's sites (the synthetic rooms, a new site), never a held-out one
        sites = tuple(ts for ts in sites_mod.find_sites(folder) if sites_mod.decision_group(ts) != sites_mod.HELD_OUT)
    else:
        sites = sites_mod.development_sites(local)
    variant = Variant("pf-doa", "pf-doa", True, ())
    cfg = EvalConfig(methods=("pf-doa",), sites=sites, site_seeds=seeds, table1=False, sweeps=False,
                     site_roles=(ROLES[role],), site_variants=(variant,), calibration="walk")
    rows: list[dict] = []
    orig_cov, orig_centroid, orig_misfit = pf_doa_mod.report_cov, pf_doa_mod.centroid_cov, unc.Misfit.cov_at
    parts: dict[str, tuple[float, ...]] = {}

    def report_cov(x, y, cloud, model, box):
        parts["cloud"] = cloud  # the truncated, narrowed cloud, before the model's error is added
        return orig_cov(x, y, cloud, model, box)

    def centroid_cov(model, x, y, centroid, persistence, share=None):
        parts["centroid"] = (*centroid, persistence, x, y)
        return orig_centroid(model, x, y, centroid, persistence, share)

    def misfit_cov(self, x, y, present):
        misfit = orig_misfit(self, x, y, present)
        parts["misfit"] = NO_BOUND if misfit is None else tuple(v / unc.MISFIT_SHARE for v in misfit)
        return misfit

    pf_doa_mod.report_cov, pf_doa_mod.centroid_cov = report_cov, centroid_cov
    setattr(unc.Misfit, "cov_at", misfit_cov)  # noqa: B010 (mypy refuses a method assigned)
    try:
        for job in build_jobs(cfg):
            name, role, cal, run = job.params
            assert role not in sites_mod.HELD_OUT_ROLES
            for seq in _sequences(cfg, job):
                est: Any = make_estimator("pf-doa", seq.site, rng=_replay_rng(job.trial, seq),
                                     **{k: v for k, v in seq.site.sections.get("estimator", {}).items()
                                        if k != "method"})
                recs = []
                for i in range(len(seq)):
                    parts.clear()
                    e = est.step(Observation(float(seq.t[i]), seq.rssi[i].copy(),
                                             None if seq.count is None else seq.count[i]),
                                 seq.odometry[i] if seq.odometry is not None else None)
                    gx, gy = seq.truth[i]
                    if not (math.isfinite(e.x) and math.isfinite(gx) and math.isfinite(gy)):
                        continue
                    cloud = parts.get("cloud", e.cov)  # no report_cov: the cloud alone was reported
                    recs.append((math.hypot(gx - e.x, gy - e.y), e.x, e.y, float(e.r95), *cloud,
                                 *parts.get("misfit", NO_BOUND), gx, gy, *parts.get("centroid", NO_CENTROID)))
                if recs:
                    rows.append(dict(site=name, cal=cal, run=run, seed=job.trial, beacon=seq.beacon,
                                     box=(*est.lo.tolist(), *est.hi.tolist()), est=np.array(recs)))
            print(f"{name} {cal}->{run} seed {job.trial}: {sum(len(r['est']) for r in rows)} estimates",
                  file=sys.stderr)
    finally:
        pf_doa_mod.report_cov, pf_doa_mod.centroid_cov = orig_cov, orig_centroid
        setattr(unc.Misfit, "cov_at", orig_misfit)  # noqa: B010
    with open(out, "wb") as f:
        pickle.dump(rows, f)


# ----------------------------------------------------------------------------- offline
def score(rows: list[dict], r95s: list[np.ndarray]) -> dict[str, tuple[float, float, float]]:
    """Per site: (truth within r95, worst quarter within r95, median r95 / median error)."""
    by: dict[str, dict[int, list]] = {}
    for row, r95 in zip(rows, r95s):
        by.setdefault(row["site"], {}).setdefault(row["seed"], []).append((row["est"][:, ERR], r95))
    out = {}
    for site, seeds in by.items():
        hit = tot = wh = wt = 0
        ratio = []
        for parts in seeds.values():
            e = np.concatenate([p[0] for p in parts])
            r = np.concatenate([p[1] for p in parts])
            inside = e <= r
            hit += int(inside.sum())
            tot += e.size
            worst = np.argsort(e, kind="stable")[-math.ceil(e.size / 4):]
            wh += int(inside[worst].sum())
            wt += worst.size
            ratio.append(np.median(r) / np.median(e))
        out[site] = (hit / tot, wh / wt, float(np.mean(ratio)))
    return out


Candidate = Callable[[dict], np.ndarray]


def candidate(share: float, centroid: float = 0.0, truncate: bool = True) -> Candidate:
    """The report with ``share`` x the misfit's single-observation covariance and the
    centroid's term at ``centroid`` (0: none) x the recorded persistence: the filter's own sum
    truncated to the box (``report_cov``) or the plain sum; r95 by ``r95_of``."""
    def f(row: dict) -> np.ndarray:
        box = row["box"]
        est = row["est"]
        if centroid and est.shape[1] <= PERSISTENCE:
            sys.exit("uncertainty_study: the centroid's term needs a recording with the centroid (record it again)")
        cents = est[:, CENTROID_X:MODEL_X + 2].tolist() if centroid else [None] * len(est)
        out = np.empty(len(est))
        for k, ((_err, x, y, _r95, cx, cxy, cy, mx, mxy, my), c) in enumerate(zip(est[:, :PARTS].tolist(), cents)):
            model = None if mx != mx else (share * mx, share * mxy, share * my)
            if c is not None and c[0] == c[0]:
                at = (c[3], c[4]) if len(c) > 3 else (x, y)  # the filter's estimate, before the pull
                model = unc.centroid_cov(model, *at, (c[0], c[1]), c[2], centroid)
            if model is None:
                cov = (cx, cxy, cy)
            elif truncate:
                cov = unc.report_cov(x, y, (cx, cxy, cy), model, box)
            else:
                cov = (cx + model[0], cxy + model[1], cy + model[2])
            out[k] = unc.r95_of(*cov)
        return out
    return f


STOP_BINS = ((0, 0), (1, 2), (3, 5), (6, 10), (11, 20), (21, None))
MOVED_M = 0.3  # the truth moved between two estimates by more than this: a new place


def by_stop(rows: list[dict]) -> None:
    """Per site, how often the truth lies within the reported r95, by the estimates since the
    truth last moved (MOVED_M): whether a standing target's misses are the step after it
    moved (no filter can know) or its steady state; the share of the estimates in each bin."""
    if any(r["est"].shape[1] <= TRUTH_Y for r in rows):
        sys.exit("uncertainty_study: --by-stop needs a recording with the truth (record it again)")
    by: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for row in rows:
        est = row["est"]
        step = np.r_[math.inf, np.hypot(np.diff(est[:, TRUTH_X]), np.diff(est[:, TRUTH_Y]))]
        since = np.empty(len(est), dtype=int)
        count = 0
        for i, moved in enumerate((step > MOVED_M).tolist()):
            count = 0 if moved else count + 1
            since[i] = count
        by.setdefault(row["site"], []).append((since, est[:, ERR] <= est[:, R95]))
    names = [f"{a}" if a == b else f"{a}-{b}" if b is not None else f"{a}+" for a, b in STOP_BINS]
    print("| site | " + " | ".join(f"{n} since moved" for n in names) + " |")
    print("|---|" + "---|" * len(names))
    for site in sorted(by):
        since = np.concatenate([p[0] for p in by[site]])
        inside = np.concatenate([p[1] for p in by[site]])
        cells = []
        for a, b in STOP_BINS:
            m = (since >= a) & (since <= (b if b is not None else since.max()))
            cells.append(f"{100 * m.mean():.0f} %: {100 * inside[m].mean():.1f}" if m.any() else "-")
        print(f"| {site} | " + " | ".join(cells) + " |")


def evaluate(paths: list[str], only: str, seeds: str = "", stops: bool = False) -> None:
    rows: list[dict] = []
    for path in paths:
        with open(path, "rb") as f:
            rows += pickle.load(f)
    if seeds:
        lo, hi = (int(v) for v in seeds.split("-"))
        rows = [r for r in rows if lo <= r["seed"] <= hi]
    if stops:
        by_stop(rows)
        return
    cands: dict[str, Candidate] = {"reported": lambda row: row["est"][:, R95]}
    for share in (0.5, 1.0, 1.5, 2.0, 2.5):
        cands[f"misfit x {share:g}, truncated to the box"] = candidate(share)
        for c in (0.1, 0.15, 0.2, 0.3):
            cands[f"misfit x {share:g}, centroid x {c:g}, truncated to the box"] = candidate(share, c)
        cands[f"misfit x {share:g}, centroid x {unc.CENTROID_SHARE:g}, not truncated"] = candidate(
            share, unc.CENTROID_SHARE, False)
    sites = sorted({r["site"] for r in rows})
    print("| candidate | " + " | ".join(sites) + " | worst |")
    print("|---|" + "---|" * (len(sites) + 1))
    for name, fn in cands.items():
        if only and only not in name:
            continue
        sc = score(rows, [fn(row) for row in rows])
        cells = [f"{100 * sc[s][0]:.1f}/{100 * sc[s][1]:.1f}" for s in sites]
        dev = max(max(85 - 100 * c, 100 * c - 98, 0) for c, _w, _r in sc.values())
        wq = min(w for _c, w, _r in sc.values())
        print(f"| {name} | " + " | ".join(cells) + f" | out {dev:.1f} / wq {100 * wq:.0f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--seeds", type=int, default=3)
    r.add_argument("--out", default="build/unc.pkl")
    r.add_argument("--local", default="build/sites")
    r.add_argument("--role", choices=sorted(ROLES), default="walk")
    r.add_argument("--sites", default="", help="record this folder's sites (held-out ones refused) instead of the development sites")
    e = sub.add_parser("evaluate")
    e.add_argument("--in", dest="paths", nargs="+", default=["build/unc.pkl"], help="one or more recordings, pooled")
    e.add_argument("--only", default="")
    e.add_argument("--seeds", default="", help="a range of the recorded seeds, e.g. 0-4")
    e.add_argument("--by-stop", action="store_true",
                   help="the reported r95's coverage by the estimates since the truth last moved, per site")
    args = ap.parse_args()
    if args.cmd == "record":
        record(args.seeds, args.out, args.local, args.role, args.sites)
    else:
        evaluate(args.paths, args.only, args.seeds, args.by_stop)
    return 0


if __name__ == "__main__":
    sys.exit(main())
