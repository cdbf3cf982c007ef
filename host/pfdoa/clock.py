"""Time as a dependency: one small clock interface, passed to everything that reads time.

The gateway's transports stamp chunks with :meth:`Clock.now`, its runner measures health
periods and ``--duration`` with :meth:`Clock.monotonic`, and every wait (reconnect backoff,
capture pacing, the bounded wait for odometry) goes through :meth:`Clock.sleep` or
:meth:`Clock.wait`. Production code uses :data:`SYSTEM` (:class:`SystemClock`); tests pass a
:class:`FakeClock`, which only moves when told to, so no test sleeps past a production timer.

Nothing outside :class:`SystemClock` calls ``time.time()`` or ``time.monotonic()`` on those
paths.
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod


class Clock(ABC):
    """Host time for the gateway (Unix seconds) and a monotonic time for periods."""

    @abstractmethod
    def now(self) -> float:
        """Unix seconds (the host clock: chunk stamps, output ``t``, odometry ``t``)."""

    @abstractmethod
    def monotonic(self) -> float:
        """Seconds on a clock that never goes back (periods, deadlines)."""

    @abstractmethod
    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass."""

    @abstractmethod
    def wait(self, event: threading.Event, timeout: float) -> bool:
        """Wait until ``event`` is set or ``timeout`` seconds passed; returns whether it is set."""


class SystemClock(Clock):
    """The machine's clocks (the only place the gateway reads them)."""

    def now(self) -> float:
        return time.time()

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return event.wait(max(timeout, 0.0))


SYSTEM = SystemClock()


class FakeClock(Clock):
    """A clock that moves only when told to (:meth:`advance`, :meth:`set`). Thread-safe.

    ``now()`` starts at ``start`` (Unix seconds), ``monotonic()`` at 0; both move together.
    ``sleep`` and ``wait`` block until the clock has been advanced past their deadline (or,
    for ``wait``, the event is set): the code under test runs in its threads while the test
    decides when time passes. With ``auto_advance=True`` they advance the clock themselves
    and return at once, for single-threaded code that sleeps.
    """

    def __init__(self, start: float = 1_700_000_000.0, auto_advance: bool = False) -> None:
        self._cond = threading.Condition()
        self._start = float(start)
        self._elapsed = 0.0
        self.auto_advance = auto_advance

    def now(self) -> float:
        with self._cond:
            return self._start + self._elapsed

    def monotonic(self) -> float:
        with self._cond:
            return self._elapsed

    def advance(self, seconds: float) -> None:
        if not seconds >= 0:
            raise ValueError(f"a clock does not go back ({seconds})")
        with self._cond:
            self._elapsed += seconds
            self._cond.notify_all()

    def set(self, now: float) -> None:
        """Move ``now()`` forward to ``now`` (Unix seconds); never back."""
        with self._cond:
            self._elapsed = max(self._elapsed, now - self._start)
            self._cond.notify_all()

    def sleep(self, seconds: float) -> None:
        self._until(max(seconds, 0.0), None)

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return self._until(max(timeout, 0.0), event)

    def _until(self, seconds: float, event: threading.Event | None) -> bool:
        with self._cond:
            deadline = self._elapsed + seconds
            if self.auto_advance:
                if event is None or not event.is_set():
                    self._elapsed = deadline
                    self._cond.notify_all()
                return event is not None and event.is_set()
            while self._elapsed < deadline:
                if event is not None and event.is_set():
                    return True
                # Short real-time slices: an Event cannot wake this condition.
                self._cond.wait(0.005 if event is not None else None)
        return event is not None and event.is_set()
