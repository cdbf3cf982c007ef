"""The simulated radio channel: what each anchor's radio reports for a beacon.

reading = mean_rssi(p)                 (pfdoa.radio: log-distance, 3-D, + per-anchor offsets)
        + shadowing_a(p)               (spatially correlated, fixed per anchor and seed)
        + channel_offset[a, ch]        (frequency-selective, fixed per anchor/channel)
        + N(0, noise_db)               (fast fading, independent per reading)
        - multipath_db w.p. multipath_prob   (bursts)
then rounded to whole dBm (radios report integers) and clamped to the radio's range.

The room (the shadowing field and the per-channel offsets) is drawn from ``rng`` when the
channel is made; the readings' noise comes from ``noise_rng`` (by default ``rng`` itself,
after the room's draws), so that other walks through the same room can hear the same
walls with noise of their own.

Shadowing is a sum of random sinusoids (random Fourier features): with wave vectors drawn
from N(0, 1/L^2) it is a stationary field with covariance sigma^2 exp(-d^2 / (2 L^2)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pfdoa.radio import PathLoss, mean_rssi

SHADOWING_COMPONENTS = 64


@dataclass(frozen=True)
class ChannelConfig:
    noise_db: float = 2.0  # std of per-reading Gaussian noise
    shadowing_db: float = 0.0  # std of the correlated shadowing field
    shadowing_corr_m: float = 1.5  # its correlation length
    channel_db: float = 0.0  # std of fixed per-(anchor, channel) offsets
    multipath_prob: float = 0.0  # probability that a reading is hit by a burst
    multipath_db: float = 6.0  # extra loss of a burst (positive number = weaker)
    miss_prob: float = 0.0  # probability that a radio misses a reading altogether
    quantize_db: float = 1.0  # 0 = keep floats
    floor_dbm: float = -110.0  # readings below are not received (sensitivity)
    ceil_dbm: float = 20.0


class Channel:
    """Seeded channel for ``anchors`` (n, 2), ``heights`` above the beacon's plane, with path
    loss ``model`` and per-anchor ``offsets``:
    the room from ``rng``, the readings' noise from ``noise_rng`` (default: ``rng``)."""

    def __init__(
        self,
        anchors: np.ndarray,
        model: PathLoss,
        offsets: np.ndarray | None,
        config: ChannelConfig,
        rng: np.random.Generator,
        n_channels: int = 40,
        noise_rng: np.random.Generator | None = None,
        heights: np.ndarray | None = None,
    ) -> None:
        self.anchors = np.asarray(anchors, dtype=float)
        # each anchor's height above the beacon's plane (Site.heights; None: on it)
        self.heights = None if heights is None else np.asarray(heights, dtype=float)
        self.model = model
        self.offsets = None if offsets is None else np.asarray(offsets, dtype=float)
        self.config = config
        self.rng = rng if noise_rng is None else noise_rng  # the readings' noise
        n = len(self.anchors)
        k = SHADOWING_COMPONENTS
        # Field parameters are drawn once, so the field is fixed in space for this seed.
        self._wave = rng.normal(0.0, 1.0 / max(config.shadowing_corr_m, 1e-6), size=(n, k, 2))
        self._phase = rng.uniform(0.0, 2 * np.pi, size=(n, k))
        self._chan = rng.normal(0.0, config.channel_db, size=(n, n_channels)) if config.channel_db > 0 else np.zeros((n, n_channels))

    def shadowing(self, points: np.ndarray) -> np.ndarray:
        """Shadowing (dB) at points (..., 2) for every anchor -> (..., n)."""
        if self.config.shadowing_db <= 0:
            return np.zeros(np.shape(points)[:-1] + (len(self.anchors),))
        p = np.asarray(points, dtype=float)
        arg = np.einsum("...d,akd->...ak", p, self._wave) + self._phase
        k = self._wave.shape[1]
        return self.config.shadowing_db * np.sqrt(2.0 / k) * np.cos(arg).sum(axis=-1)

    def expected(self, points: np.ndarray) -> np.ndarray:
        """Noise-free but shadowed RSSI (dBm), (..., n)."""
        return mean_rssi(points, self.anchors, self.model, self.offsets, self.heights) + self.shadowing(points)

    def sample(self, point: np.ndarray, channels: np.ndarray) -> tuple[np.ndarray, dict[str, int]]:
        """Readings for one beacon at ``point`` (2,) heard on ``channels`` (m,) by every anchor.

        Returns (n, m) readings in dBm (NaN = not received) and counts of what happened.
        """
        return self.readings(self.expected(np.asarray(point, dtype=float)), channels)

    def readings(self, expected: np.ndarray, channels: np.ndarray,
                 rng: np.random.Generator | None = None) -> tuple[np.ndarray, dict[str, int]]:
        """What every anchor's radio reports of a transmission whose noise-free, shadowed RSSI
        at the anchors is ``expected`` (n,): the per-channel offsets, the noise, the bursts,
        rounding and the radio's range (the module doc), drawn from ``rng`` (default: the
        readings' noise stream). Anchor-to-anchor links (pfdoasim.peers) go through here too."""
        cfg = self.config
        rng = self.rng if rng is None else rng
        n, m = len(self.anchors), len(channels)
        base = np.asarray(expected, dtype=float)[:, None]
        r = base + self._chan[:, channels] + rng.normal(0.0, cfg.noise_db, size=(n, m))
        burst = rng.random((n, m)) < cfg.multipath_prob
        r = r - burst * cfg.multipath_db
        if cfg.quantize_db > 0:
            r = np.round(r / cfg.quantize_db) * cfg.quantize_db
        missed = (rng.random((n, m)) < cfg.miss_prob) | (r < cfg.floor_dbm)
        r = np.minimum(r, cfg.ceil_dbm)
        r[missed] = np.nan
        return r, {"readings": int(n * m), "multipath": int(burst.sum()), "missed": int(missed.sum())}
