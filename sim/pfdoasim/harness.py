"""`pfdoa sim` behind the command line: build scenarios, run them against a gateway, score.

The gateway runs as a separate process (``python -m pfdoa gateway``) on the simulator's
port, exactly as it would on a robot: it gets the site file the simulator writes (with
the gateway's timers scaled to the speed-up, so they mean the same in simulated time),
and its JSON-lines output is scored against the ground truth by beacon sequence number.
"""

from __future__ import annotations

import argparse
import errno
import json
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pfdoa.errors import InputError
from pfdoa.site import load_site, site_to_toml
from pfdoasim import faults as faults_mod
from pfdoasim.anchors import anchor_factory
from pfdoasim.runner import Simulation
from pfdoasim.scenario import SCENARIOS, Scenario, build
from pfdoasim.score import Score, plot, read_estimates, score
from pfdoasim.transports import CanVirtualTransport, PtyTransport, SlcanPtyTransport, StdoutTransport, Transport

log = logging.getLogger(__name__)

# Gateway timers in simulated seconds; divided by the speed-up for the gateway's wall clock,
# but never below what a loaded machine's scheduler honours (a 20 ms stall must not split a
# set or mark an anchor stale).
GATEWAY_SIM_TIMING = {"set_timeout_s": 0.3, "stale_after_s": 2.0, "health_interval_s": 10.0,
                      "reconnect_min_s": 0.2, "reconnect_max_s": 1.0}
GATEWAY_WALL_FLOOR = {"set_timeout_s": 0.1, "stale_after_s": 0.25, "health_interval_s": 0.5,
                      "reconnect_min_s": 0.01, "reconnect_max_s": 0.05}
SLCAN_BITRATE = 500000
STARTUP_SKIP_S = 2.0  # the filter's convergence from a uniform prior is not scored
SWEEP_SILENCE_FROM_S = 5.0


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


def estimator_options(site, speedup: float) -> dict:
    """The site's [estimator] table with its rates expressed in wall-clock time.

    The gateway stamps sets with its own (wall) clock, so at ``speedup`` times real time
    the robot really moves ``speedup`` times faster as far as the estimator can tell: its
    motion prior (``speed``, m/s) is multiplied and its correlation time divided by it.
    Defaults come from an instance built with the site's options, so they follow the
    estimator's own defaults.
    """
    from pfdoa.estimators import make_estimator

    table = dict(site.sections.get("estimator", {}))
    if speedup == 1.0:
        return table
    method = table.get("method", "pf-doa")
    est = make_estimator(method, site, **{k: v for k, v in table.items() if k != "method"})
    if getattr(est, "speed", None):
        table["speed"] = float(est.speed) * speedup
    if getattr(est, "velocity_time", 0.0):
        table["velocity_time"] = float(est.velocity_time) / speedup
    return table


def gateway_site_toml(sc: Scenario, speed: float) -> str:
    """The scenario's site file, with its timers and rates in the gateway's wall-clock time.

    [gateway] timers (GATEWAY_SIM_TIMING, in simulated seconds) are divided by the
    speed-up; [estimator] rates are scaled by :func:`estimator_options`.
    """
    k = speed if speed and speed > 0 else 1.0
    g = {key: max(v / k, GATEWAY_WALL_FLOOR[key]) for key, v in GATEWAY_SIM_TIMING.items()}
    g["reconnect_max_s"] = max(g["reconnect_max_s"], g["reconnect_min_s"])
    g.update(sc.gateway)
    lines = ["", "[gateway]"] + [f"{key} = {_toml_value(v)}" for key, v in g.items()]
    est = estimator_options(sc.site, k)
    if est:
        lines += ["", "[estimator]"] + [f"{key} = {_toml_value(v)}" for key, v in est.items()]
    return site_to_toml(sc.site) + "\n".join(lines) + "\n"


def make_transport(kind: str, link: str | None, can_channel: str) -> Transport:
    if kind == "pty":
        return PtyTransport(link)
    if kind == "slcan":
        return SlcanPtyTransport(link)
    if kind == "can-virtual":
        return CanVirtualTransport(can_channel)
    if kind == "stdout":
        return StdoutTransport()
    raise InputError(f"unknown transport {kind!r}")


