"""The gateway's live peer calibration: the anchors' peer readings (SPEC 3.5) in, a fit of
the radio model every ``refit_s`` of timer time out (:mod:`pfdoa.peercal`), reported in the
health and, when it is well-conditioned, used by the estimators.

Configured by the site's ``[[beacons]]`` entry of kind ``"anchors"`` (docs/anchors.md)::

    [[beacons]]
    kind = "anchors"   # the anchors hear each other: filter table entry ANCHORS
    period_ms = 1000   # each anchor sends its own advertisement this often (default 1000)
    refit_s = 60.0     # the gateway refits this often, on its timer time (default 60)
    apply = true       # use a well-conditioned fit in the estimators (default true)

**When a fit is used** (``apply``): it must be well-conditioned
(:attr:`pfdoa.peercal.PeerFit.conditioned`: enough links per anchor, small standard errors
of ``n`` and of the receive offsets, ``n`` in range), and it must change what the model in
use predicts: the RMS over every anchor and a grid of the site's area of the difference in
predicted RSSI is at least ``APPLY_CHANGE_DB``. A fit that passes replaces the estimators'
model (:meth:`pfdoa.peercal.PeerFit.apply`: ``A``, ``n``, the receive offsets as
``rssi_offset_db``; the beacon transmits like an average anchor), and each estimator starts
again from its prior (its particles spread over the area), which is why a fit that changes
next to nothing is not used. After a walk calibration (``pfdoa calibrate`` writes
``apply = false``) the fit is reported only: a drift of the anchors shows in the health.

Every decision runs on the gateway's timer time (a capture replays to the same fits).
"""

from __future__ import annotations

import logging
import math
from typing import Callable

import numpy as np

from pfdoa.errors import InputError
from pfdoa.gateway.beacons import PeersConfig
from pfdoa.peercal import PeerFit, PeerReadings, fit_peers
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import Site

log = logging.getLogger(__name__)

APPLY_CHANGE_DB = 0.5  # a fit is used when it moves the predicted RSSI by this much (RMS) or more
GRID = 12  # points per side of the grid the change is measured on


def prediction_change_db(a: Site, b: Site) -> float:
    """RMS over the anchors and a grid of ``a``'s area of the difference between what the two
    sites' models predict (dB)."""
    from pfdoa.estimators.common import default_margin, search_box

    lo, hi = search_box(a, default_margin(a.positions))
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], GRID), np.linspace(lo[1], hi[1], GRID))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    ra = mean_rssi(pts, a.positions, PathLoss.from_site(a), a.offsets, a.heights)
    rb = mean_rssi(pts, b.positions, PathLoss.from_site(b), b.offsets, b.heights)
    return float(np.sqrt(np.mean((ra - rb) ** 2)))


class LivePeers:
    """Peer readings of ``site``'s anchors, refitted every ``cfg.refit_s`` of timer time;
    ``on_model(site)`` gets every fit that is used (see the module doc)."""

    def __init__(self, site: Site, cfg: PeersConfig, on_model: Callable[[Site], object] | None = None) -> None:
        self.site = site  # as the site file says: the fits' positions, and what a fit replaces
        self.cfg = cfg
        self.on_model = on_model
        self.readings = PeerReadings(site.anchor_ids)
        self.in_use = site  # the model the estimators run with
        self.fit: PeerFit | None = None
        self.fit_t: float | None = None  # timer time of the last fit
        self.applied_t: float | None = None
        self.applied = 0  # fits used
        self.fits = 0
        self.change_db: float | None = None  # the last fit's change against the model in use
        self.not_fitted = ""  # why the last refit made no fit
        self._next = -math.inf
        self._fitted_at = -1  # readings count of the last fit
        self._last_t = -math.inf  # the latest reading's time

    def add(self, receiver: int, transmitter: int, rssi_dbm: float, t: float) -> None:
        if self._next == -math.inf:
            self._next = t + self.cfg.refit_s  # the first fit one period after the first reading
        self._last_t = max(self._last_t, t)
        self.readings.add(receiver, transmitter, rssi_dbm)

    def finish(self) -> None:
        """End of input: one last fit of what came since the last one (a replay's final
        counters and health say what the whole input gives)."""
        if self.readings.readings != self._fitted_at and math.isfinite(self._last_t):
            self._fitted_at = self.readings.readings
            self.refit(self._last_t)

    def poll(self, now: float) -> None:
        """Timer time is ``now``: refit when a period has passed and readings came in."""
        if now < self._next or self.readings.readings == self._fitted_at:
            return
        self._next = now + self.cfg.refit_s
        self._fitted_at = self.readings.readings
        self.refit(now)

    def refit(self, now: float) -> PeerFit | None:
        try:
            fit = fit_peers(self.site, self.readings)
        except InputError as exc:
            self.not_fitted = str(exc)
            return None
        self.not_fitted = ""
        self.fit, self.fit_t = fit, now
        self.fits += 1
        fitted = fit.apply(self.site)
        self.change_db = prediction_change_db(self.in_use, fitted)
        log.info("peer fit at t=%.1f: A %.2f dBm, n %.3f (se %.3f), %d links, %s, change %.2f dB", now,
                 fit.rssi_at_1m_dbm, fit.path_loss_exponent, fit.se_exponent, fit.links,
                 "well-conditioned" if fit.conditioned else f"not well-conditioned ({fit.reason})", self.change_db)
        if self.cfg.apply and fit.conditioned and self.change_db >= APPLY_CHANGE_DB:
            self.in_use, self.applied_t = fitted, now
            self.applied += 1
            log.warning("peer fit used from t=%.1f on (its model moves the predicted RSSI by %.2f dB RMS): "
                        "rssi_at_1m_dbm %.2f, path_loss_exponent %.3f", now, self.change_db,
                        fitted.radio.rssi_at_1m_dbm, fitted.radio.path_loss_exponent)
            if self.on_model is not None:
                self.on_model(fitted)
        return fit

    def to_json(self) -> dict:
        """What the health reports: the last fit, when, whether the estimators use it."""
        r = self.readings
        out: dict = {"readings": r.readings, "unknown_anchor": r.unknown_anchor, "itself": r.itself,
                     "fits": self.fits, "applied": self.applied, "apply": self.cfg.apply,
                     "refit_s": self.cfg.refit_s}
        if self.fit is not None:
            out.update(fit=self.fit.to_json(), fit_t=self.fit_t, applied_t=self.applied_t,
                       change_db=None if self.change_db is None else round(self.change_db, 3),
                       in_use={"rssi_at_1m_dbm": self.in_use.radio.rssi_at_1m_dbm,
                               "path_loss_exponent": self.in_use.radio.path_loss_exponent})
        elif self.not_fitted:
            out["not_fitted"] = self.not_fitted
        return out

    def line(self) -> str:
        """The health line's part."""
        f = self.fit
        if f is None:
            return f"peers {self.readings.readings} readings, no fit yet"
        state = "in use" if self.applied_t is not None and self.applied_t == self.fit_t else (
            "well-conditioned" if f.conditioned else "not well-conditioned")
        return (f"peers n={f.path_loss_exponent:.2f} A={f.rssi_at_1m_dbm:.1f} {f.links} links {state}")
