"""A radio map from the calibration trace: each anchor's residual from the path-loss model,
smoothed over the floor, trusted as far as it predicts passes it has not seen.

Walls and furniture shadow an anchor over a region, the same way every time the target is
there; the path-loss model (:mod:`pfdoa.radio`) cannot hold that, a calibration trace with
ground truth can. The map is the differential residual (an anchor's offset-free RSS minus
the model pf-doa uses, minus the window's mean over its anchors: the filter compares RSS
differences, :mod:`pfdoa.estimators.pf_doa`) of every time window of the calibration trace,
kernel-smoothed over the floor::

    m_k(x) = trust * sum_i K(x - x_i) r_ik / (PRIOR_WINDOWS + sum_i K(x - x_i))

with a Gaussian kernel of ``LENGTH_M`` (the scale of indoor shadowing: a room, a wall) and
a prior of ``PRIOR_WINDOWS`` windows at zero, so a region with few readings keeps the model.
What is written into the site file is the windows' residuals binned on the map's grid (sum
and count per cell and anchor), so its size is bounded by the area, not the trace's length.

**Trust.** A residual that repeats at a place is a map; one that came with the moment
(a person walking between target and anchor, the target's own rotation) is not, and a map
of one pass cannot tell them apart. So the map is checked by block cross-validation on the
calibration trace itself: cut into ``BLOCK_S`` blocks, each block predicted from the map of
the others less its two neighbours (readings are correlated in time), and ``trust`` is the
share of the residual variance the map explains in-sample that it still explains on the
blocks it did not see (0 to 1). A walk that passes each place once has nothing to predict
its blocks from and gets trust 0: no map. pf-doa adds ``m_k`` to its model RSS
(docs/archive/estimator-study.md, "Radio map").

The site-file table (``[radio_map]``) is untrusted input: :func:`parse_radio_map` checks
every shape and bound, and the grid the estimator builds from it is bounded in memory
(``MAX_TABLE_VALUES``) whatever the file says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.radio import distances

LENGTH_M = 1.0  # kernel length: indoor shadowing varies over about a metre (walls, furniture)
PRIOR_WINDOWS = 5.0  # windows' worth of "residual 0" at every point (shrinks sparse regions)
BLOCK_S = 30.0  # cross-validation blocks of the calibration trace (about one pass of a room)
CELL_FRACTION = 0.25  # grid cell as a share of the kernel length
MARGIN_LENGTHS = 3.0  # the grid reaches this many kernel lengths beyond the data
MAX_TABLE_VALUES = 1 << 18  # cells x anchors of the estimator's table (2 MiB of float64)
MAX_AXIS_CELLS = 1024  # cells along either axis (the kernel matrices: 8 MiB each at most)
MAX_STORED_VALUES = 40_000  # binned cells x anchors written to a site file (file size bound)
MAX_ABS_RESIDUAL_DB = 100.0
MIN_TRUST = 0.01  # below, a map changes no estimate measurably and only fills the site file


@dataclass(frozen=True)
class GridSpec:
    """A regular grid: cell (i, j) has centre origin + (i + 0.5, j + 0.5) * cell."""

    origin: tuple[float, float]
    cell_m: float
    nx: int
    ny: int

    def flat_index(self, points: np.ndarray) -> np.ndarray:
        """Flat cell index of each point; ``nx * ny`` (a zero row) for points off the grid."""
        f = (np.asarray(points, dtype=float) - np.asarray(self.origin)) / self.cell_m
        ok = np.all(np.isfinite(f), axis=1) & (f[:, 0] >= 0) & (f[:, 1] >= 0) & (f[:, 0] < self.nx) & (f[:, 1] < self.ny)
        idx = np.full(f.shape[0], self.nx * self.ny, dtype=np.intp)
        idx[ok] = f[ok, 0].astype(np.intp) * self.ny + f[ok, 1].astype(np.intp)
        return idx

    def centres(self, axis: int) -> np.ndarray:
        n = self.nx if axis == 0 else self.ny
        return self.origin[axis] + (np.arange(n) + 0.5) * self.cell_m


def grid_around(points: np.ndarray, length_m: float, n_anchors: int, max_values: int = MAX_TABLE_VALUES) -> GridSpec:
    """A grid over ``points`` plus ``MARGIN_LENGTHS`` kernel lengths, cells of
    ``CELL_FRACTION`` of the length, coarser where needed to stay within ``max_values``."""
    lo = points.min(axis=0) - MARGIN_LENGTHS * length_m
    hi = points.max(axis=0) + MARGIN_LENGTHS * length_m
    span = hi - lo
    cell = CELL_FRACTION * length_m
    max_cells = max(1, max_values // max(n_anchors, 1))
    # Each axis too (the smoother's kernel matrices are axis x axis), and the cells' total.
    cell = max(cell, float(span.max()) / MAX_AXIS_CELLS, math.sqrt(float(span[0] * span[1]) / max_cells))
    while math.ceil(span[0] / cell) * math.ceil(span[1] / cell) > max_cells:
        cell *= 1.1
    return GridSpec((float(lo[0]), float(lo[1])), float(cell), int(math.ceil(span[0] / cell)), int(math.ceil(span[1] / cell)))


def _binned(grid: GridSpec, points: np.ndarray, residual: np.ndarray, weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(sum, count) of ``residual`` (points x anchors, NaN = absent) per cell and anchor:
    arrays (anchors, nx, ny). ``weight``: each point's count (default 1)."""
    cells = grid.nx * grid.ny
    idx = grid.flat_index(points)
    n_anchors = residual.shape[1]
    total = np.zeros((n_anchors, cells + 1))
    count = np.zeros((n_anchors, cells + 1))
    w = np.ones(points.shape[0]) if weight is None else weight
    for k in range(n_anchors):
        ok = np.isfinite(residual[:, k])
        wk = w[:, k] if w.ndim == 2 else w
        total[k] = np.bincount(idx[ok], weights=residual[ok, k] * wk[ok], minlength=cells + 1)
        count[k] = np.bincount(idx[ok], weights=wk[ok], minlength=cells + 1)
    shape = (n_anchors, grid.nx, grid.ny)
    return total[:, :cells].reshape(shape), count[:, :cells].reshape(shape)


