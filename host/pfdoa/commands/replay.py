"""pfdoa replay: run a recorded trace through the gateway's reassembly and an estimator."""

from __future__ import annotations

import argparse
import logging

HELP = "replay a recorded RSSI trace (CSV) through reassembly and an estimator, offline"
DESCRIPTION = """\
Replay a recorded trace offline through the same reassembly and estimator code as
'pfdoa gateway', and write one position per synchronized anchor set.

TRACE.csv has a header with at least t,anchor,rssi_dbm (seconds, site anchor id, dBm);
other columns are ignored. With a seq column, readings are grouped by beacon sequence
(as live). Without one, they are grouped by time window: a window takes every reading for
--window seconds, an anchor's repeated readings in it are combined (median in dB), and its
estimate is stamped with the time of its last reading.

ODOM.csv (optional) has t,dx,dy,dtheta robot-frame increments, each covering the time
since the previous row; the motion between two estimates' times is composed from them
(the share of an increment that straddles an estimate's time is interpolated) and given
to the estimator with the later one.
"""
EPILOG = """\
examples:
  pfdoa replay host/pfdoa/data/herolab_wifi_robot/trial_exp2.csv.gz --config host/pfdoa/data/herolab_wifi_robot/site.toml
  pfdoa replay run1.csv --config site.toml --odom run1.odom.csv --method pf-doa --seed 1 --out run1.jsonl
  pfdoa replay run1.csv --config site.toml --method wcl --window 0.5 --format csv --out -

output fields: t x y sigma doa seq anchors missing stale rebooted r95 cov lost (see 'pfdoa gateway --help')
methods: {methods}
exit status: 0 ok, 1 output could not be written, 2 bad configuration or input file,
  130/143 stopped by SIGINT/SIGTERM (the estimates made until then are written, whole records)
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    try:
        from pfdoa.estimators import METHODS

        methods = ", ".join(METHODS)
    except ImportError:  # pragma: no cover - the estimators are part of the package
        methods = "see pfdoa.estimators"
    p.epilog = EPILOG.format(methods=methods)
    p.add_argument("trace", metavar="TRACE.csv", help="recorded readings: t,anchor,rssi_dbm[,seq] (.gz ok)")
    p.add_argument("--config", "-c", required=True, metavar="SITE.toml", help="site file (anchors, radio, [gateway], [estimator])")
    p.add_argument("--method", "-m", metavar="NAME", help="estimator (default: [estimator] method, else pf-doa)")
    p.add_argument("--odom", metavar="ODOM.csv", help="odometry increments t,dx,dy,dtheta")
    p.add_argument("--seed", type=int, default=0, help="random seed of the estimator (default 0)")
    p.add_argument("--window", type=float, metavar="S", help="time window in seconds when the trace has no seq (default: [gateway] window_s, 1.0)")
    p.add_argument("--mode", choices=("seq", "window"), help="grouping (default: seq when the trace has a seq column, else window)")
    p.add_argument("--out", "-o", metavar="PATH", help="output file, '-' for standard output (default: [output] path, -)")
    p.add_argument("--format", "-f", choices=("jsonl", "csv"), help="output format (default: [output] format, jsonl)")
    p.add_argument("--stats", metavar="PATH", help="also write the final counters as JSON to PATH")


def run(args: argparse.Namespace) -> int:
    from pfdoa.commands._common import (SignalStop, check_number, check_outputs, check_seed,
                                        combined_warning)
    from pfdoa.errors import InputError, Interrupted
    from pfdoa.gateway.odomsource import odometry_buffer
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.gateway.setup import build_pipeline, load_settings
    from pfdoa.output import write_stats
    from pfdoa.trace import (check_anchor_ids, odometry_overlap_warning, read_odometry, read_trace,
                             time_unit_warnings)

    log = logging.getLogger("pfdoa.replay")
    check_seed(args.seed)
    check_number("--window", args.window)
    st = load_settings(args.config, args.out, args.format)
    check_outputs({"--out": st.output.path, "--stats": args.stats},
                  {"the trace": [args.trace], "--config": [args.config], "--odom": [args.odom] if args.odom else []})
    trace = read_trace(args.trace)
    for w in time_unit_warnings(trace.t, args.trace, trace.anchor):
        log.warning("%s", w)
    check_anchor_ids(trace, st.site.anchor_ids, args.config)
    odom = None
    if args.odom:
        od = read_odometry(args.odom)
        for w in time_unit_warnings(od.t, args.odom) + [odometry_overlap_warning(od.t, trace.t, args.odom)]:
            if w:
                log.warning("%s", w)
        odom = odometry_buffer(od)
    mode = args.mode or ("seq" if trace.seq is not None else "window")
    if mode == "seq" and trace.seq is None:
        raise InputError(f"{args.trace}: --mode seq needs a seq column")
    pipe = build_pipeline(st, method=args.method, seed=args.seed, mode=mode, window_s=args.window,
                          odometry=odom, tolerate_errors=False)
    grouper, loc = pipe.grouper, pipe.localizer
    t, anchor, rssi = trace.t.tolist(), trace.anchor.tolist(), trace.rssi_dbm.tolist()
    seq = trace.seq.tolist() if mode == "seq" else None
    last_t = None
    done = 0
    # SIGINT/SIGTERM stop the loop between readings; what was estimated is then written
    # (the output is closed in `finally`), the counters too, and the exit status says so.
    with SignalStop() as sig:
        try:
            for i in range(len(t)):
                if sig.stopped:
                    break
                if mode == "seq" and t[i] != last_t:
                    loc.handle_all(grouper.poll(t[i]))
                    last_t = t[i]
                r = Reading(int(anchor[i]), rssi[i], t[i], None if seq is None else int(seq[i]) & 0xFFFF)
                loc.handle_all(grouper.push(r))
                done = i + 1
            if not sig.stopped:
                loc.handle_all(grouper.flush())
                loc.finish()
        finally:
            pipe.close()
    summary = pipe.summary()
    summary["mode"] = mode
    summary["method"] = loc.estimator.name or args.method
    if sig.stopped:
        summary["interrupted"] = {"signal": sig.name(), "readings_done": done, "readings": len(t)}
    if pipe.localizer.output_error is not None:
        summary["output_error"] = str(pipe.localizer.output_error.strerror or pipe.localizer.output_error)
    if args.stats:
        write_stats(args.stats, summary)
    log.info("replay %s: %d readings, %d sets (%s), %d estimates, %d unknown-anchor readings%s",
             args.trace, summary["readings"], summary["sets"], mode, summary["estimates"], summary["unknown_anchor"],
             f", {summary['combined']} combined, {summary['dropped']} dropped" if "combined" in summary else "")
    w = combined_warning(summary, grouper, args.trace)
    if w:
        log.warning("%s", w)
    if pipe.localizer.output_error is not None:
        from pfdoa.errors import PfdoaError

        raise PfdoaError(f"--out {st.output.path}: cannot write: {summary['output_error']}")
    if sig.stopped:
        raise Interrupted(sig.signum, f"stopped by {sig.name()} after {done} of {len(t)} readings; the "
                                      f"{summary['estimates']} estimates made are written to {st.output.path}")
    return 0
