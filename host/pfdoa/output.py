"""Position output: one record per estimate, as JSON lines or CSV.

Fields, in this order (the CSV header is the same names)::

    t        seconds (gateway: Unix time of the set's last report; replay: trace time)
    x, y     metres, site frame
    sigma    1-sigma radial uncertainty (m); null/empty when the method has none
    doa      direction of arrival of the RSS gradient (rad, site frame); null when not computed
    seq      beacon sequence of the set; null in time-window mode
    anchors  anchor ids whose reports were used
    missing  configured anchors without a report in this set
    stale    anchors silent for longer than gateway.stale_after_s
    rebooted anchors whose reboot was detected since the previous set
    r95      radius (m) around (x, y) that holds the true position with 95 % probability
             according to the estimator; null when the method has none
    cov      position covariance [xx, xy, yy] (m^2) about (x, y); null when the method has none
    lost     true when the estimator's own evidence says it no longer explains the readings
             (the position is then a guess); null when the method does not judge
    heading  robot heading (rad, site frame, circular mean of the particles) when the
             estimator tracks one (the particle filters given odometry); null otherwise
    heading_var  its variance (rad^2, from the circular spread, at most pi^2/3); null without
             a heading

In CSV, lists (ids, cov) are joined with ``;``, booleans are ``true``/``false`` and
unknown values are empty. JSON never contains NaN (it is written as null).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from typing import IO, Sequence

FIELDS = ("t", "x", "y", "sigma", "doa", "seq", "anchors", "missing", "stale", "rebooted", "r95", "cov", "lost",
          "heading", "heading_var")


@dataclass
class Record:
    t: float
    x: float
    y: float
    sigma: float | None = None
    doa: float | None = None
    seq: int | None = None
    anchors: Sequence[int] = ()
    missing: Sequence[int] = ()
    stale: Sequence[int] = ()
    rebooted: Sequence[int] = ()
    r95: float | None = None
    cov: Sequence[float] | None = None
    lost: bool | None = None
    heading: float | None = None
    heading_var: float | None = None


def _num(v: float | None, digits: int) -> float | None:
    if v is None:
        return None
    v = float(v)
    return round(v, digits) if math.isfinite(v) else None


def _values(r: Record) -> dict:
    return {
        "t": _num(r.t, 6),
        "x": _num(r.x, 4),
        "y": _num(r.y, 4),
        "sigma": _num(r.sigma, 4),
        "doa": _num(r.doa, 4),
        "seq": r.seq,
        "anchors": [int(a) for a in r.anchors],
        "missing": [int(a) for a in r.missing],
        "stale": [int(a) for a in r.stale],
        "rebooted": [int(a) for a in r.rebooted],
        "r95": _num(r.r95, 4),
        "cov": _cov(r.cov),
        "lost": None if r.lost is None else bool(r.lost),
        "heading": _num(r.heading, 4),
        "heading_var": _num(r.heading_var, 6),
    }


def _cov(c: Sequence[float] | None) -> list[float] | None:
    if c is None:
        return None
    v = [_num(x, 6) for x in c]
    return None if any(x is None for x in v) else v


def _csv(x) -> str:
    if isinstance(x, list):
        return ";".join(repr(a) if isinstance(a, float) else str(a) for a in x)
    if isinstance(x, bool):
        return "true" if x else "false"
    return "" if x is None else repr(x) if isinstance(x, float) else str(x)


class Writer:
    """Writes records to a text stream; ``flush_each`` for live output read by other programs."""

    def __init__(self, stream: IO[str], fmt: str = "jsonl", flush_each: bool = False) -> None:
        if fmt not in ("jsonl", "csv"):
            raise ValueError(f"unknown output format {fmt!r}")
        self.stream = stream
        self.fmt = fmt
        self.flush_each = flush_each
        self.count = 0
        if fmt == "csv":
            stream.write(",".join(FIELDS) + "\n")

    def write(self, r: Record) -> None:
        v = _values(r)
        if self.fmt == "jsonl":
            line = json.dumps(v, separators=(",", ":"))
        else:
            line = ",".join(_csv(v[k]) for k in FIELDS)
        self.stream.write(line + "\n")
        self.count += 1
        if self.flush_each:
            self.stream.flush()

    def flush(self) -> None:
        try:
            self.stream.flush()
        except (BrokenPipeError, ValueError):
            pass

    def close(self) -> None:
        self.flush()
        if self.stream not in (sys.stdout, sys.stderr):
            self.stream.close()


def open_writer(path: str, fmt: str, flush_each: bool = False) -> Writer:
    """``path`` "-" is standard output. Raises InputError when the file cannot be created."""
    from pfdoa.errors import InputError

    if path == "-":
        return Writer(sys.stdout, fmt, flush_each)
    try:
        stream = open(path, "w", encoding="utf-8", newline="")
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return Writer(stream, fmt, flush_each)


def write_stats(path: str, summary: dict) -> None:
    """Write a run's final counters as JSON (``--stats``); an unwritable path is an InputError."""
    from pfdoa.errors import InputError

    try:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=1)
    except OSError as exc:
        raise InputError(f"--stats {path}: cannot write: {exc.strerror or exc}") from None
