"""How a simulation run is set up: its options, and the one way the gateway process is started and ended.

* :class:`RunOptions` - a frozen record of what ``pfdoa sim`` was asked (built once from the
  command line by :meth:`RunOptions.from_args`; library code never sees ``argparse``).
* :class:`GatewayProcess` - ``python -m pfdoa gateway`` as a separate process, exactly as
  on a robot, with **one shutdown rule**: when the simulation is over its input ends and
  the gateway finishes by itself. In virtual time the gateway reads a timed stream on
  standard input, and the end of the stream (EOF) is the end of its input: it drains, flushes
  and exits. On live ports (real time) there is no end of input a gateway can see, so
  after the simulation it gets ``grace_s`` of wall time to read what is still in the ports'
  buffers, then SIGINT, as an operator would stop it. Either way it is killed only if it
  has not exited within ``hang_s`` (a hang guard, never an accuracy input).
"""

from __future__ import annotations

import argparse
import logging
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from pfdoa.outfiles import open_stream

log = logging.getLogger(__name__)

HANG_S = 120.0  # a gateway still running this long after its input ended is killed


@dataclass(frozen=True)
class RunOptions:
    """What to run: anchor backend, transport, time base, gateway (see ``pfdoa sim --help``).

    ``realtime`` False is virtual time: frames travel as a timed stream and nothing waits
    for the wall clock; ``transport`` then only chooses the framing (UART for pty/stdout,
    CAN for slcan/can-virtual). ``realtime`` True serves real ports at ``speed`` x real time.
    """

    anchor_backend: str = "c"
    core_lib: str | None = None
    transport: str = "pty"
    realtime: bool = False
    speed: float = 10.0
    link: str | None = None
    can_channel: str = "pfdoa-sim"
    wait_s: float = 30.0
    gateway: bool = False
    odom: bool = False
    gateway_args: tuple[str, ...] = ()
    trace_out: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "RunOptions":
        transport = args.transport
        # Serving a port or raw bytes to an external gateway is real time by nature; the
        # timed stream (and a run with its own gateway, unless --realtime) is virtual.
        realtime = bool(args.realtime) or (not args.gateway and transport != "timed")
        return cls(anchor_backend=args.anchor_backend, core_lib=args.core_lib, transport=transport,
                   realtime=realtime, speed=float(args.speed), link=args.link, can_channel=args.can_channel,
                   wait_s=float(args.wait), gateway=bool(args.gateway), odom=bool(args.odom),
                   gateway_args=tuple(args.gateway_arg), trace_out=args.trace_out)

    @property
    def can(self) -> bool:
        return self.transport in ("slcan", "can-virtual")

    @property
    def time_scale(self) -> float:
        """How many simulated seconds pass per second the gateway measures (1 in virtual time)."""
        return self.speed if self.realtime and self.speed > 0 else 1.0


class GatewayProcess:
    """``pfdoa gateway`` in its own process on the given inputs (see the module doc)."""

    def __init__(self, site_path: Path, out_path: Path, stats_path: Path, log_path: Path, inputs: list[str],
                 seed: int, extra: tuple[str, ...] = (), stream: bool = False) -> None:
        self.cmd = [sys.executable, "-m", "pfdoa", "-q", "gateway", "--config", str(site_path), "--out",
                    str(out_path), "--stats", str(stats_path), "--seed", str(seed), *inputs, *extra]
        self.log_path = log_path
        self.stream = stream  # its input is a timed stream on our pipe to its stdin
        self.proc: subprocess.Popen | None = None

    def start(self) -> "GatewayProcess":
        log.info("gateway: %s", " ".join(self.cmd))
        with open_stream(str(self.log_path), "the gateway's log")[0] as gw_log:
            self.proc = subprocess.Popen(self.cmd, stdin=subprocess.PIPE if self.stream else subprocess.DEVNULL,
                                         stdout=gw_log, stderr=subprocess.STDOUT)
        return self

    @property
    def stdin(self):
        return self.proc.stdin if self.proc is not None else None

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def finish(self, grace_s: float = 0.0, hang_s: float = HANG_S) -> int | None:
        """The input has ended: let the gateway finish (the one shutdown rule); its status."""
        p = self.proc
        if p is None:
            return None
        if self.stream and p.stdin is not None:
            try:
                p.stdin.close()  # EOF: the end of the stream is the end of the run
            except (BrokenPipeError, OSError):
                pass
        elif p.poll() is None:
            try:
                p.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                p.send_signal(signal.SIGINT)
        try:
            return p.wait(timeout=hang_s)
        except subprocess.TimeoutExpired:
            log.error("the gateway did not exit within %.0f s of the end of its input: killed", hang_s)
            p.kill()
            return p.wait()

    def kill(self) -> None:
        """Only for errors in the simulator itself."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def log_tail(self, n: int = 5) -> list[str]:
        try:
            return self.log_path.read_text(errors="replace").splitlines()[-n:]
        except OSError:
            return []
