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
unknown values are empty; text (frame_id, beacon) is quoted by the csv module where it holds
a comma, a quote or a line break, and text a spreadsheet would run as a formula gets a
leading ``'`` (:func:`csv_text`). JSON never contains NaN (it is written as null).
"""

from __future__ import annotations

import csv
import json
import math
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
    if isinstance(x, str):
        return csv_text(x)
    return "" if x is None else repr(x) if isinstance(x, float) else str(x)


# A text field that a spreadsheet would run as a formula (OWASP "CSV injection"): these
# first characters start one in Excel, LibreOffice and Google Sheets.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_text(value: str) -> str:
    """A free-text CSV field (a beacon id: any bytes a BLE device or an MQTT client chose)
    made safe to open in a spreadsheet: one that starts like a formula, or with a quote,
    gets a leading ``'`` (the spreadsheets' own "this is text" mark, which they hide).
    :func:`csv_text_value` undoes it exactly, so every id reads back as it was; the csv
    module quotes commas, quotes and line breaks."""
    return "'" + value if value.startswith(FORMULA_START + ("'",)) else value


def csv_text_value(field: str) -> str:
    """The text :func:`csv_text` wrote."""
    return field[1:] if field.startswith("'") else field


class Writer:
    """Writes records to a text stream; ``flush_each`` for live output read by other programs.
    ``header``: the CSV header first (not when appending to a file that has one)."""

    def __init__(self, stream: IO[str], fmt: str = "jsonl", flush_each: bool = False, header: bool = True) -> None:
        if fmt not in ("jsonl", "csv"):
            raise ValueError(f"unknown output format {fmt!r}")
        self.stream = stream
        self.fmt = fmt
        self.flush_each = flush_each
        self.count = 0
        self._csv = csv.writer(stream, lineterminator="\n") if fmt == "csv" else None
        if self._csv is not None and header:
            self._csv.writerow(FIELDS)

    def write(self, r: Record) -> None:
        v = record_values(r)
        if self._csv is None:
            self.stream.write(json.dumps(v, separators=(",", ":")) + "\n")
        else:
            self._csv.writerow([_csv(v[k]) for k in FIELDS])
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


def open_writer(path: str, fmt: str, flush_each: bool = False, existing: str = "replace") -> Writer:
    """``path`` "-" is standard output; any other path is opened by
    :func:`pfdoa.outfiles.open_stream` (``existing``: "keep" appends to a file of the same
    format, the CSV header only into a new or empty one). Raises OutputError when it cannot
    be opened."""
    from pfdoa.errors import InputError
    from pfdoa.outfiles import open_stream

    if path == "-":
        if sys.stdout is None:  # started with standard output closed (`>&-`)
            raise InputError("--out -: standard output is closed; give --out FILE")
        return Writer(sys.stdout, fmt, flush_each)
    if fmt == "csv":
        def same_kind(first: bytes) -> bool:
            return first == ",".join(FIELDS).encode()
    else:
        def same_kind(first: bytes) -> bool:
            return first.startswith(b"{")
    stream, fresh = open_stream(path, "--out", existing=existing, same_kind=same_kind)
    return Writer(stream, fmt, flush_each, header=fresh)


def write_stats(path: str, summary: dict) -> None:
    """Write a run's final counters as JSON (``--stats``; "-" is standard output); a file
    is replaced whole (:func:`pfdoa.outfiles.write_whole`); a failure is an OutputError."""
    from pfdoa.outfiles import write_stdout, write_whole

    text = json.dumps(summary, indent=1) + "\n"
    if path == "-":
        try:
            write_stdout(text, "--stats -")
        except BrokenPipeError:
            pass
        return
    write_whole(path, text, "--stats")
