"""Settings shared by ``pfdoa gateway`` and ``pfdoa replay`` (site, tables, estimator) and the
one pipeline builder, :func:`build_pipeline`: the data path from the inputs to the outputs,
stated in one place, with the beacon routing as a strategy (:data:`ROUTES`)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.gateway.beacons import BeaconsConfig, beacons_config
from pfdoa.gateway.config import GatewayConfig, OutputConfig, gateway_config, output_config
from pfdoa.site import Site, load_site

if TYPE_CHECKING:
    from pfdoa.gateway.beacons import BeaconTracker, FrameBeacons, RecordWriter
    from pfdoa.gateway.decoding import Gateway
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.localizer import Localizer
    from pfdoa.gateway.runner import Runner
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
                      source: str | None = None, health=None, beacons: BeaconsConfig | None = None,
                      **options: Any) -> Callable[[str, "RecordWriter"], "Localizer"]:
    """``make_localizer`` for a :class:`~pfdoa.gateway.beacons.BeaconTracker`: per beacon a
    Localizer over :func:`build_estimator` seeded by
    :func:`~pfdoa.gateway.beacons.beacon_seed`, without odometry, counting into ``health``;
    ``options`` (``tolerate_errors``, ``sinks``, ``frame_id``) go to every Localizer;
    ``beacons``: the site's validated ``[[beacons]]`` (a beacon's own ``target_z``)."""
    from pfdoa.gateway.beacons import beacon_seed, beacon_site
    from pfdoa.gateway.localizer import Localizer

    table = beacons if beacons is not None else BeaconsConfig()

    def make(beacon: str, writer: Any) -> Localizer:  # any RecordWriter (Localizer types it as a Writer)
        est = build_estimator(beacon_site(site, table, beacon), method, beacon_seed(seed, beacon), source)
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
                                           beacons=beacons, **options),
                         beacons, on_record=on_record, on_gone=on_gone)


@dataclass
class Pipeline:
    """Reassembler, decoding gateway, localizer, output: one object for ``gateway`` and ``replay``."""

    settings: Settings
    grouper: Any  # the primary beacon's SeqReassembler or WindowGrouper
    gateway: "Gateway"
    localizer: "Localizer"  # the primary beacon's
    health: "Health"
    writer: Any  # pfdoa.output.Writer, or any object with write(record) and close()
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

    def runner(self, inputs: list, cfg: GatewayConfig | None = None, **options: Any) -> "Runner":
        """The :class:`~pfdoa.gateway.runner.Runner` that reads ``inputs`` (made by
        :func:`pfdoa.gateway.inputs.make_inputs`) into this pipeline: its gateway, localizer
        and sinks; ``cfg`` (default the settings' ``[gateway]``) and ``options`` as the Runner's."""
        from pfdoa.gateway.runner import Runner

        return Runner(inputs, self.gateway, cfg or self.settings.gateway, localizer=self.localizer,
                      sinks=self.sinks, **options)

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

    model, positions, offsets, heights = PathLoss.from_site(site), site.positions, site.offsets, site.heights

    def make(key: bytes) -> AuthGuard:
        return AuthGuard(key, health.auth, site.anchor_ids, positions,
                         lambda pts: mean_rssi(pts, positions, model, offsets, heights), site.bounds)

    return make


class _Parts:
    """What every beacon's chain in one pipeline is built from: the settings, the estimator's
    name and seed, grouping, odometry, the health every stage counts into, the sinks, and
    the one position output the beacons' records share."""

    def __init__(self, st: Settings, *, method: str | None, seed: int | None, mode: str | None,
                 window_s: float | None, odometry, tolerate_errors: bool, sinks, frame_id: str, health,
                 writer) -> None:
        self.st, self.method, self.seed, self.mode, self.window_s = st, method, seed, mode, window_s
        self.odometry, self.tolerate_errors, self.sinks, self.frame_id = odometry, tolerate_errors, sinks, frame_id
        self.health, self.writer = health, writer
        self.out = _SharedOutput(writer)

    def grouper(self, has_seq: bool = True, window_s: float | None = None):
        """A beacon's reassembler: by sequence (the mode asked for, else the site's) or, for
        beacons without one, by time window (its own ``window_s``, else the pipeline's)."""
        from pfdoa.gateway.decoding import make_grouper

        ids, gcfg = self.st.site.anchor_ids, self.st.gateway
        if has_seq:
            return make_grouper(ids, gcfg, self.mode, self.window_s)
        return make_grouper(ids, gcfg, "window", window_s or self.window_s)

    def localizer(self, site: Site, seed: int | None, writer, odometry=None, beacon: str | None = None) -> "Localizer":
        """A beacon's localizer: an estimator of the pipeline's method on ``site`` (the site's
        model, or a live peer fit's; with the ``target_z`` of ``beacon``'s entry) seeded
        ``seed``, writing to ``writer``."""
        from pfdoa.gateway.beacons import beacon_site
        from pfdoa.gateway.localizer import Localizer

        st = self.st
        est = build_estimator(beacon_site(site, st.beacons, beacon) if beacon else site, self.method, seed,
                              st.source)
        return Localizer(site, est, writer, odometry, self.health,
                         tolerate_errors=self.tolerate_errors, odom_wait_s=st.gateway.odom_wait_s, sinks=self.sinks,
                         frame_id=self.frame_id)

    def primary(self, writer, beacon: str | None = None) -> "Localizer":
        """The localizer of the beacon the odometry belongs to: the pipeline's seed and odometry."""
        return self.localizer(self.st.site, self.seed, writer, self.odometry, beacon)

    def record(self, beacon: str, rec) -> None:
        """A beacon's record, named, to the shared output."""
        rec.beacon = beacon
        self.out.write(rec)


@dataclass
class Routed:
    """What a :class:`BeaconRoute` built: the primary beacon's grouper and localizer (the
    one the odometry belongs to, whose counters the pipeline reports) and, when it routes
    several beacons, their :class:`~pfdoa.gateway.beacons.FrameBeacons` and the anchors'
    live peer fit (:class:`~pfdoa.gateway.peers.LivePeers`), for the gateway."""

    grouper: Any
    localizer: "Localizer"
    beacons: "FrameBeacons | None" = None
    peers: Any = None


class BeaconRoute(ABC):
    """How the reports of our frames reach a beacon's reassembler and estimator: the beacon
    routing stage of :func:`build_pipeline`'s data path (one of :data:`ROUTES`)."""

    name: ClassVar[str]

    @abstractmethod
    def build(self, parts: _Parts) -> Routed: ...


class FramesRoute(BeaconRoute):
    """``pfdoa gateway``: every beacon of our frames by the index its reports carry (the site's
    ``[[beacons]]``, else the anchors' first-boot table), each with its own reassembler and
    estimator (:class:`~pfdoa.gateway.beacons.FrameBeacons`; the beacons besides the primary
    seeded per beacon, :func:`~pfdoa.gateway.beacons.beacon_seed`); records name their
    beacon. With the site's anchors' entry the anchors' peer readings are refitted live and
    a fit in use rebuilds every beacon's estimator on the fitted site."""

    name = "frames"

    def build(self, parts: _Parts) -> Routed:
        from pfdoa.gateway.beacons import FrameBeacons, beacon_seed, beacon_site
        from pfdoa.gateway.localizer import Localizer
        from pfdoa.gateway.reassembly import SeqReassembler, WindowGrouper

        st, seed = parts.st, parts.seed
        current = {"site": st.site}  # the model the estimators use: the site's, or a live peer fit's

        def later(beacon: str, w) -> Localizer:
            return parts.localizer(current["site"], beacon_seed(seed, beacon), w, beacon=beacon)

        beacons = FrameBeacons(st.site.anchor_ids, st.beacons, parts.grouper, later,
                               lambda beacon, w: parts.primary(w, beacon), on_record=parts.record,
                               default_window_s=parts.window_s or st.gateway.window_s,
                               make_guard=auth_guards(st.site, parts.health), auth=parts.health.auth)
        first, first_loc = beacons.primary.grouper, beacons.primary_localizer
        assert isinstance(first, (SeqReassembler, WindowGrouper)) and isinstance(first_loc, Localizer)

        def use_site(site: Site) -> None:
            current["site"] = site
            for name, loc in beacons.tracker.localizers():
                if isinstance(loc, Localizer):
                    loc.estimator = build_estimator(beacon_site(site, st.beacons, name), parts.method,
                                                    seed if loc is first_loc else beacon_seed(seed, name), st.source)

        peers = None
        if st.beacons.peers is not None:
            from pfdoa.gateway.peers import LivePeers

            peers = LivePeers(st.site, st.beacons.peers, on_model=use_site)
            parts.health.peers = peers
        return Routed(first, first_loc, beacons, peers)


class SingleRoute(BeaconRoute):
    """``pfdoa replay`` of a trace or a recording: one beacon, one reassembler and estimator;
    records named ``beacon`` (None: unnamed)."""

    name = "single"

    def __init__(self, beacon: str | None = None) -> None:
        self.beacon = beacon

    def build(self, parts: _Parts) -> Routed:
        writer = _Named(parts.writer, self.beacon) if self.beacon else parts.writer
        return Routed(parts.grouper(), parts.primary(writer, self.beacon))


ROUTES: dict[str, type[BeaconRoute]] = {"frames": FramesRoute, "single": SingleRoute}


def named_beacons_tracker(parts: _Parts) -> "BeaconTracker":
    """Beside the route, readings that name their beacon (ESPresense devices, a trace's
    beacon column; ``Gateway.push_beacon``) go to a tracker of their own
    (:func:`build_named_tracker`): a window grouper and an estimator per beacon id, at most
    ``[beacons] max_beacons``; the sinks hear when one is let go (``beacon_gone``)."""
    st = parts.st
    return build_named_tracker(st.site, st.gateway, st.beacons, method=parts.method, seed=parts.seed,
                               source=st.source, health=parts.health, window_s=parts.window_s,
                               on_record=parts.record, on_gone=getattr(parts.sinks, "beacon_gone", None),
                               tolerate_errors=parts.tolerate_errors, sinks=parts.sinks, frame_id=parts.frame_id)


def build_pipeline(st: Settings, *, method: str | None, seed: int | None, mode: str | None = None,
                   window_s: float | None = None, odometry=None,
                   tolerate_errors: bool = True, flush_each: bool = False, existing: str = "replace",
                   frames: bool = True, sinks=None,
                   frame_id: str | None = None, beacon: str | None = None,
                   named_beacons: bool = False, writer=None) -> Pipeline:
    """The one pipeline builder (``pfdoa gateway``, ``pfdoa replay``, the fleet simulator and
    its benchmark). The data path, in order:

    1. **inputs** (:mod:`pfdoa.gateway.inputs`), read by a :class:`~pfdoa.gateway.runner.Runner`
       (:meth:`Pipeline.runner`), or readings handed in directly (a replay, the fleet);
    2. **decoding** (:class:`~pfdoa.gateway.decoding.Gateway`): a protocol decoder per byte
       stream, CAN frames, anchor clocks, event means, the health;
    3. **beacon routing** (a :class:`BeaconRoute` of :data:`ROUTES`): ``frames`` (our frames'
       beacons by index, :class:`FramesRoute`) or, with ``frames=False``, one beacon
       (:class:`SingleRoute`, records named ``beacon``); with ``named_beacons``, also readings
       that name their beacon (:func:`named_beacons_tracker`);
    4. per beacon a **reassembler** (mode "seq"/"window", default from the site; ``window_s``)
       and a **localizer**: an estimator (``method``; the primary beacon gets ``seed`` and
       ``odometry``, the others are seeded by :func:`pfdoa.gateway.beacons.beacon_seed`);
    5. the **position writer** (``writer``, default the settings' ``[output]``, opened here:
       ``flush_each``, ``existing`` as in :func:`pfdoa.outfiles`) and the **sinks** (a
       :class:`~pfdoa.sinks.base.Sink`: every reading and record, closed with the writer);
       every record carries ``frame_id``.

    With the site's anchors' entry (``[[beacons]]`` kind ``"anchors"``), the frames route
    gives the gateway a :class:`~pfdoa.gateway.peers.LivePeers`: the anchors' peer readings,
    refitted on the timers; a fit it uses rebuilds every beacon's estimator with the fitted
    site (each with the seed it started with), and so are the beacons that appear later.

    Raises ConfigError/InputError on bad settings."""
    from pfdoa.gateway.decoding import Gateway
    from pfdoa.gateway.health import Health
    from pfdoa.output import DEFAULT_FRAME, open_writer

    health = Health()
    if writer is None:
        writer = open_writer(st.output.path, st.output.format, flush_each=flush_each, existing=existing)
    parts = _Parts(st, method=method, seed=seed, mode=mode, window_s=window_s, odometry=odometry,
                   tolerate_errors=tolerate_errors, sinks=sinks, frame_id=frame_id or DEFAULT_FRAME, health=health,
                   writer=writer)
    route = FramesRoute() if frames else SingleRoute(beacon)
    r = route.build(parts)
    named = named_beacons_tracker(parts) if named_beacons else None
    gw = Gateway(r.grouper, r.localizer.handle, health, beacons=r.beacons,
                 on_reading=sinks.reading if sinks is not None else None, named=named, peers=r.peers)
    return Pipeline(st, r.grouper, gw, r.localizer, health, writer, sinks)
