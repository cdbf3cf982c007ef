"""The interface every position estimator implements (PF-DOA, the paper's comparison methods)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

# The shared records live in pfdoa.types (the lowest floor); estimator code imports them from here.
from pfdoa.types import Estimate, Observation, Odometry

__all__ = ["CHI2_2DOF_95", "Estimate", "Estimator", "Observation", "Odometry", "mahalanobis2", "mahalanobis2_many"]

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


def mahalanobis2_many(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """:func:`mahalanobis2` of each row of ``d`` (k, 2) under the matching row of ``cov``
    (k, 3: xx, xy, yy); inf where a covariance is singular."""
    xx, xy, yy = cov.T
    dx, dy = d.T
    det = xx * yy - xy * xy
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(det > 0.0, (yy * dx * dx - 2.0 * xy * dx * dy + xx * dy * dy) / det, math.inf)


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
