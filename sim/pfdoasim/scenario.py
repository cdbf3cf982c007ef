"""Scenarios: a site, a ground-truth track, the radio channel, odometry noise and faults.

Named scenarios (``pfdoa sim --scenario NAME``):

* ``demo``              6 x 6 m room, 4 corner anchors, a seeded walk, mild shadowing.
* ``paper-boundary``, ``paper-inside``, ``paper-diagonal``
                        the paper's Dataset 0 paths (6 x 6 m, 0.1 m steps, n = 3), driven
                        as closed loops (the reference data's jumps become straight legs).
* ``espresense-6x4``    ESPresense-companion's accuracy-harness shape: 4 corner anchors in a
                        6 x 4 m two-room space, RSS noise 2.5 dB plus 10 % multipath bursts of
                        -6 dB, two walking tracks (``track`` = 0 or 1).
* ``walk``              a seeded random walk in any site (``--config SITE.toml``).
* ``two-beacons``       the ``demo`` room and walk for our beacon (entry 0 of the anchors'
                        filter tables), and an iBeacon on a walk of its own (entry 1,
                        no sequence number: its readings form events by time on the
                        anchors, ``NO_SEQ``), both at 10 Hz, half a period apart.
* ``demo-auth``         the ``demo`` run with our authenticated rolling beacon
                        (protocol/SPEC.md 9): its advertisements go to the anchors as
                        they are received (the raw BLE path), the anchors hold its key
                        (entry 0, ``PFDOA_AUTH``) and the gateway's site names its key
                        file (``beacon.key`` beside the site file).
* ``spoof``, ``spoof-auth``  ``demo`` and ``demo-auth`` with a spoofing transmitter
                        (:class:`Spoofer`): 10 dB louder than our beacon, at (1, 5), it
                        rebroadcasts our beacon's captured advertisements between ours:
                        after each one, the latest with the next sequence number written
                        in, one 2 s old and one 30 s old. Its radio has noise of its own,
                        so our beacon's readings are those of the run without it.
* ``hall``              a 10 x 6 m hall, eight anchors on its walls (corners and the
                        middle of each wall), n = 2.2, 1.5 dB of shadowing correlated over
                        2 m, a seeded walk.
* ``flat``              a 9 x 7 m flat, six anchors (five on walls, one on a shelf inside),
                        n = 2.7, 2 dB of shadowing correlated over 1 m (more, closer walls),
                        a seeded walk.

Anchors that hear each other (``Scenario.peer_period_ms`` > 0, ``pfdoa sim --peers MS``):
the anchors' tables get an ``ANCHORS`` entry (the last), each anchor sends its own
advertisement every that many ms and reports the others' (:mod:`pfdoasim.peers`: the same
channel, transmit offsets ``true_tx_offsets``), and the gateway's ``[[beacons]]`` gets the
anchors' entry (``peer_gateway``: its ``refit_s``, ``apply``).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace

import numpy as np

from pfdoa.errors import InputError
from pfdoa.odometry import OdometryNoise
from pfdoa.paths import paper_path
from pfdoa.protocol import beacons as beacon_frames
from pfdoa.protocol import defs
from pfdoa.protocol.filters import BeaconFilter
from pfdoa.radio import PathLoss
from pfdoa.site import Anchor, Site
from pfdoasim.channel import ChannelConfig
from pfdoasim.faults import FaultConfig
from pfdoasim.trajectories import random_waypoints, stamp, walking_track

BLE_ADV_CHANNELS = (37, 38, 39)
ZIGBEE_CHANNEL = 15
PEER_INDEX = defs.BEACON_SLOTS - 1  # the anchors' filter table entry of kind ANCHORS


@dataclass(frozen=True)
class AnchorSettings:
    """The anchors' stored configuration (protocol/SPEC.md 1.3), given to every core at boot."""

    alpha_q8: int = 64
    spike_db: int = 12
    offset_q8: int = 0
    report_mode: int = 0
    decimation: int = 1


