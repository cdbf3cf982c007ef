"""`pfdoa calibrate`: fit the radio model of a site to traces with ground truth."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys

HELP = "fit rssi_at_1m_dbm, path_loss_exponent and per-anchor offsets to traces with ground truth"
DESCRIPTION = """\
Fit the log-distance radio model RSSI = A - 10 n log10(d) + offset_anchor to every reading
of TRACE(s) that has ground truth (columns gt_x, gt_y) and write a complete site file with
the fitted values (anchor positions and ids kept). Offsets are fixed by a gauge: they sum
to zero (default) or --reference-anchor has offset 0. The fit is Huber-weighted iteratively
reweighted least squares (outliers weigh less; what `pfdoa eval` uses); --least-squares
fits plain least squares instead. Readings that cannot separate every parameter fit fewer,
and the report says so: a static beacon (one distance per anchor, which the offsets alone
could explain) fits A and n without offsets; readings all at one distance fit A alone, with
n kept from the site file. Readings that barely follow distance (a fitted n between 0 and
0.5, the lowest a site file takes) get n = 0.5 and A and the offsets fitted with it; a fit
where the readings rise with distance is refused (usually anchor ids or positions that do
not match the ground truth).

The site file is a site.toml, or a data folder's anchors.json ("anchors": [[x, y], ...],
the trace's anchor column indexing that list); the output is always a site.toml.
The fit residual (RMS dB, overall and per anchor) is printed on stdout.

pf-doa's reported uncertainty (r95, cov) needs nothing from the calibration: it follows the
model's running misfit online. One walk through the room is a calibration; more walks fit
the same model on more readings.

Several beacons: a trace with a beacon column (t,...,beacon) may name several transmitters,
each reading with its own ground truth. The radio model is fitted on all their readings
together; the radio map's time windows group each beacon's readings alone.

Radio map: walls and furniture shadow an anchor over a region, the same way each time the
target is there. The residuals of the fit (per anchor, over --window time windows) are
smoothed over the floor (1 m kernel) into a [radio_map] table that pf-doa adds to its model,
scaled by its trust: the share of the map's fit that still predicts 30 s blocks of the traces
it was not fitted on. A walk that passes each place once cannot show that its residuals
repeat: then no map is written (the report says so). --no-radio-map never writes one.

examples:
  pfdoa calibrate run1.csv --config site.toml --out site.fitted.toml
  pfdoa calibrate run1.csv run2.csv --config site.toml --out site.fitted.toml
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
    parser.add_argument("--window", type=float, metavar="S",
                        help="time window (s) for the radio map (default: [gateway] window_s, else 1, or the traces' "
                             "reporting interval when longer, then written as [gateway] window_s)")
    # Retired with the uncertainty factors they served (issue 47): accepted, warned, ignored.
    parser.add_argument("--odom", action="append", default=[], help=argparse.SUPPRESS)
    parser.add_argument("--mode", help=argparse.SUPPRESS)
    parser.add_argument("--no-uncertainty", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--no-radio-map", action="store_true",
                        help="write no [radio_map] (the residual map pf-doa adds to the model; see above)")


