"""`pfdoa sim`: the software-in-the-loop simulator (package pfdoasim)."""

from __future__ import annotations

import argparse

HELP = "simulate anchors (real firmware core) and a moving robot; feed a gateway; score it"
DESCRIPTION = """\
Simulate a robot carrying a beacon through a site. Every anchor is an instance of the
real firmware core (firmware/build/host/libpfdoa_anchor.so, built on demand) fed with
simulated radio readings; its frames go out on a pseudo-terminal (a USB serial port to
the gateway), SLCAN over a pseudo-terminal, python-can's in-process virtual bus, or
standard output, paced at --speed times real time, with optional --faults.
Ground truth is written alongside (--out-dir: trace.csv t,anchor,rssi_dbm,gt_x,gt_y,seq;
trace.odom.csv t,dx,dy,dtheta; trace.summary.json with every injected fault counted;
site.toml for the gateway).

With --gateway the simulator starts `pfdoa gateway` as a separate process on the port,
then scores its estimates against the ground truth (matched by beacon sequence number):
RMSE, median, p95 and max error, per-anchor link statistics, and a PNG (--plot).
Without --gateway it prints the port path(s) and waits (--wait) for a reader.

scenarios: demo, paper-boundary, paper-inside, paper-diagonal, espresense-6x4 (two walking
tracks; --sweep also silences each anchor in turn), walk (needs --config SITE.toml)

faults (comma-separated): loss=P dup=P reorder=P ber=RATE drift_ppm=PPM reboot=1
  silence=ANCHOR@START+DURATION portdrop=START+DURATION   (times in simulated seconds)

examples:
  pfdoa sim --scenario demo --gateway --odom --speed 10 --plot build/demo.png
  pfdoa sim --scenario espresense-6x4 --gateway --odom --sweep --speed 20   (median/p95/max, each anchor silenced)
  pfdoa sim --scenario demo --gateway --transport slcan --faults loss=0.02,dup=0.01,ber=1e-5,portdrop=20+2
  pfdoa sim --scenario demo --link /tmp/anchors.tty &   pfdoa gateway --config build/sim/demo/site.toml --serial /tmp/anchors.tty
  pfdoa sim --score build/sim/demo/gateway.jsonl --out-dir build/sim/demo
  pfdoa sim --scenario demo --anchor-backend qemu --gateway --speed 5   (four QEMU anchors, four ports)
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
    g.add_argument("--anchor-backend", default="c", choices=("c", "mpy", "py-mean", "qemu"),
                   help="c: the firmware core via ctypes (default); mpy: the MicroPython anchor under "
                        "CPython; py-mean: unfiltered test double; qemu: the Cortex-M3 firmware image "
                        "under QEMU, one serial port per anchor (pfdoasim.qemu)")
    g.add_argument("--core-lib", metavar="PATH", help="anchor core shared library (default: build it)")
    t = parser.add_argument_group("transport")
    t.add_argument("--transport", default="pty", choices=("pty", "slcan", "can-virtual", "stdout"))
    t.add_argument("--link", metavar="PATH", help="stable symlink to the pty (needed for portdrop faults)")
    t.add_argument("--can-channel", default="pfdoa-sim", metavar="NAME", help="virtual CAN channel name")
    t.add_argument("--speed", type=float, default=10.0, metavar="X", help="times real time (0 = as fast as possible)")
    t.add_argument("--wait", type=float, default=30.0, metavar="S", help="wait this long for a reader to open the port")
    o = parser.add_argument_group("gateway and output")
    o.add_argument("--out-dir", metavar="DIR", help="where trace, site file, gateway output go (default build/sim/SCENARIO)")
    o.add_argument("--trace-out", metavar="PATH", help="trace CSV path (default OUT_DIR/trace.csv)")
    o.add_argument("--gateway", action="store_true", help="run `pfdoa gateway` as a separate process and score it")
    o.add_argument("--odom", action="store_true", help="stream the robot's odometry to the gateway (--odom FIFO)")
    o.add_argument("--gateway-arg", action="append", default=[], metavar="ARG", help="extra argument for the gateway")
    o.add_argument("--sweep", action="store_true", help="also run with each anchor silenced in turn (from 5 s on)")
    o.add_argument("--score", metavar="JSONL", help="only score this gateway output against OUT_DIR's trace")
    o.add_argument("--plot", metavar="PNG", help="plot true vs estimated path")
    o.add_argument("--json", action="store_true", help="print the results as one JSON document")


def run(args: argparse.Namespace) -> int:
    if args.anchor_backend == "qemu":
        from pfdoasim.qemu import main as qemu_main

        return qemu_main(args)
    from pfdoasim.harness import main

    return main(args)
