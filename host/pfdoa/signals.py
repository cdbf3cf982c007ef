"""SIGINT and SIGTERM: the one way every ``pfdoa`` command stops on them.

:func:`pfdoa.cli.main` runs every command inside a :class:`Stop`. The first SIGINT or
SIGTERM records which signal came (:attr:`Stop.signum`, :attr:`Stop.event` set) and then:

* by default raises :class:`~pfdoa.errors.Interrupted` in the main thread, so the command
  unwinds through its ``finally`` blocks (a whole file being written is left as it was, a
  temporary file removed) and ends with one line and the shell's status for the signal
  (128 + its number: 130, 143);
* inside :meth:`Stop.graceful` (a loop that checks :attr:`Stop.event` between records:
  replay, the gateway's runner, ``pfdoa anchors``, the simulator) only sets the event; the
  loop stops at a record boundary, the command closes its outputs, prints its counters and
  then raises ``Interrupted`` itself. Blocking calls inside such a loop that the event
  cannot reach (opening a FIFO that has no reader or writer yet) run in
  :meth:`Stop.interruptible`, where a signal raises again.

A second signal while the first is being handled restores the default action and raises
it, so a stuck process can still be stopped. The handlers are installed even when the
process was started with SIGINT ignored (a shell's background job): every command stops
on both signals. Worker processes (``pfdoa eval --jobs``) ignore SIGINT (a terminal's
Ctrl-C reaches the whole process group) and die on SIGTERM: the parent decides and stops
them (:func:`worker_init`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Any, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)

_active: "Stop | None" = None


def current() -> "Stop | None":
    """The Stop the running command is inside (None outside the command line)."""
    return _active


def signal_name(signum: int) -> str:
    return signal.Signals(signum).name


class Stop:
    """SIGINT/SIGTERM while active (see the module doc). ``event``: an event to set (the
    gateway's runner's), else one of its own."""

    def __init__(self, event: threading.Event | None = None) -> None:
        self.event = event if event is not None else threading.Event()
        self.signum: int | None = None
        self._raising = [True]  # the mode stack: raise at once, or only set the event
        self._old: dict[int, Any] = {}
        self._outer: Stop | None = None

    # -- the handler ----------------------------------------------------------------------
    def _handle(self, signum: int, _frame) -> None:
        if self.signum is not None:  # the second one: the default action, now
            signal.signal(signum, signal.SIG_DFL)
            signal.raise_signal(signum)
            return
        self.signum = signum
        self.event.set()
        if self._raising[-1]:
            self.raise_if_stopped()

    def raise_if_stopped(self, what: str = "") -> None:
        """Raise :class:`~pfdoa.errors.Interrupted` when a signal came (``what``: how far
        the command got, for its one line)."""
        from pfdoa.errors import Interrupted

        if self.signum is not None:
            raise Interrupted(self.signum, f"stopped by {self.name()}" + (f" {what}" if what else ""))

    @property
    def stopped(self) -> bool:
        """A signal came (not merely the event set by a loop that ended)."""
        return self.signum is not None

    def name(self) -> str:
        return signal_name(self.signum) if self.signum else ""

    # -- modes ----------------------------------------------------------------------------
    @contextlib.contextmanager
    def _mode(self, raising: bool) -> Iterator["Stop"]:
        self._raising.append(raising)
        try:
            if raising:
                self.raise_if_stopped()
            yield self
        finally:
            self._raising.pop()

    def graceful(self) -> contextlib.AbstractContextManager["Stop"]:
        """Signals only set :attr:`event`; the caller's loop checks it."""
        return self._mode(False)

    def interruptible(self) -> contextlib.AbstractContextManager["Stop"]:
        """Signals raise :class:`~pfdoa.errors.Interrupted` (a blocking call inside a
        graceful section); a signal that came before raises at once."""
        return self._mode(True)

    # -- installing -----------------------------------------------------------------------
    def __enter__(self) -> "Stop":
        global _active
        if threading.current_thread() is threading.main_thread():
            self._old = {s: signal.signal(s, self._handle) for s in SIGNALS}
        self._outer, _active = _active, self
        return self

    def __exit__(self, *exc) -> None:
        global _active
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}
        _active = self._outer


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """:meth:`Stop.interruptible` of the running command (nothing outside one)."""
    stop = current()
    if stop is None:
        yield
        return
    with stop.interruptible():
        yield


def worker_init() -> None:
    """A worker process of a pool: Ctrl-C (sent to the whole process group) is the parent's
    to handle; SIGTERM (the parent stopping the pool) ends it at once."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def active() -> Stop:
    """The running command's Stop, or an idle one (no handlers) when called outside the
    command line: the callers' checks then never fire."""
    return _active if _active is not None else Stop()
