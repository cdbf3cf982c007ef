"""`pfdoa sim` behind the command line: build scenarios, run them against a gateway, score.

The gateway runs as a separate process (``python -m pfdoa gateway``, started and ended by
:class:`~pfdoasim.launch.GatewayProcess`), exactly as it would on a robot, and its
JSON-lines output is scored against the ground truth by beacon sequence number.

**Virtual time** (the default with ``--gateway``): the simulator writes every frame the
anchors send as a timed stream (the gateway's capture format, arrival = simulated send
time + the modelled transport latency) into the gateway's standard input
(``--replay-capture -``); the gateway's timers run on the stream's times and the odometry
travels in the same stream, so the estimates and the summary are a function of the seed
alone, byte for byte, however fast or loaded the machine. The site file's times are
simulated seconds, unscaled.

**Real time** (``--realtime``, or serving a port without ``--gateway``): frames go out on a
pseudo-terminal or SLCAN at ``--speed`` times real time, the gateway reads the port on its
wall clock, and the site file written for it expresses time in wall seconds (timers divided
by the speed-up, estimator rates scaled). For serving a live port; scores vary a little from
run to run.
"""

from __future__ import annotations

import argparse
import errno
import json
import logging
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pfdoa import signals
from pfdoa.api import write_key_file
from pfdoa.errors import InputError
from pfdoa.outfiles import write_whole
from pfdoa.protocol import defs
from pfdoa.site import load_site, require_wire_ids, site_to_toml
from pfdoasim import faults as faults_mod
from pfdoasim.backends import anchor_factory
from pfdoasim.calibration import Calibration, calibrate_room
from pfdoasim.launch import GatewayProcess, RunOptions
from pfdoasim.runner import Simulation, reports_path
from pfdoasim.scenario import AUTH_KEY_FILE, SCENARIOS, Scenario, build
from pfdoasim.score import Score, plot, read_estimates, read_report_times, score, score_by_time
from pfdoasim.transports import PtyTransport, SlcanPtyTransport, StdoutTransport, TimedStreamTransport, Transport

log = logging.getLogger(__name__)

# Gateway timers in simulated seconds. In real time they are divided by the speed-up for
# the gateway's wall clock, but never below what a loaded machine's scheduler honours.
GATEWAY_SIM_TIMING = {"set_timeout_s": 0.3, "stale_after_s": 2.0, "health_interval_s": 10.0,
                      "reconnect_min_s": 0.2, "reconnect_max_s": 1.0}
GATEWAY_WALL_FLOOR = {"set_timeout_s": 0.1, "stale_after_s": 0.25, "health_interval_s": 0.5,
                      "reconnect_min_s": 0.01, "reconnect_max_s": 0.05}
SLCAN_BITRATE = 500000
STARTUP_SKIP_S = 2.0  # the filter's convergence from a uniform prior is not scored
CLOCK_WARMUP_S = 10.0  # event-time errors are also reported from here on (the clock fits' start)
SWEEP_SILENCE_FROM_S = 5.0
REALTIME_GRACE_S = 2 * GATEWAY_WALL_FLOOR["set_timeout_s"] + 0.2  # a live gateway reads what is left


