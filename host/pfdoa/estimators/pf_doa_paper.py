"""``pf-doa-paper``: the paper's method (Sec. III, Alg. 1) done correctly.

N particles uniform over the anchors' bounding box plus a small margin; the measured DOA is
the plane-fit gradient's direction smoothed over a window of k (Eqs. 3-5); a particle's
predicted DOA is the direction of the plane-fit gradient of the radio model's noise-free RSS
at the particle (independent of A and n); the weight is the product over the last M steps of
a Gaussian in the *wrapped* DOA error (Eq. 6), summed in logs; normalised (Eq. 7);
systematic resampling every step; the estimate is the max-weight particle (``estimate="mean"``
selects the weighted mean).

Choice for the M-term product: each particle carries a fixed ring of its last M
log-likelihood terms, each computed when that DOA arrived, at the position the particle (or
the ancestor it was resampled from) had then; rows travel with resampling. Every stored DOA
is thus compared with the prediction at the particle's own past position (its present
position shifted back by the motion it has undergone since), at O(N) cost per step instead
of M predictions per particle. Every per-particle array is preallocated at construction.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.doa import DoaSmoother, doa_from_gradient
from pfdoa.estimators.base import Estimate, Observation, Odometry
from pfdoa.estimators.common import dt_between
from pfdoa.estimators.particles import ParticleFilterBase

TWO_PI = 2.0 * math.pi


def degraded(count: int) -> str:
    return f"only {count} usable anchors, prediction only"


class PaperPfDoa(ParticleFilterBase):
    name = "pf-doa-paper"
    # The DOA-only weights cannot tell a particle's heading quickly, so the full random
    # walk stays on top of odometry to keep the cloud from drifting with wrong headings.
    walk_with_odometry = 1.0
    OPTIONS = frozenset({"particles", "history", "window", "sigma_doa", "estimate", "margin", "speed",
                         "odometry_noise", "min_anchors"})

    def __init__(self, site, *, rng: np.random.Generator | None = None, particles: int = 200,
                 history: int = 10, window: int = 5, sigma_doa: float = 0.3, estimate: str = "max",
                 margin: float | None = None, speed: float = 0.3, odometry_noise: float = 0.2,
                 min_anchors: int = 3, **_: object) -> None:
        super().__init__(site, rng, particles, margin, speed, odometry_noise, min_anchors)
        self.M = history
        self.sigma_doa = sigma_doa
        self.estimate = estimate
        self.smoother = DoaSmoother(window)
        n = particles
        self.ring = np.zeros((history, n))  # row m: log-likelihood terms of one past DOA
        self.gather_ring = np.empty((history, n))
        self._ones_m = np.ones(history)
        self.g = np.empty((n, 2))
        self.pred = np.empty(n)
        self.logw = np.empty(n)
        # The operator the cached -op.T was derived from, held (not its id: once the
        # GradientFit cache is cleared a new operator could reuse a freed object's id).
        self._op: np.ndarray | None = None
        self._op_neg_t = np.empty((self.n_anchors, 2))
        self.reset()

    def reset(self) -> None:
        self._reset_particles()
        self.ring.fill(0.0)
        self.head = -1
        self.smoother.reset()
        self.t_prev: float | None = None

    def _predicted_doa(self, op: np.ndarray) -> np.ndarray:
        """DOA of the plane-fit gradient of the model's noise-free RSS at every particle.

        RSS = A - 5 n log10(d^2): the gradient of RSS is -5n times that of log10(d^2), and
        n > 0 only scales it, so the direction is that of -(log10 d^2) @ op.T.
        """
        if op is not self._op:
            np.negative(op.T, out=self._op_neg_t)
            self._op = op
        np.matmul(self.dist.log10(self.xy), self._op_neg_t, out=self.g)
        return np.arctan2(self.g[:, 1], self.g[:, 0], out=self.pred)

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        dt = dt_between(self.t_prev, obs.t)
        self.t_prev = obs.t
        self._move(dt, odom)
        extra: dict = {}
        op = self.fit.operator(p.mask) if p.count >= self.min_anchors else None
        doa = None
        if op is not None:
            rssi = p.rssi if p.count == self.n_anchors else np.where(p.mask, p.rssi, 0.0)
            doa = self.smoother.push(doa_from_gradient(op @ rssi))
        if op is None or doa is None:
            extra["degraded"] = degraded(p.count) if op is None else "zero gradient, prediction only"
            mx, my, sig = self._mean_and_sigma()
            return self._estimate(obs.t, mx, my, sig, None, p.ids, extra)
        # Eq. 6 in logs: -(wrapped error)^2 / (2 sigma^2), the constant factor cancels in Eq. 7.
        self.head = (self.head + 1) % self.M
        e = self.ring[self.head]
        np.subtract(self._predicted_doa(op), doa - math.pi, out=e)
        np.remainder(e, TWO_PI, out=e)
        e -= math.pi
        np.multiply(e, e, out=e)
        e *= -0.5 / (self.sigma_doa * self.sigma_doa)
        np.matmul(self._ones_m, self.ring, out=self.logw)
        top = float(np.maximum.reduce(self.logw))
        if not math.isfinite(top):
            self._recover()
            self.ring.fill(0.0)
            extra["recovered"] = True
        else:
            np.subtract(self.logw, top, out=self.w)
            np.exp(self.w, out=self.w)
            self.w *= 1.0 / float(np.add.reduce(self.w))
        ex, ey, sig = self._best() if self.estimate == "max" else self._mean_and_sigma()
        est = self._estimate(obs.t, ex, ey, sig, doa, p.ids, extra)
        idx = self._resample()  # Alg. 1 resamples every step
        np.take(self.ring, idx, axis=1, out=self.gather_ring)
        self.ring[...] = self.gather_ring
        return est
