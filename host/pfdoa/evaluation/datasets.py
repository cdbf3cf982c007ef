"""The evaluation's inputs as sequences of observations with ground truth.

Every dataset becomes :class:`Sequence` objects: observation times, RSSI per anchor in site
order (NaN = missing), the robot-frame odometry increment since the previous observation
(or None) and the ground truth, which only the scorer reads. Data come from
``pfdoa/data`` (committed copies, see its README.md), never from outside the package.
"""

from __future__ import annotations

import csv
import functools
import gzip
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.odometry import OdometryNoise, noisy_increments
from pfdoa.paths import paper_path
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import Anchor, Site, load_site, parse_site
from pfdoa.trace import (
    DEFAULT_WINDOW_S,
    OdometryTrace,
    by_beacon,
    group_by_window,
    odometry_part,
    read_odometry,
    read_trace,
    reporting_window,
)
from pfdoa.types import Odometry

DATA_DIR = Path(__file__).resolve().parent.parent / "data"


@dataclass
class Sequence:
    name: str
    site: Site
    t: np.ndarray  # (k,)
    rssi: np.ndarray  # (k, n_anchors) dBm, site order, NaN = missing
    truth: np.ndarray  # (k, 2) metres; for scoring only
    odometry: list[Odometry] | None = None  # increment since the previous observation
    count: np.ndarray | None = None  # (k, n_anchors) readings behind each value (time windows)
    beacon: str = ""  # the beacon a recorded run's readings name ("": none, the site's one beacon)

    def __len__(self) -> int:
        return int(self.t.size)


def make_site(name: str, positions, a1m: float, n: float, offsets=None) -> Site:
    offsets = np.zeros(len(positions)) if offsets is None else np.asarray(offsets, dtype=float)
    anchors = tuple(Anchor(id=i, x=float(x), y=float(y), rssi_offset_db=float(o))
                    for i, ((x, y), o) in enumerate(zip(positions, offsets)))
    return Site(radio=PathLoss(float(a1m), float(n)), anchors=anchors, name=name)


# --------------------------------------------------------------------------- Dataset 0
D0_SIZE_M = 6.0
D0_STEP_M = 0.1
D0_RSSI_AT_1M_DBM = -40.0
D0_PATH_LOSS_EXPONENT = 3.0
D0_NOISE_DB = (1.0, 2.0, 3.0, 4.0)
D0_PATHS = ("Diagonal", "Inside", "Boundary")  # Table I order
D0_DT_S = 1.0  # one observation per 0.1 m step: a slow robot at 1 Hz


def d0_site(n: float = D0_PATH_LOSS_EXPONENT, size_m: float = D0_SIZE_M) -> Site:
    """Anchors N1..N4 at (0,0), (0,s), (s,s), (s,0) as in the paper's gradient equations."""
    s = size_m
    return make_site("dataset0", [(0, 0), (0, s), (s, s), (s, 0)], D0_RSSI_AT_1M_DBM, n)


def _headings(path: np.ndarray) -> np.ndarray:
    """Heading at each point = direction to the next point (the last keeps the previous one)."""
    d = np.diff(path, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]]) if h.size else np.zeros(len(path))


def d0_sequence(path_name: str, noise_db: float, rng: np.random.Generator,
                n: float = D0_PATH_LOSS_EXPONENT, step_m: float = D0_STEP_M) -> Sequence:
    """The paper's simulation: Gaussian RSS noise on the log-distance model along a paper path.

    Odometry: the true robot-frame increments between consecutive points (heading = direction
    of travel) with the default slip noise (:class:`pfdoa.odometry.OdometryNoise`); the paper's teleports between path
    segments show up as one long increment, as wheel odometry would report a drive there.
    """
    site = d0_site(n)
    pts = paper_path(path_name.lower(), size_m=D0_SIZE_M, step_m=step_m)
    t = np.arange(len(pts)) * D0_DT_S
    mu = mean_rssi(pts, site.positions, PathLoss.from_site(site), site.offsets, site.heights)
    rssi = mu + rng.normal(0.0, noise_db, size=mu.shape)
    track = np.column_stack([t, pts, _headings(pts)])
    inc = noisy_increments(track, OdometryNoise(), rng)
    odo = [Odometry(0.0, 0.0, 0.0)] + [Odometry(float(a), float(b), float(c)) for _, a, b, c in inc[1:]]
    return Sequence(f"dataset0/{path_name}/{noise_db:g}dB", site, t, rssi, pts, odo)


