"""The reassembled readings of a live run as a trace (``--readings-out trace.csv``).

The file is the trace format that ``pfdoa replay``, ``calibrate`` and ``eval`` read
(:func:`pfdoa.trace.read_trace`)::

    t,anchor,rssi_dbm[,seq][,gt_x,gt_y][,beacon]

``t`` is the reading's receive time as the gateway used it (Unix s; with ESPresense
message time, the message's time), written with ``repr`` so it reads back to the same
float; ``seq`` the beacon sequence (0..65535); ``beacon`` the id of the beacon a reading
names (ESPresense devices; CSV-quoted when it holds a comma, a quote or edge spaces).
Ground truth is never invented: the ``gt_x,gt_y`` columns exist only when the caller
gives a ground-truth source (a simulator, a tracking system; ``--ground-truth FILE``:
:class:`GroundTruthFile`), and a reading it has no position for gets empty fields (read
back as unknown). With them the file is what ``pfdoa calibrate`` and ``pfdoa eval`` need.

The ``seq`` and ``beacon`` columns are decided by the first reading (live anchors always
send a sequence; ESPresense readings never do, and always name their beacon). A later
reading that does not fit the file (no sequence in a file with a seq column; a named
beacon's in a file without a beacon column; a beacon id with a control character, which
one CSV line cannot hold) is counted in ``skipped``; a reading of our frames in a file
with a beacon column gets an empty one (read back as no beacon).
"""

from __future__ import annotations

import csv
import logging
import math
import sys
from typing import IO, Callable

import numpy as np

from pfdoa.errors import InputError
from pfdoa.sinks.base import Sink, open_text_target

log = logging.getLogger(__name__)

GroundTruth = Callable[[float], "tuple[float, float] | None"]


def _f(v: float) -> str:
    return repr(float(v))


def _beacon_field(beacon: str) -> str | None:
    """``beacon`` as one CSV field of one line (None: it cannot be, it holds a control character)."""
    if any(ord(c) < 0x20 or c == "\x7f" for c in beacon):
        return None
    if "," in beacon or '"' in beacon or beacon != beacon.strip():
        return '"' + beacon.replace('"', '""') + '"'
    return beacon


class ReadingsCsvSink(Sink):
    name = "readings"

    def __init__(self, target: str | IO[str], ground_truth: GroundTruth | None = None,
                 flush_each: bool = True) -> None:
        self.stream = open_text_target(target, "--readings-out") if isinstance(target, str) else target
        self.ground_truth = ground_truth
        self.flush_each = flush_each
        self.with_seq: bool | None = None  # decided by the first reading
        self.with_beacon = False
        self.count = 0
        self.skipped = 0

    def _skip(self, why: str) -> None:
        if not self.skipped:
            log.warning("--readings-out: %s; such readings are skipped (counted)", why)
        self.skipped += 1

    def reading(self, r, beacon: str | None = None) -> None:
        if self.with_seq is None:
            self.with_seq = r.seq is not None
            self.with_beacon = beacon is not None
            cols = ["t", "anchor", "rssi_dbm"] + (["seq"] if self.with_seq else [])
            if self.ground_truth is not None:
                cols += ["gt_x", "gt_y"]
            self.stream.write(",".join(cols + (["beacon"] if self.with_beacon else [])) + "\n")
        fields = [_f(r.t), str(int(r.anchor_id)), _f(r.rssi_dbm)]
        named = ""
        if beacon is not None:
            if not self.with_beacon:
                return self._skip("a named beacon's reading in a file without a beacon column")
            field = _beacon_field(beacon)
            if field is None:
                return self._skip("a beacon id with a control character")
            named = field
        if self.with_seq:
            if r.seq is None:
                return self._skip("a reading without a beacon sequence in a file with a seq column")
            fields.append(str(int(r.seq) & 0xFFFF))
        if self.ground_truth is not None:
            gt = self.ground_truth(r.t)
            if gt is not None and all(math.isfinite(v) for v in gt):
                fields += [_f(gt[0]), _f(gt[1])]
            else:
                fields += ["", ""]
        if self.with_beacon:
            fields.append(named)
        self.stream.write(",".join(fields) + "\n")
        self.count += 1
        if self.flush_each:
            self.stream.flush()

    def _close(self) -> None:
        if self.with_seq is None:  # no reading at all: still a trace file, with its header
            self.stream.write("t,anchor,rssi_dbm,seq" + (",gt_x,gt_y" if self.ground_truth is not None else "") + "\n")
        try:
            self.stream.flush()
        except (BrokenPipeError, ValueError):
            pass
        if self.stream not in (sys.stdout, sys.stderr):
            self.stream.close()


