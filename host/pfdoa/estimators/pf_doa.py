"""PF-DOA: particle filters on the DOA of the RSS gradient.

Two estimators share the particle machinery here:

``pf-doa-paper`` (:class:`PaperPfDoa`) is the paper's method (Sec. III, Alg. 1) done
correctly: N particles uniform over the anchors' bounding box plus a small margin; the
measured DOA is the plane-fit gradient's direction smoothed over a window of k (Eqs. 3-5);
a particle's predicted DOA is the direction of the plane-fit gradient of the radio model's
noise-free RSS at the particle (independent of A and n); the weight is the product over the
last M steps of a Gaussian in the *wrapped* DOA error (Eq. 6), summed in logs; normalised
(Eq. 7); systematic resampling every step; the estimate is the max-weight particle
(``estimate="mean"`` selects the weighted mean).

Choice for the M-term product: each particle carries a fixed (N, M) ring of its last M
log-likelihood terms, each computed when that DOA arrived, at the position the particle (or
the ancestor it was resampled from) had then. Rows travel with resampling. This compares
every stored DOA with the prediction at the particle's own past position (shifted back by
the motion it has undergone since), at O(N) cost per step, instead of recomputing M
predictions per particle.

``pf-doa`` (:class:`PfDoa`) is the default: a standard recursive (SIR) filter whose
measurement model is the full offset-free RSS vector, not only its direction:

* the differential RSS residual ``e_i = (RSS_i - m_i(x)) - mean_j (RSS_j - m_j(x))`` over
  the present anchors, with ``m(x)`` the model's noise-free RSS at the particle. Centring
  removes the transmit power A (the profile likelihood over an unknown A), so only anchor
  geometry and the path-loss exponent matter;
* a Student-t likelihood on ``e`` (heavy tails: multipath bursts and NLOS do not wipe out
  the particle set);
* a per-particle path-loss exponent drawn around the site's value (the site value is a
  calibration, not a truth);
* the DOA term of the paper as an optional extra factor (``doa_weight``; the DOA is a
  deterministic function of the same RSS differences, so by default it is off);
* motion: odometry with proportional noise when given, otherwise a random walk whose
  1-sigma per axis is ``speed * dt``; resampling only when the effective sample size drops
  below ``resample_threshold * N``, followed by regularisation (kernel jitter);
* estimate: weighted mean; sigma: the particle spread.

Both filters preallocate every array at construction: ``step`` does not grow memory and
keeps array identities (resampling gathers into a scratch buffer and copies back).
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa import odometry as odo
from pfdoa.doa import DoaSmoother, GradientFit, doa_from_gradient
from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import ObservationPrep, bounding_box, default_margin, dt_between, model_of
from pfdoa.estimators.resampling import SystematicResampler

RESEED_FRACTION = 0.25  # share of particles re-drawn uniformly when every weight vanished
MIN_EXPONENT = 1.0
MAX_EXPONENT = 8.0
# Jump (kidnap) handling, see PfDoa._jump_test.
JUMP_PROBABILITY = 0.01  # prior probability per observation that the target left the cloud
JUMP_GATE = 1.0  # nats per anchor below the running evidence before the test runs
EVIDENCE_RATE = 0.05  # running average rate of the per-anchor log evidence
CANDIDATES = 1000  # uniform candidates for the test and the reset
# Online RSS noise scale (adapt_sigma): bounds in dB and averaging rate per observation.
SIGMA_RSS_MIN = 1.0  # 1 dB RSSI quantisation and model error make less meaningless
SIGMA_RSS_MAX = 20.0
SIGMA_RATE = 0.1


class _ParticleBase(Estimator):
    """Particle storage, initialisation, motion and bookkeeping shared by both filters."""

    def __init__(self, site, rng: np.random.Generator | None, particles: int, margin: float | None,
                 speed: float, odometry_noise: float, min_anchors: int) -> None:
        self.site = site
        self.prep = ObservationPrep(site)
        self.model = model_of(site)
        self.anchors = site.positions
        self.n_anchors = self.anchors.shape[0]
        self.fit = GradientFit(self.anchors)
        self.N = particles
        self.margin = default_margin(self.anchors) if margin is None else margin
        self.lo, self.hi = bounding_box(self.anchors, self.margin)
        self.speed = speed
        self.odometry_noise = odometry_noise
        self.min_anchors = min_anchors
        self._seed_rng = rng if rng is not None else np.random.default_rng()
        # The generator state at construction, so reset() replays the same sequence.
        self._rng_state = self._seed_rng.bit_generator.state
        self.rng = self._seed_rng
        n = particles
        self.state = np.zeros((n, 5))  # x, y, heading, vx, vy
        self.pose = self.state[:, :3]
        self.xy = self.state[:, :2]
        self.vel = self.state[:, 3:]
        self.velocity_time = 0.0  # 0: random walk; > 0: velocity state with this correlation time
        self.w = np.empty(n)
        self.noise = np.empty((n, 3))
        self.noise_xy = np.empty((n, 2))
        self.noise_1 = np.empty(n)
        self.scratch = np.empty((2, n))
        self.gather = np.empty((n, 5))
        self.resampler = SystematicResampler(n)

    # -- initialisation and motion --------------------------------------------------------
    def _seed_uniform(self, sel: slice | np.ndarray = slice(None)) -> None:
        p = self.pose[sel]
        k = p.shape[0]
        p[:, 0] = self.rng.uniform(self.lo[0], self.hi[0], k)
        p[:, 1] = self.rng.uniform(self.lo[1], self.hi[1], k)
        p[:, 2] = self.rng.uniform(-np.pi, np.pi, k)
        self.pose[sel] = p
        if self.velocity_time > 0.0:
            self.vel[sel] = self.speed * self.rng.standard_normal((k, 2))
        else:
            self.vel[sel] = 0.0

    def _move(self, dt: float, odom: Odometry | None) -> None:
        noise = self.noise
        if odom is not None:
            # Proportional noise on each increment plus a small floor, per particle.
            self.rng.standard_normal(out=noise)
            a = self.odometry_noise
            step = math.hypot(odom.dx, odom.dy)
            s_lin = a * step + 0.01 * self.speed * dt
            s_ang = a * abs(odom.dtheta) + 0.5 * a * step
            noise[:, 0] *= s_lin
            noise[:, 0] += odom.dx
            noise[:, 1] *= s_lin
            noise[:, 1] += odom.dy
            noise[:, 2] *= s_ang
            noise[:, 2] += odom.dtheta
            odo.apply(self.pose, noise[:, 0], noise[:, 1], noise[:, 2], self.scratch)
        if dt > 0.0 and self.speed > 0.0:
            xyn = self.noise_xy
            self.rng.standard_normal(out=xyn)
            if odom is None and self.velocity_time > 0.0:
                # Ornstein-Uhlenbeck velocity (Singer model): stationary 1-sigma ``speed`` per
                # axis, correlation time ``velocity_time``; position integrates it.
                a = math.exp(-dt / self.velocity_time)
                xyn *= self.speed * math.sqrt(1.0 - a * a)
                self.vel *= a
                self.vel += xyn
                np.multiply(self.vel, dt, out=xyn)
            else:
                xyn *= self.speed * dt * (0.1 if odom is not None else 1.0)
            self.xy += xyn
        np.clip(self.xy, self.lo, self.hi, out=self.xy)

    def _resample(self, extra_rows: list[np.ndarray]) -> np.ndarray:
        idx = self.resampler(self.w, self.rng)
        np.take(self.state, idx, axis=0, out=self.gather)
        self.state[...] = self.gather
        for arr in extra_rows:
            g = arr[idx]
            arr[...] = g
        return idx

    def _mean_and_sigma(self) -> tuple[float, float, float]:
        w = self.w
        m = w @ self.xy
        sq = self.scratch.T  # (N, 2) view of the scratch buffer
        np.multiply(self.xy, self.xy, out=sq)
        m2 = w @ sq
        mx, my = float(m[0]), float(m[1])
        var = float(m2[0] + m2[1]) - mx * mx - my * my
        return mx, my, math.sqrt(var) if var > 0.0 else 0.0

    def _recover(self) -> None:
        """Every weight vanished or is NaN: re-seed part of the cloud, equal weights."""
        bad = ~np.isfinite(self.pose).all(axis=1)
        k = max(1, int(RESEED_FRACTION * self.N))
        pick = self.rng.choice(self.N, size=k, replace=False)
        bad[pick] = True
        self._seed_uniform(bad)
        self.w.fill(1.0 / self.N)


class PaperPfDoa(_ParticleBase):
    name = "pf-doa-paper"
    OPTIONS = frozenset({"particles", "history", "window", "sigma_doa", "estimate", "margin", "speed",
                         "odometry_noise", "min_anchors"})

    def __init__(self, site, *, rng: np.random.Generator | None = None, particles: int = 200,
                 history: int = 10, window: int = 5, sigma_doa: float = 0.3, estimate: str = "max",
                 margin: float | None = None, speed: float = 0.5, odometry_noise: float = 0.2,
                 min_anchors: int = 3, **_: object) -> None:
        super().__init__(site, rng, particles, margin, speed, odometry_noise, min_anchors)
        self.M = history
        self.sigma_doa = sigma_doa
        self.estimate = estimate
        self.smoother = DoaSmoother(window)
        n, na = particles, self.n_anchors
        self.ring = np.zeros((n, history))  # per-particle log-likelihood terms
        self.D = np.empty((n, na, 2))
        self.d2 = np.empty((n, na))
        self.g = np.empty((n, 2))
        self.pred = np.empty(n)
        self.err = np.empty(n)
        self.logw = np.empty(n)
        self._dmin2 = self.model.min_distance_m**2
        self.reset()

    def reset(self) -> None:
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = self._rng_state
        self._seed_uniform()
        self.w.fill(1.0 / self.N)
        self.ring.fill(0.0)
        self.head = -1
        self.smoother.reset()
        self.t_prev: float | None = None

    def _predicted_doa(self, op: np.ndarray) -> np.ndarray:
        """DOA of the plane-fit gradient of the model's noise-free RSS at every particle."""
        np.subtract(self.xy[:, None, :], self.anchors, out=self.D)
        np.multiply(self.D, self.D, out=self.D)
        np.add(self.D[:, :, 0], self.D[:, :, 1], out=self.d2)
        np.maximum(self.d2, self._dmin2, out=self.d2)
        np.log10(self.d2, out=self.d2)
        # RSS = A - 5 n log10(d^2): the gradient of RSS is -5n times that of log10(d^2);
        # n > 0 only scales it, so the direction is that of -(log10 d^2) @ op.T.
        np.matmul(self.d2, op.T, out=self.g)
        np.negative(self.g, out=self.g)
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
            doa = self.smoother.push(doa_from_gradient(op @ np.where(p.mask, p.rssi, 0.0)))
        if doa is None:
            extra["degraded"] = (f"only {p.count} usable anchors" if op is None else "zero gradient") + \
                ", prediction only"
            mx, my, sig = self._mean_and_sigma()
            return Estimate(obs.t, mx, my, sig, None, p.ids, extra)
        pred = self._predicted_doa(op)
        e = self.err
        np.subtract(pred, doa, out=e)
        e += np.pi
        np.remainder(e, 2 * np.pi, out=e)
        e -= np.pi
        e *= 1.0 / self.sigma_doa
        np.multiply(e, e, out=e)
        e *= -0.5
        self.head = (self.head + 1) % self.M
        self.ring[:, self.head] = e
        np.sum(self.ring, axis=1, out=self.logw)
        top = float(self.logw.max())
        if not math.isfinite(top):
            self._recover()
            extra["recovered"] = True
        else:
            np.subtract(self.logw, top, out=self.w)
            np.exp(self.w, out=self.w)
            self.w *= 1.0 / float(self.w.sum())
        if self.estimate == "max":
            best = int(np.argmax(self.w))
            ex, ey = float(self.pose[best, 0]), float(self.pose[best, 1])
            _, _, sig = self._mean_and_sigma()
        else:
            ex, ey, sig = self._mean_and_sigma()
        self._resample([self.ring])  # Alg. 1 resamples every step
        return Estimate(obs.t, ex, ey, sig, doa, p.ids, extra)


