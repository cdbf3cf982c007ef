"""pf-doa's measurement model: what one observation says about each particle's position.

The log-distance model (:mod:`pfdoa.radio`, 3-D distances) gives each particle's model RSS
``A + gain log10(d^2) (+ the site's radio map)``, ``gain = -5 n``. The residual
``e = model - RSS`` over the present anchors is centred (its mean over them removed: the
differential RSS, independent of the transmitter's power), partly where the transmitter's
power has been learnt (:class:`PowerTracker`), after each anchor's offset learnt online
(:class:`AnchorOffsets`), and scored by a Gaussian of the online noise
scale (:class:`NoiseScale`), weighted by the evidence the site's calibration says the
readings hold (:attr:`RssModel.weight`). docs/estimator.md says why each piece is there and
what measurement chose it.

The scalars updated at each observation are bounded by conditional expressions, not by
``min``/``max``: a builtin call costs as much as ten comparisons and a step bounds some thirty
values (here and in :mod:`pfdoa.estimators.pf_uncertainty`). Each keeps the operand order of
the call it replaces (``min(x, c)`` is ``c if x > c else x``), so NaN and signed zeros come
out as before.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.estimators.common import add_reduce
from pfdoa.odometry import compose
from pfdoa.types import Odometry

# Physical range of the path-loss exponent the filter uses. The lowest indoor values reported
# are ~1.6 (in-building line of sight, waveguiding corridors: Rappaport, Wireless
# Communications, Table 4.2). A fit below it (BLE 5.1 rooms: 0.5-1.1, readings that barely
# follow distance) is the site's, but as the model's slope it makes every RSS difference a
# large distance ratio: the model keeps 1.6 and the readings' evidence is weighted by
# fit / 1.6 instead (:attr:`RssModel.weight`), and each particle carries its own exponent
# (1-sigma UNRELIABLE_EXPONENT_SPREAD above the floor).
MIN_EXPONENT = 1.6
MAX_EXPONENT = 8.0
UNRELIABLE_EXPONENT_SPREAD = 0.3
SIGMA_RSS_MIN = 1.0  # dB: below the 1 dB RSSI quantisation plus model error it means nothing
SIGMA_RSS_MAX = 20.0
SIGMA_RATE = 0.1  # the online noise scale's averaging rate per observation
POWER_MIN_ANCHORS = 4  # observations that teach the transmitter's power (and the anchors' offsets)
# The anchors' offsets learnt online (AnchorOffsets): the running-average rate per observation
# (about 100 observations: longer than the place-fixed deviations of tens of seconds it should
# not learn) and the prior's bound, the per-anchor spread measured between devices (+-1-3 dB).
OFFSET_RATE = 0.01
OFFSET_MAX_DB = 3.0
# How much the target moves (MovingShare): the estimate's (with odometry, the odometry's) speed
# over about the last SPEED_WINDOW_S seconds, over MOVING_SPEED, up to 1 (1 until the
# positions span that long).
# A standing target's readings repeat its place's deviations: the offsets do not learn them
# (a phone held still at a point for a minute taught the offsets that point's walls), and the
# report widens the cloud they narrowed (pf_uncertainty.STANDING_SHARE_MIN). Seconds, not
# updates: ten observations a second would otherwise see a walker's second as a standing
# target's ten.
SPEED_WINDOW_S = 10.0
MOVING_SPEED = 0.2  # m/s: 2 m in 10 s
SPEED_SAMPLE_S = 0.95  # the track keeps an estimate about every second (1 s windows jitter)
# The same repeats make a slow target's consecutive observations fewer independent ones than
# they are: below FULL_EVIDENCE_SPEED an observation the cloud expected counts for a share of
# its likelihood in proportion to the speed, at least EVIDENCE_SHARE_MIN (a tempered
# likelihood); one that surprises the cloud counts whole (pf_uncertainty.SURPRISE_GATE).
FULL_EVIDENCE_SPEED = 0.1  # m/s: 1 m in 10 s, about a place's deviation's extent
EVIDENCE_SHARE_MIN = 0.3
CENTRES_MAX = 256  # cached centring matrices (one per set of present anchors)


def capped_average(avg: float, var: float, rate: float) -> float:
    """One step of a running average of residual power at ``rate``, where a burst can at most
    quadruple the average (NoiseScale's, and the report's CloudShare)."""
    cap = 4.0 * avg
    return avg + rate * ((cap if cap < var else var) - avg)  # min(var, cap)


def noise_share(post_var: float, prior_var: float) -> float:
    """The RSS noise's share of the prior-predictive residual power, in (0, 1]: the factor
    that narrows the cloud's spread."""
    floor = SIGMA_RSS_MIN * SIGMA_RSS_MIN
    share = (floor if floor > post_var else post_var) / prior_var  # max(post_var, floor)
    return 1.0 if share > 1.0 else share


