"""Settings shared by ``pfdoa gateway`` and ``pfdoa replay``: site, tables, estimator."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.gateway.beacons import BeaconsConfig, beacons_config
from pfdoa.gateway.config import GatewayConfig, OutputConfig, gateway_config, output_config
from pfdoa.site import Site, load_site

if TYPE_CHECKING:
    from pfdoa.gateway.beacons import BeaconTracker, RecordWriter
    from pfdoa.gateway.localizer import Localizer
    from pfdoa.output import Record

DEFAULT_METHOD = "pf-doa"


@dataclass(frozen=True)
class Settings:
    site: Site
    gateway: GatewayConfig
    output: OutputConfig
    source: str
    beacons: BeaconsConfig = BeaconsConfig()
    espresense: Any = None  # pfdoa.mqtt.espresense.EspresenseConfig when the site has [espresense]


def load_settings(path: str, out: str | None = None, fmt: str | None = None, site: Site | None = None) -> Settings:
    """Load and validate the site file; command-line ``out``/``fmt`` override ``[output]``.

    ``site``: already parsed (e.g. from a recording's copy of its site file; ``path`` then
    names where it came from in error messages)."""
    site = site if site is not None else load_site(path)
    src = str(path)
    gcfg = gateway_config(site.sections, src)
    ocfg = output_config(site.sections, src)
    bcfg = beacons_config(site.sections, src)
    esp = None
    if "espresense" in site.sections:  # validated whenever it is there, used by --mqtt-input espresense
        from pfdoa.mqtt.espresense import espresense_config

        esp = espresense_config(site.sections, src, site.anchor_ids, site.radio.rssi_at_1m_dbm)
    if out is not None:
        ocfg = replace(ocfg, path=out)
    if fmt is not None:
        ocfg = replace(ocfg, format=fmt)
    return Settings(site, gcfg, ocfg, src, bcfg, esp)


def estimator_method(site: Site, method: str | None) -> str:
    """The estimator's name: ``method`` (the command line), else ``[estimator] method``, else pf-doa."""
    name = method or site.sections.get("estimator", {}).get("method", DEFAULT_METHOD)
    if not isinstance(name, str):
        raise ConfigError("estimator", "method", f"must be a string, got {name!r}")
    return name


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


def beacon_localizers(site: Site, gateway: GatewayConfig, *, method: str | None, seed: int | None,
                      source: str | None = None, health=None,
                      **options: Any) -> Callable[[str, "RecordWriter"], "Localizer"]:
    """``make_localizer`` for a :class:`~pfdoa.gateway.beacons.BeaconTracker`: per beacon a
    Localizer over :func:`build_estimator` seeded by
    :func:`~pfdoa.gateway.beacons.beacon_seed`, without odometry, counting into ``health``;
    ``options`` (``tolerate_errors``, ``sinks``, ``frame_id``) go to every Localizer."""
    from pfdoa.gateway.beacons import beacon_seed
    from pfdoa.gateway.localizer import Localizer

    def make(beacon: str, writer: Any) -> Localizer:  # any RecordWriter (Localizer types it as a Writer)
        est = build_estimator(site, method, beacon_seed(seed, beacon), source)
        return Localizer(site, est, writer, None, health, odom_wait_s=gateway.odom_wait_s, **options)

    return make