def _smooth(grid: GridSpec, total: np.ndarray, count: np.ndarray, length_m: float, prior_windows: float) -> np.ndarray:
    """The kernel regression of the module doc on binned data: (nx * ny + 1, anchors), the
    last row zero (off the grid). The Gaussian is separable, so two small matrix products
    per anchor instead of a kernel between every cell and every point."""
    cx, cy = grid.centres(0), grid.centres(1)
    kx = np.exp(-0.5 * ((cx[:, None] - cx[None, :]) / length_m) ** 2)
    ky = np.exp(-0.5 * ((cy[:, None] - cy[None, :]) / length_m) ** 2)
    n_anchors = total.shape[0]
    table = np.zeros((grid.nx * grid.ny + 1, n_anchors))
    for k in range(n_anchors):
        num = kx @ total[k] @ ky.T
        den = kx @ count[k] @ ky.T
        table[:-1, k] = (num / (prior_windows + den)).ravel()
    return table


@dataclass(frozen=True)
class RadioMap:
    """The ``[radio_map]`` of a site: the calibration windows' residuals binned on cells (mean
    and number of windows per visited cell and anchor, rows in the order of ``anchors``), the
    trust and the smoother's two constants."""

    anchors: tuple[int, ...]
    x: np.ndarray  # cell centres of the visited cells (m)
    y: np.ndarray
    residual_db: np.ndarray  # (anchors, cells): mean residual in the cell (NaN: no reading)
    count: np.ndarray  # (anchors, cells): windows in the cell
    trust: float
    length_m: float = LENGTH_M
    prior_windows: float = PRIOR_WINDOWS

    def table(self, anchor_ids: Sequence[int]) -> tuple[GridSpec, np.ndarray]:
        """The map on a grid, (cells + 1, anchors in ``anchor_ids`` order) scaled by trust;
        anchors the map does not name get zeros."""
        pts = np.column_stack([self.x, self.y])
        col = {aid: j for j, aid in enumerate(self.anchors)}
        res = np.full((pts.shape[0], len(anchor_ids)), np.nan)
        cnt = np.zeros((pts.shape[0], len(anchor_ids)))
        for k, aid in enumerate(anchor_ids):
            j = col.get(aid)
            if j is not None:
                res[:, k] = self.residual_db[j]
                cnt[:, k] = self.count[j]
        grid = grid_around(pts, self.length_m, len(anchor_ids))
        total, count = _binned(grid, pts, np.where(cnt > 0, res, np.nan), cnt)
        return grid, self.trust * _smooth(grid, total, count, self.length_m, self.prior_windows)

    def to_section(self) -> dict[str, Any]:
        """The site-file table (:func:`pfdoa.site.site_to_toml` writes it)."""
        def rows(a: np.ndarray, digits: int) -> list[list[float]]:
            return [[round(float(v), digits) if math.isfinite(v) else 0.0 for v in row] for row in a]

        return {
            "trust": round(self.trust, 4), "length_m": self.length_m, "prior_windows": self.prior_windows,
            "anchors": list(self.anchors),
            "x": [round(float(v), 3) for v in self.x], "y": [round(float(v), 3) for v in self.y],
            "residual_db": rows(np.where(self.count > 0, self.residual_db, 0.0), 2),
            "count": [[int(c) for c in row] for row in self.count],
        }


