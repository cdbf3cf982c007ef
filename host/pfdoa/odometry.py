"""Planar odometry increments: compose them, and apply them to particle poses.

An increment (dx, dy, dtheta) is the motion since the previous pose expressed in the robot
frame at that previous pose (dx forward, dy left, dtheta counter-clockwise), as in
:class:`pfdoa.estimators.base.Odometry`. Replay composes the increments that arrive between
two observations into one and hands it to the estimator's ``step``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from pfdoa.estimators.base import Odometry


def compose(a: Odometry, b: Odometry) -> Odometry:
    """The increment of doing ``a`` and then ``b`` (``b`` expressed in the frame after ``a``)."""
    c, s = math.cos(a.dtheta), math.sin(a.dtheta)
    dth = math.remainder(a.dtheta + b.dtheta, 2 * math.pi)
    return Odometry(a.dx + c * b.dx - s * b.dy, a.dy + s * b.dx + c * b.dy, dth)


def compose_all(increments: Iterable[Odometry]) -> Odometry:
    """Compose a sequence of increments in order (identity for an empty sequence)."""
    total = Odometry()
    for inc in increments:
        total = compose(total, inc)
    return total


def apply(
    xy: np.ndarray,
    heading: np.ndarray,
    dx: float | np.ndarray,
    dy: float | np.ndarray,
    dtheta: float | np.ndarray,
    scratch: np.ndarray | None = None,
) -> None:
    """Move particle poses in place by robot-frame increments.

    xy (N, 2) and heading (N,) are the poses; dx, dy, dtheta are scalars or per-particle
    arrays (N,) (a noisy copy of the increment per particle). ``scratch`` (2, N) avoids
    allocating in the hot path. Heading is kept in [-pi, pi).
    """
    n = heading.shape[0]
    if scratch is None:
        scratch = np.empty((2, n))
    c, s = scratch[0], scratch[1]
    np.cos(heading, out=c)
    np.sin(heading, out=s)
    xy[:, 0] += c * dx - s * dy
    xy[:, 1] += s * dx + c * dy
    heading += dtheta
    # keep heading bounded so float precision does not degrade over long runs
    heading -= 2 * np.pi * np.floor((heading + np.pi) / (2 * np.pi))


def apply_poses(poses: np.ndarray, dx, dy, dtheta) -> None:
    """:func:`apply` for poses stored as rows (x, y, theta) of one (N, 3) array."""
    heading = poses[:, 2].copy()
    xy = poses[:, :2]
    apply(xy, heading, dx, dy, dtheta)
    poses[:, 2] = heading
