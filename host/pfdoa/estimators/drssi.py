"""Differential-RSS grid search (paper Appendix B, Podevijn et al. 2018).

DRSS_i = RSS_i - RSS_ref with the strongest present anchor as reference, which cancels the
unknown transmit power. The offline phase tabulates the model's RSS on a grid over the
anchors' bounding box (configurable resolution); online, the cell with the least squared
difference between model and measured DRSS over the present anchors is the estimate.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import ObservationPrep, kept_last, make_grid, model_of, search_box
from pfdoa.radio import mean_rssi

# Table values (cells x present anchors) scored per block: a floor-sized grid (hundreds of
# thousands of cells, dozens of anchors) scored whole makes temporaries of hundreds of MB per
# step; blocks keep them in cache (four times faster on a 56-anchor floor) and give the same
# costs, row by row. A room's grid is one block.
BLOCK_VALUES = 32768


class DifferentialRssGrid(Estimator):
    name = "drssi"
    OPTIONS = frozenset({"resolution", "margin", "min_anchors"})

    def __init__(self, site, *, resolution: float = 0.1, margin: float = 0.0, min_anchors: int = 3,
                 **_: object) -> None:
        self.prep = ObservationPrep(site)
        self.anchors = site.positions
        self.min_anchors = min_anchors
        lo, hi = search_box(site, margin)
        _, _, self.points = make_grid(lo, hi, resolution)
        self.table = mean_rssi(self.points, self.anchors, model_of(site), heights=site.heights)  # (cells, n)
        self._cost = np.empty(len(self.points))
        self.reset()

    def reset(self) -> None:
        self.last = self.anchors.mean(axis=0)

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        if p.count < self.min_anchors:
            return kept_last(obs.t, self.last, p)
        idx = np.flatnonzero(p.mask)
        r = p.rssi[idx]
        ref = int(np.argmax(r))
        dr = r - r[ref]
        cost = self._cost
        block = max(1, BLOCK_VALUES // idx.size)
        for start in range(0, cost.size, block):
            t = self.table[start : start + block, idx]
            diff = (t - t[:, ref : ref + 1]) - dr
            (diff * diff).sum(axis=1, out=cost[start : start + block])
        best = int(np.argmin(cost))
        self.last = self.points[best]
        return Estimate(obs.t, float(self.last[0]), float(self.last[1]), math.nan, None, p.ids,
                        {"cost": float(cost[best])})
