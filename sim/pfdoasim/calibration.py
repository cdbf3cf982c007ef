"""Calibrate a simulated room as a deployment does: walk it with ground truth, fit, then run.

``pfdoa sim --calibrate N``: before the run, the robot walks the room N more times
(:func:`pfdoasim.scenario.build` with ``walk`` = 1..N: the same walls, receiver offsets and
anchor clocks, a walk and a run's randomness of its own), each through the anchors'
firmware and a gateway process that records the readings it reassembled with the walk's
ground truth (``--readings-out``, ``--ground-truth``), as a robot recording calibration walks
under a tracking system would. ``pfdoa calibrate`` (the command, in its own process) fits
the radio model and the radio map on those recordings; the run's gateway is then given the
fitted site file instead of the room's true model.

The model the simulator's radio follows (log-distance, plus shadowing that walls cast the
same way at every pass) is one the estimator can only partly learn from such walks (the
radio map); the rest is misfit that pf-doa's reported uncertainty follows online
(docs/simulator.md).
"""

from __future__ import annotations

import csv
import logging
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from pfdoa.errors import InputError
from pfdoa.outfiles import open_stream, write_whole
from pfdoa.site import Site, load_site
from pfdoasim.launch import RunOptions
from pfdoasim.scenario import Scenario

log = logging.getLogger(__name__)

MAX_WALKS = 20


@dataclass(frozen=True)
class Calibration:
    """What the calibration walks gave: the fitted site file, and what ``pfdoa calibrate`` said."""

    site_path: Path
    site: Site
    report: list[str]  # pfdoa calibrate's report (stdout lines)
    walks: tuple[Path, ...]  # the recorded readings, with ground truth


def write_truth(sc: Scenario, path: Path) -> None:
    """The walk's ground truth (t, x, y) in the format ``pfdoa gateway --ground-truth`` reads."""
    with open_stream(str(path), "a walk's ground truth")[0] as fh:
        w = csv.writer(fh)
        w.writerow(("t", "x", "y"))
        for t, x, y, _h in sc.track:
            w.writerow((f"{t:.4f}", f"{x:.4f}", f"{y:.4f}"))


def calibrate_room(walk: Callable[[int], Scenario], walks: int, opts: RunOptions, out_dir: Path, label: str,
                   run: Callable[[Scenario, RunOptions, Path, str], object]) -> Calibration:
    """Record ``walks`` calibration walks (``walk(k)`` builds the k-th) with ``run`` (the
    simulator against a gateway process, in virtual time) and fit them with ``pfdoa calibrate``.

    The walks' gateways get only the recording options, not the run's ``--gateway-arg``s
    (a live view or a recording belongs to the run). Raises InputError when the walks gave
    nothing to fit or ``pfdoa calibrate`` refused them."""
    if not 1 <= walks <= MAX_WALKS:
        raise InputError(f"--calibrate must be between 1 and {MAX_WALKS} walks, got {walks}")
    if not opts.gateway or opts.realtime:
        raise InputError("--calibrate records the walks through a gateway in virtual time: add --gateway, "
                         "drop --realtime")
    out_dir.mkdir(parents=True, exist_ok=True)
    readings = []
    for k in range(1, walks + 1):
        sc = walk(k)
        d = out_dir / f"walk{k}"
        d.mkdir(parents=True, exist_ok=True)
        truth, rec = d / "truth.csv", d / "readings.csv"
        write_truth(sc, truth)
        rec.unlink(missing_ok=True)
        wopts = replace(opts, gateway_args=(f"--readings-out={rec}", f"--ground-truth={truth}"), trace_out=None)
        run(sc, wopts, d, f"{label} calibration walk {k}")
        if not rec.exists() or rec.stat().st_size == 0:
            raise InputError(f"{label}: calibration walk {k} recorded no readings ({d / 'gateway.log'})")
        readings.append(rec)
    site_in = out_dir / "site.toml"  # the room's site file as the gateway gets it, before fitting
    write_whole(site_in, (out_dir / "walk1" / "site.toml").read_text(), "the room's site file")
    fitted = out_dir / "fitted.toml"
    cmd = [sys.executable, "-m", "pfdoa", "-q", "calibrate", *map(str, readings), "--config", str(site_in),
           "--out", str(fitted)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise InputError(f"{label}: pfdoa calibrate on the calibration walks failed: {last}")
    return Calibration(fitted, load_site(fitted), proc.stdout.rstrip("\n").splitlines(), tuple(readings))
