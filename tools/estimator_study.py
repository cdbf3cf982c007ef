#!/usr/bin/env python3
"""Estimator study: RMSE of every method on the development data (docs/archive/estimator-study.md).

(a) simulation: 6 x 6 m room, anchors at the corners, A = -40 dBm, n = 3, i.i.d. Gaussian
    RSS noise 1-4 dB, the paper's Dataset 0 paths (boundary, inside/cross, diagonal) at
    0.1 m steps, one observation per step every ``--dt`` seconds, ``--trials`` seeds.
(b) the real robot traces (herolab_wifi_robot): readings sharing ``t`` form one
    observation; A, n and per-anchor offsets are fitted by least squares on one run
    (``--calib-run``) against ground truth and every other run is scored.

Variants of pf-doa are given as ``name:key=value,key=value`` (``--variant``), e.g.
``--variant "t2:tail_dof=2"``. Odometry (b) is used when ``--odometry`` is set.

Usage: .venv/bin/python tools/estimator_study.py [--sim] [--robot] [--methods all] ...
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from pfdoa.estimators import METHODS, Observation, Odometry, make_estimator
from pfdoa.evaluation.datasets import DATA_DIR, odometry_beside  # noqa: E402
from pfdoa.evaluation.runner import parse_variant
from pfdoa.paths import paper_path
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import load_site, parse_site

TRACES = DATA_DIR / "herolab_wifi_robot"  # the committed copies (gzipped)


def square_site(side: float = 6.0, a: float = -40.0, n: float = 3.0):
    corners = [(0.0, 0.0), (0.0, side), (side, side), (side, 0.0)]
    return parse_site({"radio": {"rssi_at_1m_dbm": a, "path_loss_exponent": n},
                       "anchors": [{"id": i, "x": x, "y": y} for i, (x, y) in enumerate(corners)]})


def rmse(est: np.ndarray, gt: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((est - gt) ** 2, axis=1))))


def run(est, ts, rss, odoms=None) -> tuple[np.ndarray, float]:
    out = np.empty((len(ts), 2))
    t0 = time.perf_counter()
    for i in range(len(ts)):
        e = est.step(Observation(float(ts[i]), rss[i]), None if odoms is None else odoms[i])
        out[i] = e.x, e.y
    return out, (time.perf_counter() - t0) / len(ts)


def _headings(path: np.ndarray) -> np.ndarray:
    d = np.diff(path, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]])


def sim_odometry(gt: np.ndarray, ts: np.ndarray, rng: np.random.Generator) -> list:
    """True robot-frame increments with pfdoasim's default slip noise (heading = direction
    of travel); a teleport between path segments appears as one long drive."""
    from pfdoa.odometry import OdometryNoise, noisy_increments

    inc = noisy_increments(np.column_stack([ts, gt, _headings(gt)]), OdometryNoise(), rng)
    return [Odometry()] + [Odometry(float(a), float(b), float(c)) for _, a, b, c in inc[1:]]


def sim_study(variants: list[tuple[str, str, dict]], noises: list[float], trials: int, dt: float,
              use_odometry: bool = False, paths: tuple[str, ...] = ("boundary", "inside", "diagonal")
              ) -> tuple[dict[tuple[str, str, float], float], dict[str, list[float]]]:
    site = square_site()
    model = PathLoss(-40.0, 3.0)
    res: dict[tuple[str, str, float], float] = {}
    times: dict[str, list[float]] = {}
    for path_name in paths:
        gt = paper_path(path_name, 6.0, 0.1)
        clean = mean_rssi(gt, site.positions, model)
        ts = dt * np.arange(len(gt))
        for sigma in noises:
            for label, method, opts in variants:
                errs = []
                for trial in range(trials):
                    rng = np.random.default_rng(1000 * trial + int(10 * sigma))
                    rss = clean + sigma * rng.standard_normal(clean.shape)
                    odoms = sim_odometry(gt, ts, rng) if use_odometry else None
                    est = make_estimator(method, site, rng=np.random.default_rng(trial), **opts)
                    xy, tstep = run(est, ts, rss, odoms)
                    errs.append(rmse(xy, gt))
                    times.setdefault(label, []).append(tstep)
                res[(label, path_name, sigma)] = float(np.mean(errs))
    return res, times


def load_run(path: Path):
    from pfdoa.trace import read_odometry, read_trace

    tr = read_trace(path)
    ts, inv = np.unique(tr.t, return_inverse=True)
    rss = np.full((ts.size, 4), np.nan)
    rss[inv, tr.anchor.astype(int)] = tr.rssi_dbm
    gt = np.full((ts.size, 2), np.nan)
    gt[inv, 0] = tr.gt_x
    gt[inv, 1] = tr.gt_y
    odoms = None
    op = odometry_beside(path)
    if op is not None:
        o = read_odometry(op)
        # one odometry row per observation time in these files; compose rows by time anyway
        odoms = [Odometry() for _ in ts]
        k = np.searchsorted(ts, o.t, side="left")
        for j in range(o.t.size):
            if 0 <= k[j] < ts.size:
                from pfdoa.odometry import compose

                odoms[k[j]] = compose(odoms[k[j]], Odometry(float(o.dx[j]), float(o.dy[j]), float(o.dtheta[j])))
    return tr, ts, rss, gt, odoms


def robot_study(variants, calib_run: str, use_odometry: bool, robust: bool = False, seeds: int = 1,
                include_held_out: bool = False):
    """calib_run "all": every (calibration run, scored run) pair; per scored run the RMSE
    over all its pairs (errors pooled). The held-out runs (pfdoa.evaluation.sites.PROTOCOLS)
    are left out unless asked for: decisions are made without them."""
    from pfdoa.api import calibrate_traces

    base = load_site(TRACES / "site.toml")
    from pfdoa.evaluation.sites import PROTOCOLS

    held_out = () if include_held_out else PROTOCOLS["herolab_wifi_robot"].held_out
    runs = sorted(p for p in TRACES.glob("*.csv.gz") if ".odom." not in p.name)
    data = {p.name.removesuffix(".csv.gz"): load_run(p) for p in runs}
    data = {k: v for k, v in data.items() if k not in held_out}
    calib_runs = list(data) if calib_run == "all" else [calib_run]
    sq: dict[tuple[str, str], list[float]] = {}
    site = base
    for cal_name in calib_runs:
        site = calibrate_traces([data[cal_name][0]], base, robust=robust).apply(base)
        for name, (_, ts, rss, gt, odoms) in data.items():
            if name == cal_name:
                continue
            for label, method, opts in variants:
                for seed in range(seeds if method.startswith("pf-doa") else 1):
                    est = make_estimator(method, site, rng=np.random.default_rng(seed), **opts)
                    xy, _ = run(est, ts, rss, odoms if use_odometry else None)
                    ok = np.isfinite(gt).all(axis=1)
                    sq.setdefault((label, name), []).extend(np.sum((xy[ok] - gt[ok]) ** 2, axis=1))
    res = {k: float(np.sqrt(np.mean(v))) for k, v in sq.items()}
    pooled: dict[str, list[float]] = {}
    for (label, _), v in sq.items():
        pooled.setdefault(label, []).extend(v)
    return site, res, {k: float(np.sqrt(np.mean(v))) for k, v in pooled.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim", action="store_true")
    ap.add_argument("--robot", action="store_true")
    ap.add_argument("--methods", default="all", help="comma list of methods, or 'all', or 'none'")
    ap.add_argument("--variant", action="append", default=[], help="name:key=value,... (pf-doa options)")
    ap.add_argument("--noise", default="1,2,3,4")
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--dt", type=float, default=1.0, help="seconds between simulated observations")
    ap.add_argument("--calib-run", default="trial_exp2", help="run to calibrate on, or 'all' for every pair")
    ap.add_argument("--huber", action="store_true", help="robust (Huber) calibration")
    ap.add_argument("--seeds", type=int, default=1, help="particle-filter seeds per robot run (errors pooled)")
    ap.add_argument("--odometry", action="store_true", help="feed odometry (simulated: true increments + slip)")
    ap.add_argument("--include-held-out", action="store_true",
                    help="also the robot's held-out runs (the first two studies used all nine; do not decide on them)")
    args = ap.parse_args()
    methods = list(METHODS) if args.methods == "all" else [m for m in args.methods.split(",") if m and m != "none"]
    variants = [(m, m, {}) for m in methods] + [parse_variant(v) for v in args.variant]
    labels = [v[0] for v in variants]
    if args.sim:
        noises = [float(x) for x in args.noise.split(",")]
        res, times = sim_study(variants, noises, args.trials, args.dt, args.odometry)
        paths = sorted({k[1] for k in res}, key=["boundary", "inside", "diagonal"].index)
        print(f"## simulation: RMSE (m), mean over {args.trials} trials, dt={args.dt}s"
              f"{', odometry' if args.odometry else ''}\n")
        print("| method | " + " | ".join(f"{p} {s:g}dB" for s in noises for p in paths) + " | mean 2dB |")
        print("|---" * (len(noises) * len(paths) + 2) + "|")
        for lab in labels:
            cells = [f"{res[(lab, p, s)]:.3f}" for s in noises for p in paths]
            m2 = np.mean([res[(lab, p, 2.0)] for p in paths]) if 2.0 in noises else float("nan")
            print(f"| {lab} | " + " | ".join(cells) + f" | {m2:.3f} |")
        print("\nmedian step time (us): " + ", ".join(f"{lab} {1e6 * np.median(times[lab]):.0f}" for lab in labels))
    if args.robot:
        site, res, pooled = robot_study(variants, args.calib_run, args.odometry, args.huber, args.seeds,
                                        args.include_held_out)
        runs = sorted({k[1] for k in res})
        fit = "" if args.calib_run == "all" else (
            f": A={site.radio.rssi_at_1m_dbm:.2f} n={site.radio.path_loss_exponent:.3f} "
            f"offsets={[round(float(o), 2) for o in site.offsets]}")
        print(f"\n## robot traces: RMSE (m), calibrated on {args.calib_run}{' (Huber)' if args.huber else ''}"
              f"{fit}{', odometry' if args.odometry else ''}\n")
        print("| method | " + " | ".join(runs) + " | pooled |")
        print("|---" * (len(runs) + 2) + "|")
        for lab in labels:
            print(f"| {lab} | " + " | ".join(f"{res[(lab, r)]:.3f}" for r in runs) + f" | {pooled[lab]:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
