#!/usr/bin/env python3
"""pf-doa's reported uncertainty on the development sites: record once, try formulas offline.

``record``: runs pf-doa (one calibration walk, every ordered pair, seeds 0..S-1, as ``make
eval-sites`` scores it; ``--role uncalibrated``: each run with its site file as given) on the
development sites only (held-out sites and the held-out runs of development sites are refused, as in tools/sites_study.py) and saves per estimate its
error and the uncertainty's parts: the truncated cloud's covariance, the present anchors'
centred posterior-mean residual, and the estimate (the misfit's Jacobian is recomputed from
it). The point estimates are pf-doa's own: the recording only reads the filter's state.

``evaluate``: replays candidate misfit terms over the recording (in time order per run, as
the filter would compute them online, never from the truth) and prints, per site and
worst site first, how often the truth lies within r95 and the worst quarter of errors
(per seed, pooled over the pairs) does: the columns of docs/sites.md.

Usage: .venv/bin/python tools/uncertainty_study.py record [--seeds 3] [--role walk|uncalibrated] [--out build/unc.npz]
       .venv/bin/python tools/uncertainty_study.py evaluate [--in build/unc.npz]
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


def record(seeds: int, out: str, local: str, role: str = "walk") -> None:
    from pfdoa.estimators import make_estimator
    from pfdoa.estimators.base import Observation

    sites = sites_mod.development_sites(local)
    variant = Variant("pf-doa", "pf-doa", True, ())
    cfg = EvalConfig(methods=("pf-doa",), sites=sites, site_seeds=seeds, table1=False, sweeps=False,
                     site_roles=(ROLES[role],), site_variants=(variant,), calibration="walk")
    rows: list[dict] = []
    orig_report = pf_doa_mod.PfDoa._report
    state: dict = {}

    def report(self, t, doa, ids, extra, mode=None):
        e = orig_report(self, t, doa, ids, extra, mode)
        # the truncated cloud: the reported cov less the misfit's share of it
        m = self.misfit.cov_at(e.x, e.y, self._present) if self._present else None
        cx, cxy, cy = e.cov
        if m is not None:
            cx, cxy, cy = cx - m[0], cxy - m[1], cy - m[2]
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
                    anchors=est.anchors.copy(), heights=est.heights.copy(), k=est.misfit.k, dmin2=est.misfit.dmin2,
                    scal=np.array([r[:14] for r in recs]), res=np.array([r[14] for r in recs]),
                    present=np.array([r[15] for r in recs])))
            print(f"{name} {cal}->{run} seed {job.trial}: {sum(len(r['scal']) for r in rows)} estimates",
                  file=sys.stderr)
    finally:
        pf_cls._report = orig_report
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


def evaluate(path: str, only: str, seeds: str = "") -> None:
    with open(path, "rb") as f:
        rows = pickle.load(f)
    if seeds:
        lo, hi = (int(v) for v in seeds.split("-"))
        rows = [r for r in rows if lo <= r["seed"] <= hi]
    prep = []
    for row in rows:
        G, A, bad = geometry(row)
        st: dict[object, dict[str, np.ndarray]] = {r: running_stats(row, r) for r in (0.05,)}
        st["power start"] = running_stats(row, 0.05, True)
        st["power 1/k"] = running_stats(row, 0.05, True, True)
        st["1/k"] = running_stats(row, 0.05, False, True)
        prep.append((G, A, bad, st))

    def misfit_cov(row, p, V):
        G, A, bad, _ = p
        m = sandwich(G, A, np.maximum(V, 0.0))
        return np.where(bad[:, None], 0.0, m)

    def cloud(row):
        s = row["scal"]
        return s[:, 4], s[:, 5], s[:, 6]

    def total(row, mc, share_cloud=1.0):
        cx, cxy, cy = cloud(row)
        return r95_vec(share_cloud * cx + mc[:, 0], share_cloud * cxy + mc[:, 1], share_cloud * cy + mc[:, 2])

    def c_share(share, key: object = 0.05):
        def f(row, p):
            return total(row, share * misfit_cov(row, p, p[3][key]["c1"]))
        return f

    def c_rho(power, lo=0.0):
        """share = a function of the residuals' lag-1 correlation (pooled over anchors)"""
        def f(row, p):
            st = p[3][0.05]
            c1, c0 = st["c1"], st["c0"]
            rho = np.clip(np.maximum(c1, 0).sum(1) / np.maximum(c0.sum(1), 1e-9), 0.0, 1.0)
            share = np.maximum(rho ** power, lo)
            return total(row, share[:, None] * misfit_cov(row, p, c1))
        return f

    def c_rho_c0(power):
        """misfit from the residual power c0 times rho^power (the persistent share of the power)"""
        def f(row, p):
            st = p[3][0.05]
            c1, c0 = st["c1"], st["c0"]
            rho = np.clip(np.maximum(c1, 0).sum(1) / np.maximum(c0.sum(1), 1e-9), 0.0, 1.0)
            return total(row, (rho ** power)[:, None] * misfit_cov(row, p, c0))
        return f

    def c_max(share):
        def f(row, p):
            cx, cxy, cy = cloud(row)
            mc = share * misfit_cov(row, p, p[3][0.05]["c1"])
            return np.maximum(r95_vec(cx, cxy, cy), r95_vec(mc[:, 0], mc[:, 1], mc[:, 2]))
        return f

    def c_emp(share, comb="rss"):
        """the cloud's own 95 % radius (particles, not a Gaussian of their moments) with the misfit's"""
        def f(row, p):
            mc = share * misfit_cov(row, p, p[3][0.05]["c1"])
            mr = r95_vec(mc[:, 0], mc[:, 1], mc[:, 2])
            q = row["scal"][:, 12]
            return np.sqrt(q * q + mr * mr) if comb == "rss" else np.maximum(q, mr)
        return f

    def c_emp_scaled(share):
        """the cloud's covariance scaled by (own 95 % radius / its Gaussian's)^2, plus the misfit's"""
        def f(row, p):
            cx, cxy, cy = cloud(row)
            g = r95_vec(cx, cxy, cy)
            k = np.where(g > 0, (row["scal"][:, 12] / np.where(g > 0, g, 1.0)) ** 2, 1.0)
            mc = share * misfit_cov(row, p, p[3][0.05]["c1"])
            return r95_vec(k * cx + mc[:, 0], k * cxy + mc[:, 1], k * cy + mc[:, 2])
        return f

    def shares(row, warm):
        """the noise share of the cloud as NoiseScale computes it (warm: averages of the first
        k inputs while k < 1 / SIGMA_RATE instead of starting from sigma_rss)"""
        s = row["scal"]
        out = np.empty(len(s))
        s2 = post = 16.0
        kp = kq = 0
        for t in range(len(s)):
            a, b = s[t, 10], s[t, 11]
            if a == a:
                kp += 1
                r = max(0.1, 1.0 / kp) if warm else 0.1
                s2 = a if (warm and kp == 1) else s2 + r * (min(a, 4.0 * s2) - s2)
                s2 = min(max(s2, 1.0), 400.0)
            if b == b:
                kq += 1
                r = max(0.1, 1.0 / kq) if warm else 0.1
                post = b if (warm and kq == 1) else post + r * (min(b, 4.0 * post) - post)
            out[t] = min(max(post, 1.0) / s2, 1.0)
        return out

    def c_warm(share, key=0.05):
        def f(row, p):
            k = shares(row, True) / np.maximum(shares(row, False), 1e-9)
            cx, cxy, cy = cloud(row)
            mc = share * misfit_cov(row, p, p[3][key]["c1"])
            return r95_vec(k * cx + mc[:, 0], k * cxy + mc[:, 1], k * cy + mc[:, 2])
        return f

    def moved(row, tau):
        """the estimate's net displacement over the last tau seconds (since the first estimate
        while fewer have passed): how far the filter could have averaged the misfit"""
        s = row["scal"]
        t, x, y = s[:, 0], s[:, 2], s[:, 3]
        j = np.maximum(np.searchsorted(t, t - tau, side="right") - 1, 0)
        return np.hypot(x - x[j], y - y[j])

    def c_move(tau, ell):
        """the misfit's share 1 / (1 + L / ell), L the net displacement over tau: all of the
        single-observation bound at a standstill, less along a path"""
        def f(row, p):
            sh = 1.0 / (1.0 + moved(row, tau) / ell)
            return total(row, sh[:, None] * misfit_cov(row, p, p[3]["power 1/k"]["c1"]))
        return f

    def slope_shift(row, p):
        """A G^T m_c per estimate: the position shift per unit relative error of the slope (m_c the
        model's centred RSS at the estimate)"""
        G, A, bad, _ = p
        s = row["scal"]
        a, h = row["anchors"], row["heights"]
        dx = s[:, 2][:, None] - a[None, :, 0]
        dy = s[:, 3][:, None] - a[None, :, 1]
        pm = row["present"]
        m = np.where(pm, -0.5 * row["k"] * np.log(np.maximum(dx * dx + dy * dy + h[None, :] ** 2, row["dmin2"])), 0.0)
        m = np.where(pm, m - (m.sum(1) / np.maximum(pm.sum(1), 1))[:, None], 0.0)
        bx, by = (G[..., 0] * m).sum(1), (G[..., 1] * m).sum(1)
        return (np.where(bad, 0.0, A[:, 0] * bx + A[:, 1] * by), np.where(bad, 0.0, A[:, 1] * bx + A[:, 2] * by))

    def c_slope(rel):
        """the report plus a relative slope uncertainty ``rel`` mapped to position"""
        def f(row, p):
            ux, uy = slope_shift(row, p)
            slope = (rel * rel) * np.stack([ux * ux, ux * uy, uy * uy], -1)
            return total(row, 0.5 * misfit_cov(row, p, p[3]["power 1/k"]["c1"]) + slope)
        return f

    def c_narrow(power):
        """the cloud narrowed by the noise share to the power ``power`` (1: as reported, 0: not at all)"""
        def f(row, p):
            sh = np.maximum(shares(row, True), 1e-9)
            return total(row, 0.5 * misfit_cov(row, p, p[3]["power 1/k"]["c1"]), sh ** power / sh)
        return f

    cands: dict[str, Candidate] = {"reported": lambda row, p: row["scal"][:, 7]}
    for pw in (0.5, 0.0):
        cands[f"cloud narrowed by the noise share ^ {pw:g}"] = c_narrow(pw)
    for tau in (5.0, 10.0):
        for ell in (1.0, 2.0):
            cands[f"misfit share by displacement, {tau:g} s, {ell:g} m"] = c_move(tau, ell)
    for rel in (0.1, 0.3, 0.5, 0.7):
        cands[f"slope uncertainty {rel:g}"] = c_slope(rel)
    for s in (0.5, 0.75, 0.875, 1.0):
        cands[f"warm share cloud + {s} lag1"] = c_warm(s)
        cands[f"warm share cloud + {s} lag1 from power"] = c_warm(s, "power start")
        cands[f"warm share cloud + {s} lag1 power 1/k"] = c_warm(s, "power 1/k")
        cands[f"warm share cloud + {s} lag1 1/k"] = c_warm(s, "1/k")
        cands[f"share {s}, lag1 power 1/k"] = c_share(s, "power 1/k")
        cands[f"share {s}, lag1 from power"] = c_share(s, "power start")
    if rows[0]["scal"].shape[1] > 12:
        for s in (0.5, 0.75, 1.0):
            cands[f"emp cloud (+) {s} lag1"] = c_emp(s)
            cands[f"emp-scaled cloud + {s} lag1"] = c_emp_scaled(s)
        cands["max(emp cloud, 1.0 lag1)"] = c_emp(1.0, "max")
    for s in (0.25, 0.5, 0.75, 1.0):
        cands[f"share {s}"] = c_share(s)
    for pw in (0.5, 1.0, 2.0):
        cands[f"rho^{pw} x lag1"] = c_rho(pw)
        cands[f"rho^{pw} x power"] = c_rho_c0(pw)
    cands["max(cloud, 0.5 lag1)"] = c_max(0.5)
    cands["max(cloud, 1.0 lag1)"] = c_max(1.0)
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
        print(f"| {name} | " + " | ".join(cells) + f" | out {dev:.0f} / wq {100 * wq:.0f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--seeds", type=int, default=3)
    r.add_argument("--out", default="build/unc.pkl")
    r.add_argument("--local", default="build/sites")
    r.add_argument("--role", choices=sorted(ROLES), default="walk")
    e = sub.add_parser("evaluate")
    e.add_argument("--in", dest="path", default="build/unc.pkl")
    e.add_argument("--only", default="")
    e.add_argument("--seeds", default="", help="a range of the recorded seeds, e.g. 0-4")
    args = ap.parse_args()
    if args.cmd == "record":
        record(args.seeds, args.out, args.local, args.role)
    else:
        evaluate(args.path, args.only, args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