def gateway_command(transport: Transport, kind: str, site_path: Path, out_path: Path, stats_path: Path,
                    extra: list[str]) -> list[str]:
    port = transport.paths()[0]
    cmd = [sys.executable, "-m", "pfdoa", "-q", "gateway", "--config", str(site_path), "--out", str(out_path),
           "--stats", str(stats_path)]
    if kind == "pty":
        cmd += ["--serial", port]
    elif kind == "slcan":
        cmd += ["--can", f"slcan:{port}@{SLCAN_BITRATE},sleep_after_open=0"]
    else:
        raise InputError(f"--gateway runs the gateway in another process: use --transport pty or slcan, not {kind}")
    return cmd + extra


def open_fifo_writer(path: Path, timeout_s: float) -> int:
    """Open a FIFO for non-blocking writing once its reader (the gateway) has it open."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            return os.open(path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno != errno.ENXIO or time.monotonic() > end:
                raise InputError(f"nobody opened the odometry FIFO {path} within {timeout_s:g} s") from None
            time.sleep(0.01)


@dataclass
class RunResult:
    label: str
    summary: dict
    score: Score | None
    gateway: dict | None  # the gateway's final counters (its --stats file)
    out_dir: Path


def prepare_run_dir(sc: Scenario, args: argparse.Namespace, out_dir: Path) -> tuple[Path, Path, Path, Path]:
    """Write the gateway's site file into out_dir and clear old outputs.

    Returns (site_path, trace_out, est_path, stats_path)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    site_path = out_dir / "site.toml"
    site_path.write_text(gateway_site_toml(sc, args.speed))
    trace_out = Path(args.trace_out) if args.trace_out else out_dir / "trace.csv"
    est_path, stats_path = out_dir / "gateway.jsonl", out_dir / "gateway.stats.json"
    for p in (est_path, stats_path):
        p.unlink(missing_ok=True)
    return site_path, trace_out, est_path, stats_path


def run_once(sc: Scenario, args: argparse.Namespace, out_dir: Path, label: str) -> RunResult:
    """One simulation run; with ``args.gateway`` against a gateway process, scored."""
    make_anchor = anchor_factory(args.anchor_backend, args.core_lib)
    site_path, trace_out, est_path, stats_path = prepare_run_dir(sc, args, out_dir)
    link = args.link
    if args.transport in ("pty", "slcan") and not link:
        link = str(out_dir / "anchors.tty")  # a stable path, and a port drop comes back at it
    odom_fifo = out_dir / "odom.fifo" if args.gateway and args.odom else None
    if odom_fifo is not None:
        odom_fifo.unlink(missing_ok=True)
        os.mkfifo(odom_fifo)
    transport = make_transport(args.transport, link, args.can_channel)
    transport.open()
    if args.gateway and args.transport == "can-virtual":
        summary, sim, rc = _run_in_process(sc, args, transport, make_anchor, site_path, est_path, stats_path,
                                           odom_fifo, trace_out, label)
    else:
        summary, sim, rc = _run_with_process(sc, args, transport, make_anchor, site_path, est_path, stats_path,
                                             odom_fifo, trace_out, label, out_dir)
    res = RunResult(label, summary, None, None, out_dir)
    if args.gateway:
        if rc not in (0, -signal.SIGINT, 130):
            gw_log = out_dir / "gateway.log"
            tail = gw_log.read_text(errors="replace").splitlines()[-5:] if gw_log.exists() else []
            log.warning("%s: gateway exited with status %s:\n%s", label, rc, "\n".join(tail))
        res.gateway = json.loads(stats_path.read_text()) if stats_path.exists() else None
        res.score = score_run(sim, est_path) if est_path.exists() else None
    return res


def _run_with_process(sc, args, transport, make_anchor, site_path, est_path, stats_path, odom_fifo, trace_out,
                      label, out_dir):
    """The simulator here, the gateway (if any) as a child process on the port."""
    proc = None
    odom_fd = None
    try:
        if args.transport != "stdout":
            real = f" ({transport.path})" if getattr(transport, "path", "") else ""
            for p in transport.paths():
                print(f"{label}: serving {args.transport} on {p}{real}", file=sys.stderr if args.gateway else sys.stdout,
                      flush=True)
        if args.gateway:
            extra = ["--seed", str(sc.seed)] + (["--odom", str(odom_fifo)] if odom_fifo else []) + args.gateway_arg
            cmd = gateway_command(transport, args.transport, site_path, est_path, stats_path, extra)
            log.info("gateway: %s", " ".join(cmd))
            gw_log = open(out_dir / "gateway.log", "w")
            proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=gw_log, stderr=subprocess.STDOUT)
            gw_log.close()
        odom_fd = open_fifo_writer(odom_fifo, args.wait) if odom_fifo else None
        if not transport.wait_reader(args.wait):
            raise InputError(f"nobody opened {transport.paths()[0]} within {args.wait:g} s")
        sim = Simulation(sc, transport, make_anchor, speed=args.speed, trace_out=trace_out, odom_fd=odom_fd)
        summary = sim.run()
        if proc is not None:
            # Let the last sets time out in the gateway, then stop it like an operator would.
            time.sleep(2 * GATEWAY_WALL_FLOOR["set_timeout_s"] + 0.2)
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    finally:
        if odom_fd is not None:
            os.close(odom_fd)
        if odom_fifo is not None:
            odom_fifo.unlink(missing_ok=True)
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        transport.close()
    return summary, sim, (proc.returncode if proc is not None else None)