class PfDoa(_ParticleBase):
    name = "pf-doa"
    OPTIONS = frozenset({"particles", "window", "sigma_doa", "sigma_rss", "estimate", "margin", "speed",
                         "odometry_noise", "doa_weight", "tail_dof", "exponent_spread", "resample_threshold",
                         "min_anchors", "velocity_time", "adapt_sigma", "power_sigma"})

    def __init__(self, site, *, rng: np.random.Generator | None = None, particles: int = 200,
                 window: int = 5, sigma_doa: float = 0.3, sigma_rss: float = 4.0, estimate: str = "mean",
                 margin: float | None = None, speed: float = 0.3, odometry_noise: float = 0.2,
                 doa_weight: float = 0.0, tail_dof: float = 4.0, exponent_spread: float = 0.0,
                 resample_threshold: float = 0.5, min_anchors: int = 3, velocity_time: float = 0.0,
                 adapt_sigma: bool = True, power_sigma: float = 0.0,
                 **_: object) -> None:
        super().__init__(site, rng, particles, margin, speed, odometry_noise, min_anchors)
        self.velocity_time = velocity_time
        self.sigma_doa = sigma_doa
        self.sigma_rss0 = sigma_rss
        self.sigma_rss = sigma_rss
        self.adapt_sigma = adapt_sigma
        # Student-t: variance = scale^2 * nu / (nu - 2); for nu <= 2 use the power as is.
        self._var_to_scale = (tail_dof - 2.0) / tail_dof if tail_dof > 2.0 else 1.0
        self.estimate = estimate
        self.doa_weight = doa_weight
        self.nu = tail_dof
        self.exponent_spread = exponent_spread
        self.resample_threshold = resample_threshold
        self.smoother = DoaSmoother(window)
        n, na = particles, self.n_anchors
        self.exponent = np.empty(n)  # per-particle path-loss exponent
        self.gain = np.empty((n, 1))  # -5 * exponent: model RSS = A + gain * log10(d^2)
        self.D = np.empty((n, na, 2))
        self.d2 = np.empty((n, na))
        self.E = np.empty((n, na))
        self.R = np.empty((n, na))
        self.ll = np.empty(n)
        self.logw = np.empty(n)
        self.g = np.empty((n, 2))
        self.pred = np.empty(n)
        self.err = np.empty(n)
        self.rssi_c = np.empty(na)
        self._dmin2 = self.model.min_distance_m**2
        self._centre = np.eye(na) - 1.0 / na  # (partial) centring matrix, all anchors present
        self._gamma = 1.0
        self.power_sigma = math.inf if power_sigma == 0.0 else power_sigma
        # Regularisation bandwidth factor for d = 2 (Silverman's rule, h = (4/(N(d+2)))^(1/(d+4))).
        self._h = (4.0 / (n * 4.0)) ** (1.0 / 6.0)
        self.reset()

    def reset(self) -> None:
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = self._rng_state
        self._seed_uniform()
        n0 = self.model.path_loss_exponent
        if self.exponent_spread > 0.0:
            self.exponent[:] = n0 + self.exponent_spread * self.rng.standard_normal(self.N)
            np.clip(self.exponent, MIN_EXPONENT, MAX_EXPONENT, out=self.exponent)
        else:
            self.exponent.fill(n0)
        np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
        self.w.fill(1.0 / self.N)
        self.logw.fill(-math.log(self.N))
        self.smoother.reset()
        self.t_prev: float | None = None
        self._log_slow: float | None = None
        self.sigma_rss = self.sigma_rss0

    def _centring(self, count: int) -> float:
        """Share gamma of the mean residual to remove, for a Gaussian prior of 1-sigma
        ``power_sigma`` on the transmitter's A around the site's value.

        Marginalising that offset from ``e = RSS - model`` gives the quadratic form
        ``|e|^2 - beta/n (sum e)^2`` with ``beta = n / (n + sigma_rss^2 / power_sigma^2)``,
        which equals ``|e - gamma mean(e)|^2`` for ``gamma = 1 - sqrt(1 - beta)``. An
        unknown A (power_sigma = inf) gives gamma = 1: the differential RSS.
        """
        if math.isinf(self.power_sigma):
            gamma = 1.0
        else:
            beta = count / (count + (self.sigma_rss / self.power_sigma) ** 2)
            gamma = 1.0 - math.sqrt(1.0 - beta)
        if count == self.n_anchors and abs(gamma - self._gamma) > 1e-3:
            self._gamma = gamma
            na = self.n_anchors
            self._centre[...] = np.eye(na) - gamma / na
        return gamma

    def _log_likelihood(self, rssi: np.ndarray, mask: np.ndarray, count: int) -> np.ndarray:
        """Student-t (or Gaussian) log-likelihood of the centred RSS residual, per particle."""
        D, d2 = self.D, self.d2
        np.subtract(self.xy[:, None, :], self.anchors, out=D)
        np.multiply(D, D, out=D)
        np.add(D[:, :, 0], D[:, :, 1], out=d2)
        np.maximum(d2, self._dmin2, out=d2)
        np.log10(d2, out=d2)
        E = self.E
        np.multiply(d2, self.gain, out=E)  # model RSS minus A
        gamma = self._centring(count)
        if count == self.n_anchors:
            E -= rssi
            res = np.matmul(E, self._centre, out=self.R)
        else:
            idx = np.flatnonzero(mask)
            res = E[:, idx] - rssi[idx]
            res -= gamma * res.mean(axis=1, keepdims=True)
        np.multiply(res, res, out=res)
        ll = self.ll
        if self.adapt_sigma:
            # Prior-predictive residual power per degree of freedom (centring removes one):
            # an estimate of the RSS noise variance plus the cloud's own spread, so it errs
            # on the wide side. A burst can at most quadruple it in one step.
            np.sum(res, axis=1, out=ll)
            var = float(self.w @ ll) / (count - 1)
            s2 = self.sigma_rss * self.sigma_rss
            var = min(var * self._var_to_scale, 4.0 * s2)
            s2 += SIGMA_RATE * (var - s2)
            self.sigma_rss = min(max(math.sqrt(max(s2, 0.0)), SIGMA_RSS_MIN), SIGMA_RSS_MAX)
        if self.nu >= 1e5:  # Gaussian limit
            np.sum(res, axis=1, out=ll)
            ll *= -0.5 / (self.sigma_rss * self.sigma_rss)
        else:
            res *= 1.0 / (self.nu * self.sigma_rss * self.sigma_rss)
            np.log1p(res, out=res)
            np.sum(res, axis=1, out=ll)
            ll *= -0.5 * (self.nu + 1.0)
        return ll

    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        dt = dt_between(self.t_prev, obs.t)
        self.t_prev = obs.t
        self._move(dt, odom)
        extra: dict = {}
        op = self.fit.operator(p.mask) if p.count >= self.min_anchors else None
        if op is None:
            extra["degraded"] = f"only {p.count} usable anchors, prediction only"
            mx, my, sig = self._mean_and_sigma()
            return Estimate(obs.t, mx, my, sig, self.smoother.value, p.ids, extra)
        rssi = p.rssi
        if p.count != self.n_anchors:
            rssi = np.where(p.mask, rssi, 0.0)
        doa = self.smoother.push(doa_from_gradient(op @ rssi))
        np.subtract(rssi, self.model.rssi_at_1m_dbm, out=self.rssi_c)  # model terms exclude A
        ll = self._log_likelihood(self.rssi_c, p.mask, p.count)
        self.logw += ll
        if self.doa_weight > 0.0 and doa is not None:
            g = self.g
            np.matmul(self.d2, op.T, out=g)  # d2 holds log10(d^2); direction is -g
            np.negative(g, out=g)
            e = np.arctan2(g[:, 1], g[:, 0], out=self.err)
            e -= doa
            e += np.pi
            np.remainder(e, 2 * np.pi, out=e)
            e -= np.pi
            np.multiply(e, e, out=e)
            e *= -0.5 * self.doa_weight / (self.sigma_doa * self.sigma_doa)
            self.logw += e
        top = float(self.logw.max())
        jump = None
        if not math.isfinite(top):
            self._recover()
            self.logw.fill(-math.log(self.N))
            extra["recovered"] = True
        else:
            np.subtract(self.logw, top, out=self.w)
            np.exp(self.w, out=self.w)
            total = float(self.w.sum())
            self.w *= 1.0 / total
            # logw was normalised, so top + log(total) is the log of the mean likelihood of
            # this observation under the prediction (the evidence), the kidnap test's input.
            log_evidence = top + math.log(total)
            self.logw -= log_evidence
            jump = self._jump_test(log_evidence, p.count, self.rssi_c, p.mask)
        if jump is not None:
            extra["jumped"] = self._jump(jump)
        elif 1.0 / float(self.w @ self.w) < self.resample_threshold * self.N:
            _, _, sig = self._mean_and_sigma()
            self._resample([self.exponent])
            self.w.fill(1.0 / self.N)
            self.logw.fill(-math.log(self.N))
            self._roughen(sig)
        if self.estimate == "max":
            best = int(np.argmax(self.w))
            ex, ey = float(self.pose[best, 0]), float(self.pose[best, 1])
            _, _, sig = self._mean_and_sigma()
        else:
            ex, ey, sig = self._mean_and_sigma()
        return Estimate(obs.t, ex, ey, sig, doa, p.ids, extra)

    def _point_log_likelihood(self, points: np.ndarray, gain: np.ndarray, rssi: np.ndarray,
                              mask: np.ndarray) -> np.ndarray:
        """The same likelihood as the hot path for arbitrary points (allocates; rare use)."""
        idx = np.flatnonzero(mask)
        d2 = ((points[:, None, :] - self.anchors[idx]) ** 2).sum(axis=2)
        res = gain[:, None] * np.log10(np.maximum(d2, self._dmin2)) - rssi[idx]
        res -= self._centring(idx.size) * res.mean(axis=1, keepdims=True)
        z = res * res / (self.sigma_rss * self.sigma_rss)
        if self.nu >= 1e5:
            return -0.5 * z.sum(axis=1)
        return -0.5 * (self.nu + 1.0) * np.log1p(z / self.nu).sum(axis=1)

    def _jump_test(self, log_evidence: float, count: int, rssi: np.ndarray, mask: np.ndarray):
        """Has the target jumped away from the cloud (kidnap, bad start, long outage)?

        The motion prior is taken as ``(1 - eps)`` * (the cloud) + ``eps`` * (uniform over the
        area). The posterior share of the uniform part is
        ``eps L_u / (eps L_u + (1 - eps) L_c)`` with ``L_c`` the evidence of the cloud and
        ``L_u`` that of uniform candidates. Evaluating ``L_u`` costs ~1000 likelihoods, so it
        is only done when the cloud's per-anchor evidence falls ``JUMP_GATE`` nats below its
        running average; otherwise the share is negligible (L_u << L_c while tracking).
        Returns None, or (share, candidates, exponents, log-likelihoods).
        """
        per_anchor = log_evidence / count
        slow = self._log_slow
        if slow is None or per_anchor >= slow - JUMP_GATE:
            self._log_slow = per_anchor if slow is None else slow + EVIDENCE_RATE * (per_anchor - slow)
            return None
        c = CANDIDATES
        pts = np.column_stack([self.rng.uniform(self.lo[0], self.hi[0], c),
                               self.rng.uniform(self.lo[1], self.hi[1], c)])
        expo = self.model.path_loss_exponent + self.exponent_spread * self.rng.standard_normal(c)
        np.clip(expo, MIN_EXPONENT, MAX_EXPONENT, out=expo)
        ll = self._point_log_likelihood(pts, -5.0 * expo, rssi, mask)
        top = float(ll.max())
        log_u = top + math.log(float(np.exp(ll - top).mean()))
        share = 1.0 / (1.0 + (1.0 - JUMP_PROBABILITY) / JUMP_PROBABILITY * math.exp(min(log_evidence - log_u, 700.0)))
        if share < 1.0 / self.N:
            self._log_slow = slow + EVIDENCE_RATE * (per_anchor - slow)
            return None
        return share, pts, expo, ll

    def _jump(self, jump) -> int:
        """Resample the cloud and replace a ``share`` of it by draws from the candidates in
        proportion to their likelihood (sensor resetting, Lenser & Veloso 2000)."""
        share, pts, expo, ll = jump
        _, _, sig = self._mean_and_sigma()
        self._resample([self.exponent])
        self._roughen(sig)
        k = min(self.N, int(round(share * self.N)))
        if k:
            prob = np.exp(ll - ll.max())
            pick = self.rng.choice(pts.shape[0], size=k, p=prob / prob.sum())
            self.xy[:k] = pts[pick]
            self.exponent[:k] = expo[pick]
            self.pose[:k, 2] = self.rng.uniform(-np.pi, np.pi, k)
            self.vel[:k] = self.speed * self.rng.standard_normal((k, 2)) if self.velocity_time > 0.0 else 0.0
            np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
        self.w.fill(1.0 / self.N)
        self.logw.fill(-math.log(self.N))
        return k

    def _roughen(self, sigma: float) -> None:
        """Kernel jitter after resampling so duplicates spread (regularised PF)."""
        h = self._h * sigma / math.sqrt(2.0)
        if h > 0.0:
            xyn = self.noise_xy
            self.rng.standard_normal(out=xyn)
            xyn *= h
            self.xy += xyn
            np.clip(self.xy, self.lo, self.hi, out=self.xy)
        if self.exponent_spread > 0.0:
            z = self.noise_1
            self.rng.standard_normal(out=z)
            z *= 0.1 * self.exponent_spread
            self.exponent += z
            np.clip(self.exponent, MIN_EXPONENT, MAX_EXPONENT, out=self.exponent)
        np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
