"""The radio model: log-distance path loss. One place, used by the simulator and the estimators.

    RSSI_i(p) = A - 10 * n * log10(max(|p - a_i|, d_min)) + offset_i

A is the RSSI at 1 m (dBm), n the path-loss exponent, a_i the anchor positions and
offset_i a per-anchor receiver offset (dB). Distances are clamped at ``d_min`` so a
position on top of an anchor stays finite.
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


def distances(points: np.ndarray, anchors: np.ndarray, min_distance_m: float = MIN_DISTANCE_M) -> np.ndarray:
    """Distances from points (..., 2) to anchors (n, 2) -> (..., n), clamped below at min_distance_m."""
    p = np.asarray(points, dtype=float)[..., None, :]
    d = np.sqrt(((p - np.asarray(anchors, dtype=float)) ** 2).sum(axis=-1))
    return np.maximum(d, min_distance_m)


def mean_rssi(
    points: np.ndarray,
    anchors: np.ndarray,
    model: PathLoss,
    offsets: np.ndarray | None = None,
) -> np.ndarray:
    """Noise-free RSSI (dBm) at anchors (n, 2) from transmitters at points (..., 2) -> (..., n)."""
    d = distances(points, anchors, model.min_distance_m)
    r = model.rssi_at_1m_dbm - 10.0 * model.path_loss_exponent * np.log10(d)
    if offsets is not None:
        r = r + np.asarray(offsets, dtype=float)
    return r


def distance_from_rssi(rssi_dbm: np.ndarray, model: PathLoss) -> np.ndarray:
    """Invert the model (offsets already removed): d = 10 ** ((A - RSSI) / (10 n))."""
    return 10.0 ** ((model.rssi_at_1m_dbm - np.asarray(rssi_dbm, dtype=float)) / (10.0 * model.path_loss_exponent))


def rssi_at_distance(d: np.ndarray, model: PathLoss) -> np.ndarray:
    """The model's RSSI (dBm, offsets excluded) at distances ``d`` (m, any shape), clamped
    below at ``min_distance_m``: for links whose distances are known already, such as the
    anchors' 3-D distances to each other (:mod:`pfdoa.peercal`)."""
    d = np.maximum(np.asarray(d, dtype=float), model.min_distance_m)
    return model.rssi_at_1m_dbm - 10.0 * model.path_loss_exponent * np.log10(d)