def _run_in_process(sc, args, transport, make_anchor, site_path, est_path, stats_path, odom_fifo, trace_out,
                    label):
    """Virtual CAN exists only inside one process: the gateway runs here (main thread, so
    its signal handling works) and the simulator in a thread, which stops the gateway with
    SIGINT when it is done, as an operator would."""
    import threading

    from pfdoa.cli import main as pfdoa_main

    done = threading.Event()
    out: dict = {}

    def simulate() -> None:
        odom_fd = None
        try:
            # The gateway opens the odometry FIFO (blocking until we do) before its bus.
            odom_fd = open_fifo_writer(odom_fifo, args.wait) if odom_fifo else None
            if not transport.wait_reader(args.wait):
                raise InputError(f"the gateway did not open {transport.paths()[0]} within {args.wait:g} s")
            sim = Simulation(sc, transport, make_anchor, speed=args.speed, trace_out=trace_out, odom_fd=odom_fd)
            out["summary"], out["sim"] = sim.run(), sim
            time.sleep(2 * GATEWAY_WALL_FLOOR["set_timeout_s"] + 0.2)
        except BaseException as exc:  # reported in the main thread
            out["error"] = exc
        finally:
            if odom_fd is not None:
                os.close(odom_fd)
            if not done.is_set():
                os.kill(os.getpid(), signal.SIGINT)

    cmd = ["-q", "gateway", "--config", str(site_path), "--out", str(est_path), "--stats", str(stats_path),
           "--can", transport.paths()[0], "--seed", str(sc.seed),
           "--duration", str(args.wait + sc.duration_s / max(args.speed, 1e-3) + 10.0)]
    cmd += (["--odom", str(odom_fifo)] if odom_fifo else []) + args.gateway_arg
    th = threading.Thread(target=simulate, name="sim", daemon=True)
    th.start()
    try:
        rc = pfdoa_main(cmd)
    finally:
        done.set()
        th.join()
        transport.close()
        if odom_fifo is not None:
            odom_fifo.unlink(missing_ok=True)
    if "error" in out:
        raise out["error"]
    return out["summary"], out["sim"], rc


def score_run(sim: Simulation, est_path: Path) -> Score:
    tr = sim.truth.arrays()
    return score(read_estimates(est_path), tr["x"], tr["y"], int(tr["seq"][0]) if tr["seq"].size else 0,
                 skip_s=STARTUP_SKIP_S, beacon_hz=sim.sc.beacon_hz)


# -- reporting --------------------------------------------------------------------------
def format_score(s: Score | None) -> str:
    if s is None or s.n == 0:
        return "no estimates"
    return (f"RMSE {s.rmse:.3f} m  median {s.median:.3f} m  p95 {s.p95:.3f} m  max {s.max:.3f} m  "
            f"({s.n} estimates, {100 * s.coverage:.0f}% of beacons)")


def format_links(res: RunResult) -> list[str]:
    f = res.summary["faults"]
    gw_anchors = (res.gateway or {}).get("anchors", {})
    flagged = res.score.stale_fraction if res.score is not None else {}
    lines = ["  reports: anchor  sent by core  dropped  dup  reord  corrupt  silenced  port down"
             " | gateway: received  lost  dup  late  flagged stale"]
    for a, c in f["per_anchor"].items():
        g = gw_anchors.get(a, {})
        fl = flagged.get(int(a), 0.0)
        lines.append(
            f"  {a:>15}  {c['reports']:>12}  {c['dropped_reports']:>7}  {c['duplicated_reports']:>3}  {c['reordered']:>5}"
            f"  {c['corrupted_reports']:>7}  {c['silenced_reports']:>8}  {c['port_down_reports']:>9} |"
            f" {g.get('received', '-'):>17}  {g.get('lost', '-'):>4}  {g.get('duplicates', '-'):>3}"
            f"  {g.get('late', '-'):>4}  {100 * fl:>11.0f} %"
        )
    if res.gateway:
        errs = res.gateway.get("errors", {})
        lines.append("  gateway decode errors: " + (" ".join(f"{k}={v}" for k, v in errs.items()) or "none")
                     + f"; reconnects: {sum(res.gateway.get('reconnects', {}).values())}")
    return lines


