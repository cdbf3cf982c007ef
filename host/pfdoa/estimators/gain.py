"""The estimate's gain about the search box's centre (pf-doa's ``estimate_gain`` and
``estimate_gain_odometry``).

pf-doa reports centre + G (estimate - centre), G a symmetric 2 x 2 matrix whose eigenvalues
lie in (0, 1]: the estimate is drawn towards the centre, never pushed away from it, along any
direction. ``pfdoa.calibrate.fit_gain`` measures G on calibration runs (the truth's least-squares
fit on the estimate); a site file holds it as ``[xx, xy, yy]``, or as one number g for the
isotropic g I (what calibrate wrote before 2026-12-05). A matrix, because where the readings
say less along one axis than along the other (a corridor, an elongated room: the anchors'
geometry), the filter's estimates overshoot more along it (docs/estimator-study.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

# A written matrix is rounded to 4 decimals, which can lift an eigenvalue of 1 by that much.
EIGEN_TOLERANCE = 1e-3


@dataclass(frozen=True)
class EstimateGain:
    """The symmetric matrix [[xx, xy], [xy, yy]]; the identity leaves the estimate as it is."""

    xx: float = 1.0
    xy: float = 0.0
    yy: float = 1.0

    @classmethod
    def isotropic(cls, g: float) -> EstimateGain:
        return cls(float(g), 0.0, float(g))

    @classmethod
    def from_matrix(cls, m: np.ndarray) -> EstimateGain:
        return cls(float(m[0, 0]), float(0.5 * (m[0, 1] + m[1, 0])), float(m[1, 1]))

    @classmethod
    def parse(cls, v: Any) -> EstimateGain:
        """A site file's value: a number in (0, 1], or [xx, xy, yy] with eigenvalues in (0, 1];
        ValueError says what is wrong (the estimator options wrap it: common.gain_option)."""
        if isinstance(v, EstimateGain):
            return v
        if isinstance(v, (list, tuple)):
            ok = len(v) == 3 and all(_is_number(x) and math.isfinite(float(x)) for x in v)
            g = cls(*(float(x) for x in v)) if ok else None
            if g is not None:
                lo, hi = g.principal()
                if lo > 0.0 and hi <= 1.0 + EIGEN_TOLERANCE:
                    return g
            raise ValueError(f"must be a number in (0, 1] or [xx, xy, yy], a symmetric matrix with eigenvalues in "
                             f"(0, 1], got {v!r}")
        f = float(v) if _is_number(v) else math.nan
        if not (math.isfinite(f) and 0.0 < f <= 1.0):
            raise ValueError(f"must be a number in (0, 1] or [xx, xy, yy], got {v!r}")
        return cls.isotropic(f)

    def matrix(self) -> np.ndarray:
        return np.array([[self.xx, self.xy], [self.xy, self.yy]])

    def principal(self) -> tuple[float, float]:
        """The eigenvalues (the gains along the matrix's principal directions), ascending."""
        lo, hi = np.linalg.eigvalsh(self.matrix())
        return float(lo), float(hi)

    @property
    def identity(self) -> bool:
        return self.xx == 1.0 and self.xy == 0.0 and self.yy == 1.0

    @property
    def isotropic_value(self) -> float | None:
        return self.xx if self.xy == 0.0 and self.xx == self.yy else None

    def apply(self, dx: float, dy: float) -> tuple[float, float]:
        """G (dx, dy): an offset from the centre, moved."""
        return self.xx * dx + self.xy * dy, self.xy * dx + self.yy * dy

    def rounded(self, digits: int = 4) -> EstimateGain:
        return EstimateGain(round(self.xx, digits), round(self.xy, digits), round(self.yy, digits))

    def option(self) -> float | list[float]:
        """The site file's value: one number when isotropic, else [xx, xy, yy]."""
        g = self.isotropic_value
        return g if g is not None else [self.xx, self.xy, self.yy]

    def __str__(self) -> str:
        g = self.isotropic_value
        return f"{g:.2f}" if g is not None else f"({self.xx:.2f}, {self.xy:.2f}, {self.yy:.2f})"


IDENTITY = EstimateGain()
GainOption = Union[float, list, EstimateGain]  # what pf-doa's estimate_gain options take


def _is_number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating))
