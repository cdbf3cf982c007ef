"""pfdoa gateway: live anchor reports in, positions out."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import secrets
import sys

from pfdoa.commands._common import check_outputs

HELP = "read anchor reports live (serial, CAN, stdin, MQTT, capture) and output positions"
DESCRIPTION = """\
Read RSSI reports from anchors (protocol/SPEC.md) on any number of inputs (--input SPEC:
serial ports, CAN buses, standard input, an MQTT broker, raw capture files; the spec
syntax is below); reassemble them into synchronized anchor sets; run an estimator; write
one position per set (JSON lines or CSV).

Sets are keyed by the beacon sequence number ([gateway] mode = "seq"): a set leaves as
soon as every configured anchor has reported, or when the missing anchors' reports are
known lost or late (after [gateway] set_timeout_s), naming the missing anchors. Mode
"window" groups by receive time instead. Duplicates and late reports are dropped and
counted; an anchor silent for [gateway] stale_after_s is reported stale; a tick or uptime
going backwards is reported as a reboot. A serial port or CAN interface that disappears is
reopened with backoff; the gateway keeps running. A device not present when the gateway
starts is waited for (--wait-for-device). SIGINT/SIGTERM flush the outputs and print the
final counters (JSON, one line on stderr).

A health line goes to stderr every [gateway] health_interval_s: frames/s, sets/s,
estimates/s, errors by kind, per-anchor loss, stale anchors, open sets.

Time: each anchor's tick is mapped to this host's clock (an online offset and drift fit
per anchor, robust to wrap, reboots, jitter and bursts; docs/gateway.md), and a set is
stamped with the time its anchors' ticks say the beacon event happened. The timers
(set timeout, staleness) run only as far as the input has been read, so input that waits
in a buffer never times a set out. A capture replays with the same timer rule on the same
stamps: the same output. --replay-capture - reads a timed stream (the capture format) on
standard input, e.g. from 'pfdoa sim --transport timed'.

