"""A fleet on one broker: ESPresense-style nodes reporting several beacons, and a local mosquitto.

* :class:`Mosquitto` runs a real broker (Debian ``mosquitto`` 2.x) on 127.0.0.1 and a free
  port from a generated configuration (2.x listens on localhost only and refuses anonymous
  clients unless told otherwise), optionally with a password file, TLS or persistence;
  stopped by its pid, restartable on the same port. Used by the tests, the demo and the
  benchmark.
* :class:`FleetScenario` (seeded): a site with ``n_anchors`` ESPresense nodes along the walls
  (each named after a room), or the anchors, radio model, node names and rooms of a site file
  (``site_file``: ``make demo-fleet`` uses examples/espresense/site.toml), ``n_beacons``
  iBeacons walking through it
  (:func:`pfdoasim.trajectories.walking_track`), each with its own transmit power, one
  radio environment (:class:`pfdoasim.channel.Channel` on :mod:`pfdoa.radio`'s model).
  :meth:`FleetScenario.messages` yields what the nodes publish, in time order: per node and
  beacon, ``rate_hz`` JSON messages a second on ``espresense/devices/<id>/<room>`` with the
  fields an ESPresense node writes (the RSSI averaged over the three advertising channels)
  and, with ``time_field``, the simulated time.
* :func:`run_gateway_fleet` - the demo (``make demo-fleet``, ``python -m pfdoasim.fleet``):
  a local mosquitto, the real ``pfdoa gateway --mqtt-input espresense`` process on the
  site file :func:`fleet_site_toml` writes, the nodes publishing in simulated time, every
  ``<prefix>/+/pose`` scored against the ground truth.
* :func:`run_fleet` - the same chain in this process (ESPresense input + beacon tracker +
  one pf-doa per beacon + publisher; ``--in-process``): the two give the same estimates.
"""

from __future__ import annotations

import getpass
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from pfdoa.errors import PfdoaError
from pfdoa.radio import PathLoss
from pfdoa.site import Anchor, Site, site_to_toml
from pfdoasim.channel import Channel, ChannelConfig
from pfdoasim.scenario import loop_track
from pfdoasim.trajectories import random_waypoints, walking_track

MOSQUITTO_CANDIDATES = ("mosquitto", "/usr/sbin/mosquitto")
# What mosquitto 2.x logs (log_type information / error) once its listeners are open, and when
# a listener's port is taken.
LISTENING = re.compile(r"mosquitto version \S+ running")
PORT_IN_USE = "Address already in use"
PORT_ATTEMPTS = 5


class _PortTaken(Exception):
    pass


def mosquitto_binary() -> str:
    for c in MOSQUITTO_CANDIDATES:
        path = shutil.which(c)
        if path:
            return path
    raise FileNotFoundError("mosquitto not found: run tools/bootstrap.sh fleet (Debian package mosquitto)")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class TlsFiles:
    cafile: str
    certfile: str
    keyfile: str