# --------------------------------------------------------------------------- Dataset 1
D1_TECHS = {"Wi-Fi": "wifi", "BLE": "ble", "Zigbee": "zigbee"}
D1_POSITIONS = [(0.0, 0.0), (0.0, 4.0), (4.0, 0.0)]  # RSSI A, B, C
# The paper's path-loss values for Dataset 1 (A dBm, n).
D1_PAPER_RADIO = {"wifi": (-45.73, 2.162), "ble": (-75.48, 2.271), "zigbee": (-50.33, 2.935)}


@functools.lru_cache(maxsize=None)
def _d1_table(tech: str, part: str) -> tuple[np.ndarray, np.ndarray]:
    """(points (k,2), rssi dBm (k,3)) of ``{tech}-{part}.csv``; RSSI stored as positive = -dBm."""
    with open(DATA_DIR / "paper_dataset1" / f"{tech}-{part}.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    pts = np.array([[float(r["x"]), float(r["y"])] for r in rows])
    rssi = -np.array([[float(r[f"RSSI {c}"]) for c in "ABC"] for r in rows])
    return pts, rssi


def d1_site(tech: str, a1m: float | None = None, n: float | None = None, offsets=None) -> Site:
    pa, pn = D1_PAPER_RADIO[tech]
    return make_site(f"dataset1-{tech}", D1_POSITIONS, pa if a1m is None else a1m, pn if n is None else n, offsets)


def d1_sequence(tech: str, site: Site) -> Sequence:
    """The 49 fingerprint points in file order as a trajectory (as the paper), 1 s apart."""
    pts, rssi = _d1_table(tech, "dataset1")
    return Sequence(f"dataset1/{tech}", site, np.arange(len(pts), dtype=float), rssi, pts, None)


# The *-testdata.csv files give x and y transposed relative to *-dataset1.csv and the stated
# anchor positions: for all three technologies a path-loss fit to the test points as given
# has n = 0.4-1.3 and a larger residual, and with x <-> y swapped n = 1.4-2.2 and a smaller
# residual (the fingerprint file as given fits n = 1.5-2.0, close to the paper's values).
D1_TESTDATA_TRANSPOSED = True


def d1_calibration_readings(tech: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, anchor index, rssi) of the 10 test points (never scored)."""
    pts, rssi = _d1_table(tech, "testdata")
    if D1_TESTDATA_TRANSPOSED:
        pts = pts[:, ::-1]
    k, m = rssi.shape
    return np.repeat(pts, m, axis=0), np.tile(np.arange(m), k), rssi.ravel()


# --------------------------------------------------------------------------- Dataset 2
D2_POSITIONS = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]  # s0..s3
D2_CHANNEL_SETS = {"Channel 0": (0,), "Channel 39": (39,), "Channels 0-39": tuple(range(40))}
D2_DWELL = 5  # observations per point for a single channel


@dataclass(frozen=True)
class D2Data:
    points: np.ndarray  # (p, 2) the static target points, along the diagonal
    # readings[a][(point index, channel)] = rssi array in file order
    readings: tuple[dict[tuple[int, int], np.ndarray], ...]


@functools.lru_cache(maxsize=1)
def d2_data() -> D2Data:
    per_anchor = []
    all_pts: set[tuple[float, float]] = set()
    for a in range(4):
        with gzip.open(DATA_DIR / "paper_dataset2" / "diag0" / f"s{a}.csv.gz", "rt", newline="") as fh:
            rows = list(csv.DictReader(fh, delimiter=";"))
        per_anchor.append(rows)
        all_pts.update((float(r["x"]), float(r["y"])) for r in rows)
    points = np.array(sorted(all_pts))
    index = {tuple(p): i for i, p in enumerate(points.tolist())}
    readings = []
    for rows in per_anchor:
        acc: dict[tuple[int, int], list[float]] = {}
        for r in rows:
            key = (index[(float(r["x"]), float(r["y"]))], int(r["channel"]))
            acc.setdefault(key, []).append(float(r["rssi"]))
        readings.append({k: np.array(v) for k, v in acc.items()})
    return D2Data(points, tuple(readings))


def d2_site(a1m: float, n: float, offsets=None) -> Site:
    return make_site("dataset2-diag", D2_POSITIONS, a1m, n, offsets)


def d2_calibration_readings(point_ids, channels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every raw reading at the given points and channels: (points, anchor index, rssi)."""
    data = d2_data()
    pts, idx, val = [], [], []
    for a, table in enumerate(data.readings):
        for p in point_ids:
            for ch in channels:
                r = table.get((p, ch))
                if r is None:
                    continue
                pts.append(np.repeat(data.points[p][None, :], r.size, axis=0))
                idx.append(np.full(r.size, a))
                val.append(r)
    return np.concatenate(pts), np.concatenate(idx), np.concatenate(val)


def d2_sequence(point_ids, channels, site: Site, name: str) -> Sequence:
    """Observations at static points visited in diagonal order.

    The anchors' readings carry no timestamps, so one observation pairs the j-th reading of
    each anchor at the same point and channel. A single channel gives ``D2_DWELL``
    observations per point (j evenly spread over the recording); several channels give one
    observation per channel (the middle reading), in channel order.
    """
    data = d2_data()
    obs, truth = [], []
    for p in point_ids:
        for ch in channels:
            tables = [tab.get((p, ch), np.zeros(0)) for tab in data.readings]
            m = min(t.size for t in tables)
            if m == 0:
                continue
            dwell = D2_DWELL if len(channels) == 1 else 1
            js = np.unique(np.linspace(0, m - 1, dwell + 2)[1:-1].round().astype(int)) if dwell > 1 else [m // 2]
            for j in js:
                obs.append([t[j] for t in tables])
                truth.append(data.points[p])
    rssi = np.array(obs, dtype=float)
    return Sequence(name, site, np.arange(len(rssi), dtype=float), rssi, np.array(truth), None)


# --------------------------------------------------------------------------- recorded traces

@dataclass(frozen=True)
class TraceSet:
    """Recorded runs of one site in the common formats (the committed robot runs, or a user's)."""

    name: str
    site_path: str
    runs: tuple[tuple[str, str, str | None], ...]  # (run name, trace path, odometry path or None)
    window_s: float = DEFAULT_WINDOW_S

    @property
    def run_names(self) -> list[str]:
        return [r[0] for r in self.runs]

    def run(self, name: str) -> tuple[str, str, str | None]:
        for r in self.runs:
            if r[0] == name:
                return r
        raise KeyError(name)


def run_name(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".csv"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def odometry_beside(trace_path: Path) -> Path | None:
    """``<run>.odom.csv[.gz]`` next to ``<run>.csv[.gz]``, if present."""
    stem = run_name(trace_path)
    for cand in (f"{stem}.odom.csv", f"{stem}.odom.csv.gz"):
        p = trace_path.with_name(cand)
        if p.exists():
            return p
    return None


def trace_set(name: str, site_path, trace_paths, *, odometry: bool = True, window_s: float | None = None) -> TraceSet:
    """A :class:`TraceSet` from trace files; odometry files found beside them are used.
    ``window_s`` None: the runs' reporting window (:func:`pfdoa.trace.reporting_window`)."""
    runs = []
    seen: set[str] = set()
    for tp in map(Path, trace_paths):
        run = run_name(tp)
        if run in seen:
            from pfdoa.errors import InputError

            raise InputError(f"{tp}: two traces named {run!r}")
        seen.add(run)
        odo = odometry_beside(tp) if odometry else None
        runs.append((run, str(tp), None if odo is None else str(odo)))
    if window_s is None:
        window_s = reporting_window([trace_cached(r[1]) for r in runs])
    return TraceSet(name, str(site_path), tuple(sorted(runs)), window_s)


NEUTRAL_RADIO = {"rssi_at_1m_dbm": -50.0, "path_loss_exponent": 2.0}  # replaced by calibration


def site_from_anchors_json(path: str | Path):
    """A :class:`~pfdoa.site.Site` from the ``anchors`` list of an anchors.json file."""
    from pfdoa.site import MAX_FILE_BYTES

    p = Path(path)
    try:
        with open(p, "rb") as fh:  # bounded, like a site.toml
            data = fh.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise ValueError(f"larger than {MAX_FILE_BYTES // 1024} KiB")
        doc = json.loads(data.decode("utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # also bad UTF-8, nesting, 4300+ digit ints
        msg = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)[:200]
        raise ConfigError(str(p), "<file>", f"cannot read JSON: {msg}") from None
    raw = doc.get("anchors") if isinstance(doc, dict) else None
    if not isinstance(raw, list) or not all(isinstance(a, list) and len(a) >= 2 for a in raw):
        raise ConfigError(str(p), "anchors", "must be a list of [x, y] positions")
    table = {"radio": dict(NEUTRAL_RADIO), "site": {"name": str(doc.get("name") or p.parent.name)},
             "anchors": [{"id": i, "x": a[0], "y": a[1]} for i, a in enumerate(raw)]}
    return parse_site(table, str(p))


@functools.lru_cache(maxsize=None)
def load_site_cached(path: str) -> Site:
    """A site file: ``site.toml`` (the contract) or a data folder's ``anchors.json``."""
    if str(path).endswith(".json"):
        return site_from_anchors_json(path)
    return load_site(path)


@functools.lru_cache(maxsize=64)
def trace_cached(path: str):
    tr = read_trace(path)
    if not tr.has_ground_truth:
        from pfdoa.errors import InputError

        raise InputError(f"{path}: evaluation needs ground truth columns gt_x,gt_y")
    return tr


@functools.lru_cache(maxsize=64)
def odometry_cached(path: str) -> OdometryTrace:
    return read_odometry(path)


def odometry_between(odo: OdometryTrace, times: np.ndarray) -> list[Odometry]:
    """Compose the odometry rows with t in (times[i-1], times[i]] for each observation i
    (rows up to times[0] for the first)."""
    from pfdoa.odometry import compose_all

    edges = np.searchsorted(odo.t, times, side="right")
    out, lo = [], 0
    for hi in edges.tolist():
        out.append(compose_all(Odometry(float(odo.dx[k]), float(odo.dy[k]), float(odo.dtheta[k])) for k in range(lo, hi)))
        lo = hi
    return out


def trace_sequences(ts: TraceSet, run: str, site: Site) -> list[Sequence]:
    """One run grouped into time windows (readings of one instant together), one sequence per
    beacon its readings name, in order of first reading (:func:`pfdoa.trace.by_beacon`; one
    for a run of one beacon), as ``pfdoa replay`` tracks each beacon alone. The run's odometry
    goes with the readings it belongs to (:func:`pfdoa.trace.odometry_part`: all of them, or
    those that name no beacon)."""
    _, trace_path, odo_path = ts.run(run)
    trace = trace_cached(trace_path)
    parts = by_beacon(trace)
    if odo_path:
        odometry_part(trace)  # InputError: several beacons, none of them the odometry's
    moving = parts[0][0] if len(parts) == 1 else ""  # the part the odometry belongs to
    out = []
    for beacon, part in parts:
        windows = list(group_by_window(part, site, ts.window_s))
        t = np.array([w.t for w in windows])
        rssi = np.array([w.rssi for w in windows]).reshape(len(windows), len(site.anchors))
        truth = np.array([w.gt if w.gt is not None else (np.nan, np.nan) for w in windows],
                         dtype=float).reshape(-1, 2)
        count = np.array([w.count for w in windows]).reshape(len(windows), len(site.anchors))
        odo = odometry_between(odometry_cached(odo_path), t) if odo_path and beacon == moving else None
        out.append(Sequence(f"{ts.name}/{run}" + (f"#{beacon}" if beacon else ""), site, t, rssi, truth, odo, count,
                            beacon))
    return out


def trace_sequence(ts: TraceSet, run: str, site: Site) -> Sequence:
    """:func:`trace_sequences` of a run of one beacon (ValueError for a run of several)."""
    (seq,) = trace_sequences(ts, run, site)
    return seq
