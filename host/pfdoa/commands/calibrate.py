"""`pfdoa calibrate`: fit the radio model of a site to traces with ground truth."""

from __future__ import annotations

import argparse
import logging
import sys

HELP = "fit rssi_at_1m_dbm, path_loss_exponent and per-anchor offsets to traces with ground truth"
DESCRIPTION = """\
Fit the log-distance radio model RSSI = A - 10 n log10(d) + offset_anchor to every reading
of TRACE(s) that has ground truth (columns gt_x, gt_y) and write a complete site file with
the fitted values (anchor positions and ids kept). Offsets are fixed by a gauge: they sum
to zero (default) or --reference-anchor has offset 0. The fit is Huber-weighted iteratively
reweighted least squares (outliers weigh less; what `pfdoa eval` uses); --least-squares
fits plain least squares instead.

The site file is a site.toml, or a data folder's anchors.json ("anchors": [[x, y], ...],
the trace's anchor column indexing that list); the output is always a site.toml.
The fit residual (RMS dB, overall and per anchor) is printed on stdout.

example:
  pfdoa calibrate run1.csv --config site.toml --out site.fitted.toml
"""

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("traces", nargs="+", metavar="TRACE.csv", help="trace(s) with columns t,anchor,rssi_dbm,gt_x,gt_y")
    parser.add_argument("--config", required=True, metavar="SITE.toml", help="site file (anchor positions): site.toml or anchors.json")
    parser.add_argument("--out", metavar="FITTED.toml", help="write the fitted site file here (default: stdout)")
    fit = parser.add_mutually_exclusive_group()
    fit.add_argument("--robust", action="store_true", help="Huber IRLS (the default; kept for old scripts)")
    fit.add_argument("--least-squares", action="store_true", help="plain least squares instead of Huber IRLS")
    parser.add_argument("--reference-anchor", type=int, metavar="ID",
                        help="gauge: this anchor's offset is 0 (default: offsets sum to zero)")
    parser.add_argument("--no-offsets", action="store_true", help="fit A and n only (all offsets 0)")


def run(args: argparse.Namespace) -> int:
    from pfdoa.commands._common import RaiseOnSignal

    with RaiseOnSignal(f"{args.out} is left as it was" if args.out else "nothing written"):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from pfdoa.calibrate import calibrate_traces, trace_readings
    from pfdoa.commands._common import check_outputs, check_site_tables
    from pfdoa.errors import InputError
    from pfdoa.evaluation.datasets import load_site_cached
    from pfdoa.output import write_atomic
    from pfdoa.site import site_to_toml
    from pfdoa.trace import check_anchor_ids, read_trace, time_unit_warnings

    check_outputs({"--out": args.out}, {"a trace": args.traces, "--config": [args.config]})
    if args.out is None and sys.stdout is None:
        raise InputError("standard output is closed; give --out FITTED.toml")
    site = load_site_cached(str(args.config))
    # The tables carried over must be ones `pfdoa replay` and `pfdoa gateway` accept.
    check_site_tables(site, str(args.config))
    if args.reference_anchor is not None and args.reference_anchor not in site.anchor_ids:
        raise InputError(f"--reference-anchor {args.reference_anchor}: not an anchor of {args.config} "
                         f"(ids {', '.join(map(str, site.anchor_ids))})")
    traces = [read_trace(p) for p in args.traces]
    for tr in traces:
        if not tr.has_ground_truth:
            raise InputError(f"{tr.source}: no ground truth columns gt_x,gt_y; calibration needs them")
        for w in time_unit_warnings(tr.t, tr.source, tr.anchor):
            log.warning("%s", w)
        check_anchor_ids(tr, site.anchor_ids, str(args.config))
        trace_readings(tr, site)  # raises on a trace it cannot use
    fit = calibrate_traces(traces, site, offsets=not args.no_offsets,
                           reference_anchor=args.reference_anchor, robust=not args.least_squares)
    if not 0.5 <= fit.path_loss_exponent <= 10.0:
        print(fit.report(), file=sys.stderr)
        raise InputError(
            f"fitted path_loss_exponent {fit.path_loss_exponent:.3f} is outside [0.5, 10]: the readings barely "
            "follow distance (check anchor ids/positions against the ground truth, or record more spread)"
        )
    text = site_to_toml(fit.apply(site))  # the one site-file writer: every table of the input kept
    _check_loads(text)
    print(fit.report(), file=sys.stdout if args.out else sys.stderr)
    if args.out:
        write_atomic(args.out, text, "--out")  # never half a file, never the old one destroyed
        log.info("wrote %s", args.out)
    else:
        sys.stdout.write(text)
    return 0


def _check_loads(text: str) -> None:
    """What calibrate writes must load as `pfdoa replay` loads it (a bug here, not bad input)."""
    from pfdoa import _toml as tomllib
    from pfdoa.commands._common import check_site_tables
    from pfdoa.site import parse_site

    check_site_tables(parse_site(tomllib.loads(text), "<fitted>"), "<fitted>")
