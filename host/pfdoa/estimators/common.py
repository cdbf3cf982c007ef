"""Pieces every estimator shares: option validation, observation preparation, grids."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from pfdoa.errors import ConfigError, InputError
from pfdoa.estimators.base import Estimate
from pfdoa.radio import PathLoss

log = logging.getLogger(__name__)

SOURCE = "estimator"  # ConfigError source for estimator options
MAX_DT_S = 10.0  # a longer gap is treated as this long (a restart, not a teleport)
MAX_GRID_CELLS = 4_000_000


def _int_in(lo: int, hi: int) -> Callable[[str, Any], int]:
    def check(key: str, v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= int(v) <= hi:
            raise ConfigError(SOURCE, key, f"must be an integer in [{lo}, {hi}], got {v!r}")
        return int(v)

    return check


def _float_in(lo: float, hi: float, lo_open: bool = False) -> Callable[[str, Any], float]:
    def check(key: str, v: Any) -> float:
        ok = not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating))
        f = float(v) if ok else math.nan
        if not ok or not math.isfinite(f) or f > hi or f < lo or (lo_open and f == lo):
            lo_br = "(" if lo_open else "["
            raise ConfigError(SOURCE, key, f"must be a number in {lo_br}{lo}, {hi}], got {v!r}")
        return f

    return check


def _choice(*values: str) -> Callable[[str, Any], str]:
    def check(key: str, v: Any) -> str:
        if v not in values:
            raise ConfigError(SOURCE, key, f"must be one of {', '.join(values)}; got {v!r}")
        return str(v)

    return check


def _flag(key: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise ConfigError(SOURCE, key, f"must be true or false, got {v!r}")
    return v


# Every option any estimator understands, with its validator. Units in the names' docs.
OPTION_CHECKS: dict[str, Callable[[str, Any], Any]] = {
    "particles": _int_in(1, 1_000_000),  # number of particles
    "history": _int_in(1, 1000),  # M: DOA observations in the paper's weight product
    "window": _int_in(1, 1000),  # k: DOA smoothing window (Eqs. 4-5)
    "sigma_doa": _float_in(0.0, 2 * math.pi, lo_open=True),  # rad, DOA error 1-sigma
    "sigma_rss": _float_in(0.0, 100.0, lo_open=True),  # dB, RSS noise scale (pf-doa: the online estimate's start)
    "estimate": _choice("max", "mean"),  # the paper's filter: max-weight particle (paper) or weighted mean
    "resolution": _float_in(0.0, 100.0, lo_open=True),  # m, grid cell size
    "speed": _float_in(0.0, 100.0),  # m/s, process noise of the random walk per second
    "margin": _float_in(0.0, 1000.0),  # m, added around the anchors' bounding box
    "odometry_noise": _float_in(0.0, 10.0),  # fraction of each odometry increment (1-sigma)
    "resample_threshold": _float_in(0.0, 1.0),  # resample when ESS < this * N
    "iterations": _int_in(1, 1000),  # trilateration Gauss-Newton/LM iterations
    "min_anchors": _int_in(3, 1000),  # fewer present anchors -> no measurement update
    "jump_probability": _float_in(0.0, 1.0, lo_open=True),  # per observation: target left the cloud
    "speed_range": _float_in(1.0, 1000.0),  # per-particle speed log-uniform in [speed/r, speed*r]
    "velocity_time": _float_in(0.0, 1e6),  # s, correlation time of the velocity state (0 = random walk)
    # pf-doa without odometry: per second, the rate at which a particle leaps (0 = never), by a
    # displacement of 1-sigma leap_m per axis, starting again from rest (a mixture motion prior)
    "leap_rate": _float_in(0.0, 100.0),
    "leap_m": _float_in(0.0, 1000.0),
    # pf-doa: add the site's [radio_map] (pfdoa calibrate fits it) to the model RSS
    "radio_map": _flag,
    "method": lambda key, v: v,  # the [estimator] table may name the method; ignored here
}

# Options of earlier pf-doa versions, retired by issue 47 (docs/estimator.md, "Tried, not
# kept"): a site file that sets one still loads, with one warning naming the key, and the
# value is ignored. The uncertainty factors, estimate gain and residual whitening that
# `pfdoa calibrate` wrote from two or more runs are among them: pf-doa's own uncertainty
# (the cloud and the model's running misfit) replaced them.
RETIRED_OPTIONS = frozenset({
    "doa_weight", "tail_dof", "exponent_spread", "adapt_sigma", "power_sigma", "learn_power", "defensive_share",
    "defensive_candidates", "r95_scale", "cov_scale", "r95_scale_odometry", "cov_scale_odometry", "estimate_gain",
    "estimate_gain_odometry", "factor_rule", "spread_correction", "shadowing_db", "residual_rho",
    "residual_rho_odometry",
})
_warned: set[str] = set()


def check_options(method: str, accepted: frozenset[str], options: dict[str, Any]) -> dict[str, Any]:
    """Validate ``options``: unknown names raise; names that belong to other methods are
    ignored (one [estimator] table can configure several methods), and so are retired ones
    (RETIRED_OPTIONS), with a warning."""
    out: dict[str, Any] = {}
    for key, value in options.items():
        if key in RETIRED_OPTIONS:
            if key not in _warned:  # once per process: every beacon and run builds an estimator
                _warned.add(key)
                log.warning("estimator option %r is retired (docs/estimator.md) and ignored", key)
            continue
        check = OPTION_CHECKS.get(key)
        if check is None:
            raise ConfigError(SOURCE, key, f"unknown estimator option (known: {', '.join(sorted(OPTION_CHECKS))})")
        v = check(key, value)
        if key in accepted:
            out[key] = v
    return out


@dataclass
class Prepared:
    """An observation with offsets removed: rssi (n,) NaN where missing, mask, count."""

    rssi: np.ndarray
    mask: np.ndarray
    count: int
    ids: tuple[int, ...]


class ObservationPrep:
    """Removes per-anchor offsets and finds the present anchors, into preallocated arrays."""

    def __init__(self, site) -> None:
        self.offsets = site.offsets.copy()
        self.ids = site.anchor_ids
        self.n = len(self.ids)
        self.rssi = np.empty(self.n)
        self.mask = np.empty(self.n, dtype=bool)
        self._all_ids = tuple(self.ids)

    def __call__(self, obs) -> Prepared:
        r = np.asarray(obs.rssi, dtype=float)
        if r.shape != (self.n,):
            raise InputError(f"observation has {r.shape} RSSI values, the site has {self.n} anchors")
        np.subtract(r, self.offsets, out=self.rssi)
        np.isfinite(self.rssi, out=self.mask)
        count = int(np.count_nonzero(self.mask))
        if count == self.n:
            ids = self._all_ids
        else:
            ids = tuple(self.ids[i] for i in np.flatnonzero(self.mask))
        return Prepared(self.rssi, self.mask, count, ids)


def kept_last(t: float, last: np.ndarray, p: Prepared) -> Estimate:
    """What a snapshot method returns with too few anchors: its last estimate, flagged."""
    return Estimate(t, float(last[0]), float(last[1]), math.nan, None, p.ids,
                    {"degraded": f"only {p.count} anchors present, kept the last estimate"})


def bounding_box(positions: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo = positions.min(axis=0) - margin
    hi = positions.max(axis=0) + margin
    return lo, hi


def search_box(site, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Where a method looks for the target: the site's ``area`` when it has one, else the
    anchors' bounding box grown by ``margin``."""
    if site.area is not None:
        x0, y0, x1, y1 = site.area
        return np.array([x0, y0], dtype=float), np.array([x1, y1], dtype=float)
    return bounding_box(site.positions, margin)


