"""Health as JSON lines: one object per health period (``--health-json PATH``).

Each line is :meth:`~pfdoa.gateway.health.HealthSnapshot.to_json` of the snapshot the human
health line is printed from: ``t`` (the gateway's host time, s), ``period_s``, ``frames_per_s``,
``sets_per_s``, ``estimates_per_s``, ``errors`` (by kind, totals), ``anchors`` (per id:
``received``, ``lost``, ``loss_pct``, ``duplicates``, ``late``, ``reboots``, ``stale``,
``period_received``, ``period_lost``, ``period_reboots``, ``schema_mismatch``, ``level``
OK/WARN/ERROR/STALE), ``stale`` (ids), ``open_sets``, ``frames``, ``sets``, ``estimates``,
``estimator_errors``, ``reconnects``. Every line is flushed, so another program can follow
the file or pipe.
"""

from __future__ import annotations

import json
import sys
from typing import IO

from pfdoa.gateway.health import HealthSnapshot
from pfdoa.sinks.base import Sink, open_text_target


class HealthJsonSink(Sink):
    name = "health-json"

    def __init__(self, target: str | IO[str], existing: str = "replace") -> None:
        self.stream = open_text_target(target, "--health-json", existing) if isinstance(target, str) else target
        self.count = 0

    def health(self, snapshot: HealthSnapshot) -> None:
        self.stream.write(json.dumps(snapshot.to_json(), separators=(",", ":"), allow_nan=False) + "\n")
        self.stream.flush()
        self.count += 1

    def _close(self) -> None:
        try:
            self.stream.flush()
        except (BrokenPipeError, ValueError):
            pass
        if self.stream not in (sys.stdout, sys.stderr):
            self.stream.close()