@dataclass(frozen=True)
class OtherBeacon:
    """A beacon besides ours in the site: what the anchors listen for (its filter table
    entry), what it advertises, where it goes. The anchors match its advertisements
    themselves (the raw BLE path), so reports about it carry its entry and, without a
    sequence number, ``NO_SEQ``."""

    name: str
    index: int  # its entry in the anchors' filter tables
    filter: BeaconFilter
    adv_a: bytes  # its BLE device address (air order)
    adv_data: bytes  # what it advertises
    track: np.ndarray  # rows (t, x, y, heading), ground truth
    hz: float
    phase_s: float  # its first advertisement (then every 1/hz)
    window_s: float  # the gateway's grouping window for it

    def times(self, duration_s: float) -> np.ndarray:
        n = int(np.floor((duration_s - self.phase_s) * self.hz + 1e-9)) + 1 if duration_s >= self.phase_s else 0
        return self.phase_s + np.arange(n) / self.hz

    def pose_at(self, t: float) -> np.ndarray:
        tt = self.track[:, 0]
        return np.array([np.interp(t, tt, self.track[:, 1]), np.interp(t, tt, self.track[:, 2])])


@dataclass(frozen=True)
class Spoofer:
    """A transmitter that rebroadcasts our beacon's captured advertisements (the SIL of
    issue 52): from (x, y), ``gain_db`` louder than our beacon. After each advertisement of
    ours it sends, for each action (kind, delay_s, phase_s), phase_s later: ("replay", D)
    the advertisement of ours sent D s earlier (nothing before there is one), ("forge", 0)
    the latest one with the next sequence number written in (which an unauthenticated
    anchor cannot tell from the beacon's own next one). The phases are at least
    POLL_AFTER_S apart and from ours (the anchors' ticks only go forward)."""

    x: float
    y: float
    gain_db: float = 10.0
    actions: tuple[tuple[str, float, float], ...] = (("forge", 0.0, 0.025), ("replay", 2.0, 0.05),
                                                     ("replay", 30.0, 0.075))

    @staticmethod
    def label(action: tuple[str, float, float]) -> str:
        return action[0] if action[0] == "forge" else f"{action[0]}_{action[1]:g}s"


