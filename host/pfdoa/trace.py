"""Readers for recorded traces and odometry, and time-window grouping into observations.

Trace format (CSV, header required, extra columns ignored, ``#`` comment lines and blank
lines skipped, ``.gz`` files read transparently)::

    t,anchor,rssi_dbm[,seq][,gt_x,gt_y][,beacon]

one row per reading: ``t`` seconds, ``anchor`` the integer anchor id of the site file,
``rssi_dbm`` the reading. ``gt_x``/``gt_y`` (ground truth, metres) come as a pair; an empty
ground-truth field means "unknown" (NaN). ``beacon`` (optional) is the id of the beacon
the reading names (an ESPresense device id as ``pfdoa gateway --readings-out`` writes it,
CSV-quoted when needed, and with a leading ``'`` when it starts like a spreadsheet formula
or with a ``'``, which the reader removes: pfdoa.output.csv_text; at most 128 characters);
an empty field means none (a reading of
the site's one beacon). With it, ``pfdoa replay`` tracks every beacon with its own
estimator, as the gateway does.

Odometry format::

    t,dx,dy,dtheta

increments in the robot frame since the previous row (metres, radians).

Files are parsed row by row into compact ``array`` buffers that become the numpy columns
without a copy (40 bytes per trace row with ground truth, 24 without; 32 per odometry row),
so a file's memory cost is bounded by its row count, never by line length: a line longer
than ``MAX_LINE_CHARS`` is rejected, and so is a file of more than ``MAX_ROWS`` rows (at most
~1 GB of columns, however well a ``.gz`` compresses).
Every problem is an :class:`~pfdoa.errors.InputError` naming ``file:line``.
"""

from __future__ import annotations

import csv
import gzip
import io
import logging
import math
import zlib
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pfdoa.errors import InputError
from pfdoa.output import csv_text_value

log = logging.getLogger(__name__)

MAX_LINE_CHARS = 4096
# Rows of one trace or odometry file: 12 anchors reporting 40 times a second for 11 hours.
MAX_ROWS = 20_000_000
# Plausible received power; anything outside is a unit or parsing mistake, not a reading.
RSSI_MIN_DBM = -200.0
RSSI_MAX_DBM = 50.0

TRACE_REQUIRED = ("t", "anchor", "rssi_dbm")
MAX_BEACON_ID = 128  # characters of a beacon id (the gateway's tracker has the same bound)
ODOM_REQUIRED = ("t", "dx", "dy", "dtheta")


@dataclass
class Trace:
    """Readings in file order (stable-sorted by ``t`` if the file was not)."""

    t: np.ndarray  # float64 seconds
    anchor: np.ndarray  # int64 anchor id
    rssi_dbm: np.ndarray  # float64
    seq: np.ndarray | None = None  # int64, if the file has a seq column
    gt_x: np.ndarray | None = None  # float64 metres (NaN = unknown), if the file has ground truth
    gt_y: np.ndarray | None = None
    source: str = ""
    beacon: np.ndarray | None = None  # object (str; "" = none), if the file has a beacon column

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def has_ground_truth(self) -> bool:
        return self.gt_x is not None

    def select(self, mask: np.ndarray) -> "Trace":
        """A new trace with the rows where ``mask`` is true."""
        pick = lambda a: None if a is None else a[mask]  # noqa: E731
        return Trace(self.t[mask], self.anchor[mask], self.rssi_dbm[mask], pick(self.seq),
                     pick(self.gt_x), pick(self.gt_y), self.source, pick(self.beacon))


def by_beacon(trace: Trace) -> list[tuple[str, Trace]]:
    """The trace's readings per beacon they name, in order of first reading (``""``: the
    readings that name none, the site's one beacon). A trace that names at most one beacon is
    one part, the trace itself (no copy): what uses the parts gives it what it gave before."""
    if trace.beacon is None or len(trace) == 0:
        return [("", trace)]
    names, first, inverse = np.unique(trace.beacon.astype(str), return_index=True, return_inverse=True)
    if names.size == 1:
        return [(str(names[0]), trace)]
    return [(str(names[k]), trace.select(inverse == k)) for k in np.argsort(first, kind="stable")]


