"""`pfdoa sim --anchor-backend qemu`: runs with QEMU anchors (:mod:`pfdoasim.backends.qemu`).

:func:`run_once` is ``pfdoa sim --anchor-backend qemu``: four (or N) QEMU anchors on N
ptys, the simulator's radio model feeding each one, scored like every other simulator run.

* **Virtual time** (the default): the simulator holds each anchor's pty itself. After every
  injected reading it waits for exactly the bytes a shadow host core
  (:mod:`pfdoasim.backends.c`, the same C sources built for the host) sends for the same reading
  at the same tick: a barrier that needs no clock, and a live check that the Cortex-M3
  image is byte-identical to the host build (mismatches are counted, ``byte_mismatches``).
  Those bytes are stamped with the simulated time and go through the link faults into the
  gateway's timed stream (``serial0..N-1``), like the host backends' frames. The wall-clock
  timeouts there are hang guards only.
* **Real time** (``--realtime``): ``pfdoa gateway --serial A --serial B ...`` reads the ptys
  itself while the simulator injects at ``--speed`` times real time (link faults cannot be
  applied then: the frames never pass through the simulator).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pfdoa.errors import InputError
from pfdoasim.backends.c import CoreLibrary
from pfdoasim.backends.qemu import SIL, QemuPool, build_images
from pfdoasim.harness import (
    REALTIME_GRACE_S,
    check_options,
    collect,
    format_score,
    pooled_scores,
    prepare_run_dir,
    report,
    run_virtual,
    scenarios_for,
    trace_truth,
)
from pfdoasim.launch import GatewayProcess, RunOptions
from pfdoasim.runner import Simulation
from pfdoasim.score import plot, read_estimates
from pfdoasim.transports import Transport as SimTransport

log = logging.getLogger(__name__)


class NullTransport(SimTransport):
    """The simulator's transport when the anchors talk to the gateway themselves (real time)."""

    name = "qemu-pty"
    is_can = False

    def __init__(self, paths: list[str]) -> None:
        self._paths = paths

    def open(self) -> None:
        pass

    def paths(self) -> list[str]:
        return self._paths

    def send(self, frames) -> int:
        return 0


def run_once(sc, opts, out_dir: Path, label: str):
    """One `pfdoa sim --anchor-backend qemu` run: N QEMU anchors, the simulator injecting
    readings; in virtual time their frames go into the gateway's timed stream, in real
    time the gateway reads their ptys. Returns the harness's RunResult."""
    if opts.transport not in ("pty", "stdout", "timed"):
        raise InputError("--anchor-backend qemu: each QEMU anchor is its own serial port (UART framing: "
                         "--transport pty)")
    f = sc.faults
    if opts.realtime:
        unsupported = [k for k in ("loss", "dup", "reorder", "ber", "portdrop") if getattr(f, k)]
        if f.latency:
            unsupported.append("jitter/batch/stall")
        if f.silence and not f.reboot:
            unsupported.append("silence without reboot=1")
        if unsupported:
            raise InputError("--anchor-backend qemu --realtime: the frames go straight from QEMU to the gateway, so "
                             f"link faults cannot be applied ({', '.join(unsupported)}); use virtual time")
    build_images()
    files = prepare_run_dir(sc, opts, out_dir)
    shadows = CoreLibrary.load(opts.core_lib).factory() if not opts.realtime else None
    pool = QemuPool(sc.site.anchor_ids, sc.anchor, shadows=shadows, filter_table=sc.filter_table())
    gw = None
    try:
        if not opts.realtime:
            sources = {a: f"serial{i}" for i, a in enumerate(sc.site.anchor_ids)}

            def boot(sim) -> None:  # the Simulation drew each anchor's boot tick: boot the firmware with it
                pool.start(sim.boot_ms)
                for a, p in zip(pool.ids, pool.paths()):
                    log.info("%s: QEMU anchor %d (mps2-an385, %s) on %s", label, a, SIL, p)

            summary, sim, gw = run_virtual(sc, opts, files, pool, sources, on_start=boot)
        else:
            sim = Simulation(sc, NullTransport([]), pool, speed=opts.speed, trace_out=files.trace)
            pool.start(sim.boot_ms)
            sim.transport = NullTransport(pool.paths())
            for a, p in zip(pool.ids, pool.paths()):
                print(f"{label}: QEMU anchor {a} (mps2-an385, {SIL}) on {p}",
                      file=sys.stderr if opts.gateway else sys.stdout, flush=True)
            if opts.gateway:
                inputs = [x for p in pool.paths() for x in ("--serial", p)]
                gw = GatewayProcess(files.site, files.estimates, files.stats, files.log, inputs, sc.seed,
                                    opts.gateway_args).start()
                _wait_ports_open(pool, gw.proc, opts.wait_s)
            else:
                print(f"{label}: waiting {opts.wait_s:g} s for a gateway on the ports: pfdoa gateway --config "
                      f"{files.site} " + " ".join(f"--serial {p}" for p in pool.paths()), flush=True)
                _wait_ports_open(pool, None, opts.wait_s)
            summary = sim.run()
            if gw is not None:
                gw.finish(grace_s=REALTIME_GRACE_S)
    except BaseException:
        if gw is not None:
            gw.kill()
        raise
    finally:
        pool.stop()
    summary["qemu"] = pool.summary()
    res = collect(f"{label}", summary, sim, gw, files, out_dir)
    if res.score is not None:
        res.summary["qemu"]["positions"] = sample_positions(sim, files.estimates)
    return res


