"""Robot trajectories in the site frame (metres).

* the paper's Dataset 0 paths are :func:`pfdoa.paths.paper_path` (evaluation shares them).
* :func:`random_waypoints` - straight legs between uniformly drawn waypoints.
* :func:`walking_track` - a person-like walk through waypoints: bounded speed and turn
  rate, speed wobble, short pauses.

All return positions sampled at equal arc length (``step_m``) or, for the timed tracks,
at a fixed rate; :func:`timed` turns a path into (t, x, y, heading).
"""

from __future__ import annotations

import numpy as np

from pfdoa.paths import resample_polyline


def random_waypoints(
    n: int,
    bounds: tuple[float, float, float, float],
    rng: np.random.Generator | int | None = None,
    margin_m: float = 0.0,
    min_leg_m: float = 0.0,
) -> np.ndarray:
    """``n`` waypoints drawn uniformly in ``bounds`` = (xmin, ymin, xmax, ymax) shrunk by ``margin_m``.

    Consecutive waypoints are at least ``min_leg_m`` apart (redrawn otherwise, bounded tries).
    """
    rng = np.random.default_rng(rng)
    xmin, ymin, xmax, ymax = bounds
    lo = np.array([xmin + margin_m, ymin + margin_m])
    hi = np.array([xmax - margin_m, ymax - margin_m])
    if np.any(hi < lo):
        raise ValueError("margin leaves no room inside bounds")
    pts = [rng.uniform(lo, hi)]
    while len(pts) < n:
        for _ in range(100):
            p = rng.uniform(lo, hi)
            if np.hypot(*(p - pts[-1])) >= min_leg_m:
                break
        pts.append(p)
    return np.array(pts[:n], dtype=float)


def waypoint_path(waypoints: np.ndarray, step_m: float = 0.1) -> np.ndarray:
    """Straight legs through ``waypoints`` sampled every ``step_m`` (end point included)."""
    return resample_polyline(waypoints, step_m, include_end=True)


def timed(path: np.ndarray, speed_mps: float, rate_hz: float) -> np.ndarray:
    """Walk a polyline at constant speed, sampled at ``rate_hz``: rows (t, x, y, heading)."""
    pts = resample_polyline(path, speed_mps / rate_hz, include_end=True)
    return stamp(pts, rate_hz)


def stamp(pts: np.ndarray, rate_hz: float) -> np.ndarray:
    """Points (k, 2) visited one per 1/rate_hz seconds -> rows (t, x, y, heading)."""
    t = np.arange(len(pts)) / rate_hz
    d = np.diff(pts, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0]) if len(d) else np.zeros(0)
    moving = np.hypot(d[:, 0], d[:, 1]) > 1e-9 if len(d) else np.zeros(0, bool)
    # Standing still keeps the previous heading.
    h = np.zeros(len(pts))
    last = float(heading[moving][0]) if np.any(moving) else 0.0
    for i in range(len(d)):
        if moving[i]:
            last = float(heading[i])
        h[i] = last
    if len(pts) > 1:
        h[-1] = h[-2]
    return np.column_stack([t, pts, h])


def walking_track(
    waypoints: np.ndarray,
    rate_hz: float = 10.0,
    speed_mps: float = 1.0,
    max_turn_rate: float = np.deg2rad(120.0),
    speed_jitter: float = 0.15,
    pause_prob: float = 0.0,
    pause_s: float = 2.0,
    rng: np.random.Generator | int | None = None,
    arrive_m: float = 0.2,
    max_duration_s: float = 3600.0,
) -> np.ndarray:
    """A walker steering through ``waypoints`` (unicycle with bounded turn rate).

    Speed wobbles around ``speed_mps`` (relative std ``speed_jitter``, low-pass filtered);
    at each reached waypoint the walker pauses for ``pause_s`` with probability
    ``pause_prob``. Returns rows (t, x, y, heading) at ``rate_hz``.
    """
    rng = np.random.default_rng(rng)
    wp = np.asarray(waypoints, dtype=float)
    if len(wp) < 2:
        raise ValueError("need at least two waypoints")
    dt = 1.0 / rate_hz
    pos = wp[0].copy()
    heading = float(np.arctan2(*(wp[1] - wp[0])[::-1]))
    wobble = 0.0
    alpha = min(1.0, dt / 1.5)  # speed wobble correlation time ~1.5 s
    rows = [(pos[0], pos[1], heading)]
    target = 1
    pause_left = 0
    max_steps = int(max_duration_s * rate_hz)
    while target < len(wp) and len(rows) < max_steps:
        if pause_left > 0:
            pause_left -= 1
            rows.append((pos[0], pos[1], heading))
            continue
        to = wp[target] - pos
        dist = float(np.hypot(*to))
        if dist < arrive_m:
            target += 1
            if pause_prob > 0 and rng.random() < pause_prob:
                pause_left = int(round(pause_s * rate_hz))
            continue
        want = float(np.arctan2(to[1], to[0]))
        err = (want - heading + np.pi) % (2 * np.pi) - np.pi
        heading += float(np.clip(err, -max_turn_rate * dt, max_turn_rate * dt))
        wobble += alpha * (rng.normal(0.0, speed_jitter) - wobble)
        # Slow down in sharp turns and when arriving, as people do.
        v = speed_mps * max(0.2, 1.0 + wobble) * max(0.3, np.cos(err)) * min(1.0, dist / 0.5 + 0.3)
        pos = pos + v * dt * np.array([np.cos(heading), np.sin(heading)])
        rows.append((pos[0], pos[1], heading))
    arr = np.array(rows, dtype=float)
    t = np.arange(len(arr)) * dt
    return np.column_stack([t, arr])