def build_named_tracker(site: Site, gateway: GatewayConfig, beacons: BeaconsConfig, *, method: str | None,
                        seed: int | None, source: str | None = None, window_s: float | None = None, health=None,
                        on_record: Callable[[str, "Record"], None] | None = None,
                        on_gone: Callable[[str, str], None] | None = None, **options: Any) -> "BeaconTracker":
    """The one builder of the tracker of beacons that readings name (ESPresense devices, a
    trace's beacon column): per beacon a window grouper (``window_s``, else ``gateway``'s)
    and a localizer from :func:`beacon_localizers` (``method``, ``seed``, ``source``,
    ``health``, ``options``), at most ``beacons.max_beacons`` of them (the gateway, the
    replay, the fleet demo and its benchmark all build it here)."""
    from pfdoa.gateway.beacons import BeaconTracker
    from pfdoa.gateway.decoding import make_grouper

    ids = site.anchor_ids
    return BeaconTracker(ids, lambda b: make_grouper(ids, gateway, "window", window_s),
                         beacon_localizers(site, gateway, method=method, seed=seed, source=source, health=health,
                                           **options),
                         beacons, on_record=on_record, on_gone=on_gone)


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
        """The final counters: health and reassembly (over every beacon), the anchors'
        clocks, odometry (the primary beacon's), the beacons (``named_beacons``: the
        tracker of beacons that readings name, ESPresense devices)."""
        g = self.gateway.groupers
        out = self.health.summary(g)
        out["no_seq"] = g.counters.no_seq  # reports without a sequence number (seq mode drops them)
        if g.counters.unknown_ids:  # which ids, so a wrong site file or id base is plain to see
            out["unknown_ids"] = {str(a): n for a, n in sorted(g.counters.unknown_ids.items())}
        windowed = [w for w in self.gateway._groupers() if hasattr(w, "combined")]
        if windowed:  # window mode: readings merged into a value, and not kept
            out["combined"] = sum(w.combined for w in windowed)
            out["dropped"] = sum(w.dropped for w in windowed)
        out["clock"] = self.gateway.clocks.summary()
        odom = self.localizer.summary()
        if odom:
            out["odometry"] = odom
        if self.gateway.beacons is not None:
            out["beacons"] = self.gateway.summary()
        if self.gateway.named is not None:
            out["named_beacons"] = self.gateway.named.summary()
            mc = self.gateway.message_clock
            if mc is not None:  # on message time: the clock of admitted times (pfdoa.gateway.msgtime)
                out["named_beacons"]["message_clock"] = {"now": mc.now, "resets": mc.resets}
        if self.gateway.unnamed_dropped:  # named readings without a tracker for them (never silent)
            out["unnamed_dropped"] = self.gateway.unnamed_dropped
        out.update(self.gateway.peers_summary())
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


class _Named:
    """A writer that names the beacon of every record (a replay of a gateway's recording)."""

    def __init__(self, writer, beacon: str) -> None:
        self.writer, self.beacon = writer, beacon

    def write(self, rec) -> None:
        rec.beacon = self.beacon
        self.writer.write(rec)


class _SharedOutput:
    """The one output writer every beacon's localizer writes to: a write that failed (a full
    disk) fails for all of them from then on, so each says so and stops."""

    def __init__(self, writer) -> None:
        self.writer = writer
        self.error: OSError | None = None

    def write(self, rec) -> None:
        if self.error is not None:
            raise self.error
        try:
            self.writer.write(rec)
        except OSError as exc:
            self.error = exc
            raise


def auth_guards(site: Site, health) -> Callable[[bytes], Any]:
    """An authenticated beacon's guard (pfdoa.gateway.auth) with the site's radio model for
    the relay pattern check, counting into ``health.auth``."""
    from pfdoa.gateway.auth import AuthGuard
    from pfdoa.radio import PathLoss, mean_rssi

    model, positions, offsets = PathLoss.from_site(site), site.positions, site.offsets

    def make(key: bytes) -> AuthGuard:
        return AuthGuard(key, health.auth, site.anchor_ids, positions,
                         lambda pts: mean_rssi(pts, positions, model, offsets), site.bounds)

    return make


