"""The radio model: log-distance path loss. One place, used by the simulator and the estimators.

    RSSI_i(p) = A - 10 * n * log10(max(|p - a_i|, d_min)) + offset_i

A is the RSSI at 1 m (dBm), n the path-loss exponent, a_i the anchor positions and
offset_i a per-anchor receiver offset (dB). Distances are clamped at ``d_min`` so a
position on top of an anchor stays finite.

Distances are 3-D: positions are on the target's plane and each anchor sits ``h_i`` above it
(``heights``: :attr:`pfdoa.site.Site.heights`, anchor z minus the target's z), so
``|p - a_i|^2 = |p - a_i|_xy^2 + h_i^2``. Without heights (a site file without z) that is the
plane's distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_DISTANCE_M = 0.1


@dataclass(frozen=True)
class PathLoss:
    """Log-distance path loss (the module doc): a site file's ``[radio]`` table, and the
    model the simulator draws from and the estimators invert."""

    rssi_at_1m_dbm: float
    path_loss_exponent: float
    min_distance_m: float = MIN_DISTANCE_M

    @classmethod
    def from_site(cls, site) -> "PathLoss":  # site: pfdoa.site.Site, whose radio is a PathLoss
        return cls(site.radio.rssi_at_1m_dbm, site.radio.path_loss_exponent, site.radio.min_distance_m)


def squared_distances(points: np.ndarray, anchors: np.ndarray, heights: np.ndarray | None = None) -> np.ndarray:
    """Squared 3-D distances from points (..., 2) on the target's plane to anchors (n, 2)
    standing ``heights`` (n,) above it (None: on it) -> (..., n), unclamped."""
    p = np.asarray(points, dtype=float)[..., None, :]
    d2 = ((p - np.asarray(anchors, dtype=float)) ** 2).sum(axis=-1)
    if heights is not None:
        d2 = d2 + np.asarray(heights, dtype=float) ** 2
    return d2


def distances(points: np.ndarray, anchors: np.ndarray, min_distance_m: float = MIN_DISTANCE_M,
              heights: np.ndarray | None = None) -> np.ndarray:
    """Distances from points (..., 2) to anchors (n, 2) at ``heights`` above the points'
    plane -> (..., n), clamped below at min_distance_m."""
    return np.maximum(np.sqrt(squared_distances(points, anchors, heights)), min_distance_m)


def mean_rssi(
    points: np.ndarray,
    anchors: np.ndarray,
    model: PathLoss,
    offsets: np.ndarray | None = None,
    heights: np.ndarray | None = None,
) -> np.ndarray:
    """Noise-free RSSI (dBm) at anchors (n, 2), ``heights`` above the transmitters' plane,
    from transmitters at points (..., 2) -> (..., n)."""
    d = distances(points, anchors, model.min_distance_m, heights)
    r = model.rssi_at_1m_dbm - 10.0 * model.path_loss_exponent * np.log10(d)
    if offsets is not None:
        r = r + np.asarray(offsets, dtype=float)
    return r


def distance_from_rssi(rssi_dbm: np.ndarray, model: PathLoss) -> np.ndarray:
    """Invert the model (offsets already removed): d = 10 ** ((A - RSSI) / (10 n)), the 3-D
    distance."""
    return 10.0 ** ((model.rssi_at_1m_dbm - np.asarray(rssi_dbm, dtype=float)) / (10.0 * model.path_loss_exponent))


def rssi_at_distance(d: np.ndarray, model: PathLoss) -> np.ndarray:
    """The model's RSSI (dBm, offsets excluded) at distances ``d`` (m, any shape), clamped
    below at ``min_distance_m``: for links whose distances are known already, such as the
    anchors' 3-D distances to each other (:mod:`pfdoa.calibration.peercal`)."""
    d = np.maximum(np.asarray(d, dtype=float), model.min_distance_m)
    return model.rssi_at_1m_dbm - 10.0 * model.path_loss_exponent * np.log10(d)