def pooled_scores(results: list[RunResult], runs, sweep: bool) -> list[tuple[str, Score | None, bool | None]]:
    """(label, pooled score over the tracks, silent anchor flagged in every run or None)."""
    out = [("all tracks", combined([r for r in results if "silent" not in r.label]), None)]
    if sweep:
        for a in runs[0][1].site.anchor_ids:
            sel = [r for r in results if r.label.endswith(f"anchor {a} silent")]
            flagged = all(r.score is not None and a in r.score.flagged_stale for r in sel)
            out.append((f"all tracks, anchor {a} silent", combined(sel), flagged))
    return out


def report(results: list[RunResult], as_json: bool, pooled=()) -> None:
    if as_json:
        doc = [{"label": r.label, "score": r.score.as_dict() if r.score else None, "sim": r.summary,
                "gateway": r.gateway} for r in results]
        doc += [{"label": label, "score": s.as_dict() if s else None, "flagged": flagged}
                for label, s, flagged in pooled]
        print(json.dumps(doc, indent=1))
        return
    for r in results:
        print(f"{r.label}: {format_score(r.score)}")
        if r.score is not None and r.score.flagged_stale:
            print(f"  gateway flagged stale: {', '.join(str(a) for a in r.score.flagged_stale)}")
        for line in format_links(r):
            print(line)
    for label, s, flagged in pooled:
        print(f"{label}: {format_score(s)}" + ("" if flagged is None else f"  flagged stale: {'yes' if flagged else 'NO'}"))


def combined(results: list[RunResult]) -> Score | None:
    """Pool the errors of several runs (the two tracks) into one set of figures."""
    errs = [r.score.errors for r in results if r.score is not None and r.score.n]
    if not errs:
        return None
    e = np.concatenate(errs)
    beacons = sum(r.score.beacons for r in results if r.score is not None)
    return Score(int(e.size), beacons, float(np.sqrt(np.mean(e**2))), float(e.mean()), float(np.median(e)),
                 float(np.percentile(e, 95)), float(e.max()), e, np.arange(e.size))


# -- entry point --------------------------------------------------------------------------
def scenarios_for(args: argparse.Namespace) -> list[tuple[str, Scenario]]:
    site = load_site(args.config) if args.config else None
    name = args.scenario or ("walk" if site is not None else "demo")
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    tracks = [args.track] if args.track is not None else ([0, 1] if name == "espresense-6x4" else [0])
    fc = faults_mod.parse_faults(args.faults)
    out = []
    for tr in tracks:
        sc = build(name, seed=args.seed, duration_s=args.duration, site=site, track=tr)
        out.append((sc.name, override(replace(sc, faults=fc), args)))
    return out


def override(sc: Scenario, args: argparse.Namespace) -> Scenario:
    """Command-line overrides of a scenario's beacon, radio, channel and odometry."""
    ch = sc.channel
    if getattr(args, "noise_db", None) is not None:
        if not args.noise_db >= 0:
            raise InputError(f"--noise-db must be >= 0, got {args.noise_db}")
        ch = replace(ch, noise_db=args.noise_db)
    if getattr(args, "shadowing_db", None) is not None:
        if not args.shadowing_db >= 0:
            raise InputError(f"--shadowing-db must be >= 0, got {args.shadowing_db}")
        ch = replace(ch, shadowing_db=args.shadowing_db)
    if getattr(args, "multipath", None):
        p, _, db = args.multipath.partition(":")
        try:
            prob, loss = float(p), float(db) if db else ch.multipath_db
        except ValueError:
            raise InputError(f"--multipath: expected P[:DB], got {args.multipath!r}") from None
        if not (0 <= prob <= 1 and loss >= 0):
            raise InputError(f"--multipath: probability in [0, 1] and a loss >= 0 dB, got {args.multipath!r}")
        ch = replace(ch, multipath_prob=prob, multipath_db=loss)
    sc = replace(sc, channel=ch)
    if getattr(args, "beacon_hz", None) is not None:
        if not 0.1 <= args.beacon_hz <= 1000:
            raise InputError(f"--beacon-hz must be in [0.1, 1000], got {args.beacon_hz}")
        sc = replace(sc, beacon_hz=args.beacon_hz)
    if getattr(args, "radio", None):
        sc = replace(sc, radio=args.radio)
    if getattr(args, "odom_noise", None) is not None:
        if not args.odom_noise >= 0:
            raise InputError(f"--odom-noise must be >= 0, got {args.odom_noise}")
        sc = replace(sc, odometry=replace(sc.odometry, trans_frac=args.odom_noise, rot_frac=args.odom_noise))
    return sc


