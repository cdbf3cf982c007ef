"""Fit the radio model (rssi_at_1m_dbm A, path_loss_exponent n, per-anchor offsets) to readings
taken at known positions.

Model (the one in :mod:`pfdoa.radio`)::

    rssi_k = A - 10 n log10(d_k) + offset_{anchor(k)} + noise

(d_k the 3-D distance: the site's anchor heights above the target's plane, pfdoa.radio).
This is linear in (A, n, offsets); A and the offsets are only defined up to a common
constant (the gauge), fixed either by ``sum(offsets) = 0`` or by one reference anchor whose
offset is 0. Ordinary least squares, or Huber-weighted IRLS (``robust=True``) so that a few
multipath outliers do not drag the fit.

Readings that cannot separate every parameter are still a calibration, of fewer parameters:
a static beacon gives one distance per anchor, which the anchors' offsets could explain
alone, so the offsets are left at zero and A and n fitted; readings that all lie at one
distance (a beacon at the centre of a symmetric layout) fit A alone, n kept from the site.
The result says which (``CalibrationResult.note``).

With ``radio_map``, the residuals the model leaves are smoothed over the floor into a map
pf-doa adds to its model, kept where it predicts parts of the traces it was not fitted on
(:mod:`pfdoa.radiomap`). pf-doa's reported uncertainty needs nothing from the calibration:
it follows the model's running misfit online (:mod:`pfdoa.estimators.pf_uncertainty`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from pfdoa.errors import InputError
from pfdoa.radio import MIN_DISTANCE_M, PathLoss, distances
from pfdoa.radiomap import BLOCK_S, RadioMap, fit_radio_map
from pfdoa.site import MIN_PATH_LOSS_EXPONENT, Site
from pfdoa.trace import DEFAULT_WINDOW_S, Trace, Window, ground_truth_at

HUBER_K = 1.345  # 95 % efficiency under Gaussian noise
MAX_IRLS_ITERATIONS = 50
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

    points: (k, 2) transmitter positions (on the plane ``site.target_z``); anchor_index: (k,) index into ``site.anchors``;
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
    d = distances(points, site.positions, MIN_DISTANCE_M, site.heights)[np.arange(y.size), idx]
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
    (:func:`pfdoa.calibration.peercal.prior_readings`); the radio map sees the traces alone."""
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


def gateway_sets(trace: Trace, site: Site) -> list[Window]:
    """The observations the gateway makes of ``trace``'s readings in seq mode: its
    :class:`~pfdoa.readings.reassembly.SeqReassembler` with the site's ``[gateway]`` timeouts
    and bounds, its timers run on the readings' times as ``pfdoa replay`` runs them (before
    each reading with a new time, then flushed), so duplicates, late reports and timed-out
    sets are what the live gateway would make of them. Each set is stamped with its time
    (the median of its readings') and the ground truth of the latest reading at or before
    it. The trace needs a ``seq`` column."""
    from pfdoa.readings.config import gateway_config
    from pfdoa.readings.grouping import make_grouper
    from pfdoa.readings.reassembly import Reading

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


__all__ = ["AnchorFit", "CalibrationResult", "fit_path_loss", "calibrate_traces", "trace_readings",
           "gateway_sets"]
