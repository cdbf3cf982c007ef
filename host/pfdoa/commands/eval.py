"""`pfdoa eval`: reproduce the paper's Table I on the committed datasets."""

from __future__ import annotations

import argparse
import logging
import sys

HELP = "reproduce Table I (Dataset 0/1/2, robot traces): RMSE and time per iteration per method"
DESCRIPTION = """\
Run every estimator on the paper's simulation (Dataset 0: three paths, RSS noise 1-4 dB,
fixed seeds), Dataset 1 (Wi-Fi/BLE/Zigbee), Dataset 2 (BLE channels 0, 39, 0-39) and the
herolab robot traces (calibrated on one run, scored on the others, with odometry), and
write a Markdown table of RMSE +- sd and median time per step beside the paper's numbers,
plus plots (RMSE vs particles / grid resolution / noise, paths, error CDF).

The data are the copies committed in the package (pfdoa/data, see its README.md). Numbers
are identical across runs except the timing columns. The full run takes a few minutes;
--quick (few trials, one noise level, no sweeps) takes well under a minute.

With --traces, only the given recorded runs are evaluated (any site, same formats:
t,anchor,rssi_dbm,gt_x,gt_y and optional <run>.odom.csv beside each trace): every method,
calibrated on one run and scored on each other run (--calibration cross, the default with
two or more traces) or with the site's radio model as given (--calibration none).

examples:
  pfdoa eval --out docs/results.md --plots docs/img
  pfdoa eval --quick --methods pf-doa wcl
  pfdoa eval --traces runs/*.csv --config site.toml --out runs-report.md --plots runs-img
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
    g = parser.add_argument_group("your own traces")
    g.add_argument("--traces", nargs="+", metavar="TRACE.csv", help="evaluate these runs instead of Table I (need gt_x,gt_y)")
    g.add_argument("--config", metavar="SITE.toml", help="site file of --traces")
    g.add_argument("--calibration", choices=("cross", "none"),
                   help="cross: calibrate on each run, score the others (default with >= 2 traces); none: site as given")
    g.add_argument("--window", type=float, default=1.0, metavar="S", help="grouping window in seconds (default 1.0)")
    g.add_argument("--no-odom", action="store_true", help="ignore <run>.odom.csv files beside the traces")


def _positive(name: str, v: int | None) -> None:
    from pfdoa.errors import InputError

    if v is not None and v < 1:
        raise InputError(f"{name} must be >= 1, got {v}")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pfdoa.errors import InputError
    from pfdoa.estimators import METHODS
    from pfdoa.evaluation import EvalConfig, evaluate

    for name in ("trials", "real_trials", "jobs"):
        _positive("--" + name.replace("_", "-"), getattr(args, name))
    methods = tuple(args.methods) if args.methods else METHODS
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    trace_opts = {}
    if args.traces:
        from pfdoa.evaluation import datasets as ds
        from pfdoa.site import load_site
        from pfdoa.trace import read_trace

        if not args.config:
            raise InputError("--traces needs --config SITE.toml")
        if not args.window > 0:
            raise InputError(f"--window must be > 0, got {args.window}")
        load_site(args.config)  # fail early, one line
        for p in args.traces:  # validate every file up front (InputError names file:line)
            if not read_trace(p).has_ground_truth:
                raise InputError(f"{p}: no ground truth columns gt_x,gt_y; evaluation needs them")
        calibration = args.calibration or ("cross" if len(args.traces) > 1 else "none")
        if calibration == "cross" and len(args.traces) < 2:
            raise InputError("--calibration cross needs at least two traces")
        ts = ds.trace_set(Path(args.config).resolve().parent.name or "traces", args.config, args.traces,
                          odometry=not args.no_odom, window_s=args.window)
        trace_opts = dict(trace_set=ts, calibration=calibration, table1=False, sweeps=False)
    elif args.config or args.calibration or args.no_odom:
        raise InputError("--config, --calibration and --no-odom go with --traces")
    if args.quick:
        cfg = EvalConfig(methods=methods, trials_sim=args.trials or 3, trials_real=args.real_trials or 1,
                         trials_traces=1, trials_sweep=1, noise_db=(2.0,), calibration_runs=1,
                         sweeps=False, seed=args.seed, jobs=args.jobs, quick=True, **trace_opts)
    else:
        cfg = EvalConfig(methods=methods, trials_sim=args.trials or 100, trials_real=args.real_trials or 10,
                         **{"sweeps": not args.no_sweeps, **trace_opts}, seed=args.seed, jobs=args.jobs)
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
    if args.traces:
        command += f" --traces ({len(args.traces)} files) --config {args.config} --calibration {trace_opts['calibration']}"
    _, text = evaluate(cfg, out=Path(args.out) if args.out else None,
                       plots_dir=Path(args.plots) if args.plots else None,
                       command=command, progress=not args.no_progress)
    if args.out:
        log.info("wrote %s", args.out)
    else:
        sys.stdout.write(text)
    return 0