class NoiseScale:
    """The RSS noise scale (dB), estimated online from the prior-predictive residual power per
    degree of freedom (so the same filter serves 1 dB simulations and 6 dB rooms), bounded to
    [SIGMA_RSS_MIN, SIGMA_RSS_MAX]; a burst can at most quadruple its variance in one step.
    ``share`` is its posterior-weighted counterpart (the residual after the update): their
    ratio is the RSS noise's share of the prior-predictive power, which also holds the cloud's
    own spread, and narrows the reported spread (:mod:`pfdoa.estimators.pf_uncertainty`)."""

    def __init__(self, sigma0: float) -> None:
        self.sigma0 = sigma0
        self.reset()

    def reset(self) -> None:
        self.sigma = self.sigma0
        self.post_var = self.sigma0 * self.sigma0

    def push(self, var: float) -> None:
        s2 = capped_average(self.sigma * self.sigma, var, SIGMA_RATE)
        s = math.sqrt(0.0 if s2 < 0.0 else s2)
        s = SIGMA_RSS_MIN if s < SIGMA_RSS_MIN else s
        self.sigma = SIGMA_RSS_MAX if s > SIGMA_RSS_MAX else s

    def push_posterior(self, var: float) -> None:
        self.post_var = capped_average(self.post_var, var, SIGMA_RATE)

    def share(self) -> float:
        """The factor on the cloud's covariance, in (0, 1]."""
        return noise_share(self.post_var, self.sigma * self.sigma)


class PowerTracker:
    """The transmitter's power relative to the site's A (dB), learnt online.

    The differential residual ignores the mean over the anchors because the transmitter's
    power is unknown (another device, its antenna, its orientation). It is one number that
    changes slowly: the running mean of the posterior-mean residual of observations with at
    least POWER_MIN_ANCHORS anchors (whose position the differential part fixes, so the prior
    does not learn from positions it chose itself), its running spread the 1-sigma of a
    Gaussian prior on the next observation's power. That prior matters when three anchors
    report: the differential RSS alone then leaves the position ambiguous along a curve.
    """

    RATE = 0.05  # running average weight once warm (1/k for the first k updates)
    WARM = 10  # updates before the prior is used
    MIN_SIGMA_DB = 0.5

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.offset = 0.0
        self.var = 0.0
        self.updates = 0

    def push(self, mean_residual: float) -> None:
        """The mean posterior residual of one observation, relative to the current offset."""
        self.updates += 1
        rate = 1.0 / self.updates
        rate = rate if rate > self.RATE else self.RATE  # max(RATE, 1 / updates)
        self.offset += rate * mean_residual
        self.var += rate * (mean_residual * mean_residual - self.var)

    def gamma(self, count: int, sigma_rss: float) -> float:
        """The share of the mean residual to remove: 1 (the differential RSS) until warm; then,
        for the Gaussian prior of 1-sigma ``s`` on the power, marginalising it from ``e`` gives
        ``|e|^2 - beta/n (sum e)^2``, ``beta = n / (n + sigma_rss^2 / s^2)``, which is
        ``|e - gamma mean(e)|^2`` for ``gamma = 1 - sqrt(1 - beta)``."""
        if self.updates < self.WARM:
            return 1.0
        s = math.sqrt(self.var)
        if s < self.MIN_SIGMA_DB:
            s = self.MIN_SIGMA_DB
        beta = count / (count + (sigma_rss / s) ** 2)
        return 1.0 - math.sqrt(1.0 - beta)


