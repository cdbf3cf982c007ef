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


def load_settings(path: str, out: str | None = None, fmt: str | None = None, site: Site | None = None) -> Settings:
    """Load and validate the site file; command-line ``out``/``fmt`` override ``[output]``.

    ``site``: already parsed (e.g. from a recording's copy of its site file; ``path`` then
    names where it came from in error messages)."""
    site = site if site is not None else load_site(path)
    src = str(path)
    gcfg = gateway_config(site.sections, src)
    ocfg = output_config(site.sections, src)
    if out is not None:
        ocfg = replace(ocfg, path=out)
    if fmt is not None:
        ocfg = replace(ocfg, format=fmt)
    return Settings(site, gcfg, ocfg, src)


def estimator_method(site: Site, method: str | None) -> str:
    """The estimator's name: ``method`` (the command line), else ``[estimator] method``, else pf-doa."""
    name = method or site.sections.get("estimator", {}).get("method", DEFAULT_METHOD)
    if not isinstance(name, str):
        raise ConfigError("estimator", "method", f"must be a string, got {name!r}")
    return name


def build_estimator(site: Site, method: str | None, seed: int | None):
    """The estimator named by :func:`estimator_method`.

    The remaining ``[estimator]`` keys are the estimator's options (validated by
    :func:`pfdoa.estimators.make_estimator`, ConfigError on a bad one).
    """
    from pfdoa.estimators import make_estimator

    table = site.sections.get("estimator", {})
    name = estimator_method(site, method)
    options = {k: v for k, v in table.items() if k != "method"}
    est = make_estimator(name, site, rng=np.random.default_rng(seed), **options)
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
    sinks: object = None  # pfdoa.sinks.base.Sink (a Fanout): readings, records, health besides the writer

    def summary(self) -> dict:
        """The final counters: health and reassembly, the anchors' clocks, odometry."""
        out = self.health.summary(self.grouper)
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
        finally:
            if self.sinks is not None:
                self.sinks.close()


def build_pipeline(st: Settings, *, method: str | None, seed: int | None, mode: str | None = None,
                   window_s: float | None = None, odometry=None,
                   tolerate_errors: bool = True, flush_each: bool = False, sinks=None,
                   frame_id: str | None = None) -> Pipeline:
    """The one gateway builder: estimator, reassembler (mode "seq"/"window", default from
    the site), health, output writer, localizer (with an odometry buffer, or None) and the
    decoding gateway that hands it the sets. ``sinks`` (a :class:`~pfdoa.sinks.base.Sink`)
    gets every reading and record besides the writer, and is closed with it; ``frame_id``
    goes into every record. Raises ConfigError/InputError on bad settings."""
    from pfdoa.gateway.decoding import Gateway, make_grouper
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.localizer import Localizer
    from pfdoa.output import DEFAULT_FRAME, open_writer

    estimator = build_estimator(st.site, method, seed)
    grouper = make_grouper(st.site.anchor_ids, st.gateway, mode, window_s)
    health = Health()
    writer = open_writer(st.output.path, st.output.format, flush_each=flush_each)
    loc = Localizer(st.site, estimator, writer, odometry, health, tolerate_errors=tolerate_errors,
                    odom_wait_s=st.gateway.odom_wait_s, sinks=sinks, frame_id=frame_id or DEFAULT_FRAME)
    gw = Gateway(grouper, loc.handle, health, on_reading=sinks.reading if sinks is not None else None)
    return Pipeline(st, grouper, gw, loc, health, writer, sinks)
