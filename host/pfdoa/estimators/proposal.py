"""Defensive mixture proposal for ``pf-doa``: a few particles drawn from the observation.

A particle filter whose cloud sits on a wrong but self-consistent solution does not come
back on its own: no particle is left where the truth is, and the cloud's evidence stays
high, so the jump test's gate (:meth:`pfdoa.estimators.pf_doa.PfDoa._jump_test`) never
opens. Mixture Monte Carlo Localization (Thrun, Fox, Burgard & Dellaert 2001) draws a
small share of the particles from the observation likelihood instead of the motion model
at every step. Here those draws are weighted so that the filter stays Bayes-correct for
its own motion prior, the mixture ``(1 - eps)`` * (the predicted cloud) + ``eps`` *
(uniform over the area), ``eps`` = ``jump_probability`` (the model the jump test uses):

* the posterior of the cloud part has mass ``(1 - eps) L_c`` (``L_c``: the cloud's
  evidence, the mean likelihood of this observation under the prediction), that of the
  uniform part ``eps L_u`` (``L_u``: the mean likelihood over uniform candidates);
* the uniform part's posterior is ``u(x) p(z | x) / L_u``; ``k`` particles drawn from it
  (systematic draws over the candidates in proportion to their likelihood) carry its mass
  in equal shares, ``eps L_u / k`` each, i.e. prior density over proposal density;
* ``k`` particles (every ``N / k``-th from a random start, each with probability k / N, so
  the cloud is not biased) make room for them; the others keep the cloud part,
  renormalised to ``(1 - eps) L_c``.

The uniform part's share ``s = eps L_u / (eps L_u + (1 - eps) L_c)`` is tiny while the
cloud explains the readings, so the drawn particles weigh almost nothing and vanish at the
next resampling; where another region explains several observations in a row better than
the cloud, its weight compounds and the filter moves there without waiting for the gate.
That is the difference from the start-up proposal tried before (docs/estimator-study.md:
the first observation's likelihood taken at full weight was over-confident).

The candidates are a fixed grid over the filter's area (cell centres: a midpoint rule for
the uniform part, each with an exponent from the filter's prior), so their model RSS is
computed once per reset and the step costs a few small matrix operations on (candidates,
anchors).
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Any

import numpy as np

from pfdoa.radio import squared_distances

# The filter it serves: a pfdoa.estimators.pf_doa.PfDoa, whose state it reads and writes.
# Not imported, even for typing: pf_doa imports this module (no import cycles).
PfDoa = Any

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0  # low-discrepancy spread of the exponent's quantiles


class DefensiveProposal:
    """``share`` of the N particles re-drawn every step from about ``candidates`` uniform
    points in proportion to their likelihood, weighted for the mixture prior (module doc)."""

    def __init__(self, n: int, share: float, candidates: int, n_anchors: int) -> None:
        self.k = min(n, max(1, int(round(share * n))))
        self.stride = n // self.k
        self.candidates = candidates
        self.pts = np.empty((0, 2))
        self.expo = np.empty(0)
        self.model = np.empty((0, n_anchors))  # candidates' model RSS minus A (gain * log10 d^2)
        self.res = np.empty((0, n_anchors))
        self.r = np.empty((0, n_anchors))
        self.ll = np.empty(0)
        self._ones = np.ones(n_anchors)
        self._base = np.arange(self.k, dtype=float) / self.k
        self.last_share = 0.0  # posterior mass of the uniform part at the latest mix

    def reset(self, pf: PfDoa, exponent_bounds: tuple[float, float]) -> None:
        """Candidates for ``pf``'s area and exponent prior. Deterministic (cell centres, the
        exponent's quantiles spread over them by a golden-ratio sequence), so the filter's
        random stream is the same as without the proposal until the first draw."""
        (x0, y0), (x1, y1) = pf.lo, pf.hi
        # nx * ny ~ candidates with square-ish cells
        nx = max(1, int(round(math.sqrt(self.candidates * (x1 - x0) / max(y1 - y0, 1e-9)))))
        ny = max(1, int(round(self.candidates / nx)))
        gx, gy = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(ny) + 0.5) / ny, indexing="ij")
        c = nx * ny
        pts = np.column_stack([x0 + gx.ravel() * (x1 - x0), y0 + gy.ravel() * (y1 - y0)])
        expo = np.full(c, pf._n0)
        if pf._n_spread > 0.0:
            inv = NormalDist().inv_cdf
            u = (np.arange(c) * GOLDEN + 0.5) % 1.0
            expo += pf._n_spread * np.array([inv(float(v)) for v in u])
            np.clip(expo, *exponent_bounds, out=expo)
        d2 = squared_distances(pts, pf.anchors, pf.heights)
        self.model = -5.0 * expo[:, None] * np.log10(np.maximum(d2, pf.dist.dmin2))
        if pf._map is not None:  # the site's radio map, as in the filter's own likelihood
            self.model += pf._map.at(pts)
        self.pts, self.expo = pts, expo
        self.res = np.empty_like(self.model)
        self.r = np.empty_like(self.model)
        self.ll = np.empty(c)
        self.last_share = 0.0

    def _log_likelihood(self, pf: PfDoa, rssi_c: np.ndarray, mask: np.ndarray, count: int) -> np.ndarray:
        """The filter's likelihood (its noise scale, centring and tails) at the candidates."""
        _, centre = pf._centre_for(mask, count)
        np.subtract(self.model, rssi_c, out=self.res)
        r = np.matmul(self.res, centre, out=self.r)
        np.multiply(r, r, out=r)
        s2 = pf.sigma_rss * pf.sigma_rss
        ll = self.ll
        if pf.gaussian:
            np.matmul(r, self._ones, out=ll)
            ll *= -0.5 / s2
        else:
            r *= 1.0 / (pf.nu * s2)
            np.log1p(r, out=r)
            np.matmul(r, self._ones, out=ll)
            ll *= -0.5 * (pf.nu + 1.0)
        return ll

    def mix(self, pf: PfDoa, log_evidence: float, rssi_c: np.ndarray, mask: np.ndarray, count: int) -> slice:
        """Replace k of ``pf``'s particles after its measurement update; ``pf.w`` (and
        ``pf.logw``) hold the cloud's normalised posterior, ``log_evidence`` = log L_c.
        Returns the particles replaced."""
        k = self.k
        ll = self._log_likelihood(pf, rssi_c, mask, count)
        top = float(np.maximum.reduce(ll))
        ll -= top
        prob = np.exp(ll, out=ll)
        cs = np.cumsum(prob, out=prob)
        total = float(cs[-1])
        log_u = top + math.log(total / cs.size)
        eps = pf.jump_probability
        s = 1.0 / (1.0 + (1.0 - eps) / eps * math.exp(min(log_evidence - log_u, 700.0)))
        self.last_share = s
        rng = pf.rng
        start = int(rng.integers(self.stride))
        out = slice(start, start + k * self.stride, self.stride)
        w = pf.w
        keep = 1.0 - float(np.add.reduce(w[out]))
        if keep > 1e-12:
            w *= (1.0 - s) / keep
        else:  # the drawn-out particles held the whole cloud: only the uniform part is left
            w.fill(0.0)
            s = 1.0
        # systematic draws over the candidates' cumulative likelihood
        pick = np.searchsorted(cs, (self._base + rng.random() / k) * total, side="right")
        np.minimum(pick, cs.size - 1, out=pick)
        pf.xy[out] = self.pts[pick]
        pf.exponent[out] = self.expo[pick]
        pf.gain[out, 0] = -5.0 * self.expo[pick]
        pf.heading[out] = rng.uniform(-np.pi, np.pi, k)
        pf._seed_motion(out, k)
        w[out] = s / k
        np.log(np.maximum(w, 1e-300), out=pf.logw)
        return out