def _floats(source: str, key: str, value: Any, n: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or (n is not None and len(value) != n):
        raise ConfigError(source, f"radio_map.{key}", f"must be a list of {n if n is not None else 'some'} numbers")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ConfigError(source, f"radio_map.{key}", "must hold numbers only")
    a = np.array(value, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ConfigError(source, f"radio_map.{key}", "must hold finite numbers")
    return a


def _scalar(source: str, table: dict, key: str) -> float:
    return schema.check_value(source, f"radio_map.{key}", schema.row("radio_map", key), table.get(key))


KEYS = schema.names_of("radio_map")  # every key is required (pfdoa calibrate writes them all)


def parse_radio_map(table: Any, anchor_ids: Iterable[int], source: str = "<site>") -> RadioMap:
    """Validate a ``[radio_map]`` table (:class:`~pfdoa.errors.ConfigError` naming the key)."""
    if not isinstance(table, dict):
        raise ConfigError(source, "radio_map", "must be a table ([radio_map])")
    schema.check_keys(source, "radio_map", table, KEYS)
    schema.required(source, "radio_map", table, schema.keys_of("radio_map"))
    trust, length, prior = (_scalar(source, table, k) for k in ("trust", "length_m", "prior_windows"))
    ids = table["anchors"]
    known = set(anchor_ids)
    if (not isinstance(ids, list) or not ids or len(set(map(repr, ids))) != len(ids)
            or not all(isinstance(a, int) and not isinstance(a, bool) and a in known for a in ids)):
        raise ConfigError(source, "radio_map.anchors", "must list distinct anchor ids of this site")
    x = _floats(source, "x", table["x"])
    y = _floats(source, "y", table["y"], x.size)
    if x.size == 0 or x.size * len(ids) > MAX_STORED_VALUES:
        raise ConfigError(source, "radio_map.x", f"must hold 1 to {MAX_STORED_VALUES // len(ids)} cells for {len(ids)} anchors")
    if np.any(np.abs(x) > 1e5) or np.any(np.abs(y) > 1e5):
        raise ConfigError(source, "radio_map.x", "positions beyond 100 km")
    rows = []
    for key in ("residual_db", "count"):
        v = table[key]
        if not isinstance(v, list) or len(v) != len(ids):
            raise ConfigError(source, f"radio_map.{key}", f"must be one row per anchor ({len(ids)})")
        a = np.array([_floats(source, key, r, x.size) for r in v])
        rows.append(a)
    residual, count = rows
    if np.any(np.abs(residual) > MAX_ABS_RESIDUAL_DB):
        raise ConfigError(source, "radio_map.residual_db", f"residuals beyond {MAX_ABS_RESIDUAL_DB:g} dB")
    if np.any(count < 0) or np.any(count != np.round(count)) or np.any(count > 1e9):
        raise ConfigError(source, "radio_map.count", "must hold whole window counts >= 0")
    return RadioMap(tuple(ids), x, y, np.where(count > 0, residual, np.nan), count, trust, length, prior)


# -- fitting ------------------------------------------------------------------------------
def residuals(site, windows: Iterable, exponent: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions, differential residuals (windows x anchors, NaN = absent), times) of the
    windows with ground truth under the model pf-doa runs: the site's A and offsets and
    path-loss ``exponent``, each window's mean over its anchors removed."""
    pos = site.positions
    a1m, dmin = site.radio.rssi_at_1m_dbm, site.radio.min_distance_m
    offsets = site.offsets
    heights = site.heights
    xy, res, ts = [], [], []
    for w in windows:
        if w.gt is None or not (math.isfinite(w.gt[0]) and math.isfinite(w.gt[1])):
            continue
        d = distances(w.gt, pos, dmin, heights)
        r = w.rssi - offsets - (a1m - 10.0 * exponent * np.log10(d))
        if np.count_nonzero(np.isfinite(r)) < 2:  # one anchor has no difference to another
            continue
        xy.append(w.gt)
        res.append(r - np.nanmean(r))
        ts.append(w.t)
    n = len(site.anchors)
    return (np.array(xy, dtype=float).reshape(-1, 2), np.array(res, dtype=float).reshape(-1, n),
            np.array(ts, dtype=float))


def _explained(r: np.ndarray, p: np.ndarray) -> float:
    ok = np.isfinite(r)
    tot = float(np.sum(r[ok] ** 2))
    return 1.0 - float(np.sum((r[ok] - p[ok]) ** 2)) / tot if tot > 0.0 else 0.0


def trust_of(points: np.ndarray, residual: np.ndarray, block: np.ndarray, run: np.ndarray,
             length_m: float = LENGTH_M, prior_windows: float = PRIOR_WINDOWS) -> float:
    """Block cross-validated share of the in-sample explained variance (module doc).
    ``block``: each window's block number within its ``run``; a block is predicted from the
    other runs and the blocks of its own run at least two away."""
    grid = grid_around(points, length_m, residual.shape[1])
    idx = grid.flat_index(points)

    def fit(sel: np.ndarray) -> np.ndarray:
        total, count = _binned(grid, points[sel], residual[sel])
        return _smooth(grid, total, count, length_m, prior_windows)

    inside = _explained(residual, fit(np.ones(points.shape[0], dtype=bool))[idx])
    if not inside > 0.0:
        return 0.0
    pred = np.zeros_like(residual)
    for r, b in sorted(set(zip(run.tolist(), block.tolist()))):
        here = (run == r) & (block == b)
        train = (run != r) | (np.abs(block - b) > 1)
        if train.any():
            pred[here] = fit(train)[idx[here]]
    return float(np.clip(max(_explained(residual, pred), 0.0) / inside, 0.0, 1.0))


def fit_radio_map(site, runs: Sequence[Iterable], exponent: float, *, length_m: float = LENGTH_M,
                  prior_windows: float = PRIOR_WINDOWS, block_s: float = BLOCK_S) -> RadioMap | None:
    """The radio map of the calibration ``runs`` (each an iterable of
    :class:`~pfdoa.trace.Window`, with ground truth) for ``site`` (already calibrated), or
    None when it does not predict blocks it has not seen (trust below ``MIN_TRUST``) or there
    are too few windows."""
    parts = [residuals(site, w, exponent) for w in runs]
    points = np.concatenate([p[0] for p in parts])
    if points.shape[0] < 3:
        return None
    residual = np.concatenate([p[1] for p in parts])
    block = np.concatenate([np.floor((p[2] - (p[2].min() if p[2].size else 0.0)) / block_s) for p in parts]).astype(np.int64)
    run = np.concatenate([np.full(p[0].shape[0], i) for i, p in enumerate(parts)])
    trust = trust_of(points, residual, block, run, length_m, prior_windows)
    if not trust >= MIN_TRUST:
        return None
    # Stored binned on the estimator's own grid cells (coarser if the file would be large).
    n = residual.shape[1]
    grid = grid_around(points, length_m, n)
    while True:
        total, count = _binned(grid, points, residual)
        visited = np.flatnonzero(count.sum(axis=0).ravel() > 0)
        if visited.size * n <= MAX_STORED_VALUES:
            break
        grid = GridSpec(grid.origin, grid.cell_m * 2.0, math.ceil(grid.nx / 2), math.ceil(grid.ny / 2))
    cx, cy = grid.centres(0), grid.centres(1)
    tot, cnt = total.reshape(n, -1)[:, visited], count.reshape(n, -1)[:, visited]
    mean = np.divide(tot, cnt, out=np.full_like(tot, np.nan), where=cnt > 0)
    return RadioMap(tuple(site.anchor_ids), cx[visited // grid.ny], cy[visited % grid.ny], mean, cnt,
                    round(trust, 4), length_m, prior_windows)


class MapLookup:
    """The map's table for a filter: per-anchor correction at many points, the hot path
    without allocation (buffers for ``n`` points)."""

    def __init__(self, rmap: RadioMap, anchor_ids: Sequence[int], n: int) -> None:
        self.grid, grid_table = rmap.table(anchor_ids)
        g = self.grid
        k = grid_table.shape[1]
        # The one copy kept: the grid inside a border of zero cells, ((nx + 2) * (ny + 2),
        # anchors). A point off the grid, clipped onto the border, reads zeros, with no mask
        # to build per call.
        padded = np.zeros((g.nx + 2, g.ny + 2, k))
        padded[1:-1, 1:-1] = grid_table[:-1].reshape(g.nx, g.ny, k)
        self.table = padded.reshape(-1, k)
        self._stride = g.ny + 2
        self._origin = np.array(g.origin)
        self._inv_cell = 1.0 / g.cell_m
        self._border = np.array([g.nx, g.ny], dtype=float)  # the far border's cell (the near one is -1)
        self._f = np.empty((n, 2))
        self._i = np.empty((n, 2), dtype=np.intp)
        self._idx = np.empty(n, dtype=np.intp)
        self.out = np.empty((n, k))

    def at(self, points: np.ndarray) -> np.ndarray:
        """(k, anchors) correction at any ``points``, zero off the grid or where not finite
        (allocates; rare use)."""
        g = self.grid
        flat = g.flat_index(points)
        row, col = np.divmod(flat, g.ny)
        idx = (row + 1) * self._stride + col + 1
        idx[flat == g.nx * g.ny] = 0  # a border cell: zeros
        return self.table[idx]

    def into(self, xy: np.ndarray) -> np.ndarray:
        """The correction at the ``n`` particles ``xy`` (finite: the filters clamp them to
        their box) into :attr:`out` (no allocation); the same values as :meth:`at`."""
        f = self._f
        np.subtract(xy, self._origin, out=f)
        f *= self._inv_cell
        np.floor(f, out=f)
        np.clip(f, -1.0, self._border, out=f)
        np.copyto(self._i, f, casting="unsafe")  # whole numbers already
        idx = self._idx
        np.multiply(self._i[:, 0], self._stride, out=idx)
        idx += self._i[:, 1]
        idx += self._stride + 1  # the border's offset
        return np.take(self.table, idx, axis=0, out=self.out)


__all__ = ["RadioMap", "MapLookup", "GridSpec", "fit_radio_map", "parse_radio_map", "residuals", "trust_of",
           "LENGTH_M", "PRIOR_WINDOWS", "BLOCK_S"]
