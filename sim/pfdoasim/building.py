"""A two-floor house for the floor and room estimates (:mod:`pfdoa.rooms`).

:func:`two_floor_site`: a 10 x 8 m plan on two floors (``ground`` z 0-3 m, ``first`` z
3-6 m), four rooms on each (:data:`ROOMS`), six anchors on each floor 2.6 m above it along
the walls (the two floors' anchors at other places, as nodes in a house are), a stair
from the ground floor's hall (x 6.5 -> 9.5 m at y 7.3 m) up to the first floor's landing.

:class:`BuildingWalk` (seeded): one beacon carried 1 m above the floor it is on, walking
between random points of a floor for 15-35 s, then to the stair and up or down it
(0.5 m/s), and so on. Every :attr:`BuildingConfig.rate_hz` it advertises once (a beacon
sequence number) and every anchor reports what it heard: the log-distance model of
:mod:`pfdoa.radio` over the 3-D distance, less :attr:`BuildingConfig.slab_loss_db` for
each floor slab between the beacon and the anchor (ITU-R P.1238's floor penetration loss
at 2.4 GHz is of this order, 10-20 dB), Gaussian noise and bursts of extra loss, rounded
to whole dBm; below -100 dBm nothing is heard. The site file's radio model is the
simulator's own (no calibration error: the numbers are about floors and rooms, not the
radio model).

:func:`run_building` writes the site file and the trace, runs ``pfdoa replay`` on them (the
same localizer as the gateway: floor filter, that floor's anchors, estimator, room) and
scores every estimate against the truth at its time: the floor, away from the stair
(horizontally more than :data:`STAIR_CLEARANCE_M` from it), and the room, where the true
position is more than :data:`WALL_CLEARANCE_M` from every wall of its room.
``python -m pfdoasim.building --seeds 1,2,3`` prints them (docs/fleet.md).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pfdoa.outfiles import open_stream, write_whole
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import Anchor, Site, site_to_toml
from pfdoasim.trajectories import random_waypoints, walking_track

FLOORS = (("ground", 0.0, 3.0), ("first", 3.0, 6.0))
PLAN = (0.0, 0.0, 10.0, 8.0)  # xmin, ymin, xmax, ymax (m), both floors
ROOMS = {
    "ground": {"kitchen": (0.0, 0.0, 5.0, 4.0), "living": (5.0, 0.0, 10.0, 4.0), "dining": (0.0, 4.0, 5.0, 8.0),
               "hall": (5.0, 4.0, 10.0, 8.0)},
    "first": {"bedroom": (0.0, 0.0, 5.0, 4.0), "nursery": (5.0, 0.0, 10.0, 4.0), "bath": (0.0, 4.0, 5.0, 8.0),
              "landing": (5.0, 4.0, 10.0, 8.0)},
}
ANCHOR_XY = {
    "ground": ((0.0, 0.0), (5.0, 0.0), (10.0, 0.0), (10.0, 8.0), (5.0, 8.0), (0.0, 8.0)),
    "first": ((0.0, 4.0), (3.5, 0.0), (10.0, 2.0), (10.0, 6.0), (7.0, 8.0), (2.0, 8.0)),
}
ANCHOR_HEIGHT_M = 2.6  # above the floor (a ceiling node)
STAIR = ((6.5, 7.3), (9.5, 7.3))  # bottom (ground floor) -> top (first floor)
STAIR_CLEARANCE_M = 1.5
WALL_CLEARANCE_M = 0.5
SENSITIVITY_DBM = -100.0


@dataclass(frozen=True)
class BuildingConfig:
    seed: int = 1
    duration_s: float = 150.0
    rate_hz: float = 5.0  # advertisements per second
    rssi_at_1m_dbm: float = -59.0
    path_loss_exponent: float = 2.7
    noise_db: float = 2.5
    burst_prob: float = 0.1  # a reading hit by a burst of extra loss
    burst_db: float = 6.0
    slab_loss_db: float = 15.0
    beacon_height_m: float = 1.0  # above the floor it is on
    speed_mps: float = 0.8
    stair_speed_mps: float = 0.5


def _rect(r: tuple[float, float, float, float]) -> list[list[float]]:
    x0, y0, x1, y1 = r
    return [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]


def two_floor_site(cfg: BuildingConfig = BuildingConfig()) -> Site:
    """The house's site: anchors with their z, the radio model, [[floors]], [[rooms]]."""
    anchors: list[Anchor] = []
    for (name, zmin, _zmax) in FLOORS:
        for x, y in ANCHOR_XY[name]:
            anchors.append(Anchor(id=len(anchors), x=x, y=y, z=zmin + ANCHOR_HEIGHT_M))
    sections = {
        "site": {"area": list(PLAN)},
        "floors": [{"name": n, "z": [lo, hi]} for n, lo, hi in FLOORS],
        "rooms": [{"name": room, "floor": floor, "polygon": _rect(r)} for floor, rooms in ROOMS.items()
                  for room, r in rooms.items()],
    }
    return Site(radio=PathLoss(cfg.rssi_at_1m_dbm, cfg.path_loss_exponent), anchors=tuple(anchors),
                name="two-floor-house", sections=sections, area=PLAN, target_z=cfg.beacon_height_m)


