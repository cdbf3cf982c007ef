"""The `pfdoa` command line.

Each subcommand is a module in :mod:`pfdoa.commands` exposing ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``; modules are discovered, so adding
a command never edits this file. Heavy imports belong inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys

from pfdoa import __version__
from pfdoa.errors import PfdoaError

# Display order in --help; commands not listed follow alphabetically.
ORDER = ["gateway", "replay", "sim", "calibrate", "eval"]


def _command_modules() -> list[tuple[str, object]]:
    import pfdoa.commands as pkg

    names = [m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_")]
    names.sort(key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))
    return [(n.replace("_", "-"), importlib.import_module(f"pfdoa.commands.{n}")) for n in names]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pfdoa",
        description="Indoor localization from the direction of arrival (DOA) of RSSI: "
        "anchor gateway, PF-DOA estimator, simulator and evaluation.",
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
    args = parser.parse_args(argv)
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
    try:
        return int(args._run(args) or 0)
    except PfdoaError as exc:
        print(f"pfdoa: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
