"""A scripted gateway run for the sink tests: real reassembler, health and output records.

``scripted_run()`` pushes RSSI readings of four anchors through a SeqReassembler (with a
lost report, a duplicate, a reboot and an anchor that goes silent), runs the sets through
a fixed "estimate" (a known track, so the records are known), and takes health snapshots
at two moments, returning everything the sinks are fed and what they should give back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pfdoa.gateway.health import Health, HealthSampler
from pfdoa.output import Record
from pfdoa.readings.reassembly import Reading, SeqReassembler
from pfdoa.site import parse_site

SITE = parse_site({
    "radio": {"rssi_at_1m_dbm": -45.0, "path_loss_exponent": 2.0},
    "anchors": [{"id": 0, "x": 0.0, "y": 0.0}, {"id": 1, "x": 6.0, "y": 0.0},
                {"id": 2, "x": 6.0, "y": 4.0}, {"id": 3, "x": 0.0, "y": 4.0}],
}, "scripted-site")
T0 = 1_700_000_000.125


@dataclass
class CovRecord(Record):
    """A Record with the fields the estimators are gaining (cov, heading)."""

    cov: tuple[float, float, float] | None = None
    heading: float | None = None
    heading_var: float | None = None


def track(k: int) -> tuple[float, float]:
    """A known path inside the site (m)."""
    return 1.0 + 4.0 * k / 40.0, 1.0 + 2.0 * math.sin(k / 8.0)


@dataclass
class Run:
    readings: list = field(default_factory=list)
    records: list = field(default_factory=list)
    snapshots: list = field(default_factory=list)  # (snapshot, Health.line at the same moment)


def scripted_run(n_sets: int = 40) -> Run:
    health = Health()
    grouper = SeqReassembler(SITE.anchor_ids, set_timeout_s=0.25, stale_after_s=1.0)
    sampler = HealthSampler(health, grouper)
    run = Run()
    health.start(0.0)
    sampler.start(0.0)
    for k in range(n_sets):
        t = T0 + 0.1 * k
        for a in SITE.anchor_ids:
            if a == 1 and k == 7:
                continue  # lost
            if a == 3 and k >= 25:
                continue  # silent from here: stale after 1 s
            tick = 100 * k + 5 * a if not (a == 2 and k >= 30) else 100 * (k - 30)  # anchor 2 reboots at k = 30
            r = Reading(a, -50.0 - a - 0.25 * (k % 7), t + 0.001 * a, seq=(65530 + k) & 0xFFFF, tick_ms=tick)
            copies = 2 if (a == 0 and k == 12) else 1  # one duplicate
            for _ in range(copies):
                run.readings.append(r)
                health.frames += 1
                health.reports += 1
                for s in grouper.push(r):
                    run.records.append(_record(s, len(run.records)))
                    health.estimates += 1
        for s in grouper.poll(t + 0.05):
            run.records.append(_record(s, len(run.records)))
            health.estimates += 1
        if k in (19, n_sets - 1):
            now = 2.0 if k == 19 else 4.0
            run.snapshots.append((sampler.sample(now, t), health.line(now, grouper)))
    for s in grouper.flush():
        run.records.append(_record(s, len(run.records)))
    return run


def _record(s, k: int) -> CovRecord:
    x, y = track(k)
    # A tilted ellipse whose size changes along the track; heading known on every 2nd record.
    a, b, th = 0.04 + 0.01 * (k % 5), 0.01 + 0.002 * k, 0.3 * k
    c, sn = math.cos(th), math.sin(th)
    xx = a * c * c + b * sn * sn
    yy = a * sn * sn + b * c * c
    xy = (a - b) * c * sn
    heading = (0.2 * k) % (2 * math.pi) - math.pi if k % 2 == 0 else None
    return CovRecord(t=s.t, x=x, y=y, sigma=math.sqrt(xx + yy), doa=None, seq=s.seq, anchors=s.anchors,
                     missing=s.missing, stale=s.stale, rebooted=s.rebooted, cov=(xx, xy, yy),
                     heading=heading, heading_var=0.05 if heading is not None else None)
