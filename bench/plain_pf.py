"""A plain bootstrap particle filter: the floor a user could write in an afternoon.

The cost reference of ``make bench`` (issue 47): N particles, a random walk, a Gaussian
likelihood on the differential RSS (each observation's and each particle's model RSS with
their mean over the anchors removed, so the transmit power does not matter), systematic
resampling every step, the weighted mean as the estimate. Vectorised with numpy and written
plainly: no preallocated buffers, no pools of random numbers, no caches.
"""

from __future__ import annotations

import numpy as np


class PlainParticleFilter:
    def __init__(self, site, particles: int = 200, speed: float = 0.3, sigma_db: float = 4.0,
                 rng: np.random.Generator | None = None) -> None:
        self.anchors = site.positions
        self.n_exp = site.radio.path_loss_exponent
        self.rng = rng if rng is not None else np.random.default_rng()
        self.n = particles
        self.speed, self.sigma = speed, sigma_db
        lo, hi = self.anchors.min(axis=0), self.anchors.max(axis=0)
        self.p = self.rng.uniform(lo, hi, (particles, 2))
        self.w = np.full(particles, 1.0 / particles)
        self.t: float | None = None

    def step(self, t: float, rssi: np.ndarray) -> tuple[float, float]:
        dt = 0.0 if self.t is None else t - self.t
        self.t = t
        self.p += self.rng.normal(0.0, self.speed * dt + 1e-3, self.p.shape)
        ok = np.isfinite(rssi)
        d = np.linalg.norm(self.p[:, None, :] - self.anchors[None, ok, :], axis=2)
        model = -10.0 * self.n_exp * np.log10(np.maximum(d, 0.1))
        res = (rssi[ok] - rssi[ok].mean()) - (model - model.mean(axis=1, keepdims=True))
        logw = -0.5 * (res ** 2).sum(axis=1) / self.sigma ** 2
        self.w = np.exp(logw - logw.max())
        self.w /= self.w.sum()
        x, y = self.w @ self.p
        positions = (np.arange(self.n) + self.rng.random()) / self.n
        idx = np.minimum(np.searchsorted(np.cumsum(self.w), positions), self.n - 1)
        self.p = self.p[idx]
        return float(x), float(y)
