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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from pfdoa.errors import InputError
from pfdoa.odometry import OdometryNoise
from pfdoa.paths import paper_path
from pfdoa.site import Anchor, Radio, Site
from pfdoasim.channel import ChannelConfig
from pfdoasim.faults import FaultConfig
from pfdoasim.trajectories import random_waypoints, stamp, walking_track

BLE_ADV_CHANNELS = (37, 38, 39)
ZIGBEE_CHANNEL = 15


@dataclass(frozen=True)
class AnchorSettings:
    """The anchors' stored configuration (protocol/SPEC.md 1.3), given to every core at boot."""

    alpha_q8: int = 64
    spike_db: int = 12
    offset_q8: int = 0
    report_mode: int = 0
    decimation: int = 1


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

    @property
    def duration_s(self) -> float:
        return float(self.track[-1, 0]) if len(self.track) else 0.0

    @property
    def channels(self) -> np.ndarray:
        return np.array(self.adv_channels if self.radio == "ble" else (ZIGBEE_CHANNEL,), dtype=int)

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
        radio=Radio(rssi_at_1m_dbm, n),
        anchors=tuple(Anchor(id=i, x=x, y=y) for i, (x, y) in zip(ids, corners)),
        name=name,
    )


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


def build(name: str, seed: int = 0, duration_s: float | None = None, site: Site | None = None,
          track: int = 0) -> Scenario:
    """A named scenario (see the module doc). ``duration_s`` None = the scenario's default."""
    rng = np.random.default_rng(seed)
    key = name.lower()
    if key == "demo":
        site = site or square_site(6.0, 6.0, -45.0, 3.0, name="sim-demo")
        tr = _walk(site, duration_s or 60.0, rng)
        return Scenario("demo", site, tr, beacon_hz=10.0,
                        channel=ChannelConfig(noise_db=2.0, shadowing_db=1.0, multipath_prob=0.05),
                        seed=seed)
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
    if key == "walk":
        if site is None:
            raise InputError("scenario 'walk' needs a site (--config SITE.toml)")
        tr = _walk(site, duration_s or 60.0, rng)
        return Scenario("walk", site, tr, beacon_hz=10.0,
                        channel=ChannelConfig(noise_db=2.0, shadowing_db=1.0, multipath_prob=0.05),
                        seed=seed)
    raise InputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")


SCENARIOS = ("demo", "paper-boundary", "paper-inside", "paper-diagonal", "espresense-6x4", "walk")


def with_duration(sc: Scenario, duration_s: float) -> Scenario:
    return replace(sc, track=loop_track(sc.track, duration_s))