def sample_positions(sim, est_path: Path, every_s: float = 5.0) -> list[dict]:
    """Some of the gateway's positions next to the ground truth (matched by beacon seq)."""
    est = read_estimates(est_path)
    tr = sim.truth.arrays()
    if est.seq.size == 0 or tr["seq"].size == 0:
        return []
    k = est.seq - int(tr["seq"][0])  # beacon index
    step = max(1, int(round(every_s * sim.sc.beacon_hz)))
    out = []
    for i in np.flatnonzero((k >= 0) & (k < tr["x"].size) & (k % step == 0)):
        b = int(k[i])
        out.append({"t": round(float(tr["t"][b]), 2), "seq": int(tr["seq"][b]),
                    "x": round(float(est.x[i]), 3), "y": round(float(est.y[i]), 3),
                    "true_x": round(float(tr["x"][b]), 3), "true_y": round(float(tr["y"][b]), 3),
                    "error_m": round(float(np.hypot(est.x[i] - tr["x"][b], est.y[i] - tr["y"][b])), 3)})
    return out


def format_positions(rows: list[dict]) -> list[str]:
    lines = ["  positions from the gateway (every 5 s of the run):",
             "       t/s    seq   est x   est y  true x  true y  error/m"]
    for r in rows:
        lines.append(f"    {r['t']:>6.1f}  {r['seq']:>5}  {r['x']:>6.2f}  {r['y']:>6.2f}  {r['true_x']:>6.2f}"
                     f"  {r['true_y']:>6.2f}  {r['error_m']:>7.2f}")
    return lines


