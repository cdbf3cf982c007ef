"""Direction of arrival (DOA) of the RSS gradient over the anchors (paper Sec. III, Eqs. 1-5).

The gradient comes from a least-squares plane fit ``RSS_i ~ c + gx * x_i + gy * y_i`` over
the anchors that reported (any >= 3 non-collinear anchors). For four anchors on a
rectangle it equals the paper's central differences (Eqs. 1-2) exactly, see
:func:`central_differences`. The plane fit is linear in the RSS, so its 2 x n operator is
precomputed once per set of present anchors.

RSS grows towards the transmitter, so the gradient points from the anchors towards the
robot: ``doa = atan2(gy, gx)`` is the bearing of the robot seen from the anchors' centroid
(site frame, radians, (-pi, pi]). ``atan2`` keeps the quadrant that the paper's
``arctan(gy / gx)`` loses.

Smoothing (Eqs. 4-5) is done on unit vectors, never on raw angles (an average of 179 deg and
-179 deg must be 180 deg, not 0): the smoothed DOA is the direction of
``sum_{n=0}^{k-1} 0.99**n * (cos, sin)(DOA_{l-n})``, newest weight 0.99**0. The paper's
normalisation 1 / sum(0.99**n) does not change a direction, so it is not applied.

Zero gradient (all present anchors equal after offsets, e.g. the robot at the centre of a
symmetric layout with 1 dB quantisation): the direction is undefined, so that step gives no
DOA (``None``); the smoother is not fed and keeps its previous value.
"""

from __future__ import annotations

import math

import numpy as np

# Below this gradient magnitude (dB/m) the direction is treated as undefined.
ZERO_GRADIENT_DB_PER_M = 1e-9
DECAY = 0.99  # the paper's weight base (Eq. 5)
_CACHE_LIMIT = 256  # operators per GradientFit (one per set of present anchors)


def plane_fit_operator(positions: np.ndarray) -> np.ndarray:
    """The (2, n) matrix G with ``G @ rss = (gx, gy)`` of the least-squares plane fit.

    Raises ValueError for fewer than 3 anchors or collinear anchors (no unique plane).
    """
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise ValueError("need at least 3 anchor positions of shape (n, 2)")
    centred = p - p.mean(axis=0)  # centring decouples c from (gx, gy) and helps conditioning
    scale = float(np.abs(centred).max()) or 1.0
    sv = np.linalg.svd(centred / scale, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        raise ValueError("anchor positions are collinear")
    # With centred coordinates the intercept column is orthogonal to x and y, so the
    # gradient rows are the pseudo-inverse of the centred coordinates alone.
    return np.linalg.pinv(centred)


class GradientFit:
    """Plane-fit gradient over a fixed set of anchors, with any subset missing.

    ``operator(mask)`` returns the (2, n) operator with zero columns for missing anchors
    (None if fewer than 3 present or they are collinear); operators are cached per mask.
    """

    def __init__(self, positions: np.ndarray) -> None:
        self.positions = np.array(positions, dtype=float)
        self.n = self.positions.shape[0]
        self.full = plane_fit_operator(self.positions)
        self._cache: dict[bytes, np.ndarray | None] = {}

    def operator(self, mask: np.ndarray | None = None) -> np.ndarray | None:
        if mask is None or mask.all():
            return self.full
        key = np.asarray(mask, dtype=bool).tobytes()
        if key in self._cache:
            return self._cache[key]
        op: np.ndarray | None = None
        idx = np.flatnonzero(mask)
        if idx.size >= 3:
            try:
                sub = plane_fit_operator(self.positions[idx])
            except ValueError:
                sub = None
            if sub is not None:
                op = np.zeros((2, self.n))
                op[:, idx] = sub
        if len(self._cache) >= _CACHE_LIMIT:
            self._cache.clear()
        self._cache[key] = op
        return op

    def gradient(self, rssi: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray | None:
        """(gx, gy) in dB/m of offset-free RSS (n,); entries outside ``mask`` are ignored."""
        op = self.operator(mask)
        if op is None:
            return None
        r = np.asarray(rssi, dtype=float)
        if mask is not None and not mask.all():
            r = np.where(mask, r, 0.0)
        return op @ r


def central_differences(s: np.ndarray, dx: float, dy: float) -> tuple[float, float]:
    """The paper's Eqs. 1-2 for anchors N1=(0,0), N2=(0,dy), N3=(dx,dy), N4=(dx,0)."""
    s1, s2, s3, s4 = (float(v) for v in s)
    gx = (s3 - s2) / (2 * dx) + (s4 - s1) / (2 * dx)
    gy = (s3 - s4) / (2 * dy) + (s2 - s1) / (2 * dy)
    return gx, gy


def doa_from_gradient(g: np.ndarray | None, eps: float = ZERO_GRADIENT_DB_PER_M) -> float | None:
    """Quadrant-correct DOA (rad) of a gradient, or None if it is (near) zero or missing."""
    if g is None:
        return None
    gx, gy = float(g[0]), float(g[1])
    if not (math.isfinite(gx) and math.isfinite(gy)) or math.hypot(gx, gy) <= eps:
        return None
    return math.atan2(gy, gx)


def wrap_angle(a):
    """Wrap angle(s) to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class DoaSmoother:
    """The paper's exponentially weighted moving DOA over a window of k samples (Eqs. 4-5).

    A fixed ring of k unit vectors; ``push`` adds the newest DOA (None: nothing is added),
    ``value`` is the direction of the 0.99**n-weighted vector sum (newest n = 0), or the
    previous value if the sum vanishes (opposite bearings cancelling).
    """

    def __init__(self, window: int = 5, decay: float = DECAY) -> None:
        if window < 1:
            raise ValueError("window must be >= 1")
        self.window = int(window)
        self.decay = float(decay)
        self._ring = np.zeros((self.window, 2))
        # _weights[h] is the weight vector over ring slots when the newest sample is slot h.
        slots = np.arange(self.window)
        self._weights = self.decay ** ((np.arange(self.window)[:, None] - slots[None, :]) % self.window)
        self.reset()

    def reset(self) -> None:
        self._ring.fill(0.0)
        self._head = -1
        self.count = 0
        self.value: float | None = None

    def push(self, doa: float | None) -> float | None:
        """Add one DOA (rad) and return the smoothed DOA (None until the first DOA)."""
        if doa is None or not math.isfinite(doa):
            return self.value
        self._head = (self._head + 1) % self.window
        self._ring[self._head, 0] = math.cos(doa)
        self._ring[self._head, 1] = math.sin(doa)
        self.count = min(self.count + 1, self.window)
        c, s = self._weights[self._head] @ self._ring
        if math.hypot(c, s) > 1e-12:
            self.value = math.atan2(s, c)
        return self.value
