"""Checks the commands share: option values, outputs against inputs, site tables.

Not a command (``pfdoa.cli`` skips modules starting with ``_``). Every check raises
:class:`~pfdoa.errors.InputError` or :class:`~pfdoa.errors.ConfigError`: one line naming
the option or the file and key, exit status 2.
"""

from __future__ import annotations

import math
import os
import stat
from typing import Any

from pfdoa.errors import InputError

SEED_MAX = 2**128  # numpy's SeedSequence takes any non-negative integer; beyond this is a typo


def add_input_options(group, input_help: str, stdin_help: str) -> None:
    """``--input SPEC`` (pfdoa.gateway.inputs) and the older spellings both commands take:
    ``--serial``, ``--can``, ``--stdin``."""
    group.add_argument("--input", "-i", action="append", default=[], metavar="SPEC",
                       help=f"an input as KIND:ARGUMENT ({input_help}); repeat for several")
    group.add_argument("--serial", "-s", action="append", default=[], metavar="URL[@BAUD]",
                       help="serial port or pyserial URL (= --input serial:URL); repeat for several")
    group.add_argument("--can", action="append", default=[], metavar="SPEC",
                       help="CAN bus through python-can (= --input can:SPEC); repeat for several")
    group.add_argument("--stdin", action="store_true", help=f"{stdin_help} (= --input stdin)")


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


def _identity(path: str, fd: int) -> tuple[int, int] | None:
    """(device, inode) of a regular file or FIFO at ``path`` ("-": descriptor ``fd``);
    None for what is not there and for devices (a terminal or /dev/null may be read and
    written at once)."""
    try:
        st = os.fstat(fd) if path == "-" else os.stat(path)
    except (OSError, ValueError):
        return None
    return (st.st_dev, st.st_ino) if stat.S_ISREG(st.st_mode) or stat.S_ISFIFO(st.st_mode) else None


def _same(a: str, b: str, a_fd: int, b_fd: int) -> bool:
    ia, ib = _identity(a, a_fd), _identity(b, b_fd)
    if ia is not None or ib is not None:
        return ia == ib
    if "-" in (a, b):  # standard output twice; standard input and output are two streams
        return a == b and a_fd == b_fd
    try:
        if stat.S_ISCHR(os.stat(a).st_mode):  # /dev/null twice is fine
            return False
    except (OSError, ValueError):
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def check_outputs(outputs: dict[str, str | None], inputs: dict[str, list[str]], stdin: bool = False) -> None:
    """An output that is also an input of the run (or another output) would destroy it:
    InputError (exit 2), before anything is opened.

    Files are compared by device and inode, so a symbolic or hard link, /dev/stdin and the
    file standard input or output is redirected from are caught too: "-" as an output is
    standard output, as an input (or with ``stdin``: the run reads standard input) standard
    input (``pfdoa gateway --stdin --stats X < X`` would truncate its own input). Devices
    may be both (a terminal); "-" may be one output only."""
    outs = [(k, v) for k, v in outputs.items() if v]
    ins = [(k, p) for k, paths in inputs.items() for p in paths if p]
    if stdin:
        ins.append(("standard input", "-"))
    for i, (ko, o) in enumerate(outs):
        for ki, p in ins:
            if _same(o, p, 1, 0):
                where = "standard output" if o == "-" else o
                what = ki if p != "-" or ki == "standard input" else f"{ki} (standard input)"
                raise InputError(f"{ko} {where} is also {what}: it would be overwritten")
        for ko2, o2 in outs[i + 1:]:
            if _same(o, o2, 1, 1):
                what = "standard output" if "-" in (o, o2) else f"the same file {o}"
                raise InputError(f"{ko} and {ko2} are {what}")


def check_site_tables(site, source: str) -> None:
    """The site's ``[gateway]``, ``[output]`` and ``[estimator]`` tables as ``pfdoa replay``
    and ``pfdoa gateway`` check them (for commands that only carry them over)."""
    from pfdoa.gateway.setup import build_estimator
    from pfdoa.readings.config import gateway_config, output_config

    gateway_config(site.sections, source)
    output_config(site.sections, source)
    build_estimator(site, None, 0, source)


def input_counters(transports, odometry_reader=None) -> dict[str, Any]:
    """The inputs' own counters for the final line: capture files (malformed lines, times
    that jump), CAN frames ignored, live odometry lines skipped, the MQTT inputs'. Only what is non-empty, so a plain run's counters stay short."""
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


def check_gateway_args(args, specs: list) -> None:
    """``pfdoa gateway``'s option values (before anything is opened); ``specs``: its
    inputs (:func:`pfdoa.gateway.inputs.specs_from_args`, with the site's ``[mqtt] inputs``)."""
    if not specs:
        raise InputError("no input: give --input SPEC (serial:URL, can:INTERFACE:CHANNEL, stdin, capture:FILE, "
                         "mqtt:KIND; or --serial, --can, --stdin, --replay-capture, --mqtt-input)")
    check_seed(args.seed)
    check_number("--window", args.window)
    check_number("--duration", args.duration)
    check_number("--health", args.health, strict=False)
    check_number("--wait-for-device", getattr(args, "wait_for_device", None), strict=False)