def estimator_options(site, speedup: float) -> dict:
    """The site's [estimator] table with its rates expressed in the gateway's time.

    In virtual time (``speedup`` 1) the gateway's seconds are simulated seconds and the table
    is unchanged. In real time at ``speedup`` times real time the robot really moves
    ``speedup`` times faster as far as the gateway's wall clock can tell: the estimator's
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
    # Only the particle filters have a motion prior; the others keep their table as it is.
    speed, velocity_time = getattr(est, "speed", None), getattr(est, "velocity_time", 0.0)
    if speed:
        table["speed"] = float(speed) * speedup
    if velocity_time:
        table["velocity_time"] = float(velocity_time) / speedup
    return table


def gateway_site_toml(sc: Scenario, speed: float) -> str:
    """The scenario's site file, with its timers and rates in the gateway's time.

    ``speed`` is simulated seconds per gateway second: 1 in virtual time (nothing is scaled);
    in real time the [gateway] timers (GATEWAY_SIM_TIMING, simulated seconds) are divided
    by it (floored, GATEWAY_WALL_FLOOR) and [estimator] rates scaled by
    :func:`estimator_options`. The site is the room as it truly is (its anchors and radio
    model), or ``sc.gateway_site`` when the scenario gives the gateway another one (a site
    fitted by ``pfdoa calibrate``: its tables, such as [radio_map], are kept).
    """
    k = speed if speed and speed > 0 else 1.0
    if k == 1.0:
        g = dict(GATEWAY_SIM_TIMING)
    else:
        g = {key: max(v / k, GATEWAY_WALL_FLOOR[key]) for key, v in GATEWAY_SIM_TIMING.items()}
        g["reconnect_max_s"] = max(g["reconnect_max_s"], g["reconnect_min_s"])
    g.update(sc.gateway)
    site = sc.site if sc.gateway_site is None else sc.gateway_site
    sections: dict[str, Any] = {} if sc.gateway_site is None else dict(site.sections)
    sections["gateway"] = {**sections.get("gateway", {}), **g}
    est = estimator_options(site, k)
    if est:
        sections["estimator"] = est
    beacons = sc.beacons_table()
    if beacons:
        sections["beacons"] = beacons
    return site_to_toml(replace(site, sections=sections))  # pfdoa.site's one writer


def make_port(kind: str, link: str | None) -> Transport:
    """A real-time port the gateway opens (pty or SLCAN over a pty), or standard output."""
    if kind == "pty":
        return PtyTransport(link)
    if kind == "slcan":
        return SlcanPtyTransport(link)
    if kind == "stdout":
        return StdoutTransport()
    raise InputError(f"--transport {kind} has no real-time port: python-can's virtual bus lives in one "
                     "process (use virtual time: drop --realtime; or --transport slcan)")


def gateway_inputs(transport: Transport, kind: str) -> list[str]:
    """The gateway's input options for a real-time port."""
    port = transport.paths()[0]
    if kind == "pty":
        return ["--serial", port]
    if kind == "slcan":
        return ["--can", f"slcan:{port}@{SLCAN_BITRATE},sleep_after_open=0"]
    raise InputError(f"--gateway in real time reads a port: use --transport pty or slcan, not {kind}")


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
    score: Score | None  # our beacon's
    gateway: dict | None  # the gateway's final counters (its --stats file)
    out_dir: Path
    beacon_scores: dict[str, Score | None] | None = None  # with other beacons: each one's, ours included


@dataclass(frozen=True)
class RunFiles:
    site: Path
    trace: Path
    estimates: Path
    stats: Path
    log: Path