class BuildingWalk:
    """The beacon's walk (rows t, x, y, z, on_stair) and the anchors' readings of it."""

    def __init__(self, cfg: BuildingConfig = BuildingConfig()) -> None:
        self.cfg = cfg
        self.site = two_floor_site(cfg)
        self.rng = np.random.default_rng(cfg.seed)
        self.track = self._walk()
        self._noise_seed = int(self.rng.integers(0, 2**63))  # readings() gives the same every call

    def _walk(self) -> np.ndarray:
        c, rng = self.cfg, self.rng
        dt = 1.0 / c.rate_hz
        bottom, top = np.array(STAIR[0]), np.array(STAIR[1])
        floor = 0
        pos = bottom.copy()
        parts: list[np.ndarray] = []
        t0 = 0.0
        while t0 < c.duration_s:
            z = FLOORS[floor][1] + c.beacon_height_m
            n = int(rng.integers(3, 6))
            wp = np.vstack([pos, random_waypoints(n, PLAN, rng, margin_m=0.4, min_leg_m=2.0),
                            bottom if floor == 0 else top])
            leg = walking_track(wp, rate_hz=c.rate_hz, speed_mps=c.speed_mps, rng=rng, pause_prob=0.3, pause_s=2.0)
            parts.append(np.column_stack([leg[:, 0] + t0, leg[:, 1:3], np.full(len(leg), z), np.zeros(len(leg))]))
            t0 = parts[-1][-1, 0] + dt
            # The stair: straight, z from this floor's beacon height to the other's.
            a, b = (bottom, top) if floor == 0 else (top, bottom)
            k = max(2, int(round(np.hypot(*(b - a)) / c.stair_speed_mps * c.rate_hz)))
            f = np.linspace(0.0, 1.0, k)
            z1 = FLOORS[1 - floor][1] + c.beacon_height_m
            parts.append(np.column_stack([t0 + np.arange(k) * dt, a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]),
                                          z + f * (z1 - z), np.ones(k)]))
            t0 = parts[-1][-1, 0] + dt
            floor, pos = 1 - floor, b.copy()
        track = np.concatenate(parts)
        return track[track[:, 0] < c.duration_s]

    def readings(self) -> np.ndarray:
        """Rows (t, anchor id, rssi dBm, seq), one advertisement per track row."""
        c = self.cfg
        rng = np.random.default_rng(self._noise_seed)
        anchors = np.array([[a.x, a.y, a.z] for a in self.site.anchors])
        boundaries = np.array([hi for _n, _lo, hi in FLOORS[:-1]])
        p = self.track[:, 1:4]
        mean = mean_rssi(p, anchors, self.site.radio)  # 3-D distances
        lo, hi = np.minimum(p[:, 2:3, None], anchors[None, :, 2:3]), np.maximum(p[:, 2:3, None], anchors[None, :, 2:3])
        slabs = ((lo < boundaries) & (boundaries < hi)).sum(axis=-1).reshape(mean.shape)
        r = mean - c.slab_loss_db * slabs + rng.normal(0.0, c.noise_db, mean.shape)
        r = np.round(r - c.burst_db * (rng.random(mean.shape) < c.burst_prob))
        k, a = np.nonzero(r >= SENSITIVITY_DBM)
        ids = np.array(self.site.anchor_ids)
        # Each anchor reports a few ms after the advertisement (its own radio and link).
        t = self.track[k, 0] + 0.002 * (a + 1)
        return np.column_stack([t, ids[a], r[k, a], k % 65536])

    def truth(self, t: np.ndarray) -> np.ndarray:
        """Rows (x, y, z, on_stair) at times ``t`` (the walk's row at or just before)."""
        k = np.clip(np.searchsorted(self.track[:, 0], np.asarray(t) + 1e-9) - 1, 0, len(self.track) - 1)
        return self.track[k, 1:5]


def true_floor(z: float) -> str:
    return next(n for n, lo, hi in FLOORS if lo <= z < hi)


def true_room(x: float, y: float, floor: str) -> tuple[str | None, float]:
    """The room holding (x, y) on ``floor`` and the distance to its nearest wall (m)."""
    for name, (x0, y0, x1, y1) in ROOMS[floor].items():
        if x0 <= x <= x1 and y0 <= y <= y1:
            return name, min(x - x0, x1 - x, y - y0, y1 - y)
    return None, 0.0


