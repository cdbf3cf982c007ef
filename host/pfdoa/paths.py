"""The paper's Dataset 0 paths in the site frame (metres), and arc-length resampling.

* :func:`paper_path` - the paper's paths (Boundary, Inside/Cross, Diagonal) in a square room
  with anchors at the corners (0,0), (0,s), (s,s), (s,0).
* :func:`resample_polyline` - points at equal arc length along a polyline.

The evaluation of the paper's simulated dataset and the simulator's scenarios both walk
these paths, so they live here (the simulator imports them; :mod:`pfdoa` never imports it).
"""

from __future__ import annotations

import numpy as np

# Vertices of the paper's Dataset 0 paths as fractions of the room side, read off the
# authors' simulation_datapoints_*.csv (60 x 60 m frame centred on the origin, mapped to
# [0, 1]). Each path is a list of separately drawn segments: the reference data jumps
# between them (the robot is teleported), and so do we.
_PAPER_SEGMENTS: dict[str, list[list[tuple[float, float]]]] = {
    # Clockwise along the walls, starting and ending at the middle of the top wall.
    "boundary": [[(0.5, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0), (0.0, 1.0), (0.5, 1.0)]],
    # Cross coverage: centre -> middle of the right wall, then top-middle -> centre.
    "inside": [[(0.5, 0.5), (1.0, 0.5)], [(0.5, 1.0), (0.5, 0.5)]],
    # Centre -> top-right corner, then top-middle -> right-middle.
    "diagonal": [[(0.5, 0.5), (1.0, 1.0)], [(0.5, 1.0), (1.0, 0.5)]],
}
PAPER_PATHS = tuple(_PAPER_SEGMENTS)
_ALIASES = {"cross": "inside", "diag": "diagonal", "boundry": "boundary"}


def resample_polyline(vertices: np.ndarray, step_m: float, include_end: bool = False) -> np.ndarray:
    """Points every ``step_m`` of arc length along a polyline (k, 2), starting at its first vertex."""
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 1:
        raise ValueError("vertices must have shape (k, 2), k >= 1")
    if step_m <= 0:
        raise ValueError("step_m must be positive")
    seg = np.hypot(*np.diff(v, axis=0).T) if len(v) > 1 else np.zeros(0)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    n = int(np.floor(total / step_m + 1e-9)) + 1
    s = np.arange(n) * step_m
    if not include_end and n > 1 and total - s[-1] < 1e-9:
        s = s[:-1]  # the end point belongs to whatever comes next (as in the reference data)
    elif include_end and total - s[-1] > 1e-9:
        s = np.append(s, total)
    x = np.interp(s, cum, v[:, 0])
    y = np.interp(s, cum, v[:, 1])
    return np.column_stack([x, y])


def paper_path(name: str, size_m: float = 6.0, step_m: float = 0.1, closed: bool = False) -> np.ndarray:
    """The paper's Dataset 0 path ``name`` ("boundary", "inside" or "diagonal"), shape (k, 2).

    Site frame: anchors at (0,0), (0,size), (size,size), (size,0); points every ``step_m``
    metres of arc length along each drawn segment (segment end points excluded, as in the
    reference data).

    ``closed``: a path a robot can drive: the drawn segments joined by straight legs and
    a leg back to the start, so repeating it never teleports (simulation scenarios).
    """
    key = _ALIASES.get(name.lower(), name.lower())
    if key not in _PAPER_SEGMENTS:
        raise ValueError(f"unknown paper path {name!r}; expected one of {', '.join(PAPER_PATHS)}")
    if size_m <= 0:
        raise ValueError("size_m must be positive")
    segs = _PAPER_SEGMENTS[key]
    if closed:
        joined = [v for seg in segs for v in seg]
        return resample_polyline(np.asarray(joined + [joined[0]]) * size_m, step_m)
    parts = [resample_polyline(np.asarray(seg) * size_m, step_m) for seg in segs]
    return np.concatenate(parts, axis=0)
