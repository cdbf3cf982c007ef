"""Fit the radio model (rssi_at_1m_dbm A, path_loss_exponent n, per-anchor offsets) to readings
taken at known positions, and measure how honest the filter's uncertainty is on that site.

Model (the one in :mod:`pfdoa.radio`)::

    rssi_k = A - 10 n log10(d_k) + offset_{anchor(k)} + noise

This is linear in (A, n, offsets); A and the offsets are only defined up to a common
constant (the gauge), fixed either by ``sum(offsets) = 0`` or by one reference anchor whose
offset is 0. Ordinary least squares, or Huber-weighted IRLS (``robust=True``) so that a few
multipath outliers do not drag the fit.

Readings that cannot separate every parameter are still a calibration, of fewer parameters:
a static beacon gives one distance per anchor, which the anchors' offsets could explain
alone, so the offsets are left at zero and A and n fitted; readings that all lie at one
distance (a beacon at the centre of a symmetric layout) fit A alone, n kept from the site.
The result says which (``CalibrationResult.note``).

Uncertainty (:func:`learn_uncertainty`): calibration traces have ground truth, so they show
how far the filter's reported 95 % radius and covariance are from its actual errors on this
site (model misfit, readings correlated in time). Out of sample: each trace is left out in
turn (or, with ``fit_on``, one trace is fitted and each other one scored); the model is
fitted on the rest and ``pf-doa`` run over the left-out trace's time windows with factors of
1 (its particles' spread, with the RSS noise's share of the online noise estimate). First the
estimate's gain about the search box's centre (``estimate_gain``, :func:`fit_gain`): the
least-squares g of truth - centre on estimate - centre (one number, or a symmetric matrix
where that predicts each fold from the others better), below 1 where the filter's estimates
scatter further out than the target goes (readings that say less than the filter believes);
then, on the errors of the estimates moved by it, the 95 % quantiles of error / r95 and of the
squared Mahalanobis distance / 5.991 are the factors (``r95_scale``, ``cov_scale``;
``*_odometry`` and ``estimate_gain_odometry`` from runs with their odometry) that the fitted
site file carries in its ``[estimator]`` table. pf-doa applies them in place of its online
widening for the residuals' correlation in time, which does not follow the error from one
run to another (:meth:`pfdoa.estimators.pf_doa.PfDoa._uncertainty_scale`). It takes two or
more traces: two halves of one run share its radio conditions and cannot show how well
another run will match the fit; on the development runs their factors moved the coverage of
other runs away from 95 %, not towards it (docs/estimator-study.md), so a single trace gets
no factors.

The same runs choose how pf-doa treats its residuals in time (``residual_rho``, and
``residual_rho_odometry`` with odometry): each candidate of ``WHITENING_CANDIDATES`` is scored
on the same folds, and the one whose estimates (moved by its own gain) have the lowest RMSE
is kept if that is WHITENING_MARGIN below the plain filter's (:func:`choose_whitening`); the
factors and gain are those measured with the choice. Readings held or slowly varying
between observations (a Wi-Fi node's sample-and-hold) make errors correlated in time that
whitening models; a walker's residuals, correlated by the walls passed, are not helped by it
(docs/estimator-study.md): which holds is a property of the site that its runs show.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from pfdoa.errors import InputError
from pfdoa.estimators.common import FACTOR_KEYS, FACTOR_RULE
from pfdoa.estimators.gain import IDENTITY, EstimateGain
from pfdoa.radio import MIN_DISTANCE_M, PathLoss, distances
from pfdoa.radiomap import BLOCK_S, RadioMap, fit_radio_map
from pfdoa.site import MIN_PATH_LOSS_EXPONENT, Site
from pfdoa.trace import DEFAULT_WINDOW_S, Trace, Window, ground_truth_at

HUBER_K = 1.345  # 95 % efficiency under Gaussian noise
# Uncertainty factors (learn_uncertainty): estimator seeds per fold, the fewest scored windows
# per motion mode worth a factor, and the factors' bounds.
UNCERTAINTY_SEEDS = 3
MIN_UNCERTAINTY_WINDOWS = 20
R95_SCALE_RANGE = (0.2, 10.0)
COV_SCALE_RANGE = (0.04, 100.0)
GAIN_RANGE = (0.05, 1.0)  # the estimate's gain about the centre: never away from it
GAIN_RIDGE = 0.01  # how far fit_gain leans towards the isotropic gain (share of the offsets' power)
MAX_IRLS_ITERATIONS = 50
# pf-doa's residual_rho values the calibration runs choose from (0: independent in time; 0.5
# the value measured best where whitening helps, the robot's sample-and-hold readings).
WHITENING_CANDIDATES = (0.0, 0.5)
# A candidate other than the first is chosen only when its folds' RMSE is this much lower:
# where whitening changes nothing, the folds' RMSE still differs by up to 3 % (the robot's
# development runs without odometry, 30 pairs), and where it helps by 5-13 % (with odometry).
WHITENING_MARGIN = 0.03
CHOSEN_KEYS = ("residual_rho", "residual_rho_odometry")  # chosen on the runs beside the factors
# A calibration trace that reaches past the estimators' search box grows it to cover the
# trace when that adds at least this share of its area (covering_area).
AREA_GROWTH_MIN = 0.1
# Below this spread of log10(distance) A and n cannot be told apart.
MIN_LOG_DISTANCE_SPREAD = 0.05


@dataclass(frozen=True)
class AnchorFit:
    id: int
    readings: int
    offset_db: float
    rms_db: float  # residual RMS of this anchor's readings (NaN without readings)
    bias_db: float  # mean residual (NaN without readings)


@dataclass(frozen=True)
class CalibrationResult:
    rssi_at_1m_dbm: float
    path_loss_exponent: float
    anchors: tuple[AnchorFit, ...]
    rms_db: float  # residual RMS over all readings used
    readings: int
    robust: bool
    gauge: str  # "sum-zero", "reference <id>" or "none"
    radio_map: RadioMap | None = None  # calibrate_traces(radio_map=True): None when not trusted
    radio_map_note: str = ""  # why there is no map, or what it holds (report)
    note: str = ""  # which parameters the readings could not determine, and what was fitted instead
    extent: tuple[float, float, float, float] | None = None  # (xmin, ymin, xmax, ymax) of the positions fitted

    @property
    def offsets(self) -> np.ndarray:
        return np.array([a.offset_db for a in self.anchors])

    def apply(self, site: Site) -> Site:
        """``site`` with the fitted radio parameters and offsets (positions and sections kept)."""
        by_id = {a.id: a.offset_db for a in self.anchors}
        anchors = tuple(dataclasses.replace(a, rssi_offset_db=round(by_id.get(a.id, 0.0), 4)) for a in site.anchors)
        radio = PathLoss(round(self.rssi_at_1m_dbm, 4), round(self.path_loss_exponent, 4))
        # A map of the input site belongs to its old model: replaced, or dropped.
        sections = {k: v for k, v in site.sections.items() if k != "radio_map"}
        if self.radio_map is not None:
            sections["radio_map"] = self.radio_map.to_section()
        return dataclasses.replace(site, radio=radio, anchors=anchors, sections=sections,
                                   area=covering_area(site, self.extent))

    def report(self) -> str:
        """Human-readable summary: parameters and residuals per anchor."""
        lines = [
            f"rssi_at_1m_dbm     = {self.rssi_at_1m_dbm:.2f} dBm",
            f"path_loss_exponent = {self.path_loss_exponent:.3f}",
            f"fit: {'Huber IRLS' if self.robust else 'least squares'}, offsets gauge {self.gauge}, "
            f"{self.readings} readings, residual RMS {self.rms_db:.2f} dB",
        ]
        w = max([6] + [len(str(a.id)) for a in self.anchors])  # a dataset's ids may be 10 digits
        lines.append(f"{'anchor':>{w}}  readings  offset_dB  rms_dB  bias_dB")
        for a in self.anchors:
            lines.append(f"{a.id:>{w}}  {a.readings:>8}  {a.offset_db:>9.2f}  {a.rms_db:>6.2f}  {a.bias_db:>7.2f}")
        if self.note:
            lines.append(self.note)
        if self.radio_map_note:
            lines.append(self.radio_map_note)
        return "\n".join(lines)


def covering_area(site: Site, extent: tuple[float, float, float, float] | None
                  ) -> tuple[float, float, float, float] | None:
    """The site's area grown to cover ``extent`` (where calibration saw the target), when that
    adds at least AREA_GROWTH_MIN to it; else the site's own area (None: around the anchors).

    Anchors on a ceiling or inset from the walls leave the floor's edges outside their
    bounding box, where the estimators never look; the calibration trace shows the target
    goes there. Small excursions (a robot's edge of the arena, a tracking system's offset) are
    left to the margin: the box is a strong prior (letting the particles 10 % of the anchors'
    span past it cost 20 % on the robot's development runs without odometry), and a larger
    box costs accuracy wherever the target stays inside."""
    from pfdoa.estimators.common import default_margin, search_box

    if extent is None:
        return site.area
    lo, hi = search_box(site, default_margin(site.positions))
    new_lo, new_hi = np.minimum(lo, extent[:2]), np.maximum(hi, extent[2:])
    if float(np.prod(new_hi - new_lo)) < (1.0 + AREA_GROWTH_MIN) * float(np.prod(hi - lo)):
        return site.area
    return (round(float(new_lo[0]), 3), round(float(new_lo[1]), 3), round(float(new_hi[0]), 3), round(float(new_hi[1]), 3))


def _huber_weights(r: np.ndarray) -> np.ndarray:
    scale = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    if not scale > 1e-9:
        return np.ones_like(r)
    a = np.abs(r) / (HUBER_K * scale)
    return np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))


def fit_path_loss(
    points: np.ndarray,
    anchor_index: np.ndarray,
    rssi_dbm: np.ndarray,
    site: Site,
    *,
    offsets: bool = True,
    reference_anchor: int | None = None,
    robust: bool = False,
) -> CalibrationResult:
    """Fit A, n and per-anchor offsets.

    points: (k, 2) transmitter positions; anchor_index: (k,) index into ``site.anchors``;
    rssi_dbm: (k,). ``offsets=False`` fits A and n only; otherwise the gauge is
    ``sum(offsets) = 0`` over anchors with readings, or offset(reference_anchor) = 0.
    """
    points = np.asarray(points, dtype=float)
    idx = np.asarray(anchor_index, dtype=int)
    y = np.asarray(rssi_dbm, dtype=float)
    keep = np.isfinite(y) & np.all(np.isfinite(points), axis=1)
    points, idx, y = points[keep], idx[keep], y[keep]
    n_anchors = len(site.anchors)
    if y.size < 3:
        raise InputError(f"calibration needs readings at known positions; got {y.size}")
    d = distances(points, site.positions, MIN_DISTANCE_M)[np.arange(y.size), idx]
    logd = np.log10(d)
    counts = np.bincount(idx, minlength=n_anchors)
    present = np.flatnonzero(counts > 0)
    note = ""
    if float(logd.max() - logd.min()) < MIN_LOG_DISTANCE_SPREAD:
        # One distance: A alone is determined; n is the site's, the offsets zero.
        n_fixed = site.radio.path_loss_exponent
        X = np.ones((y.size, 1))
        y_fit = y + 10.0 * n_fixed * logd
        gauge = "none"
        free: list[int] = []
        note = (f"calibration: the transmitter-anchor distances span too little ({d.min():.2f}..{d.max():.2f} m) "
                f"to separate rssi_at_1m_dbm from path_loss_exponent: fitted rssi_at_1m_dbm alone, "
                f"path_loss_exponent kept at the site's {n_fixed:g}, no offsets")
    else:
        n_fixed = None
        y_fit = y
        X, free, gauge = _design(logd, idx, present, site, counts, offsets, reference_anchor)
        if np.linalg.matrix_rank(X) < X.shape[1]:
            if X.shape[1] == 2:
                raise InputError("calibration: the readings do not determine the parameters (degenerate geometry)")
            # e.g. a static beacon: each anchor's offset could explain its one distance alone.
            X, free, gauge = _design(logd, idx, present, site, counts, False, None)
            note = ("calibration: the readings do not separate the per-anchor offsets from the distances "
                    "(e.g. a static beacon: one distance per anchor): fitted rssi_at_1m_dbm and "
                    "path_loss_exponent, no offsets")

    beta = _irls(X, y_fit, robust)
    if n_fixed is None and 0.0 < beta[1] < MIN_PATH_LOSS_EXPONENT:
        # The readings barely follow distance (a flat room, a body-worn tag): the fit is real,
        # but no site file holds it. A and the offsets are fitted again with n at the minimum,
        # so pfdoa eval scores exactly what calibrate writes and replay reads.
        held = (f"calibration: the readings barely follow distance (fitted path_loss_exponent {beta[1]:.3f}): "
                f"path_loss_exponent held at the site file's minimum {MIN_PATH_LOSS_EXPONENT:g}, "
                "rssi_at_1m_dbm and the offsets fitted with it")
        note = f"{note}\n{held}" if note else held
        n_fixed = MIN_PATH_LOSS_EXPONENT
        y_fit = y + 10.0 * n_fixed * logd
        X = np.delete(X, 1, axis=1)
        beta = _irls(X, y_fit, robust)
    first_offset = 2 if n_fixed is None else 1  # the columns: A, [n,] free offsets

    a1m = float(beta[0])
    n = float(beta[1]) if n_fixed is None else float(n_fixed)
    off = np.zeros(n_anchors)
    if free:
        off[free] = beta[first_offset:]
        if gauge == "sum-zero":
            off[present[-1]] = -float(np.sum(beta[first_offset:]))
    resid = y_fit - X @ beta
    fits = []
    for j, a in enumerate(site.anchors):
        r = resid[idx == j]
        fits.append(AnchorFit(
            id=a.id, readings=int(r.size), offset_db=float(off[j]),
            rms_db=float(np.sqrt(np.mean(r**2))) if r.size else math.nan,
            bias_db=float(np.mean(r)) if r.size else math.nan,
        ))
    return CalibrationResult(
        rssi_at_1m_dbm=a1m, path_loss_exponent=n, anchors=tuple(fits),
        rms_db=float(np.sqrt(np.mean(resid**2))), readings=int(y.size), robust=robust, gauge=gauge, note=note,
        extent=(float(points[:, 0].min()), float(points[:, 1].min()), float(points[:, 0].max()), float(points[:, 1].max())),
    )


def _irls(X: np.ndarray, y: np.ndarray, robust: bool) -> np.ndarray:
    """Least squares of ``y`` on ``X``; with ``robust``, Huber-reweighted until it settles."""
    w = np.ones_like(y)
    beta = np.zeros(X.shape[1])
    for _ in range(MAX_IRLS_ITERATIONS if robust else 1):
        sw = np.sqrt(w)
        new, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
        converged = np.allclose(new, beta, atol=1e-6)
        beta = new
        if robust:
            w = _huber_weights(y - X @ beta)
            if converged:
                break
    return beta


def _design(logd: np.ndarray, idx: np.ndarray, present: np.ndarray, site: Site, counts: np.ndarray,
            offsets: bool, reference_anchor: int | None) -> tuple[np.ndarray, list[int], str]:
    """(design matrix over [A, n, free offsets], the anchors whose offset is free, gauge)."""
    cols = [np.ones_like(logd), -10.0 * logd]
    free: list[int] = []
    gauge = "none"
    if offsets and present.size > 1:
        if reference_anchor is not None:
            try:
                ref = site.index_of(reference_anchor)
            except KeyError:
                raise InputError(f"reference anchor {reference_anchor} is not in the site") from None
            if counts[ref] == 0:
                raise InputError(f"reference anchor {reference_anchor} has no readings")
            free = [int(j) for j in present if j != ref]
            for j in free:
                cols.append((idx == j).astype(float))
            gauge = f"reference {reference_anchor}"
        else:
            # Sum-zero: the last present anchor's offset is minus the sum of the others.
            last = present[-1]
            free = [int(j) for j in present[:-1]]
            for j in free:
                cols.append((idx == j).astype(float) - (idx == last).astype(float))
            gauge = "sum-zero"
    return np.column_stack(cols), free, gauge


def trace_readings(trace: Trace, site: Site) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(points, anchor_index, rssi, skipped_unknown_anchor) of the readings with ground truth."""
    if trace.gt_x is None or trace.gt_y is None:
        raise InputError(f"{trace.source}: calibration needs ground truth columns gt_x,gt_y")
    index = {aid: i for i, aid in enumerate(site.anchor_ids)}
    ai = np.array([index.get(int(a), -1) for a in trace.anchor], dtype=int)
    known = ai >= 0
    gt = np.column_stack([trace.gt_x, trace.gt_y])
    ok = known & np.all(np.isfinite(gt), axis=1)
    return gt[ok], ai[ok], trace.rssi_dbm[ok], int(np.count_nonzero(~known))


def calibrate_traces(traces: list[Trace], site: Site, *, radio_map: bool = True, window_s: float = DEFAULT_WINDOW_S,
                     prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                     **options) -> CalibrationResult:
    """Fit the radio model to every reading with ground truth in ``traces`` (see
    :func:`fit_path_loss`); with ``radio_map``, also the map of what the model misses
    (:mod:`pfdoa.radiomap`, over the traces' ``window_s`` time windows), kept where it
    predicts parts of the traces it was not fitted on. ``prior``: pseudo-readings (points,
    anchor index, rssi) fitted with the readings, holding the fit near another one's
    (:func:`pfdoa.peercal.prior_readings`); the radio map sees the traces alone."""
    parts = [trace_readings(t, site) for t in traces]
    pts = np.concatenate([p[0] for p in parts])
    if pts.shape[0] == 0:
        raise InputError("calibration: no readings with ground truth from anchors of the site")
    if prior is not None:
        parts.append(prior + (0,))
        pts = np.concatenate([pts, prior[0]])
    fit = fit_path_loss(pts, np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts]),
                        site, **options)
    if not radio_map:
        return fit
    return _with_radio_map(fit, traces, site, window_s)


