"""Run one estimator over one sequence and score it against ground truth.

The estimator only ever sees :class:`~pfdoa.estimators.base.Observation` (time, RSSI and
how many readings each value combines) and odometry; the ground truth stays here and is
used after each step to compute the plain Euclidean error in metres (no rescaling, no
alignment), and whether the truth lies within the estimate's ``r95`` and within the 95 %
ellipse of its ``cov`` (Mahalanobis distance squared <= ``CHI2_2DOF_95``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from pfdoa.estimators.base import CHI2_2DOF_95, Estimate, Observation, mahalanobis2
from pfdoa.evaluation.datasets import Sequence


@dataclass(frozen=True)
class Variant:
    """A table row: a method, whether it gets odometry, and options for make_estimator."""

    label: str
    method: str
    use_odometry: bool = False
    options: tuple[tuple[str, object], ...] = ()


def parse_variant(text: str) -> tuple[str, str, dict]:
    """``name:key=value,...`` (the study tools' ``--variant``) -> (name, method, options);
    ``method=...`` among them names the method (default pf-doa), values are Python literals
    (else strings)."""
    import ast

    name, _, rest = text.partition(":")
    method = "pf-doa"
    opts: dict = {}
    for kv in filter(None, rest.split(",")):
        k, _, v = kv.partition("=")
        if k == "method":
            method = v
            continue
        try:
            opts[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            opts[k] = v
    return name, method, opts


@dataclass
class RunResult:
    errors: np.ndarray  # (k,) metres
    step_ms: np.ndarray  # (k,) wall time of each step() call
    estimates: np.ndarray  # (k, 2)
    held: int = 0  # steps where the estimator returned no finite position (previous one scored)
    failure: str = ""  # exception text if the estimator raised
    extra: dict = field(default_factory=dict)
    # Per scored step (aligned with errors); None when the method reports no such value.
    in_cov: np.ndarray | None = None  # truth within the 95 % ellipse of cov
    lost: np.ndarray | None = None  # the estimate was flagged lost
    r95_m: np.ndarray | None = None  # the reported r95 (NaN where none: a held step)

    @property
    def in_r95(self) -> np.ndarray | None:
        """Per scored step, 1.0 where the truth lies within r95 of the estimate."""
        return within_r95(self.errors, self.r95_m)


def within_r95(errors: np.ndarray, r95: np.ndarray | None) -> np.ndarray | None:
    """1.0 where the error is within r95, 0.0 where not, NaN where no r95 was reported; None
    for a method that reports none."""
    if r95 is None:
        return None
    return np.where(np.isnan(r95), np.nan, (errors <= r95).astype(float))


def _uncertainty(e: Estimate, dx: float, dy: float) -> tuple[float, float, float]:
    """(in cov ellipse, lost) for one step as 1.0 / 0.0, and r95; NaN where the method gives
    no value."""
    in_cov = float(mahalanobis2(dx, dy, e.cov) <= CHI2_2DOF_95) if e.cov is not None else math.nan
    return in_cov, math.nan if e.lost is None else float(e.lost), float(e.r95)


def run_sequence(variant: Variant, seq: Sequence, rng: np.random.Generator) -> RunResult:
    """Run a fresh estimator of ``variant`` over ``seq``; score every step that has ground truth.

    The estimator gets the options of the site's ``[estimator]`` table (as ``pfdoa replay``
    does; a calibrated site may carry some), then the variant's own."""
    from pfdoa.estimators import make_estimator

    table = {k: v for k, v in seq.site.sections.get("estimator", {}).items() if k != "method"}
    est = make_estimator(variant.method, seq.site, rng=rng, **{**table, **dict(variant.options)})
    k = len(seq)
    out = np.empty((k, 2))
    unc = np.full((k, 3), np.nan)
    step_ms = np.empty(k)
    last = seq.site.positions.mean(axis=0)
    held = 0
    clock = time.perf_counter_ns
    for i in range(k):
        obs = Observation(float(seq.t[i]), seq.rssi[i].copy(), None if seq.count is None else seq.count[i])
        odo = seq.odometry[i] if (variant.use_odometry and seq.odometry is not None) else None
        t0 = clock()
        e = est.step(obs, odo)
        step_ms[i] = (clock() - t0) * 1e-6
        if math.isfinite(e.x) and math.isfinite(e.y):
            last = np.array([e.x, e.y])
            gx, gy = seq.truth[i]
            unc[i] = _uncertainty(e, float(gx - e.x), float(gy - e.y))
        else:
            held += 1
        out[i] = last
    have = np.all(np.isfinite(seq.truth), axis=1)
    err = np.hypot(*(out[have] - seq.truth[have]).T)
    u = unc[have]

    def column(j: int) -> np.ndarray | None:
        return u[:, j] if np.isfinite(u[:, j]).any() else None

    return RunResult(err, step_ms, out, held, in_cov=column(0), lost=column(1), r95_m=column(2))


__all__ = ["CHI2_2DOF_95", "RunResult", "Variant", "mahalanobis2", "parse_variant", "run_sequence"]
