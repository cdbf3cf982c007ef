"""Particle storage and the vectorised pieces both PF-DOA filters share.

Layout is chosen for speed at small N (the hot path is dominated by per-call overhead, not
arithmetic): positions are one contiguous (N, 2) array (strided views cost several times
more per operation), heading and velocity are separate arrays, every buffer is allocated
once, and squared distances to the anchors come from one matrix product
``|p|^2 - 2 p.a + |a|^2`` instead of a broadcast subtraction over a trailing axis of 2.
Products and gathers call the array's methods (``w.dot(x)``, ``x.take(idx)``): the same C
code as ``np.dot`` and ``np.take``, without their Python-level dispatch (a third of a dot
at N = 200, half a take). The matrix products too (``a.dot(b, out=c)``, not ``np.matmul``):
for C-contiguous operands both make the same BLAS call (gemm; gemv for a vector), and the
ufunc's setup costs as much again.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa import odometry as odo
from pfdoa.doa import GradientFit
from pfdoa.estimators.base import Estimate, Estimator, Odometry
from pfdoa.estimators.common import ObservationPrep, default_margin, model_of, search_box
from pfdoa.estimators.resampling import SystematicResampler

# Variance of a heading uniform on the circle (rad^2): the most a circular spread can say.
HEADING_VAR_MAX = math.pi * math.pi / 3.0
RESEED_FRACTION = 0.25  # share of particles re-drawn uniformly when every weight vanished
POOL_MIN = 1 << 16  # standard normals pre-drawn per filter (see NormalPool)


class NormalPool:
    """Standard normal noise served as random windows of a pool drawn once per reset.

    Drawing 2N fresh normals costs ~10 us at N = 200, a quarter of the whole step budget;
    a window at a random offset of a pool 16 times larger costs ~1 us. Two windows overlap
    with probability < 2 k / size (about 1 % at N = 200), which is harmless for process
    and jitter noise. The pool is redrawn from the filter's generator on reset, so runs
    stay deterministic for a seed.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.pool = np.empty(size)

    def refill(self, rng: np.random.Generator) -> None:
        rng.standard_normal(out=self.pool)

    def take(self, k: int, rng: np.random.Generator) -> np.ndarray:
        start = int(rng.random() * (self.size - k + 1))
        return self.pool[start : start + k]


class SquaredDistances:
    """``log10`` of squared particle-anchor distances (clamped at the model's d_min), 3-D:
    each anchor ``heights`` above the particles' plane (pfdoa.radio), which costs nothing
    here (h^2 joins the anchor's constant term)."""

    def __init__(self, anchors: np.ndarray, n: int, min_distance_m: float, heights: np.ndarray | None = None) -> None:
        na = anchors.shape[0]
        self.B = -2.0 * anchors.T.copy()  # (2, n_anchors)
        self.a2 = (anchors * anchors).sum(axis=1)
        if heights is not None:
            self.a2 += heights * heights
        # |a|^2 and |p|^2 as full (n, n_anchors) arrays: adding a row or a column broadcast over
        # a few anchors costs three times a same-shape add at N = 200. |p|^2 = (p * p) @ ones
        # rounds x^2 + y^2 once, as the sum over the trailing axis did.
        self.a2_full = np.tile(self.a2, (n, 1))
        self.p2_full = np.empty((n, na))
        self._ones = np.ones((2, na))
        self.dmin2 = min_distance_m * min_distance_m
        self._dmin2 = np.array(self.dmin2)  # 0-d: see ParticleFilterBase._operand
        self.out = np.empty((n, na))
        self.sq = np.empty((n, 2))

    def log10(self, xy: np.ndarray) -> np.ndarray:
        d2 = self.out
        xy.dot(self.B, out=d2)
        np.multiply(xy, xy, out=self.sq)
        self.sq.dot(self._ones, out=self.p2_full)
        d2 += self.p2_full
        d2 += self.a2_full
        np.maximum(d2, self._dmin2, out=d2)
        return np.log10(d2, out=d2)