def _with_radio_map(fit: CalibrationResult, traces: list[Trace], site: Site, window_s: float) -> CalibrationResult:
    from pfdoa.estimators.pf_doa import MAX_EXPONENT, MIN_EXPONENT
    from pfdoa.trace import by_beacon, group_by_window

    fitted = fit.apply(site)
    # The exponent pf-doa runs with (raised to the physical floor): the map corrects that model.
    exponent = min(max(fitted.radio.path_loss_exponent, MIN_EXPONENT), MAX_EXPONENT)
    # Each trace one run of windows (its blocks of time shared by its beacons), each beacon's
    # readings windowed alone: a window never mixes two beacons' readings and places.
    rmap = fit_radio_map(fitted, [[w for _, part in by_beacon(t) for w in group_by_window(part, fitted, window_s)]
                                  for t in traces], exponent)
    if rmap is None:
        note = ("radio map: none (the residuals do not repeat at a place across parts of the traces: "
                "nothing it would learn predicts the rest)")
    else:
        note = (f"radio map: {rmap.x.size} cells of {rmap.length_m:g} m kernel, trust {rmap.trust:.2f} "
                f"(the share of its fit that predicts {BLOCK_S:g} s blocks it was not fitted on)")
    return dataclasses.replace(fit, radio_map=rmap, radio_map_note=note)