def prepare_run_dir(sc: Scenario, opts: RunOptions, out_dir: Path) -> RunFiles:
    """Write the gateway's site file into out_dir and clear old outputs."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = RunFiles(out_dir / "site.toml", Path(opts.trace_out) if opts.trace_out else out_dir / "trace.csv",
                     out_dir / "gateway.jsonl", out_dir / "gateway.stats.json", out_dir / "gateway.log")
    write_whole(files.site, gateway_site_toml(sc, opts.time_scale), "the site file")
    if sc.auth_key is not None:  # the authenticated beacon's key file the site names (mode 0600)
        key_file = out_dir / AUTH_KEY_FILE
        key_file.unlink(missing_ok=True)
        write_key_file(key_file, sc.auth_key)
    for p in (files.estimates, files.stats):
        p.unlink(missing_ok=True)
    return files


def run_once(sc: Scenario, opts: RunOptions, out_dir: Path, label: str) -> RunResult:
    """One simulation run; with ``opts.gateway`` against a gateway process, scored."""
    files = prepare_run_dir(sc, opts, out_dir)
    make_anchor = anchor_factory(opts.anchor_backend, opts.core_lib)
    if opts.realtime:
        summary, sim, gw = _run_realtime(sc, opts, files, make_anchor, label, out_dir)
    else:
        sources = {a: f"serial{i}" for i, a in enumerate(sc.site.anchor_ids)} if not opts.can else None
        summary, sim, gw = run_virtual(sc, opts, files, make_anchor, sources)
    return collect(label, summary, sim, gw, files, out_dir)


def run_virtual(sc: Scenario, opts: RunOptions, files: RunFiles, make_anchor, sources: dict[int, str] | None,
                on_start=None) -> tuple[dict, Simulation, GatewayProcess | None]:
    """Virtual time: the timed stream into a gateway process (or onto standard output).

    Without a gateway (``--transport timed``) the stream goes to standard output.
    ``on_start(sim)`` runs once the simulation exists (the QEMU backend boots its anchors)."""
    gw = None
    if opts.gateway:
        gw = GatewayProcess(files.site, files.estimates, files.stats, files.log, ["--replay-capture", "-"],
                            sc.seed, opts.gateway_args, stream=True).start()
        stream = gw.stdin
    else:
        stream = sys.stdout.buffer
    tr = TimedStreamTransport(stream, can=opts.can, faults=sc.faults, sources=sources, odometry=opts.odom)
    try:
        sim = Simulation(sc, tr, make_anchor, speed=0.0, trace_out=files.trace)
        if on_start is not None:
            on_start(sim)
        tr.open()
        summary = sim.run()
        tr.close()
        summary["stream"] = {"lines": tr.lines, "frames": tr.frames}
    except BaseException:
        if gw is not None:
            gw.kill()
        raise
    if gw is not None:
        gw.finish()
    return summary, sim, gw


def _run_realtime(sc: Scenario, opts: RunOptions, files: RunFiles, make_anchor, label: str, out_dir: Path):
    """Real time: the simulator serves a port, the gateway (if any) reads it on its wall clock."""
    link = opts.link
    if opts.transport in ("pty", "slcan") and not link:
        link = str(out_dir / "anchors.tty")  # a stable path, and a port drop comes back at it
    transport = make_port(opts.transport, link)
    odom_fifo = out_dir / "odom.fifo" if opts.gateway and opts.odom else None
    if odom_fifo is not None:
        odom_fifo.unlink(missing_ok=True)
        os.mkfifo(odom_fifo)
    transport.open()
    gw = None
    odom_fd = None
    try:
        if opts.transport != "stdout":
            path = getattr(transport, "path", "")  # the pty behind a --link symlink
            real = f" ({path})" if path else ""
            for p in transport.paths():
                print(f"{label}: serving {opts.transport} on {p}{real}", file=sys.stderr if opts.gateway else sys.stdout,
                      flush=True)
        if opts.gateway:
            extra = (("--odom", str(odom_fifo)) if odom_fifo else ()) + opts.gateway_args
            gw = GatewayProcess(files.site, files.estimates, files.stats, files.log,
                                gateway_inputs(transport, opts.transport), sc.seed, extra).start()
        with signals.interruptible():  # waits that SIGINT/SIGTERM end (pfdoa.signals)
            odom_fd = open_fifo_writer(odom_fifo, opts.wait_s) if odom_fifo else None
            if not transport.wait_reader(opts.wait_s):
                raise InputError(f"nobody opened {transport.paths()[0]} within {opts.wait_s:g} s")
        sim = Simulation(sc, transport, make_anchor, speed=opts.speed, trace_out=files.trace, odom_fd=odom_fd)
        summary = sim.run()
        if gw is not None:
            gw.finish(grace_s=REALTIME_GRACE_S)
    except BaseException:
        if gw is not None:
            gw.kill()
        raise
    finally:
        if odom_fd is not None:
            os.close(odom_fd)
        if odom_fifo is not None:
            odom_fifo.unlink(missing_ok=True)
        transport.close()
    return summary, sim, gw


def collect(label: str, summary: dict, sim: Simulation, gw: GatewayProcess | None, files: RunFiles,
            out_dir: Path) -> RunResult:
    """The run's result: the gateway's counters and its score (if a gateway ran)."""
    res = RunResult(label, summary, None, None, out_dir)
    if gw is not None:
        rc = gw.proc.returncode if gw.proc is not None else None
        if rc not in (0, -2, 130, 143):
            log.warning("%s: gateway exited with status %s:\n%s", label, rc, "\n".join(gw.log_tail()))
        res.gateway = json.loads(files.stats.read_text()) if files.stats.exists() else None
        res.score = score_run(sim, files.estimates, files.trace) if files.estimates.exists() else None
        if sim.sc.others:
            res.beacon_scores = score_others(sim, files.estimates) if files.estimates.exists() else {}
            res.beacon_scores = {sim.sc.beacon_name: res.score, **res.beacon_scores}
    return res


def score_run(sim: Simulation, est_path: Path, trace_out: Path | None = None) -> Score:
    """Our beacon's estimates, by sequence number."""
    tr = sim.truth.arrays()
    times = None
    if trace_out is not None and not sim.speed:  # virtual time: the gateway's t is simulated time
        p = reports_path(trace_out)
        times = read_report_times(p) if p.exists() else None
    beacon = sim.sc.beacon_name if sim.sc.others else None
    return score(read_estimates(est_path, beacon), tr["x"], tr["y"], int(tr["seq"][0]) if tr["seq"].size else 0,
                 skip_s=STARTUP_SKIP_S, beacon_hz=sim.sc.beacon_hz, report_times=times, clock_warmup_s=CLOCK_WARMUP_S)


