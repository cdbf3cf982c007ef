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


def build_estimator(site: Site, method: str | None, seed: int | None, source: str | None = None):
    """The estimator named on the command line, else by ``[estimator] method``, else pf-doa.

    The remaining ``[estimator]`` keys are the estimator's options (validated by
    :func:`pfdoa.estimators.make_estimator`, ConfigError on a bad one; with ``source``, the
    site file's name, the error names the file and ``estimator.KEY``). An unknown
    ``method`` from the command line is an InputError naming ``--method``.
    """
    from pfdoa.errors import InputError
    from pfdoa.estimators import METHODS, make_estimator

    table = site.sections.get("estimator", {})
    if method is not None and method not in METHODS:
        raise InputError(f"--method {method}: unknown estimator (known: {', '.join(METHODS)})")
    listed = table.get("method", DEFAULT_METHOD)  # checked even when --method overrides it
    if not isinstance(listed, str) or listed not in METHODS:
        raise ConfigError(source or "estimator", "estimator.method" if source else "method",
                          f"unknown estimator {listed!r} (known: {', '.join(METHODS)})")
    name = method or listed
    if seed is not None and not 0 <= seed < 2**128:
        raise InputError(f"--seed must be an integer >= 0, got {seed}")
    options = {k: v for k, v in table.items() if k != "method"}
    for k, v in options.items():  # no estimator option is this large; float(v) would overflow
        if isinstance(v, int) and not -(2**63) <= v < 2**63:
            raise ConfigError(source or "estimator", f"estimator.{k}" if source else k, "integer out of range")
    try:
        est = make_estimator(name, site, rng=np.random.default_rng(seed), **options)
    except ConfigError as exc:
        if source is None or exc.source != "estimator":
            raise
        raise ConfigError(source, f"estimator.{exc.key}", exc.problem) from None
    if not getattr(est, "name", ""):
        est.name = name
    return est


@dataclass
class Pipeline:
    """Reassembler, decoding gateway, localizer, output: one object for ``gateway`` and ``replay``."""

    settings: Settings
    grouper: object
    gateway: object  # pfdoa.gateway.decoding.Gateway
    localizer: object  # pfdoa.gateway.localizer.Localizer
    health: object  # pfdoa.gateway.health.Health
    writer: object  # pfdoa.output.Writer

    def summary(self) -> dict:
        """The final counters: health and reassembly, the anchors' clocks, odometry."""
        out = self.health.summary(self.grouper)
        g = self.grouper
        out["no_seq"] = g.counters.no_seq  # reports without a sequence number (seq mode drops them)
        if g.counters.unknown_ids:  # which ids, so a wrong site file or id base is plain to see
            out["unknown_ids"] = {str(a): n for a, n in sorted(g.counters.unknown_ids.items())}
        if hasattr(g, "combined"):  # window mode: readings merged into a value, and not kept
            out["combined"] = g.combined
            out["dropped"] = g.dropped
        out["clock"] = self.gateway.clocks.summary()
        odom = self.localizer.summary()
        if odom:
            out["odometry"] = odom
        return out

    def close(self) -> None:
        try:
            self.writer.close()
        except OSError as exc:
            if self.localizer.output_error is None:
                self.localizer.output_error = exc


def build_pipeline(st: Settings, *, method: str | None, seed: int | None, mode: str | None = None,
                   window_s: float | None = None, odometry=None,
                   tolerate_errors: bool = True, flush_each: bool = False) -> Pipeline:
    """The one gateway builder: estimator, reassembler (mode "seq"/"window", default from
    the site), health, output writer, localizer (with an odometry buffer, or None) and the
    decoding gateway that hands it the sets. Raises ConfigError/InputError on bad settings."""
    from pfdoa.gateway.decoding import Gateway, make_grouper
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.localizer import Localizer
    from pfdoa.output import open_writer

    estimator = build_estimator(st.site, method, seed, st.source)
    grouper = make_grouper(st.site.anchor_ids, st.gateway, mode, window_s)
    health = Health()
    writer = open_writer(st.output.path, st.output.format, flush_each=flush_each)
    loc = Localizer(st.site, estimator, writer, odometry, health, tolerate_errors=tolerate_errors,
                    odom_wait_s=st.gateway.odom_wait_s)
    gw = Gateway(grouper, loc.handle, health)
    return Pipeline(st, grouper, gw, loc, health, writer)