@dataclass(frozen=True)
class UncertaintyScale:
    """Factors on pf-doa's r95 and cov measured out of sample on calibration traces."""

    r95: float
    cov: float
    windows: int  # scored time windows per seed behind the factors without odometry
    folds: str  # how the traces were split
    r95_odometry: float | None = None
    cov_odometry: float | None = None
    windows_odometry: int = 0
    gain: EstimateGain = IDENTITY  # the estimate's gain about the search box's centre (fit_gain)
    gain_odometry: EstimateGain = IDENTITY
    rho: float = 0.0  # the residual whitening chosen on the same folds (WHITENING_CANDIDATES)
    rho_odometry: float = 0.0

    def options(self) -> dict[str, float | list[float]]:
        """The ``[estimator]`` keys: the factors pf-doa reads and the rule they were measured
        under; a gain only when it moves the estimate."""
        out: dict[str, float | list[float]] = {"r95_scale": round(self.r95, 4), "cov_scale": round(self.cov, 4)}
        if self.r95_odometry is not None and self.cov_odometry is not None:
            out.update(r95_scale_odometry=round(self.r95_odometry, 4), cov_scale_odometry=round(self.cov_odometry, 4))
        for key, g in (("estimate_gain", self.gain), ("estimate_gain_odometry", self.gain_odometry)):
            written = g.rounded()
            if not written.identity:
                out[key] = written.option()
        for key, rho in zip(CHOSEN_KEYS, (self.rho, self.rho_odometry)):
            if rho > 0.0:
                out[key] = rho
        out["factor_rule"] = FACTOR_RULE
        return out

    def apply(self, site: Site) -> Site:
        """``site`` with these factors in its ``[estimator]`` table (other keys kept)."""
        table = {k: v for k, v in site.sections.get("estimator", {}).items() if k not in _SCALE_KEYS}
        return dataclasses.replace(site, sections={**site.sections, "estimator": {**table, **self.options()}})

    def report(self) -> str:
        line = (f"uncertainty ({self.folds}, {self.windows} windows x {UNCERTAINTY_SEEDS} seeds): "
                f"r95 x {self.r95:.2f}, cov x {self.cov:.2f}, estimate gain {self.gain}, "
                f"residual whitening {self.rho:g}")
        if self.r95_odometry is not None:
            line += (f"; with odometry ({self.windows_odometry} windows) r95 x {self.r95_odometry:.2f}, "
                     f"cov x {self.cov_odometry:.2f}, estimate gain {self.gain_odometry}, "
                     f"residual whitening {self.rho_odometry:g}")
        return line