class Mosquitto:
    """A mosquitto process on 127.0.0.1:``port`` with its files in ``workdir``.

    ``users`` (name -> password) writes a password file with ``mosquitto_passwd`` and turns
    anonymous access off. ``persistence`` keeps retained messages and persistent sessions
    (with their queued QoS 1 messages) across :meth:`restart`, saved on a clean stop.
    ``max_queued_messages`` bounds what the broker holds for one offline session.
    """

    def __init__(self, workdir: str | Path, port: int | None = None, *, users: dict[str, str] | None = None,
                 persistence: bool = False, tls: TlsFiles | None = None,
                 max_queued_messages: int = 100_000) -> None:
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._port_given = bool(port)
        self.port = port or free_port()
        self.users = dict(users or {})
        self.persistence = persistence
        self.tls = tls
        self.max_queued_messages = int(max_queued_messages)
        self.conf = self.workdir / "mosquitto.conf"
        self.log = self.workdir / "mosquitto.log"
        self.proc: subprocess.Popen | None = None
        self.starts = 0

    def url(self, prefix: str = "pfdoa", user: str | None = None) -> str:
        scheme = "mqtts" if self.tls else "mqtt"
        who = f"{user}@" if user else ""
        return f"{scheme}://{who}127.0.0.1:{self.port}/{prefix}"

    def _write_config(self) -> None:
        lines = [
            f"listener {self.port} 127.0.0.1",
            f"allow_anonymous {'false' if self.users else 'true'}",
            f"persistence {'true' if self.persistence else 'false'}",
            f"max_queued_messages {self.max_queued_messages}",
            "log_dest stderr",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "log_type information",
            "connection_messages true",
            # Messages to subscribers leave at once, not ~40 ms later behind Nagle + delayed ACK.
            "set_tcp_nodelay true",
        ]
        if os.geteuid() == 0:
            # As root, mosquitto drops to user "mosquitto", which cannot read our files.
            lines.append(f"user {getpass.getuser()}")
        if self.persistence:
            lines += [f"persistence_location {self.workdir}/", "persistence_file mosquitto.db"]
        if self.users:
            pw = self.workdir / "passwd"
            pw.write_text("")
            for name, password in self.users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(pw), name, password], check=True,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            lines.append(f"password_file {pw}")
        if self.tls:
            lines += [f"cafile {self.tls.cafile}", f"certfile {self.tls.certfile}", f"keyfile {self.tls.keyfile}"]
        self.conf.write_text("\n".join(lines) + "\n")

    def start(self, timeout_s: float = 10.0) -> "Mosquitto":
        """Start the broker and wait until it listens. A port picked by :func:`free_port` is
        free only when picked: another process (a second test worker's broker) can bind it
        before this one does, so a first start whose port was taken retries on a new one. A
        restart keeps its port (clients reconnect to it) and fails if it is gone."""
        if self.proc is not None and self.proc.poll() is None:
            return self
        attempts = PORT_ATTEMPTS if not self._port_given and self.starts == 0 else 1
        for attempt in range(attempts):
            if attempt:
                self.port = free_port()
            try:
                return self._start_once(timeout_s)
            except _PortTaken:
                pass
        raise RuntimeError(f"mosquitto could not listen on port {self.port}: {self.log_tail()}")

    def _start_once(self, timeout_s: float) -> "Mosquitto":
        self._write_config()
        offset = self.log.stat().st_size if self.log.exists() else 0
        self._log_fh = open(self.log, "ab")
        # Its own session: a Ctrl-C at the terminal stops whoever started it, who stops the
        # broker last (after the gateway has delivered what it holds).
        self.proc = subprocess.Popen([mosquitto_binary(), "-c", str(self.conf)], stdout=self._log_fh,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        self.starts += 1
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                code = self.proc.returncode
                self.stop()
                if PORT_IN_USE in self._log_since(offset):
                    raise _PortTaken(self.port)
                raise RuntimeError(f"mosquitto exited with {code}: {self.log_tail()}")
            # "running" is logged once every listener is open: a connection alone could reach
            # another broker that took the port while this one is failing to bind it.
            if LISTENING.search(self._log_since(offset)):
                try:
                    with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                        return self
                except OSError:
                    pass
            time.sleep(0.02)
        self.stop()
        raise RuntimeError(f"mosquitto did not listen on port {self.port} within {timeout_s} s: {self.log_tail()}")

    def _log_since(self, offset: int) -> str:
        try:
            with open(self.log, "rb") as f:
                f.seek(offset)
                return f.read().decode(errors="replace")
        except OSError:
            return ""

    def stop(self, timeout_s: float = 10.0) -> None:
        """SIGTERM by pid (a persistent broker saves its database), SIGKILL if it hangs."""
        p = self.proc
        if p is None:
            return
        if p.poll() is None:
            os.kill(p.pid, signal.SIGTERM)
            try:
                p.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.kill(p.pid, signal.SIGKILL)
                p.wait()
        self.proc = None
        self._log_fh.close()

    def restart(self) -> None:
        self.stop()
        self.start()

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def log_tail(self, n: int = 2000) -> str:
        try:
            return self.log.read_text(errors="replace")[-n:]
        except OSError:
            return ""

    def __enter__(self) -> "Mosquitto":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# -- the fleet: beacons walking in a site, ESPresense nodes reporting them ----------------

ROOM_NAMES = ("kitchen", "hall", "office", "lounge", "bedroom", "bath", "garage", "study", "porch", "attic",
              "cellar", "landing")
ESPRESENSE_ABSORPTION = 2.7  # the node firmware's default path-loss exponent for "distance"


# Nodes report every beacon ~10 times a second and the beacons walk: a window short enough
# that the beacon moves little within it, long enough to combine a few readings per node.
FLEET_WINDOW_S = 0.3


@dataclass(frozen=True)
class FleetConfig:
    n_beacons: int = 4
    n_anchors: int = 8
    width_m: float = 12.0
    height_m: float = 8.0
    duration_s: float = 60.0
    rate_hz: float = 10.0  # messages per anchor per beacon per second
    seed: int = 1
    rssi_at_1m_dbm: float = -59.0
    path_loss_exponent: float = 2.7
    # ESPresense-companion's accuracy-harness noise: 2.5 dB plus 10 % bursts of -6 dB
    channel: ChannelConfig = ChannelConfig(noise_db=2.5, multipath_prob=0.10, multipath_db=6.0)
    tx_spread_db: float = 4.0  # beacons' rssi@1m spread uniformly over +- this
    speed_mps: float = 0.8
    topic_prefix: str = "espresense"
    time_field: str = "t"  # sim time in every message ("" = none: receive times would be used)
    # A site file with [espresense] rooms (node name -> anchor id): its anchors, radio model
    # and rooms replace n_anchors, width_m, height_m, rssi_at_1m_dbm, path_loss_exponent.
    site_file: str | None = None


@dataclass(frozen=True, slots=True)
class FleetMessage:
    t: float
    topic: str
    payload: bytes
    beacon: str
    anchor: int


def _site_file(path: str) -> tuple[Site, dict[str, int]]:
    """A fleet's site from a file: its anchors must all be ESPresense nodes (``[espresense]
    rooms`` names each one), which report from where the file puts them."""
    from pfdoa.api import espresense_config
    from pfdoa.errors import ConfigError
    from pfdoa.site import load_site

    site = load_site(path)
    esp = espresense_config(site.sections, path, site.anchor_ids, site.radio.rssi_at_1m_dbm)
    named = set(esp.rooms.values())
    for i, a in enumerate(site.anchors):
        if a.id not in named:
            raise ConfigError(path, f"anchors[{i}]", f"anchor {a.id} is no ESPresense node: name it in "
                              "[espresense] rooms")
    return site, dict(esp.rooms)


def perimeter_anchors(n: int, width_m: float, height_m: float) -> list[tuple[float, float]]:
    """``n`` anchors evenly spaced along the walls, the first in the corner (0, 0)."""
    per = 2.0 * (width_m + height_m)
    corners = [(0.0, 0.0), (width_m, 0.0), (width_m, height_m), (0.0, height_m), (0.0, 0.0)]
    out = []
    for i in range(n):
        s = i * per / n
        for (x0, y0), (x1, y1) in zip(corners, corners[1:]):
            seg = abs(x1 - x0) + abs(y1 - y0)
            if s <= seg + 1e-9:
                f = s / seg
                out.append((round(x0 + f * (x1 - x0), 6), round(y0 + f * (y1 - y0), 6)))
                break
            s -= seg
    return out


class FleetScenario:
    """Seeded: the site, one walking track and transmit power per beacon, the nodes' rooms."""

    def __init__(self, cfg: FleetConfig = FleetConfig()) -> None:
        rng = np.random.default_rng(cfg.seed)
        if cfg.site_file is not None:
            self.site, self.rooms = _site_file(cfg.site_file)
            x0, y0, x1, y1 = self.site.bounds
            cfg = replace(cfg, n_anchors=len(self.site.anchors), width_m=x1 - x0, height_m=y1 - y0,
                          rssi_at_1m_dbm=self.site.radio.rssi_at_1m_dbm,
                          path_loss_exponent=self.site.radio.path_loss_exponent)
        else:
            if not 1 <= cfg.n_anchors <= len(ROOM_NAMES):
                raise ValueError(f"n_anchors must be in 1..{len(ROOM_NAMES)}")
            pos = perimeter_anchors(cfg.n_anchors, cfg.width_m, cfg.height_m)
            self.site = Site(radio=PathLoss(cfg.rssi_at_1m_dbm, cfg.path_loss_exponent),
                             anchors=tuple(Anchor(id=i + 1, x=x, y=y) for i, (x, y) in enumerate(pos)),
                             name="sim-fleet")
            self.rooms = {ROOM_NAMES[i]: a.id for i, a in enumerate(self.site.anchors)}
        self.cfg = cfg
        x0, y0 = (self.site.bounds[:2] if cfg.site_file is not None else (0.0, 0.0))
        self.walk_bounds = (x0, y0, x0 + cfg.width_m, y0 + cfg.height_m)
        node = {aid: room for room, aid in self.rooms.items()}
        self.node_names = [node[a.id] for a in self.site.anchors]  # each anchor's topic level
        self.beacons = [f"iBeacon:{uuid.UUID(bytes=rng.bytes(16))}-1-{k}" for k in range(cfg.n_beacons)]
        self.tx_offset = {b: float(rng.uniform(-cfg.tx_spread_db, cfg.tx_spread_db)) for b in self.beacons}
        self.tracks = {b: self._track(rng) for b in self.beacons}
        # One environment for every beacon (same shadowing field), independent fast fading.
        self.channel = Channel(self.site.positions, PathLoss.from_site(self.site), None, cfg.channel,
                               np.random.default_rng(rng.integers(0, 2**63)))
        # Each node reports each beacon at its own phase within the period.
        self.phase = rng.uniform(0.0, 1.0 / cfg.rate_hz, size=(cfg.n_beacons, cfg.n_anchors))

    def _track(self, rng: np.random.Generator) -> np.ndarray:
        c = self.cfg
        need = c.duration_s + 1.0
        for n in (4, 16, 64, 256):  # no longer a walk than needed (walking_track steps in Python)
            wp = random_waypoints(n, self.walk_bounds, rng, margin_m=0.5,
                                  min_leg_m=0.3 * min(c.width_m, c.height_m))
            tr = walking_track(wp, rate_hz=20.0, speed_mps=c.speed_mps, rng=rng, pause_prob=0.2, pause_s=1.5)
            if tr[-1, 0] >= need:
                break
        return loop_track(tr, need)

    def truth(self, beacon: str, t: float) -> np.ndarray:
        tr = self.tracks[beacon]
        return np.array([np.interp(t, tr[:, 0], tr[:, 1]), np.interp(t, tr[:, 0], tr[:, 2])])

    def espresense_table(self) -> dict:
        """The site file's ``[espresense]`` table for these nodes."""
        return {"rooms": dict(self.rooms), "time_field": self.cfg.time_field, "topic_prefix": self.cfg.topic_prefix}

    def messages(self, duration_s: float | None = None) -> Iterator[FleetMessage]:
        """Every node's message for every beacon, in time order (generated lazily, tick by tick)."""
        c = self.cfg
        dur = c.duration_s if duration_s is None else duration_s
        channels = np.array([37, 38, 39])
        period = 1.0 / c.rate_hz
        for k in range(int(round(dur * c.rate_hz))):
            tick: list[FleetMessage] = []
            for bi, b in enumerate(self.beacons):
                ref = c.rssi_at_1m_dbm + self.tx_offset[b]
                for ai, a in enumerate(self.site.anchors):
                    t = k * period + float(self.phase[bi, ai])
                    r, _ = self.channel.sample(self.truth(b, t), channels)
                    heard = r[ai][np.isfinite(r[ai])]
                    if not heard.size:
                        continue  # the node heard nothing this period: it reports nothing
                    rssi = float(heard.mean()) + self.tx_offset[b]
                    tick.append(FleetMessage(t, f"{c.topic_prefix}/devices/{b}/{self.node_names[ai]}",
                                             self._payload(b, rssi, ref, t), b, a.id))
            tick.sort(key=lambda m: m.t)
            yield from tick

    def _payload(self, beacon: str, rssi: float, ref: float, t: float) -> bytes:
        """The fields an ESPresense node writes (BleFingerprint::fill), plus the sim time."""
        dist = 10.0 ** ((ref - rssi) / (10.0 * ESPRESENSE_ABSORPTION))
        doc = {"id": beacon, "rssi@1m": round(ref, 2), "rssi": round(rssi, 2), "rxAdj": 0,
               "distance": round(dist, 2), "int": int(1000 / self.cfg.rate_hz)}
        if self.cfg.time_field:
            doc[self.cfg.time_field] = round(t, 6)
        return json.dumps(doc, separators=(",", ":")).encode()


# -- the in-process demo: broker + nodes + subscriber + tracker + estimators + publisher ---

@dataclass
class FleetResult:
    seed: int
    method: str
    per_beacon: dict  # beacon -> {"n", "mean_m", "median_m", "p95_m"}
    counters: dict

    @property
    def mean_error_m(self) -> float:
        return float(np.mean([v["mean_m"] for v in self.per_beacon.values()]))


def _errors(sc: FleetScenario, records: list, warmup_s: float) -> dict:
    out = {}
    for b in sc.beacons:
        e = np.array([np.hypot(*(np.array([x, y]) - sc.truth(b, t))) for bb, t, x, y in records
                      if bb == b and t >= warmup_s])
        out[b] = ({"n": int(e.size), "mean_m": round(float(e.mean()), 3), "median_m": round(float(np.median(e)), 3),
                   "p95_m": round(float(np.percentile(e, 95)), 3)} if e.size else {"n": 0})
    return out


def run_fleet(cfg: FleetConfig, workdir: str | Path, method: str = "pf-doa", warmup_s: float = 5.0,
              batch_s: float = 1.0, broker: Mosquitto | None = None, stall_s: float = 30.0,
              interrupt: Interrupt | None = None) -> FleetResult:
    """One seeded run through a real broker, in this process; per-beacon accuracy.

    The nodes' messages carry the simulated time (``time_field``) and are published one
    ``batch_s`` of simulated time at a time; the next batch waits until the subscriber has
    received and the tracker consumed the previous one. So the estimates depend on the
    seed only, not on how fast this machine or the broker runs.
    """
    from pfdoa.api import (
        ClientConfig,
        EspresenseInput,
        MqttClient,
        Publisher,
        PublisherConfig,
        Sink,
        build_pipeline,
        parse_url,
        pose_payload,
    )

    sc = FleetScenario(cfg)
    st = fleet_settings(sc)  # what the gateway process reads from fleet_site_toml
    own_broker = broker is None
    broker = broker or Mosquitto(Path(workdir) / "broker").start()
    records: list = []
    gw = MqttClient(ClientConfig(parse_url(broker.url("pfdoa/fleet")), client_id=f"fleet-gateway-{cfg.seed}",
                                 queue_size=1_000_000)).start()
    nodes = MqttClient(ClientConfig(parse_url(broker.url("espresense-sim")), client_id=f"fleet-nodes-{cfg.seed}",
                                    queue_size=1_000_000)).start()
    try:
        inp = EspresenseInput(gw, st.espresense, qos=1, max_queue=1_000_000).start()
        pub = Publisher(gw, PublisherConfig(node_id="fleet-demo"))

        class Scored:
            """The position output: each estimate as published (rounded as the JSON output)."""

            def write(self, rec) -> None:
                v = json.loads(pose_payload(rec.beacon, rec))
                records.append((rec.beacon, v["t"], v["x"], v["y"]))

            def close(self) -> None:
                pass

        class Published(Sink):
            """Every estimate and every beacon let go, to the broker."""

            def write(self, record) -> None:
                pub.estimate(record.beacon, record)

            def beacon_gone(self, beacon: str, reason: str) -> None:
                pub.beacon_gone(beacon)

        pipe = build_pipeline(st, method=method, seed=cfg.seed, named_beacons=True, writer=Scored(), sinks=Published())
        gateway, tracker, health = pipe.gateway, pipe.gateway.named, pipe.health
        assert tracker is not None  # named_beacons
        if not (gw.wait_connected(10) and nodes.wait_connected(10)):
            raise RuntimeError(f"could not connect to the broker: {broker.log_tail()}")
        if not gw.wait_subscribed(inp.topic_filter, 10):
            raise RuntimeError("the broker did not acknowledge the subscription")
        sent, now, next_health = 0, 0.0, 5.0
        batch_end = batch_s
        pending: list[FleetMessage] = []
        for m in sc.messages():
            if m.t < batch_end:
                pending.append(m)
                continue
            if interrupt is not None:
                interrupt.check()
            sent += _publish_and_consume(nodes, inp, gateway, pending, sent, stall_s)
            now = max(now, batch_end)
            gateway.poll(now)
            if now >= next_health:
                pub.health({"t": now, "estimates": health.estimates, **tracker.summary()})
                for aid, st_ in inp.anchor_status(now).items():
                    pub.anchor_status(aid, st_)
                next_health += 5.0
            pending, batch_end = [m], batch_end + batch_s
        sent += _publish_and_consume(nodes, inp, gateway, pending, sent, stall_s)
        gateway.finish()
        pub.health({"t": cfg.duration_s, "estimates": health.estimates, **tracker.summary()})
        delivered = gw.flush(stall_s)
        pipe.close()
        counters: dict[str, Any] = {"messages": sent, "input": inp.counters(), "tracker": tracker.summary(),
                    "estimates": health.estimates, "estimator_errors": health.estimator_errors,
                    "published_all": delivered, "mqtt": gw.summary()}
        counters["tracker"].pop("beacons", None)
        return FleetResult(cfg.seed, method, _errors(sc, records, warmup_s), counters)
    finally:
        nodes.stop(2.0)
        gw.stop(2.0)
        if own_broker:
            broker.stop()


def _publish_and_consume(nodes, inp, gateway, batch: list, sent_before: int, stall_s: float) -> int:
    for m in batch:
        nodes.publish(m.topic, m.payload)
    want = sent_before + len(batch)
    last, progress = inp.messages, time.monotonic()
    while inp.messages < want or inp.pending:
        for br in inp.read(0.05):
            gateway.push_beacon(br)
        if inp.messages != last:
            last, progress = inp.messages, time.monotonic()
        elif time.monotonic() - progress > stall_s:
            raise RuntimeError(f"no message for {stall_s} s: {inp.messages} of {want} arrived")
    return len(batch)


# -- the demo through the real gateway process ---------------------------------------------

GATEWAY_PREFIX = "pfdoa/fleet"
GATEWAY_HEALTH_S = 0.2  # how often the gateway says how far it has read (the publisher waits on it)


def fleet_sections(sc: FleetScenario, node_id: str = "fleet-demo") -> dict:
    """The scenario's site tables for the gateway: its anchors and radio model come with the
    site; ``[espresense]`` (rooms, message time), windows of :data:`FLEET_WINDOW_S`, a health
    period short enough for :func:`run_gateway_fleet` to pace the nodes by it."""
    sections = dict(sc.site.sections)  # a site file's own tables ([[rooms]], ...) stay
    sections.update({
        "gateway": {"mode": "window", "window_s": FLEET_WINDOW_S, "health_interval_s": GATEWAY_HEALTH_S},
        "beacons": {"max_beacons": max(32, sc.cfg.n_beacons)},
        "espresense": sc.espresense_table(),
        "mqtt": {"node_id": node_id},
    })
    return sections


def fleet_site_toml(sc: FleetScenario, node_id: str = "fleet-demo") -> str:
    """The site file of the scenario for ``pfdoa gateway`` (:func:`fleet_sections`)."""
    return site_to_toml(replace(sc.site, sections=fleet_sections(sc, node_id)))


def fleet_settings(sc: FleetScenario):
    """The gateway's settings of the scenario, as ``pfdoa gateway`` reads them from
    :func:`fleet_site_toml` (for the same chain in this process)."""
    from pfdoa.api import load_settings

    return load_settings("<fleet>", site=replace(sc.site, sections=fleet_sections(sc)))


class _Inbox:
    """What a subscriber received on the broker, by topic kind (paho's thread appends)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.poses: list[dict] = []
        self.topics: dict[str, str] = {}  # beacon -> the topic its poses came on
        self.health: dict | None = None

    def on_pose(self, topic: str, payload: bytes, _t: float) -> None:
        doc = json.loads(payload)
        with self.lock:
            self.poses.append(doc)
            self.topics.setdefault(doc["beacon"], topic)

    def on_health(self, _topic: str, payload: bytes, _t: float) -> None:
        doc = json.loads(payload)
        with self.lock:
            self.health = doc

    def unique_poses(self) -> list[dict]:
        """Poses by (beacon, t), first arrival kept (QoS 1 may deliver one twice)."""
        with self.lock:
            seen: dict[tuple, dict] = {}
            for p in self.poses:
                seen.setdefault((p["beacon"], p["t"]), p)
            return list(seen.values())

    def espresense(self) -> dict:
        with self.lock:
            return dict(((self.health or {}).get("inputs") or {}).get("espresense") or {})


class Interrupt:
    """Ctrl-C as a flag: SIGINT sets it, and the demo raises KeyboardInterrupt at its next
    wait or batch (:meth:`check`), never at an arbitrary instruction inside an MQTT client
    or a lock's critical section, where it could leave a lock held and the shutdown that
    follows (stopping the clients, the gateway and the broker) hanging."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def __enter__(self) -> "Interrupt":
        self._previous = signal.signal(signal.SIGINT, self._on_sigint)
        return self

    def __exit__(self, *exc) -> None:
        signal.signal(signal.SIGINT, self._previous)

    def _on_sigint(self, _signum, _frame) -> None:
        if self.requested:  # a second Ctrl-C: at once
            raise KeyboardInterrupt
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


def _wait(pred, what: str, timeout_s: float, proc: subprocess.Popen | None = None, log: Path | None = None,
          interrupt: Interrupt | None = None) -> None:
    """Wait for an event (the timeout only bounds a failure); a gateway that exits is one."""
    end = time.monotonic() + timeout_s
    while not pred():
        if interrupt is not None:
            interrupt.check()
        if proc is not None and proc.poll() is not None:
            tail = log.read_text(errors="replace")[-2000:] if log is not None and log.exists() else ""
            raise RuntimeError(f"pfdoa gateway exited with {proc.returncode} while waiting for {what}: {tail}")
        if time.monotonic() > end:
            raise RuntimeError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.02)


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 60.0) -> int:
    """``sig`` by pid (the gateway flushes and prints its final counters), SIGKILL if it hangs."""
    if proc.poll() is None:
        os.kill(proc.pid, sig)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
    return int(proc.returncode)


