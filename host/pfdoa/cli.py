"""The `pfdoa` command line.

Each subcommand is a module exposing ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``: the modules of :mod:`pfdoa.commands`, and modules other packages
register in the ``pfdoa.commands`` entry point group (the simulator's ``sim``:
``pfdoasim.command``; dependencies run one way, so this package never imports it). Both
are discovered, so adding a command never edits this file. Heavy imports belong inside
``run``. A registered command whose package is missing or broken still appears, and
running it says why in one line.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
from importlib import metadata
from typing import Any

from pfdoa import __version__
from pfdoa.errors import InputError, Interrupted, PfdoaError

log = logging.getLogger(__name__)

# Display order in --help; commands not listed follow alphabetically.
ORDER = ["gateway", "replay", "sim", "calibrate", "eval"]
ENTRY_POINTS = "pfdoa.commands"
# Commands other packages of this distribution provide: when the entry point is missing
# (the package is not installed) the command still exists and says so.
EXPECTED = {"sim": "the simulator (package pfdoasim)"}


class _Unavailable:
    """A stand-in command whose run() is one error line (exit 2)."""

    def __init__(self, name: str, why: str) -> None:
        self.name, self.why = name, why
        self.HELP = f"(unavailable: {why})"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.set_defaults(_any_arguments=True)  # whatever follows, the answer is run()'s one line

    def run(self, args: argparse.Namespace) -> int:
        raise InputError(f"pfdoa {self.name}: {self.why}")


def _registered() -> dict[str, Any]:
    """Commands registered by other packages (entry points), name -> module."""
    out: dict[str, Any] = {}
    for ep in metadata.entry_points(group=ENTRY_POINTS):
        if ep.name in out:
            continue  # the same distribution seen twice on sys.path: the first wins, as imports do
        try:
            out[ep.name] = ep.load()
        except Exception as exc:  # a broken plugin must not take the other commands down
            out[ep.name] = _Unavailable(ep.name, f"{ep.value} cannot be imported ({type(exc).__name__}: {exc})")
    for name, what in EXPECTED.items():
        if name not in out:
            out[name] = _Unavailable(name, f"{what} is not installed (pip install . from a pfdoa checkout)")
    return out


def _command_modules() -> list[tuple[str, Any]]:
    import pfdoa.commands as pkg

    mods = {m.name.replace("_", "-"): importlib.import_module(f"pfdoa.commands.{m.name}")
            for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_")}
    for name, mod in _registered().items():
        if name in mods:
            log.debug("command %s of %s ignored: pfdoa has its own", name, getattr(mod, "__name__", mod))
            continue
        mods[name] = mod
    names = sorted(mods, key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))
    return [(n, mods[n]) for n in names]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pfdoa",
        description="Indoor localization from the RSSI that anchors report, with a particle filter after "
        "PF-DOA: anchor gateway, estimators, simulator and evaluation.",
        epilog="Run 'pfdoa COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"pfdoa {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _command_modules():
        p = sub.add_parser(
            name,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def reserve_std_fds() -> list[str]:
    """Standard streams the process was started without (``<&- >&- 2>&-``), by name.

    Each closed descriptor 0/1/2 is pointed at /dev/null so that no file opened later gets
    its number (an output file on descriptor 1 would also receive everything printed);
    ``sys.stdin``/``sys.stdout`` stay None for the commands to refuse ``-`` with one line,
    and a closed standard error becomes /dev/null (``print(file=None)`` would go to stdout).
    """
    closed = []
    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        try:
            os.fstat(fd)
            continue
        except OSError:
            closed.append(name)
        null = os.open(os.devnull, os.O_RDWR)
        if null != fd:
            os.dup2(null, fd)
            os.close(null)
    if "stderr" in closed or sys.stderr is None:
        sys.stderr = open(2, "w", closefd=False)
    return closed


class RepeatFilter(logging.Filter):
    """Rate-limits log records by their message template: each may appear ``burst`` times
    (the last of them says so), then once per ``period_s`` of the records' own time stamps,
    with how many were suppressed meanwhile. A flood of one kind (a capture whose times
    jump makes every anchor stale again and again) then costs a few lines, never the log;
    the final counters hold the totals."""

    def __init__(self, burst: int = 10, period_s: float = 60.0, max_keys: int = 1024) -> None:
        super().__init__()
        self.burst = burst
        self.period_s = period_s
        self.max_keys = max_keys
        self._seen: dict[tuple[str, object], list] = {}  # template -> [count, suppressed, last shown]
        self.suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.msg)
        st = self._seen.get(key)
        if st is None:
            if len(self._seen) >= self.max_keys:  # bounded memory: start counting afresh
                self._seen.clear()
            st = self._seen[key] = [0, 0, record.created]
        st[0] += 1
        if st[0] < self.burst:
            st[2] = record.created
            return True
        if st[0] == self.burst:
            record.msg = f"{record.msg} (more like this: at most one per {self.period_s:g} s)"
            st[2] = record.created
            return True
        if record.created - st[2] < self.period_s:
            st[1] += 1
            self.suppressed += 1
            return False
        if st[1]:
            record.msg = f"{record.msg} ({st[1]} more like this suppressed)"
        st[1] = 0
        st[2] = record.created
        return True


def main(argv: list[str] | None = None) -> int:
    reserve_std_fds()
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and not getattr(args, "_any_arguments", False):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    level = logging.WARNING if args.quiet else (logging.INFO if args.verbose == 0 else logging.DEBUG)
    root = logging.getLogger()
    configured = bool(root.handlers)  # embedded (or under pytest): leave the host's handlers alone
    logging.basicConfig(level=level, format="pfdoa: %(levelname)s: %(message)s", stream=sys.stderr)
    if not configured:
        for handler in root.handlers:
            handler.addFilter(RepeatFilter())
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    from pfdoa.signals import Stop

    try:
        with Stop():  # SIGINT/SIGTERM: one mechanism for every command (pfdoa.signals)
            rc = int(args._run(args) or 0)
            _flush_stdout()
            return rc
    except (PfdoaError, Interrupted) as exc:
        _say_error(str(exc))
        return exc.exit_code
    except KeyboardInterrupt:  # raised by code outside the Stop (none should be)
        return 130
    except BrokenPipeError:
        _quiet_stdout()
        return 0


def _flush_stdout() -> None:
    """What a command printed on standard output reaches it, or the command fails with one
    line (a full disk behind ``> file``, ``> /dev/full``): never a traceback at exit."""
    from pfdoa.errors import OutputError

    if sys.stdout is None:
        return
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except (OSError, ValueError) as exc:
        _quiet_stdout()
        raise OutputError(f"standard output: cannot write: {getattr(exc, 'strerror', None) or exc}") from None


def _quiet_stdout() -> None:
    """Standard output failed: point it at /dev/null, so the interpreter's own flush at exit
    finds nothing to fail on (what was lost is said once, by the caller)."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.close(null)
    except OSError:
        pass


def _say_error(text: str) -> None:
    try:
        print(f"pfdoa: error: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