_SCALE_KEYS = (*FACTOR_KEYS, *CHOSEN_KEYS, "factor_rule")  # what apply() replaces


class FoldScore(NamedTuple):
    """One scored trace of :func:`learn_uncertainty`: pf-doa without factors, every scored
    window of every seed (:func:`score_uncertainty`)."""

    error: np.ndarray  # (k, 2) truth - estimate, m
    offset: np.ndarray  # (k, 2) estimate - the search box's centre (PfDoa.box_centre), m
    r95: np.ndarray  # (k,) the particles' 95 % radius
    cov: np.ndarray  # (k, 3) the particles' covariance (xx, xy, yy)
    windows: int  # scored windows per seed (every seed scores the same windows)

    def moved_errors(self, gain: EstimateGain = IDENTITY) -> np.ndarray:
        """(k, 2) truth - estimate, each estimate moved by ``gain`` towards the centre
        (``estimate_gain``: estimate - centre mapped by G)."""
        if gain.identity:
            return self.error
        return self.error + self.offset - self.offset @ gain.matrix()  # G is symmetric

    def ratios(self, gain: EstimateGain = IDENTITY) -> tuple[np.ndarray, np.ndarray]:
        """(error / r95, squared Mahalanobis distance) of the estimate moved by ``gain``
        towards the centre (``estimate_gain``); inf where the spread claims certainty."""
        from pfdoa.estimators.base import mahalanobis2_many

        e = self.moved_errors(gain)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.r95 > 0.0, np.hypot(e[:, 0], e[:, 1]) / self.r95, math.inf)
        return ratio, mahalanobis2_many(e, self.cov)

    def squared_errors(self, gain: EstimateGain = IDENTITY) -> np.ndarray:
        """Squared error of each estimate moved by ``gain`` towards the centre."""
        e = self.moved_errors(gain)
        return np.einsum("ij,ij->i", e, e)


