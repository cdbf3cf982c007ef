"""Markov grid localisation on the DOA (paper Appendix B).

A discrete belief over grid cells covering the anchors' bounding box (default 0.1 m). Each
step: prediction = the belief blurred by a Gaussian of 1-sigma ``speed * dt`` (motion
model without heading, so odometry is not used); update = the same wrapped-Gaussian DOA
likelihood as PF-DOA evaluated on every cell (predicted DOA of a cell = DOA of the plane-fit
gradient of the model's noise-free RSS there); estimate = the most probable cell. A floor
keeps every cell reachable so the belief recovers from a wrong peak.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.doa import DoaSmoother, GradientFit, doa_from_gradient
from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import ObservationPrep, dt_between, make_grid, model_of, search_box
from pfdoa.radio import mean_rssi

FLOOR = 1e-9  # fraction of uniform mass mixed in each step


class MarkovGrid(Estimator):
    name = "markov"
    OPTIONS = frozenset({"resolution", "margin", "sigma_doa", "window", "speed", "min_anchors"})

    def __init__(self, site, *, resolution: float = 0.1, margin: float = 0.0, sigma_doa: float = 0.3,
                 window: int = 5, speed: float = 0.5, min_anchors: int = 3, **_: object) -> None:
        self.prep = ObservationPrep(site)
        self.anchors = site.positions
        self.fit = GradientFit(self.anchors)
        self.smoother = DoaSmoother(window)
        self.sigma_doa = sigma_doa
        self.speed = speed
        self.res = resolution
        self.min_anchors = min_anchors
        lo, hi = search_box(site, margin)
        xs, ys, self.points = make_grid(lo, hi, resolution)
        self.shape = (ys.size, xs.size)
        self.model_rssi = mean_rssi(self.points, self.anchors, model_of(site), heights=site.heights)
        self._pred_key: bytes | None = None
        self._pred = np.empty(self.points.shape[0])
        self.belief = np.empty(self.shape)
        self.reset()

    def reset(self) -> None:
        self.belief.fill(1.0 / self.belief.size)
        self.smoother.reset()
        self.t_prev: float | None = None
        self.last = self.anchors.mean(axis=0)

    def _predicted_doa(self, mask: np.ndarray) -> np.ndarray | None:
        key = mask.tobytes()
        if key != self._pred_key:
            op = self.fit.operator(mask)
            if op is None:
                return None
            g = self.model_rssi @ op.T
            np.arctan2(g[:, 1], g[:, 0], out=self._pred)
            self._pred_key = key
        return self._pred

    def _blur(self, sigma_m: float) -> None:
        s = sigma_m / self.res
        if s < 0.3:
            return
        r = int(math.ceil(3 * s))
        k = np.exp(-0.5 * (np.arange(-r, r + 1) / s) ** 2)
        k /= k.sum()
        for axis in (0, 1):
            b = self.belief
            n = b.shape[axis]
            out = np.zeros_like(b)
            for j, w in enumerate(k):
                off = j - r
                if abs(off) >= n:
                    continue
                if axis == 0:
                    if off >= 0:
                        out[off:] += w * b[: n - off]
                    else:
                        out[:off] += w * b[-off:]
                else:
                    if off >= 0:
                        out[:, off:] += w * b[:, : n - off]
                    else:
                        out[:, :off] += w * b[:, -off:]
            self.belief = out

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        dt = dt_between(self.t_prev, obs.t)
        self.t_prev = obs.t
        self._blur(self.speed * dt)
        extra: dict = {}
        doa = None
        pred = self._predicted_doa(p.mask) if p.count >= self.min_anchors else None
        if pred is not None:
            doa = self.smoother.push(doa_from_gradient(self.fit.gradient(p.rssi, p.mask)))
        else:
            extra["degraded"] = f"only {p.count} usable anchors, prediction only"
        flat = self.belief.reshape(-1)
        if doa is not None:
            e = (pred - doa + np.pi) % (2 * np.pi) - np.pi
            flat *= np.exp(-0.5 * (e / self.sigma_doa) ** 2)
        total = flat.sum()
        if not math.isfinite(total) or total <= 0.0:
            flat.fill(1.0 / flat.size)
            extra["recovered"] = True
        else:
            flat *= (1.0 - FLOOR) / total
            flat += FLOOR / flat.size
        best = int(np.argmax(flat))
        est = self.points[best]
        d = self.points - est
        sigma = math.sqrt(float(flat @ (d * d).sum(axis=1)))
        self.last = est
        return Estimate(obs.t, float(est[0]), float(est[1]), sigma, doa, p.ids, extra)
