"""The reassembled readings of a live run as a trace (``--readings-out trace.csv``).

The file is the trace format that ``pfdoa replay``, ``calibrate`` and ``eval`` read
(:func:`pfdoa.trace.read_trace`)::

    t,anchor,rssi_dbm[,seq][,gt_x,gt_y][,beacon]

``t`` is the reading's receive time as the gateway used it (Unix s; with ESPresense
message time, the message's time), written with ``repr`` so it reads back to the same
float; ``seq`` the beacon sequence (0..65535); ``beacon`` the id of the beacon a reading
names (ESPresense devices; always CSV-quoted, and made safe for spreadsheets by
:func:`pfdoa.output.csv_text`, which the trace reader undoes).
Ground truth is never invented: the ``gt_x,gt_y`` columns exist only when the caller
gives a ground-truth source (a simulator, a tracking system; ``--ground-truth FILE``:
:class:`GroundTruthFile`), and a reading it has no position for gets empty fields (read
back as unknown). With them the file is what ``pfdoa calibrate`` and ``pfdoa eval`` need.

The ``seq`` and ``beacon`` columns are decided by the first reading (live anchors always
send a sequence; ESPresense readings never do, and always name their beacon), or, when a
restarted gateway continues its earlier file (``existing="keep"``, pfdoa.outfiles), by that
file's header (a file whose header is not one of these, or whose ground-truth columns
differ, is moved aside and a new one begun). A later
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
from pfdoa.outfiles import open_stream
from pfdoa.output import csv_text
from pfdoa.sinks.base import Sink

log = logging.getLogger(__name__)

GroundTruth = Callable[[float], "tuple[float, float] | None"]


def _columns(with_seq: bool, with_gt: bool, with_beacon: bool) -> list[str]:
    return (["t", "anchor", "rssi_dbm"] + (["seq"] if with_seq else []) + (["gt_x", "gt_y"] if with_gt else [])
            + (["beacon"] if with_beacon else []))


def _has_control(text: str) -> bool:
    return any(ord(c) < 0x20 or c == "\x7f" for c in text)


class ReadingsCsvSink(Sink):
    """``existing``: what to do with a file already at the path (pfdoa.outfiles): "keep"
    (the gateway) continues a trace whose header is one this sink writes, with its columns."""

    name = "readings"

    def __init__(self, target: str | IO[str], ground_truth: GroundTruth | None = None,
                 flush_each: bool = True, existing: str = "replace") -> None:
        self.ground_truth = ground_truth
        self.flush_each = flush_each
        self.with_seq: bool | None = None  # decided by the first reading (or the file continued)
        self.with_beacon = False
        self.count = 0
        self.skipped = 0
        self.stream: IO[str]
        if not isinstance(target, str):
            self.stream = target
        elif target == "-":
            if sys.stdout is None:
                raise InputError("--readings-out -: standard output is closed")
            self.stream = sys.stdout
        else:
            self.stream, _ = open_stream(target, "--readings-out", existing=existing, same_kind=self._continues)
        # Numbers as numbers, text quoted: a beacon id with commas, quotes or edge spaces reads back whole.
        self._csv = csv.writer(self.stream, quoting=csv.QUOTE_NONNUMERIC, lineterminator="\n")

    def _continues(self, first: bytes) -> bool:
        """The header of the file there: one of ours with the same ground-truth columns?
        Then its columns are this run's (checked when appending to a kept file)."""
        try:
            cols = first.decode("utf-8").lstrip("\ufeff").split(",")
        except UnicodeDecodeError:
            return False
        with_gt = "gt_x" in cols
        for with_seq in (False, True):
            for with_beacon in (False, True):
                if cols == _columns(with_seq, with_gt, with_beacon) and with_gt == (self.ground_truth is not None):
                    self.with_seq, self.with_beacon = with_seq, with_beacon
                    return True
        return False

    def _skip(self, why: str) -> None:
        if not self.skipped:
            log.warning("--readings-out: %s; such readings are skipped (counted)", why)
        self.skipped += 1

    def reading(self, r, beacon: str | None = None) -> None:
        if self.with_seq is None:
            self.with_seq = r.seq is not None
            self.with_beacon = beacon is not None
            self.stream.write(",".join(_columns(self.with_seq, self.ground_truth is not None, self.with_beacon)) + "\n")
        fields: list = [float(r.t), int(r.anchor_id), float(r.rssi_dbm)]
        named = ""
        if beacon is not None:
            if not self.with_beacon:
                return self._skip("a named beacon's reading in a file without a beacon column")
            if _has_control(beacon):
                return self._skip("a beacon id with a control character")
            named = csv_text(beacon)
        if self.with_seq:
            if r.seq is None:
                return self._skip("a reading without a beacon sequence in a file with a seq column")
            fields.append(int(r.seq) & 0xFFFF)
        if self.ground_truth is not None:
            gt = self.ground_truth(r.t)
            if gt is not None and all(math.isfinite(v) for v in gt):
                fields += [float(gt[0]), float(gt[1])]
            else:
                fields += ["", ""]
        if self.with_beacon:
            fields.append(named)
        self._csv.writerow(fields)
        self.count += 1
        if self.flush_each:
            self.stream.flush()

    def _close(self) -> None:
        if self.with_seq is None:  # no reading at all: still a trace file, with its header
            self.stream.write(",".join(_columns(True, self.ground_truth is not None, False)) + "\n")
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