def build_pipeline(st: Settings, *, method: str | None, seed: int | None, mode: str | None = None,
                   window_s: float | None = None, odometry=None,
                   tolerate_errors: bool = True, flush_each: bool = False, existing: str = "replace",
                   frames: bool = True, sinks=None,
                   frame_id: str | None = None, beacon: str | None = None,
                   named_beacons: bool = False) -> Pipeline:
    """The one gateway builder: estimator, reassembler (mode "seq"/"window", default from
    the site), health, output writer, localizer (with an odometry buffer, or None) and the
    decoding gateway that hands it the sets. ``sinks`` (a :class:`~pfdoa.sinks.base.Sink`)
    gets every reading and record besides the writer, and is closed with it; ``frame_id``
    goes into every record; ``existing``: what the output does with a file at its path
    (pfdoa.outfiles: "keep" for the gateway). Raises ConfigError/InputError on bad settings.

    ``frames`` (the gateway): every beacon of our frames gets its own reassembler and
    estimator (:class:`pfdoa.gateway.beacons.FrameBeacons`, the site's ``[[beacons]]``), and
    records name their beacon. The primary beacon (the one the odometry belongs to) keeps
    ``seed``, ``odometry`` and ``Pipeline.grouper``/``localizer``; the others' estimators are
    seeded by :func:`pfdoa.gateway.beacons.beacon_seed`. ``frames=False`` (a replay of a
    trace): one beacon, records named ``beacon`` (None: unnamed); with ``named_beacons``
    also the tracker below (a replay of a trace or recording whose readings name beacons).

    With the site's anchors' entry (``[[beacons]]`` kind ``"anchors"``), the gateway gets a
    :class:`~pfdoa.gateway.peers.LivePeers`: the anchors' peer readings, refitted on the
    timers; a fit it uses rebuilds every beacon's estimator with the fitted site (each with
    the seed it started with), and so are the beacons that appear later.

    ``named_beacons`` (ESPresense input): readings that name their beacon
    (:class:`~pfdoa.gateway.beacons.BeaconReading`, ``Gateway.push_beacon``) go to a
    :class:`~pfdoa.gateway.beacons.BeaconTracker`: one window grouper (``[gateway]
    window_s``) and one estimator per beacon id (seeded by ``beacon_seed``, no odometry),
    at most ``[beacons] max_beacons`` of them; records are named by the id and the sinks
    are told when a beacon is let go (``beacon_gone``)."""
    from pfdoa.gateway.beacons import FrameBeacons, beacon_seed
    from pfdoa.gateway.decoding import Gateway, make_grouper
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.localizer import Localizer
    from pfdoa.gateway.reassembly import SeqReassembler, WindowGrouper
    from pfdoa.output import DEFAULT_FRAME, open_writer

    ids, gcfg = st.site.anchor_ids, st.gateway
    health = Health()
    writer = open_writer(st.output.path, st.output.format, flush_each=flush_each, existing=existing)
    frame = frame_id or DEFAULT_FRAME
    on_reading = sinks.reading if sinks is not None else None

    def make_localizer(estimator, w, odom) -> Localizer:
        return Localizer(st.site, estimator, w, odom, health, tolerate_errors=tolerate_errors,
                         odom_wait_s=gcfg.odom_wait_s, sinks=sinks, frame_id=frame)

    out = _SharedOutput(writer)

    def on_record(beacon: str, rec) -> None:
        rec.beacon = beacon
        out.write(rec)

    def named_tracker() -> BeaconTracker | None:
        if not named_beacons:
            return None
        return build_named_tracker(st.site, gcfg, st.beacons, method=method, seed=seed, source=st.source,
                                   health=health, window_s=window_s, on_record=on_record,
                                   on_gone=getattr(sinks, "beacon_gone", None), tolerate_errors=tolerate_errors,
                                   sinks=sinks, frame_id=frame)

    if not frames:
        grouper = make_grouper(ids, gcfg, mode, window_s)
        loc = make_localizer(build_estimator(st.site, method, seed, st.source), _Named(writer, beacon) if beacon else writer,
                             odometry)
        gw = Gateway(grouper, loc.handle, health, on_reading=on_reading, named=named_tracker())
        return Pipeline(st, grouper, gw, loc, health, writer, sinks)

    def group(has_seq: bool, beacon_window_s: float | None):
        if has_seq:
            return make_grouper(ids, gcfg, mode, window_s)
        return make_grouper(ids, gcfg, "window", beacon_window_s or window_s)

    def primary(beacon: str, w) -> Localizer:
        return make_localizer(build_estimator(st.site, method, seed, st.source), w, odometry)

    current = {"site": st.site}  # the model the estimators use: the site's, or a live peer fit's

    def later(beacon: str, w) -> Localizer:  # the beacons besides the primary: estimators seeded per beacon
        est = build_estimator(current["site"], method, beacon_seed(seed, beacon), st.source)
        return Localizer(current["site"], est, w, None, health, odom_wait_s=gcfg.odom_wait_s,
                         tolerate_errors=tolerate_errors, sinks=sinks, frame_id=frame)

    beacons = FrameBeacons(ids, st.beacons, group, later, primary, on_record=on_record,
                           default_window_s=window_s or gcfg.window_s, make_guard=auth_guards(st.site, health),
                           auth=health.auth)
    first = beacons.primary.grouper
    first_loc = beacons.primary_localizer
    assert isinstance(first, (SeqReassembler, WindowGrouper)) and isinstance(first_loc, Localizer)

    def use_site(site: Site) -> None:
        current["site"] = site
        for name, loc in beacons.tracker.localizers():
            if isinstance(loc, Localizer):
                loc.estimator = build_estimator(site, method, seed if loc is first_loc else beacon_seed(seed, name),
                                                st.source)

    peers = None
    if st.beacons.peers is not None:
        from pfdoa.gateway.peers import LivePeers

        peers = LivePeers(st.site, st.beacons.peers, on_model=use_site)
        health.peers = peers
    gw = Gateway(first, first_loc.handle, health, beacons=beacons, on_reading=on_reading, named=named_tracker(),
                 peers=peers)
    return Pipeline(st, first, gw, first_loc, health, writer, sinks)