@dataclass
class Scenario:
    name: str
    site: Site
    track: np.ndarray  # rows (t, x, y, heading), ground truth, t from 0
    beacon_hz: float = 10.0
    radio: str = "ble"  # "ble": readings on the advertising channels; "zigbee": one per beacon
    adv_channels: tuple[int, ...] = BLE_ADV_CHANNELS
    channel: ChannelConfig = field(default_factory=ChannelConfig)
    odometry: OdometryNoise = field(default_factory=OdometryNoise)
    anchor: AnchorSettings = field(default_factory=AnchorSettings)
    faults: FaultConfig = field(default_factory=FaultConfig)
    seed: int = 0
    # true RSSI offsets of the anchors' receivers (default: the site's, i.e. perfect calibration)
    true_offsets: np.ndarray | None = None
    # gateway settings written into the site file for the gateway (sim-time seconds)
    gateway: dict = field(default_factory=dict)
    # beacons besides ours (their entries in the anchors' filter tables); ours is entry 0
    # and, with others, named `beacon_name` in the gateway's [[beacons]]
    others: tuple[OtherBeacon, ...] = ()
    beacon_name: str = "b0"
    # 0: the run; k >= 1: the k-th calibration walk through the same room (its own track,
    # and its own readings' noise, faults, odometry and latency; the room's walls, offsets
    # and anchor clocks are the seed's: pfdoasim.calibration)
    walk: int = 0
    # the site file the gateway is given (default: ``site``, the room as it truly is); the
    # simulated radio always follows ``site`` and ``true_offsets``
    gateway_site: Site | None = None
    # our beacon as the authenticated rolling beacon (SPEC 9) with this key; its counter is
    # floor((auth_epoch_ms + simulated ms) / 4096)
    auth_key: bytes | None = None
    auth_epoch_ms: int = 0
    # a transmitter replaying and forging our beacon's advertisements
    spoofer: Spoofer | None = None
    # anchors that hear each other (module doc): their advertisement period (0: they send
    # none), their transmit offsets (dB, default 0) and the gateway's anchors' entry's keys
    peer_period_ms: int = 0
    true_tx_offsets: np.ndarray | None = None
    peer_gateway: dict = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.track[-1, 0]) if len(self.track) else 0.0

    @property
    def channels(self) -> np.ndarray:
        return np.array(self.adv_channels if self.radio == "ble" else (ZIGBEE_CHANNEL,), dtype=int)

    @property
    def raw_beacon(self) -> bool:
        """Our beacon's advertisements reach the anchors as received frames (matched by the
        cores), not as readings the board matched (the authenticated beacon, a spoofer)."""
        return self.auth_key is not None or self.spoofer is not None

    def filter_table(self) -> tuple[BeaconFilter, ...] | None:
        """The anchors' filter table: ours in entry 0 (the authenticated beacon with its key),
        the others in theirs, the ANCHORS entry last when the anchors hear each other (None:
        the first-boot table, ours only)."""
        if not self.others and self.auth_key is None and not self.peer_period_ms:
            return None
        ours = BeaconFilter.pfdoa(defs.FILTER_DEFAULT_ID) if self.auth_key is None else BeaconFilter.pfdoa_auth(self.auth_key)
        table = [ours] + [BeaconFilter.none()] * (defs.BEACON_SLOTS - 1)
        for b in self.others:
            table[b.index] = b.filter
        if self.peer_period_ms:
            if any(b.index == PEER_INDEX for b in self.others):
                raise ValueError(f"entry {PEER_INDEX} is the anchors' (peer readings)")
            table[PEER_INDEX] = BeaconFilter.anchors(self.peer_period_ms)
        return tuple(table)

    def beacons_table(self) -> list[dict]:
        """The gateway's ``[[beacons]]`` for this scenario (empty with our beacon alone),
        written by pfdoa.site's one writer."""
        peers = ([{"kind": "anchors", "index": PEER_INDEX, "period_ms": self.peer_period_ms, **self.peer_gateway}]
                 if self.peer_period_ms else [])
        if not self.others and self.auth_key is None:
            return peers
        out: list[dict] = [{"name": self.beacon_name, "kind": "pfdoa", "odometry": True}]
        if self.auth_key is not None:  # the key in a file of its own beside the site file
            out = [{"name": self.beacon_name, "kind": "pfdoa_auth", "key_file": AUTH_KEY_FILE, "odometry": True}]
        for b in self.others:
            f = b.filter
            if f.kind != defs.FILTER_IBEACON:
                raise ValueError(f"{b.name}: only iBeacons are written here")
            out.append({"name": b.name, "kind": "ibeacon", "index": b.index, "uuid": f.match[:16].hex(),
                        "major": int.from_bytes(f.match[16:18], "big"),
                        "minor": int.from_bytes(f.match[18:20], "big"), "period_ms": f.period_ms,
                        "window_s": float(b.window_s)})
        return out + peers

    def pose_at(self, t: float) -> np.ndarray:
        """Ground truth (x, y, heading) at time t (linear interpolation, heading unwrapped)."""
        tt = self.track[:, 0]
        x = np.interp(t, tt, self.track[:, 1])
        y = np.interp(t, tt, self.track[:, 2])
        h = np.interp(t, tt, np.unwrap(self.track[:, 3]))
        return np.array([x, y, h])


def square_site(width_m: float, height_m: float, rssi_at_1m_dbm: float, n: float,
                ids: tuple[int, ...] = (1, 2, 3, 4), name: str = "") -> Site:
    """Four anchors at the corners (0,0), (0,h), (w,h), (w,0) (the paper's order)."""
    corners = [(0.0, 0.0), (0.0, height_m), (width_m, height_m), (width_m, 0.0)]
    return Site(
        radio=PathLoss(rssi_at_1m_dbm, n),
        anchors=tuple(Anchor(id=i, x=x, y=y) for i, (x, y) in zip(ids, corners)),
        name=name,
    )


def hall_site() -> Site:
    """The ``hall`` scenario's room: 10 x 6 m, eight anchors on the walls (ids 1-8)."""
    spots = [(0.0, 0.0), (0.0, 3.0), (0.0, 6.0), (5.0, 6.0), (10.0, 6.0), (10.0, 3.0), (10.0, 0.0), (5.0, 0.0)]
    return Site(radio=PathLoss(-55.0, 2.2), anchors=tuple(Anchor(id=i + 1, x=x, y=y) for i, (x, y) in enumerate(spots)),
                name="sim-hall")


def flat_site() -> Site:
    """The ``flat`` scenario's rooms: 9 x 7 m, six anchors (ids 1-6), one of them inside."""
    spots = [(0.0, 0.0), (0.0, 7.0), (4.5, 7.0), (9.0, 5.0), (9.0, 0.0), (4.0, 2.5)]
    return Site(radio=PathLoss(-52.0, 2.7), anchors=tuple(Anchor(id=i + 1, x=x, y=y) for i, (x, y) in enumerate(spots)),
                name="sim-flat")


