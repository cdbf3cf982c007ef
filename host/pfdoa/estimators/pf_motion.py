"""pf-doa's motion model beyond the shared one (:meth:`ParticleFilterBase._move`: odometry with
proportional noise, else an Ornstein-Uhlenbeck velocity whose speed is a per-particle scale).

* the search box's edges reflect a particle (:func:`reflect_into`), they do not hold it: a
  box that clamps piles the particles that would leave it onto its edge, where the estimate
  then sits whenever the readings point outwards (the walls of a room whose RSS says little);
* leaps (:class:`Leaps`), without odometry: a mixture motion prior for a target that moves
  further than the speed prior allows (a walker setting off after a pause);
* regularisation after resampling (:func:`roughen`): Gaussian kernel jitter, and with
  odometry the heading's too, after Liu and West's shrinkage towards the mean.

docs/estimator.md ("Motion") gives the measurements behind each.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.pf_model import MAX_EXPONENT, MIN_EXPONENT

TWO_PI = 2.0 * math.pi
HEADING_MEAN_MIN_R = 0.1  # below this mean resultant length the headings are not shrunk
FEW_LEAPS = 8  # up to this many leaps in a step are applied one by one (Leaps.__call__)
NO_LEAPS: frozenset[int] = frozenset()


def reflect_into(flat: np.ndarray, lo: np.ndarray, hi: np.ndarray, tmp: np.ndarray) -> None:
    """Reflect coordinates (flattened (N, 2), bounds of the same shape) at the box's edges, in
    place: ``2 clip(x) - x``; a point beyond twice the box (a leap across it) ends on the far
    edge. ``tmp``: scratch of the same shape."""
    np.maximum(flat, lo, out=tmp)  # maximum and minimum: np.clip costs twice as much here
    np.minimum(tmp, hi, out=tmp)
    np.add(tmp, tmp, out=tmp)  # 2 clip(x), exactly, without a scalar operand to convert
    np.subtract(tmp, flat, out=flat)
    np.maximum(flat, lo, out=flat)
    np.minimum(flat, hi, out=flat)


class Leaps:
    """Each particle leaps at the rate ``rate`` per second (a Poisson process, so the cloud's
    leaps come at N ``rate`` per second): displaced by 1-sigma ``sigma_m`` per axis, started
    again from rest. The cloud thus keeps a few particles where the target would be had it
    moved further than the speed prior allows; when it has, those take the weight and the
    cloud catches up in a step or two. The waiting times and the particles come from pools
    drawn from the filter's generator (a step without a leap costs a subtraction), first when
    an interval could hold a leap (with odometry none does: the random stream is the same as
    without leaps)."""

    POOL = 1024

    def __init__(self, n: int, rate: float, sigma_m: float) -> None:
        self.n = n
        self.rate = rate
        self.sigma_m = sigma_m
        self._none = np.empty(0, dtype=np.intp)
        self.idx = self._none  # the particles that leapt at this step ...
        self.leapt: set[int] | frozenset[int] = NO_LEAPS  # ... each once
        self._ints = np.empty(self.POOL, dtype=np.intp)
        self._waits: list[float] = []
        self._k = self._j = 0
        self.until = math.nan

    def reset(self) -> None:
        self.idx = self._none
        self.leapt = NO_LEAPS
        self.until = math.nan  # the pools are drawn at the first interval that could hold a leap

    def _refill(self, rng: np.random.Generator) -> None:
        self._ints[:] = rng.integers(0, self.n, self.POOL)
        self._waits = (rng.exponential(1.0, self.POOL) / (self.n * self.rate)).tolist()
        self._k = self._j = 0

    def _wait(self, rng: np.random.Generator) -> float:
        if self._k == self.POOL:
            self._refill(rng)
        w = self._waits[self._k]
        self._k += 1
        return w

    def __call__(self, dt: float, xy: memoryview[float], vel: memoryview[float] | None, rng: np.random.Generator,
                 normals) -> int:
        """Leap; returns how many particles leapt (their indices in :attr:`idx`, each once in
        :attr:`leapt`). ``xy``, ``vel``: flat (2 N,) memoryviews of the positions and velocities,
        particle i's x at 2 i and y at 2 i + 1 (a few particles' values cost half as much so as
        through numpy's scalar indexing, and a flat index half as much as an (i, 0) pair)."""
        self.idx = self._none
        self.leapt = NO_LEAPS
        if not dt > 0.0 or self.rate <= 0.0:
            return 0
        if self.until != self.until:  # NaN: the first such interval since the reset
            self._refill(rng)
            self.until = self._wait(rng)
        self.until -= dt
        if self.until > 0.0:
            return 0
        m = 0
        until = self.until
        k, waits = self._k, self._waits
        while until <= 0.0:  # _wait inlined: one call a leap was a tenth of the leaps' cost
            if k == self.POOL:
                self._refill(rng)
                k, waits = 0, self._waits
            until += waits[k]
            k += 1
            m += 1
        self.until, self._k = until, k
        if m > self.n:
            m = self.n
        if m > self.POOL:  # more than a pool holds (thousands of particles after a gap): drawn here
            idx = self.idx = rng.integers(0, self.n, m)
        else:
            if self._j + m > self.POOL:
                self._refill(rng)
            idx = self.idx = self._ints[self._j:self._j + m]  # a particle drawn twice leaps once
            self._j += m
        z = normals.take(2 * m, rng)
        ids = idx.tolist()
        self.leapt = set(ids)
        if m > FEW_LEAPS:
            np.asarray(xy).reshape(-1, 2)[idx] += self.sigma_m * z.reshape(m, 2)
            if vel is not None:
                np.asarray(vel).reshape(-1, 2)[idx] = 0.0  # from rest: the motion step re-grows the velocity
            return m
        # A few leaps (four a step at N = 200 and 10 Hz) as plain floats: the fancy-indexed
        # update costs several times more. The same values: a particle drawn twice keeps its
        # last draw, as ``xy[idx] += ...`` leaves it.
        s = self.sigma_m
        zs = z.tolist()
        draws = zip(ids, range(m)) if len(self.leapt) == m else dict(zip(ids, range(m))).items()
        for i, j in draws:  # (particle, its last draw)
            i, j = 2 * i, 2 * j  # flat indices: the particle's x, its draw's first normal
            xy[i] = xy[i] + s * zs[j]
            xy[i + 1] = xy[i + 1] + s * zs[j + 1]
            if vel is not None:
                vel[i] = 0.0  # two scalar stores cost half of one row's broadcast
                vel[i + 1] = 0.0
        return m


