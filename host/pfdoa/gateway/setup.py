"""Settings shared by ``pfdoa gateway`` and ``pfdoa replay``: site, tables, estimator."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.gateway.config import GatewayConfig, OutputConfig, gateway_config, output_config
from pfdoa.site import Site, load_site

DEFAULT_METHOD = "pf-doa"


@dataclass(frozen=True)
class Settings:
    site: Site
    gateway: GatewayConfig
    output: OutputConfig
    source: str


def load_settings(path: str, out: str | None = None, fmt: str | None = None) -> Settings:
    """Load and validate the site file; command-line ``out``/``fmt`` override ``[output]``."""
    site = load_site(path)
    src = str(path)
    gcfg = gateway_config(site.sections, src)
    ocfg = output_config(site.sections, src)
    if out is not None:
        ocfg = replace(ocfg, path=out)
    if fmt is not None:
        ocfg = replace(ocfg, format=fmt)
    return Settings(site, gcfg, ocfg, src)


def build_estimator(site: Site, method: str | None, seed: int | None):
    """The estimator named on the command line, else by ``[estimator] method``, else pf-doa.

    The remaining ``[estimator]`` keys are the estimator's options (validated by
    :func:`pfdoa.estimators.make_estimator`, ConfigError on a bad one).
    """
    from pfdoa.estimators import make_estimator

    table = site.sections.get("estimator", {})
    name = method or table.get("method", DEFAULT_METHOD)
    if not isinstance(name, str):
        raise ConfigError("estimator", "method", f"must be a string, got {name!r}")
    options = {k: v for k, v in table.items() if k != "method"}
    est = make_estimator(name, site, rng=np.random.default_rng(seed), **options)
    if not getattr(est, "name", ""):
        est.name = name
    return est
