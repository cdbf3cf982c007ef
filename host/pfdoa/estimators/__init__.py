"""Position estimators: PF-DOA (ours and the paper's) and the paper's comparison methods.

``make_estimator(name, site, rng=..., **options)`` builds one; ``METHODS`` lists the names.
Options come from the site's ``[estimator]`` table and the command line; see
:data:`pfdoa.estimators.common.OPTION_CHECKS` for every name, its range and unit. An option
unknown to every method, or a bad value, raises :class:`pfdoa.errors.ConfigError`; an
option that only other methods use is ignored, so one table can configure them all.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.estimators.base import Estimate, Estimator, Observation, Odometry
from pfdoa.estimators.common import SOURCE, check_options
from pfdoa.estimators.drssi import DifferentialRssGrid
from pfdoa.estimators.markov import MarkovGrid
from pfdoa.estimators.pf_doa import PfDoa
from pfdoa.estimators.pf_doa_paper import PaperPfDoa
from pfdoa.estimators.trilateration import Trilateration
from pfdoa.estimators.wcl import WeightedCentroid

_CLASSES: dict[str, type] = {
    "pf-doa": PfDoa,
    "pf-doa-paper": PaperPfDoa,
    "trilateration": Trilateration,
    "wcl": WeightedCentroid,
    "drssi": DifferentialRssGrid,
    "markov": MarkovGrid,
}
METHODS: tuple[str, ...] = tuple(_CLASSES)


def uses_rng(name: str) -> bool:
    """Does the method draw random numbers (so its result depends on the seed)?"""
    cls = _CLASSES.get(name)
    return bool(cls is not None and cls.uses_rng)


def make_estimator(name: str, site, *, rng: np.random.Generator | None = None, **options: Any) -> Estimator:
    """Build the estimator ``name`` for ``site`` (a :class:`pfdoa.site.Site`)."""
    cls = _CLASSES.get(name)
    if cls is None:
        raise ConfigError(SOURCE, "method", f"unknown estimator {name!r} (known: {', '.join(METHODS)})")
    kwargs = check_options(name, cls.OPTIONS, options)
    if cls.uses_rng:
        kwargs["rng"] = rng
    return cls(site, **kwargs)


__all__ = ["METHODS", "make_estimator", "uses_rng", "Estimate", "Estimator", "Observation", "Odometry"]
