"""The records every layer shares: an anchor set in, odometry in, a position out.

They live on the lowest floor of the package (no imports of ours), so that odometry,
the gateway, evaluation and the simulator can use them without importing the estimators;
:mod:`pfdoa.estimators.base` re-exports them for estimator code.
"""

from __future__ import annotations

import math
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


def position_cov(estimate) -> tuple[float, float, float] | None:
    """An estimate's or output record's position covariance ``(xx, xy, yy)`` (m^2), or None
    when it has none: its ``cov`` when finite, else the isotropic covariance its ``sigma``
    implies (sigma = sqrt(var_x + var_y), for methods without a covariance)."""
    cov = getattr(estimate, "cov", None)
    if cov is not None:
        xx, xy, yy = (float(v) for v in cov)
        if all(math.isfinite(v) for v in (xx, xy, yy)):
            return xx, xy, yy
    sigma = getattr(estimate, "sigma", None)
    if sigma is not None and math.isfinite(float(sigma)):
        v = float(sigma) ** 2 / 2.0
        return v, 0.0, v
    return None
