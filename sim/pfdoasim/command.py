"""`pfdoa sim`: the software-in-the-loop simulator.

Registered by this package as an entry point (``pfdoa.commands`` group, pyproject.toml) and
found there by :mod:`pfdoa.cli`, with the same interface as the built-in commands
(``HELP``, ``DESCRIPTION``, ``add_arguments``, ``run``). Only light imports at module level:
``pfdoa --help`` builds this parser.
"""

from __future__ import annotations

import argparse

from pfdoasim import backends

HELP = "simulate anchors (real firmware core) and a moving robot; feed a gateway; score it"
DESCRIPTION = """\
Simulate a robot carrying a beacon through a site. Every anchor is an instance of the
real firmware core (libpfdoa_anchor.so, built on demand: pfdoasim.firmware) fed with
simulated radio readings, with optional --faults. Ground truth is written alongside
(--out-dir: trace.csv t,anchor,rssi_dbm,gt_x,gt_y,seq; trace.odom.csv t,dx,dy,dtheta;
trace.reports.csv k,seq,anchor,t (when each report's event closed); trace.summary.json
with every injected fault counted; site.toml for the gateway).

With --gateway the simulator starts `pfdoa gateway` as a separate process and scores
its estimates against the ground truth (matched by beacon sequence number): RMSE,
median, p95 and max error, event-time error, per-anchor link statistics, a PNG (--plot).

Time. With --gateway the run is in virtual time: every frame travels to the gateway as a
line of a timed stream (the capture format, on its standard input) stamped with the
simulated time it was sent plus the modelled transport latency, and the gateway's timers
run on those times. The same seed gives the same estimates and summary, byte for byte,
however fast or loaded the machine; --transport only chooses the framing (pty, stdout:
UART, one serial link per anchor; slcan, can-virtual: one CAN bus). --transport timed
without --gateway writes that stream to standard output (pipe it into
`pfdoa gateway --replay-capture -`). --realtime (implied when serving a pty, SLCAN or
raw stdout without --gateway) paces the run at --speed times real time on a real port:
a pseudo-terminal, SLCAN over one, or standard output; without --gateway it prints the
port path(s) and waits (--wait) for a reader.

scenarios: demo, paper-boundary, paper-inside, paper-diagonal, espresense-6x4 (two walking
tracks; --sweep also silences each anchor in turn), walk (needs --config SITE.toml)

faults (comma-separated): loss=P dup=P reorder=P ber=RATE drift_ppm=PPM skew=ANCHOR@PPM
  reboot=1 silence=ANCHOR@START+DURATION portdrop=START+DURATION
  jitter=MS batch=MS stall=START+DURATION   (transport latency, virtual time)
  (times in simulated seconds; silence, portdrop, stall and skew may repeat)

examples:
  pfdoa sim --scenario demo --gateway --odom --plot build/demo.png
  pfdoa sim --scenario espresense-6x4 --gateway --odom --sweep   (median/p95/max, each anchor silenced)
  pfdoa sim --scenario demo --gateway --transport slcan --faults loss=0.02,dup=0.01,ber=1e-5,portdrop=20+2
  pfdoa sim --scenario demo --gateway --faults jitter=50,skew=1@-100,skew=2@100 --json
  pfdoa sim --scenario demo --transport timed | pfdoa gateway --config build/sim/demo/site.toml --replay-capture -
  pfdoa sim --scenario demo --link /tmp/anchors.tty &   pfdoa gateway --config build/sim/demo/site.toml --serial /tmp/anchors.tty
  pfdoa sim --scenario demo --gateway --realtime --speed 10   (a real pty, the gateway on its wall clock)
  pfdoa sim --score build/sim/demo/gateway.jsonl --out-dir build/sim/demo
  pfdoa sim --scenario demo --anchor-backend qemu --gateway   (four QEMU anchors, byte identity checked live)

exit status: 0 ok, 1 an output could not be written, 2 bad options, 130/143 stopped by
  SIGINT/SIGTERM (the beacons so far are written and scored first)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("scenario")
    g.add_argument("--scenario", default=None, metavar="NAME", help="named scenario (default: demo, or walk with --config)")
    g.add_argument("--config", metavar="SITE.toml", help="site file: anchors and radio model (replaces the scenario's site)")
    g.add_argument("--track", type=int, default=None, metavar="N", help="espresense-6x4: track 0 or 1 (default: both)")
    g.add_argument("--duration", type=float, default=None, metavar="S", help="simulated seconds (default: the scenario's)")
    g.add_argument("--seed", type=int, default=1, metavar="N", help="random seed (default 1)")
    g.add_argument("--faults", default="", metavar="SPEC", help="fault injection, see below")
    g.add_argument("--beacon-hz", type=float, metavar="HZ", help="beacon rate (default: the scenario's)")
    g.add_argument("--radio", choices=("ble", "zigbee"), help="BLE (readings on advertising channels) or 802.15.4")
    g.add_argument("--noise-db", type=float, metavar="DB", help="per-reading Gaussian noise (std, dB)")
    g.add_argument("--shadowing-db", type=float, metavar="DB", help="spatially correlated shadowing (std, dB)")
    g.add_argument("--multipath", metavar="P[:DB]", help="multipath bursts: probability per reading and loss in dB")
    g.add_argument("--odom-noise", type=float, metavar="FRAC", help="odometry error per metre / radian (std)")
    g.add_argument("--peers", type=int, metavar="MS",
                   help="the anchors hear each other: each sends its own advertisement every MS ms and reports the "
                        "others' (protocol/SPEC.md 3.5); the gateway refits the radio model from them")
    g.add_argument("--anchor-backend", default=backends.DEFAULT, choices=backends.names(),
                   help="; ".join(f"{name}: {summary}" for name, (_, _, summary) in backends.BACKENDS.items()))
    g.add_argument("--core-lib", metavar="PATH", help="anchor core shared library (default: build it)")
    t = parser.add_argument_group("transport and time")
    t.add_argument("--transport", default="pty", choices=("pty", "slcan", "can-virtual", "stdout", "timed"),
                   help="framing and port (see Time above; default pty)")
    t.add_argument("--realtime", action="store_true", help="run in real time on a real port (pty, slcan, stdout)")
    t.add_argument("--link", metavar="PATH", help="real time: stable symlink to the pty (needed for portdrop faults)")
    t.add_argument("--can-channel", default="pfdoa-sim", metavar="NAME", help="virtual CAN channel name")
    t.add_argument("--speed", type=float, default=10.0, metavar="X",
                   help="real time: times real time (0 = as fast as possible, raw stdout only)")
    t.add_argument("--wait", type=float, default=30.0, metavar="S", help="real time: wait this long for a reader to open the port")
    o = parser.add_argument_group("gateway and output")
    o.add_argument("--out-dir", metavar="DIR", help="where trace, site file, gateway output go (default build/sim/SCENARIO; "
                   "with --calibrate build/sim/SCENARIO-calibrated)")
    o.add_argument("--trace-out", metavar="PATH", help="trace CSV path (default OUT_DIR/trace.csv)")
    o.add_argument("--gateway", action="store_true", help="run `pfdoa gateway` as a separate process and score it")
    o.add_argument("--odom", action="store_true", help="stream the robot's odometry to the gateway (--odom FIFO)")
    o.add_argument("--gateway-arg", action="append", default=[], metavar="ARG", help="extra argument for the gateway")
    o.add_argument("--sweep", action="store_true", help="also run with each anchor silenced in turn (from 5 s on)")
    o.add_argument("--calibrate", type=int, default=0, metavar="N",
                   help="first walk the room N more times with ground truth (its own walks, the same walls), "
                        "fit them with `pfdoa calibrate` and give the gateway the fitted site (demo, walk; "
                        "needs --gateway)")
    o.add_argument("--score", metavar="JSONL", help="only score this gateway output against OUT_DIR's trace")
    o.add_argument("--plot", metavar="PNG", help="plot true vs estimated path")
    o.add_argument("--json", action="store_true", help="print the results as one JSON document")


def check_args(args: argparse.Namespace) -> None:
    """Option values the simulator would otherwise take as given (one line, exit 2)."""
    import os

    from pfdoa.api import check_number, check_seed
    from pfdoa.errors import InputError

    check_seed(args.seed)
    check_number("--duration", args.duration)
    for name in ("noise_db", "shadowing_db", "odom_noise", "wait"):
        check_number("--" + name.replace("_", "-"), getattr(args, name), strict=False)
    if args.track is not None and args.track not in (0, 1):
        raise InputError(f"--track must be 0 or 1, got {args.track}")
    if args.trace_out and os.path.isdir(args.trace_out):
        raise InputError(f"--trace-out {args.trace_out}: is a directory")
    if args.trace_out and os.path.exists(args.trace_out) and not os.path.isfile(args.trace_out):
        # its companions (.odom.csv, .summary.json, .reports.csv) go beside it: /dev/null.odom.csv is no place
        raise InputError(f"--trace-out {args.trace_out}: not a regular file (the trace's companion files are "
                         "written beside it)")
    from pfdoa.api import check_outputs

    check_outputs({"--trace-out": args.trace_out, "--plot": args.plot},
                  {"--config": [args.config] if args.config else [], "--score": [args.score] if args.score else []})
    if args.out_dir and os.path.exists(args.out_dir) and not os.path.isdir(args.out_dir):
        raise InputError(f"--out-dir {args.out_dir}: not a directory")
    if args.plot:
        from pfdoa.plotting import require

        require("--plot")


def run(args: argparse.Namespace) -> int:
    from pfdoa import signals

    check_args(args)
    if not backends.backend(args.anchor_backend).in_process:
        from pfdoasim.qemu_harness import main as qemu_main  # the one backend that is not in-process

        return qemu_main(args)  # SIGINT/SIGTERM raise at once; its finally blocks stop QEMU and the gateway
    from pfdoasim.harness import main

    # SIGINT/SIGTERM end the beacon loop (pfdoasim.runner): the trace and summary of the
    # beacons so far are written, a gateway gets the end of its stream and finishes, the
    # results are printed; then the one line and 130/143 (pfdoa.signals).
    stop = signals.active()
    with stop.graceful():
        rc = main(args)
    stop.raise_if_stopped("(the run so far is written and scored above)")
    return rc