MAX_GAP_S = 1.0  # ground truth is not interpolated across a longer gap between its samples
MAX_TRUTH_ROWS = 2_000_000  # a ground-truth file is read whole (10 h at 50 Hz); beyond this it is refused


class GroundTruthFile:
    """Positions from a CSV file (``--ground-truth``), interpolated at any time.

    The header names ``t`` and either ``gt_x,gt_y`` (a trace, e.g. the simulator's
    ``trace.csv``) or ``x,y`` (a tracking system's export); other columns are ignored, and
    rows with empty positions are skipped. Times are on the gateway's host clock. Calling
    it with a time gives the position linearly interpolated between the samples around it,
    or None outside the file's span or inside a gap longer than :data:`MAX_GAP_S`. A bad
    file is one :class:`~pfdoa.errors.InputError` naming the file and line.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        rows: list[tuple[float, float, float]] = []
        try:
            with open(path, encoding="utf-8", newline="") as fh:
                reader = csv.reader(fh)
                cols = None
                for lineno, fields in enumerate(reader, start=1):
                    if not fields or fields[0].lstrip().startswith("#"):
                        continue
                    if cols is None:
                        names = {n.strip().lstrip("\ufeff"): i for i, n in enumerate(fields)}
                        pair = next((p for p in (("gt_x", "gt_y"), ("x", "y")) if all(c in names for c in p)), None)
                        if "t" not in names or pair is None:
                            raise InputError(f"--ground-truth {path}:{lineno}: the header needs t and gt_x,gt_y "
                                             f"(or x,y); got {','.join(fields)}")
                        cols = (names["t"], names[pair[0]], names[pair[1]])
                        continue
                    try:
                        vals = [fields[i].strip() for i in cols]
                    except IndexError:
                        raise InputError(f"--ground-truth {path}:{lineno}: too few columns") from None
                    if vals[1] == "" or vals[2] == "":
                        continue
                    try:
                        t, x, y = (float(v) for v in vals)
                    except ValueError:
                        raise InputError(f"--ground-truth {path}:{lineno}: not a number in {','.join(vals)}") from None
                    if not all(math.isfinite(v) for v in (t, x, y)):
                        raise InputError(f"--ground-truth {path}:{lineno}: not finite")
                    rows.append((t, x, y))
                    if len(rows) > MAX_TRUTH_ROWS:
                        raise InputError(f"--ground-truth {path}: more than {MAX_TRUTH_ROWS} rows")
        except OSError as exc:
            raise InputError(f"--ground-truth {path}: cannot read: {exc.strerror or exc}") from None
        except (UnicodeDecodeError, csv.Error) as exc:
            raise InputError(f"--ground-truth {path}: not a CSV text file ({exc})") from None
        if not rows:
            raise InputError(f"--ground-truth {path}: no positions")
        a = np.array(sorted(rows), dtype=float)
        keep = np.concatenate(([True], np.diff(a[:, 0]) > 0))  # one sample per time (the first)
        self.t, self.x, self.y = a[keep, 0], a[keep, 1], a[keep, 2]

    def __call__(self, t: float) -> tuple[float, float] | None:
        ts = self.t
        if not ts[0] <= t <= ts[-1]:
            return None
        i = int(np.searchsorted(ts, t, side="right"))
        if i >= len(ts):  # t is the last sample
            return float(self.x[-1]), float(self.y[-1])
        t0, t1 = ts[i - 1], ts[i]
        if t == t0:
            return float(self.x[i - 1]), float(self.y[i - 1])
        if t1 - t0 > MAX_GAP_S:
            return None
        w = (t - t0) / (t1 - t0)
        x0, y0 = self.x[i - 1], self.y[i - 1]
        return float(x0 + w * (self.x[i] - x0)), float(y0 + w * (self.y[i] - y0))