def describe_beacons(parts: list[tuple[str, Trace]], most: int = 4) -> str:
    """``"2 beacons (a, b)"``: for messages (the readings without a name are "(none)")."""
    names = [n or "(none)" for n, _ in parts]
    return f"{len(names)} beacons ({', '.join(names[:most])}{', ...' if len(names) > most else ''})"


def odometry_part(trace: Trace) -> Trace:
    """The readings a trace's odometry belongs to: all of them when it names at most one
    beacon, else those that name none (the robot's own beacon, as ``pfdoa replay`` gives its
    odometry to them). InputError when every reading names a beacon of several."""
    parts = by_beacon(trace)
    if len(parts) == 1:
        return parts[0][1]
    for name, part in parts:
        if name == "":
            return part
    raise InputError(f"{trace.source or 'trace'}: names {describe_beacons(parts)} and its odometry belongs to the "
                     "readings with no beacon name, of which it has none (give the robot's beacon's readings an "
                     "empty beacon field, or leave the odometry out)")


class OdometryTrace(NamedTuple):
    """Odometry increments; unpacks as ``t, dx, dy, dtheta = read_odometry(path)``."""

    t: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    dtheta: np.ndarray


def _open_text(path: Path) -> io.TextIOBase:
    try:
        if path.suffix == ".gz":
            return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", newline="")
        return open(path, encoding="utf-8", newline="")
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None


