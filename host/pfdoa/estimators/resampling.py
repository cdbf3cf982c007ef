"""Particle resampling with an injectable random generator.

Unlike FilterPy's ``systematic_resample`` (global RNG, unclamped cumulative sum: round-off
in ``cumsum[-1] < 1`` can index one past the end), the cumulative sum is clamped to
exactly 1 and indices are clipped, so weights summing to ``1 - 1e-12`` (or carrying tiny
negative round-off) never index out of range.
"""

from __future__ import annotations

import numpy as np


class SystematicResampler:
    """Systematic resampling into preallocated buffers for N particles."""

    def __init__(self, n: int) -> None:
        self.n = n
        self._base = np.arange(n, dtype=float) / n
        self._cumsum = np.empty(n)
        self._positions = np.empty(n)
        self.indices = np.empty(n, dtype=np.intp)
        # Scalar operands as 0-d arrays (a Python number costs each ufunc call a conversion)
        self._scale = np.empty(())
        self._offset = np.empty(())
        self._last = np.array(n - 1, dtype=np.intp)

    def __call__(self, weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Indices (N,) drawn with probability ``weights`` (normalised, length N).

        The returned array is an internal buffer, overwritten by the next call.
        """
        cs = self._cumsum
        # np.add.accumulate and the searchsorted method: what np.cumsum and np.searchsorted
        # run, without their dispatch (a third of the call at N = 200).
        np.add.accumulate(weights, out=cs)
        total = cs.item(-1)
        if total != 1.0:  # (a product by 1 changes nothing)
            self._scale[()] = 1.0 / total if total > 0 else 1.0
            cs *= self._scale
        cs[-1] = 1.0
        self._offset[()] = rng.random() / self.n
        np.add(self._base, self._offset, out=self._positions)
        np.minimum(cs.searchsorted(self._positions, side="right"), self._last, out=self.indices)
        return self.indices


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Functional form of :class:`SystematicResampler` (allocates; for tests and tools)."""
    w = np.asarray(weights, dtype=float)
    return SystematicResampler(w.size)(w, rng).copy()
