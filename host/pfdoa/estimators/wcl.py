"""Weighted centroid localisation (paper Appendix B).

The paper's weights ``RSSI_i / sum_j RSSI_j`` are ill-defined for dBm (negative, and a
stronger signal is a *smaller* magnitude). We use the standard form of Blumenthal et al.
(2007): weights proportional to inverse distance, ``w_i = 1 / d_i`` with ``d_i`` from the
path-loss model, which is monotone in RSSI and independent of the dBm sign convention.
``d_i`` is the model's (3-D) distance: with anchor heights, the distance on the target's plane
would be sqrt(d_i^2 - h_i^2), which gives a reading stronger than the height allows an
unbounded weight; a weight only ranks the anchors, and the slant distance ranks them alike.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import ObservationPrep, kept_last, model_of
from pfdoa.radio import distance_from_rssi


class WeightedCentroid(Estimator):
    name = "wcl"
    OPTIONS = frozenset({"min_anchors"})

    def __init__(self, site, *, min_anchors: int = 3, **_: object) -> None:
        self.prep = ObservationPrep(site)
        self.model = model_of(site)
        self.anchors = site.positions
        self.min_anchors = min_anchors
        self.reset()

    def reset(self) -> None:
        self.last = self.anchors.mean(axis=0)

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        if p.count < self.min_anchors:
            return kept_last(obs.t, self.last, p)
        d = np.maximum(distance_from_rssi(p.rssi[p.mask], self.model), 1e-3)
        w = 1.0 / d
        x = (w @ self.anchors[p.mask]) / w.sum()
        self.last = x
        return Estimate(obs.t, float(x[0]), float(x[1]), math.nan, None, p.ids)
