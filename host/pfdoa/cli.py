"""The `pfdoa` command line.

Each subcommand is a module in :mod:`pfdoa.commands` exposing ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``; modules are discovered, so adding
a command never edits this file. Heavy imports belong inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys

from pfdoa import __version__
from pfdoa.errors import PfdoaError

# Display order in --help; commands not listed follow alphabetically.
ORDER = ["gateway", "replay", "sim", "calibrate", "eval", "bench"]


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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else (logging.INFO if args.verbose == 0 else logging.DEBUG)
    logging.basicConfig(level=level, format="pfdoa: %(levelname)s: %(message)s", stream=sys.stderr)
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
