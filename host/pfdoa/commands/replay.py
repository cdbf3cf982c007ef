"""pfdoa replay: run a recorded trace, or a gateway's recording, through reassembly and an estimator."""

from __future__ import annotations

import argparse
import logging

REPLAY_BLOCK = 65536  # trace rows turned into Python values at a time
HELP = "replay a recorded RSSI trace (CSV) or a gateway recording (MCAP) through reassembly and an estimator"
DESCRIPTION = """\
Replay a recorded trace offline through the same reassembly and estimator code as
'pfdoa gateway', and write one position per synchronized anchor set.

TRACE.csv has a header with at least t,anchor,rssi_dbm (seconds, site anchor id, dBm);
other columns are ignored. With a seq column, readings are grouped by beacon sequence
(as live). Without one, they are grouped by time window: a window takes every reading for
--window seconds, an anchor's repeated readings in it are combined (median in dB), and its
estimate is stamped with the time of its last reading. With a beacon column (a named
beacon's id per reading, as 'pfdoa gateway --readings-out' writes for ESPresense devices;
empty = the site's one beacon) every beacon gets its own window grouper and estimator,
seeded from --seed and its id as the gateway seeds it, the timers run to each reading's
time after it (the gateway's rule for message time), and every record carries its beacon.

ODOM.csv (optional) has t,dx,dy,dtheta robot-frame increments, each covering the time
since the previous row; the motion between two estimates' times is composed from them
(the share of an increment that straddles an estimate's time is interpolated) and given
to the estimator with the later one.

RUN.mcap, a recording of 'pfdoa gateway --record' (or 'pfdoa replay --record'), holds its
site file, estimator, seed, grouping, the readings with their event times, the odometry
and the times the gateway's timers ran, in the order the gateway processed them: its
replay runs them exactly as the gateway did and writes the same estimates (--config,
--method, --seed, --mode, --window, --odom override what it holds); readings that name a
beacon go to that beacon's own estimator, as in the gateway.
"""
EPILOG = """\
examples:
  pfdoa replay host/pfdoa/data/herolab_wifi_robot/trial_exp2.csv.gz --config host/pfdoa/data/herolab_wifi_robot/site.toml
  pfdoa replay run1.csv --config site.toml --odom run1.odom.csv --method pf-doa --seed 1 --out run1.jsonl
  pfdoa replay run1.csv --config site.toml --method wcl --window 0.5 --format csv --out -
  pfdoa replay run.mcap --out again.jsonl        (a gateway's recording: its estimates again)
  pfdoa replay run1.csv --config site.toml --record run1.mcap --readings-out run1.readings.csv

output fields: t x y sigma doa seq anchors missing stale rebooted r95 cov lost frame_id stamp
  beacon heading heading_var room room_p floor floor_p (see 'pfdoa gateway --help'); beacon
  when the trace or recording names beacons, room and floor when the site has [[rooms]], [[floors]]
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
    p.add_argument("trace", metavar="TRACE.csv|RUN.mcap",
                   help="recorded readings: t,anchor,rssi_dbm[,seq][,beacon] (.gz ok), or a gateway recording "
                        "(.mcap)")
    p.add_argument("--config", "-c", metavar="SITE.toml",
                   help="site file (anchors, radio, [gateway], [estimator]); a recording holds its own")
    p.add_argument("--method", "-m", metavar="NAME", help="estimator (default: [estimator] method, else pf-doa)")
    p.add_argument("--odom", metavar="ODOM.csv", help="odometry increments t,dx,dy,dtheta")
    p.add_argument("--seed", type=int, default=None, help="random seed of the estimator (default 0; a recording's own)")
    p.add_argument("--window", type=float, metavar="S", help="time window in seconds when the trace has no seq (default: [gateway] window_s, 1.0)")
    p.add_argument("--mode", choices=("seq", "window"), help="grouping (default: seq when the trace has a seq column, else window)")
    p.add_argument("--out", "-o", metavar="PATH", help="output file, '-' for standard output (default: [output] path, -)")
    p.add_argument("--format", "-f", choices=("jsonl", "csv"), help="output format (default: [output] format, jsonl)")
    p.add_argument("--stats", metavar="PATH", help="also write the final counters as JSON to PATH")
    from pfdoa.sinks import options as sink_options

    sink_options.add_arguments(p, ("record", "readings-out"))


# Not an input kind (pfdoa.gateway.inputs: streams the runner reads on its clock): decoded readings, own times.
def _is_recording(path: str) -> bool:
    return str(path).endswith(".mcap")


def run(args: argparse.Namespace) -> int:
    from pfdoa import signals
    from pfdoa.commands._common import check_number, check_outputs, check_seed, combined_warning
    from pfdoa.errors import InputError, OutputError
    from pfdoa.gateway.setup import load_settings
    from pfdoa.output import write_stats
    from pfdoa.sinks import options as sink_options

    log = logging.getLogger("pfdoa.replay")
    check_seed(args.seed)
    check_number("--window", args.window)
    recording = None
    if _is_recording(args.trace):
        from pfdoa.sinks import sink_class

        sink_class("mcap")  # a missing 'ros' extra is one line here
        from pfdoa.sinks.mcap import open_recording

        recording = open_recording(args.trace)
        if recording.cut:  # a gateway killed (or a power cut) before it finished the file
            ext = recording.extent
            log.warning("%s: the recording was cut (its writer never finished it): replayed up to its last "
                        "complete chunk, %d of its %d bytes; the sets still open there are not estimated, as "
                        "the gateway had not", args.trace, ext.complete, ext.size)
        st = load_settings(args.config, args.out, args.format) if args.config else \
            load_settings(f"{args.trace}:site_toml", args.out, args.format, site=_recorded_site(recording))
    elif args.config is None:
        raise InputError(f"{args.trace}: a trace needs --config SITE.toml (only a .mcap recording holds its site)")
    else:
        st = load_settings(args.config, args.out, args.format)
    check_outputs({"--out": st.output.path, "--stats": args.stats, **sink_options.output_paths(args)},
                  {"the trace": [args.trace], "--config": [args.config] if args.config else [],
                   "--odom": [args.odom] if args.odom else [], **sink_options.input_paths(args)})
    # SIGINT/SIGTERM stop the loop between readings; what was estimated is then written
    # (the output is closed by the replay), the counters too, and the exit status says so
    # (pfdoa.signals; reading the files and waiting for a FIFO's reader end at once).
    sig = signals.active()
    with sig.graceful():  # to the written counters: a signal after the loop does not cut them
        if recording is not None:
            pipe, mode, done, total = _replay_recording(args, st, recording, sig)
        else:
            pipe, mode, done, total = _replay_trace(args, st, sig, log)
        grouper = pipe.grouper
        summary = pipe.summary()
        summary["mode"] = mode
        summary["method"] = pipe.localizer.estimator.name or args.method
        if sig.stopped:
            summary["interrupted"] = {"signal": sig.name(), "readings_done": done, "readings": total}
        if recording is not None and recording.cut:
            summary["cut"] = {"bytes": recording.extent.size, "bytes_read": recording.extent.complete}
        if pipe.localizer.output_error is not None:
            summary["output_error"] = str(pipe.localizer.output_error.strerror or pipe.localizer.output_error)
        if pipe.sinks is not None and pipe.sinks.failed:
            summary["sink_errors"] = dict(pipe.sinks.failed)
        if args.stats:
            write_stats(args.stats, summary)
        log.info("replay %s: %d readings, %d sets (%s), %d estimates, %d unknown-anchor readings%s",
                 args.trace, summary["readings"], summary["sets"], mode, summary["estimates"], summary["unknown_anchor"],
                 f", {summary['combined']} combined, {summary['dropped']} dropped" if "combined" in summary else "")
        w = combined_warning(summary, grouper, args.trace)
        if w:
            log.warning("%s", w)
    if pipe.localizer.output_error is not None:
        raise OutputError(f"--out {st.output.path}: cannot write: {summary['output_error']}")
    if "sink_errors" in summary:
        raise OutputError(f"{', '.join(sink_options.failed_outputs(args, pipe.sinks))}: could not be written (said "
                          "above); the other outputs are whole")
    sig.raise_if_stopped(f"after {done} of {total} readings; the {summary['estimates']} estimates made are written "
                         f"to {st.output.path}")
    return 0


def _open(args, st, *, method, seed, mode, window_s, odometry, odometry_kind, tolerate_errors, beacon=None,
          named=False):
    """The sinks (before anything else is created) and the pipeline that feeds them."""
    from pfdoa.gateway.setup import build_pipeline, estimator_method
    from pfdoa.sinks import options as sink_options

    sinks = sink_options.open_sinks(
        args, st.site, args.config, out_path=st.output.path,
        metadata={"method": estimator_method(st.site, method), "seed": str(seed), "mode": mode,
                  "window_s": repr(window_s or st.gateway.window_s), "odometry": odometry_kind})
    try:
        return build_pipeline(st, method=method, seed=seed, mode=mode, window_s=window_s, odometry=odometry,
                              tolerate_errors=tolerate_errors, frames=False, sinks=sinks if len(sinks) else None,
                              frame_id=args.frame_id, beacon=beacon, named_beacons=named)
    except BaseException:
        sinks.close()
        raise


def _final_health(pipe, t0: float, t1: float) -> None:
    """One health snapshot over the whole replay, for the sinks (a recording's diagnostics)."""
    if pipe.sinks is not None and t1 > t0:
        sampler = pipe.health.sampler(pipe.grouper, pipe.gateway.named)
        sampler.start(t0, 0, 0)
        pipe.sinks.health(sampler.sample(t1, t1))


def _replay_trace(args, st, sig, log):
    import math

    from pfdoa.errors import InputError
    from pfdoa.gateway.beacons import BeaconReading
    from pfdoa.gateway.odomsource import odometry_buffer
    from pfdoa.readings.reassembly import Reading
    from pfdoa.sinks import options as sink_options
    from pfdoa.trace import check_anchor_ids, odometry_overlap_warning, read_odometry, read_trace, time_unit_warnings

    with sig.interruptible():  # a long read (or a FIFO nobody writes) ends on a signal
        trace = read_trace(args.trace)
    for w in time_unit_warnings(trace.t, args.trace, trace.anchor):
        log.warning("%s", w)
    check_anchor_ids(trace, st.site.anchor_ids, args.config)
    odom = None
    if args.odom:
        with sig.interruptible():
            od = read_odometry(args.odom)
        for w in time_unit_warnings(od.t, args.odom) + [odometry_overlap_warning(od.t, trace.t, args.odom)]:
            if w:
                log.warning("%s", w)
        odom = odometry_buffer(od)
    mode = args.mode or ("seq" if trace.seq is not None else "window")
    if mode == "seq" and trace.seq is None:
        raise InputError(f"{args.trace}: --mode seq needs a seq column")
    seed = 0 if args.seed is None else args.seed
    pipe = _open(args, st, method=args.method, seed=seed, mode=mode, window_s=args.window, odometry=odom,
                 odometry_kind="file" if args.odom else "none", tolerate_errors=False,
                 named=trace.beacon is not None)
    grouper, loc, sinks = pipe.grouper, pipe.localizer, pipe.sinks
    named = pipe.gateway.named  # the tracker of named beacons (a trace with a beacon column), or None
    n = len(trace.t)
    last_t = None
    timer = -math.inf
    done = 0
    try:
        if sinks is not None and args.odom:
            sink_options.record_odometry_file(sinks, args.odom)
        # Block by block: Python lists of a whole long trace would take ~4 times the memory
        # of its arrays (a day at 40 readings a second from 12 anchors: 41 M rows).
        for lo in range(0, n, REPLAY_BLOCK):
            if sig.stopped:
                break
            hi = min(lo + REPLAY_BLOCK, n)
            t, anchor, rssi = trace.t[lo:hi].tolist(), trace.anchor[lo:hi].tolist(), trace.rssi_dbm[lo:hi].tolist()
            seq = trace.seq[lo:hi].tolist() if mode == "seq" else None
            beacon = trace.beacon[lo:hi].tolist() if trace.beacon is not None else None
            for i in range(hi - lo):
                if sig.stopped:
                    break
                loc.stamp_t = t[i]
                if mode == "seq" and t[i] != last_t:
                    if sinks is not None:
                        sinks.timer(t[i])
                    loc.handle_all(grouper.poll(t[i]))
                    last_t = t[i]
                r = Reading(int(anchor[i]), rssi[i], t[i], None if seq is None else int(seq[i]) & 0xFFFF)
                if beacon is not None and beacon[i]:
                    pipe.gateway.push_beacon(BeaconReading(beacon[i], r))  # the sinks get it with its beacon
                else:
                    if sinks is not None:
                        sinks.reading(r)
                    loc.handle_all(grouper.push(r))
                if named is not None and t[i] > timer:
                    # The gateway's timers on message time: right after each reading, to its time.
                    timer = t[i]
                    if sinks is not None:
                        sinks.timer(timer)
                    named.poll(timer)
                done = lo + i + 1
        if not sig.stopped:
            if sinks is not None:
                sinks.inputs_ended()
            if named is not None:
                named.flush()
            loc.handle_all(grouper.flush())
            loc.finish()
        if done:
            _final_health(pipe, float(trace.t[0]), float(trace.t[done - 1]))
    finally:
        pipe.close()
    return pipe, mode, done, n


def _recorded_site(recording):
    """The site file a recording holds (ConfigError naming the recording when it is bad)."""
    from pfdoa import _toml as tomllib
    from pfdoa.errors import ConfigError, InputError
    from pfdoa.site import parse_site

    src = f"{recording.path}:site_toml"
    if not recording.site_toml:
        raise InputError(f"{recording.path}: the recording holds no site file; give --config SITE.toml")
    try:
        data = tomllib.loads(recording.site_toml)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(src, "<syntax>", str(exc)) from None
    return parse_site(data, src)


def _replay_recording(args, st, recording, sig):
    """A gateway's recording, event by event as its runner had them (pfdoa.gateway.runner):
    a reading goes to the reassembler, an odometry increment to the localizer's buffer, a
    timer mark runs the timers; the same seed and settings give the same estimates."""
    import math

    from pfdoa.errors import InputError
    from pfdoa.gateway.beacons import BeaconReading
    from pfdoa.gateway.odomsource import load_odometry
    from pfdoa.gateway.transports import OdomLine
    from pfdoa.odometry import OdometryBuffer
    from pfdoa.readings.reassembly import Reading
    from pfdoa.sinks import options as sink_options

    meta = recording.metadata
    try:
        seed = args.seed if args.seed is not None else int(meta.get("seed", "0"))
        window_s = args.window or (float(meta["window_s"]) if meta.get("window_s") else None)
    except ValueError:
        raise InputError(f"{recording.path}: metadata seed {meta.get('seed')!r} or window_s "
                         f"{meta.get('window_s')!r} is not a number") from None
    if window_s is not None and not (math.isfinite(window_s) and window_s > 0):
        raise InputError(f"{recording.path}: metadata window_s {window_s} must be > 0")
    mode = args.mode or meta.get("mode") or st.gateway.mode
    if mode not in ("seq", "window"):
        raise InputError(f"{recording.path}: metadata mode {mode!r} is neither seq nor window")
    kind = "file" if args.odom else meta.get("odometry", "none")
    args.frame_id = args.frame_id or meta.get("frame_id") or None
    if args.odom:
        odometry = load_odometry(args.odom)
    elif kind == "file":  # read whole before the run, as the gateway did
        odometry = OdometryBuffer()
        for inc in recording.odometry():
            odometry.add(inc.t_odom, inc.dx, inc.dy, inc.dtheta)
        odometry.end()
    elif kind == "stream":
        odometry = OdometryBuffer()
    else:
        odometry = None
    has_named = any(isinstance(r, BeaconReading) for r in recording.readings())  # ESPresense devices
    pipe = _open(args, st, method=args.method or meta.get("method"), seed=seed, mode=mode, window_s=window_s,
                 odometry=odometry, odometry_kind=kind, tolerate_errors=True, beacon=meta.get("beacon"),
                 named=has_named)
    grouper, loc, sinks = pipe.grouper, pipe.localizer, pipe.sinks
    named = pipe.gateway.named
    first = last = None
    done = 0
    try:
        if sinks is not None and args.odom:
            sink_options.record_odometry_file(sinks, args.odom)
        for ev in recording.events():
            if sig.stopped:
                break
            loc.stamp_t = ev.t
            first = ev.t if first is None else first
            last = ev.t
            if isinstance(ev, BeaconReading):
                pipe.gateway.push_beacon(ev)  # to its beacon's estimator; the sinks get it with its beacon
                done += 1
            elif isinstance(ev, Reading):
                if mode == "seq" and ev.seq is None:
                    raise InputError(f"{recording.path}: a reading without a beacon sequence cannot be grouped "
                                     "by sequence; use --mode window")
                if sinks is not None:
                    sinks.reading(ev)
                loc.handle_all(grouper.push(ev))
                done += 1
            elif isinstance(ev, OdomLine):
                if kind == "file":
                    if sinks is not None and not args.odom:
                        sinks.odometry(ev)
                    continue
                if odometry is not None:
                    if sinks is not None:
                        sinks.odometry(ev)
                    odometry.add(ev.t_odom, ev.dx, ev.dy, ev.dtheta)
                    loc.release(loc.now)
            else:  # the timers ran here
                if sinks is not None:
                    sinks.timer(ev.t)
                loc.now = max(loc.now, ev.t)
                if named is not None:  # in the gateway's order (Gateway.poll, Gateway.finish)
                    named.poll(ev.t)
                loc.handle_all(grouper.poll(ev.t))
                loc.release(ev.t)
        if not sig.stopped and not recording.cut:  # the gateway's end of input; a cut one never got there
            if sinks is not None:
                sinks.inputs_ended()
            if named is not None:
                named.flush()
            loc.handle_all(grouper.flush())
            loc.finish()
        if first is None:
            raise InputError(f"{recording.path}: no readings recorded"
                             + (" (the recording was cut before its first complete chunk)" if recording.cut else ""))
        _final_health(pipe, first, last)
    finally:
        pipe.close()
    # a recording's total is known only once read through; an interrupted one reports what was done
    return pipe, mode, done, done
