"""Pieces every estimator shares: option validation, observation preparation, grids."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from pfdoa import schema
from pfdoa.errors import ConfigError, InputError
from pfdoa.estimators.base import Estimate
from pfdoa.radio import PathLoss

log = logging.getLogger(__name__)

SOURCE = "estimator"  # ConfigError source for estimator options
MAX_DT_S = 10.0  # a longer gap is treated as this long (a restart, not a teleport)
MAX_GRID_CELLS = 4_000_000


def _checker(key: str) -> Callable[[str, Any], Any]:
    spec = schema.row("estimator", key)

    def check(name: str, v: Any) -> Any:
        if isinstance(v, np.integer):  # options given in code may be numpy numbers
            v = int(v)
        return schema.check_value(SOURCE, name, spec, v)

    return check


# Every option any estimator understands, checked by its row in pfdoa.schema (type, range,
# unit, doc: docs/site-file.md). The [estimator] table may name the method: ignored here.
OPTION_CHECKS: dict[str, Callable[[str, Any], Any]] = {
    k.key: _checker(k.key) for k in schema.keys_of("estimator") if k.key != "method"}
OPTION_CHECKS["method"] = lambda key, v: v

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


def add_reduce(vals: list[float]) -> float:
    """``np.add.reduce`` of ``vals`` (at least one), to the last bit: below eight values numpy
    adds them in order, which plain floats do for less than the call costs; from eight on it
    sums pairwise, and numpy does."""
    if len(vals) >= 8:
        return float(np.add.reduce(np.array(vals)))
    total = vals[0]
    for v in vals[1:]:
        total += v
    return total


def dt_between(t_prev: float | None, t: float) -> float:
    """Seconds since the previous observation, clamped to [0, MAX_DT_S]; 0 on the first."""
    if t_prev is None or not math.isfinite(t) or not math.isfinite(t_prev):
        return 0.0
    dt = t - t_prev
    dt = 0.0 if dt < 0.0 else dt
    return MAX_DT_S if dt > MAX_DT_S else dt  # min(max(dt, 0), MAX_DT_S) without two builtin calls
