"""`pfdoa eval`: reproduce the paper's Table I on the committed datasets."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the command's imports are lazy (pfdoa --help stays fast)
    from pathlib import Path

    from pfdoa.evaluation.datasets import TraceSet

HELP = "reproduce Table I (Dataset 0/1/2) and score every method on real sites (held-out runs, deployment ratios)"
DESCRIPTION = """\
Run every estimator on the paper's simulation (Dataset 0: three paths, RSS noise 1-4 dB,
fixed seeds), Dataset 1 (Wi-Fi/BLE/Zigbee), Dataset 2 (BLE channels 0, 39, 0-39) and the
real sites committed in pfdoa/data (the herolab Wi-Fi robot, BLE, Wi-Fi and Zigbee development
sites and three held-out BLE sites: each scored run calibrated on another run, held-out runs
reported apart), and write a Markdown report:
RMSE +- sd and median time per step beside the paper's numbers, per site pooled RMSE,
median and p90 as means over estimator seeds 0-9 with their spread, how often the truth
lies within the reported r95 and covariance, and plots (RMSE vs particles / grid
resolution / noise, paths, error CDF).

The data are the copies committed in the package (pfdoa/data, see its README.md). Numbers
are identical across runs except the timing columns. The full run takes several minutes
(--jobs 2 halves it); --quick (few trials, one seed, one calibration per scored run, no
sweeps) takes about a minute.