class MovingShare:
    """How much the target moves: its speed since the oldest of the positions a ring keeps
    (about one a second over SPEED_WINDOW_S), over MOVING_SPEED, up to 1; 1 until the ring
    spans that long. The positions are the posterior mean's, or, once odometry has been seen,
    the odometry's own dead-reckoned path (:meth:`odometry`): it measures the motion, where a
    slow robot's estimate wanders by its readings' deviations. docs/estimator.md."""

    def __init__(self) -> None:
        self._track = [(0.0, 0.0, 0.0)] * (int(SPEED_WINDOW_S) + 1)  # (t, x, y) about a second apart
        self._kept = 0
        self.share = 1.0
        self._pose: Odometry | None = None  # the odometry's dead-reckoned pose, in its own frame

    def reset(self) -> None:
        self._kept = 0
        self.share = 1.0
        self._pose = None

    def odometry(self, odom: Odometry) -> None:
        """Compose a robot-frame increment into the dead-reckoned pose. Its frame is arbitrary
        (the first increment's): only distances along it are read."""
        if self._pose is None:  # a new track: the estimates it holds are in another frame
            self._pose = odom
            self._kept = 0
            self.share = 1.0
        else:
            self._pose = compose(self._pose, odom)

    def push(self, t: float, x: float, y: float) -> float:
        """The share at time ``t``, the estimate (x, y) (kept in :attr:`share`); the
        dead-reckoned position instead once there is one."""
        if self._pose is not None:
            x, y = self._pose.dx, self._pose.dy
        size = len(self._track)
        if not self._kept or t - self._track[(self._kept - 1) % size][0] >= SPEED_SAMPLE_S:
            self._track[self._kept % size] = (t, x, y)
            self._kept += 1
        share = 1.0
        if self._kept >= size:
            t0, x0, y0 = self._track[self._kept % size]  # the oldest
            span = t - t0
            if span > 0.0:
                share = math.hypot(x - x0, y - y0) / (span * MOVING_SPEED)
                if share > 1.0:
                    share = 1.0
        self.share = share
        return share

    def evidence_share(self) -> float:
        """The share of an expected observation's log-likelihood that counts: the speed over
        FULL_EVIDENCE_SPEED, within [EVIDENCE_SHARE_MIN, 1]."""
        k = self.share * (MOVING_SPEED / FULL_EVIDENCE_SPEED)
        return 1.0 if k >= 1.0 else EVIDENCE_SHARE_MIN if k < EVIDENCE_SHARE_MIN else k


class AnchorOffsets:
    """Each anchor's offset beyond the calibrated one (dB), learnt online: another phone or tag
    has its own per-anchor offsets of +-1-3 dB on top of the common shift (the transmitter's
    power, :class:`PowerTracker`), which a calibration walk with another device cannot hold.
    The running mean (rate OFFSET_RATE) of the posterior-mean residual centred over the
    present anchors, of the observations that teach the power; each offset held within
    +-OFFSET_MAX_DB (the prior) and their sum zero (the common part is the power's); the rate
    scaled by how much the target moves (:class:`MovingShare`). docs/estimator.md
    ("Likelihood") gives the measurements."""

    def __init__(self, n: int) -> None:
        # dB per anchor, subtracted from the readings (RssModel.residuals); plain floats, as
        # a few anchors' cost less so
        self.values = [0.0] * n
        self._all = range(n)

    def reset(self) -> None:
        self.values = [0.0] * len(self.values)

    @property
    def db(self) -> np.ndarray:
        """The offsets (dB per anchor) as an array (a copy)."""
        return np.array(self.values)

    def push(self, r: list[float], present: tuple[int, ...] | None, mean: float, moving: float) -> None:
        """``r``: the posterior-mean residual (model - RSS) as plain floats, as the filter holds
        it; ``present``: the anchors that reported (None: all); ``mean`` their residuals' mean;
        ``moving`` the MovingShare. The step, the bounds and the sum as plain floats (a few
        anchors cost less so than a ufunc each; the sum in numpy's order of additions: the
        same offsets to the last bit)."""
        rate = OFFSET_RATE * moving
        if not rate > 0.0:
            return
        db = self.values
        for i in self._all if present is None else present:
            db[i] -= (r[i] - mean) * rate
        lo, hi = -OFFSET_MAX_DB, OFFSET_MAX_DB
        db = [hi if d > hi else lo if d < lo else d for d in db]  # np.maximum/np.minimum's values, NaN kept
        shift = add_reduce(db) / len(db)
        self.values = [d - shift for d in db]


