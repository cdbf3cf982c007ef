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
    poses: np.ndarray,
    dx: float | np.ndarray,
    dy: float | np.ndarray,
    dtheta: float | np.ndarray,
    scratch: np.ndarray | None = None,
) -> None:
    """Move poses (N, 3) = (x, y, theta) in place by robot-frame increments.

    dx, dy, dtheta are scalars or per-pose arrays (N,) (a noisy copy per particle).
    ``scratch`` (2, N) avoids allocating in the hot path.
    """
    n = poses.shape[0]
    if scratch is None:
        scratch = np.empty((2, n))
    c, s = scratch[0], scratch[1]
    th = poses[:, 2]
    np.cos(th, out=c)
    np.sin(th, out=s)
    # x += c dx - s dy ; y += s dx + c dy, evaluated without temporaries where possible
    poses[:, 0] += c * dx - s * dy
    poses[:, 1] += s * dx + c * dy
    th += dtheta
    # keep theta bounded so float precision does not degrade over long runs
    np.subtract(th, 2 * np.pi * np.floor((th + np.pi) / (2 * np.pi)), out=th)
