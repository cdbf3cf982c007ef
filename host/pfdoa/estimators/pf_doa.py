"""PF-DOA: particle filters on the DOA of the RSS gradient.

``pf-doa-paper`` (:class:`PaperPfDoa`) is the paper's method (Sec. III, Alg. 1) done
correctly: N particles uniform over the anchors' bounding box plus a small margin; the
measured DOA is the plane-fit gradient's direction smoothed over a window of k (Eqs. 3-5);
a particle's predicted DOA is the direction of the plane-fit gradient of the radio model's
noise-free RSS at the particle (independent of A and n); the weight is the product over the
last M steps of a Gaussian in the *wrapped* DOA error (Eq. 6), summed in logs; normalised
(Eq. 7); systematic resampling every step; the estimate is the max-weight particle
(``estimate="mean"`` selects the weighted mean).

Choice for the M-term product: each particle carries a fixed ring of its last M
log-likelihood terms, each computed when that DOA arrived, at the position the particle (or
the ancestor it was resampled from) had then; rows travel with resampling. Every stored DOA
is thus compared with the prediction at the particle's own past position (its present
position shifted back by the motion it has undergone since), at O(N) cost per step instead
of M predictions per particle.

``pf-doa`` (:class:`PfDoa`) is the default, chosen by measurement (docs/estimator-study.md):
a recursive (SIR) filter whose measurement model is the whole offset-free RSS vector, not
only its direction:

* residual ``e = RSS - model(x)`` over the present anchors with its mean removed: the
  differential RSS, independent of the transmit power A (``power_sigma`` > 0 keeps part of
  the mean for a known-ish A: exact marginalisation of a Gaussian prior on A);
* the transmitter's power learnt online (``learn_power``, :class:`PowerTracker`): the
  running mean of the posterior-mean residual, with its spread, becomes that Gaussian prior on
  A around the learnt value, which resolves what the differential RSS leaves ambiguous
  when only three anchors report;
* Gaussian likelihood on ``e`` by default; a finite ``tail_dof`` gives a Student-t (heavy
  tails resist single-reading bursts but make the filter slow to believe a real jump; with
  time windows an anchor's value is already a median of its readings);
* RSS noise scale estimated online from the prior-predictive residual (``adapt_sigma``),
  bounded to [1, 20] dB, so the same defaults serve 1 dB simulations and 5 dB real rooms;
* motion: odometry with proportional noise when given (heading is a particle state,
  uniform at start); otherwise an Ornstein-Uhlenbeck velocity (correlation time
  ``velocity_time`` = 5 s; 0 gives a random walk of 1-sigma ``speed * dt``) whose speed is
  a per-particle scale, log-uniform in [speed / speed_range, speed * speed_range] =
  [0.06, 1.5] m/s by default, so a slow robot and a walking person both fit;
* resampling only when the effective sample size drops below ``resample_threshold * N``,
  then regularisation (Gaussian kernel jitter, Silverman bandwidth); with odometry the
  heading is jittered as well (else resampled copies of a wrong heading differ only by the
  odometry noise and the cloud drifts with it), and position and heading are first shrunk
  towards their means by sqrt(1 - h^2) so the jitter does not widen the cloud (Liu and
  West's kernel shrinkage): with odometry the motion noise is small and the unshrunk
  kernel (+17 % variance per resampling at N = 200) made the reported spread too wide.
  Without odometry the shrinkage was measured and not kept (docs/estimator-study.md,
  "Regularisation with odometry");
* optionally, per motion mode (``residual_rho``, ``residual_rho_odometry``; written by
  :func:`pfdoa.calibrate.learn_uncertainty` where the site's calibration runs gain from it),
  each particle's centred residual whitened by its previous one, ``r_t - rho r_(t-1)``
  (AR(1) errors: readings held or drifting between observations are not that many
  independent ones); the online noise scale then measures the innovation;
* without odometry, leaps (:meth:`PfDoa._leap`): each particle, at the rate ``leap_rate``
  = 0.1 per second, is displaced by 1-sigma ``leap_m`` = 2.5 m per axis and starts again
  from rest, a mixture motion prior for a target that moves further than the speed prior
  allows (a walker setting off after a pause: the cloud, narrowed while it stood, lags);
  the online noise scale leaves the leapt particles out;
* a jump (kidnap) test with sensor resetting: see :meth:`PfDoa._jump_test`
  (``jump_probability`` per observation);
* optionally (off by default; measured without and with the noise-share correction, and with
  the spread reported from the cloud's part, and not kept: docs/estimator-study.md,
  "Defensive proposals"), without odometry, a defensive proposal: every step
  ``defensive_share`` of the particles are drawn from the observation's likelihood over a
  grid, weighted as the posterior of the same jump prior (:mod:`pfdoa.estimators.proposal`);
  the estimate is the whole mixture's, the reported spread the cloud's part
  (:meth:`PfDoa._report_weights`);
* the site's path-loss exponent, raised to the physical minimum ``MIN_EXPONENT`` = 1.6
  (a lower fit is a poorly conditioned calibration, not a property of the radio); for such
  a site the exponent is also a per-particle unknown (1-sigma 0.3 above the minimum);
* optional per-particle path-loss exponent (``exponent_spread``) and the paper's DOA term
  (``doa_weight``; the DOA is a function of the same RSS differences, so it adds no
  information and is off by default);
* estimate: weighted mean (``estimate="max"``: max-weight particle); sigma: particle
  spread; ``r95`` and ``cov``: the particles' 95 % radius and second moments about the
  estimate, narrowed by the RSS noise's share of the online noise estimate, which also
  holds the cloud's own spread (``spread_correction``, :class:`NoiseShare`), and widened by
  the correction measured across the site's calibration traces where it has one
  (``r95_scale``, ``cov_scale`` and their ``_odometry`` pair:
  :func:`pfdoa.calibrate.learn_uncertainty`), else online for the residuals' correlation
  in time (:class:`ResidualCorrelation`); ``lost``: the recent evidence has fallen well
  below its running level.

Both filters preallocate every per-particle array at construction: ``step`` does not grow
memory and keeps array identities.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from pfdoa.doa import DoaSmoother, doa_from_gradient
from pfdoa.estimators.base import CHI2_2DOF_95, Estimate, Observation, Odometry
from pfdoa.estimators.common import dt_between, gain_option
from pfdoa.estimators.gain import GainOption
from pfdoa.estimators.particles import ParticleFilterBase
from pfdoa.estimators.proposal import DefensiveProposal
from pfdoa.radio import squared_distances
from pfdoa.radiomap import MapLookup, parse_radio_map

# Physical range of the path-loss exponent the filter uses. The lowest indoor values reported
# are ~1.6 (in-building line of sight, waveguiding corridors: Rappaport, Wireless
# Communications, Table 4.2). A site fit below that comes from a poorly conditioned
# calibration (small area, noisy or lagging readings bias the fitted slope towards zero) and
# would make the filter read every RSS difference as a large distance ratio.
MIN_EXPONENT = 1.6
# Such a site's exponent is not known: each particle then carries its own, drawn with at least
# this 1-sigma around MIN_EXPONENT (clipped there), as ``exponent_spread`` does on request.
UNRELIABLE_EXPONENT_SPREAD = 0.3
MAX_EXPONENT = 8.0
# Jump (kidnap) handling, see PfDoa._jump_test.
JUMP_GATE = 1.0  # nats per anchor below the running evidence before the test runs
EVIDENCE_RATE = 0.05  # running average rate of the per-anchor log evidence
LOST_RATE = 0.3  # short average of the same evidence: below the running one by JUMP_GATE = lost
CANDIDATES = 1000  # uniform candidates for the test and the reset
POWER_MIN_ANCHORS = 4  # observations that teach the transmitter's power (PowerTracker)
# Online RSS noise scale (adapt_sigma): bounds in dB and averaging rate per observation.
SIGMA_RSS_MIN = 1.0  # below the 1 dB RSSI quantisation plus model error it means nothing
SIGMA_RSS_MAX = 20.0
SIGMA_RATE = 0.1
TWO_PI = 2.0 * math.pi
# Below this mean resultant length the headings are nearly uniform: not shrunk (_roughen_heading).
HEADING_MEAN_MIN_R = 0.1
# With shadowing_db, the particles' spread keeps at least this share of the online noise.
MIN_NOISE_SHARE = 0.1
_NORMAL = NormalDist()  # the leaps' threshold on the pool's standard normals (PfDoa._leap)


class ResidualCorrelation:
    """Lag-1 autocorrelation of the centred posterior-mean RSS residuals, averaged online.

    The filter treats successive observations as independent; real rooms are not (the same
    wall shadows an anchor for as long as the target stays near it: on the development
    sites rho = 0.3-0.9). Averaging n such AR(1) errors leaves (1 + rho) / (1 - rho) times
    the variance the filter assumes, so the reported spread is widened by the square root
    of that. Only the report uses it: the filter itself is unchanged, so there is no
    feedback (a tempering of the likelihood by an online rho proved unstable). Used only in
    a motion mode for which the site has no measured factors (``r95_scale`` / ``cov_scale``,
    their ``_odometry`` pair): those replace this widening (``PfDoa._uncertainty_scale``).
    """

    RATE = 0.05
    MAX_RHO = 0.95

    def __init__(self, n: int) -> None:
        self.prev = np.zeros(n)
        self.cur = np.zeros(n)
        self.prev_mask = np.zeros(n, dtype=bool)
        self.reset()

    def reset(self) -> None:
        self.prev_mask[:] = False
        self.prev_full = False
        self.prev_sq = 0.0
        self.c01 = 0.0
        self.c00 = 0.0

    def push(self, residual: np.ndarray, mask: np.ndarray, count: int) -> None:
        """residual: offset-free RSS minus the model, posterior mean (any value where ~mask;
        its sign does not matter)."""
        cur = self.cur
        full = count == mask.size
        if full:  # the common case, without masks
            np.subtract(residual, float(residual.sum()) / count, out=cur)
            aa = float(np.dot(cur, cur))
            if self.prev_full:
                self._update(float(np.dot(cur, self.prev)), aa, self.prev_sq)
            elif self.prev_mask.any():
                a, b = cur[self.prev_mask], self.prev[self.prev_mask]
                self._update(float(np.dot(a, b)), float(np.dot(a, a)), float(np.dot(b, b)))
            self.prev_mask[:] = True
        else:
            np.multiply(residual, mask, out=cur)
            cur -= float(cur.sum()) / count
            both = mask & self.prev_mask
            a, b = cur[both], self.prev[both]
            if a.size >= 2:
                self._update(float(np.dot(a, b)), float(np.dot(a, a)), float(np.dot(b, b)))
            self.prev_mask[:] = mask
            aa = 0.0
        self.prev, self.cur = cur, self.prev
        self.prev_full, self.prev_sq = full, aa

    def _update(self, ab: float, aa: float, bb: float) -> None:
        self.c01 += self.RATE * (ab - self.c01)
        self.c00 += self.RATE * (0.5 * (aa + bb) - self.c00)

    @property
    def rho(self) -> float:
        return min(max(self.c01 / self.c00, 0.0), self.MAX_RHO) if self.c00 > 0.0 else 0.0

    def inflation(self) -> float:
        rho = self.rho
        return math.sqrt((1.0 + rho) / (1.0 - rho))


class NoiseShare:
    """How much of the online noise estimate is RSS noise, not the cloud's own spread.

    ``adapt_sigma`` sets the noise scale from the prior-predictive residual: the RSS noise
    variance plus the spread of the predicted cloud's model RSS, so where the model is right
    the filter's posterior, and the spread it reports, are too wide (Dataset 0 at 2 dB without
    odometry: 2.87 dB median). The same residual power weighted by the posterior instead
    (each particle's residual after the update) is close to the noise variance on a right
    model (the fit to the position takes two degrees of freedom, the posterior's spread
    gives most of them back: ~2.2 dB for a true 2 dB). The reported spread is scaled by the
    ratio of the two running estimates (never above 1): the filter, which keeps the wider
    noise as its robustness to a wrong model, is unchanged. Where the misfit dominates the
    residual the two differ less (median variance ratio: simulation 0.6-0.8, the robot
    0.67-0.75, philotuxo 0.86, kolakowski 0.94); the factors measured across runs
    (:func:`pfdoa.calibrate.learn_uncertainty`) are learnt with this correction on.
    """

    def __init__(self, sigma0: float) -> None:
        self.sigma0 = sigma0
        self.reset()

    def reset(self) -> None:
        self.var = self.sigma0 * self.sigma0

    def push(self, var: float) -> None:
        """Posterior-weighted residual power per degree of freedom of one observation (dB^2),
        averaged as ``adapt_sigma`` averages the prior-predictive one (rate, burst limit)."""
        s2 = self.var
        self.var = s2 + SIGMA_RATE * (min(var, 4.0 * s2) - s2)

    def variance_ratio(self, sigma_rss: float) -> float:
        """Factor on the reported covariance (its square root on r95), in (0, 1]."""
        s2 = max(self.var, SIGMA_RSS_MIN * SIGMA_RSS_MIN)
        return min(s2 / (sigma_rss * sigma_rss), 1.0)


class PowerTracker:
    """The transmitter's power relative to the site's A (dB), learnt online.

    The differential likelihood ignores the mean residual over the anchors because the
    transmitter's power is unknown (another device, another antenna, its orientation). But
    it is one number that changes slowly, and every observation with enough anchors shows
    it: the mean of its posterior-mean residual. Its running average is the offset, its running
    spread the 1-sigma of a Gaussian prior on the next observation's power (exactly
    ``power_sigma``'s partial centring, around the learnt value). The prior matters most
    when few anchors report: with three, the differential RSS alone leaves the position
    ambiguous along a curve. Learnt only from observations of ``POWER_MIN_ANCHORS`` or more
    anchors, whose position the differential part fixes, so that the prior does not learn
    from positions it chose itself.
    """

    RATE = 0.05  # running average weight once warm (1/k for the first k updates)
    WARM = 10  # updates before the prior is used
    MIN_SIGMA_DB = 0.5

    def reset(self) -> None:
        self.offset = 0.0
        self.var = 0.0
        self.updates = 0

    def __init__(self) -> None:
        self.reset()

    @property
    def ready(self) -> bool:
        return self.updates >= self.WARM

    @property
    def sigma(self) -> float:
        return max(math.sqrt(self.var), self.MIN_SIGMA_DB)

    def push(self, mean_residual: float) -> None:
        """The mean posterior residual of one observation, relative to the current offset."""
        self.updates += 1
        rate = max(self.RATE, 1.0 / self.updates)
        self.offset += rate * mean_residual
        self.var += rate * (mean_residual * mean_residual - self.var)


def _pair(k: float | None, kc: float | None, name: str, name_c: str) -> tuple[float, float] | None:
    if (k is None) != (kc is None):
        from pfdoa.errors import ConfigError

        raise ConfigError("estimator", name if k is None else name_c, f"{name} and {name_c} come together")
    return None if k is None or kc is None else (float(k), float(kc))


def _degraded(count: int) -> str:
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
        if doa is None:
            extra["degraded"] = _degraded(p.count) if op is None else "zero gradient, prediction only"
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


class PfDoa(ParticleFilterBase):
    name = "pf-doa"
    OPTIONS = frozenset({"particles", "window", "sigma_doa", "sigma_rss", "estimate", "margin", "speed",
                         "odometry_noise", "doa_weight", "tail_dof", "exponent_spread", "resample_threshold",
                         "min_anchors", "velocity_time", "adapt_sigma", "power_sigma",
                         "jump_probability", "speed_range", "learn_power", "r95_scale", "cov_scale",
                         "r95_scale_odometry", "cov_scale_odometry", "spread_correction", "defensive_share",
                         "defensive_candidates", "radio_map", "shadowing_db", "estimate_gain",
                         "estimate_gain_odometry", "residual_rho", "residual_rho_odometry", "leap_rate", "leap_m"})

    def __init__(self, site, *, rng: np.random.Generator | None = None, particles: int = 200,
                 window: int = 5, sigma_doa: float = 0.3, sigma_rss: float = 4.0, estimate: str = "mean",
                 margin: float | None = None, speed: float = 0.3, odometry_noise: float = 0.2,
                 doa_weight: float = 0.0, tail_dof: float = 1e6, exponent_spread: float = 0.0,
                 resample_threshold: float = 0.5, min_anchors: int = 3, velocity_time: float = 5.0,
                 adapt_sigma: bool = True, power_sigma: float = 0.0, jump_probability: float = 0.05,
                 speed_range: float = 5.0, learn_power: bool = True, r95_scale: float | None = None,
                 cov_scale: float | None = None, r95_scale_odometry: float | None = None,
                 cov_scale_odometry: float | None = None, spread_correction: bool = True,
                 defensive_share: float = 0.0, defensive_candidates: int = 200, radio_map: bool = True,
                 shadowing_db: float = 0.0, estimate_gain: GainOption = 1.0, estimate_gain_odometry: GainOption = 1.0,
                 residual_rho: float = 0.0, residual_rho_odometry: float = 0.0, leap_rate: float = 0.1,
                 leap_m: float = 2.5, **_: object) -> None:
        super().__init__(site, rng, particles, margin, speed, odometry_noise, min_anchors, velocity_time,
                         speed_range)
        # The site's [radio_map] (pfdoa.radiomap: residuals of the calibration trace), added
        # to the model RSS; the table was validated when the site was loaded.
        table = site.sections.get("radio_map") if radio_map else None
        self._map = (MapLookup(parse_radio_map(table, site.anchor_ids), site.anchor_ids, particles)
                     if table is not None else None)
        # Uncertainty factors measured on the calibration trace (both of a mode, or none).
        self._scales = _pair(r95_scale, cov_scale, "r95_scale", "cov_scale")
        self._scales_odometry = _pair(r95_scale_odometry, cov_scale_odometry, "r95_scale_odometry",
                                      "cov_scale_odometry")
        # The estimate's gain about the search box's centre (box_centre), fitted with the factors.
        self._gains = (gain_option("estimate_gain", estimate_gain),
                       gain_option("estimate_gain_odometry", estimate_gain_odometry))
        self.box_centre = (0.5 * float(self.lo[0] + self.hi[0]), 0.5 * float(self.lo[1] + self.hi[1]))
        self.learn_power = learn_power
        self.sigma_doa = sigma_doa
        self.jump_probability = jump_probability
        self.sigma_rss0 = sigma_rss
        self.adapt_sigma = adapt_sigma
        self.power_sigma = math.inf if power_sigma == 0.0 else power_sigma
        self.estimate = estimate
        self.doa_weight = doa_weight
        self.nu = tail_dof
        self.gaussian = tail_dof >= 1e5
        # The residual power is used as the scale^2 as is, not shrunk by the Student-t
        # variance factor (nu - 2) / nu: the prior-predictive residual underestimates the
        # noise when errors are correlated in time (the prior follows them), and the study
        # (docs/estimator-study.md) measured the unshrunk scale better on real traces.
        self._var_to_scale = 1.0
        self.exponent_spread = exponent_spread
        self.resample_threshold = resample_threshold
        self.smoother = DoaSmoother(window)
        n, na = particles, self.n_anchors
        # A share of the particles drawn from each observation's likelihood (proposal.py).
        self.proposal = (DefensiveProposal(n, defensive_share, defensive_candidates, na)
                         if defensive_share > 0.0 else None)
        self.correlation = ResidualCorrelation(na)
        # With measured factors for both motion modes the online widening is never reported
        # (_uncertainty_scale), so its per-step update (~5 us of the step) is skipped.
        self._track_correlation = self._scales is None or self._scales_odometry is None
        self.power = PowerTracker()
        # Report-only: scale r95/cov by the RSS noise's share of the online noise estimate.
        self.noise_share = NoiseShare(sigma_rss) if spread_correction and adapt_sigma else None
        self._resid = np.empty(na)  # posterior-mean residual of the latest observation
        # The particles the proposal drew at this step (1.0, else 0.0; carried through this
        # step's resampling) and the weights the spread is then reported from (_report_weights).
        self._drawn = np.zeros(n)
        self._wc = np.empty(n)
        self._mixed = False
        self.exponent = np.empty(n)  # per-particle path-loss exponent
        self.gain = np.empty((n, 1))  # -5 * exponent: model RSS = A + gain * log10(d^2)
        self.E = np.empty((n, na))
        self.R = np.empty((n, na))
        self.ll = np.empty(n)
        self.logw = np.empty(n)
        self.g = np.empty((n, 2))
        self.err = np.empty(n)
        self.rssi_c = np.empty(na)
        self._ones = np.ones(na)
        self._centres: dict[bytes, tuple[float, np.ndarray]] = {}  # per anchor mask
        # Regularisation bandwidth factor for d = 2 (Silverman: h = (4 / (N (d + 2)))^(1/(d + 4))).
        self._h = (4.0 / (n * 4.0)) ** (1.0 / 6.0)
        self.shadowing_db = shadowing_db
        # AR(1) residuals (without, with odometry): each particle's previous centred residual,
        # carried through resampling; zero at the start, for re-seeded particles and for an
        # anchor that was missing. _cur_res is scratch (copies, not swaps: arrays keep identity).
        self._rhos = (float(residual_rho), float(residual_rho_odometry))
        self._whiten = max(self._rhos) > 0.0
        self._prev_res = np.zeros((n, na))
        self._cur_res = np.empty((n, na))
        self._floor_mask = np.zeros(na, dtype=bool)  # the anchors of the latest update (shadowing_db)
        self.leap_rate = float(leap_rate)
        self.leap_m = float(leap_m)
        self._leapt = np.zeros(n, dtype=bool)  # which particles leapt at this step (_leap) ...
        self._n_leapt = 0  # ... and how many
        self._leap_dt = math.nan  # the interval _leap_z was computed for
        self._leap_z = math.inf
        self.reset()

    def reset(self) -> None:
        self._reset_particles()
        n_site = self.model.path_loss_exponent
        n0 = self._n0 = min(max(n_site, MIN_EXPONENT), MAX_EXPONENT)
        spread = self.exponent_spread
        if n_site < MIN_EXPONENT:
            spread = max(spread, UNRELIABLE_EXPONENT_SPREAD)
        self._n_spread = spread
        if spread > 0.0:
            self.exponent[:] = n0 + spread * self.rng.standard_normal(self.N)
            np.clip(self.exponent, MIN_EXPONENT, MAX_EXPONENT, out=self.exponent)
        else:
            self.exponent.fill(n0)
        np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
        if self.proposal is not None:
            self.proposal.reset(self, (MIN_EXPONENT, MAX_EXPONENT))
        self.logw.fill(-math.log(self.N))
        self.smoother.reset()
        self.t_prev: float | None = None
        self._log_slow: float | None = None
        self._log_fast: float | None = None
        self._is_lost = False
        self.correlation.reset()
        self.power.reset()
        if self.noise_share is not None:
            self.noise_share.reset()
        self.sigma_rss = self.sigma_rss0
        self._prev_res.fill(0.0)
        self._n_leapt = 0

    # -- measurement model ----------------------------------------------------------------
    def _gamma(self, count: int) -> float:
        """Share gamma of the mean residual to remove, for a Gaussian prior of 1-sigma
        ``power_sigma`` on the transmitter's A around the site's value.

        Marginalising that offset from ``e = RSS - model`` gives the quadratic form
        ``|e|^2 - beta/n (sum e)^2`` with ``beta = n / (n + sigma_rss^2 / power_sigma^2)``,
        which equals ``|e - gamma mean(e)|^2`` for ``gamma = 1 - sqrt(1 - beta)``. An
        unknown A (power_sigma = inf) gives gamma = 1: the differential RSS.
        """
        ps = self.power.sigma if self.learn_power and self.power.ready else self.power_sigma
        if math.isinf(ps):
            return 1.0
        beta = count / (count + (self.sigma_rss / ps) ** 2)
        return 1.0 - math.sqrt(1.0 - beta)

    def _centre_for(self, mask: np.ndarray, count: int) -> tuple[float, np.ndarray]:
        """(gamma, C): ``e @ C`` is the partially centred residual over the present anchors
        with zero columns for the missing ones, so a missing anchor costs nothing extra in
        the hot path. Cached per mask (and recomputed when gamma moves)."""
        gamma = self._gamma(count)
        key = mask.tobytes()
        hit = self._centres.get(key)
        # gamma follows the online noise and power estimates; a 1 % change is immaterial
        # and recomputing the matrix every step would cost a tenth of the step.
        if hit is not None and abs(hit[0] - gamma) <= 0.01:
            return hit
        m = mask.astype(float)
        c = (np.diag(m) - (gamma / count) * np.outer(m, m))
        if len(self._centres) >= 256:
            self._centres.clear()
        self._centres[key] = (gamma, c)
        return gamma, c

    def _log_likelihood(self, rssi_c: np.ndarray, mask: np.ndarray, count: int) -> np.ndarray:
        """Log-likelihood of the (partially) centred RSS residual per particle.

        rssi_c: offset-free RSS minus A (the model terms below exclude A), any finite value
        where an anchor is missing."""
        E = self.E
        np.multiply(self.dist.log10(self.xy), self.gain, out=E)
        gamma, centre = self._centre_for(mask, count)
        E -= rssi_c
        if self._map is not None:
            E += self._map.into(self.xy)
        res = np.matmul(E, centre, out=self.R)
        if self._whiten:
            # The innovation r_t - rho r_(t-1) is what is independent in time; the online
            # noise scale below then measures its power.
            rho = self._rhos[1] if self._odometry_seen else self._rhos[0]
            prev, cur = self._prev_res, self._cur_res
            np.copyto(cur, res)
            if rho > 0.0:
                prev *= rho
                res -= prev
            np.copyto(prev, cur)
        ones = self._ones
        np.multiply(res, res, out=res)
        ll = self.ll
        if self.adapt_sigma:
            # Prior-predictive residual power per degree of freedom (centring removes one):
            # the RSS noise variance plus the cloud's own spread, so it errs on the wide
            # side. A burst can at most quadruple it in one step.
            np.matmul(res, ones, out=ll)
            var = self._residual_power(ll) / max(count - gamma, 1.0)
            s2 = self.sigma_rss * self.sigma_rss
            s2 += SIGMA_RATE * (min(var * self._var_to_scale, 4.0 * s2) - s2)
            self.sigma_rss = min(max(math.sqrt(max(s2, 0.0)), SIGMA_RSS_MIN), SIGMA_RSS_MAX)
        s2 = self.sigma_rss * self.sigma_rss
        if self.gaussian:
            if not self.adapt_sigma:  # else ll holds the sums of squares already
                np.matmul(res, ones, out=ll)
            ll *= -0.5 / s2
        else:
            res *= 1.0 / (self.nu * s2)
            np.log1p(res, out=res)
            np.matmul(res, ones, out=ll)
            ll *= -0.5 * (self.nu + 1.0)
        return ll

    def _point_log_likelihood(self, points: np.ndarray, gain: np.ndarray, rssi_c: np.ndarray,
                              mask: np.ndarray) -> np.ndarray:
        """The same likelihood as the hot path for arbitrary points (allocates; rare use)."""
        idx = np.flatnonzero(mask)
        res = self._point_residual(points, gain, rssi_c, idx)
        res -= self._gamma(idx.size) * res.mean(axis=1, keepdims=True)
        z = res * res / (self.sigma_rss * self.sigma_rss)
        if self.gaussian:
            return -0.5 * z.sum(axis=1)
        return -0.5 * (self.nu + 1.0) * np.log1p(z / self.nu).sum(axis=1)

    def _point_residual(self, points: np.ndarray, gain: np.ndarray, rssi_c: np.ndarray,
                        idx: np.ndarray) -> np.ndarray:
        """Model RSS (with the radio map) less the readings at arbitrary points, for the anchors
        ``idx``, not centred: (points, idx.size) (allocates; rare use)."""
        d2 = squared_distances(points, self.anchors[idx], self.heights[idx])
        res = gain[:, None] * np.log10(np.maximum(d2, self.dist.dmin2)) - rssi_c[idx]
        if self._map is not None:
            res += self._map.at(points)[:, idx]
        return res

    def _doa_term(self, op: np.ndarray, doa: float) -> None:
        """The paper's DOA factor (wrapped Gaussian), weighted by ``doa_weight``."""
        g = self.g
        np.matmul(self.dist.out, op.T, out=g)  # dist.out holds log10(d^2); direction is -g
        e = np.arctan2(-g[:, 1], -g[:, 0], out=self.err)
        e -= doa - math.pi
        np.remainder(e, TWO_PI, out=e)
        e -= math.pi
        np.multiply(e, e, out=e)
        e *= -0.5 * self.doa_weight / (self.sigma_doa * self.sigma_doa)
        self.logw += e

    # -- the filter step ------------------------------------------------------------------
    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        dt = dt_between(self.t_prev, obs.t)
        self.t_prev = obs.t
        self._leap(dt if odom is None else 0.0)  # with odometry nothing leaps: no interval to leap in
        self._move(dt, odom)
        extra: dict = {}
        self._mixed = False
        op = self.fit.operator(p.mask) if p.count >= self.min_anchors else None
        if op is None:
            extra["degraded"] = _degraded(p.count)
            mx, my, sig = self._mean_and_sigma()
            return self._estimate(obs.t, mx, my, sig, self.smoother.value, p.ids, extra)
        if self.shadowing_db > 0.0:
            np.copyto(self._floor_mask, p.mask)
        rssi = p.rssi if p.count == self.n_anchors else np.where(p.mask, p.rssi, 0.0)
        doa = self.smoother.push(doa_from_gradient(op @ rssi))
        # Offset-free RSS minus A: the site's A, plus the transmitter's own offset once learnt.
        np.subtract(rssi, self.model.rssi_at_1m_dbm + self.power.offset, out=self.rssi_c)
        self.logw += self._log_likelihood(self.rssi_c, p.mask, p.count)
        if self.doa_weight > 0.0 and doa is not None:
            self._doa_term(op, doa)
        top = float(np.maximum.reduce(self.logw))
        jump = None
        if not math.isfinite(top):
            self._recover()
            self._prev_res.fill(0.0)
            self.logw.fill(-math.log(self.N))
            extra["recovered"] = True
            self._is_lost = True
        else:
            np.subtract(self.logw, top, out=self.w)
            np.exp(self.w, out=self.w)
            total = float(np.add.reduce(self.w))
            self.w *= 1.0 / total
            # logw was normalised, so top + log(total) is the log of the mean likelihood of
            # this observation under the prediction (the evidence): the jump test's input.
            log_evidence = top + math.log(total)
            self.logw -= log_evidence
            self._track_evidence(log_evidence / p.count)
            self._learn_from_residual(p.mask, p.count)
            jump = self._jump_test(log_evidence, p.count, self.rssi_c, p.mask)
            if jump is None and self.proposal is not None and odom is None:
                out = self.proposal.mix(self, log_evidence, self.rssi_c, p.mask, p.count)
                self._drawn.fill(0.0)
                self._drawn[out] = 1.0
                self._prev_res[out] = 0.0
                self._mixed = True
        mode = None
        if jump is not None:
            k = extra["jumped"] = self._jump(jump)
            # The posterior is now bimodal (old cloud, re-seeded part): report the mean of
            # the heavier mode, not a point between the two where there is no mass.
            mode = slice(0, k) if 2 * k >= self.N else slice(k, self.N)
        elif 1.0 / float(np.dot(self.w, self.w)) < self.resample_threshold * self.N:
            _, _, sig = self._mean_and_sigma()
            idx = self._resample((self.exponent, self._drawn) if self._mixed else (self.exponent,))
            self._carry_residuals(idx)
            self.logw.fill(-math.log(self.N))
            self._roughen(sig)
        ex, ey, sig = self._best() if self.estimate == "max" else self._mean_and_sigma()
        if mode is not None and self.estimate == "mean":
            ex, ey = (float(v) for v in self.xy[mode].mean(axis=0))
        extra["sigma_rss"] = self.sigma_rss
        return self._estimate(obs.t, ex, ey, sig, doa, p.ids, extra)

    def _estimate(self, t: float, ex: float, ey: float, sig: float, doa, ids, extra: dict) -> Estimate:
        """The particles' estimate moved towards the search box's centre by the gain measured
        with the uncertainty factors (``estimate_gain``: centre + G (estimate - centre), G a
        symmetric matrix, the least-squares fit of the calibration runs' truth on the estimate,
        :func:`pfdoa.calibrate.uncertainty_from`): where the readings say little (a room where
        RSS barely follows distance) the filter's confident estimates overshoot, and the
        calibration runs measure by how much. r95 and cov stay the particles' about their own
        estimate: the factors were measured on the moved estimate's errors."""
        est = super()._estimate(t, ex, ey, sig, doa, ids, extra)
        g = self._gains[1] if self._odometry_seen else self._gains[0]
        if not g.identity:
            cx, cy = self.box_centre
            dx, dy = g.apply(ex - cx, ey - cy)
            est.x = cx + dx
            est.y = cy + dy
        return est

    def _learn_from_residual(self, mask: np.ndarray, count: int) -> None:
        """The posterior-mean residual of this observation (offset-free RSS minus the model,
        weighted over the updated particles) feeds the reported spread's correlation factor
        and the transmitter-power tracker, its posterior-weighted power the reported spread's
        noise share; never the particles' weights directly."""
        if self.noise_share is not None:  # first: the power update below may move gamma
            self.noise_share.push(self._posterior_residual_power(mask, count))
        r = self._resid
        # E holds model - RSS for every particle (_log_likelihood): r is minus the residual,
        # which the correlation does not mind.
        np.dot(self.w, self.E, out=r)
        if self._track_correlation:
            self.correlation.push(r, mask, count)
        if self.learn_power and count >= POWER_MIN_ANCHORS and not self._is_lost:
            self.power.push(-float(np.dot(r, mask)) / count)

    def _posterior_residual_power(self, mask: np.ndarray, count: int) -> float:
        """The residual power per degree of freedom that ``adapt_sigma`` measures, weighted by
        the posterior (the updated weights) instead of the prior."""
        # The centring this step's likelihood used, read only: the cache's gamma must not
        # follow the noise update made since, or the next step's weights would change.
        gamma, centre = self._centres[mask.tobytes()]
        if self.gaussian:  # ll = -|centred residual|^2 / (2 sigma_rss^2), from this step
            ss = float(np.dot(self.w, self.ll)) * (-2.0 * self.sigma_rss * self.sigma_rss)
        else:  # ll is no longer quadratic: recompute the centred residuals
            res = np.matmul(self.E, centre, out=self.R)
            np.multiply(res, res, out=res)
            np.matmul(res, self._ones, out=self.err)
            ss = float(np.dot(self.w, self.err))
        return ss / max(count - gamma, 1.0)

    def _report_weights(self) -> np.ndarray:
        """After a defensive mix, the reported spread is the cloud's part of the posterior
        (this step's drawn particles, or their copies after resampling, left out and the rest
        renormalised): the posterior given no jump at this step. The estimate stays the whole
        mixture's. Where the likelihood is flat the uniform part holds up to
        ``jump_probability`` of the mass, spread over the whole area, which the 95 % radius
        would reach into (docs/estimator-study.md, "Defensive proposals"). When the drawn part holds most of
        the mass the filter is moving there, and the whole mixture is reported."""
        if not self._mixed:
            return self.w
        wc = self._wc
        np.subtract(1.0, self._drawn, out=wc)
        wc *= self.w
        total = float(np.add.reduce(wc))
        if total < 0.5:
            return self.w
        wc *= 1.0 / total
        return wc

    def _cov_floor(self, ex: float, ey: float) -> tuple[float, float, float] | None:
        """The position error that a time-constant, place-dependent deviation of each
        anchor's RSS from the model (``shadowing_db`` 1-sigma, independent between anchors)
        causes at (ex, ey) through the geometry of the latest update's anchors:
        sigma_b^2 (J_c^T J_c)^-1, J_c the centred Jacobian of the model RSS (the filter uses
        the differential RSS). The readings cannot average it out, so it is added to the
        reported covariance. None when off or the geometry gives no bound."""
        if self.shadowing_db <= 0.0:
            return None
        m = self._floor_mask
        if int(np.count_nonzero(m)) < 3:
            return None
        d = np.subtract((ex, ey), self.anchors[m])
        d2 = np.maximum(np.einsum("ij,ij->i", d, d) + self.heights[m] ** 2, self.model.min_distance_m ** 2)
        g = d * (-10.0 * self._n0 / math.log(10.0) / d2)[:, None]
        g -= g.mean(axis=0)
        a, b, c = float(np.dot(g[:, 0], g[:, 0])), float(np.dot(g[:, 0], g[:, 1])), float(np.dot(g[:, 1], g[:, 1]))
        det = a * c - b * b
        if not det > 1e-12 * (a * c + 1e-300):
            return None
        v = self.shadowing_db * self.shadowing_db / det
        return c * v, -b * v, a * v

    def _uncertainty_scale(self) -> tuple[float, float]:
        """The correction measured across the site's calibration traces in this motion mode
        (``r95_scale`` / ``cov_scale``, ``*_odometry`` with odometry:
        :func:`pfdoa.calibrate.learn_uncertainty`), else the online widening for the
        residuals' correlation in time (:class:`ResidualCorrelation`); times the RSS noise's
        share of the online noise estimate (:class:`NoiseShare`).

        A measured factor replaces the online widening rather than multiplying it: both
        correct the same overconfidence, and across runs the online rho does not follow the
        error (robot development runs: the run with the lowest rho, 0.32-0.38 against
        0.46-0.69, has the largest error to spread ratio), so with it the factor measured on
        some runs held 76-77 % of another run's errors within r95; without it, 89-92 %
        (docs/estimator-study.md, "Measured factors replace the online correlation
        widening")."""
        learnt = self._learnt_scales()
        g, g2 = self._online_scale(learnt is None)
        if learnt is None:
            return g, g2
        return learnt[0] * g, learnt[1] * g2

    def _learnt_scales(self) -> tuple[float, float] | None:
        return self._scales_odometry if self._odometry_seen else self._scales

    def _online_scale(self, widen: bool) -> tuple[float, float]:
        """(r95, cov) factors of the online corrections: the correlation widening when
        ``widen``, times the RSS noise's share of the online noise estimate."""
        g = self.correlation.inflation() if widen else 1.0
        g2 = g * g
        if self.noise_share is not None:
            g2 *= self.noise_share.variance_ratio(self.sigma_rss)
            g = math.sqrt(g2)
        return g, g2

    def _reported_uncertainty(self, ex: float, ey: float, r95: float, cov: tuple[float, float, float]
                              ) -> tuple[float, tuple[float, float, float]]:
        """With ``shadowing_db``: the particles' spread, scaled online, holds only the share
        of the online RSS noise that is not the walls' (sigma_rss^2 - sigma_b^2 of it: the
        filter took the walls for noise that averages out), plus the walls' own position
        error (:meth:`_cov_floor`), which does not average out; a measured factor then
        multiplies the whole, as it was measured on the whole."""
        floor = self._cov_floor(ex, ey)
        if floor is None:
            return super()._reported_uncertainty(ex, ey, r95, cov)
        learnt = self._learnt_scales()
        g, g2 = self._online_scale(learnt is None)
        s2 = self.sigma_rss * self.sigma_rss
        g2 *= max(1.0 - self.shadowing_db * self.shadowing_db / s2, MIN_NOISE_SHARE)
        tr = (cov[0] + cov[2]) * g2  # the particles' share of the variance
        extra = floor[0] + floor[2]
        # r95 grows with the total variance, keeping the cloud's shape
        r95 = (r95 * math.sqrt(g2) * math.sqrt((tr + extra) / tr) if tr > 0.0
               else math.sqrt(CHI2_2DOF_95 * 0.5 * extra))
        cov = (cov[0] * g2 + floor[0], cov[1] * g2 + floor[1], cov[2] * g2 + floor[2])
        if learnt is not None:
            r95 *= learnt[0]
            cov = (cov[0] * learnt[1], cov[1] * learnt[1], cov[2] * learnt[1])
        return r95, cov

    def _track_evidence(self, per_anchor: float) -> None:
        """Lost: the recent evidence per anchor (short average) has fallen ``JUMP_GATE``
        nats below its running level, i.e. for several observations the cloud has explained
        the readings far worse than it used to."""
        fast = self._log_fast
        self._log_fast = per_anchor if fast is None else fast + LOST_RATE * (per_anchor - fast)
        slow = self._log_slow
        self._is_lost = slow is not None and self._log_fast < slow - JUMP_GATE

    def _lost(self) -> bool | None:
        return self._is_lost

    def _jump_test(self, log_evidence: float, count: int, rssi_c: np.ndarray, mask: np.ndarray):
        """Has the target jumped away from the cloud (kidnap, bad start, long outage)?

        The motion prior is taken as ``(1 - eps)`` * (the cloud) + ``eps`` * (uniform over
        the area). The posterior share of the uniform part is
        ``eps L_u / (eps L_u + (1 - eps) L_c)``, with ``L_c`` the evidence of the cloud and
        ``L_u`` that of uniform candidates. Evaluating ``L_u`` costs ~1000 likelihoods, so
        it is only done when the cloud's per-anchor evidence falls ``JUMP_GATE`` nats below
        its running average; otherwise the share is negligible (L_u << L_c while tracking).
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
        expo = self._n0 + self._n_spread * self.rng.standard_normal(c)
        np.clip(expo, MIN_EXPONENT, MAX_EXPONENT, out=expo)
        ll = self._point_log_likelihood(pts, -5.0 * expo, rssi_c, mask)
        top = float(ll.max())
        log_u = top + math.log(float(np.exp(ll - top).mean()))
        eps = self.jump_probability
        odds = (1.0 - eps) / eps * math.exp(min(log_evidence - log_u, 700.0))
        share = 1.0 / (1.0 + odds)
        if share < 1.0 / self.N:
            self._log_slow = slow + EVIDENCE_RATE * (per_anchor - slow)
            return None
        return share, pts, expo, ll

    def _jump(self, jump) -> int:
        """Resample the cloud and replace a ``share`` of it by draws from the candidates in
        proportion to their likelihood (sensor resetting, Lenser & Veloso 2000)."""
        share, pts, expo, ll = jump
        _, _, sig = self._mean_and_sigma()
        self._carry_residuals(self._resample((self.exponent,)))
        self._roughen(sig)
        k = min(self.N, int(round(share * self.N)))
        if k:
            self._prev_res[:k] = 0.0  # a re-seeded particle has no history
            prob = np.exp(ll - ll.max())
            pick = self.rng.choice(pts.shape[0], size=k, p=prob / prob.sum())
            self.xy[:k] = pts[pick]
            self.exponent[:k] = expo[pick]
            self.heading[:k] = self.rng.uniform(-np.pi, np.pi, k)
            self._seed_motion(slice(0, k), k)
            np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
        self.logw.fill(-math.log(self.N))
        return k

    def _leap(self, dt: float) -> None:
        """Each particle leaps with probability 1 - exp(-leap_rate dt): displaced by 1-sigma
        ``leap_m`` per axis and started again from rest. The motion prior is then a mixture
        of the speed prior and these leaps, so the cloud keeps a few particles where the
        target would be had it moved further than the speed prior allows; when it has (a
        walker setting off after a pause, while the cloud narrowed about the still target
        and its velocities decayed), those particles take the weight and the cloud catches
        up in a step or two instead of drifting after it. Not with odometry, which measures
        the motion (and leaps there cost accuracy: docs/estimator-study.md)."""
        self._n_leapt = 0
        if not (dt > 0.0 and self.leap_rate > 0.0):
            return
        if dt != self._leap_dt:  # the threshold is recomputed only when the interval changes
            p = -math.expm1(-self.leap_rate * dt)
            self._leap_dt = dt
            # The upper p-quantile, -inv_cdf(p): 1 - p would round to 1 for a tiny interval.
            self._leap_z = math.inf if not p > 0.0 else -math.inf if p >= 1.0 else -_NORMAL.inv_cdf(p)
        n = self.N
        # A particle leaps where its standard normal of the pool is above the (1 - p) quantile:
        # a Bernoulli(p) draw per particle at the pool's cost (NormalPool).
        np.greater(self.normals.take(n, self.rng), self._leap_z, out=self._leapt)
        idx = np.flatnonzero(self._leapt)
        m = idx.size
        if m == 0:
            return
        moved = self.xy[idx]
        moved += self.leap_m * self.normals.take(2 * m, self.rng).reshape(m, 2)
        self.xy[idx] = moved  # clamped into the box by the motion step that follows
        if self.velocity_time > 0.0:
            self.vel[idx] = 0.0  # from rest: the motion step re-grows it (as good as a fresh draw)
        if self._whiten:
            self._prev_res[idx] = 0.0  # its previous residual was at another place
        self._n_leapt = m

    def _residual_power(self, ss: np.ndarray) -> float:
        """The prior-weighted mean of the particles' residual sums of squares ``ss``, for the
        online noise scale, without the particles that leapt at this step: their residuals
        say where the target is not, not how noisy its readings are (with them in, the scale
        grows and the filter trusts its readings less: Dataset 0 without odometry 0.363 ->
        0.418 m with 0.1 leaps of 2 m per second)."""
        total = float(np.dot(self.w, ss))
        if not self._n_leapt:
            return total
        leapt = self._leapt
        wl = self.w[leapt]
        kept = 1.0 - float(np.add.reduce(wl))
        if not kept > 1e-9:
            return total
        return (total - float(np.dot(wl, ss[leapt]))) / kept

    def _carry_residuals(self, idx: np.ndarray) -> None:
        """Each resampled particle takes its ancestor's previous residual (AR(1) whitening)."""
        if self._whiten:
            np.take(self._prev_res, idx, axis=0, out=self._cur_res)
            np.copyto(self._prev_res, self._cur_res)

    def _roughen(self, sigma: float) -> None:
        """Kernel jitter after resampling so duplicates spread (regularised PF). With
        odometry the heading is jittered too, and position and heading are first shrunk
        towards their means so that the jitter keeps the cloud's spread (Liu and West's
        kernel shrinkage; why only with odometry: the class doc)."""
        shrink = math.sqrt(1.0 - self._h * self._h) if self._odometry_seen else 1.0
        h = self._h * sigma / math.sqrt(2.0)
        if h > 0.0:
            if shrink < 1.0:
                m = np.dot(self.w, self.xy)  # the weights are uniform after resampling
                self.xy -= m
                self.xy *= shrink
                self.xy += m
            z = self.normals.take(2 * self.N, self.rng).reshape(self.N, 2)
            np.multiply(z, h, out=self.noise_xy)
            self.xy += self.noise_xy
            self._clamp()
        if self._odometry_seen:
            self._roughen_heading(shrink)
        if self.log_speed_range > 0.0:
            # let the speed scale wander (10 % per resampling) so it can follow the target
            np.multiply(self.normals.take(self.N, self.rng), 0.1, out=self.noise_1)
            np.exp(self.noise_1, out=self.noise_1)
            self.pspeed *= self.noise_1
            np.clip(self.pspeed, math.exp(self._log_speed_lo), math.exp(self._log_speed_hi), out=self.pspeed)
        if self._n_spread > 0.0:
            np.multiply(self.normals.take(self.N, self.rng), 0.1 * self._n_spread, out=self.noise_1)
            self.exponent += self.noise_1
            np.clip(self.exponent, MIN_EXPONENT, MAX_EXPONENT, out=self.exponent)
        np.multiply(self.exponent, -5.0, out=self.gain[:, 0])

    def _roughen_heading(self, shrink: float) -> None:
        """The heading's kernel jitter: the bandwidth factor times its circular spread,
        after shrinking each heading's deviation from the circular mean by ``shrink`` (not
        when the headings are nearly uniform, whose mean direction is noise)."""
        mean, r = self._circular_mean()  # the weights are uniform after resampling
        spread = math.sqrt(-2.0 * math.log(max(r, 1e-12)))
        if r > HEADING_MEAN_MIN_R:
            dev = self.noise_1
            np.subtract(self.heading, mean - math.pi, out=dev)
            np.remainder(dev, TWO_PI, out=dev)
            dev -= math.pi
            dev *= shrink
            np.add(dev, mean, out=self.heading)
        np.multiply(self.normals.take(self.N, self.rng), self._h * spread, out=self.noise_1)
        self.heading += self.noise_1