class ParticleFilterBase(Estimator):
    """Particles (position, heading, velocity), initialisation, motion, estimate."""

    walk_with_odometry = 0.1  # share of the random walk kept when odometry is given
    uses_rng = True

    def __init__(self, site, rng: np.random.Generator | None, particles: int, margin: float | None,
                 speed: float, odometry_noise: float, min_anchors: int, velocity_time: float = 0.0,
                 speed_range: float = 1.0) -> None:
        self.site = site
        self.prep = ObservationPrep(site)
        self.model = model_of(site)
        self.anchors = site.positions
        self.n_anchors = self.anchors.shape[0]
        self.fit = GradientFit(self.anchors)
        self.N = n = particles
        self.margin = default_margin(self.anchors) if margin is None else margin
        self.lo, self.hi = search_box(site, self.margin)
        self.speed = speed
        # Per-particle speed scale, log-uniform in [speed / range, speed * range]: the filter
        # selects the motion noise that fits the target (slow robot or walking person).
        self.log_speed_range = math.log(speed_range)
        self._log_speed_lo = math.log(max(speed, 1e-9)) - self.log_speed_range
        self._log_speed_hi = math.log(max(speed, 1e-9)) + self.log_speed_range
        self._speed_lo, self._speed_hi = math.exp(self._log_speed_lo), math.exp(self._log_speed_hi)
        self.odometry_noise = odometry_noise
        self.min_anchors = min_anchors
        self.velocity_time = velocity_time  # 0: random walk; > 0: velocity state (OU process)
        # The OU step's factors (exp(-dt / velocity_time), its innovation's share) for _ou_dt
        self._ou_dt = math.nan
        self._ou = (1.0, 0.0)
        base = rng if rng is not None else np.random.default_rng()
        # The generator state at construction, so reset() replays the same sequence.
        self._rng_state = base.bit_generator.state
        self.rng = base
        self.xy = np.empty((n, 2))
        self._xy_flat = self.xy.reshape(-1)  # views of the same memory
        self._lo_flat = np.tile(self.lo, n)
        self._hi_flat = np.tile(self.hi, n)
        self.heading = np.empty(n)
        self.vel = np.zeros((n, 2))
        self._vel_flat = self.vel.reshape(-1)
        self.pspeed = np.full(n, speed)
        self._pspeed_col = self.pspeed[:, None]
        # pspeed in both columns for the motion step's (N, 2) product (a column broadcast over
        # a trailing 2 costs several times a same-shape product), refreshed there when
        # _pspeed_stale. Only this class writes pspeed (seeding, resampling, the wander).
        self._pspeed_xy = np.empty((n, 2))
        self._pspeed_xy_flat = self._pspeed_xy.reshape(-1)
        self._pspeed_stale = True
        self.w = np.empty(n)
        # The scalar operand of a ufunc as a 0-d array, set before each call: a Python float
        # costs the call about 0.1 us more to convert.
        self._operand = np.empty(())
        self.noise_xy = np.empty((n, 2))
        self._noise_xy_flat = self.noise_xy.reshape(-1)
        self.noise_1 = np.empty(n)
        self.scratch = np.empty((2, n))
        self.sq = np.empty((n, 2))
        self.gather_xy = np.empty((n, 2))
        self.gather_1 = np.empty(n)
        self.dev = np.empty((n, 2))  # particles minus the estimate (uncertainty)
        self._ones2 = np.ones(2)
        self._est_xy = np.empty(2)
        self.r2 = np.empty(n)
        self.resampler = SystematicResampler(n)
        self.normals = NormalPool(max(POOL_MIN, 16 * 2 * n))
        self.heights = site.heights
        self.dist = SquaredDistances(self.anchors, n, self.model.min_distance_m, self.heights)

    def _reset_particles(self) -> None:
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = self._rng_state
        self.normals.refill(self.rng)
        self._seed_uniform()
        self.w.fill(1.0 / self.N)
        self._odometry_seen = False  # the heading is a state only once odometry moves the particles

    # -- initialisation and motion --------------------------------------------------------
    def _seed_uniform(self, sel: slice | np.ndarray = slice(None)) -> None:
        k = self.heading[sel].shape[0]
        self.xy[sel, 0] = self.rng.uniform(self.lo[0], self.hi[0], k)
        self.xy[sel, 1] = self.rng.uniform(self.lo[1], self.hi[1], k)
        self.heading[sel] = self.rng.uniform(-np.pi, np.pi, k)
        self._seed_motion(sel, k)

    def _seed_motion(self, sel, k: int) -> None:
        if self.log_speed_range > 0.0:
            self.pspeed[sel] = np.exp(self.rng.uniform(self._log_speed_lo, self._log_speed_hi, k))
        else:
            self.pspeed[sel] = self.speed
        self._pspeed_stale = True
        if self.velocity_time > 0.0:
            self.vel[sel] = self.pspeed[sel][:, None] * self.rng.standard_normal((k, 2))
        else:
            self.vel[sel] = 0.0

    def _wander_speeds(self) -> None:
        """Each particle's speed scale wanders 10 % (log-normal) at a resampling, held within
        its log-uniform range."""
        if not self.log_speed_range > 0.0:
            return
        noise = self.noise_1
        np.multiply(self.normals.take(self.N, self.rng), 0.1, out=noise)
        np.exp(noise, out=noise)
        self.pspeed *= noise
        np.maximum(self.pspeed, self._speed_lo, out=self.pspeed)
        np.minimum(self.pspeed, self._speed_hi, out=self.pspeed)
        self._pspeed_stale = True

    def _clamp(self) -> None:
        # Same-shape flat bounds: broadcasting over a trailing axis of 2 is slow at large N.
        flat = self._xy_flat
        np.maximum(flat, self._lo_flat, out=flat)
        np.minimum(flat, self._hi_flat, out=flat)

    def _move(self, dt: float, odom: Odometry | None) -> None:
        n = self.N
        if odom is not None:
            self._odometry_seen = True
            # Per-particle noisy copy of the increment: noise proportional to its size.
            a = self.odometry_noise
            step = math.hypot(odom.dx, odom.dy)
            s_lin = a * step
            s_ang = a * abs(odom.dtheta) + 0.5 * a * step
            z = self.normals.take(3 * n, self.rng)
            dx = z[:n] * s_lin + odom.dx
            dy = z[n : 2 * n] * s_lin + odom.dy
            dth = z[2 * n :] * s_ang + odom.dtheta
            odo.apply(self.xy, self.heading, dx, dy, dth, self.scratch)
        if dt > 0.0 and self.speed > 0.0:
            # On the (N, 2) arrays' flat views: the noise's window needs no reshape.
            z = self.normals.take(2 * n, self.rng)
            xyn = self._noise_xy_flat
            speed = self._pspeed_xy_flat
            if self._pspeed_stale:
                self._pspeed_xy[...] = self._pspeed_col
                self._pspeed_stale = False
            if odom is None and self.velocity_time > 0.0:
                # Ornstein-Uhlenbeck velocity (Singer model): stationary 1-sigma ``speed`` per
                # axis, correlation time ``velocity_time``; position integrates it.
                if dt != self._ou_dt:  # the factors of the latest interval: beacons come at a fixed rate
                    a = math.exp(-dt / self.velocity_time)
                    self._ou_dt, self._ou = dt, (a, math.sqrt(1.0 - a * a))
                a, fresh = self._ou
                vel, c = self._vel_flat, self._operand
                np.multiply(z, speed, out=xyn)
                c[()] = fresh
                xyn *= c
                c[()] = a
                vel *= c
                vel += xyn
                c[()] = dt
                np.multiply(vel, c, out=xyn)
            else:
                # Random walk, 1-sigma speed * dt per axis (scaled down on top of odometry).
                np.multiply(z, speed, out=xyn)
                xyn *= dt * (self.walk_with_odometry if odom is not None else 1.0)
            self._xy_flat += xyn
        self._clamp()

    def _resample(self, extra: tuple[np.ndarray, ...] = ()) -> np.ndarray:
        """Systematic resampling; gathers into scratch buffers and copies back, so every
        array keeps its identity. ``extra``: more per-particle 1-D arrays to carry along."""
        idx = self.resampler(self.w, self.rng)
        self.xy.take(idx, axis=0, out=self.gather_xy)
        self.xy[...] = self.gather_xy
        for arr in (self.heading, self.pspeed, *extra):
            arr.take(idx, out=self.gather_1)
            arr[...] = self.gather_1
        self._pspeed_stale = True
        if self.velocity_time > 0.0:
            self.vel.take(idx, axis=0, out=self.gather_xy)
            self.vel[...] = self.gather_xy
        self.w.fill(1.0 / self.N)
        return idx

    def _mean_and_sigma(self, w: np.ndarray | None = None) -> tuple[float, float, float]:
        """Weighted mean and 1-sigma radial spread sqrt(var_x + var_y) (weights ``w``, by
        default the particles' own)."""
        w = self.w if w is None else w
        m = w.dot(self.xy)
        np.multiply(self.xy, self.xy, out=self.sq)
        m2 = w.dot(self.sq)
        mx, my = float(m[0]), float(m[1])
        var = float(m2[0] + m2[1]) - mx * mx - my * my
        return mx, my, math.sqrt(var) if var > 0.0 else 0.0

    def _uncertainty(self, ex: float, ey: float, w: np.ndarray) -> tuple[float, tuple[float, float, float]]:
        """(r95, cov) of the particles weighted by ``w`` around the estimate (ex, ey): the
        radius holding 95 % of the weight, and the second moments (xx, xy, yy) about the
        estimate (the covariance when the estimate is the weighted mean; wider when it is not)."""
        d = self.dev
        e = self._est_xy
        e[0], e[1] = ex, ey
        np.subtract(self.xy, e, out=d)
        sq = self.sq
        np.multiply(d, d, out=sq)
        cxx, cyy = w.dot(sq).tolist()
        np.multiply(d[:, 0], d[:, 1], out=self.noise_1)
        cxy = float(w.dot(self.noise_1))
        r2 = self.r2
        sq.dot(self._ones2, out=r2)
        order = np.argsort(r2)
        cw = self.gather_1
        w.take(order, out=cw)
        np.cumsum(cw, out=cw)
        k = int(np.searchsorted(cw, 0.95))
        return math.sqrt(float(r2[order[min(k, self.N - 1)]])), (cxx, cxy, cyy)

    def _estimate(self, t: float, ex: float, ey: float, sig: float, doa, ids, extra: dict) -> Estimate:
        """``sig`` is replaced by the reported weights' spread when they are not the particles'."""
        w = self._report_weights()
        if w is not self.w:
            _, _, sig = self._mean_and_sigma(w)
        r95, cov = self._reported_uncertainty(ex, ey, *self._uncertainty(ex, ey, w))
        heading, heading_var = self._heading() if self._odometry_seen else (None, None)
        return Estimate(t, ex, ey, sig, doa, ids, extra, r95=r95, cov=cov, lost=self._lost(),
                        heading=heading, heading_var=heading_var)

    def _heading(self) -> tuple[float, float]:
        """Weighted circular mean of the particles' headings and its variance -2 ln R (R the
        mean resultant length: exact for a wrapped normal), at most that of a uniform heading."""
        mean, r = self._circular_mean()
        var = -2.0 * math.log(r) if r > 0.0 else math.inf
        return mean, min(var, HEADING_VAR_MAX)

    def _circular_mean(self) -> tuple[float, float]:
        """(mean direction, mean resultant length R) of the headings, weighted by ``w``."""
        h = self.noise_1
        np.cos(self.heading, out=h)
        c = float(self.w.dot(h))
        np.sin(self.heading, out=h)
        s = float(self.w.dot(h))
        return math.atan2(s, c), math.hypot(c, s)

    def _report_weights(self) -> np.ndarray:
        """The weights the reported spread (sigma, r95, cov) is taken from: the particles'."""
        return self.w

    def _uncertainty_scale(self) -> tuple[float, float]:
        """Factors on the particles' 95 % radius (r95) and on their covariance (cov)."""
        return 1.0, 1.0

    def _reported_uncertainty(self, ex: float, ey: float, r95: float, cov: tuple[float, float, float]
                              ) -> tuple[float, tuple[float, float, float]]:
        """The particles' (r95, cov) about the estimate (ex, ey) as reported: scaled by
        :meth:`_uncertainty_scale`."""
        k, kc = self._uncertainty_scale()
        if k != 1.0 or kc != 1.0:
            r95 *= k
            cov = (cov[0] * kc, cov[1] * kc, cov[2] * kc)
        return r95, cov

    def _lost(self) -> bool | None:
        """Whether the filter's own evidence says it lost the target (None: not judged)."""
        return None

    def _best(self) -> tuple[float, float, float]:
        """The max-weight particle (the paper's estimate) and the spread."""
        b = int(np.argmax(self.w))
        _, _, sig = self._mean_and_sigma()
        return float(self.xy[b, 0]), float(self.xy[b, 1]), sig

    def _recover(self) -> None:
        """Every weight vanished or is NaN: re-seed part of the cloud, equal weights."""
        bad = ~(np.isfinite(self.xy).all(axis=1) & np.isfinite(self.heading))
        k = max(1, int(RESEED_FRACTION * self.N))
        bad[self.rng.choice(self.N, size=k, replace=False)] = True
        self._seed_uniform(bad)
        self.w.fill(1.0 / self.N)