class RssModel:
    """The site's model for ``n`` particles, with preallocated buffers (the filter's hot path).

    ``exponent`` / ``gain`` are per particle (a site fitted below MIN_EXPONENT: each particle
    its own); ``weight`` multiplies the log-likelihood (below 1 for such a site)."""

    def __init__(self, site, n: int, radio_map) -> None:
        self.a1m = site.radio.rssi_at_1m_dbm
        self.n_site = site.radio.path_loss_exponent
        self.n0 = min(max(self.n_site, MIN_EXPONENT), MAX_EXPONENT)
        self.spread = UNRELIABLE_EXPONENT_SPREAD if self.n_site < MIN_EXPONENT else 0.0
        self._gain0 = np.array(-5.0 * self.n0)  # 0-d: see ParticleFilterBase._operand
        # The readings' evidence weighed by the fitted slope over the model's: a room whose RSS
        # barely follows distance says less than the floored model believes
        # (docs/estimator.md, "Likelihood").
        self.weight = min(self.n_site / self.n0, 1.0)
        self.map = radio_map  # a pfdoa.radiomap.MapLookup, or None
        na = len(site.anchors)
        self.exponent = np.empty(n)
        # -5 * exponent in every anchor's column (a column broadcast costs several times a
        # same-shape product); refreshed by sync_gain when the exponents change
        self.gain = np.empty((n, na))
        self.E = np.empty((n, na))  # model - RSS per particle and anchor (uncentred)
        self.R = np.empty((n, na))  # centred, then squared
        self.ss = np.empty(n)  # sum of squared centred residuals per particle
        self.rssi_c = np.empty(na)
        # rssi_c in every row: filling it and a same-shape subtraction cost less than a
        # subtraction broadcast over a few anchors. It is filled as the outer product ones (n, 1)
        # x rssi_c (1, na): BLAS writes each value as 1 x v, the same double, in less than half
        # the time of a broadcast copy.
        self.rssi_full = np.empty((n, na))
        self._ones_col = np.ones((n, 1))
        self._rssi_row = self.rssi_c.reshape(1, na)
        self.ones = np.ones(na)
        self.noise = None  # NoiseScale, set by the filter
        self.power = PowerTracker()
        self.offsets = AnchorOffsets(na)
        self._centres: dict[tuple[bytes, float], tuple[float, np.ndarray]] = {}

    def reset(self, rng: np.random.Generator) -> None:
        if self.spread > 0.0:
            self.exponent[:] = self.n0 + self.spread * rng.standard_normal(self.exponent.size)
            np.clip(self.exponent, MIN_EXPONENT, MAX_EXPONENT, out=self.exponent)
        else:
            self.exponent.fill(self.n0)
        self.sync_gain()
        self.power.reset()
        self.offsets.reset()

    def sync_gain(self) -> None:
        np.multiply(self.exponent, -5.0, out=self.gain[:, 0])
        self.gain[:, 1:] = self.gain[:, :1]

    def centre_for(self, mask: np.ndarray, count: int, sigma: float) -> tuple[float, np.ndarray]:
        """(gamma, C): ``e @ C`` is the partially centred residual over the present anchors
        with zero columns for the missing ones (a missing anchor costs nothing in the hot path).
        Cached per mask and gamma rounded to 0.01 (immaterial; a rebuild every step would cost
        a tenth of the step)."""
        gamma = round(self.power.gamma(count, sigma), 2)
        key = (mask.tobytes(), gamma)
        hit = self._centres.get(key)
        if hit is not None:
            return hit
        m = mask.astype(float)
        c = np.diag(m) - (gamma / count) * np.outer(m, m)
        if len(self._centres) >= CENTRES_MAX:
            self._centres.clear()
        self._centres[key] = (gamma, c)
        return gamma, c

    def residuals(self, log10_d2: np.ndarray, xy: np.ndarray, rssi: np.ndarray, mask: np.ndarray,
                  count: int, sigma: float) -> tuple[float, np.ndarray]:
        """Fill E (model - RSS) and ss (each particle's centred residual power); returns
        (gamma, C). ``rssi``: offset-free RSS, any finite value where an anchor is missing."""
        base = self.a1m + self.power.offset
        # (rssi - base) - offset as plain floats: a list costs less than two ufuncs on a few anchors
        self.rssi_c[:] = [v - base - d for v, d in zip(rssi.tolist(), self.offsets.values)]
        E = self.E
        if self.spread > 0.0:
            np.multiply(log10_d2, self.gain, out=E)
        else:
            np.multiply(log10_d2, self._gain0, out=E)
        self._ones_col.dot(self._rssi_row, out=self.rssi_full)
        E -= self.rssi_full
        if self.map is not None:
            E += self.map.into(xy)
        gamma, centre = self.centre_for(mask, count, sigma)
        R = E.dot(centre, out=self.R)  # np.matmul's BLAS call (pfdoa.estimators.particles)
        np.multiply(R, R, out=R)
        R.dot(self.ones, out=self.ss)
        return gamma, centre

    def point_log_likelihood(self, points: np.ndarray, exponents: np.ndarray, anchors: np.ndarray,
                             heights: np.ndarray, dmin2: float, mask: np.ndarray, sigma: float) -> np.ndarray:
        """The hot path's log-likelihood at arbitrary points (allocates; the jump test)."""
        from pfdoa.radio import squared_distances

        idx = np.flatnonzero(mask)
        d2 = np.maximum(squared_distances(points, anchors[idx], heights[idx]), dmin2)
        res = -5.0 * exponents[:, None] * np.log10(d2) - self.rssi_c[idx]
        if self.map is not None:
            res += self.map.at(points)[:, idx]
        res -= self.power.gamma(idx.size, sigma) * res.mean(axis=1, keepdims=True)
        return (-0.5 * self.weight / (sigma * sigma)) * (res * res).sum(axis=1)
