"""Anchor clocks: map each anchor's millisecond tick to the gateway's host clock.

Every RSSI_REPORT carries the anchor's ``tick_ms`` (u32, wraps every 49.7 days) at the
moment its beacon event closed (protocol/SPEC.md 3). The gateway knows when the bytes
*arrived*; between the two lie the UART, a USB adapter that batches frames, the kernel and
the scheduler. All of that delay is >= 0, and most frames see close to its minimum, so the
map is fitted to the **lower envelope** of the points (tick, arrival): the min-delay
filtering of NTP/PTP, and the one-sided fit of Moon, Skelly and Towsley ("Estimation and
removal of clock skew from network delay measurements", INFOCOM 1999).

Per anchor (:class:`AnchorClock`), over a sliding window of ``WINDOW_S`` seconds of ticks:

* the window is cut into segments of ``SEGMENT_S``; each keeps only its lowest point (least
  ``arrival - rate * tick``): bounded memory (at most ``MAX_SEGMENTS`` points) whatever
  the report rate, and a burst or stall (points far above the envelope) costs nothing;
* the **rate** (drift) is the slope of the lower convex hull of the segment minima where
  it spans their mean tick: Moon et al.'s linear programme (the line under every point
  with the least total distance to them). It is bounded to ``1 +- MAX_DRIFT_PPM`` (a
  crystal is within a few tens of ppm; a fit outside that is noise), and pulled towards
  nominal (one tick = 1 ms) as much as it is uncertain: a Gaussian prior of
  ``PRIOR_PPM`` on the drift, and an uncertainty of the fitted slope that grows with how
  high the segment minima sit above the envelope (heavy jitter) and shrinks with the span
  (a short window at the start). Low jitter: the drift is followed within seconds;
  heavy jitter: the rate stays near nominal until the window is long;
* the **offset** puts the line under every segment minimum, touching the hull;
* the rate is fitted when a segment opens (or an older one changes): the newest segment's
  minimum, which a chunk of reports read at once lowers at each report, moves the offset
  alone until then (a refit per report was most of the gateway's time on bulk reads);
* an event's time is the line at its tick, never after its own report's arrival. (An
  event at tick ``T`` happened during millisecond ``[T, T + 1)``; the envelope already
  sits on the reports whose fraction of a tick plus delay was least, so nothing is added.)

Unwrapping: ticks are extended to 64 bits with the signed u32 difference to the newest
tick, so a wrap is just the next millisecond and a reordered report maps to its own
(earlier) time. The model starts afresh (``resets``) when the tick goes back by more than
``REBOOT_TICK_SLACK_MS`` (a reboot, as the tracker counts it), when the caller says the
anchor rebooted (its STATUS uptime went back), or when a report's tick maps more than
``JUMP_S`` after its own arrival (the tick jumped forward: a reboot at another tick base).

What it cannot see: a constant part of the delay (it is in every point, so the mapped
times are late by the minimum transport latency); a host clock step (the window follows
a step back at once, a step forward after up to ``WINDOW_S``). docs/gateway.md has the
failure modes.
"""

from __future__ import annotations

import math
from collections import deque

TICK_MOD = 1 << 32
HALF_TICKS = 1 << 31
REBOOT_TICK_SLACK_MS = 1000  # as the reassembler's reboot rule (a tick back by more)
WINDOW_S = 60.0  # tick seconds of history the fit uses
SEGMENT_S = 1.0  # one lowest point per segment of tick time
MAX_SEGMENTS = int(math.ceil(WINDOW_S / SEGMENT_S)) + 1
MIN_SPAN_S = 2.0  # the rate is fitted once the window spans this much tick time
# The fitted rate's uncertainty is taken as SHRINK_K * (median height of the segment minima
# above the envelope) / span; it is combined with a prior N(0, PRIOR_PPM) on the drift.
SHRINK_K = 0.5
PRIOR_PPM = 200.0
MAX_DRIFT_PPM = 500.0
JUMP_S = 1.0  # a report mapped this far after its own arrival: the tick jumped


