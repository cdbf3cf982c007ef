"""Planar odometry increments: compose them, buffer them by time, apply them to particle poses,
and the wheel-odometry noise model that makes them from a ground-truth track.

An increment (dx, dy, dtheta) is the motion since the previous pose expressed in the robot
frame at that previous pose (dx forward, dy left, dtheta counter-clockwise), as in
:class:`pfdoa.types.Odometry`. A timed increment ``(t, dx, dy, dtheta)`` covers
the interval ``(t_prev, t]`` since the previous one. :class:`OdometryBuffer` holds them in
time order and gives the motion over exactly the interval between two estimates
(:meth:`OdometryBuffer.take`), interpolating the increment that straddles an estimate's
time; live (``pfdoa gateway --odom``) and offline (``pfdoa replay --odom``) use it alike.

:func:`noisy_increments` is wheel odometry from a ground-truth track (rows t, x, y, heading):
increments with noise proportional to the motion (slip) plus a small constant term, like
the probabilistic-robotics odometry model. The simulator and the evaluation of the paper's
simulated dataset both use it, so it lives here rather than in the simulator.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pfdoa.types import Odometry


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


ODOM_MAX = 10000  # buffered increments at most (the oldest are dropped beyond, counted)


class OdometryBuffer:
    """Timed increments in time order; the motion over any interval of time.

    ``add`` appends an increment covering ``(t of the previous one, t]`` (the very first
    covers only its own instant). Increments whose ``t`` is not after the newest are
    dropped and counted (``out_of_order``); beyond ``max_len`` the oldest are dropped
    (``dropped``). ``take(t)`` returns the motion from the previous ``take`` (or the first
    increment) up to ``t``: whole increments, plus the share ``(t - t_a) / (t_b - t_a)`` of
    the one that straddles ``t`` (its motion scaled linearly; the rest is the next
    interval's). Time not yet covered by any increment stays for the next ``take``: motion
    reported late is not lost, it goes into the next estimate.
    """

    def __init__(self, max_len: int = ODOM_MAX) -> None:
        self.max_len = int(max_len)
        self._t: deque[float] = deque()
        self._inc: deque[Odometry] = deque()
        self._pos: float | None = None  # motion is consumed up to this time
        self.newest: float | None = None  # t of the newest increment ever added
        self.ended = False  # no more increments will come (a file read whole, a stream's end)
        self.lines = 0
        self.dropped = 0
        self.out_of_order = 0
        self.first: float | None = None

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t: float, dx: float, dy: float, dtheta: float) -> bool:
        """Append one increment; False (and counted) when it is not after the newest."""
        t = float(t)
        if self.newest is not None and not t > self.newest:
            self.out_of_order += 1
            return False
        if len(self._t) >= self.max_len:
            self._t.popleft()
            self._inc.popleft()
            self.dropped += 1
        self._t.append(t)
        self._inc.append(Odometry(float(dx), float(dy), float(dtheta)))
        if self.first is None:
            self.first = self._pos = t  # the first increment covers only its own instant
        self.newest = t
        self.lines += 1
        return True

    def end(self) -> None:
        self.ended = True

    def covers(self, t: float) -> bool:
        """An increment at or after ``t`` has arrived (the motion up to ``t`` is known)."""
        return self.newest is not None and self.newest >= t

    def take(self, t: float) -> Odometry | None:
        """The motion over (previous take, t]; None when no increment ever arrived."""
        if self.first is None or self._pos is None:
            return None
        total = Odometry()
        pos = self._pos
        while self._t and self._t[0] <= t:
            total = compose(total, self._inc.popleft())
            pos = self._t.popleft()
        if self._t and t > pos:
            tb, inc = self._t[0], self._inc[0]
            f = (t - pos) / (tb - pos)
            total = compose(total, Odometry(inc.dx * f, inc.dy * f, inc.dtheta * f))
            g = 1.0 - f
            self._inc[0] = Odometry(inc.dx * g, inc.dy * g, inc.dtheta * g)
            pos = t
        self._pos = pos
        return total


@dataclass(frozen=True)
class OdometryNoise:
    trans_frac: float = 0.05  # std of translation error per metre travelled
    rot_frac: float = 0.05  # std of rotation error per radian turned
    trans_abs_m: float = 0.002  # std per step, even when standing still
    rot_abs_rad: float = 0.002


def increments(track: np.ndarray) -> np.ndarray:
    """Noise-free robot-frame increments of rows (t, x, y, heading) -> rows (t, dx, dy, dtheta).

    Row i holds the motion from pose i-1 to pose i (row 0 is zero motion), expressed in the
    robot frame of pose i-1, as the ``.odom.csv`` format (``t,dx,dy,dtheta``) defines.
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
