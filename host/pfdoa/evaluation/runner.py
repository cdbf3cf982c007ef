"""Run one estimator over one sequence and score it against ground truth.

The estimator only ever sees :class:`~pfdoa.estimators.base.Observation` (time and RSSI)
and odometry; the ground truth stays here and is used after each step to compute the plain
Euclidean error in metres (no rescaling, no alignment).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from pfdoa.estimators.base import Observation
from pfdoa.evaluation.datasets import Sequence


@dataclass(frozen=True)
class Variant:
    """A table row: a method, whether it gets odometry, and options for make_estimator."""

    label: str
    method: str
    use_odometry: bool = False
    options: tuple[tuple[str, object], ...] = ()


@dataclass
class RunResult:
    errors: np.ndarray  # (k,) metres
    step_ms: np.ndarray  # (k,) wall time of each step() call
    estimates: np.ndarray  # (k, 2)
    held: int = 0  # steps where the estimator returned no finite position (previous one scored)
    failure: str = ""  # exception text if the estimator raised
    extra: dict = field(default_factory=dict)


def run_sequence(variant: Variant, seq: Sequence, rng: np.random.Generator) -> RunResult:
    """Run a fresh estimator of ``variant`` over ``seq``; score every step that has ground truth."""
    from pfdoa.estimators import make_estimator

    est = make_estimator(variant.method, seq.site, rng=rng, **dict(variant.options))
    k = len(seq)
    out = np.empty((k, 2))
    step_ms = np.empty(k)
    last = seq.site.positions.mean(axis=0)
    held = 0
    clock = time.perf_counter_ns
    for i in range(k):
        obs = Observation(float(seq.t[i]), seq.rssi[i].copy())
        odo = seq.odometry[i] if (variant.use_odometry and seq.odometry is not None) else None
        t0 = clock()
        e = est.step(obs, odo)
        step_ms[i] = (clock() - t0) * 1e-6
        if math.isfinite(e.x) and math.isfinite(e.y):
            last = np.array([e.x, e.y])
        else:
            held += 1
        out[i] = last
    have = np.all(np.isfinite(seq.truth), axis=1)
    err = np.hypot(*(out[have] - seq.truth[have]).T)
    return RunResult(err, step_ms, out, held)