def main(args) -> int:
    """`pfdoa sim --anchor-backend qemu`: the harness's scenarios, reporting and plot, each
    run with QEMU anchors (:func:`run_once`)."""
    opts = RunOptions.from_args(args)
    if opts.transport == "pty" and not args.gateway and not args.realtime:
        opts = RunOptions(**{**opts.__dict__, "realtime": True})  # serving the ptys: real time
    check_options(args, opts)
    if args.sweep or args.score:
        raise InputError("--anchor-backend qemu: --sweep and --score are not supported; use the c backend")
    runs = scenarios_for(args)
    base_dir = Path(args.out_dir) if args.out_dir else Path("build/sim") / (runs[0][1].name.split("/")[0] + "-qemu")
    results = []
    for label, sc in runs:
        sub = base_dir / label.split("/")[1] if "/" in label else base_dir
        results.append(run_once(sc, opts, sub, f"{label} (QEMU anchors)"))
    if args.gateway:
        pooled = pooled_scores(results, runs, False) if len(runs) > 1 else []
        if args.json:
            report(results, True, pooled)
        else:
            for r in results:
                for line in format_positions(r.summary.get("qemu", {}).get("positions", [])):
                    print(line)
                print(f"{r.label}: {format_score(r.score)}")
                for line in format_qemu_links(r):
                    print(line)
            for label, sc_, _ in pooled:
                print(f"{label}: {format_score(sc_)}")
        if args.plot and results[0].score is not None:
            r = results[0]
            gx, gy = trace_truth(r)
            plot(args.plot, gx, gy, read_estimates(r.out_dir / "gateway.jsonl"), r.score,
                 runs[0][1].site.positions, title=f"pfdoa sim: {r.label}")
            print(f"plot: {args.plot}")
    else:
        for r in results:
            print(f"{r.label}: {r.summary['beacons']} beacons injected; trace in {r.out_dir}")
    return 0


def format_qemu_links(res) -> list[str]:
    """Per QEMU anchor: readings injected, and what the gateway made of its port."""
    injected = res.summary.get("qemu", {}).get("injected", {})
    gw = (res.gateway or {}).get("anchors", {})
    lines = ["  QEMU anchor  readings injected | gateway: reports received  lost  dup  late  reboots"]
    for a, n in injected.items():
        g = gw.get(a, {})
        lines.append(f"  {a:>11}  {n:>17} | {g.get('received', '-'):>26}  {g.get('lost', '-'):>4}"
                     f"  {g.get('duplicates', '-'):>3}  {g.get('late', '-'):>4}  {g.get('reboots', '-'):>7}")
    q = res.summary.get("qemu", {})
    if q.get("byte_mismatches") is not None:
        lines.append(f"  byte identity with the host build, checked live: {sum(q['bytes_compared'].values())} bytes, "
                     f"{q['byte_mismatches']} differ")
    if res.gateway:
        errs = res.gateway.get("errors", {})
        lines.append("  gateway: " + f"{res.gateway.get('frames', 0)} frames, {res.gateway.get('status', 0)} STATUS, "
                     f"{res.gateway.get('sets', 0)} anchor sets ({res.gateway.get('complete', 0)} complete); "
                     "decode errors: " + (" ".join(f"{k}={v}" for k, v in errs.items()) or "none"))
    return lines


def _wait_ports_open(pool: QemuPool, proc: subprocess.Popen | None, timeout_s: float) -> None:
    """Wait until the gateway (proc, or any other process) has every pty open: its pyserial
    open flushes pending input, so injecting earlier could lose the first reports."""
    end = time.monotonic() + timeout_s
    want = {os.path.realpath(p) for p in pool.paths()}
    while True:
        if proc is not None and proc.poll() is not None:
            raise InputError(f"the gateway exited with status {proc.returncode} before opening the ports")
        if proc is not None:
            opened = _open_ptys(proc.pid)
        else:
            ours = {os.getpid()} | {q.proc.pid for q in pool.anchors.values() if q.proc is not None}
            opened = set().union(*(_open_ptys(int(d)) for d in os.listdir("/proc")
                                   if d.isdigit() and int(d) not in ours))
        if want <= opened:
            return
        if time.monotonic() > end:
            raise InputError(f"the gateway did not open the QEMU ports within {timeout_s:g} s")
        time.sleep(0.02)


def _open_ptys(pid: int) -> set[str]:
    out = set()
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                out.add(os.readlink(f"/proc/{pid}/fd/{fd}"))
            except OSError:
                pass
    except OSError:
        pass
    return out