def score_others(sim: Simulation, est_path: Path) -> dict[str, Score | None]:
    """Each other beacon's estimates, by time (virtual time: the gateway's t is simulated
    time; in real time the times are not comparable, None)."""
    out: dict[str, Score | None] = {}
    for b in sim.sc.others:
        tr = sim.other_truth[b.name].arrays()
        out[b.name] = None if sim.speed else score_by_time(read_estimates(est_path, b.name, by_time=True), tr["t"],
                                                           tr["x"], tr["y"], skip_s=STARTUP_SKIP_S)
    return out


# -- reporting --------------------------------------------------------------------------
def format_score(s: Score | None) -> str:
    if s is None or s.n == 0:
        return "no estimates"
    unc = "".join(f"  {name} {100 * v:.0f} %" for name, v in (("in r95", s.in_r95), ("in cov", s.in_cov))
                  if v is not None)
    return (f"RMSE {s.rmse:.3f} m  median {s.median:.3f} m  p95 {s.p95:.3f} m  max {s.max:.3f} m{unc}  "
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
    out: list[tuple[str, Score | None, bool | None]] = [
        ("all tracks", combined([r for r in results if "silent" not in r.label]), None)]
    if sweep:
        for a in runs[0][1].site.anchor_ids:
            sel = [r for r in results if r.label.endswith(f"anchor {a} silent")]
            flagged = all(r.score is not None and a in r.score.flagged_stale for r in sel)
            out.append((f"all tracks, anchor {a} silent", combined(sel), flagged))
    return out


def report(results: list[RunResult], as_json: bool, pooled=(), calibrations: list[Calibration] | None = None) -> None:
    if as_json:
        doc: list[dict[str, Any]] = [{"label": r.label, "score": r.score.as_dict() if r.score else None, "sim": r.summary,
                "gateway": r.gateway,
                **({"beacons": {n: s.as_dict() if s else None for n, s in r.beacon_scores.items()}}
                   if r.beacon_scores is not None else {})} for r in results]
        doc += [{"label": label, "score": s.as_dict() if s else None, "flagged": flagged}
                for label, s, flagged in pooled]
        doc += [{"label": "calibration", "site": str(c.site_path), "walks": [str(w) for w in c.walks],
                 "report": c.report} for c in calibrations or ()]
        print(json.dumps(doc, indent=1))
        return
    for c in calibrations or ():
        print(f"calibration ({len(c.walks)} walks with ground truth, pfdoa calibrate -> {c.site_path}):")
        for line in c.report:
            print(f"  {line}")
    for r in results:
        print(f"{r.label}: {format_score(r.score)}")
        for name, s in (r.beacon_scores or {}).items():
            print(f"  beacon {name}: " + (f"mean {s.mean:.3f} m  " if s is not None and s.n else "") + format_score(s))
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
    scored = [r.score for r in results if r.score is not None and r.score.n]

    def pooled(name: str) -> float | None:  # a share over every run's estimates, when each run has it
        v = [getattr(s, name) for s in scored]
        return None if any(x is None for x in v) else sum(x * s.n for x, s in zip(v, scored)) / e.size

    return Score(int(e.size), beacons, float(np.sqrt(np.mean(e**2))), float(e.mean()), float(np.median(e)),
                 float(np.percentile(e, 95)), float(e.max()), e, np.arange(e.size),
                 in_r95=pooled("in_r95"), in_cov=pooled("in_cov"))


# -- entry point --------------------------------------------------------------------------
def scenarios_for(args: argparse.Namespace, walk: int = 0) -> list[tuple[str, Scenario]]:
    """The runs the command line asks for (``walk`` k >= 1: their k-th calibration walk)."""
    site = load_site(args.config) if args.config else None
    if site is not None:  # its anchors run our firmware and speak our frames
        require_wire_ids(site, args.config, "the simulator's anchors")
    name = args.scenario or ("walk" if site is not None else "demo")
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    tracks = [args.track] if args.track is not None else ([0, 1] if name == "espresense-6x4" else [0])
    fc = faults_mod.parse_faults(args.faults)
    out = []
    for tr in tracks:
        sc = build(name, seed=args.seed, duration_s=args.duration, site=site, track=tr, walk=walk)
        out.append((sc.name, override(replace(sc, faults=fc), args)))
    return out


def calibrated(args: argparse.Namespace, opts: RunOptions, runs: list[tuple[str, Scenario]], base_dir: Path
               ) -> tuple[list[tuple[str, Scenario]], list[Calibration]]:
    """With ``--calibrate N``: each run's room walked N times and fitted (pfdoasim.calibration),
    the run's gateway given the fitted site."""
    if not args.calibrate:
        return runs, []
    out, cals = [], []
    for i, (label, sc) in enumerate(runs):
        def walk(k: int, i: int = i) -> Scenario:
            return scenarios_for(args, walk=k)[i][1]

        cal = calibrate_room(walk, args.calibrate, opts, base_dir / "calibration", label, run_once)
        cals.append(cal)
        out.append((label, replace(sc, gateway_site=cal.site)))
    return out, cals


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
    if getattr(args, "peers", None) is not None:
        if not defs.FILTER_PERIOD_MIN <= args.peers <= defs.FILTER_PERIOD_MAX:
            raise InputError(f"--peers must be {defs.FILTER_PERIOD_MIN}..{defs.FILTER_PERIOD_MAX} ms, got {args.peers}")
        sc = replace(sc, peer_period_ms=args.peers)
    return sc


def check_options(args: argparse.Namespace, opts: RunOptions) -> None:
    """Combinations of options that cannot work: one line, InputError."""
    if not (args.speed >= 0 and args.speed < float("inf")):
        raise InputError(f"--speed must be a finite number >= 0, got {args.speed}")
    if not opts.gateway and opts.transport == "can-virtual":
        raise InputError("--transport can-virtual exists only inside a simulation with a gateway: add --gateway, "
                         "or use --transport timed to write the timed stream to standard output")
    if opts.realtime and opts.gateway and not opts.speed:
        raise InputError("--realtime --gateway needs a finite --speed (the gateway's timers run on the wall clock)")
    if opts.realtime and opts.transport in ("can-virtual", "timed"):
        raise InputError(f"--transport {opts.transport} has no real-time port: drop --realtime (virtual time) "
                         "or use --transport pty or slcan")


def default_out_dir(args: argparse.Namespace, sc: Scenario) -> Path:
    """``build/sim/SCENARIO``; a calibrated run's (``--calibrate``) is ``SCENARIO-calibrated``:
    its site file is the fitted one (``make demo``'s), which a later run of the same scenario
    without calibration (writing the room's true model as its site file) must not replace."""
    name = sc.name.split("/")[0]
    return Path("build/sim") / (f"{name}-calibrated" if getattr(args, "calibrate", 0) else name)


def main(args: argparse.Namespace) -> int:
    opts = RunOptions.from_args(args)
    check_options(args, opts)
    runs = scenarios_for(args)
    base_dir = Path(args.out_dir) if args.out_dir else default_out_dir(args, runs[0][1])
    if args.score:
        return score_only(args, runs[0][1], base_dir)
    if args.trace_out and (len(runs) > 1 or args.sweep):
        raise InputError("--trace-out names one trace; with several runs use --out-dir")
    runs, calibrations = calibrated(args, opts, runs, base_dir)
    results: list[RunResult] = []
    for label, sc in runs:
        sub = base_dir / label.split("/")[1] if "/" in label else base_dir
        results.append(run_once(sc, opts, sub, label))
        if args.sweep:
            for a in sc.site.anchor_ids:
                silence = faults_mod.Silence(a, SWEEP_SILENCE_FROM_S, 1e9)
                f = replace(sc.faults, silence=sc.faults.silence + (silence,))
                results.append(run_once(replace(sc, faults=f), opts, sub / f"silent{a}", f"{label} anchor {a} silent"))
    if opts.gateway:
        pooled = pooled_scores(results, runs, args.sweep) if len(runs) > 1 else []
        report(results, args.json, pooled, calibrations)
        r = results[0]
        if args.plot and r.score is not None:
            tr = trace_truth(r)
            plot(args.plot, tr[0], tr[1], read_estimates(r.out_dir / "gateway.jsonl"), r.score,
                 runs[0][1].site.positions, title=f"pfdoa sim: {r.label}")
            print(f"plot: {args.plot}")
    elif not args.json:
        # With --transport stdout or timed the frames own standard output.
        text_out = sys.stderr if args.transport in ("stdout", "timed") else sys.stdout
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
    if tr.gt_x is None or tr.gt_y is None:  # the simulator always writes them
        raise InputError(f"{r.out_dir / 'trace.csv'}: no gt_x,gt_y columns")
    _, first = np.unique(tr.t, return_index=True)
    return tr.gt_x[first], tr.gt_y[first]


def score_only(args: argparse.Namespace, sc: Scenario, out_dir: Path) -> int:
    """Score an existing gateway output against a trace written earlier (truth by seq)."""
    from pfdoa.trace import read_trace

    trace_path = Path(args.trace_out) if args.trace_out else out_dir / "trace.csv"
    tr = read_trace(trace_path)
    if tr.seq is None or tr.gt_x is None or tr.gt_y is None:
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
