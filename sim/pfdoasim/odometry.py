"""Wheel odometry from a ground-truth track: robot-frame increments with noise.

Increments between consecutive poses (x, y, heading) are expressed in the robot frame of
the earlier pose, as the common ``.odom.csv`` format (``t,dx,dy,dtheta``) defines. Noise is
proportional to the motion (slip) plus a small constant term, like FilterPy's / the
probabilistic-robotics odometry model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OdometryNoise:
    trans_frac: float = 0.05  # std of translation error per metre travelled
    rot_frac: float = 0.05  # std of rotation error per radian turned
    trans_abs_m: float = 0.002  # std per step, even when standing still
    rot_abs_rad: float = 0.002


def increments(track: np.ndarray) -> np.ndarray:
    """Noise-free robot-frame increments of rows (t, x, y, heading) -> rows (t, dx, dy, dtheta).

    Row i holds the motion from pose i-1 to pose i (row 0 is zero motion).
    """
    t, x, y, h = (np.asarray(track, dtype=float)[:, i] for i in range(4))
    dxw, dyw = np.diff(x, prepend=x[:1]), np.diff(y, prepend=y[:1])
    h0 = np.concatenate([h[:1], h[:-1]])
    c, s = np.cos(h0), np.sin(h0)
    dx = c * dxw + s * dyw
    dy = -s * dxw + c * dyw
    dth = (np.diff(h, prepend=h[:1]) + np.pi) % (2 * np.pi) - np.pi
    return np.column_stack([t, dx, dy, dth])


def noisy_increments(track: np.ndarray, noise: OdometryNoise, rng: np.random.Generator) -> np.ndarray:
    """:func:`increments` with multiplicative and additive Gaussian noise."""
    inc = increments(track)
    dist = np.hypot(inc[:, 1], inc[:, 2])
    k = len(inc)
    sd_t = noise.trans_frac * dist + noise.trans_abs_m
    sd_r = noise.rot_frac * np.abs(inc[:, 3]) + noise.rot_abs_rad
    out = inc.copy()
    out[:, 1] += rng.normal(0.0, 1.0, k) * sd_t
    out[:, 2] += rng.normal(0.0, 1.0, k) * sd_t
    out[:, 3] += rng.normal(0.0, 1.0, k) * sd_r
    return out