def run_gateway_fleet(cfg: FleetConfig, workdir: str | Path, method: str = "pf-doa", warmup_s: float = 5.0,
                      batch_s: float = 1.0, broker: Mosquitto | None = None, extra: tuple = (),
                      stall_s: float = 60.0, on_start=None, gateway_args: tuple[str, ...] = (),
                      interrupt: Interrupt | None = None) -> FleetResult:
    """One seeded run through a real broker and the real ``pfdoa gateway`` process.

    The gateway reads ESPresense messages (``--mqtt-input espresense``) on the site file of
    :func:`fleet_site_toml`; its timers run on the messages' simulated time. The nodes
    publish one ``batch_s`` of simulated time at a time and wait until the gateway's
    health (``<prefix>/health``, ``inputs.espresense``) says it has taken every message
    so far from its inbox, so nothing is dropped however slow the machine, and the
    estimates depend on the seed only. ``extra`` (``(topic, payload)`` pairs) are published
    with the first batch (hostile messages: the test counts their rejections). At the end
    the gateway is stopped with SIGINT (it flushes), and the poses on ``<prefix>/+/pose``
    are scored against the ground truth. ``on_start(gateway_proc, broker)`` is called
    once both run (the SIGINT test uses it). ``gateway_args`` are added to the gateway's
    command line (``--readings-out``, ``--record``, ...). The gateway and the broker are
    stopped on every exit path (an exception, KeyboardInterrupt: raised by ``interrupt``
    at a wait when Ctrl-C was pressed).
    """
    from pfdoa.api import ClientConfig, MqttClient, parse_url

    sc = FleetScenario(cfg)
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    site_path, out_path, stats_path, log_path = (work / f"gateway-{cfg.seed}.{ext}"
                                                 for ext in ("toml", "jsonl", "stats.json", "log"))
    site_path.write_text(fleet_site_toml(sc))
    own_broker = broker is None
    proc: subprocess.Popen | None = None
    listener = nodes = None
    inbox = _Inbox()
    try:
        broker = broker or Mosquitto(work / "broker").start()
        listener = MqttClient(ClientConfig(parse_url(broker.url(GATEWAY_PREFIX)),
                                           client_id=f"fleet-scorer-{cfg.seed}-{os.getpid()}")).start()
        listener.subscribe(f"{GATEWAY_PREFIX}/+/pose", inbox.on_pose, 1)
        listener.subscribe(f"{GATEWAY_PREFIX}/health", inbox.on_health, 1)
        nodes = MqttClient(ClientConfig(parse_url(broker.url("espresense-sim")), queue_size=1_000_000,
                                        client_id=f"fleet-nodes-{cfg.seed}-{os.getpid()}")).start()
        if not (listener.wait_subscribed(f"{GATEWAY_PREFIX}/+/pose", 10) and nodes.wait_connected(10)):
            raise RuntimeError(f"could not connect to the broker: {broker.log_tail()}")
        with open(log_path, "wb") as log_fh, open(out_path, "wb") as out_fh:
            # Its own session: a Ctrl-C at the terminal reaches the demo, which stops the
            # gateway itself (SIGINT: it flushes) before the broker.
            proc = subprocess.Popen([sys.executable, "-m", "pfdoa", "gateway", "--config", str(site_path),
                                     "--mqtt", broker.url(GATEWAY_PREFIX), "--mqtt-input", "espresense",
                                     "--method", method, "--seed", str(cfg.seed), "--stats", str(stats_path),
                                     *gateway_args],
                                    stdin=subprocess.DEVNULL, stdout=out_fh, stderr=log_fh, start_new_session=True)
        _wait(lambda: bool(inbox.espresense().get("subscribed")), "the gateway's ESPresense subscription",
              stall_s, proc, log_path, interrupt)
        if on_start is not None:
            on_start(proc, broker)
        sent = 0

        def publish(batch: list) -> None:
            nonlocal sent
            for topic, payload in batch:
                nodes.publish(topic, payload)
            sent += len(batch)
            _wait(lambda: inbox.espresense().get("messages", 0) >= sent and inbox.espresense().get("pending") == 0,
                  f"the gateway to read {sent} messages", stall_s, proc, log_path, interrupt)

        batch: list = list(extra)
        batch_end = batch_s
        for m in sc.messages():
            if m.t >= batch_end:
                publish(batch)
                batch, batch_end = [], batch_end + batch_s
            batch.append((m.topic, m.payload))
        publish(batch)
        code = stop_process(proc, signal.SIGINT)
        if code != 128 + signal.SIGINT:  # stopped by the signal, after its final counters
            raise RuntimeError(f"pfdoa gateway exited with {code}: {log_path.read_text(errors='replace')[-2000:]}")
        stats = json.loads(stats_path.read_text())
        made = stats["mqtt"]["estimates"]
        _wait(lambda: len(inbox.unique_poses()) >= made, f"{made} poses on the broker", stall_s,
              interrupt=interrupt)
        poses = inbox.unique_poses()
        records = [(p["beacon"], p["t"], p["x"], p["y"]) for p in poses]
        out = [json.loads(ln) for ln in out_path.read_text().splitlines()]  # the gateway's stdout
        named = dict(stats.get("named_beacons", {}))
        named.pop("beacons", None)
        counters: dict[str, Any] = {
            "messages": sent, "input": stats.get("inputs", {}).get("mqtt-espresense", {}), "tracker": named,
            "estimates": stats["estimates"], "estimator_errors": stats["estimator_errors"],
            "queue_drops": stats["queue_drops"], "poses": len(poses), "output_lines": len(out),
            "same_on_stdout": sorted((p["beacon"], p["t"], p["x"], p["y"]) for p in poses)
            == sorted((o["beacon"], o["t"], o["x"], o["y"]) for o in out),
            "pose_topics": dict(inbox.topics),
            "published_all": stats["mqtt"]["undelivered"] == 0 and stats["mqtt"]["queue_dropped"] == 0,
            "mqtt": stats["mqtt"]}
        return FleetResult(cfg.seed, method, _errors(sc, records, warmup_s), counters)
    finally:
        if proc is not None:
            stop_process(proc, signal.SIGTERM, 10.0)
        for c in (nodes, listener):
            if c is not None:
                c.stop(2.0)
        if own_broker and broker is not None:
            broker.stop()