def loop_track(track: np.ndarray, duration_s: float) -> np.ndarray:
    """Repeat a track (rows t, x, y, heading) until it covers ``duration_s``, then cut it."""
    if duration_s <= 0:
        raise InputError(f"duration must be > 0 s, got {duration_s}")
    dt = float(track[1, 0] - track[0, 0]) if len(track) > 1 else 0.1
    period = float(track[-1, 0]) + dt
    reps = int(math.ceil((duration_s + dt) / period))
    parts = []
    for r in range(reps):
        p = track.copy()
        p[:, 0] += r * period
        parts.append(p)
    out = np.concatenate(parts)
    return out[out[:, 0] <= duration_s + 1e-9]


def _walk(site: Site, duration_s: float, rng: np.random.Generator, speed_mps: float = 0.8,
          margin_m: float = 0.4) -> np.ndarray:
    xmin, ymin, xmax, ymax = site.bounds
    pts = []
    track = np.zeros((0, 4))
    for n in (16, 64, 256, 1024):
        wp = random_waypoints(n, (xmin, ymin, xmax, ymax), rng, margin_m=margin_m,
                              min_leg_m=0.3 * min(xmax - xmin, ymax - ymin))
        track = walking_track(wp, rate_hz=20.0, speed_mps=speed_mps, rng=rng, pause_prob=0.2, pause_s=1.5)
        if track[-1, 0] >= duration_s:
            break
        pts.append(wp)
    return loop_track(track, duration_s)


# Two walks through the two rooms of the 6 x 4 m space (a wall at x = 3 with a door at
# y 1.5..2.5), in the spirit of ESPresense-companion's baseline tracks.
ESPRESENSE_TRACKS = (
    np.array([[0.8, 0.8], [2.2, 3.2], [2.6, 2.0], [3.4, 2.0], [5.2, 3.2], [5.2, 0.8], [3.4, 2.0],
              [2.6, 2.0], [0.8, 3.0], [0.8, 0.8]]),
    np.array([[5.4, 2.0], [4.0, 0.6], [3.4, 1.8], [2.6, 2.2], [1.5, 3.4], [0.6, 2.0], [1.5, 0.6],
              [2.6, 1.8], [3.4, 2.2], [4.6, 3.4], [5.4, 2.0]]),
)


WALK_SCENARIOS = ("demo", "walk", "hall", "flat")  # their track is a seeded walk: a room can be walked again
CALIBRATION_STREAM = 0xCA1  # keys calibration walks' random streams apart from every other use of the seed