def main(args: argparse.Namespace) -> int:
    if args.speed < 0:
        raise InputError(f"--speed must be >= 0, got {args.speed}")
    if args.gateway and not args.speed:
        raise InputError("--gateway needs a finite --speed (the gateway's timers run on the wall clock)")
    if args.transport == "can-virtual" and not args.gateway:
        raise InputError("--transport can-virtual exists only inside this process: add --gateway")
    runs = scenarios_for(args)
    base_dir = Path(args.out_dir) if args.out_dir else Path("build/sim") / runs[0][1].name.split("/")[0]
    if args.score:
        return score_only(args, runs[0][1], base_dir)
    if args.trace_out and (len(runs) > 1 or args.sweep):
        raise InputError("--trace-out names one trace; with several runs use --out-dir")
    results: list[RunResult] = []
    for label, sc in runs:
        sub = base_dir / label.split("/")[1] if "/" in label else base_dir
        results.append(run_once(sc, args, sub, label))
        if args.sweep:
            for a in sc.site.anchor_ids:
                silence = faults_mod.Silence(a, SWEEP_SILENCE_FROM_S, 1e9)
                f = replace(sc.faults, silence=sc.faults.silence + (silence,))
                results.append(run_once(replace(sc, faults=f), args, sub / f"silent{a}", f"{label} anchor {a} silent"))
    if args.gateway:
        pooled = pooled_scores(results, runs, args.sweep) if len(runs) > 1 else []
        report(results, args.json, pooled)
        if args.plot and results[0].score is not None:
            r = results[0]
            tr = trace_truth(r)
            plot(args.plot, tr[0], tr[1], read_estimates(r.out_dir / "gateway.jsonl"), r.score,
                 runs[0][1].site.positions, title=f"pfdoa sim: {r.label}")
            print(f"plot: {args.plot}")
    elif not args.json:
        # With --transport stdout the frames own standard output.
        text_out = sys.stderr if args.transport == "stdout" else sys.stdout
        for r in results:
            t = r.summary["faults"]["total"]
            print(f"{r.label}: {r.summary['beacons']} beacons, {t['frames']} frames, {t['sent']} sent; "
                  f"trace in {r.out_dir}", file=text_out)
    else:
        report(results, True)
    return 0


def trace_truth(r: RunResult) -> tuple[np.ndarray, np.ndarray]:
    from pfdoa.trace import read_trace

    tr = read_trace(r.out_dir / "trace.csv")
    _, first = np.unique(tr.t, return_index=True)
    return tr.gt_x[first], tr.gt_y[first]


def score_only(args: argparse.Namespace, sc: Scenario, out_dir: Path) -> int:
    """Score an existing gateway output against a trace written earlier (truth by seq)."""
    from pfdoa.trace import read_trace

    trace_path = Path(args.trace_out) if args.trace_out else out_dir / "trace.csv"
    tr = read_trace(trace_path)
    if tr.seq is None or not tr.has_ground_truth:
        raise InputError(f"{trace_path}: needs seq and gt_x,gt_y columns")
    _, first = np.unique(tr.t, return_index=True)
    beacon_hz = 1.0 / float(np.median(np.diff(tr.t[first]))) if first.size > 1 else 1.0
    s = score(read_estimates(args.score), tr.gt_x[first], tr.gt_y[first], int(tr.seq[first[0]]),
              skip_s=STARTUP_SKIP_S, beacon_hz=beacon_hz)
    if args.json:
        print(json.dumps(s.as_dict()))
    else:
        print(f"{args.score}: {format_score(s)}")
    if args.plot:
        plot(args.plot, tr.gt_x[first], tr.gt_y[first], read_estimates(args.score), s, sc.site.positions)
    return 0