def run(args: argparse.Namespace) -> int:
    from pfdoa.commands._common import RaiseOnSignal

    with RaiseOnSignal(f"{args.out} is left as it was" if args.out else "nothing written"):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from pfdoa.calibrate import calibrate_traces, trace_readings
    from pfdoa.commands._common import check_number, check_outputs, check_site_tables
    from pfdoa.errors import InputError
    from pfdoa.evaluation.datasets import load_site_cached
    from pfdoa.output import write_atomic
    from pfdoa.site import MAX_PATH_LOSS_EXPONENT, MIN_PATH_LOSS_EXPONENT, site_to_toml
    from pfdoa.trace import DEFAULT_WINDOW_S, check_anchor_ids, read_trace, time_unit_warnings

    check_outputs({"--out": args.out}, {"a trace": args.traces, "--config": [args.config]})
    retired = [f for f, v in (("--odom", args.odom), ("--mode", args.mode), ("--no-uncertainty", args.no_uncertainty))
               if v]
    if retired:
        log.warning("%s: retired (pfdoa calibrate measures no uncertainty factors: pf-doa's own follow its misfit "
                    "online); ignored", ", ".join(retired))
    if args.out is None and sys.stdout is None:
        raise InputError("standard output is closed; give --out FITTED.toml")
    site = load_site_cached(str(args.config))
    # The tables carried over must be ones `pfdoa replay` and `pfdoa gateway` accept.
    check_site_tables(site, str(args.config))
    if args.reference_anchor is not None and args.reference_anchor not in site.anchor_ids:
        raise InputError(f"--reference-anchor {args.reference_anchor}: not an anchor of {args.config} "
                         f"(ids {', '.join(map(str, site.anchor_ids))})")
    check_number("--window", args.window)
    traces = [read_trace(p) for p in args.traces]
    for tr in traces:
        if not tr.has_ground_truth:
            raise InputError(f"{tr.source}: no ground truth columns gt_x,gt_y; calibration needs them")
        for w in time_unit_warnings(tr.t, tr.source, tr.anchor):
            log.warning("%s", w)
        check_anchor_ids(tr, site.anchor_ids, str(args.config))
        trace_readings(tr, site)  # raises on a trace it cannot use
    window_s, chosen = (args.window, False) if args.window else _window_s(site, traces)
    fit = calibrate_traces(traces, site, offsets=not args.no_offsets, reference_anchor=args.reference_anchor,
                           robust=not args.least_squares, radio_map=not args.no_radio_map, window_s=window_s)
    if fit.note:
        log.warning("%s", fit.note)
    if not MIN_PATH_LOSS_EXPONENT <= fit.path_loss_exponent <= MAX_PATH_LOSS_EXPONENT:
        # A positive fit below the minimum is held there (fit.note); this is a falling or
        # absurd one: the readings do not follow distance as the positions say.
        print(fit.report(), file=sys.stderr)
        raise InputError(
            f"fitted path_loss_exponent {fit.path_loss_exponent:.3f} is outside [{MIN_PATH_LOSS_EXPONENT:g}, "
            f"{MAX_PATH_LOSS_EXPONENT:g}]: the readings do not follow distance (check anchor ids/positions "
            "against the ground truth, or record more spread)"
        )
    fitted = fit.apply(site)
    if chosen and window_s != DEFAULT_WINDOW_S:
        # replay and the gateway then group this site's readings as the fit did
        gateway = {**site.sections.get("gateway", {}), "window_s": window_s}
        fitted = dataclasses.replace(fitted, sections={**fitted.sections, "gateway": gateway})
    report = fit.report()
    if window_s != DEFAULT_WINDOW_S:
        report += f"\ntime windows: {window_s:g} s"
    text = site_to_toml(fitted)  # the one site-file writer: every table of the input kept
    _check_loads(text)
    print(report, file=sys.stdout if args.out else sys.stderr)
    if args.out:
        write_atomic(args.out, text, "--out")  # never half a file, never the old one destroyed
        log.info("wrote %s", args.out)
    else:
        sys.stdout.write(text)
    return 0


def _window_s(site, traces) -> tuple[float, bool]:
    """The site's [gateway] window_s (validated there), else the traces' reporting window;
    and whether it was chosen here (then it is written into the fitted site)."""
    from pfdoa.gateway.config import gateway_config
    from pfdoa.trace import reporting_window

    if "window_s" in site.sections.get("gateway", {}):
        return gateway_config(site.sections).window_s, False
    return reporting_window(traces), True


def _check_loads(text: str) -> None:
    """What calibrate writes must load as `pfdoa replay` loads it (a bug here, not bad input)."""
    from pfdoa import _toml as tomllib
    from pfdoa.commands._common import check_site_tables
    from pfdoa.site import parse_site

    check_site_tables(parse_site(tomllib.loads(text), "<fitted>"), "<fitted>")