def score_uncertainty(trace: Trace, site: Site, odometry, window_s: float, by_seq: bool = False,
                      rho: float = 0.0) -> FoldScore:
    """pf-doa without factors (and gain 1), with residual whitening ``rho``, over ``trace``'s
    time windows (``by_seq``: one observation per beacon sequence number, as the gateway's seq
    mode groups them), seeds 0..UNCERTAINTY_SEEDS-1: its errors, estimates and spreads
    (:class:`FoldScore`). Each
    beacon the trace names is tracked alone (its own windows and filter, as replay does);
    with ``odometry``, only the readings it belongs to (:func:`pfdoa.trace.odometry_part`)."""
    from pfdoa.estimators import make_estimator
    from pfdoa.estimators.base import Observation
    from pfdoa.estimators.pf_doa import PfDoa
    from pfdoa.trace import by_beacon, group_by_window, odometry_part

    parts = [odometry_part(trace)] if odometry is not None else [p for _, p in by_beacon(trace)]
    table = {k: v for k, v in site.sections.get("estimator", {}).items() if k not in _SCALE_KEYS and k != "method"}
    raw: dict[str, float] = {k: 1.0 for k in FACTOR_KEYS}  # what the factors multiply
    raw.update(dict.fromkeys(CHOSEN_KEYS, rho))
    rows: list[tuple[float, float, float, float, float, float, float, float]] = []
    scored = 0
    for part in parts:
        windows = gateway_sets(part, site) if by_seq else list(group_by_window(part, site, window_s))
        odo = None
        if odometry is not None:
            from pfdoa.evaluation.datasets import odometry_between

            odo = odometry_between(odometry, np.array([w.t for w in windows]))
        for seed in range(UNCERTAINTY_SEEDS):
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed), **{**table, **raw})
            assert isinstance(est, PfDoa)
            cx, cy = est.box_centre
            n = 0
            for i, w in enumerate(windows):
                e = est.step(Observation(w.t, w.rssi, w.count), None if odo is None else odo[i])
                if w.gt is None or not (math.isfinite(e.x) and math.isfinite(e.y)) or e.cov is None:
                    continue
                rows.append((w.gt[0] - e.x, w.gt[1] - e.y, e.x - cx, e.y - cy, e.r95, *e.cov))
                n += 1
        scored += n  # windows per seed (every seed scores the same windows)
    a = np.array(rows, dtype=float).reshape(-1, 8)
    return FoldScore(a[:, 0:2], a[:, 2:4], a[:, 4], a[:, 5:8], scored)


