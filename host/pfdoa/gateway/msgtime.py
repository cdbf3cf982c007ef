"""The gateway's clock on message time, and which message times are plausible.

With ESPresense ``time_field`` the publisher stamps every message and the gateway's timers
(windows closing, devices timing out) run on those stamps (:mod:`pfdoa.gateway.runner`,
"message time"). One device's clock must then not be everyone's: a single message stamped
``9e10`` would otherwise take the clock thousands of years ahead, every tracked device would
time out at once, and the timers would never run again (they never go back).

:class:`MessageClock` is that clock: the latest *admitted* message time. A reading is
admitted when its time ``t`` lies within

    ``[now - MAX_LAG_S, now + MAX_LEAD_S + host seconds since now last moved]``

(``now`` the clock). The gateway's clock is at or after every device's own latest time,
so a reading more than ``MAX_LAG_S`` behind its own device's latest is refused too. The
host-time allowance lets a fleet that fell silent (nobody in range overnight) resume on
its own clock, which moved on meanwhile; it never applies while messages keep coming.
Refused readings are counted by device (``time_ahead``, ``time_behind``:
:meth:`pfdoa.gateway.beacons.BeaconTracker.refuse`) and move nothing: no clock, no window,
no timeout.

The first reading sets the clock. Should that one be the wrong one (a node with a broken
clock heard first), the fleet's readings all look implausible: after :data:`RESYNC`
refused readings in a row, all on one side of the clock and within ``MAX_LEAD_S`` of each
other, the clock moves to them (``resets``, said on the log); a lone device with a wrong
clock among working ones never gets that many in a row. A clock set back makes the
tracker let go the devices heard on the dropped clock (``BeaconTracker.rebase``).

Not for recordings: ``pfdoa replay`` replays what the gateway admitted, with its timer
marks, and so needs no check of its own.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

log = logging.getLogger(__name__)

MAX_LEAD_S = 10.0  # a message time this far after the clock (plus the host time since it moved) is refused
MAX_LAG_S = 10.0  # ... this far before it
RESYNC = 64  # refused readings in a row, consistent among themselves, that move the clock to them

AHEAD = "time_ahead"
BEHIND = "time_behind"


class MessageClock:
    """The latest admitted message time (see the module doc). ``monotonic``: this host's
    clock, for the allowance after a silence (injected in tests)."""

    def __init__(self, lead_s: float = MAX_LEAD_S, lag_s: float = MAX_LAG_S, resync: int = RESYNC,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self.lead_s = float(lead_s)
        self.lag_s = float(lag_s)
        self.resync = int(resync)
        self.monotonic = monotonic
        self.now: float | None = None
        self.resets = 0  # times the clock was moved to a run of refused readings
        self.moved_back = False  # the last admit() set the clock back (the caller rebases)
        self._moved_at = 0.0  # host time when `now` last moved
        self._run: tuple[str, int, float, float] | None = None  # (side, count, lowest, highest) of refusals in a row

    def admit(self, t: float) -> str | None:
        """None when ``t`` is plausible (the clock moves to it if later), else why not
        (:data:`AHEAD` or :data:`BEHIND`)."""
        host = self.monotonic()
        self.moved_back = False
        now = self.now
        if now is None:
            self._move(t, host)
            return None
        if t > now + self.lead_s + max(0.0, host - self._moved_at):
            side = AHEAD
        elif t < now - self.lag_s:
            side = BEHIND
        else:
            self._run = None
            if t > now:
                self._move(t, host)
            return None
        run = self._run
        if run is not None and run[0] == side and max(run[3], t) - min(run[2], t) <= self.lead_s:
            run = (side, run[1] + 1, min(run[2], t), max(run[3], t))
        else:
            run = (side, 1, t, t)
        self._run = run
        if run[1] < self.resync:
            return side
        # A run of readings that agree with each other and not with the clock: the clock
        # was the odd one out (see the module doc).
        self.resets += 1
        self._run = None
        self.moved_back = side == BEHIND
        log.warning("message time: %d readings in a row %s the gateway's clock (%.3f), agreeing with each "
                    "other: the clock moves to %.3f", run[1], "after" if side == AHEAD else "before", now, run[3])
        self._move(run[3], host)
        return None

    def _move(self, t: float, host: float) -> None:
        self.now = t
        self._moved_at = host
