"""``pf-doa``, the default estimator: a particle filter on the whole offset-free RSS vector.

Each observation (the RSS of the anchors that heard the beacon, offsets removed) updates N
particles (position, velocity, and with odometry heading):

* model (:mod:`pfdoa.estimators.pf_model`): the log-distance model in 3-D with the site's
  radio map; the residual centred over the anchors (the differential RSS), partly once the
  transmitter's power is learnt; a Gaussian of the online noise scale, weighted by how much
  the site's fitted slope says, and for a slow target tempered unless the observation
  surprises the cloud (:meth:`PfDoa._temper`);
* motion (:meth:`ParticleFilterBase._move`, :mod:`pfdoa.estimators.pf_motion`): odometry with
  proportional noise when given, else an Ornstein-Uhlenbeck velocity of a per-particle speed
  scale, with leaps; the search box reflects; resampling when the effective sample size falls
  below ``resample_threshold * N``, then kernel jitter;
* a jump test with sensor resetting (:meth:`PfDoa._jump_test`) for a target that left the
  cloud (kidnap, a long outage);
* uncertainty (:mod:`pfdoa.estimators.pf_uncertainty`): the cloud's spread plus the position
  error of the model's running misfit and the estimate's disagreement with the anchors'
  weighted centroid; the estimate is the posterior mean taken as a measurement of the cloud's
  covariance under a uniform prior over the search box, moved towards that centroid where
  the model's misfit persists; ``lost``.

docs/estimator.md explains each default with the measurement that chose it. Every
per-particle array is preallocated at construction: ``step`` does not grow memory.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.base import Estimate, Observation, Odometry
from pfdoa.estimators.common import add_reduce, dt_between
from pfdoa.estimators.particles import ParticleFilterBase
from pfdoa.estimators.pf_doa_paper import PaperPfDoa, degraded
from pfdoa.estimators.pf_model import (
    MAX_EXPONENT,
    MIN_EXPONENT,
    POWER_MIN_ANCHORS,
    MovingShare,
    NoiseScale,
    RssModel,
)
from pfdoa.estimators.pf_motion import Leaps, reflect_into, roughen
from pfdoa.estimators.pf_uncertainty import (
    CENTROID_POWER,
    STANDING_SHARE_MIN,
    CloudShare,
    Evidence,
    Lag,
    Misfit,
    centroid_cov,
    pulled_to_centroid,
    r95_of,
    report_cov,
    truncated_cov,
)
from pfdoa.estimators.wcl import Centroid
from pfdoa.radiomap import MapLookup, parse_radio_map

__all__ = ["PfDoa", "PaperPfDoa", "MIN_EXPONENT", "MAX_EXPONENT"]

CANDIDATES = 1000  # uniform candidates of the jump test and the reset
ZERO_GRADIENT = 1e-9  # dB/m: below it the observation's DOA is undefined


class PfDoa(ParticleFilterBase):
    name = "pf-doa"
    OPTIONS = frozenset({"particles", "sigma_rss", "margin", "speed", "speed_range", "velocity_time",
                         "odometry_noise", "resample_threshold", "min_anchors", "jump_probability", "leap_rate",
                         "leap_m", "radio_map"})

    def __init__(self, site, *, rng: np.random.Generator | None = None, particles: int = 200,
                 sigma_rss: float = 4.0, margin: float | None = None, speed: float = 0.3,
                 speed_range: float = 5.0, velocity_time: float = 5.0, odometry_noise: float = 0.2,
                 resample_threshold: float = 0.5, min_anchors: int = 3, jump_probability: float = 0.05,
                 leap_rate: float = 0.2, leap_m: float = 2.5, radio_map: bool = True, **_: object) -> None:
        super().__init__(site, rng, particles, margin, speed, odometry_noise, min_anchors, velocity_time,
                         speed_range)
        n, na = particles, self.n_anchors
        table = site.sections.get("radio_map") if radio_map else None  # validated when the site loaded
        lookup = MapLookup(parse_radio_map(table, site.anchor_ids), site.anchor_ids, n) if table is not None else None
        self.rss = RssModel(site, n, lookup)
        self.noise = NoiseScale(sigma_rss)
        self.cloud_share = CloudShare()
        self.misfit = Misfit(self.anchors, self.heights, site.radio.path_loss_exponent, self.model.min_distance_m)
        self.evidence = Evidence()
        self.lag = Lag()
        self.leaps = Leaps(n, leap_rate, leap_m)
        self.moving = MovingShare()
        self.jump_probability = jump_probability
        self.resample_threshold = resample_threshold
        # Regularisation bandwidth factor for d = 2 (Silverman: h = (4 / (N (d + 2)))^(1/(d + 4))).
        self.h = (4.0 / (n * 4.0)) ** (1.0 / 6.0)
        self.logw = np.empty(n)
        self.ll = np.empty(n)
        self.r = np.empty(na)  # the posterior-mean residual (model - RSS) of the latest update
        self._all = tuple(range(na))
        self._present_mask = np.ones(na, dtype=bool)  # the anchors of the latest update when some were missing
        # Column views of the positions and of their deviations from the estimate (the
        # report): a scalar per column costs less than a row broadcast over a trailing 2.
        self._cols = (self.xy[:, 0], self.xy[:, 1], self.dev[:, 0], self.dev[:, 1])
        self._box = (*self.lo.tolist(), *self.hi.tolist())  # x0, y0, x1, y1 as floats
        self.centroid = Centroid(self.anchors, self.model, CENTROID_POWER)
        self._tmp_flat = np.empty(2 * n)
        # The arrays whose values the leaps touch one by one, as flat memoryviews
        # (Leaps.__call__): every array keeps its identity, so these stay theirs
        self._xy_cells, self._vel_cells = memoryview(self._xy_flat), memoryview(self._vel_flat)
        self._w_cells, self._ss_cells = memoryview(self.w), memoryview(self.rss.ss)
        self.reset()

    def reset(self) -> None:
        self._reset_particles()
        self.rss.reset(self.rng)
        self.logw.fill(-math.log(self.N))
        self.t_prev: float | None = None
        self.noise.reset()
        self.cloud_share.reset()
        self.misfit.reset()
        self.evidence.reset()
        self.lag.reset()
        self.leaps.reset()
        self.moving.reset()
        self._kappa = 1.0  # the share of the latest observation's log-likelihood that counted
        self._present: tuple[int, ...] = ()  # the anchors of the latest update ...
        self._centroid: tuple[float, float] | None = None  # ... and their weighted centroid (the report)
        self._mean: list[float] | None = None  # the posterior mean while the cloud is the update's

    def _clamp(self) -> None:
        reflect_into(self._xy_flat, self._lo_flat, self._hi_flat, self._tmp_flat)

    # -- the filter step ------------------------------------------------------------------
    def step(self, obs: Observation, odom: Odometry | None = None) -> Estimate:
        p = self.prep(obs)
        self._mean = None
        dt = dt_between(self.t_prev, obs.t)
        self.t_prev = obs.t
        # With odometry nothing leaps: it measures the motion (and leaps there cost accuracy).
        leapt = self.leaps(0.0 if odom is not None else dt, self._xy_cells,
                           self._vel_cells if self.velocity_time > 0.0 else None, self.rng, self.normals)
        self._move(dt, odom)
        if odom is not None:
            self.moving.odometry(odom)
        extra: dict = {}
        count, mask = p.count, p.mask
        full = count == self.n_anchors
        op = self.fit.full if full else self.fit.operator(mask) if count >= self.min_anchors else None
        if op is None or count < self.min_anchors:
            extra["degraded"] = degraded(count)
            return self._report(obs.t, None, p.ids, extra)
        px, py = self.w.dot(self.xy).tolist()  # the prediction's mean, before the update (the lag: _report)
        rssi = p.rssi if full else np.where(mask, p.rssi, 0.0)
        gx, gy = op.dot(rssi).tolist()
        doa = math.atan2(gy, gx) if math.hypot(gx, gy) > ZERO_GRADIENT else None
        if full:
            self._present = self._all
        elif not self._present or self._present is self._all or not np.array_equal(mask, self._present_mask):
            np.copyto(self._present_mask, mask)
            self._present = tuple(np.flatnonzero(mask).tolist())
        self._centroid = self.centroid(p.rssi, self._present)
        rss = self.rss
        dof = self._log_likelihood(rssi, mask, count, leapt)
        ss = rss.ss
        logw = self.logw
        log_evidence_whole, whole_exp = self._temper(count, dof)
        logw += self.ll
        w = self.w
        # An observation that surprised the cloud was not tempered: _temper's exp is this one
        top, total = whole_exp if whole_exp is not None else self._exp_from_top(logw, w)
        c = self._operand  # (ParticleFilterBase.__init__)
        jump = None
        if not math.isfinite(top):
            self._recover()
            logw.fill(-math.log(self.N))
            extra["recovered"] = True
            self.evidence.lost = True
        else:
            c[()] = 1.0 / total
            w *= c
            # logw was normalised, so top + log(total) is the log of the mean likelihood of
            # this observation under the prediction (the evidence).
            log_evidence = top + math.log(total)
            c[()] = log_evidence
            logw -= c
            if log_evidence_whole is not None:  # lost and the jump test weigh the whole evidence
                log_evidence = log_evidence_whole
            # Per anchor, with the Gaussian's normaliser: a noise scale that grows to explain
            # readings the cloud no longer fits lowers the evidence instead of hiding the misfit.
            per_anchor = (log_evidence - dof * math.log(self.noise.sigma)) / count
            self.evidence.push(per_anchor)
            self._learn(ss, mask, count, dof, full, obs.t)
            if self.evidence.below_gate(per_anchor, self._odometry_seen):
                jump = self._jump_test(log_evidence, per_anchor, mask)
        mode = None
        if jump is not None:
            self._mean = None
            k = extra["jumped"] = self._jump(jump)
            # The posterior is now bimodal (old cloud, re-seeded part): report the mean of the
            # heavier mode, not a point between the two where there is no mass.
            mode = slice(0, k) if 2 * k >= self.N else slice(k, self.N)
        elif 1.0 / float(w.dot(w)) < self.resample_threshold * self.N:
            self._mean = None
            _, _, sig = self._mean_and_sigma()
            self._resample((rss.exponent,) if rss.spread > 0.0 else ())
            if rss.spread > 0.0:
                rss.sync_gain()
            logw.fill(-math.log(self.N))
            roughen(self, sig)
        extra["sigma_rss"] = self.noise.sigma
        return self._report(obs.t, doa, p.ids, extra, mode, (px, py))

    def _log_likelihood(self, rssi: np.ndarray, mask: np.ndarray, count: int, leapt: int) -> float:
        """Each particle's log-likelihood of this observation into :attr:`ll` (the model's
        residuals in ``rss.E`` and ``rss.ss``); the online noise scale learns from it first.
        Returns the residual's degrees of freedom (the anchors less the centring)."""
        rss, noise = self.rss, self.noise
        gamma, _ = rss.residuals(self.dist.log10(self.xy), self.xy, rssi, mask, count, noise.sigma)
        dof = count - gamma
        if dof < 1.0:
            dof = 1.0
        prior = self._prior_power(leapt) / dof
        noise.push(prior)
        self.cloud_share.push_prior(prior)
        c = self._operand  # (ParticleFilterBase.__init__)
        c[()] = -0.5 * rss.weight / (noise.sigma * noise.sigma)
        np.multiply(rss.ss, c, out=self.ll)
        return dof

    def _temper(self, count: int, dof: float) -> tuple[float | None, tuple[float, float] | None]:
        """A slow target's observation the cloud expected counts for a share of its
        log-likelihood (:meth:`MovingShare.evidence_share`): its readings repeat the deviations
        of the place the last ones described. Scales :attr:`ll` unless the observation
        surprises the cloud (:meth:`Evidence.surprised`). Returns the whole observation's log
        evidence when it is tempered or could have been, else None; and, when it surprised
        the cloud, :meth:`_exp_from_top` of ``logw + ll`` (top, sum), whose exp :attr:`w`
        then holds: the step's own, not computed twice."""
        kappa = self._kappa = self.moving.evidence_share()
        if kappa >= 1.0:
            return None, None
        scratch = self.w  # rewritten from logw after this
        np.add(self.logw, self.ll, out=scratch)
        top, total = self._exp_from_top(scratch, scratch)
        whole = top + math.log(total)
        if self.evidence.surprised((whole - dof * math.log(self.noise.sigma)) / count):
            return whole, (top, total)
        c = self._operand
        c[()] = kappa
        self.ll *= c
        return whole, None

    def _exp_from_top(self, logv: np.ndarray, out: np.ndarray) -> tuple[float, float]:
        """``out`` = exp(``logv`` - top), top its largest value; returns (top, the sum of
        ``out``), so that top + log(sum) is the log of the sum of exp(``logv``). A top that is
        not finite (a NaN, or every value -inf) is returned with a NaN sum, ``out`` untouched.
        The top by ``argmax``: np.maximum.reduce's value at a third of its cost, but for the
        sign of a zero, which exp(logv - top) and top + log(sum >= 1) drop."""
        top = logv.item(logv.argmax())
        if not math.isfinite(top):
            return top, math.nan
        c = self._operand  # (ParticleFilterBase.__init__)
        c[()] = top
        np.subtract(logv, c, out=out)
        np.exp(out, out=out)
        return top, float(np.add.reduce(out))

    def _prior_power(self, leapt: int) -> float:
        """The prior-weighted mean of the particles' residual powers (``rss.ss``), for the
        online noise scale, without the particles that leapt at this step: their residuals say
        where the target is not, not how noisy its readings are."""
        total = float(self.w.dot(self.rss.ss))
        if not leapt:
            return total
        # A few particles: plain floats, read through memoryviews of w and ss.
        w, ss_cells = self._w_cells, self._ss_cells
        out = kept = 0.0
        for i in self.leaps.leapt:
            wi = w[i]
            kept += wi
            out += wi * ss_cells[i]
        kept = 1.0 - kept
        if not kept > 1e-9:
            return total
        return (total - out) / kept

    def _learn(self, ss: np.ndarray, mask: np.ndarray, count: int, dof: float, full: bool, t: float) -> None:
        """What the updated cloud says about the readings, never fed back into the weights
        directly: the posterior residual power (the noise share of the report), the
        posterior-mean residual (the misfit of the report, the transmitter's power and the
        anchors' offsets), the posterior mean (how much the target moves)."""
        w = self.w
        post = float(w.dot(ss)) / dof
        self.noise.push_posterior(post)
        self.cloud_share.push_posterior(post)
        r = w.dot(self.rss.E, out=self.r)
        vals = r.tolist()
        mean = add_reduce(vals if full else [vals[i] for i in self._present]) / count
        self.misfit.push(vals, self._present, mean)
        if count >= POWER_MIN_ANCHORS and not self.evidence.lost:
            self.rss.power.push(-mean)
            # The posterior mean: how much the target moves (the offsets' rate, the report's
            # cloud); the report takes it too unless the cloud is resampled first.
            mx, my = self._mean = w.dot(self.xy).tolist()
            self.rss.offsets.push(vals, None if full else self._present, mean, self.moving.push(t, mx, my))

    # -- the report -----------------------------------------------------------------------
    def _report(self, t: float, doa, ids, extra: dict, mode: slice | None = None,
                prediction: tuple[float, float] | None = None) -> Estimate:
        """The estimate and its uncertainty (the module doc of pf_uncertainty). ``prediction``:
        the cloud's mean before this observation's update (none without an update)."""
        w = self.w
        xy = self.xy
        if mode is None:
            mx, my = self._mean or w.dot(xy).tolist()
        else:
            mx, my = (float(v) for v in xy[mode].mean(axis=0))
        d = self.dev
        x, y, dx, dy = self._cols
        c = self._operand  # (ParticleFilterBase.__init__)
        c[()] = mx
        np.subtract(x, c, out=dx)
        c[()] = my
        np.subtract(y, c, out=dy)
        sq = self.sq
        np.multiply(d, d, out=sq)
        cxx, cyy = w.dot(sq).tolist()
        np.multiply(dx, dy, out=self.noise_1)
        cxy = float(w.dot(self.noise_1))
        var = cxx + cyy
        sig = math.sqrt(0.0 if var < 0.0 else var)
        share = self.noise.share()
        cxx, cxy, cyy = cxx * share, cxy * share, cyy * share
        # The estimate: the posterior mean as a measurement of the cloud's covariance, the
        # search box a uniform prior (its mean truncated to the box); the report adds the
        # misfit's position error, which the cloud does not hold (docs/estimator.md).
        ex, ey, (vx, cxy, vy) = truncated_cov(mx, my, (cxx, cxy, cyy), self._box)
        # The report narrows the cloud by the warm-started share (pf_uncertainty.CloudShare).
        report_share = self.cloud_share.share()
        if report_share is not None and share > 0.0:
            k = report_share / share
            vx, cxy, vy = vx * k, cxy * k, vy * k
        moving = self.moving.share
        if moving < 1.0:  # a standing target's cloud, widened (pf_uncertainty.STANDING_SHARE_MIN) ...
            # ... less what its tempered likelihood already left wider (_temper)
            k = self._kappa / (moving if moving > STANDING_SHARE_MIN else STANDING_SHARE_MIN)
            vx, cxy, vy = vx * k, cxy * k, vy * k
        model = self.misfit.cov_at(ex, ey, self._present) if self._present else None
        if prediction is not None:
            self.lag.push(mx - prediction[0], my - prediction[1])
        if model is not None:  # none before the first update, when there is no lag either
            model = self.lag.cov(model)
        if self._centroid is not None:  # set with _present, at the first update
            # The model's error is the filter's estimate's; the pull towards the centroid
            # removes part of it, and the report keeps it whole.
            model = centroid_cov(model, ex, ey, self._centroid, self.misfit.persistence)
            ex, ey = pulled_to_centroid(ex, ey, self._centroid, self.misfit.persistence, self.misfit.level, self._box)
        cov = report_cov(ex, ey, (vx, cxy, vy), model, self._box)
        heading, heading_var = self._heading() if self._odometry_seen else (None, None)
        r95, lost = r95_of(*cov), self.evidence.lost
        # Every field in Estimate's order: five keywords cost as much as the record itself.
        return Estimate(t, ex, ey, sig, doa, ids, extra, r95, cov, lost, heading, heading_var)

    # -- kidnap: the jump test and sensor resetting -----------------------------------------
    def _jump_test(self, log_evidence: float, per_anchor: float, mask: np.ndarray):
        """Has the target jumped away from the cloud (kidnap, bad start, long outage)?

        The motion prior is taken as ``(1 - eps)`` * (the cloud) + ``eps`` * (uniform over
        the area). The posterior share of the uniform part is
        ``eps L_u / (eps L_u + (1 - eps) L_c)``, with ``L_c`` the evidence of the cloud and
        ``L_u`` that of uniform candidates. Evaluating ``L_u`` costs ~1000 likelihoods, so
        it is only done when the cloud's per-anchor evidence has fallen below its running
        average by a gate (:meth:`Evidence.below_gate`). Returns None, or (share, candidates,
        exponents, log-likelihoods)."""
        rss = self.rss
        c = CANDIDATES
        pts = np.column_stack([self.rng.uniform(self.lo[0], self.hi[0], c),
                               self.rng.uniform(self.lo[1], self.hi[1], c)])
        expo = rss.n0 + rss.spread * self.rng.standard_normal(c)
        np.clip(expo, MIN_EXPONENT, MAX_EXPONENT, out=expo)
        ll = rss.point_log_likelihood(pts, expo, self.anchors, self.heights, self.dist.dmin2, mask, self.noise.sigma)
        top = float(ll.max())
        log_u = top + math.log(float(np.exp(ll - top).mean()))
        eps = self.jump_probability
        odds = (1.0 - eps) / eps * math.exp(min(log_evidence - log_u, 700.0))
        share = 1.0 / (1.0 + odds)
        if share < 1.0 / self.N:
            self.evidence.learn(per_anchor)
            return None
        return share, pts, expo, ll

    def _jump(self, jump) -> int:
        """Resample the cloud and replace a ``share`` of it by draws from the candidates in
        proportion to their likelihood (sensor resetting, Lenser & Veloso 2000)."""
        share, pts, expo, ll = jump
        rss = self.rss
        _, _, sig = self._mean_and_sigma()
        self._resample((rss.exponent,))
        roughen(self, sig)
        k = min(self.N, int(round(share * self.N)))
        if k:
            prob = np.exp(ll - ll.max())
            pick = self.rng.choice(pts.shape[0], size=k, p=prob / prob.sum())
            self.xy[:k] = pts[pick]
            rss.exponent[:k] = expo[pick]
            self.heading[:k] = self.rng.uniform(-np.pi, np.pi, k)
            self._seed_motion(slice(0, k), k)
        rss.sync_gain()
        self.logw.fill(-math.log(self.N))
        return k