def build(name: str, seed: int = 0, duration_s: float | None = None, site: Site | None = None,
          track: int = 0, walk: int = 0) -> Scenario:
    """A named scenario (see the module doc). ``duration_s`` None = the scenario's default.

    ``walk`` k >= 1 is the k-th calibration walk through the same room: a walk of its own
    (its trajectory seeded by (seed, k)) in a scenario whose track is a seeded walk."""
    key = name.lower()
    if walk:
        if key not in WALK_SCENARIOS:
            raise InputError(f"scenario {name!r} has a fixed track; calibration walks need a seeded walk "
                             f"({', '.join(WALK_SCENARIOS)})")
        if walk < 0:
            raise InputError(f"walk must be >= 0, got {walk}")
        rng = np.random.default_rng([seed, CALIBRATION_STREAM, walk])
    else:
        rng = np.random.default_rng(seed)
    if key == "demo":
        site = site or square_site(6.0, 6.0, -45.0, 3.0, name="sim-demo")
        tr = _walk(site, duration_s or 60.0, rng)
        return Scenario("demo", site, tr, beacon_hz=10.0,
                        channel=ChannelConfig(noise_db=2.0, shadowing_db=1.0, multipath_prob=0.05),
                        seed=seed, walk=walk)
    if key.startswith("paper-"):
        size, step = 6.0, 0.1
        site = site or square_site(size, size, -45.0, 3.0, name=f"sim-{key}")
        pts = paper_path(key[len("paper-"):], size_m=size, step_m=step, closed=True)
        beacon_hz = 10.0  # one beacon per 0.1 m step: 1 m/s
        tr = stamp(pts, beacon_hz)
        if duration_s:
            tr = loop_track(tr, duration_s)
        return Scenario(key, site, tr, beacon_hz=beacon_hz, radio="zigbee",
                        channel=ChannelConfig(noise_db=2.0), seed=seed)
    if key == "espresense-6x4":
        if track not in (0, 1):
            raise InputError(f"espresense-6x4 has tracks 0 and 1, got {track}")
        site = site or square_site(6.0, 4.0, -59.0, 2.7, name="sim-espresense-6x4")
        wp = ESPRESENSE_TRACKS[track]
        tr = walking_track(wp, rate_hz=20.0, speed_mps=0.7, rng=rng, pause_prob=0.3, pause_s=2.0,
                           speed_jitter=0.1)
        tr = loop_track(tr, duration_s or 60.0)
        return Scenario(f"espresense-6x4/track{track}", site, tr, beacon_hz=5.0, radio="ble",
                        adv_channels=(37,),
                        channel=ChannelConfig(noise_db=2.5, multipath_prob=0.10, multipath_db=6.0),
                        seed=seed)
    if key == "two-beacons":
        sc = build("demo", seed, duration_s, site)
        # Its own random stream: our beacon walks exactly as in "demo" with this seed.
        tag_track = _walk(sc.site, duration_s or 60.0, np.random.default_rng([seed, 1]))
        hz = sc.beacon_hz
        tag = OtherBeacon("ibeacon", 1, BeaconFilter.ibeacon(IBEACON_UUID, 1, 2, period_ms=IBEACON_PERIOD_MS),
                          IBEACON_ADDRESS, beacon_frames.ibeacon_adv_data(bytes.fromhex(IBEACON_UUID), 1, 2),
                          tag_track, hz, 0.5 / hz, 1.0 / hz)
        return replace(sc, name="two-beacons", others=(tag,), beacon_name="ours")
    if key in ("demo-auth", "spoof", "spoof-auth"):
        sc = build("demo", seed, duration_s, site)
        auth = key != "spoof"
        return replace(sc, name=key, auth_key=sim_auth_key(seed) if auth else None, auth_epoch_ms=AUTH_EPOCH_MS,
                       spoofer=Spoofer(*SPOOFER_AT) if key.startswith("spoof") else None)
    if key in ("hall", "flat"):
        site = site or (hall_site() if key == "hall" else flat_site())
        tr = _walk(site, duration_s or 60.0, rng)
        shadowing = (1.5, 2.0) if key == "hall" else (2.0, 1.0)  # (sigma dB, correlation length m)
        return Scenario(key, site, tr, beacon_hz=10.0,
                        channel=ChannelConfig(noise_db=2.0, shadowing_db=shadowing[0], shadowing_corr_m=shadowing[1],
                                              multipath_prob=0.05),
                        seed=seed, walk=walk)
    if key == "walk":
        if site is None:
            raise InputError("scenario 'walk' needs a site (--config SITE.toml)")
        tr = _walk(site, duration_s or 60.0, rng)
        return Scenario("walk", site, tr, beacon_hz=10.0,
                        channel=ChannelConfig(noise_db=2.0, shadowing_db=1.0, multipath_prob=0.05),
                        seed=seed, walk=walk)
    raise InputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")


SCENARIOS = ("demo", "paper-boundary", "paper-inside", "paper-diagonal", "espresense-6x4", "walk", "two-beacons",
             "demo-auth", "spoof", "spoof-auth", "hall", "flat")
# The authenticated beacon's key file, beside the gateway's site file; the simulated
# beacon's key comes from the seed (a run is a function of it); its clock starts at
# AUTH_EPOCH_MS (2026-01-01, Unix milliseconds), half a period (2,048 ms) into one.
AUTH_KEY_FILE = "beacon.key"
AUTH_EPOCH_MS = 1_767_225_600_000
SPOOFER_AT = (1.0, 5.0)


def sim_auth_key(seed: int) -> bytes:
    return hashlib.sha256(f"pfdoa simulated beacon key {seed}".encode()).digest()[:defs.AUTH_KEY_LEN]
# The two-beacons scenario's iBeacon (Apple Proximity Beacon Specification): an arbitrary
# UUID, major 1 minor 2, at a fixed device address; its events span at most half a period.
IBEACON_UUID = "f7826da64fa24e988024bc5b71e0893e"
IBEACON_ADDRESS = bytes.fromhex("0a0b0c0d0e0f")
IBEACON_PERIOD_MS = 50
