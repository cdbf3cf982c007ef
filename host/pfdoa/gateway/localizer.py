"""Anchor sets -> estimator -> output records, with the odometry over each set's interval.

:class:`Localizer` is shared by ``pfdoa gateway`` and ``pfdoa replay``. Each set is stepped
with the motion of the robot between the previous estimate's time and its own, composed
from an :class:`~pfdoa.odometry.OdometryBuffer` by the increments' own timestamps (not by
when they arrived). Both times are on the gateway's host clock.

Live, the odometry for a set may still be on its way when the set is ready. The set then
waits, in the order sets leave, until an increment at or after its time has arrived, for
at most ``odom_wait_s`` of the runner's timer time after it left (:meth:`release` is called
as that time advances); after that it goes on with the motion known so far, and the rest is carried
into the next interval. An odometry stream that has not reached within ``odom_fresh_s``
of a set's time is gone (or on another clock): the set is stepped at once, without
odometry, so the estimator uses its own motion model. Once the stream has ended (a file
read whole, the end of a capture), nothing waits.

Each record goes to the position writer and then to the ``sinks`` (a
:class:`~pfdoa.sinks.base.Sink`, e.g. the fan-out of ``--record``, ``--web``), stamped with
``stamp_t``: the gateway's time of the item being processed when the estimate was made
(set by the runner; by ``pfdoa replay``, the reading's time).

A site with ``[[floors]]`` or ``[[rooms]]`` gives every record its ``floor`` and ``room``
(:class:`pfdoa.rooms.Places`, one per localizer, i.e. per beacon): the floor from the set's
readings before the estimate (with anchors on several floors the estimator then gets that
floor's anchors alone, their heights above the beacon on that floor: [[floors]] target_z,
:func:`pfdoa.rooms.floor_site`, applied when the estimator is built), the room from the estimate.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Iterable

import numpy as np

from pfdoa.estimators.base import Estimator, Observation
from pfdoa.gateway.health import Health
from pfdoa.odometry import OdometryBuffer
from pfdoa.output import DEFAULT_FRAME, Record, Writer
from pfdoa.readings.reassembly import AnchorSet
from pfdoa.rooms import Places, site_plan
from pfdoa.types import position_cov

log = logging.getLogger(__name__)

ODOM_WAIT_S = 0.25  # a set waits this long (timer time) for its odometry
ODOM_FRESH_S = 1.0  # odometry further behind a set's time than this is gone
MAX_PENDING = 64  # sets waiting for odometry at most (beyond: the oldest goes on, counted)


class Localizer:
    """Anchor sets -> estimator -> output records (see the module doc)."""

    def __init__(self, site, estimator: Estimator, writer: Writer | None, odometry: OdometryBuffer | None = None,
                 health: Health | None = None, tolerate_errors: bool = True, odom_wait_s: float = ODOM_WAIT_S,
                 odom_fresh_s: float = ODOM_FRESH_S, sinks=None, frame_id: str = DEFAULT_FRAME) -> None:
        self.anchor_ids = site.anchor_ids
        self.tolerate_errors = tolerate_errors  # live: count and go on; offline: raise
        self.estimator = estimator
        self.writer = writer
        self.sinks = sinks  # a Sink (pfdoa.sinks): gets every record after the writer
        self.frame_id = frame_id
        self.stamp_t = -math.inf  # the gateway's time of the item in process (the records' stamp)
        self.odometry = odometry
        self.health = health or Health()
        self.odom_wait_s = float(odom_wait_s)
        self.odom_fresh_s = float(odom_fresh_s)
        self.records: list[Record] | None = None  # set to a list to keep records (tests)
        self.now = -math.inf  # the runner's timer time, as last told by release()
        self._pending: deque[tuple[AnchorSet, float]] = deque()
        # Odometry bookkeeping for the final counters.
        self.odom_waited = 0  # sets that waited for their odometry
        self.odom_gave_up = 0  # ... and went on without all of it
        self.odom_none = 0  # sets stepped without odometry (stream gone, or never there)
        self.pending_evicted = 0
        self._warned_clock = False
        self.output_error: OSError | None = None  # the output could not be written (a full disk)
        self.odometry_requested = odometry is not None  # False: a buffer for a stream's O lines, if any
        plan = site_plan(site)
        self.places = Places(plan, site.offsets) if plan is not None else None

    # -- the set stream -------------------------------------------------------------------
    def handle(self, s: AnchorSet) -> None:
        """A set left the reassembler (the Gateway's ``on_set``)."""
        if (self.odometry is None or self.odometry.ended) and not self._pending:
            self._step(s)
            return
        # It left at timer time `now` (not before its own time: the timer may lag an item).
        self._pending.append((s, max(self.now, s.t)))
        if len(self._pending) > MAX_PENDING:
            self.pending_evicted += 1
            self._step(self._pending.popleft()[0], gave_up=True)
        self.release(self.now)

    def handle_all(self, sets: Iterable[AnchorSet]) -> None:
        for s in sets:
            self.handle(s)

    def release(self, now: float) -> None:
        """Timer time is ``now``: step every waiting set whose odometry is there, or gone,
        or has been waited for long enough (in the order the sets left)."""
        self.now = max(self.now, now)
        od = self.odometry
        while self._pending:
            s, ready = self._pending[0]
            if od is None or od.ended or od.covers(s.t) or not self._alive(s.t):
                gave_up = False
            elif self.now >= ready + self.odom_wait_s:
                gave_up = True
            else:
                return
            self._pending.popleft()
            self._step(s, gave_up=gave_up, waited=self.now > ready)

    def finish(self) -> None:
        """End of input: every waiting set is stepped with what is known."""
        while self._pending:
            s, _ = self._pending.popleft()
            self._step(s)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def _alive(self, t: float) -> bool:
        od = self.odometry
        return od is not None and od.newest is not None and od.newest >= t - self.odom_fresh_s

    # -- one estimate ---------------------------------------------------------------------
    def _odometry_for(self, t: float):
        od = self.odometry
        if od is None:
            return None
        if od.first is None or od.first > t + self.odom_fresh_s or od.newest < t - self.odom_fresh_s:
            # No increment near this set's time: the stream has not started, is gone, or
            # runs on another clock than the gateway's (then it never overlaps: say so).
            if od.first is not None and not self._warned_clock and (od.first > t + 3600 or od.newest < t - 3600):
                self._warned_clock = True
                log.warning("odometry times (%.3f..%.3f) are more than an hour from the sets' (%.3f): odometry t "
                            "must be on the gateway's host clock; estimating without it", od.first, od.newest, t)
            self.odom_none += 1
            if od.newest is not None and od.newest < t:
                od.take(t)  # what is this old belongs to no estimate
            return None
        return od.take(t)

    def _step(self, s: AnchorSet, gave_up: bool = False, waited: bool = False) -> Record | None:
        self.odom_waited += waited
        self.odom_gave_up += gave_up
        rssi = s.vector(self.anchor_ids)
        floor = floor_p = None
        if self.places is not None:
            floor, floor_p = self.places.floor(s.t, rssi)
            rssi = self.places.mask(rssi, floor)
        obs = Observation(s.t, rssi, s.count_vector(self.anchor_ids))
        odom = self._odometry_for(s.t)
        try:
            est = self.estimator.step(obs, odom)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            if not self.tolerate_errors:
                raise
            # One bad set must not stop a live gateway; count it and go on.
            self.health.estimator_errors += 1
            log.warning("estimator failed on set at t=%.3f: %s", s.t, exc)
            return None
        self.health.estimates += 1
        place = None
        if self.places is not None:
            place = self.places.place(est.x, est.y, position_cov(est), floor, floor_p)
        rec = Record(
            t=s.t, x=est.x, y=est.y, sigma=est.sigma, doa=est.doa, seq=s.seq,
            anchors=est.anchors_used or s.anchors, missing=s.missing, stale=s.stale, rebooted=s.rebooted,
            r95=est.r95, cov=est.cov, lost=est.lost, frame_id=self.frame_id,
            stamp=self.stamp_t if math.isfinite(self.stamp_t) else s.t, heading=est.heading,
            heading_var=est.heading_var,
        )
        if place is not None:
            rec.room, rec.room_p, rec.floor, rec.floor_p = place.room, place.room_p, place.floor, place.floor_p
        if self.writer is not None and self.output_error is None:
            try:
                self.writer.write(rec)
            except OSError as exc:  # counted and said; the gateway goes on (counters, capture)
                self.output_error = exc
                log.error("output: %s; no more positions are written", exc.strerror or exc)
        if self.sinks is not None:
            self.sinks.write(rec)
        if self.records is not None:
            self.records.append(rec)
        return rec

    def summary(self) -> dict:
        """Odometry counters for the final line (empty without odometry)."""
        od = self.odometry
        if od is None or (od.lines == 0 and not self.odometry_requested):
            return {}
        return {"lines": od.lines, "dropped": od.dropped, "out_of_order": od.out_of_order,
                "waited": self.odom_waited, "gave_up": self.odom_gave_up, "without": self.odom_none,
                "pending_evicted": self.pending_evicted}