def gateway_sets(trace: Trace, site: Site) -> list[Window]:
    """The observations the gateway makes of ``trace``'s readings in seq mode: its
    :class:`~pfdoa.gateway.reassembly.SeqReassembler` with the site's ``[gateway]`` timeouts
    and bounds, its timers run on the readings' times as ``pfdoa replay`` runs them (before
    each reading with a new time, then flushed), so duplicates, late reports and timed-out
    sets are what the live gateway would make of them. Each set is stamped with its time
    (the median of its readings') and the ground truth of the latest reading at or before
    it. The trace needs a ``seq`` column."""
    from pfdoa.gateway.config import gateway_config
    from pfdoa.gateway.decoding import make_grouper
    from pfdoa.gateway.reassembly import Reading

    if trace.seq is None:
        raise InputError(f"{trace.source or 'trace'}: grouping by beacon sequence needs a seq column")
    grouper = make_grouper(site.anchor_ids, gateway_config(site.sections), "seq")
    t, anchor, rssi, seq = trace.t.tolist(), trace.anchor.tolist(), trace.rssi_dbm.tolist(), trace.seq.tolist()
    sets = []
    last_t = None
    for i in range(len(t)):
        if t[i] != last_t:
            sets += grouper.poll(t[i])
            last_t = t[i]
        sets += grouper.push(Reading(int(anchor[i]), rssi[i], t[i], int(seq[i]) & 0xFFFF))
    sets += grouper.flush()
    ids = site.anchor_ids
    at = np.maximum(np.searchsorted(trace.t, [s.t for s in sets], side="right") - 1, 0)
    return [Window(s.t, s.vector(ids), ground_truth_at(trace, k), s.count_vector(ids)) for s, k in zip(sets, at.tolist())]