def roughen(pf, sigma: float) -> None:
    """Kernel jitter after resampling so copies spread (the regularised PF; bandwidth
    ``pf.h`` times the cloud's spread ``sigma``). With odometry the motion noise is small and
    an unshrunk kernel (+17 % variance per resampling at N = 200) made the reported spread too
    wide, so position and heading are first shrunk towards their means by sqrt(1 - h^2) (Liu
    and West) and the heading is jittered too (else resampled copies of a wrong heading differ
    only by the odometry noise and the cloud drifts with it). Without odometry shrinkage was
    measured and not kept. The speed scale wanders (10 % per resampling) so it can follow the
    target; the exponent (a site with one per particle) 10 % of its spread."""
    n = pf.N
    odometry = pf._odometry_seen
    shrink = math.sqrt(1.0 - pf.h * pf.h) if odometry else 1.0
    h = pf.h * sigma / math.sqrt(2.0)
    if h > 0.0:
        if shrink < 1.0:
            m = pf.w.dot(pf.xy)  # the weights are uniform after resampling
            pf.xy -= m
            pf.xy *= shrink
            pf.xy += m
        np.multiply(pf.normals.take(2 * n, pf.rng).reshape(n, 2), h, out=pf.noise_xy)
        pf.xy += pf.noise_xy
        pf._clamp()
    if odometry:
        _roughen_heading(pf, shrink)
    pf._wander_speeds()
    model = pf.rss
    if model.spread > 0.0:
        np.multiply(pf.normals.take(n, pf.rng), 0.1 * model.spread, out=pf.noise_1)
        model.exponent += pf.noise_1
        np.clip(model.exponent, MIN_EXPONENT, MAX_EXPONENT, out=model.exponent)
        model.sync_gain()


def _roughen_heading(pf, shrink: float) -> None:
    """The heading's jitter: the bandwidth factor times its circular spread, after shrinking
    each heading's deviation from the circular mean by ``shrink`` (not when the headings are
    nearly uniform, whose mean direction is noise)."""
    mean, r = pf._circular_mean()
    # r of equal headings can round to just above 1: the log must not turn positive
    spread = math.sqrt(-2.0 * math.log(min(max(r, 1e-12), 1.0)))
    if r > HEADING_MEAN_MIN_R:
        dev = pf.noise_1
        np.subtract(pf.heading, mean - math.pi, out=dev)
        np.remainder(dev, TWO_PI, out=dev)
        dev -= math.pi
        dev *= shrink
        np.add(dev, mean, out=pf.heading)
    np.multiply(pf.normals.take(pf.N, pf.rng), pf.h * spread, out=pf.noise_1)
    pf.heading += pf.noise_1