With --sites DIR, only real sites are evaluated: DIR is a site folder or a folder of them,
each with site.toml or anchors.json and runs <run>.csv (t,anchor,rssi_dbm,gt_x,gt_y[,seq])
with optional <run>.odom.csv. A run whose beacon column names several beacons is scored as
pfdoa replay tracks it: each beacon alone, with its own seed, the errors pooled (the
odometry goes with the readings that name no beacon). Every
run is calibrated on each other run of its site and scored (--calibration cross; with the
default --calibration auto, a folder holding some of a committed site's development runs,
recognised by content under any names, keeps that site's held-out protocol, and a folder with
a committed site's site file and none of its runs, such as other tracks of that room, is
calibrated on that site's development runs and scored as held out; --traces likewise), or
scored with
the site file as given (--calibration none, and a site of one run). A calibration run that
cannot determine every parameter (a static beacon: one distance per anchor) fits fewer, as
pfdoa calibrate does, and the report says which; one that cannot calibrate at all (too few
readings at known positions) calibrates nothing, named on stderr and under the report's
failures, and the other pairs are scored. In a folder of sites, a site whose files
cannot be read (a bad site file, an unreadable trace) is named on stderr and in the report,
every other site is scored, and the exit status is 2; a single site folder must read whole.
--traces with --config does the same for trace files of one site. A report of --sites or
--traces prints the comparison and no project-target PASS/FAIL lines (those are make eval's).

--calibration walk judges every site like a deployment (make eval-sites, docs/sites.md): each
run calibrated on ONE other run alone, as pfdoa calibrate of one walk writes the site, every
ordered pair, and each run scored uncalibrated with the site file as given; per site the ratio
of pf-doa's pooled RMSE to the best other method's, how often the truth lies within its r95
(all estimates, and the worst quarter of errors), with and without odometry where a site has
it; over sites the worst and the mean ratio. Held-out sites and runs are reported apart, and
so are new sites (yours: no run of theirs is one our decisions looked at), never as in-sample.
--sites takes several folders (the committed sites are in pfdoa/data).

examples:
  pfdoa eval --out docs/results.md --plots docs/img
  pfdoa eval --quick --methods pf-doa wcl
  pfdoa eval --sites ../shared/data/traces --out sites.md
  pfdoa eval --sites host/pfdoa/data build/sites --calibration walk --jobs 2 --out docs/sites.md
  pfdoa eval --sites host/pfdoa/data/kolakowski_ble_dev --calibration walk --quick
  pfdoa eval --traces runs/*.csv --config site.toml --out runs-report.md --plots runs-img

exit status: 0 ok, 1 an output could not be written, 2 bad options or input files (also a
  folder of sites with one that could not be read), 130/143 stopped by SIGINT/SIGTERM
  (--out is left as it was; the worker processes are stopped too)
"""

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="few trials, 2 dB only, no sweeps (< 1 min)")
    parser.add_argument("--trials", type=int, metavar="N", help="Dataset 0 trials per path and noise level (default 100, quick 3)")
    parser.add_argument("--real-trials", type=int, metavar="N", help="seeds per real-data experiment (default 10, quick 1)")
    parser.add_argument("--methods", nargs="+", metavar="M", help="methods to run (default: all)")
    parser.add_argument("--no-sweeps", action="store_true", help="skip the particle / resolution sweeps")
    parser.add_argument("--seed", type=int, default=20_240_521, help="base seed (default %(default)s)")
    parser.add_argument("--jobs", type=int, default=1, metavar="N", help="worker processes (default 1; results do not depend on it)")
    parser.add_argument("--out", metavar="FILE.md", help="write the Markdown report here (default: stdout)")
    parser.add_argument("--plots", metavar="DIR", help="write PNG plots here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--cache", metavar="DIR",
                        help="keep the results of the methods that draw no random numbers in DIR, by content (data, "
                             "calibration, options, the methods' code): a rerun computes only what changed "
                             "(make eval-sites: build/eval-cache)")
    g = parser.add_argument_group("real sites")
    g.add_argument("--sites", nargs="+", metavar="DIR",
                   help="evaluate the site folder(s) in each DIR instead of Table I and the committed sites")
    g.add_argument("--traces", nargs="+", metavar="TRACE.csv", help="evaluate these runs of one site (need gt_x,gt_y)")
    g.add_argument("--config", metavar="SITE.toml", help="site file of --traces")
    g.add_argument("--calibration", choices=("auto", "cross", "none", "walk"),
                   help="auto (default): the committed sites' held-out protocol, cross otherwise; cross: calibrate on "
                        "each run, score every other run; none: the site file as given; walk: judged like a "
                        "deployment (one calibration walk per pair, and uncalibrated; per-site ratios, make eval-sites)")
    g.add_argument("--seeds", type=int, metavar="N", help="estimator seeds 0..N-1 per real-site pair (default 10, quick 1)")
    g.add_argument("--window", type=float, metavar="S",
                   help="grouping window in seconds (default: 1, or a site's reporting interval when longer)")
    g.add_argument("--no-odom", action="store_true", help="ignore <run>.odom.csv files beside the traces")


def _positive(name: str, v: int | None) -> None:
    from pfdoa.errors import InputError

    if v is not None and v < 1:
        raise InputError(f"{name} must be >= 1, got {v}")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pfdoa.commands._common import check_number, check_seed
    from pfdoa.errors import InputError, Interrupted, OutputError
    from pfdoa.estimators import METHODS
    from pfdoa.evaluation import EvalConfig, evaluate
    from pfdoa.outfiles import write_stdout

    if args.plots:
        from pfdoa.plotting import require

        require("--plots")  # before the run, not after it
    for name in ("trials", "real_trials", "jobs", "seeds"):
        _positive("--" + name.replace("_", "-"), getattr(args, name))
    check_seed(args.seed)
    check_number("--window", args.window)
    methods = tuple(args.methods) if args.methods else METHODS
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    from pfdoa.evaluation import sites as sites_mod

    if args.sites and args.traces:
        raise InputError("--sites and --traces are alternatives; give one")
    if args.calibration == "walk" and not (args.sites or args.traces):
        raise InputError("--calibration walk goes with --sites or --traces (make eval-sites)")
    if args.calibration == "walk" and args.plots:
        raise InputError("--plots goes with Table I or --calibration auto/cross/none; walk's report has none")
    site_opts: dict = {}
    calibration = args.calibration or "auto"
    if args.traces:
        from pfdoa.evaluation import datasets as ds
        from pfdoa.site import load_site
        from pfdoa.trace import read_trace

        if not args.config:
            raise InputError("--traces needs --config SITE.toml")
        load_site(args.config)  # fail early, one line
        for p in args.traces:  # validate every file up front (InputError names file:line)
            if not read_trace(p).has_ground_truth:
                raise InputError(f"{p}: no ground truth columns gt_x,gt_y; evaluation needs them")
        ts = ds.trace_set(Path(args.config).resolve().parent.name or "traces", args.config, args.traces,
                          odometry=not args.no_odom, window_s=args.window)
        if calibration in ("auto", "walk"):
            ts = sites_mod.with_room_runs(ts, odometry=not args.no_odom, window_s=args.window)
        site_opts = dict(sites=(ts,))
    elif args.sites:
        sets: list[TraceSet] = []
        refused: list[str] = []
        for root in args.sites:
            got, bad = _readable_sites(Path(root), odometry=not args.no_odom, window_s=args.window,
                                       room_runs=calibration in ("auto", "walk"))
            sets += got
            refused += bad
        seen: dict[str, str] = {}
        for ts in sets:  # a site is named by its folder: two of one name would be one site's figures
            if ts.name in seen:
                raise InputError(f"--sites: two site folders named {ts.name!r} ({seen[ts.name]}, {ts.site_path})")
            seen[ts.name] = ts.site_path
        site_opts = dict(sites=tuple(sets), refused=tuple(refused))
    elif args.config:
        raise InputError("--config goes with --traces")
    elif args.no_odom or args.window is not None:
        site_opts = dict(sites=sites_mod.committed_sites(odometry=not args.no_odom, window_s=args.window))
    if args.traces:
        _check_sites(site_opts["sites"])  # every file read now: a bad one is one line, before minutes of work
    if site_opts and (args.sites or args.traces):
        _check_outputs(args, site_opts["sites"])
    if site_opts:
        for ts in site_opts["sites"]:
            if calibration != "none" and len(ts.runs) < 2:
                log.warning("%s: one run, no other run to calibrate it on: scored with its site file as given",
                            ts.name)
        site_opts["calibration"] = calibration
        if args.sites or args.traces:
            site_opts.update(table1=False, sweeps=False)
    elif args.calibration:
        site_opts["calibration"] = args.calibration
    if args.cache:
        try:
            Path(args.cache).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--cache {args.cache}: cannot use it: {exc.strerror or exc}") from None
        site_opts["cache_dir"] = args.cache  # the report does not say: it changes no number
    if args.quick:
        cfg = EvalConfig(methods=methods, trials_sim=args.trials or 3, trials_real=args.real_trials or 1,
                         trials_sweep=1, noise_db=(2.0,), site_seeds=args.seeds or 1, site_pairs=1,
                         sweeps=False, seed=args.seed, jobs=args.jobs, quick=True,
                         **{k: v for k, v in site_opts.items() if k != "sweeps"})
    else:
        cfg = EvalConfig(methods=methods, trials_sim=args.trials or 100, trials_real=args.real_trials or 10,
                         site_seeds=args.seeds or 10, **{"sweeps": not args.no_sweeps, **site_opts},
                         seed=args.seed, jobs=args.jobs)
    command = "pfdoa eval" + (" --quick" if args.quick else "")
    if args.trials:
        command += f" --trials {args.trials}"
    if args.real_trials:
        command += f" --real-trials {args.real_trials}"
    if args.methods:
        command += " --methods " + " ".join(methods)
    if args.no_sweeps:
        command += " --no-sweeps"
    if args.seed != 20_240_521:
        command += f" --seed {args.seed}"
    if args.seeds:
        command += f" --seeds {args.seeds}"
    if args.sites:
        command += " --sites " + " ".join(args.sites)
    if args.traces:
        named = " ".join(map(str, args.traces)) if len(args.traces) <= 3 else f"({len(args.traces)} files)"
        command += f" --traces {named} --config {args.config}"
    if args.calibration:
        command += f" --calibration {args.calibration}"
    if args.no_odom:
        command += " --no-odom"
    if args.window is not None:
        command += f" --window {args.window:g}"
    if args.out is None and sys.stdout is None:
        raise InputError("standard output is closed; give --out FILE.md")
    if args.out and Path(args.out).is_dir():
        raise InputError(f"--out {args.out}: is a directory")
    # The report is written whole at the end (pfdoa.outfiles: atomically, or through to a
    # device or FIFO); SIGINT/SIGTERM raise at once (pfdoa.signals), the pool's workers are
    # stopped, and the old report stays whole.
    try:
        _, text = evaluate(cfg, out=Path(args.out) if args.out else None,
                           plots_dir=Path(args.plots) if args.plots else None, command=command,
                           progress=not args.no_progress)
    except Interrupted as exc:
        raise Interrupted(exc.signum, f"{exc}: {args.out} is left as it was" if args.out else f"{exc}: nothing "
                          "written") from None
    except OSError as exc:  # the report's or the plots' folder could not be made
        raise OutputError(f"{exc.filename or args.out}: cannot write: {exc.strerror or exc}") from None
    if args.out:
        log.info("wrote %s", args.out)
    else:
        write_stdout(text, "the report")
    refused = site_opts.get("refused", ())
    if refused:  # the rest is reported; the exit status still says that some input was bad
        log.error("%d site folder(s) of %s not evaluated (each named above and in the report)", len(refused),
                  ", ".join(args.sites))
        return 2
    return 0


def _readable_sites(root: Path, *, odometry: bool, window_s: float | None, room_runs: bool
                    ) -> tuple[tuple[TraceSet, ...], tuple[str, ...]]:
    """The sites of ``--sites`` with every file read now (a bad one is one line, before minutes
    of work), and the error lines of the folders that could not be read. A folder that is
    itself a site must read whole; in a folder of sites, one unreadable site is named (logged
    and in the report) and the others are scored."""
    from pfdoa.errors import ConfigError, InputError
    from pfdoa.evaluation import sites as sites_mod

    if not root.is_dir() or sites_mod.site_file(root) is not None:
        sets = sites_mod.find_sites(root, odometry=odometry, window_s=window_s, room_runs=room_runs)
        _check_sites(sets)
        return sets, ()
    good: list[TraceSet] = []
    refused: list[str] = []
    for d in sites_mod.site_dirs(root):
        try:
            ts = sites_mod.site_folder(d, odometry=odometry, window_s=window_s, room_runs=room_runs)
            _check_sites((ts,))
        except (ConfigError, InputError) as exc:
            log.error("%s (site %s not evaluated)", exc, d.name)
            refused.append(str(exc))
            continue
        good.append(ts)
    if not good:
        why = (f"none of its {len(refused)} site folder(s) could be read (each named above)" if refused else
               sites_mod.NO_SITES)
        raise InputError(f"{root}: {why}")
    return tuple(good), tuple(refused)


def _check_sites(sets) -> None:
    """Load every site file, trace and odometry file of the site folders (InputError or
    ConfigError naming the file), as the evaluation will."""
    from pfdoa.errors import InputError
    from pfdoa.evaluation.datasets import load_site_cached
    from pfdoa.trace import check_anchor_ids, odometry_part, read_odometry, read_trace

    for ts in sets:
        site = load_site_cached(str(ts.site_path))
        for _run, trace_path, odom_path in ts.runs:
            tr = read_trace(trace_path)
            if not tr.has_ground_truth:
                raise InputError(f"{trace_path}: no ground truth columns gt_x,gt_y; evaluation needs them")
            check_anchor_ids(tr, site.anchor_ids, str(ts.site_path))
            if odom_path:
                read_odometry(odom_path)
                odometry_part(tr)  # several beacons: the odometry needs the readings that name none


def _check_outputs(args, sets) -> None:
    """--out must not be one of the evaluated files (it would be overwritten)."""
    from pfdoa.commands._common import check_outputs

    inputs: dict[str, list[str]] = {"a site file": [str(ts.site_path) for ts in sets],
                                    "a trace": [r[1] for ts in sets for r in ts.runs],
                                    "an odometry file": [r[2] for ts in sets for r in ts.runs if r[2]]}
    check_outputs({"--out": args.out}, inputs)