def stair_distance(x: float, y: float) -> float:
    (ax, ay), (bx, by) = STAIR
    u = max(0.0, min(1.0, ((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / ((bx - ax) ** 2 + (by - ay) ** 2)))
    return math.hypot(x - (ax + u * (bx - ax)), y - (ay + u * (by - ay)))


def write_run(walk: BuildingWalk, out: Path) -> tuple[Path, Path]:
    """site.toml and trace.csv (t,anchor,rssi_dbm,seq) of the walk in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    site, trace = out / "site.toml", out / "trace.csv"
    write_whole(site, site_to_toml(walk.site), "the building's site file")  # pfdoa.outfiles, as every output
    rows = walk.readings()
    with open_stream(str(trace), "the building's trace")[0] as fh:
        fh.write("t,anchor,rssi_dbm,seq\n")
        for t, a, r, s in rows.tolist():
            fh.write(f"{t:.4f},{int(a)},{int(r)},{int(s)}\n")
    return site, trace


@dataclass
class BuildingScore:
    seed: int
    estimates: int
    floor_scored: int  # estimates away from the stair
    floor_correct: int
    room_scored: int  # estimates more than WALL_CLEARANCE_M from every wall of the true room
    room_correct: int
    mean_error_m: float

    @property
    def floor_rate(self) -> float:
        return self.floor_correct / self.floor_scored if self.floor_scored else math.nan

    @property
    def room_rate(self) -> float:
        return self.room_correct / self.room_scored if self.room_scored else math.nan


def score(walk: BuildingWalk, records: list[dict]) -> BuildingScore:
    """Floor and room of every record against the walk's truth at the record's time."""
    t = np.array([r["t"] for r in records])
    truth = walk.truth(t)
    fs = fc = rs = rc = 0
    err = []
    for rec, (x, y, z, on_stair) in zip(records, truth.tolist()):
        floor = true_floor(z)
        err.append(math.hypot(rec["x"] - x, rec["y"] - y))
        if not on_stair and stair_distance(x, y) > STAIR_CLEARANCE_M:
            fs += 1
            fc += rec["floor"] == floor
        if on_stair:
            continue
        room, wall = true_room(x, y, floor)
        if room is not None and wall > WALL_CLEARANCE_M:
            rs += 1
            rc += rec["room"] == room
    return BuildingScore(walk.cfg.seed, len(records), fs, fc, rs, rc, float(np.mean(err)) if err else math.nan)


def run_building(cfg: BuildingConfig, workdir: str | Path, method: str = "pf-doa") -> BuildingScore:
    """Write the run, ``pfdoa replay`` it (seeded) and score the floors and rooms."""
    from pfdoa.cli import main

    walk = BuildingWalk(cfg)
    out = Path(workdir) / f"building-{cfg.seed}"
    site, trace = write_run(walk, out)
    est = out / "estimates.jsonl"
    rc = main(["-q", "replay", str(trace), "--config", str(site), "--method", method, "--seed", str(cfg.seed),
               "--out", str(est)])
    if rc != 0:
        raise RuntimeError(f"pfdoa replay exited with {rc}")
    return score(walk, [json.loads(ln) for ln in est.read_text().splitlines()])


def main(argv: list[str] | None = None) -> int:
    """``python -m pfdoasim.building``: floor and room accuracy in the two-floor house over seeds."""
    import argparse
    import tempfile

    ap = argparse.ArgumentParser(prog="python -m pfdoasim.building", description=main.__doc__)
    ap.add_argument("--seeds", default="1,2,3", help="comma-separated (default 1,2,3)")
    ap.add_argument("--duration", type=float, default=BuildingConfig.duration_s, help="simulated seconds per seed")
    ap.add_argument("--method", default="pf-doa")
    a = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in a.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds {a.seeds!r}: expected integers separated by commas")
    with tempfile.TemporaryDirectory(prefix="pfdoa-building-") as tmp:
        scores = [run_building(BuildingConfig(seed=s, duration_s=a.duration), tmp, a.method) for s in seeds]
    for s in scores:
        print(f"seed {s.seed}: {s.estimates} estimates, floor {s.floor_correct}/{s.floor_scored} = "
              f"{100 * s.floor_rate:.1f} % away from the stair, room {s.room_correct}/{s.room_scored} = "
              f"{100 * s.room_rate:.1f} % more than {WALL_CLEARANCE_M} m from a wall, mean error {s.mean_error_m:.2f} m")
    fc, fs = sum(s.floor_correct for s in scores), sum(s.floor_scored for s in scores)
    rc, rs = sum(s.room_correct for s in scores), sum(s.room_scored for s in scores)
    print(f"{a.method}, seeds {a.seeds}: floor {100 * fc / fs:.1f} % ({fc}/{fs}), room {100 * rc / rs:.1f} % "
          f"({rc}/{rs}); no odometry; the site's radio model is the simulator's own")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
