"""Inputs for the hostile-input tests (tests/*/test_hostile_*.py; not a test module).

A 6 x 6 m site with anchors 1..4 at the corners and traces of a beacon walking through it,
noise-free from the site's own radio model, so every estimate is deterministic.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

ANCHORS = {1: (0.0, 0.0), 2: (0.0, 6.0), 3: (6.0, 6.0), 4: (6.0, 0.0)}
A1M, N = -45.0, 2.5
SITE = (f"[radio]\nrssi_at_1m_dbm = {A1M}\npath_loss_exponent = {N}\n" + "".join(
    f"\n[[anchors]]\nid = {a}\nx = {x}\ny = {y}\n" for a, (x, y) in ANCHORS.items())
    + "\n[gateway]\nset_timeout_s = 0.3\nstale_after_s = 2.0\n")


def position(k: int) -> tuple[float, float]:
    return 3.0 + 2.0 * math.cos(0.01 * k), 3.0 + 2.0 * math.sin(0.01 * k)


def rssi(a: int, p: tuple[float, float]) -> float:
    x, y = ANCHORS[a]
    d = max(math.hypot(p[0] - x, p[1] - y), 0.1)
    return round(A1M - 10 * N * math.log10(d), 2)


def trace_rows(n: int, dt: float = 0.1, per_anchor: int = 1, seq: bool = True, t_scale: float = 1.0,
               ids=tuple(ANCHORS)) -> list[str]:
    """CSV lines (header first): ``n`` beacons ``dt`` apart, ``per_anchor`` readings each."""
    head = "t,anchor,rssi_dbm,gt_x,gt_y" + (",seq" if seq else "")
    rows = [head]
    for k in range(n):
        p = position(k)
        for j in range(per_anchor):
            t = (k * dt + j * dt / (per_anchor + 1)) * t_scale
            for a, aid in zip(ANCHORS, ids):
                rows.append(f"{t:.6g},{aid},{rssi(a, p)},{p[0]:.4f},{p[1]:.4f}" + (f",{k}" if seq else ""))
    return rows


def write_trace(path: Path, n: int, **kw) -> Path:
    path.write_text("\n".join(trace_rows(n, **kw)) + "\n")
    return path


def write_site(path: Path, extra: str = "") -> Path:
    path.write_text(SITE + extra)
    return path


def write_odometry(path: Path, n: int, dt: float = 0.1, t0: float = 0.0) -> Path:
    path.write_text("t,dx,dy,dtheta\n" + "".join(f"{t0 + k * dt:.6f},0.02,0,0.01\n" for k in range(n)))
    return path


def report_lines(k: int, t: float, source=lambda a: f"serial{a}") -> list[str]:
    """Capture lines of beacon ``k`` heard by every anchor at time ``t`` (our frames, one
    byte-stream source per anchor), then the gateway's timers."""
    from pfdoa.protocol.messages import RssiReport
    from pfdoa.protocol.uart import encode_uart

    p = position(k)
    out = []
    for a in ANCHORS:
        q8 = int(round(rssi(a, p) * 256))
        frame = encode_uart(RssiReport(k, 1000 + 100 * k, q8, int(round(q8 / 256)), 1, 37, 0), a)
        out.append(f"({t + 0.001 * a:.6f}) {source(a)} S {frame.hex()}")
    return out + [f"({t + 0.01:.6f}) - T"]


def write_capture_lines(path: Path, lines: list[str]) -> Path:
    path.write_text("# pfdoa capture v2\n" + "".join(ln + "\n" for ln in lines))
    return path


def write_capture(path: Path, n: int, dt: float = 0.1) -> Path:
    """A v2 capture of ``n`` beacons ``dt`` apart (``pfdoa gateway --replay-capture``)."""
    return write_capture_lines(path, [ln for k in range(n) for ln in report_lines(k, dt * k)])


def final_counters(stderr: str) -> dict:
    lines = [ln for ln in stderr.splitlines() if ln.startswith("pfdoa: final ")]
    assert len(lines) == 1, stderr[-3000:]
    return json.loads(lines[0][len("pfdoa: final "):])


def error_line(stderr: str) -> str:
    """The one error line a bad input must give (and nothing like a traceback)."""
    assert "Traceback" not in stderr, stderr[-3000:]
    errors = [ln for ln in stderr.splitlines() if ln.startswith("pfdoa: error: ")]
    assert len(errors) == 1, stderr[-3000:]
    return errors[0]
