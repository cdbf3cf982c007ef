"""Nonlinear least-squares trilateration (paper Appendix B).

Distances come from inverting the path-loss model; the position minimises
``sum_i (|p - a_i| - d_i)^2`` (3-D distances: each anchor at its height above the target's
plane, pfdoa.radio) by Levenberg-Marquardt (damped Gauss-Newton), started at the
centroid of the present anchors, for a bounded number of iterations. The result is clamped
to the anchors' bounding box grown by its own size, so a wild distance cannot send the
estimate arbitrarily far.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import ObservationPrep, bounding_box, kept_last, model_of
from pfdoa.radio import distance_from_rssi


class Trilateration(Estimator):
    name = "trilateration"
    OPTIONS = frozenset({"iterations", "min_anchors"})

    def __init__(self, site, *, iterations: int = 20, min_anchors: int = 3, **_: object) -> None:
        self.prep = ObservationPrep(site)
        self.model = model_of(site)
        self.anchors = site.positions
        self.h2 = site.heights ** 2
        self.iterations = iterations
        self.min_anchors = min_anchors
        ext = self.anchors.max(axis=0) - self.anchors.min(axis=0)
        self.lo, self.hi = bounding_box(self.anchors, float(ext.max()))
        self.reset()

    def reset(self) -> None:
        self.last = self.anchors.mean(axis=0)

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        if p.count < self.min_anchors:
            return kept_last(obs.t, self.last, p)
        a = self.anchors[p.mask]
        h2 = self.h2[p.mask]
        d = distance_from_rssi(p.rssi[p.mask], self.model)
        x = a.mean(axis=0)
        lam = 1e-3
        cost = _cost(x, a, h2, d)
        for _ in range(self.iterations):
            diff = x - a
            rng = np.sqrt((diff * diff).sum(axis=1) + h2)
            rng = np.maximum(rng, 1e-9)
            res = rng - d
            jac = diff / rng[:, None]
            jtj = jac.T @ jac
            jtr = jac.T @ res
            step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-9), -jtr)
            cand = x + step
            c2 = _cost(cand, a, h2, d)
            if c2 < cost:
                x, cost, lam = cand, c2, lam * 0.3
                if float(step @ step) < 1e-12:
                    break
            else:
                lam *= 10.0
                if lam > 1e9:
                    break
        x = np.clip(x, self.lo, self.hi)
        self.last = x
        return Estimate(obs.t, float(x[0]), float(x[1]), math.nan, None, p.ids, {"cost": float(cost)})


def _cost(x: np.ndarray, a: np.ndarray, h2: np.ndarray, d: np.ndarray) -> float:
    diff = x - a
    r = np.sqrt((diff * diff).sum(axis=1) + h2) - d
    return float(r @ r)
