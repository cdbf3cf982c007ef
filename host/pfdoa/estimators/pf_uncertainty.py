"""pf-doa's reported uncertainty: the cloud's spread, plus the position error the model's misfit
causes, which the readings cannot average out, and the estimate's disagreement with a
model-free one.

* the cloud: the particles' second moments about the estimate, narrowed by the RSS noise's
  share of the online noise estimate (:meth:`pfdoa.estimators.pf_model.NoiseScale.share`;
  the report's from averages started at their first values, :class:`CloudShare`);
* the estimate: the filter's posterior mean as a measurement with the cloud's covariance,
  under a uniform prior over the search box: its mean, truncated to the box
  (:func:`truncated_mean`), which draws an estimate the cloud holds against a wall inwards;
* the misfit (:class:`Misfit`): what the model persistently cannot explain at the estimate,
  each anchor's running lag-2 autocovariance of the posterior-mean residual, what persists
  over two observations (started at its first residual's power), mapped to position through
  the anchors' geometry there:
  ``MISFIT_SHARE A J^T V J A``, J the centred Jacobian of the model RSS with the site's
  fitted slope, A = (J^T J)^-1. It follows the
  place and the time: wide where the anchors' geometry says little or the readings keep
  missing the model, nothing for noise that is new at each observation;
* the centroid's term (:func:`centroid_cov`): the estimate's disagreement with the anchors'
  weighted centroid of the same readings, along it, counted by the share of the residual
  power that persists: wide where the estimate rests on the model alone;
* the estimate reported: moved towards that centroid by the persistence above a floor
  (:func:`pulled_to_centroid`), where the readings keep missing the model;
* the lag (:class:`Lag`): the running mean of each update's shift of the posterior mean
  from the prediction's, along it: a cloud that trails the target moves its way step after
  step, one that follows it moves by noise about it;
* ``cov`` is the truncated cloud's plus those three terms, the sum truncated to the box about the
  estimate; ``r95`` the radius holding 95 % of a Gaussian of that covariance (:func:`r95_of`);
* ``lost`` (:class:`Evidence`): the recent evidence has fallen well below its running level.

docs/estimator.md ("Uncertainty") gives the measurements behind each.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.pf_model import SIGMA_RATE, SIGMA_RSS_MAX, SIGMA_RSS_MIN, capped_average, noise_share

# A standing target's readings repeat its place's deviations, so the cloud, narrowed as if
# each observation were new, holds it ever tighter where the readings say no more: the report
# divides the cloud's covariance by how much the target moves (pf_model.MovingShare), at most
# by 1 / STANDING_SHARE_MIN. The estimate does not move.
STANDING_SHARE_MIN = 0.1
# The multiple of the persistent misfit's single-observation position error that the report
# adds, one constant for every site. The residual at the estimate understates the deviation
# (the estimate has moved to absorb part of it), most at a target that stands still, which the
# widened cloud now covers in part. With the lag-2 levels (:meth:`Misfit.cov_at`) and the
# widened cloud, 0.9 puts the truth within r95 for 87.6-97.9 % on the development sites and
# the worst quarter for at least 58 % (one calibration walk, seeds 0-2; 1.3 without the
# widening: 84.5-98.3 %, 52 %; docs/estimator.md, "Uncertainty").
MISFIT_SHARE = 0.9
# The disagreement d between the estimate and the anchors' weighted centroid of the same
# readings (:class:`pfdoa.estimators.wcl.Centroid`, a model-free estimate), added as
# CENTROID_SHARE x the persistence x d d^T. Where the estimate stands on the model alone (a
# place whose walls the model misses, a standing target whose residual the estimate has
# absorbed) the centroid does not follow it; the persistence (:attr:`Misfit.persistence`)
# leaves it out where the model explains the readings up to new noise (the centroid's own
# pull to the anchors' middle is no error of the estimate's). docs/estimator.md, "Uncertainty",
# has the measurements.
CENTROID_SHARE = 0.2
# The lag's running mean (:class:`Lag`), added as LAG_SHARE x m m^T: a filter of gain K that
# trails the target by e shifts by about K e a step, so LAG_SHARE = 2 puts the 95 % radius
# near e at the gains of 0.2-0.4 a trailing cloud shows. LAG_RATE averages about three
# updates, so the shifts of a cloud that follows cancel. docs/estimator.md, "Uncertainty".
LAG_SHARE = 2.0
LAG_RATE = 0.3
# The estimate moves towards that centroid by w = the persistence above PULL_FLOOR, in full
# once the persistent part is PULL_LEVEL (dB^2 per anchor) or more, in proportion below it:
# where the readings keep missing the model at the estimate (walls it does not hold), the
# model-free centroid is the better guide. Below the floor (new noise, and the persistence a
# tracking filter's own lag leaves) the model's estimate stands, and a small repeating part
# moves it little (without noise a residual repeats whole but says nothing; at 1 dB of noise
# the lag's repeats are about 1 dB^2). docs/estimator.md, "Uncertainty", has the measurements.
PULL_FLOOR = 0.3
PULL_LEVEL = 4.0
# That centroid weighs each anchor by 1 / d^CENTROID_POWER (wcl's own is 1 / d): with 1 / d it
# draws every estimate towards the anchors' middle, by metres at the ends of a long room whose
# anchors run along its sides (Feng's office: pf-doa 2.18 -> 2.01 m at 1.5, 1.95 m at 2). The
# draw is also what the small rooms gain from the pull (2 costs the walls rooms more).
CENTROID_POWER = 1.5
MISFIT_RATE = 0.05  # running average rate of the residual power
MISFIT_STEPS = 1.0 / MISFIT_RATE  # weights 1/k until then
MIN_SLOPE = 0.5  # the lowest exponent a site file holds (pfdoa.site.MIN_PATH_LOSS_EXPONENT)
JUMP_GATE = 1.0  # nats per anchor below the running evidence: lost, and the jump test runs
# Without odometry the jump test runs from half that: a tag set down at a point metres away
# (a survey's next point, a phone switched on elsewhere) leaves an evidence only about half a
# nat per anchor below its level once the online noise scale has grown with such moves, and
# the leaps take several observations to follow it (docs/estimator.md, "Motion"). With
# odometry the motion is measured and a re-seeded particle has no heading: 1 nat.
JUMP_GATE_FREE = 0.5
# An observation whose (untempered) evidence falls this far below the running level tells the
# cloud something new (the target or its surroundings changed): it counts whole, tempered or
# not (pf_model.EVIDENCE_SHARE_MIN). Nats per anchor.
SURPRISE_GATE = 0.1
EVIDENCE_RATE = 0.05  # running average rate of the per-anchor log evidence
LOST_RATE = 0.3  # its short average
# r95^2 / l1 of a 2-D Gaussian with covariance eigenvalues l1 >= l2 = u l1, u = 0, 0.1, ..., 1
# (the 95 % quantile of l1 z1^2 + l2 z2^2: 3.8415 = chi2(1) at u = 0, 5.9915 = chi2(2) at u =
# 1; in between by quadrature, tests/unit/test_estimators.py checks them by simulation).
_R95_F = (3.8415, 3.9484, 4.073, 4.2245, 4.4103, 4.6283, 4.8714, 5.1332, 5.4091, 5.6958, 5.9915)


def r95_of(cxx: float, cxy: float, cyy: float) -> float:
    """The radius about the mean holding 95 % of a 2-D Gaussian of covariance (xx, xy, yy)."""
    half = 0.5 * (cxx + cyy)
    q = 0.25 * (cxx - cyy) ** 2 + cxy * cxy
    disc = math.sqrt(0.0 if q < 0.0 else q)  # bounds without min/max (pfdoa.estimators.pf_model)
    l1 = half + disc
    if not l1 > 0.0:
        return 0.0
    l2 = half - disc
    u = (0.0 if l2 < 0.0 else l2) / l1
    u = (1.0 if u > 1.0 else u) * 10.0  # linear between the table's points
    i = int(u)
    if i > 9:
        i = 9
    return math.sqrt(l1 * (_R95_F[i] + (u - i) * (_R95_F[i + 1] - _R95_F[i])))


FAR_SIGMAS = 8.0  # an edge this many sigmas away truncates nothing (to double precision)
_PHI_0 = 0.3989422804014327  # 1 / sqrt(2 pi): the standard normal's density at 0
_SQRT_HALF = 0.7071067811865476


def truncated_mean(mu: float, var: float, lo: float, hi: float) -> tuple[float, float]:
    """Mean and variance of N(mu, var) truncated to [lo, hi] (one axis)."""
    sd = math.sqrt(var) if var > 0.0 else 0.0
    if sd <= 0.0:
        return min(max(mu, lo), hi), 0.0
    a, b = (lo - mu) / sd, (hi - mu) / sd
    if a < -FAR_SIGMAS and b > FAR_SIGMAS:  # the box's edges are far: nothing to truncate
        return mu, var
    # The standard normal's density and distribution at a and b, inline (four calls cost
    # more than the arithmetic)
    pa = math.exp(-0.5 * a * a) * _PHI_0 if a * a < 1400.0 else 0.0
    pb = math.exp(-0.5 * b * b) * _PHI_0 if b * b < 1400.0 else 0.0
    z = 0.5 * (1.0 + math.erf(b * _SQRT_HALF)) - 0.5 * (1.0 + math.erf(a * _SQRT_HALF))
    if not z > 1e-12:  # far outside: the nearer edge
        return (lo if mu < lo else hi), 0.0
    r = (pa - pb) / z
    f = 1.0 + (a * pa - b * pb) / z - r * r
    return mu + sd * r, var * (1e-6 if f < 1e-6 else f)


def truncated_cov(x: float, y: float, cov: tuple[float, float, float], box: tuple[float, float, float, float]
                  ) -> tuple[float, float, tuple[float, float, float]]:
    """N((x, y), cov) truncated to the box (x0, y0, x1, y1) per axis: its mean and its
    covariance, the correlation kept."""
    x0, y0, x1, y1 = box
    cxx, cxy, cyy = cov
    den = cxx * cyy  # 0 also where two tiny variances underflow (a cloud of a few equal particles)
    if cxx > 0.0 and cyy > 0.0 and den < math.inf:
        # Most reports: both axes' edges far, decided by truncated_mean's own test without its
        # two calls. Nothing is truncated, and the correlation's factor is sqrt(den / den) = 1.
        sx, sy = math.sqrt(cxx), math.sqrt(cyy)
        far = FAR_SIGMAS
        if (x0 - x) / sx < -far and (x1 - x) / sx > far and (y0 - y) / sy < -far and (y1 - y) / sy > far:
            return x, y, cov
    ex, vx = truncated_mean(x, cxx, x0, x1)
    ey, vy = truncated_mean(y, cyy, y0, y1)
    if cxx > 0.0 and den > 0.0:  # (and so cyy > 0)
        cxy *= math.sqrt(vx * vy / den)
    return ex, ey, (vx, cxy, vy)


def report_cov(x: float, y: float, cloud: tuple[float, float, float], model: tuple[float, float, float] | None,
               box: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """The reported covariance at the estimate (x, y): the (truncated, narrowed) cloud's plus
    the model's error (the misfit's and the centroid's terms), that sum truncated to the box
    about the estimate. The box bounds the model's error as it bounds the cloud's: a small
    room is not reported wider than itself."""
    if model is None:
        return cloud
    total = (cloud[0] + model[0], cloud[1] + model[1], cloud[2] + model[2])
    return truncated_cov(x, y, total, box)[2]


def centroid_cov(model: tuple[float, float, float] | None, x: float, y: float, centroid: tuple[float, float],
                 persistence: float, share: float | None = None) -> tuple[float, float, float]:
    """``model`` (the misfit's covariance, or None) plus ``share`` x ``persistence`` x d d^T,
    d = (x, y) - ``centroid``: the estimate's disagreement with the anchors' weighted centroid
    as a covariance along it, counted by the share of the residuals' power that persists
    (none where the model explains the readings up to new noise). ``share``: None for
    CENTROID_SHARE, the filter's; tools/uncertainty_study.py tries others."""
    dx, dy = x - centroid[0], y - centroid[1]
    s = (CENTROID_SHARE if share is None else share) * persistence
    cxx, cxy, cyy = (0.0, 0.0, 0.0) if model is None else model
    return cxx + s * dx * dx, cxy + s * dx * dy, cyy + s * dy * dy


def pulled_to_centroid(x: float, y: float, centroid: tuple[float, float], persistence: float, level: float,
                       box: tuple[float, float, float, float]) -> tuple[float, float]:
    """The estimate (x, y) moved towards the anchors' weighted ``centroid`` by the share
    ``persistence - PULL_FLOOR`` (nothing below the floor) times ``level / PULL_LEVEL`` up to
    1 (``level``: the persistent part, dB^2 per anchor), held in the box (x0, y0, x1, y1): a
    site's area may leave anchors, and so their centroid, outside it."""
    full = level / PULL_LEVEL
    w = (persistence - PULL_FLOOR) * (1.0 if full > 1.0 else full)
    if not w > 0.0:
        return x, y
    x0, y0, x1, y1 = box
    x += w * (centroid[0] - x)
    y += w * (centroid[1] - y)
    return min(max(x, x0), x1), min(max(y, y0), y1)


class CloudShare:
    """The RSS noise's share of the prior-predictive residual power, as the report narrows the
    cloud by it: the running averages of :class:`pfdoa.estimators.pf_model.NoiseScale` (its
    rate, its 4x burst limit, its bounds), each started from its first value and averaged
    with weights 1/k until the rate is reached. NoiseScale starts both from the prior
    ``sigma_rss``, so its ratio is 1 at first and narrows the cloud only after some ten
    observations: a short run was reported with the unnarrowed cloud throughout. The filter
    keeps NoiseScale's (its likelihood and the estimate's truncation use it); only the
    reported covariance takes this one."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.prior = self.post = 0.0
        self.k_prior = self.k_post = 0

    def push_prior(self, var: float) -> None:
        self.k_prior = k = self.k_prior + 1
        rate = 1.0 / k
        v = var if k == 1 else capped_average(self.prior, var, rate if rate > SIGMA_RATE else SIGMA_RATE)
        lo, hi = SIGMA_RSS_MIN * SIGMA_RSS_MIN, SIGMA_RSS_MAX * SIGMA_RSS_MAX
        v = lo if v < lo else v
        self.prior = hi if v > hi else v

    def push_posterior(self, var: float) -> None:
        self.k_post = k = self.k_post + 1
        rate = 1.0 / k
        self.post = var if k == 1 else capped_average(self.post, var, rate if rate > SIGMA_RATE else SIGMA_RATE)

    def share(self) -> float | None:
        """The factor on the cloud's covariance, in (0, 1]; None before both averages have a value."""
        if not (self.k_prior and self.k_post):
            return None
        return noise_share(self.post, self.prior)


class Lag:
    """How far the cloud trails the target: the running mean (rate ``LAG_RATE``) of each
    update's shift of the posterior mean from the prediction's mean. After a leap, a corner or
    a survey's next point the cloud moves the same way for several updates; the readings'
    noise shifts it to and fro. :meth:`cov` adds ``LAG_SHARE`` x m m^T along that mean."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.mx = self.my = 0.0

    def push(self, dx: float, dy: float) -> None:
        self.mx += LAG_RATE * (dx - self.mx)
        self.my += LAG_RATE * (dy - self.my)

    def cov(self, model: tuple[float, float, float]) -> tuple[float, float, float]:
        """``model`` plus the lag's covariance."""
        mx, my = self.mx, self.my
        cxx, cxy, cyy = model
        return cxx + LAG_SHARE * mx * mx, cxy + LAG_SHARE * mx * my, cyy + LAG_SHARE * my * my


class Misfit:
    """The misfit that persists: the running lag-1 and lag-2 autocovariances (dB^2) of each
    anchor's posterior-mean residual, centred over the present anchors, and the position
    covariance the lag-2 ones make at a point. Noise that is new at each observation averages
    out in the filter and adds nothing to it; a deviation the model misses at a place (walls,
    the carrier's body, another device's offsets) repeats while the target is near there.
    The report takes what repeats two observations apart: one apart also repeats what lasts a
    single step (a reading held over into the next window, the estimate's lag behind a moving
    target), not a deviation the estimate keeps. The lag-1 levels give the persistence and the
    pull."""

    def __init__(self, anchors: np.ndarray, heights: np.ndarray, site_exponent: float, min_distance_m: float) -> None:
        self._ax, self._ay = anchors[:, 0].tolist(), anchors[:, 1].tolist()
        self._h2 = (heights * heights).tolist()
        # The Jacobian's slope: the site's fitted exponent (not the model's floor: where the
        # readings barely follow distance, they say that little about position).
        self.k = -10.0 * max(site_exponent, MIN_SLOPE) / math.log(10.0)
        self.dmin2 = min_distance_m * min_distance_m
        self.n = anchors.shape[0]
        self._nans = [math.nan] * self.n  # the residuals before the first: every anchor missing
        self.reset()

    def reset(self) -> None:
        self.var = [0.0] * self.n  # per anchor, dB^2 (plain floats: a few anchors cost less so)
        self.var2 = [0.0] * self.n  # per anchor, the lag-2 autocovariance, dB^2 (the report's)
        self.power = [0.0] * self.n  # per anchor, the residual's power, averaged alike
        # The share of the latest present anchors' residual power that persists from one
        # observation to the next (their lag-1 levels over their powers), in [0, 1]: 1 until a
        # pair of residuals has shown that they decorrelate, near 0 where the model explains
        # the readings up to new noise.
        self.persistence = 0.0
        self.level = 0.0  # their lag-1 levels' mean, dB^2 per anchor
        self.seen = [0] * self.n  # per anchor: its power start and the lag-1 pairs averaged since
        self.seen2 = [0] * self.n  # the same for the lag-2 pairs
        self._prev: list[float] = self._nans  # the previous centred residual, NaN where missing
        self._prev2: list[float] = self._nans  # the one before it

    def push(self, r: list[float], present: tuple[int, ...], mean: float) -> None:
        """``r``: the posterior-mean residual (n plain floats, as the filter holds it), any
        value where an anchor is missing;
        ``present`` the anchors that reported and ``mean`` their residuals' mean.

        An anchor's first residual starts its average at its power: until a pair of
        residuals has shown that they decorrelate, all of it may persist. The lag-1 products
        that follow are averaged with weights 1/k, then at MISFIT_RATE: the start counts as
        one observation, not as the average's whole past. The lag-2 level starts there too,
        but its first pair replaces the start (counted as one, the start widened the early
        reports: the robot 99.0 against 98.7 % within r95 at the share 1.5)."""
        count = len(present)
        cur = [math.nan] * self.n
        prev, prev2 = self._prev, self._prev2
        self._prev, self._prev2 = cur, prev
        if count < 3:
            for i in present:
                cur[i] = r[i] - mean
            return
        scale = count / (count - 1.0)  # the centring's share of each anchor's power
        var, var2, power, seen, seen2 = self.var, self.var2, self.power, self.seen, self.seen2
        steps, slow = MISFIT_STEPS, MISFIT_RATE
        v_sum = p_sum = 0.0
        for i in present:  # each anchor's centred residual, then its levels from it
            c = cur[i] = r[i] - mean
            k = seen[i]
            if not k:
                v = p = var[i] = var2[i] = power[i] = c * c * scale
                seen[i] = 1  # the lag-2 start is no observation: the first lag-2 pair replaces it
            else:
                v, p = var[i], power[i]
                b = prev[i]
                if b == b:  # seen twice in a row (NaN: missing before, keeps its level)
                    seen[i] = k = k + 1
                    rate = 1.0 / k if k < steps else slow  # max(MISFIT_RATE, 1 / k)
                    var[i] = v = v + rate * (c * b * scale - v)
                    power[i] = p = p + rate * (c * c * scale - p)
                b = prev2[i]
                if b == b:  # seen two observations ago
                    seen2[i] = k = seen2[i] + 1
                    var2[i] += (1.0 / k if k < steps else slow) * (c * b * scale - var2[i])
            if v > 0.0:
                v_sum += v
            p_sum += p
        share = v_sum / p_sum if p_sum > 0.0 else 0.0
        self.persistence = 1.0 if share > 1.0 else share
        self.level = v_sum / count

    def cov_at(self, x: float, y: float, present: tuple[int, ...]) -> tuple[float, float, float] | None:
        """MISFIT_SHARE (J^T J)^-1 J^T V J (J^T J)^-1 at (x, y): the position error that each
        present anchor's persistent deviation (V, its lag-2 level) makes through the centred
        Jacobian J of the model RSS; None where the geometry gives no bound. Plain floats: a
        few anchors cost less so than as arrays."""
        k, dmin2 = self.k, self.dmin2
        ax, ay, h2 = self._ax, self._ay, self._h2
        gxs, gys = [], []
        for i in present:
            dx, dy = x - ax[i], y - ay[i]
            d2 = dx * dx + dy * dy + h2[i]
            g = k / (d2 if d2 > dmin2 else dmin2)
            gxs.append(g * dx)
            gys.append(g * dy)
        n = len(gxs)
        mx, my = sum(gxs) / n, sum(gys) / n
        v = self.var2
        sxx = sxy = syy = bxx = bxy = byy = 0.0
        for i, gx, gy in zip(present, gxs, gys):
            gx -= mx
            gy -= my
            sxx += gx * gx
            sxy += gx * gy
            syy += gy * gy
            vi = v[i]
            if vi > 0.0:  # a level at or below 0 (or NaN) counts as 0: its products add nothing
                vx = vi * gx
                bxx += vx * gx
                bxy += vx * gy
                byy += vi * gy * gy
        det = sxx * syy - sxy * sxy
        if not det > 1e-12 * (sxx * syy + 1e-300):
            return None
        # A = (J^T J)^-1 = [[syy, -sxy], [-sxy, sxx]] / det; cov = A B A
        axx, axy, ayy = syy / det, -sxy / det, sxx / det
        txx, txy = axx * bxx + axy * bxy, axx * bxy + axy * byy  # (A B) first row
        tyx, tyy = axy * bxx + ayy * bxy, axy * bxy + ayy * byy  # (A B) second row
        s = MISFIT_SHARE
        return (s * (txx * axx + txy * axy), s * (txx * axy + txy * ayy), s * (tyx * axy + tyy * ayy))


class Evidence:
    """The per-anchor log evidence of each observation (the mean likelihood under the
    prediction, with the Gaussian's normaliser: a noise scale grown to explain readings the
    cloud no longer fits lowers it): its running level and a short average. ``lost`` when
    the short one falls JUMP_GATE nats below the running one: for several observations the
    cloud has explained the readings far worse than it used to."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.slow: float | None = None
        self.fast: float | None = None
        self.lost = False

    def push(self, per_anchor: float) -> None:
        fast = self.fast
        self.fast = per_anchor if fast is None else fast + LOST_RATE * (per_anchor - fast)
        self.lost = self.slow is not None and self.fast < self.slow - JUMP_GATE

    def surprised(self, per_anchor: float) -> bool:
        """Whether this observation's evidence is SURPRISE_GATE below the running level."""
        slow = self.slow
        return slow is not None and per_anchor < slow - SURPRISE_GATE

    def below_gate(self, per_anchor: float, odometry: bool) -> bool:
        """Whether this observation's evidence is below the gate (JUMP_GATE with odometry,
        JUMP_GATE_FREE without): the jump test should run; otherwise the running level learns it."""
        slow = self.slow
        if slow is not None and per_anchor < slow - (JUMP_GATE if odometry else JUMP_GATE_FREE):
            return True
        self.learn(per_anchor)
        return False

    def learn(self, per_anchor: float) -> None:
        slow = self.slow
        self.slow = per_anchor if slow is None else slow + EVIDENCE_RATE * (per_anchor - slow)