def _print_result(r: FleetResult, in_process: bool) -> None:
    """One seed's lines: only numbers that depend on the seed (no timings, no duplicates)."""
    c = r.counters
    poses = "" if in_process else f", {c['poses']} poses on {GATEWAY_PREFIX}/+/pose"
    print(f"seed {r.seed}: {c['messages']} messages, {c['estimates']} estimates{poses}, "
          f"rejected {c['input']['rejected']}, dropped {c['input']['queue_drops']}, "
          f"published all: {c['published_all']}", flush=True)
    for b, v in r.per_beacon.items():
        print(f"  {b}: n={v['n']} mean {v.get('mean_m')} m, median {v.get('median_m')} m, p95 {v.get('p95_m')} m",
              flush=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m pfdoasim.fleet``: the fleet demo; per-beacon accuracy over seeds."""
    import argparse
    import tempfile

    ap = argparse.ArgumentParser(prog="python -m pfdoasim.fleet", description=main.__doc__)
    ap.add_argument("--beacons", type=int, default=4)
    ap.add_argument("--anchors", type=int, help="ESPresense nodes along the walls of a 12 x 8 m site (default 8)")
    ap.add_argument("--site", metavar="SITE.toml", help="the home's site file instead: its anchors (all ESPresense "
                                                       "nodes, [espresense] rooms), radio model and rooms")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default 60)")
    ap.add_argument("--seeds", default="1,2,3", help="comma-separated (default 1,2,3)")
    ap.add_argument("--method", default="pf-doa")
    ap.add_argument("--in-process", action="store_true",
                    help="run the gateway's chain in this process instead of the pfdoa gateway process")
    ap.add_argument("--workdir", metavar="DIR", help="keep the site files, outputs and logs here (default: a temporary "
                                                     "directory, removed)")
    ap.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    a = ap.parse_args(argv)
    if hasattr(signal, "SIGUSR1"):  # kill -USR1 <pid>: every thread's stack on stderr (a hang's where)
        import faulthandler

        faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        seeds = [int(s) for s in a.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds {a.seeds!r}: expected integers separated by commas")
    if a.site and a.anchors is not None:
        ap.error("--anchors and --site are alternatives (the site file places its nodes)")
    try:
        base = FleetConfig(n_beacons=a.beacons, n_anchors=a.anchors or 8, duration_s=a.duration, site_file=a.site)
        n_nodes = len(FleetScenario(replace(base, duration_s=0.0)).site.anchors)
    except PfdoaError as exc:  # a bad site file: one line
        print(f"pfdoasim.fleet: {exc}", file=sys.stderr)
        return exc.exit_code
    results = []
    how = "in this process" if a.in_process else "through the pfdoa gateway process"
    where = f" in {a.site}" if a.site else ""
    print(f"fleet demo {how}: mosquitto on 127.0.0.1, {n_nodes} ESPresense nodes{where}, {a.beacons} beacons, "
          f"{a.duration:g} simulated s per seed", flush=True)

    def started(proc: subprocess.Popen, broker: Mosquitto) -> None:  # on stderr: the summary stays the same
        print(f"pfdoasim.fleet: gateway pid {proc.pid}, broker pid {broker.proc.pid if broker.proc else None}",
              file=sys.stderr, flush=True)

    try:
        with Interrupt() as interrupt, tempfile.TemporaryDirectory(prefix="pfdoa-fleet-") as tmp:
            work = Path(a.workdir) if a.workdir else Path(tmp)
            with Mosquitto(work / "broker") as broker:
                for seed in seeds:
                    cfg = replace(base, seed=seed)
                    if a.in_process:
                        r = run_fleet(cfg, work, a.method, broker=broker, interrupt=interrupt)
                    else:
                        r = run_gateway_fleet(cfg, work, a.method, broker=broker, on_start=started,
                                              interrupt=interrupt)
                    results.append(r)
                    _print_result(r, a.in_process)
                    interrupt.check()
    except KeyboardInterrupt:  # the gateway and the broker are stopped by now (finally blocks)
        print("pfdoasim.fleet: interrupted; gateway and broker stopped", file=sys.stderr, flush=True)
        return 130
    means = [r.mean_error_m for r in results]
    print(f"{a.method}, {a.beacons} beacons x {n_nodes} anchors, {a.duration:g} s, seeds {a.seeds}: mean error "
          f"over beacons and seeds {np.mean(means):.3f} m (per seed: {', '.join(f'{m:.3f}' for m in means)}); "
          f"no odometry; in-sample: the site's radio model is the simulator's own (no calibration error); "
          f"first 5 s not scored")
    if a.json:
        Path(a.json).write_text(json.dumps([r.__dict__ for r in results], indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
