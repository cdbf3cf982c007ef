#!/usr/bin/env python3
"""pf-doa's reported uncertainty on the development sites: record once, try formulas offline.

``record``: runs pf-doa (one calibration walk, every ordered pair, seeds 0..S-1, as ``make
eval-sites`` scores it; ``--role uncalibrated``: each run with its site file as given) on the
development sites only (held-out sites and the held-out runs of development sites are
refused, as in tools/sites_study.py), or on a folder's sites (``--sites``: the synthetic
rooms of tools/synthetic_sites.py, a new site; held-out ones refused), and saves per
estimate its error and the uncertainty's parts: the truncated cloud's covariance, the
present anchors' centred posterior-mean residual, the estimate (the misfit's Jacobian is
recomputed from it) and the search box. The point estimates are pf-doa's own: the
recording only reads the filter's state.

``evaluate``: replays the report's misfit term at several multiples, truncated to the box or
not, over one or more recordings (in time order per run, as the filter computes it online,
never from the truth) and prints per site how often the truth lies within r95 and the worst
quarter of errors (per seed, pooled over the pairs) does: the columns of docs/sites.md.
Earlier candidates and their figures are in docs/estimator.md ("Uncertainty").

Usage: .venv/bin/python tools/uncertainty_study.py record [--seeds 3] [--role walk|uncalibrated] [--sites DIR] [--out build/unc.pkl]
       .venv/bin/python tools/uncertainty_study.py evaluate [--in build/unc.pkl ...]
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

_R95_F = np.array(unc._R95_F)


ROLES = {"walk": sites_mod.ONE_WALK, "uncalibrated": sites_mod.UNCALIBRATED}


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
    orig_report = pf_doa_mod.PfDoa._report
    orig_cov = pf_doa_mod.report_cov
    state: dict = {}

    def report_cov(x, y, cloud, misfit, box):
        state["cloud"] = cloud  # the truncated, narrowed cloud, before the misfit is added
        return orig_cov(x, y, cloud, misfit, box)

    def report(self, t, doa, ids, extra, mode=None):
        state["cloud"] = None
        e = orig_report(self, t, doa, ids, extra, mode)
        cx, cxy, cy = e.cov if state["cloud"] is None else state["cloud"]
        prev = self.misfit._prev
        # the cloud's own 95 % radius about the estimate (narrowed as the cloud's cov is)
        d2 = ((self.xy[:, 0] - e.x) ** 2 + (self.xy[:, 1] - e.y) ** 2) * self.noise.share()
        order = np.argsort(d2)
        cw = np.cumsum(self.w[order])
        q95 = math.sqrt(float(d2[order[min(int(np.searchsorted(cw, 0.95 * cw[-1])), d2.size - 1)]]))
        m2 = float(np.dot(self.w, d2))
        kurt = float(np.dot(self.w, d2 * d2)) / (m2 * m2) if m2 > 0 else math.nan
        state["row"] = (e, (cx, cxy, cy), None if prev is None else list(prev), tuple(self._present),
                        self.noise.sigma, q95, kurt)
        return e

    pf_cls: Any = pf_doa_mod.PfDoa  # the recording wraps two methods of the filter's classes
    noise_cls: Any = pf_doa_mod.NoiseScale
    orig_push, orig_post = noise_cls.push, noise_cls.push_posterior

    def push(self, var):
        state["prior"] = var
        orig_push(self, var)

    def push_posterior(self, var):
        state["post"] = var
        orig_post(self, var)

    pf_cls._report = report
    pf_doa_mod.report_cov = report_cov
    noise_cls.push = push
    noise_cls.push_posterior = push_posterior
    try:
        for job in build_jobs(cfg):
            name, role, cal, run = job.params
            assert role not in sites_mod.HELD_OUT_ROLES
            for seq in _sequences(cfg, job):
                est: Any = make_estimator("pf-doa", seq.site, rng=_replay_rng(job.trial, seq),
                                     **{k: v for k, v in seq.site.sections.get("estimator", {}).items()
                                        if k != "method"})
                na = est.n_anchors
                recs = []
                last_prev = None
                for i in range(len(seq)):
                    obs = Observation(float(seq.t[i]), seq.rssi[i].copy(),
                                      None if seq.count is None else seq.count[i])
                    odo = seq.odometry[i] if seq.odometry is not None else None
                    for key in ("row", "prior", "post"):
                        state.pop(key, None)
                    est.step(obs, odo)
                    e, cloud, prev, present, sigma, q95, kurt = state["row"]
                    gx, gy = seq.truth[i]
                    if not (math.isfinite(e.x) and math.isfinite(gx) and math.isfinite(gy)):
                        continue
                    pushed = prev is not None and prev is not last_prev
                    last_prev = prev
                    res = np.full(na, np.nan) if prev is None else np.array(prev)
                    pm = np.zeros(na, bool)
                    pm[list(present)] = True
                    recs.append((float(seq.t[i]), math.hypot(gx - e.x, gy - e.y), e.x, e.y, *cloud, float(e.r95),
                                 sigma, float(pushed), state.get("prior", math.nan), state.get("post", math.nan),
                                 q95, kurt, res, pm))
                if not recs:
                    continue
                rows.append(dict(
                    site=name, cal=cal, run=run, seed=job.trial, beacon=seq.beacon,
                    anchors=est.anchors.copy(), heights=est.heights.copy(), lo=est.lo.copy(), hi=est.hi.copy(),
                    k=est.misfit.k, dmin2=est.misfit.dmin2,
                    scal=np.array([r[:14] for r in recs]), res=np.array([r[14] for r in recs]),
                    present=np.array([r[15] for r in recs])))
            print(f"{name} {cal}->{run} seed {job.trial}: {sum(len(r['scal']) for r in rows)} estimates",
                  file=sys.stderr)
    finally:
        pf_cls._report = orig_report
        pf_doa_mod.report_cov = orig_cov
        noise_cls.push = orig_push
        noise_cls.push_posterior = orig_post
    with open(out, "wb") as f:
        pickle.dump(rows, f)


# ----------------------------------------------------------------------------- offline
def r95_vec(cxx: np.ndarray, cxy: np.ndarray, cyy: np.ndarray) -> np.ndarray:
    """:func:`pfdoa.estimators.pf_uncertainty.r95_of`, vectorised."""
    half = 0.5 * (cxx + cyy)
    disc = np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
    l1 = half + disc
    ok = l1 > 0
    l1s = np.where(ok, l1, 1.0)
    u = np.clip(np.maximum(half - disc, 0.0) / l1s, 0.0, 1.0) * 10.0
    i = np.minimum(u.astype(int), 9)
    f = _R95_F[i] + (u - i) * (_R95_F[i + 1] - _R95_F[i])
    return np.where(ok, np.sqrt(l1s * f), 0.0)


def geometry(row: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per estimate the centred Jacobian G (T, na, 2) at the estimate (0 for missing anchors)
    and A = (G^T G)^-1 as (axx, axy, ayy) arrays; NaN where singular."""
    s = row["scal"]
    ex, ey = s[:, 2], s[:, 3]
    a, h = row["anchors"], row["heights"]
    dx = ex[:, None] - a[None, :, 0]
    dy = ey[:, None] - a[None, :, 1]
    g = row["k"] / np.maximum(dx * dx + dy * dy + h[None, :] ** 2, row["dmin2"])
    pm = row["present"]
    gx, gy = np.where(pm, g * dx, 0.0), np.where(pm, g * dy, 0.0)
    n = np.maximum(pm.sum(1), 1)
    gx = np.where(pm, gx - (gx.sum(1) / n)[:, None], 0.0)
    gy = np.where(pm, gy - (gy.sum(1) / n)[:, None], 0.0)
    sxx, sxy, syy = (gx * gx).sum(1), (gx * gy).sum(1), (gy * gy).sum(1)
    det = sxx * syy - sxy * sxy
    bad = ~(det > 1e-12 * (sxx * syy + 1e-300))
    det = np.where(bad, np.nan, det)
    return np.stack([gx, gy], -1), np.stack([syy / det, -sxy / det, sxx / det], -1), bad


