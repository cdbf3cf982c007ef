"""`pfdoa calibrate`: fit the radio model of a site to traces with ground truth."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys

HELP = ("fit rssi_at_1m_dbm, path_loss_exponent and per-anchor offsets to traces with ground truth, "
        "or to the anchors hearing each other (--from-anchors)")
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

Without a walk (--from-anchors RECORDING): anchors whose filter table has the anchors' entry
([[beacons]] kind = "anchors", set by `pfdoa anchors filters`) send their own advertisement
and report each other's (protocol/SPEC.md 3.5). RECORDING is a capture of the gateway's
input (`pfdoa gateway --capture FILE`, or `pfdoa sim --transport timed`); its peer readings
and the anchors' positions (3-D where the site has heights) fit the path loss and every
anchor's receive and transmit offsets (docs/anchors.md): the receive offsets become
rssi_offset_db, A is the anchors' own, taken for the beacon's (it transmits like an average
anchor; --beacon-tx-db says by how much it is stronger). Nothing else of the site changes.
The fit is reported with its standard errors; one that is not well-conditioned (too few
links, n or an offset poorly determined) is written with a warning: the gateway would not
use it live. With TRACE.csv files too, the walk's fit is held near the peer fit (the peer
fit's predictions join the readings as a prior), and the site's anchors' entry gets
apply = false: the walk's fit is the better one, the gateway's live peer fit only reports.

examples:
  pfdoa calibrate run1.csv --config site.toml --out site.fitted.toml
  pfdoa calibrate run1.csv run2.csv --config site.toml --out site.fitted.toml
  pfdoa calibrate --from-anchors live.cap --config site.toml --out site.fitted.toml
  pfdoa calibrate walk.csv --from-anchors live.cap --config site.toml --out site.fitted.toml

exit status: 0 ok, 1 an output could not be written, 2 bad configuration or input file,
  130/143 stopped by SIGINT/SIGTERM (--out is left as it was)
"""

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("traces", nargs="*", metavar="TRACE.csv",
                        help="trace(s) with columns t,anchor,rssi_dbm,gt_x,gt_y (or none, with --from-anchors)")
    parser.add_argument("--from-anchors", action="append", default=[], metavar="RECORDING",
                        help="a capture file (pfdoa gateway --capture) with the anchors' peer readings: fit the model "
                             "to the anchors hearing each other; repeat for several")
    parser.add_argument("--beacon-tx-db", type=float, default=0.0, metavar="DB",
                        help="with --from-anchors: how much stronger the beacon transmits than an average anchor "
                             "(default 0: the same radio at the same power)")
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
    from numpy.linalg import LinAlgError

    from pfdoa.errors import InputError, Interrupted

    # SIGINT/SIGTERM raise Interrupted at once (pfdoa.signals): the site file is written whole
    # at the end, so stopping on the way leaves --out as it was.
    try:
        return _run(args)
    except Interrupted as exc:
        raise Interrupted(exc.signum, f"{exc}: {args.out} is left as it was" if args.out else f"{exc}: nothing "
                          "written") from None
    except LinAlgError as exc:  # numbers that pass every check but still defeat the fit
        raise InputError(f"the fit failed on these traces ({exc}): check the positions and the ground truth "
                         "for absurd values") from None


def _run(args: argparse.Namespace) -> int:
    from pfdoa.errors import InputError

    retired = [f for f, v in (("--odom", args.odom), ("--mode", args.mode), ("--no-uncertainty", args.no_uncertainty))
               if v]
    if retired:
        log.warning("%s: retired (pfdoa calibrate measures no uncertainty factors: pf-doa's own follow its misfit "
                    "online); ignored", ", ".join(retired))
    if not args.traces and not args.from_anchors:
        raise InputError("give TRACE.csv files with ground truth, or --from-anchors RECORDING (or both)")
    if not args.traces:
        return _from_anchors(args)
    return _walk(args)


def _peer_fit(args: argparse.Namespace, site):
    """The peer fit of --from-anchors (InputError when the recordings hold none, or too little)."""
    from pfdoa.calibration.peercal import fit_peers
    from pfdoa.errors import InputError
    from pfdoa.gateway.peers import read_captures

    if not abs(args.beacon_tx_db) <= 40.0:  # NaN too
        raise InputError(f"--beacon-tx-db must be a number within +-40 dB, got {args.beacon_tx_db:g}")
    readings, info = read_captures(args.from_anchors, site)
    if readings.readings == 0:
        what = (f"{info['peer_readings']} peer readings, none from two anchors of the site"
                if info["peer_readings"] else f"no peer readings ({info['reports']} reports in {info['chunks']} chunks)")
        raise InputError(f"--from-anchors {', '.join(args.from_anchors)}: {what}; the anchors send and report them "
                         "with the anchors' entry in their filter table ([[beacons]] kind = \"anchors\", "
                         "pfdoa anchors filters)")
    fit = fit_peers(site, readings, robust=not args.least_squares)
    if not fit.conditioned:
        log.warning("the peer fit is not well-conditioned (%s): the gateway would not use it live", fit.reason)
    return fit


