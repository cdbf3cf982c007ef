"""The interface every position estimator implements (PF-DOA, the paper's comparison methods)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Observation:
    """One synchronized anchor set.

    rssi: dBm per anchor in *site order* (``Site.anchors``), NaN where an anchor is
    missing or stale. Per-anchor offsets are NOT yet removed (estimators do that).
    count: how many readings each value combines (time windows average an anchor's
    repeated readings, :func:`pfdoa.trace.combine_db`); None means one reading each.
    """

    t: float
    rssi: np.ndarray
    count: np.ndarray | None = None


@dataclass(frozen=True)
class Odometry:
    """Motion since the previous step, in the robot frame at the previous pose."""

    dx: float = 0.0
    dy: float = 0.0
    dtheta: float = 0.0


@dataclass
class Estimate:
    t: float
    x: float
    y: float
    sigma: float  # 1-sigma radial uncertainty (m); NaN when the method has none
    doa: float | None = None  # DOA of the RSS gradient (rad, site frame), if computed
    anchors_used: tuple[int, ...] = ()
    extra: dict = field(default_factory=dict)
    r95: float = math.nan  # radius (m) around (x, y) holding the true position with 95 % probability
    cov: tuple[float, float, float] | None = None  # position covariance (xx, xy, yy), m^2
    lost: bool | None = None  # the method's own evidence says it no longer explains the readings (None: not judged)
    # Heading of the robot (rad, site frame, circular mean) and its variance (rad^2, from the
    # circular spread) when the method tracks one (the particle filters, once given odometry).
    heading: float | None = None
    heading_var: float | None = None


# 95 % quantile of the chi-square distribution with 2 degrees of freedom: the squared
# Mahalanobis distance bound of a 2-D 95 % ellipse.
CHI2_2DOF_95 = 5.991


def mahalanobis2(dx: float, dy: float, cov: tuple[float, float, float]) -> float:
    """Squared Mahalanobis distance of (dx, dy) under the 2 x 2 covariance (xx, xy, yy);
    inf for a singular covariance (a point estimate claiming certainty is never "within")."""
    xx, xy, yy = cov
    det = xx * yy - xy * xy
    if not det > 0.0:
        return math.inf
    return (yy * dx * dx - 2.0 * xy * dx * dy + xx * dy * dy) / det


class Estimator(ABC):
    """Stateful position estimator. ``step`` is called once per observation, in time order."""

    name: str = ""
    uses_rng: bool = False  # make_estimator hands such a method the caller's generator

    @abstractmethod
    def reset(self) -> None:
        """Forget all state (as after construction)."""

    @abstractmethod
    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        """Consume one observation (and the odometry since the previous one)."""