def sandwich(G: np.ndarray, A: np.ndarray, V: np.ndarray) -> np.ndarray:
    """A G^T diag(V) G A per estimate: (T, 3)."""
    gx, gy = G[..., 0], G[..., 1]
    bxx, bxy, byy = (V * gx * gx).sum(1), (V * gx * gy).sum(1), (V * gy * gy).sum(1)
    axx, axy, ayy = A[:, 0], A[:, 1], A[:, 2]
    txx, txy = axx * bxx + axy * bxy, axx * bxy + axy * byy
    tyx, tyy = axy * bxx + ayy * bxy, axy * bxy + ayy * byy
    return np.stack([txx * axx + txy * axy, txx * axy + txy * ayy, tyx * axy + tyy * ayy], -1)


def running_stats(row: dict, rate: float, start_power: bool = False, counted: bool = False) -> dict[str, np.ndarray]:
    """Per estimate and anchor, as Misfit would hold them online at ``rate``: lag-1
    autocovariance (c1), power (c0) of the centred residual, and their count of updates."""
    res = row["res"]
    pushed = row["scal"][:, 9] > 0.5
    T, na = res.shape
    c1 = np.zeros((T, na))
    c0 = np.zeros((T, na))
    v1 = np.zeros(na)
    v0 = np.zeros(na)
    warm1 = warm0 = False
    prev = None
    k1 = np.zeros(na)  # lag-1 updates per anchor (the power start counts as one)
    for t in range(T):
        if pushed[t]:
            cur = res[t]
            cnt = int(np.isfinite(cur).sum())
            if cnt >= 3:
                scale = cnt / (cnt - 1.0)
                ok0 = np.isfinite(cur)
                p0 = np.where(ok0, cur * cur * scale, 0.0)
                v0 = np.where(ok0, v0 + rate * (p0 - v0), v0) if warm0 else np.where(ok0, p0, 0.0)
                new = ok0 & (k1 == 0) if start_power else np.zeros(na, bool)
                if new.any():  # an anchor's first residual: its power (all of it may persist)
                    v1 = np.where(new, p0, v1)
                    k1 = k1 + new
                    warm1 = True
                warm0 = True
                if prev is not None:
                    ok = ok0 & np.isfinite(prev) & ~new
                    p1 = np.where(ok, cur * prev * scale, 0.0)
                    k1 = k1 + ok
                    r1 = np.maximum(rate, 1.0 / np.maximum(k1, 1.0)) if counted else rate
                    v1 = np.where(ok, v1 + r1 * (p1 - v1), v1) if warm1 else np.where(ok, p1, 0.0)
                    warm1 = True
            prev = cur
        c1[t], c0[t] = v1, v0
    return {"c1": c1, "c0": c0}