def _from_anchors(args: argparse.Namespace) -> int:
    """--from-anchors alone: the peer fit, written into the site."""
    from pfdoa.commands._common import check_outputs, check_site_tables
    from pfdoa.errors import InputError
    from pfdoa.evaluation.datasets import load_site_cached
    from pfdoa.site import site_to_toml

    for opt, given in (("--reference-anchor", args.reference_anchor is not None),
                       ("--no-offsets", args.no_offsets), ("--window", args.window)):
        if given:
            raise InputError(f"{opt} belongs to a walk's fit: give TRACE.csv files too, or leave it out")
    check_outputs({"--out": args.out}, {"--from-anchors": args.from_anchors, "--config": [args.config]})
    if args.out is None and sys.stdout is None:
        raise InputError("standard output is closed; give --out FITTED.toml")
    site = load_site_cached(str(args.config))
    check_site_tables(site, str(args.config))
    fit = _peer_fit(args, site)
    text = site_to_toml(fit.apply(site, args.beacon_tx_db))  # the one site-file writer
    _check_loads(text)
    report = fit.report() + (f"\nbeacon: transmits {args.beacon_tx_db:+g} dB against an average anchor"
                             f" (rssi_at_1m_dbm {fit.rssi_at_1m_dbm + args.beacon_tx_db:.2f})")
    _write_site(args.out, text, report)
    return 0


def _walk_calibrated(site):
    """``site`` with its anchors' entry (if any) set to apply = false: a walk calibrated it."""
    beacons = site.sections.get("beacons")
    if not isinstance(beacons, list) or not any(isinstance(e, dict) and e.get("kind") == "anchors" for e in beacons):
        return site
    entries = [{**e, "apply": False} if isinstance(e, dict) and e.get("kind") == "anchors" else e for e in beacons]
    return dataclasses.replace(site, sections={**site.sections, "beacons": entries})


def _walk(args: argparse.Namespace) -> int:
    from pfdoa.calibration.calibrate import calibrate_traces, trace_readings
    from pfdoa.commands._common import check_number, check_outputs, check_site_tables
    from pfdoa.errors import InputError
    from pfdoa.evaluation.datasets import load_site_cached
    from pfdoa.site import MAX_PATH_LOSS_EXPONENT, MIN_PATH_LOSS_EXPONENT, site_to_toml
    from pfdoa.trace import DEFAULT_WINDOW_S, check_anchor_ids, read_trace, time_unit_warnings

    check_outputs({"--out": args.out}, {"a trace": args.traces, "--config": [args.config],
                                        "--from-anchors": args.from_anchors})
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
    prior = None
    if args.from_anchors:  # the walk's fit held near the anchors' own (pfdoa.calibration.peercal.prior_readings)
        from pfdoa.calibration.peercal import prior_readings

        peer = _peer_fit(args, site)
        print(peer.report(), file=sys.stderr)
        prior = prior_readings(peer, site, beacon_tx_db=args.beacon_tx_db)
    fit = calibrate_traces(traces, site, offsets=not args.no_offsets, reference_anchor=args.reference_anchor,
                           robust=not args.least_squares, radio_map=not args.no_radio_map, window_s=window_s,
                           prior=prior)
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
    fitted = _walk_calibrated(fit.apply(site))
    if chosen and window_s != DEFAULT_WINDOW_S:
        # replay and the gateway then group this site's readings as the fit did
        gateway = {**site.sections.get("gateway", {}), "window_s": window_s}
        fitted = dataclasses.replace(fitted, sections={**fitted.sections, "gateway": gateway})
    report = fit.report()
    if window_s != DEFAULT_WINDOW_S:
        report += f"\ntime windows: {window_s:g} s"
    text = site_to_toml(fitted)  # the one site-file writer: every table of the input kept
    _check_loads(text)
    _write_site(args.out, text, report)
    return 0


def _write_site(out: str | None, text: str, report: str) -> None:
    """The fitted site file to ``out`` with the report on stdout, or the file to stdout and
    the report to stderr."""
    from pfdoa.outfiles import stdout_guard, write_stdout, write_whole

    if out:
        write_whole(out, text, "--out")  # never half a file, never the old one destroyed, a device written through
        log.info("wrote %s", out)
        with stdout_guard("the report"):
            print(report)
    else:
        print(report, file=sys.stderr)
        write_stdout(text, "the fitted site file")


def _window_s(site, traces) -> tuple[float, bool]:
    """The site's [gateway] window_s (validated there), else the traces' reporting window;
    and whether it was chosen here (then it is written into the fitted site)."""
    from pfdoa.readings.config import gateway_config
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