def _rows(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of the non-blank, non-comment lines, with bounded line length."""
    with _open_text(path) as fh:
        lineno = rows = 0
        try:
            while True:
                line = fh.readline(MAX_LINE_CHARS + 1)
                if not line:
                    return
                lineno += 1
                if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
                    raise InputError(f"{path}:{lineno}: line longer than {MAX_LINE_CHARS} characters")
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                rows += 1
                if rows > MAX_ROWS + 1:  # the header and MAX_ROWS rows
                    raise InputError(f"{path}:{lineno}: more than {MAX_ROWS:,} rows; split the recording")
                yield lineno, next(csv.reader([s]))
        except UnicodeDecodeError:
            raise InputError(f"{path}:{lineno + 1}: not UTF-8 text") from None
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(f"{path}: cannot read: {exc}") from None
        except csv.Error as exc:
            raise InputError(f"{path}:{lineno}: {exc}") from None


def _header(path: Path, rows: Iterator[tuple[int, list[str]]], required: tuple[str, ...]) -> dict[str, int]:
    try:
        lineno, names = next(rows)
    except StopIteration:
        raise InputError(f"{path}: empty file (expected a header with {','.join(required)})") from None
    cols: dict[str, int] = {}
    for i, n in enumerate(names):
        name = n.strip().lstrip("\ufeff")
        if name in cols and name:  # the last one would silently win
            raise InputError(f"{path}:{lineno}: header names column {name!r} twice "
                             f"(fields {cols[name] + 1} and {i + 1})")
        cols[name] = i
    missing = [c for c in required if c not in cols]
    if missing:
        raise InputError(
            f"{path}:{lineno}: header lacks column(s) {', '.join(missing)} "
            f"(need {','.join(required)}; got {','.join(names)})"
        )
    return cols


def _float(path: Path, lineno: int, name: str, text: str, allow_empty: bool = False) -> float:
    text = text.strip()
    if allow_empty and text == "":
        return math.nan
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"{path}:{lineno}: column {name}: not a number: {text!r}") from None
    if not math.isfinite(v) and not (allow_empty and math.isnan(v)):
        raise InputError(f"{path}:{lineno}: column {name}: not a finite number: {text!r}")
    return v


def _int(path: Path, lineno: int, name: str, text: str) -> int:
    text = text.strip()
    try:
        v = int(text)
    except ValueError:
        try:  # "3.0" written by float-minded tools
            f = float(text)
        except ValueError:
            raise InputError(f"{path}:{lineno}: column {name}: not an integer: {text!r}") from None
        if not math.isfinite(f) or f != int(f):
            raise InputError(f"{path}:{lineno}: column {name}: not an integer: {text!r}")
        v = int(f)
    if not -(2**63) <= v < 2**63:  # the column is int64 (fuzz/regressions/trace)
        raise InputError(f"{path}:{lineno}: column {name}: integer out of range: {text[:40]!r}")
    return v


def _column(buf: array, dtype) -> np.ndarray:
    """A writable numpy view of an ``array`` buffer (no copy; the array stays alive with it)."""
    return np.frombuffer(buf, dtype=dtype) if len(buf) else np.zeros(0, dtype=dtype)


def _sort_by_time(t: np.ndarray, path: Path) -> np.ndarray | None:
    """Stable order by time if the file is not already in time order (else None)."""
    if t.size < 2 or bool(np.all(np.diff(t) >= 0.0)):
        return None
    log.warning("%s: rows are not in time order; sorting them by t (stable)", path)
    return np.argsort(t, kind="stable")


def _position(path: Path, lineno: int, name: str, text: str) -> float:
    """A ground-truth coordinate (empty: unknown), within a site's +-MAX_COORDINATE_M."""
    from pfdoa.site import MAX_COORDINATE_M

    v = _float(path, lineno, name, text, allow_empty=True)
    if abs(v) > MAX_COORDINATE_M:
        raise InputError(f"{path}:{lineno}: column {name}: {v:g} m is beyond +-{MAX_COORDINATE_M:g} m: not a "
                         "position in a site")
    return v


def read_trace(path: str | Path) -> Trace:
    """Read a trace CSV (see the module doc). Raises :class:`InputError` on any bad row."""
    p = Path(path)
    rows = _rows(p)
    cols = _header(p, rows, TRACE_REQUIRED)
    has_gt = "gt_x" in cols or "gt_y" in cols
    if has_gt and not ("gt_x" in cols and "gt_y" in cols):
        raise InputError(f"{p}:1: header has only one of gt_x, gt_y (need both or neither)")
    has_seq = "seq" in cols
    ib = cols.get("beacon")
    it, ia, ir = cols["t"], cols["anchor"], cols["rssi_dbm"]
    ncols = 1 + max(cols[c] for c in cols if c in ("t", "anchor", "rssi_dbm", "seq", "gt_x", "gt_y", "beacon"))
    t, anchor, rssi = array("d"), array("q"), array("d")
    seq, gx, gy = array("q"), array("d"), array("d")
    beacons: list[str] = []
    names: dict[str, str] = {}  # one string object per beacon id, however many rows name it
    for lineno, f in rows:
        if len(f) < ncols:
            raise InputError(f"{p}:{lineno}: expected at least {ncols} fields, got {len(f)}")
        t.append(_float(p, lineno, "t", f[it]))
        anchor.append(_int(p, lineno, "anchor", f[ia]))
        r = _float(p, lineno, "rssi_dbm", f[ir])
        if not RSSI_MIN_DBM <= r <= RSSI_MAX_DBM:
            raise InputError(f"{p}:{lineno}: column rssi_dbm: {r} dBm is outside [{RSSI_MIN_DBM:g}, {RSSI_MAX_DBM:g}]")
        rssi.append(r)
        if has_seq:
            seq.append(_int(p, lineno, "seq", f[cols["seq"]]))
        if has_gt:
            gx.append(_position(p, lineno, "gt_x", f[cols["gt_x"]]))
            gy.append(_position(p, lineno, "gt_y", f[cols["gt_y"]]))
        if ib is not None:
            b = csv_text_value(f[ib])  # a formula-looking id was written with a leading ' (pfdoa.output)
            if len(b) > MAX_BEACON_ID:
                raise InputError(f"{p}:{lineno}: column beacon: an id longer than {MAX_BEACON_ID} characters")
            beacons.append(names.setdefault(b, b))
    if not t:
        raise InputError(f"{p}: no readings after the header")
    tr = Trace(
        t=_column(t, np.float64),
        anchor=_column(anchor, np.int64),
        rssi_dbm=_column(rssi, np.float64),
        seq=_column(seq, np.int64) if has_seq else None,
        gt_x=_column(gx, np.float64) if has_gt else None,
        gt_y=_column(gy, np.float64) if has_gt else None,
        source=str(p),
        beacon=np.array(beacons, dtype=object) if ib is not None else None,
    )
    order = _sort_by_time(tr.t, p)
    return tr if order is None else tr.select(order)


def read_odometry(path: str | Path) -> OdometryTrace:
    """Read an odometry CSV ``t,dx,dy,dtheta``. Raises :class:`InputError` on any bad row."""
    p = Path(path)
    rows = _rows(p)
    cols = _header(p, rows, ODOM_REQUIRED)
    idx = [cols[c] for c in ODOM_REQUIRED]
    ncols = 1 + max(idx)
    bufs = [array("d") for _ in ODOM_REQUIRED]
    for lineno, f in rows:
        if len(f) < ncols:
            raise InputError(f"{p}:{lineno}: expected at least {ncols} fields, got {len(f)}")
        for name, i, buf in zip(ODOM_REQUIRED, idx, bufs):
            buf.append(_float(p, lineno, name, f[i]))
    if not bufs[0]:
        raise InputError(f"{p}: no increments after the header")
    arrays = [_column(b, np.float64) for b in bufs]
    order = _sort_by_time(arrays[0], p)
    if order is not None:
        arrays = [a[order] for a in arrays]
    return OdometryTrace(*arrays)


# -- checks a user can act on (the commands call them; warnings, or InputError) ---------------
# A reading every this many seconds or more between distinct times is not an RSSI trace in
# seconds; milliseconds are the usual mistake.
UNITS_STEP_S = 50.0
UNIX_MS = 1e11  # Unix time in milliseconds is beyond this (Unix seconds are ~1.7e9)


def time_unit_warnings(t: np.ndarray, source: str, anchor: np.ndarray | None = None) -> list[str]:
    """What looks wrong with a trace's (``anchor`` given) or odometry file's ``t`` column,
    as sentences: milliseconds for seconds, or times truncated to whole seconds."""
    if t.size < 2:
        return []
    out = []
    distinct = np.unique(t)
    if float(t.max()) > UNIX_MS:
        out.append(f"{source}: t reaches {float(t.max()):.0f}: that is milliseconds (or finer) since 1970, "
                   "not seconds (t must be seconds)")
    elif distinct.size >= 10 and float(np.median(np.diff(distinct))) >= UNITS_STEP_S:
        out.append(f"{source}: successive times are a median {float(np.median(np.diff(distinct))):g} apart: "
                   "are they milliseconds? (t must be seconds)")
    elif anchor is not None and bool(np.all(t == np.floor(t))):
        # Distinct (t, anchor) pairs: adjacent changes in (t, anchor) order (np.unique over
        # stacked columns would take several copies of a long trace).
        order = np.lexsort((anchor, t))
        ts, an = t[order], anchor[order]
        pairs = 1 + int(np.count_nonzero((ts[1:] != ts[:-1]) | (an[1:] != an[:-1])))
        if t.size >= 2 * pairs:
            out.append(f"{source}: every t is a whole number and each anchor has {t.size / pairs:.0f} readings "
                       "per time on average: were the times truncated to whole seconds? (one anchor's "
                       "readings in one window are combined into one value)")
    return out


def check_anchor_ids(trace: Trace, anchor_ids, site_source: str) -> dict[int, int]:
    """Readings per anchor id the site does not know ({} when all are known). No reading
    from a site anchor at all is an InputError (nothing could be estimated: usually the
    wrong site file, or ids numbered from another base); some unknown ids are warned about."""
    known = np.isin(trace.anchor, np.asarray(tuple(anchor_ids), dtype=np.int64))
    if bool(known.all()):
        return {}
    ids, counts = np.unique(trace.anchor[~known], return_counts=True)
    unknown = {int(a): int(n) for a, n in zip(ids, counts)}
    listed = ", ".join(str(a) for a in list(unknown)[:12]) + (", ..." if len(unknown) > 12 else "")
    site_ids = ", ".join(str(a) for a in anchor_ids)
    if not bool(known.any()):
        raise InputError(f"{trace.source}: no reading is from an anchor of {site_source} (trace anchor ids "
                         f"{listed}; site ids {site_ids})")
    log.warning("%s: %d of %d readings are from anchor id(s) %s, not in %s (ids %s); they are skipped",
                trace.source, int((~known).sum()), len(trace), listed, site_source, site_ids)
    return unknown


def odometry_overlap_warning(odom_t: np.ndarray, trace_t: np.ndarray, source: str) -> str | None:
    """A sentence when the odometry's time span never meets the trace's (another clock)."""
    if odom_t.size == 0 or trace_t.size == 0:
        return None
    lo, hi = float(odom_t.min()), float(odom_t.max())
    tlo, thi = float(trace_t.min()), float(trace_t.max())
    if hi < tlo or lo > thi:
        return (f"{source}: odometry t {lo:.3f}..{hi:.3f} never overlaps the trace's t {tlo:.3f}..{thi:.3f}: "
                "it cannot be used (odometry t must be on the trace's clock)")
    return None


# Time windows (replay here, live in pfdoa.readings.reassembly.WindowGrouper: one rule).
# A window spans ``window_s`` from its first reading; a reading within this share of
# ``window_s`` before the end already opens the next window, so periodic reporters whose
# timestamps jitter by a few ms (1.000 +- 0.002 s at 1 Hz) give one window per period.
WINDOW_JITTER = 0.05
# Readings of one anchor combined into one window at most; later ones are counted, not kept
# (bounds memory whatever the rate: 256 x 8 bytes per configured anchor).
MAX_READINGS_PER_WINDOW = 256


def window_closed(open_t: float, t: float, window_s: float) -> bool:
    """Does a reading (or a clock) at ``t`` fall after the window opened at ``open_t``?"""
    return t - open_t >= window_s * (1.0 - WINDOW_JITTER)


def combine_db(values: list[float]) -> float:
    """The robust average of one anchor's readings in a window: their median in dB
    (a multipath dip or a body-shadowed reading among them does not drag it)."""
    if len(values) == 1:
        return values[0]
    return float(np.median(values))


class Window(NamedTuple):
    """One observation: its time (a window's: its last reading's; a gateway set's, from
    :func:`pfdoa.calibration.calibrate.gateway_sets`: the set's), RSSI in site order (NaN = missing),
    ground truth, and how many readings each anchor's value combines (0 = missing)."""

    t: float
    rssi: np.ndarray
    gt: tuple[float, float] | None
    count: np.ndarray | None = None


@dataclass
class GroupingCounts:
    """What :func:`group_by_window` skipped or merged (filled while iterating)."""

    windows: int = 0
    readings_used: int = 0
    unknown_anchor_readings: int = 0
    unknown_anchors: set[int] = field(default_factory=set)
    combined_readings: int = 0  # readings merged with an earlier one of the same anchor and window
    dropped_readings: int = 0  # beyond MAX_READINGS_PER_WINDOW for one anchor in one window


DEFAULT_WINDOW_S = 1.0
MAX_REPORTING_WINDOW_S = 10.0  # a slower reporter is not localised by windows of its readings


def reporting_window(traces: list[Trace]) -> float:
    """The time window for ``traces`` when none is given: 1 s, or the anchors' typical
    reporting interval when that is longer (the median over anchors, and beacons, of each one's
    median interval between readings at distinct times; rounded to 0.1 s, at most
    MAX_REPORTING_WINDOW_S). A window shorter than the interval holds only some of the anchors
    (an anchor reporting every 3 s is in one 1 s window of three), so each estimate sees few of
    them; a longer one gives every window each anchor's reading."""
    intervals = []
    for tr in traces:
        keys = tr.anchor if tr.beacon is None else np.array([f"{b}|{a}" for b, a in zip(tr.beacon, tr.anchor)])
        order = np.argsort(keys, kind="stable")
        k, t = keys[order], tr.t[order]
        bounds = np.flatnonzero(k[1:] != k[:-1]) + 1
        for part in np.split(t, bounds):
            times = np.unique(part)
            if times.size >= 3:
                intervals.append(float(np.median(np.diff(times))))
    if not intervals:
        return DEFAULT_WINDOW_S
    typical = float(np.median(intervals))
    return float(min(max(DEFAULT_WINDOW_S, round(typical, 1)), MAX_REPORTING_WINDOW_S))


def ground_truth_at(trace: Trace, k: int) -> tuple[float, float] | None:
    """The ground truth of reading ``k`` (None when the trace has none there)."""
    if trace.gt_x is None or trace.gt_y is None:
        return None
    x, y = float(trace.gt_x[k]), float(trace.gt_y[k])
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None


def group_by_window(
    trace: Trace, site, window_s: float = DEFAULT_WINDOW_S, counts: GroupingCounts | None = None
) -> Iterator[Window]:
    """Group readings into synchronized anchor sets by time (offline evaluation and replay).

    A window opens at the first reading after the previous window and takes every reading
    until ``window_s`` has passed (see :func:`window_closed`), so readings sharing ``t``
    always belong together and the window closes on time whatever the reporting rate.
    Repeated readings of one anchor in a window are combined (:func:`combine_db`) and
    their number is the window's ``count``. Each non-empty window yields one observation
    stamped with the time of its last reading, with the ground truth of that reading (None
    if the trace has none). Readings from anchors not in the site are counted in
    ``counts`` and skipped, not logged: the commands warn once per file when they load it
    (:func:`check_anchor_ids`), and an evaluation groups one run once per calibration.
    """
    if not window_s > 0.0:
        raise InputError(f"window must be > 0 s, got {window_s}")
    counts = counts if counts is not None else GroupingCounts()
    index = {aid: i for i, aid in enumerate(site.anchor_ids)}
    n_anchors = len(index)
    t, anchor, rssi = trace.t.tolist(), trace.anchor.tolist(), trace.rssi_dbm.tolist()

    values: list[list[float]] = [[] for _ in range(n_anchors)]
    open_t: float | None = None
    last = -1  # the newest reading taken (set before any window is emitted)

    def emit() -> Window:
        vec = np.full(n_anchors, np.nan)
        cnt = np.zeros(n_anchors, dtype=np.int64)
        for j, v in enumerate(values):
            if v:
                vec[j] = combine_db(v)
                cnt[j] = len(v)
                v.clear()
        counts.windows += 1
        return Window(t[last], vec, ground_truth_at(trace, last), cnt)

    for k in range(len(t)):
        j = index.get(int(anchor[k]))
        if j is None:
            counts.unknown_anchor_readings += 1
            counts.unknown_anchors.add(int(anchor[k]))
            continue
        if open_t is not None and window_closed(open_t, t[k], window_s):
            yield emit()
            open_t = None
        if open_t is None:
            open_t = t[k]
        v = values[j]
        if len(v) >= MAX_READINGS_PER_WINDOW:
            counts.dropped_readings += 1
        else:
            if v:
                counts.combined_readings += 1
            v.append(rssi[k])
            counts.readings_used += 1
        last = k
    if open_t is not None:
        yield emit()