def learn_uncertainty(traces: list[Trace], site: Site, odometry: list | None = None, *, window_s: float = DEFAULT_WINDOW_S,
                      by_seq: bool = False, fit_on: int | None = None, **fit_options) -> UncertaintyScale | None:
    """Factors on pf-doa's r95 and cov, measured out of sample on ``traces`` (see the module
    doc); ``odometry`` (one :class:`~pfdoa.trace.OdometryTrace` or None per trace) adds the
    factors with odometry. pf-doa is scored on the observations the gateway will make: time
    windows of ``window_s``, or with ``by_seq`` one per beacon sequence number (the factors
    depend on the rate: a filter fed ten observations a second narrows faster than one fed
    one). The radio model is fitted over time windows either way. ``fit_on``: fit the model
    on ``traces[fit_on]`` alone and score each other trace, as a run calibrated on that one
    trace is used (default: each trace left out in turn, fitted on the others). None with a single trace (see the module doc) or when
    the traces are too short to measure them. ``fit_options`` go to :func:`calibrate_traces`
    for each fold's fit."""
    if len(traces) < 2:
        return None
    odometry = list(odometry) if odometry is not None else [None] * len(traces)
    folds: list[tuple[list[Trace], Trace, object]] = []
    if fit_on is not None:
        how = FIT_ON_ONE
        folds = [([traces[fit_on]], tr, odometry[i]) for i, tr in enumerate(traces) if i != fit_on]
    else:
        how = "each trace left out in turn"
        folds = [([t for j, t in enumerate(traces) if j != i], tr, odometry[i]) for i, tr in enumerate(traces)]
    modes = [False] + ([True] if any(o is not None for o in odometry) else [])
    scored: dict[float, dict[bool, list[FoldScore]]] = {rho: {m: [] for m in modes} for rho in WHITENING_CANDIDATES}
    for fit_traces, tr, odo in folds:
        try:
            fitted = calibrate_traces(fit_traces, site, window_s=window_s, **fit_options).apply(site)
        except InputError:  # e.g. a trace too short to separate A from n: no factor from it
            continue
        for rho in WHITENING_CANDIDATES:
            for with_odometry in modes:
                if with_odometry and odo is None:
                    continue
                scored[rho][with_odometry].append(score_uncertainty(tr, fitted, odo if with_odometry else None,
                                                                    window_s, by_seq, rho))
    return uncertainty_from({rho: (s[False], s.get(True, [])) for rho, s in scored.items()}, how)


FIT_ON_ONE = "fitted on one trace, each other one scored"


def fit_gain(folds: list[FoldScore]) -> EstimateGain:
    """The estimate's gain about the search box's centre measured on ``folds``: the truth's
    least-squares fit on the estimate (truth - centre ~ G (estimate - centre)), below 1 along a
    direction where the estimates scatter further from the centre than the truth goes (a
    filter surer than its readings are), which moving each estimate towards the centre
    corrects; never away from it. G is one number (:func:`_isotropic_gain`) unless a matrix
    (:func:`_matrix_gain`: an elongated room's estimates overshoot more along one axis) predicts
    the folds better, each fold from the others (leave one fold out): a matrix fitted on a few
    static points or one run maps those and not another (with a single fold: one number)."""
    iso = _isotropic_gain(folds)
    if len(folds) < 2:
        return iso
    sse_iso = sse_matrix = 0.0
    for i, left_out in enumerate(folds):
        rest = folds[:i] + folds[i + 1:]
        sse_iso += float(left_out.squared_errors(_isotropic_gain(rest)).sum())
        sse_matrix += float(left_out.squared_errors(_matrix_gain(rest)).sum())
    return _matrix_gain(folds) if sse_matrix < sse_iso else iso


def _isotropic_gain(folds: list[FoldScore]) -> EstimateGain:
    """The least-squares g of truth - centre ~ g (estimate - centre), within GAIN_RANGE."""
    off = np.concatenate([f.offset for f in folds])
    err = np.concatenate([f.error for f in folds])
    ss = float(np.einsum("ij,ij->", off, off))
    if not ss > 0.0:
        return IDENTITY
    return EstimateGain.isotropic(float(np.clip(1.0 + float(np.einsum("ij,ij->", off, err)) / ss, *GAIN_RANGE)))


