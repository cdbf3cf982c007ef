"""pfdoa gateway: live anchor reports in, positions out."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time

HELP = "read anchor reports live (serial, CAN, stdin, capture) and output positions"
DESCRIPTION = """\
Read RSSI reports from anchors (protocol/SPEC.md) on any number of serial ports, CAN
buses, standard input or raw capture files; reassemble them into synchronized anchor
sets; run an estimator; write one position per set (JSON lines or CSV).

Sets are keyed by the beacon sequence number ([gateway] mode = "seq"): a set leaves as
soon as every configured anchor has reported, or when the missing anchors' reports are
known lost or late (after [gateway] set_timeout_s), naming the missing anchors. Mode
"window" groups by receive time instead. Duplicates and late reports are dropped and
counted; an anchor silent for [gateway] stale_after_s is reported stale; a tick or uptime
going backwards is reported as a reboot. A serial port or CAN interface that disappears is
reopened with backoff; the gateway keeps running. SIGINT/SIGTERM flush the output and print
the final counters (JSON, one line on stderr).

A health line goes to stderr every [gateway] health_interval_s: frames/s, sets/s,
estimates/s, errors by kind, per-anchor loss, stale anchors, open sets.

Output fields: t (Unix time of the set's last report), x, y (m, site frame), sigma (m),
doa (rad), seq, anchors (used), missing, stale, rebooted, r95 (m: 95 % radius), cov
([xx, xy, yy] m^2), lost (the estimator no longer explains the readings).
"""


def _epilog() -> str:
    try:
        from pfdoa.estimators import METHODS

        methods = ", ".join(METHODS)
    except ImportError:  # pragma: no cover - the estimators are part of the package
        methods = "see pfdoa.estimators"
    return f"""\
examples:
  pfdoa gateway --config site.toml --serial /dev/ttyUSB0 --serial /dev/ttyUSB1@921600
  pfdoa gateway --config site.toml --can socketcan:can0 --out positions.jsonl
  pfdoa gateway --config site.toml --can slcan:/dev/ttyACM0@500000 --capture run.cap
  pfdoa gateway --config site.toml --can virtual:vc0 --method wcl --format csv
  pfdoa gateway --config site.toml --serial socket://10.0.0.7:4000 --odom /tmp/odom.fifo
  socat -u TCP:10.0.0.7:4000 - | pfdoa gateway --config site.toml --stdin
  pfdoa gateway --config site.toml --replay-capture run.cap

serial URLs: anything pyserial's serial_for_url opens (/dev/ttyACM0, loop://,
  socket://host:port, rfc2217://host:port), optionally followed by @BAUD.
CAN specs: INTERFACE:CHANNEL[@BITRATE][,key=value...] for python-can (socketcan:can0,
  slcan:/dev/ttyACM0@500000, virtual:vc0, pcan:PCAN_USBBUS1@250000), or config[:PATH]
  for python-can's configuration file. Only anchor-to-host identifiers are accepted.
capture files: '(UNIX_TIME) SOURCE S HEXBYTES' or '(UNIX_TIME) SOURCE C ID#HEXDATA' lines.
odometry: text lines t,dx,dy,dtheta (robot frame increments) from a file, FIFO or pipe.
methods: {methods}
exit status: 0 after a clean stop or when every finite input ended, 2 bad configuration
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = _epilog()
    p.add_argument("--config", "-c", required=True, metavar="SITE.toml", help="site file (anchors, radio, [gateway], [estimator], [output])")
    src = p.add_argument_group("inputs (at least one)")
    src.add_argument("--serial", "-s", action="append", default=[], metavar="URL[@BAUD]", help="serial port or pyserial URL; repeat for several")
    src.add_argument("--can", action="append", default=[], metavar="SPEC", help="CAN bus through python-can; repeat for several")
    src.add_argument("--stdin", action="store_true", help="read the UART byte stream from standard input")
    src.add_argument("--replay-capture", action="append", default=[], metavar="FILE", help="feed a raw capture file (as fast as possible; see --realtime)")
    src.add_argument("--realtime", action="store_true", help="pace --replay-capture by its recorded times")
    p.add_argument("--odom", metavar="SOURCE", help="odometry increments t,dx,dy,dtheta (file, FIFO or pipe)")
    p.add_argument("--out", "-o", metavar="PATH", help="output file, '-' for standard output (default: [output] path, -)")
    p.add_argument("--format", "-f", choices=("jsonl", "csv"), help="output format (default: [output] format, jsonl)")
    p.add_argument("--method", "-m", metavar="NAME", help="estimator (default: [estimator] method, else pf-doa)")
    p.add_argument("--seed", type=int, default=None, help="random seed of the estimator (default: random)")
    p.add_argument("--capture", metavar="FILE", help="also write every received chunk to a raw capture file")
    p.add_argument("--mode", choices=("seq", "window"), help="grouping (default: [gateway] mode, seq)")
    p.add_argument("--window", type=float, metavar="S", help="window length in window mode (default: [gateway] window_s)")
    p.add_argument("--health", type=float, metavar="S", help="health line period in seconds, 0 = off (default: [gateway] health_interval_s)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--stats", metavar="PATH", help="also write the final counters as JSON to PATH")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from pfdoa.errors import InputError
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.pipeline import Gateway, LiveOdometry, Localizer, Runner, make_grouper
    from pfdoa.gateway.setup import build_estimator, load_settings
    from pfdoa.gateway.transports import (CanTransport, CaptureReader, CaptureWriter, SerialTransport,
                                          StdinTransport, split_baud)
    from pfdoa.output import open_writer, write_stats

    log = logging.getLogger("pfdoa.gateway")
    if not (args.serial or args.can or args.stdin or args.replay_capture):
        raise InputError("no input: give --serial, --can, --stdin or --replay-capture")
    for name, v in (("--window", args.window), ("--duration", args.duration)):
        if v is not None and not v > 0:
            raise InputError(f"{name} must be > 0, got {v}")
    if args.health is not None and not args.health >= 0:
        raise InputError(f"--health must be >= 0, got {args.health}")
    st = load_settings(args.config, args.out, args.format)
    site, gcfg = st.site, st.gateway
    if args.health is not None:
        gcfg = replace(gcfg, health_interval_s=args.health)

    transports = []
    for i, spec in enumerate(args.serial):
        url, baud = split_baud(spec, gcfg.serial_baud)
        transports.append(SerialTransport(url, baud, name=f"serial{i}"))
    for i, spec in enumerate(args.can):
        transports.append(CanTransport(spec, name=f"can{i}"))
    if args.stdin:
        transports.append(StdinTransport())
    for path in args.replay_capture:
        r = CaptureReader(path, realtime=args.realtime)
        r.open()  # a missing capture file is a usage error (exit 2), not a device to retry
        transports.append(r)
    replay_only = bool(args.replay_capture) and len(transports) == len(args.replay_capture)

    estimator = build_estimator(site, args.method, args.seed)
    odom = LiveOdometry(args.odom) if args.odom else None
    health = Health()
    grouper = make_grouper(site.anchor_ids, gcfg, args.mode, args.window, live=True)
    writer = open_writer(st.output.path, st.output.format, flush_each=True)
    capture = CaptureWriter(args.capture) if args.capture else None
    loc = Localizer(site, estimator, writer, odom, health)
    gw = Gateway(grouper, loc.handle, health, capture)

    def say(line: str) -> None:
        print(f"pfdoa: {line}", file=sys.stderr, flush=True)

    runner = Runner(transports, gw, gcfg, health_out=say, replay_clock=replay_only and not args.realtime)

    def stop(signum, _frame) -> None:
        log.info("signal %d: stopping", signum)
        runner.stop.set()

    old = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    timer = None
    if args.duration:
        timer = threading.Timer(args.duration, runner.stop.set)
        timer.daemon = True
        timer.start()
    log.info("gateway: %d input(s), %d anchors, method %s, mode %s", len(transports), len(site.anchors),
             getattr(estimator, "name", args.method), args.mode or gcfg.mode)
    t0 = time.monotonic()
    try:
        runner.run()
    finally:
        if timer:
            timer.cancel()
        for s, h in old.items():
            signal.signal(s, h)
        writer.close()
        if capture:
            capture.close()
    summary = health.summary(grouper)
    summary["seconds"] = round(time.monotonic() - t0, 3)
    if odom is not None:
        summary["odometry"] = {"lines": odom.lines, "bad_lines": odom.bad_lines, "dropped": odom.dropped}
    say("final " + json.dumps(summary, separators=(",", ":")))
    if args.stats:
        write_stats(args.stats, summary)
    return 0