class AnchorClock:
    """One anchor's tick -> host time map (see the module doc)."""

    __slots__ = ("resets", "_ref_tick", "_ref_ext", "_ext0", "_y0", "_segs", "_rate", "_offset", "points")

    def __init__(self) -> None:
        self.resets = 0  # restarts after the first point (reboots, jumps)
        self.points = 0  # reports mapped since the last restart
        self._clear()

    def _clear(self) -> None:
        self._ref_tick: int | None = None  # newest tick (u32) and its extended value
        self._ref_ext = 0
        self._ext0 = 0  # extended tick and arrival of the first point: x, y are relative
        self._y0 = 0.0
        self._segs: deque[list] = deque()  # [segment index, x (s), y (s)] of each lowest point
        self._rate = 1.0
        self._offset = 0.0
        self.points = 0

    def reset(self) -> None:
        """Forget the model (the anchor rebooted): the next report starts a new one.

        A model started less than ``REBOOT_TICK_SLACK_MS`` of ticks ago already belongs to
        the new boot (one reboot seen first by its tick, then by its STATUS uptime): kept."""
        if self._ref_tick is None:
            return
        if self.points and self._ref_ext - self._ext0 < REBOOT_TICK_SLACK_MS and self.resets:
            return
        self.resets += 1
        self._clear()

    def _restart(self) -> None:
        self.resets += 1
        self._clear()

    @property
    def rate(self) -> float:
        """Host seconds per tick second (1.0 = no drift)."""
        return self._rate

    @property
    def drift_ppm(self) -> float:
        """How fast the anchor's tick runs against the host clock (ppm; + is fast)."""
        return (1.0 / self._rate - 1.0) * 1e6

    def event_time(self, tick_ms: int, arrival: float) -> float:
        """The host time at which the anchor's tick says the event happened, given that
        its report arrived at ``arrival``; updates the model with this point."""
        tick = int(tick_ms) % TICK_MOD
        if self._ref_tick is not None:
            diff = ((tick - self._ref_tick + HALF_TICKS) % TICK_MOD) - HALF_TICKS
            if diff < -REBOOT_TICK_SLACK_MS:
                self._restart()
        if self._ref_tick is None:
            self._ref_tick, self._ref_ext = tick, tick
            self._ext0, self._y0 = tick, arrival
            diff = 0
        ext = self._ref_ext + diff
        x = (ext - self._ext0) / 1000.0
        y = arrival - self._y0
        if self.points and y - (self._offset + self._rate * x) < -JUMP_S:
            self._restart()  # the tick leapt ahead of the host clock: not the same time base
            return self.event_time(tick_ms, arrival)
        if diff > 0:
            self._ref_tick, self._ref_ext = tick, ext
        segs = self._segs
        s = segs[-1] if segs else None
        if s is not None and s[0] == math.floor(x / SEGMENT_S):
            # _add's first case, inline (nearly every report): the newest segment, still open.
            rate = self._rate
            if y - rate * x < s[2] - rate * s[1] - 1e-6:
                s[1], s[2] = x, y
                self._offset = min(self._offset, y - rate * x)
        else:
            self._add(x, y)
        self.points += 1
        v = self._y0 + self._offset + self._rate * x
        return arrival if arrival < v else v  # min(v, arrival), without the call

    def _add(self, x: float, y: float) -> None:
        segs = self._segs
        k = math.floor(x / SEGMENT_S)
        rate = self._rate
        for s in reversed(segs):  # almost always the newest segment
            if s[0] == k:
                # Lower by more than a microsecond: float noise must not refit every report.
                if y - rate * x < s[2] - rate * s[1] - 1e-6:
                    s[1], s[2] = x, y
                    if s is segs[-1]:
                        # The newest segment is still open (reports read in one chunk share
                        # an arrival: each is its segment's new minimum): it lowers the
                        # offset now, and enters the rate's fit when the next one opens.
                        self._offset = min(self._offset, y - rate * x)
                    else:
                        self._fit()
                return
            if s[0] < k:
                break
        if not segs or k > segs[-1][0]:
            segs.append([k, x, y])
            while segs[-1][0] - segs[0][0] >= MAX_SEGMENTS:
                segs.popleft()
        elif k > segs[-1][0] - MAX_SEGMENTS:  # a reordered report opens an older segment
            i = next(i for i, s in enumerate(segs) if s[0] > k)
            segs.insert(i, [k, x, y])
        else:
            return  # older than the window
        self._fit()

    def _fit(self) -> None:
        """Rate: the slope of the lower hull of the segment minima at their mean tick (the
        LP solution of Moon et al.); offset: the line under every minimum."""
        segs = self._segs
        n = len(segs)
        rate = 1.0
        if n >= 2 and segs[-1][1] - segs[0][1] >= MIN_SPAN_S:
            hull: list[tuple[float, float]] = []  # monotone chain, lower part
            for _, px, py in segs:
                while len(hull) >= 2:
                    x1, y1 = hull[-2]
                    x2, y2 = hull[-1]
                    if (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1) <= 0:
                        hull.pop()
                    else:
                        break
                hull.append((px, py))
            xm = sum([s[1] for s in segs]) / n
            for (x1, y1), (x2, y2) in zip(hull, hull[1:]):
                if x1 <= xm <= x2 and x2 > x1:
                    rate = (y2 - y1) / (x2 - x1)
                    break
            bound = MAX_DRIFT_PPM * 1e-6
            rate = min(max(rate, 1.0 - bound), 1.0 + bound)
            if SHRINK_K > 0:
                # How far the segment minima typically sit above the envelope says how well
                # the hull's slope is known; a slope no better known than the crystal's own
                # spread is pulled towards nominal (a Gaussian prior of PRIOR_PPM).
                lows = [py - rate * px for _, px, py in segs]  # each height computed once
                off = min(lows)
                res = sorted([v - off for v in lows])
                spread = res[n // 2]
                span = segs[-1][1] - segs[0][1]
                sd = SHRINK_K * spread / span
                prior = PRIOR_PPM * 1e-6
                rate = 1.0 + (rate - 1.0) * prior * prior / (prior * prior + sd * sd)
        self._rate = rate
        self._offset = min([py - rate * px for _, px, py in segs])

class AnchorClocks:
    """An :class:`AnchorClock` per configured anchor (unknown ids are not modelled)."""

    def __init__(self, anchor_ids) -> None:
        self._clocks = {int(a): AnchorClock() for a in anchor_ids}

    def event_time(self, anchor_id: int, tick_ms: int | None, arrival: float) -> float:
        """The event time of a report; its arrival when there is no tick (CAN) or no model."""
        c = self._clocks.get(anchor_id)
        if c is None or tick_ms is None:
            return arrival
        return c.event_time(tick_ms, arrival)

    def reset(self, anchor_id: int) -> None:
        c = self._clocks.get(anchor_id)
        if c is not None:
            c.reset()

    def summary(self) -> dict[str, dict]:
        """Per anchor: fitted drift (ppm), model restarts, points since the last restart."""
        return {str(a): {"drift_ppm": round(c.drift_ppm, 2), "resets": c.resets, "points": c.points}
                for a, c in self._clocks.items()}