def _matrix_gain(folds: list[FoldScore]) -> EstimateGain:
    """The least-squares symmetric G of truth - centre ~ G (estimate - centre), its eigenvalues
    held within GAIN_RANGE. It leans towards the isotropic gain by GAIN_RIDGE of the offsets'
    power, which decides it only where the estimates hardly vary along some direction."""
    off = np.concatenate([f.offset for f in folds])
    truth = off + np.concatenate([f.error for f in folds])  # truth - centre
    ss = float(np.einsum("ij,ij->", off, off))
    if not ss > 0.0:
        return IDENTITY
    g0 = float(np.einsum("ij,ij->", off, truth)) / ss  # the isotropic least-squares gain
    sxx, sxy, syy = float(off[:, 0] @ off[:, 0]), float(off[:, 0] @ off[:, 1]), float(off[:, 1] @ off[:, 1])
    lam = GAIN_RIDGE * 0.5 * ss
    # Normal equations of (xx, xy, yy) for truth_x ~ xx o_x + xy o_y, truth_y ~ xy o_x + yy o_y,
    # plus lam |G - g0 I|^2 (the off-diagonal counted twice, as in the Frobenius norm).
    lhs = np.array([[sxx + lam, sxy, 0.0], [sxy, sxx + syy + 2.0 * lam, sxy], [0.0, sxy, syy + lam]])
    rhs = np.array([float(truth[:, 0] @ off[:, 0]) + lam * g0,
                    float(truth[:, 0] @ off[:, 1]) + float(truth[:, 1] @ off[:, 0]),
                    float(truth[:, 1] @ off[:, 1]) + lam * g0])
    xx, xy, yy = np.linalg.solve(lhs, rhs)
    w, v = np.linalg.eigh(np.array([[xx, xy], [xy, yy]]))
    w = np.clip(w, *GAIN_RANGE)
    if w[0] == w[1]:  # exactly isotropic (e.g. held at 1 both ways: the identity, no rounding dust)
        return EstimateGain.isotropic(float(w[0]))
    return EstimateGain.from_matrix((v * w) @ v.T)


def choose_whitening(candidates: dict[float, list[FoldScore]]) -> tuple[float, EstimateGain]:
    """(rho, gain): the candidate whose folds' estimates, each moved by that candidate's own
    gain (:func:`fit_gain`), have the lowest RMSE, where that is at least WHITENING_MARGIN
    below the first candidate's (the plain filter); else the first."""
    scored: list[tuple[float, float, EstimateGain]] = []  # (RMSE, rho, gain)
    for rho, folds in candidates.items():
        gain = fit_gain(folds)
        scored.append((math.sqrt(float(np.concatenate([f.squared_errors(gain) for f in folds]).mean())), rho, gain))
    first = scored[0]
    best = min(scored[1:], key=lambda r: (r[0], r[1]), default=first)
    chosen = best if best[0] < (1.0 - WHITENING_MARGIN) * first[0] else first
    return chosen[1], chosen[2]


def uncertainty_from(scores: dict[float, tuple[list[FoldScore], list[FoldScore]]], how: str
                     ) -> UncertaintyScale | None:
    """The residual whitening, gain and factors from folds scored without and with odometry
    (:func:`score_uncertainty`) for each candidate ``rho`` (``scores[rho]`` = (without, with
    odometry)): per motion mode, the whitening and its gain first (:func:`choose_whitening`),
    then the factors on the errors of the estimates the gain moves, from that candidate's
    folds. None when the folds without odometry hold fewer than MIN_UNCERTAINTY_WINDOWS
    windows."""
    from pfdoa.estimators.base import CHI2_2DOF_95

    found: dict[bool, tuple[float, float, int, EstimateGain, float]] = {}
    for k, with_odometry in enumerate((False, True)):
        per_rho = {rho: pair[k] for rho, pair in scores.items()}
        windows = min(sum(f.windows for f in folds) for folds in per_rho.values())
        if windows < MIN_UNCERTAINTY_WINDOWS:
            continue
        rho, gain = choose_whitening(per_rho)
        folds = per_rho[rho]
        ratio, d2 = (np.concatenate(v) for v in zip(*(f.ratios(gain) for f in folds)))
        r95 = float(np.clip(np.quantile(ratio, 0.95), *R95_SCALE_RANGE))
        cov = float(np.clip(np.quantile(d2, 0.95) / CHI2_2DOF_95, *COV_SCALE_RANGE))
        found[with_odometry] = (r95, cov, windows, gain, rho)
    if False not in found:
        return None
    r95, cov, windows, gain, rho = found[False]
    odo_f = found.get(True)
    if odo_f is None:
        return UncertaintyScale(r95, cov, windows, how, gain=gain, rho=rho)
    return UncertaintyScale(r95, cov, windows, how, r95_odometry=odo_f[0], cov_odometry=odo_f[1],
                            windows_odometry=odo_f[2], gain=gain, gain_odometry=odo_f[3], rho=rho,
                            rho_odometry=odo_f[4])


__all__ = ["AnchorFit", "CalibrationResult", "UncertaintyScale", "fit_path_loss", "calibrate_traces",
           "learn_uncertainty", "score_uncertainty", "uncertainty_from", "fit_gain", "choose_whitening",
           "WHITENING_CANDIDATES", "FoldScore", "trace_readings",
           "gateway_sets"]