Output fields: t (host time of the beacon event, from the anchors' ticks), x, y (m, site
frame), sigma (m), doa (rad), seq, anchors (used), missing, stale, rebooted, r95 (m: 95 %
radius), cov ([xx, xy, yy] m^2), lost (the estimator no longer explains the readings),
frame_id (--frame-id, default map), stamp (host time the estimate was made),
beacon (which beacon: each of the site's [[beacons]] has its own reassembly and estimator),
heading, heading_var (with odometry), room, room_p, floor, floor_p (the site's [[rooms]] and
[[floors]]: the room holding the estimate and the probability the beacon is in it, the floor
the beacon is on and its probability).

Robot outputs (docs/robot.md): --record RUN.mcap writes a ROS 2 recording (poses with
covariance, readings, odometry also as nav_msgs/Odometry, diagnostics, anchor markers, the
site frame on /tf_static when [site] map_pose places it) that 'pfdoa replay RUN.mcap'
turns back into the same estimates; --web [HOST:]PORT serves a live view; --health-json
writes each health period as JSON; --readings-out writes the readings as a trace for
replay, calibrate and eval. Without --seed a seed is drawn, printed and recorded.
--ros2 joins the robot's ROS 2 graph over DDS (no ROS installation): poses on pfdoa/pose,
health on /diagnostics, the site frame on /tf_static, the robot's odometry from /odom
(the site's [ros2] table: domain, namespace, frames, QoS).

Fleets (docs/fleet.md): --mqtt mqtt[s]://[USER@]HOST[:PORT]/PREFIX publishes every
estimate (QoS 1, held while the broker is away), health, anchor status and Home Assistant
discovery; the password comes from --mqtt-password-file or $PFDOA_MQTT_PASSWORD.
--mqtt-input frames reads our frames from the broker, --mqtt-input espresense ESPresense
nodes' messages (rooms mapped to anchors by [espresense]), one estimator per device.
"""


def _epilog() -> str:
    from pfdoa.gateway.inputs import spec_lines

    try:
        from pfdoa.estimators import METHODS

        methods = ", ".join(METHODS)
    except ImportError:  # pragma: no cover - the estimators are part of the package
        methods = "see pfdoa.estimators"
    specs = spec_lines()
    return f"""\
examples:
  pfdoa gateway --config site.toml --input serial:/dev/ttyUSB0 --input serial:/dev/ttyUSB1@921600
  pfdoa gateway --config site.toml --input can:socketcan:can0 --input serial:rfc2217://10.0.0.7:4000
  pfdoa gateway --config site.toml --serial /dev/ttyUSB0 --serial /dev/ttyUSB1@921600
  pfdoa gateway --config site.toml --can socketcan:can0 --out positions.jsonl
  pfdoa gateway --config site.toml --can slcan:/dev/ttyACM0@500000 --capture run.cap
  pfdoa gateway --config site.toml --can virtual:vc0 --method wcl --format csv
  pfdoa gateway --config site.toml --serial socket://10.0.0.7:4000 --odom /tmp/odom.fifo
  socat -u TCP:10.0.0.7:4000 - | pfdoa gateway --config site.toml --stdin
  pfdoa gateway --config site.toml --replay-capture run.cap
  pfdoa gateway --config site.toml --serial /dev/ttyACM0 --web 8080 --record run.mcap --health-json health.jsonl
  pfdoa gateway --config site.toml --can socketcan:can0 --readings-out live.csv --health 0 --health-json -
  pfdoa gateway --config site.toml --serial /dev/ttyACM0 --mqtt mqtts://robot7@broker.lan/site-a/pfdoa
  pfdoa gateway --config site.toml --mqtt mqtt://broker.lan/pfdoa --mqtt-input espresense
  pfdoa gateway --config site.toml --serial /dev/ttyACM0 --ros2 --frame-id pfdoa_site
  pfdoa sim --scenario demo --transport timed | pfdoa gateway --config build/sim/demo/site.toml --replay-capture -

input specs (--input SPEC, repeatable; KIND:ARGUMENT):
{specs}
  --serial URL, --can SPEC, --stdin, --replay-capture FILE and --mqtt-input KIND are
  spellings of serial:URL, can:SPEC, stdin, capture:FILE and mqtt:KIND.
serial URLs: anything pyserial's serial_for_url opens (/dev/ttyACM0, loop://,
  socket://host:port, rfc2217://host:port), optionally followed by @BAUD.
CAN specs: INTERFACE:CHANNEL[@BITRATE][,key=value...] for python-can (socketcan:can0,
  slcan:/dev/ttyACM0@500000, virtual:vc0, pcan:PCAN_USBBUS1@250000), or config[:PATH]
  for python-can's configuration file. Only anchor-to-host identifiers are accepted.
capture files: '(TIME) SOURCE S HEXBYTES', '(TIME) SOURCE C ID#HEXDATA', '(TIME) odom O
  t,dx,dy,dtheta' and '(TIME) - T' (timers) lines; '-' is standard input.
odometry: text lines t,dx,dy,dtheta (robot frame increments over (previous t, t]) from a
  file, FIFO or pipe; t on this host's clock (Unix seconds).
methods: {methods}
outputs: --out, --capture, --readings-out and --health-json continue a file of their kind
  that is there (a restarted gateway keeps its earlier log; the CSV header only into a new
  file); a --record, or a file of another kind, is moved aside to PATH.1 (PATH.2, ...);
  --stats is replaced whole. A device or FIFO is written through, a link followed.
exit status: 0 when --duration ended or every finite input ended, 1 an output could not be
  written (after the final counters), 2 bad configuration, input file or input that can
  never be opened, 130/143 stopped by SIGINT/SIGTERM (after the final counters)
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pfdoa.commands._common import add_input_options

    p.epilog = _epilog()
    p.add_argument("--config", "-c", required=True, metavar="SITE.toml", help="site file (anchors, radio, [gateway], [estimator], [output])")
    src = p.add_argument_group("inputs (at least one)")
    add_input_options(src, "serial:URL[@BAUD], can:INTERFACE:CHANNEL, stdin, capture:FILE, mqtt:frames, ...; "
                           "see 'input specs' below", "read the UART byte stream from standard input")
    src.add_argument("--replay-capture", action="append", default=[], metavar="FILE",
                     help="feed a capture file ('-': a timed stream on standard input) as fast as possible; "
                          "the timers run on its recorded times (= --input capture:FILE)")
    src.add_argument("--realtime", action="store_true", help="pace a capture by its recorded times")
    p.add_argument("--odom", metavar="SOURCE", help="odometry increments t,dx,dy,dtheta on this host's clock "
                                                     "(file, FIFO or pipe; with --replay-capture: a file)")
    p.add_argument("--out", "-o", metavar="PATH", help="output file, '-' for standard output (default: [output] path, -)")
    p.add_argument("--format", "-f", choices=("jsonl", "csv"), help="output format (default: [output] format, jsonl)")
    p.add_argument("--method", "-m", metavar="NAME", help="estimator (default: [estimator] method, else pf-doa)")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed of the estimator (default: drawn, printed and recorded with --record)")
    p.add_argument("--capture", metavar="FILE", help="also write every received chunk to a raw capture file")
    p.add_argument("--mode", choices=("seq", "window"), help="grouping (default: [gateway] mode, seq)")
    p.add_argument("--window", type=float, metavar="S", help="window length in window mode (default: [gateway] window_s)")
    p.add_argument("--health", type=float, metavar="S", help="health line period in seconds, 0 = off (default: [gateway] health_interval_s)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--wait-for-device", type=float, metavar="S",
                   help="wait at most S seconds for a --serial or --can device that is not present when the gateway "
                        "starts (default: for ever, saying so every minute; 0: fail at once, exit 2)")
    p.add_argument("--stats", metavar="PATH", help="also write the final counters as JSON to PATH")
    from pfdoa.sinks import options as sink_options

    sink_options.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from pfdoa import signals
    from pfdoa.clock import SYSTEM
    from pfdoa.commands._common import check_gateway_args, input_counters
    from pfdoa.errors import InputError, OutputError
    from pfdoa.gateway import inputs as registry
    from pfdoa.gateway.inputs.capture import CaptureWriter
    from pfdoa.gateway.odomsource import OdometryReader, load_odometry
    from pfdoa.gateway.setup import build_pipeline, estimator_method, load_settings
    from pfdoa.odometry import OdometryBuffer
    from pfdoa.output import write_stats
    from pfdoa.sinks import options as sink_options
    from pfdoa.site import require_wire_ids

    log = logging.getLogger("pfdoa.gateway")
    specs = registry.specs_from_args(args)  # --input and its older spellings; a bad kind is exit 2
    captures = [s for s in specs if s.kind == "capture"]
    stream = bool(captures)
    live = [s for s in specs if s.kind != "capture"]
    if stream and live:
        raise InputError(f"{captures[0].where()}: a capture replays recorded time: it cannot be mixed with live "
                         f"inputs ({live[0].where()})")
    if args.realtime and not stream:
        raise InputError("--realtime paces a capture (--input capture:FILE); live inputs are real time already")
    st = load_settings(args.config, args.out, args.format)
    mqtt_inputs = sink_options.check_mqtt_inputs(args, st, stream=stream,
                                                 others=[s.where() for s in live if s.kind != "mqtt"])
    if not any(s.kind == "mqtt" for s in specs):  # the site's [mqtt] inputs
        specs += [registry.InputSpec("mqtt", k, f"mqtt:{k}", f"{st.source}: mqtt.inputs") for k in mqtt_inputs]
    check_gateway_args(args, specs)
    gcfg = st.gateway
    if args.health is not None:
        gcfg = replace(gcfg, health_interval_s=args.health)
        st = replace(st, gateway=gcfg)
    clock = SYSTEM
    holder: dict = {}  # the sinks (the broker inputs' connection) and the pipeline, once built
    ctx = registry.InputContext(clock=clock, serial_baud=gcfg.serial_baud, realtime=args.realtime,
                                espresense=st.espresense,
                                mqtt=lambda kind: sink_options.mqtt_input(holder["sinks"], kind, st.espresense))
    transports = registry.make_inputs(specs, ctx)  # nothing is opened yet
    check_inputs(transports)
    # Named by option (--serial / --can), an --input or a broker input by its spec.
    wire = list(dict.fromkeys(s.where() if s.option == "--input" or s.kind == "mqtt" else s.option
                              for s, t in zip(specs, transports) if t.carries_frames))
    if wire:
        require_wire_ids(st.site, args.config, " / ".join(wire))
    check_outputs({"--out": st.output.path, "--capture": args.capture, "--stats": args.stats,
                   **sink_options.output_paths(args)},
                  {"--config": [args.config], **{t.where: list(t.files) for t in transports if t.files},
                   "--odom": [args.odom] if args.odom else [], **sink_options.input_paths(args)},
                  stdin=bool(registry.reads_stdin(transports)))
    for t in transports:
        for path in t.files:
            refuse_other_format(path, t.where)
    for t in transports:
        if t.finite:
            t.open()  # a terminal on stdin, a missing capture file: usage errors (exit 2), not devices to retry

    # --ros2 subscribes to the robot's odometry ([ros2] odom_topic) unless --odom names a
    # source, or a replay runs on recorded time.
    ros2_odom = False
    if args.ros2 and not args.odom and not stream:
        from pfdoa.ros2.config import ros2_settings

        ros2_odom = bool(ros2_settings(st.site.sections, args.config).odom_topic)
    odom_reader = None
    if stream:
        # A replay is a function of its inputs: an odometry file is read whole first; the
        # capture's own odometry lines (O) go into the same buffer as they come.
        if args.odom and not os.path.isfile(args.odom):
            raise InputError(f"--odom {args.odom}: with --replay-capture, odometry must be a file")
        odometry = load_odometry(args.odom) if args.odom else OdometryBuffer()
    elif args.odom:
        odom_reader = OdometryReader(args.odom, clock=clock)
        odometry = OdometryBuffer()
    elif ros2_odom:
        odometry = OdometryBuffer()
    else:
        odometry = None

    def say(line: str) -> None:
        print(f"pfdoa: {line}", file=sys.stderr, flush=True)

    # A run is reproducible from its recording only with its seed: without --seed one is drawn.
    seed = args.seed if args.seed is not None else secrets.randbelow(2**31)
    # A restarted gateway keeps what its previous run wrote (pfdoa.outfiles: text outputs
    # continued, the CSV header only into a new file; a recording or a file of another kind
    # moved aside); the final counters (--stats) are this run's, replaced whole.
    sinks = holder["sinks"] = sink_options.open_sinks(
        args, st.site, args.config, out_path=st.output.path, default_beacon=st.beacons.primary_name(),
        per_beacon=len(st.beacons.entries) > 1 or "espresense" in mqtt_inputs,
        existing="keep",
        particles=lambda: getattr(holder["pipe"].localizer.estimator, "xy", None),
        metadata={"method": estimator_method(st.site, args.method), "seed": str(seed),
                  "mode": args.mode or gcfg.mode, "window_s": repr(args.window or gcfg.window_s),
                  "odometry": ("file" if args.odom else "stream") if stream else
                  ("stream" if args.odom or ros2_odom else "none"),
                  "beacon": st.beacons.primary_name()})
    try:
        pipe = holder["pipe"] = build_pipeline(st, method=args.method, seed=seed, mode=args.mode, window_s=args.window,
                                               odometry=odometry, flush_each=True, existing="keep",
                                               sinks=sinks if len(sinks) else None,
                                               frame_id=args.frame_id, named_beacons="espresense" in mqtt_inputs)
    except BaseException:
        sinks.close()
        raise
    if stream and args.odom and pipe.sinks is not None:
        sink_options.record_odometry_file(pipe.sinks, args.odom)
    ros2_source = sink_options.ros2_odometry(sinks, clock) if ros2_odom else None
    pipe.localizer.odometry_requested = bool(args.odom) or ros2_source is not None
    try:
        capture = CaptureWriter(args.capture, existing="keep") if args.capture else None
    except BaseException:
        pipe.close()
        raise
    if args.seed is None:
        say(f"estimator seed {seed} (drawn; --seed {seed} repeats this run)")
    web = sink_options.web_url(sinks)
    if web:
        say(f"live view on {web}")

    sig = signals.active()  # SIGINT/SIGTERM set its event: the runner stops, the outputs are closed
    runner = pipe.runner(transports, gcfg, clock=clock, health_out=say, stream_timers=stream, capture=capture,
                         odometry=odom_reader or ros2_source, duration_s=args.duration, stop=sig.event,
                         wait_for_device_s=math.inf if args.wait_for_device is None else args.wait_for_device)
    log.info("gateway: %d input(s), %d anchors, method %s (seed %d), mode %s, timers on %s", len(transports),
             len(st.site.anchors), getattr(pipe.localizer.estimator, "name", args.method), seed, args.mode or gcfg.mode,
             "the stream's times" if stream else "the input read so far")
    t0 = clock.monotonic()
    # From here to the written counters a signal only stops the runner: the outputs are
    # closed whole (a recording's footer, the last records) whatever comes when.
    with sig.graceful():
        summary, error = _run_and_close(runner, pipe, capture)
        summary["seconds"] = round(clock.monotonic() - t0, 3)
        summary["seed"] = seed
        summary.update(input_counters(transports, odom_reader))
        summary.update(sink_options.sink_counters(pipe.sinks))
        say("final " + json.dumps(summary, separators=(",", ":")))
        if pipe.localizer.output_error is not None:
            summary["output_error"] = str(pipe.localizer.output_error.strerror or pipe.localizer.output_error)
        if args.stats:
            write_stats(args.stats, summary)
    if error is not None:
        raise error
    if pipe.localizer.output_error is not None:
        raise OutputError(f"--out {st.output.path}: cannot write: {summary['output_error']}")
    failed = sink_options.failed_outputs(args, pipe.sinks)
    if capture is not None and capture.errors:
        failed.append(f"--capture {args.capture}")
    if failed:
        raise OutputError(f"{', '.join(failed)}: could not be written (said above); the other outputs are whole")
    where = "standard output" if st.output.path == "-" else st.output.path
    sig.raise_if_stopped(f"after {summary['seconds']:g} s; {summary['estimates']} estimates written to {where}")
    return 0


def _run_and_close(runner, pipe, capture) -> tuple[dict, Exception | None]:
    """Run until stopped, close every output, and the counters so far (with the permanent
    input error that ended the run, if one did: said after the counters)."""
    from pfdoa.errors import PfdoaError

    error = None
    try:
        runner.run()
    except PfdoaError as exc:
        error = exc
    finally:
        pipe.close()
        if capture:
            capture.close()
    summary = pipe.summary()
    summary["timer_polls"] = runner.timer_polls
    if pipe.sinks is not None and pipe.sinks.failed:
        summary["sink_errors"] = dict(pipe.sinks.failed)
    if capture is not None:
        summary["capture"] = {"chunks": capture.chunks, "errors": capture.errors}
    return summary, error


def refuse_other_format(path: str, where: str | None = None) -> None:
    """A capture input (``where``: as the user named it, default ``--replay-capture PATH``)
    of a file that is a trace or a recording (what `pfdoa replay`
    reads) would be thousands of malformed lines and no estimate: one line, exit 2."""
    from pfdoa.errors import InputError

    where = where or f"--replay-capture {path}"
    if path == "-" or not os.path.isfile(path):  # a pipe or FIFO is read once, by the capture reader
        return
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return  # the capture reader says why, as for any capture
    if head.startswith(MCAP_MAGIC):
        raise InputError(f"{where}: an MCAP recording, not a capture; replay it with "
                         f"'pfdoa replay {path}'")
    first = head.split(b"\n", 1)[0].lstrip(b"\xef\xbb\xbf").decode("ascii", "replace")
    cols = [c.strip() for c in first.split(",")]
    if head.startswith(b"\x1f\x8b"):
        raise InputError(f"{where}: compressed (gzip), and a capture is plain text; a trace "
                         f"(.csv.gz) is replayed with 'pfdoa replay {path} --config SITE.toml'")
    if {"t", "anchor", "rssi_dbm"} <= set(cols):
        raise InputError(f"{where}: a trace (t,anchor,rssi_dbm), not a capture; replay it with "
                         f"'pfdoa replay {path} --config SITE.toml'")


def check_inputs(transports) -> None:
    """What the inputs together may not be (InputError, exit 2, before anything opens):
    standard input read twice, more byte streams than the gateway has decoders."""
    from pfdoa.errors import InputError
    from pfdoa.gateway.inputs import decoder_sources, reads_stdin
    from pfdoa.gateway.transports import MAX_DECODERS

    if len(reads_stdin(transports)) > 1:
        raise InputError(f"standard input can be read once ({', '.join(t.where for t in reads_stdin(transports))})")
    streams = decoder_sources(transports)
    if streams > MAX_DECODERS:
        raise InputError(f"{streams} byte-stream inputs: the gateway decodes at most {MAX_DECODERS} at once")


MCAP_MAGIC = b"\x89MCAP"  # the MCAP specification's magic, before its version digit
