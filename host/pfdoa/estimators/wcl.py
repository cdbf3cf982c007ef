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
from pfdoa.radio import PathLoss

MIN_DISTANCE_M = 1e-3  # a reading stronger than the model allows does not get an unbounded weight


class Centroid:
    """The anchors' positions averaged with weights ``1 / d_i^power``, d_i the model's distance
    for each reading (offsets removed; :func:`pfdoa.radio.distance_from_rssi`). Plain floats: a
    few anchors cost less so than as arrays (pf-doa computes it at every step for its report,
    :mod:`pfdoa.estimators.pf_uncertainty`, with its own power)."""

    def __init__(self, anchors: np.ndarray, model: PathLoss, power: float = 1.0) -> None:
        self.ax, self.ay = anchors[:, 0].tolist(), anchors[:, 1].tolist()
        self.a, self.k = model.rssi_at_1m_dbm, power / (10.0 * model.path_loss_exponent)
        self.top = (1.0 / MIN_DISTANCE_M) ** power

    def __call__(self, rssi: np.ndarray, present: tuple[int, ...]) -> tuple[float, float]:
        """The centroid of the anchors in ``present`` (at least one) for ``rssi`` (n,)."""
        vals = rssi.tolist()
        a, k, top, ax, ay = self.a, self.k, self.top, self.ax, self.ay
        sw = sx = sy = 0.0
        for i in present:
            w = 10.0 ** ((vals[i] - a) * k)  # 1 / d^power
            if w > top:
                w = top
            sw += w
            sx += w * ax[i]
            sy += w * ay[i]
        return sx / sw, sy / sw


class WeightedCentroid(Estimator):
    name = "wcl"
    OPTIONS = frozenset({"min_anchors"})

    def __init__(self, site, *, min_anchors: int = 3, **_: object) -> None:
        self.prep = ObservationPrep(site)
        self.model = model_of(site)
        self.anchors = site.positions
        self.centroid = Centroid(self.anchors, self.model)
        self.min_anchors = min_anchors
        self.reset()

    def reset(self) -> None:
        self.last = self.anchors.mean(axis=0)

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        if p.count < self.min_anchors:
            return kept_last(obs.t, self.last, p)
        x, y = self.centroid(p.rssi, tuple(np.flatnonzero(p.mask).tolist()))
        self.last = np.array([x, y])
        return Estimate(obs.t, x, y, math.nan, None, p.ids)