def score(rows: list[dict], r95s: list[np.ndarray]) -> dict[str, tuple[float, float, float]]:
    """Per site: (truth within r95, worst quarter within r95, median r95 / median error)."""
    by: dict[str, dict[int, list]] = {}
    for row, r95 in zip(rows, r95s):
        by.setdefault(row["site"], {}).setdefault(row["seed"], []).append((row["scal"][:, 1], r95))
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


Candidate = Callable[[dict, Any], np.ndarray]


def truncated_var(mu: np.ndarray, var: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """:func:`pfdoa.estimators.pf_uncertainty.truncated_mean`'s variance, vectorised."""
    sd = np.sqrt(np.maximum(var, 1e-300))
    a, b = (lo - mu) / sd, (hi - mu) / sd
    pa, pb = np.exp(-0.5 * np.minimum(a * a, 1400.0)), np.exp(-0.5 * np.minimum(b * b, 1400.0))
    pa, pb = pa * 0.3989422804014327, pb * 0.3989422804014327
    erf = np.frompyfunc(math.erf, 1, 1)
    z = 0.5 * (erf(b * 0.7071067811865476) - erf(a * 0.7071067811865476)).astype(float)
    far = (a < -8.0) & (b > 8.0)
    z = np.maximum(z, 1e-12)
    r = (pa - pb) / z
    out = var * np.maximum(1.0 + (a * pa - b * pb) / z - r * r, 1e-6)
    return np.where(far | ~(var > 0.0), var, out)


def evaluate(paths: list[str], only: str, seeds: str = "") -> None:
    rows: list[dict] = []
    for path in paths:
        with open(path, "rb") as f:
            rows += pickle.load(f)
    if seeds:
        lo, hi = (int(v) for v in seeds.split("-"))
        rows = [r for r in rows if lo <= r["seed"] <= hi]
    prep = []
    for row in rows:
        G, A, bad = geometry(row)
        prep.append((G, A, bad, running_stats(row, 0.05, True, True)["c1"]))

    def candidate(share: float, truncate: bool = True) -> Candidate:
        """the cloud plus ``share`` x the misfit's single-observation error, the sum truncated to
        the search box about the estimate (pf_uncertainty.report_cov) or not"""
        def f(row, p):
            G, A, bad, c1 = p
            m = share * np.where(bad[:, None], 0.0, sandwich(G, A, np.maximum(c1, 0.0)))
            s = row["scal"]
            cx, cxy, cy = s[:, 4] + m[:, 0], s[:, 5] + m[:, 1], s[:, 6] + m[:, 2]
            if truncate:
                tx = truncated_var(s[:, 2], cx, row["lo"][0], row["hi"][0])
                ty = truncated_var(s[:, 3], cy, row["lo"][1], row["hi"][1])
                cxy = cxy * np.sqrt(tx * ty / np.maximum(cx * cy, 1e-300))
                cx, cy = tx, ty
            return r95_vec(cx, cxy, cy)
        return f

    cands: dict[str, Candidate] = {"reported": lambda row, p: row["scal"][:, 7]}
    for share in (0.5, 1.0, 1.5, 2.0, 2.5):
        cands[f"misfit x {share:g}, truncated to the box"] = candidate(share)
        cands[f"misfit x {share:g}, not truncated"] = candidate(share, False)
    sites = sorted({r["site"] for r in rows})
    print("| candidate | " + " | ".join(sites) + " | worst |")
    print("|---|" + "---|" * (len(sites) + 1))
    for name, fn in cands.items():
        if only and only not in name:
            continue
        sc = score(rows, [fn(row, p) for row, p in zip(rows, prep)])
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
    args = ap.parse_args()
    if args.cmd == "record":
        record(args.seeds, args.out, args.local, args.role, args.sites)
    else:
        evaluate(args.paths, args.only, args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
