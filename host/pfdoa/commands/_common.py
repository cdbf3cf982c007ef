"""Checks the commands share: option values, outputs against inputs, site tables, signals.

Not a command (``pfdoa.cli`` skips modules starting with ``_``). Every check raises
:class:`~pfdoa.errors.InputError` or :class:`~pfdoa.errors.ConfigError`: one line naming
the option or the file and key, exit status 2.
"""

from __future__ import annotations

import math
import os
import signal
import threading
from typing import Any

from pfdoa.errors import InputError

SEED_MAX = 2**128  # numpy's SeedSequence takes any non-negative integer; beyond this is a typo


def check_seed(value: int | None, name: str = "--seed") -> None:
    if value is not None and not 0 <= value < SEED_MAX:
        raise InputError(f"{name} must be an integer >= 0, got {value}")


def check_number(name: str, value: float | None, *, minimum: float = 0.0, strict: bool = True) -> None:
    """A finite number above ``minimum`` (``strict``) or at least ``minimum``; None passes."""
    if value is None:
        return
    ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        raise InputError(f"{name} must be a finite number {'>' if strict else '>='} {minimum:g}, got {value}")


def same_file(a: str, b: str) -> bool:
    if a == "-" or b == "-":
        return a == b
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return os.path.abspath(a) == os.path.abspath(b)


def check_outputs(outputs: dict[str, str | None], inputs: dict[str, list[str]]) -> None:
    """An output that is also an input (or another output) would destroy it: InputError.
    "-" (standard output) may be one output only; as an input it is standard input."""
    outs = [(k, v) for k, v in outputs.items() if v]
    for i, (ko, o) in enumerate(outs):
        for ki, paths in inputs.items():
            for p in paths:
                if p and p != "-" and o != "-" and same_file(o, p):
                    raise InputError(f"{ko} {o} is also {ki}: it would be overwritten")
        for ko2, o2 in outs[i + 1:]:
            if same_file(o, o2):
                what = "standard output" if o == "-" else f"the same file {o}"
                raise InputError(f"{ko} and {ko2} are {what}")


def check_site_tables(site, source: str) -> None:
    """The site's ``[gateway]``, ``[output]`` and ``[estimator]`` tables as ``pfdoa replay``
    and ``pfdoa gateway`` check them (for commands that only carry them over)."""
    from pfdoa.gateway.config import gateway_config, output_config
    from pfdoa.gateway.setup import build_estimator

    gateway_config(site.sections, source)
    output_config(site.sections, source)
    build_estimator(site, None, 0, source)


class SignalStop:
    """While active, SIGINT and SIGTERM set :attr:`event` (the work loop checks it and stops
    at a record boundary) instead of killing the process; :attr:`signum` is the first one.
    A second signal while stopping restores the default action and raises it again, so an
    impatient user can still kill a stuck process."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, _frame) -> None:
        if self.event.is_set():
            signal.signal(signum, signal.SIG_DFL)
            signal.raise_signal(signum)
            return
        self.signum = signum
        self.event.set()

    def __enter__(self) -> "SignalStop":
        if threading.current_thread() is threading.main_thread():
            self._old = {s: signal.signal(s, self._handle) for s in self.SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}

    @property
    def stopped(self) -> bool:
        return self.event.is_set()

    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum else ""


class RaiseOnSignal:
    """While active, SIGINT and SIGTERM raise :class:`~pfdoa.errors.Interrupted` in the main
    thread, so ``finally`` blocks run (a temporary output is removed, the old file stays)
    and the command ends with one line and 128 + the signal's number. For commands whose
    output is written whole at the end (calibrate, eval); streams use :class:`SignalStop`."""

    def __init__(self, what: str) -> None:
        self.what = what
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, _frame) -> None:
        from pfdoa.errors import Interrupted

        raise Interrupted(signum, f"stopped by {signal.Signals(signum).name}: {self.what}")

    def __enter__(self) -> "RaiseOnSignal":
        if threading.current_thread() is threading.main_thread():
            self._old = {s: signal.signal(s, self._handle) for s in SignalStop.SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}


def input_counters(transports, odometry_reader=None) -> dict[str, Any]:
    """The inputs' own counters for the final line: capture files (malformed lines, times
    that jump, source names beyond the decoder table), CAN frames ignored, live odometry
    lines skipped. Only what is non-empty, so a plain run's counters stay short."""
    out: dict[str, Any] = {}
    for t in transports:
        stats = getattr(t, "counters", None)
        if callable(stats):
            c = stats()
            if c:
                out.setdefault("inputs", {})[t.name] = c
    if odometry_reader is not None:
        out["odometry_input"] = {"lines": odometry_reader.lines, "bad_lines": odometry_reader.bad_lines}
    return out


# A BLE advertiser sends at most every 20 ms: more readings than this per anchor and second in
# one window's value means the t column is not in seconds (a rate, so --window does not change it).
MAX_READING_RATE_HZ = 50.0


def combined_warning(summary: dict, grouper, source: str) -> str | None:
    """A sentence when the readings merged into each window's anchor values come faster than a
    radio reports (window mode). Fast reporters (BLE at tens of readings per anchor and
    second) are combined by design and not warned about; more than MAX_READING_RATE_HZ usually
    means times in a unit longer than the second (or truncated to whole seconds)."""
    combined = summary.get("combined")
    window = getattr(grouper, "window_s", None)
    if not combined or not window:
        return None
    dropped = summary.get("dropped", 0)  # beyond a window's bound: they arrived as fast
    placed = summary["readings"] - summary["unknown_anchor"] - summary["duplicates"] - dropped
    values = placed - combined  # one per anchor and window
    if values <= 0:
        return None
    rate = (placed + dropped) / values / window
    if rate <= MAX_READING_RATE_HZ:
        return None
    return (f"{source}: {combined} of {placed} readings ({100.0 * combined / placed:.0f} %) were combined with "
            f"another of the same anchor in the same {window:g} s window: {rate:.0f} readings per anchor and "
            f"second, more than a radio reports ({MAX_READING_RATE_HZ:g}); {summary['sets']} sets from "
            f"{placed} readings (check the t column's unit)")


def check_gateway_args(args, mqtt_inputs: tuple[str, ...] = ()) -> None:
    """``pfdoa gateway``'s option values (before anything is opened); ``mqtt_inputs``: the
    broker inputs asked for (``--mqtt-input`` or the site's ``[mqtt] inputs``)."""
    from pfdoa.gateway.decoding import MAX_DECODERS

    if not (args.serial or args.can or args.stdin or args.replay_capture or mqtt_inputs
            or getattr(args, "mqtt_input", None)):
        raise InputError("no input: give --serial, --can, --stdin, --replay-capture or --mqtt-input")
    check_seed(args.seed)
    check_number("--window", args.window)
    check_number("--duration", args.duration)
    check_number("--health", args.health, strict=False)
    streams = len(args.serial) + bool(args.stdin)
    if streams > MAX_DECODERS:
        raise InputError(f"{streams} byte-stream inputs: the gateway decodes at most {MAX_DECODERS} at once")
