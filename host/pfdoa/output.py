"""Position output: one record per estimate, as JSON lines or CSV.

Fields, in this order (the CSV header is the same names)::

    t        seconds on the gateway's host clock (gateway: when the beacon event happened, from
             its reports' anchor ticks; replay: trace time)
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
    frame_id the frame x, y are in (ROS REP-105; default "map", docs/robot.md)
    stamp    seconds on the gateway's host clock when the estimate was made (the receive or
             timer time that completed its set; stamp - t is the gateway's latency)
    beacon   the beacon this estimate is about (the gateway: its [[beacons]] name, or
             "b<index>"); null in a replay of a trace
    heading  robot heading (rad, site frame, circular mean of the particles) when the
             estimator tracks one (the particle filters given odometry); null otherwise
    heading_var  its variance (rad^2, from the circular spread, at most pi^2/3); null without
             a heading
    room     the site's [[rooms]] entry whose polygon holds (x, y) on the estimated floor; null
             outside every room and for a site without rooms (pfdoa.rooms)
    room_p   the probability that the beacon is in that room: the share of the position's
             uncertainty (cov, else sigma) inside the polygon, times floor_p; null without a room
             or an uncertainty
    floor    the floor the beacon is on (a [[floors]] name: with anchors on several floors,
             estimated from which floor's anchors hear it best); null for a site without floors
    floor_p  its probability (1 when only one floor holds anchors); null without floors

In CSV, lists (ids, cov) are joined with ``;``, booleans are ``true``/``false`` and
unknown values are empty. JSON never contains NaN (it is written as null).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import sys
from dataclasses import dataclass
from typing import IO, Sequence

FIELDS = ("t", "x", "y", "sigma", "doa", "seq", "anchors", "missing", "stale", "rebooted", "r95", "cov", "lost",
          "frame_id", "stamp", "beacon", "heading", "heading_var", "room", "room_p", "floor", "floor_p")
DEFAULT_FRAME = "map"


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
    frame_id: str = DEFAULT_FRAME
    stamp: float | None = None
    beacon: str | None = None
    heading: float | None = None
    heading_var: float | None = None
    room: str | None = None
    room_p: float | None = None
    floor: str | None = None
    floor_p: float | None = None


def _num(v: float | None, digits: int) -> float | None:
    if v is None:
        return None
    v = float(v)
    return round(v, digits) if math.isfinite(v) else None


def record_values(r: Record) -> dict:
    """A record as the JSON output line has it (rounded; non-finite numbers None): every
    writer of estimates (JSON lines, CSV, the MQTT pose) takes its fields from here."""
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
        "frame_id": r.frame_id,
        "stamp": _num(r.stamp, 6),
        "beacon": r.beacon,
        "heading": _num(r.heading, 4),
        "heading_var": _num(r.heading_var, 6),
        "room": r.room,
        "room_p": _num(r.room_p, 4),
        "floor": r.floor,
        "floor_p": _num(r.floor_p, 4),
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
        v = record_values(r)
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
        if sys.stdout is None:  # started with standard output closed (`>&-`)
            raise InputError("--out -: standard output is closed; give --out FILE")
        return Writer(sys.stdout, fmt, flush_each)
    try:
        stream = open(path, "w", encoding="utf-8", newline="")
    except (OSError, ValueError) as exc:  # ValueError: a NUL in a path from a site file
        raise InputError(f"{path}: cannot write: {getattr(exc, 'strerror', None) or exc}") from None
    return Writer(stream, fmt, flush_each)


def write_atomic(path: str | os.PathLike, text: str, what: str = "") -> None:
    """Write a whole file so that readers (and a signal or a full disk in between) see the
    old file or the new one, never half of one: a temporary file beside it, flushed to
    disk, renamed over it (with the old file's permissions). Raises InputError naming
    ``what`` (the option) and the path."""
    from pfdoa.errors import InputError

    target = os.fspath(path)
    label = f"{what} {target}" if what else target
    tmp = os.path.join(os.path.dirname(target) or ".",
                       f".{os.path.basename(target)}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        if os.path.isdir(target):
            raise IsADirectoryError(21, "Is a directory")
        try:
            mode: int | None = os.stat(target).st_mode & 0o7777
        except FileNotFoundError:
            mode = None  # a new file: 0666 less the umask, as for open(path, "w")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        if mode is not None:
            os.fchmod(fd, mode)
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        raise InputError(f"{label}: cannot write: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise InputError(f"{label}: cannot write: {exc.strerror or exc}") from None


def write_stats(path: str, summary: dict) -> None:
    """Write a run's final counters as JSON (``--stats``; "-" is standard output); the file
    is replaced whole (:func:`write_atomic`); an unwritable path is an InputError."""
    from pfdoa.errors import InputError

    text = json.dumps(summary, indent=1) + "\n"
    if path == "-":
        if sys.stdout is None:
            raise InputError("--stats -: standard output is closed; give --stats FILE")
        try:
            sys.stdout.write(text)
            sys.stdout.flush()
        except (BrokenPipeError, ValueError):
            pass
        return
    write_atomic(path, text, "--stats")
