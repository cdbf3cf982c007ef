"""The reassembled readings of a live run as a trace (``--readings-out trace.csv``).

The file is the trace format that ``pfdoa replay``, ``calibrate`` and ``eval`` read
(:func:`pfdoa.trace.read_trace`)::

    t,anchor,rssi_dbm,seq[,gt_x,gt_y]

``t`` is the reading's receive time as the gateway used it (Unix s), written with
``repr`` so it reads back to the same float; ``seq`` the beacon sequence (0..65535).
Ground truth is never invented: the ``gt_x,gt_y`` columns exist only when the caller
gives a ground-truth source (a simulator, a tracking system), and a reading it has no
position for gets empty fields (read back as unknown).

The ``seq`` column is decided by the first reading (live anchors always send one); a later
reading without a sequence cannot be written in that file and is counted in ``skipped``.
"""

from __future__ import annotations

import logging
import math
import sys
from typing import IO, Callable

from pfdoa.sinks.base import Sink, open_text_target

log = logging.getLogger(__name__)

GroundTruth = Callable[[float], "tuple[float, float] | None"]


def _f(v: float) -> str:
    return repr(float(v))


class ReadingsCsvSink(Sink):
    name = "readings"

    def __init__(self, target: str | IO[str], ground_truth: GroundTruth | None = None,
                 flush_each: bool = True) -> None:
        self.stream = open_text_target(target, "--readings-out") if isinstance(target, str) else target
        self.ground_truth = ground_truth
        self.flush_each = flush_each
        self.with_seq: bool | None = None  # decided by the first reading
        self.count = 0
        self.skipped = 0

    def reading(self, r) -> None:
        if self.with_seq is None:
            self.with_seq = r.seq is not None
            cols = ["t", "anchor", "rssi_dbm"] + (["seq"] if self.with_seq else [])
            if self.ground_truth is not None:
                cols += ["gt_x", "gt_y"]
            self.stream.write(",".join(cols) + "\n")
        fields = [_f(r.t), str(int(r.anchor_id)), _f(r.rssi_dbm)]
        if self.with_seq:
            if r.seq is None:
                if not self.skipped:
                    log.warning("--readings-out: a reading without a beacon sequence in a file with a seq "
                                "column; such readings are skipped (counted)")
                self.skipped += 1
                return
            fields.append(str(int(r.seq) & 0xFFFF))
        if self.ground_truth is not None:
            gt = self.ground_truth(r.t)
            if gt is not None and all(math.isfinite(v) for v in gt):
                fields += [_f(gt[0]), _f(gt[1])]
            else:
                fields += ["", ""]
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