def default_margin(positions: np.ndarray) -> float:
    """A small margin: 5 % of the larger side of the anchors' bounding box."""
    ext = positions.max(axis=0) - positions.min(axis=0)
    return 0.05 * float(ext.max())


def make_grid(lo: np.ndarray, hi: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres over [lo, hi]: xs (nx,), ys (ny,), points (ny * nx, 2) row-major in y."""
    nx = max(1, int(math.floor((hi[0] - lo[0]) / resolution)) + 1)
    ny = max(1, int(math.floor((hi[1] - lo[1]) / resolution)) + 1)
    if nx * ny > MAX_GRID_CELLS:
        raise ConfigError(SOURCE, "resolution", f"{resolution} m gives {nx * ny} cells (max {MAX_GRID_CELLS})")
    xs = lo[0] + resolution * np.arange(nx)
    ys = lo[1] + resolution * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys)
    return xs, ys, np.column_stack([gx.ravel(), gy.ravel()])


def model_of(site) -> PathLoss:
    return PathLoss.from_site(site)


def dt_between(t_prev: float | None, t: float) -> float:
    """Seconds since the previous observation, clamped to [0, MAX_DT_S]; 0 on the first."""
    if t_prev is None or not math.isfinite(t) or not math.isfinite(t_prev):
        return 0.0
    return min(max(t - t_prev, 0.0), MAX_DT_S)
