"""The experiments of Table I (and the sweeps behind the plots) as seeded, independent jobs.

A job is one (block, experiment, trial): it builds its data from its own seed, runs every
variant (method row) on the same data, and returns per-variant results. Seeds derive only
from the config seed and the job's identity (never from the order or the set of methods
run), so any subset, any worker count and any run order give the same numbers.

Blocks:

* ``dataset0`` - the paper's simulation (6 x 6 m, anchors at the corners, three paths at
  0.1 m steps, n = 3, A = -40 dBm, Gaussian RSS noise 1-4 dB). The estimators get the true
  radio model (as in the paper).
* ``dataset1-paper`` / ``dataset1-fitted`` - Dataset 1 with the paper's radio values, and
  with A, n fitted (Huber) on the 10 ``testdata`` points, which are not scored.
* ``dataset2`` - the diagonal points of Dataset 2: two-fold by alternating points; each
  fold is scored with A, n, offsets fitted (Huber) on the raw readings of the OTHER fold,
  same channels.
* ``sites`` - real sites, recorded runs in the common formats (by default the committed
  development sites, :func:`pfdoa.evaluation.sites.committed_sites`; any folder with
  ``pfdoa eval --sites``): each scored run is calibrated (Huber) on another run of its site
  and scored with every method on the same windows and calibration, for every pair that
  :func:`pfdoa.evaluation.sites.pairs` gives (held-out runs, development runs or, for a
  site without a protocol, every pair), with and without odometry where the site has it,
  for estimator seeds 0..``site_seeds - 1`` (seed s is ``pfdoa replay --seed s``; a method
  that draws no random numbers runs once). With ``calibration="walk"`` (the deployment
  protocol, :func:`pfdoa.evaluation.sites.walk_pairs`) a calibrated run gets the site as
  ``pfdoa calibrate`` of the one calibration run writes it (:func:`calibrated_site`), and an
  uncalibrated one the site file as given.
* ``sweep-particles``, ``sweep-resolution`` - Dataset 0 at 2 dB for the plots.
"""

from __future__ import annotations

import functools
import logging
import math
import multiprocessing
import traceback
import zlib
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from pfdoa import signals
from pfdoa.errors import InputError, Interrupted
from pfdoa.estimators import uses_rng
from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation import sites as sites_mod
from pfdoa.evaluation.progress import Progress
from pfdoa.evaluation.runner import RunResult, Variant, run_sequence, within_r95

log = logging.getLogger(__name__)

ODOMETRY_METHODS = ("pf-doa", "pf-doa-paper")  # also get a "(no odom)" row where odometry exists
SWEEP_PARTICLES = (25, 50, 100, 200, 400, 800)
SWEEP_RESOLUTION_M = (0.1, 0.2, 0.5, 1.0)
SWEEP_EXPONENTS = (2.0, 3.0, 4.0)


@dataclass(frozen=True)
class EvalConfig:
    methods: tuple[str, ...]
    trials_sim: int = 100  # Dataset 0 trials (noise draws) per path and noise level
    trials_real: int = 10  # seeds per real-data experiment (data fixed, estimator rng varies)
    trials_sweep: int = 10
    noise_db: tuple[float, ...] = ds.D0_NOISE_DB
    main_noise_db: float = 2.0
    sites: tuple[ds.TraceSet, ...] = field(default_factory=sites_mod.committed_sites)
    calibration: str = "auto"  # see pfdoa.evaluation.sites.pairs: "auto", "cross", "none" or "walk"
    site_seeds: int = 10  # estimator seeds 0..site_seeds-1 per (calibration run, scored run) pair
    site_pairs: int | None = None  # at most this many calibration runs per (role, scored run); None = all
    site_roles: tuple[str, ...] | None = None  # score only these roles (tools/sites_study.py: development only)
    site_variants: tuple[Variant, ...] | None = None  # rows for the sites (default: every method, +/- odometry)
    table1: bool = True  # Datasets 0, 1, 2
    sweeps: bool = True
    d2_channel_sets: tuple[str, ...] = tuple(ds.D2_CHANNEL_SETS)
    seed: int = 20_240_521
    jobs: int = 1
    quick: bool = False
    # Site folders of `pfdoa eval --sites` that could not be read (one error line each): the
    # report names them; every other site is scored.
    refused: tuple[str, ...] = ()
    # Keep the results of the methods that draw no random numbers here, by content
    # (pfdoa.evaluation.cache); None: compute everything.
    cache_dir: str | None = None


@dataclass(frozen=True)
class Job:
    block: str
    experiment: str
    trial: int
    params: tuple
    variants: tuple[Variant, ...]
    keep_paths: bool = False  # return the estimates (for path plots)


@dataclass
class JobResult:
    job: Job
    results: dict[str, RunResult]  # variant label -> result
    truth: np.ndarray | None = None
    skipped: str = ""  # why nothing was scored: the pair's calibration run cannot calibrate its site


class CalibrationFailed(InputError):
    """A run cannot calibrate its site (too few readings at known positions, ...): the pairs
    calibrated on it are left out of an evaluation, not the evaluation."""


def _stable(text: str) -> int:
    return zlib.crc32(text.encode())


def job_seed(cfg: EvalConfig, job: Job, stream: str) -> np.random.SeedSequence:
    return np.random.SeedSequence([cfg.seed, _stable(job.block), _stable(job.experiment), job.trial,
                                   _stable(repr(job.params)), _stable(stream)])


def variants_for(methods: tuple[str, ...], with_odometry: bool) -> tuple[Variant, ...]:
    out = []
    for m in methods:
        out.append(Variant(m, m, with_odometry))
        if with_odometry and m in ODOMETRY_METHODS:
            out.append(Variant(f"{m} (no odom)", m, False))
    return tuple(out)


# ----------------------------------------------------------------------------- job list
def build_jobs(cfg: EvalConfig) -> list[Job]:
    jobs: list[Job] = []
    v_odom = variants_for(cfg.methods, True)
    v_plain = variants_for(cfg.methods, False)
    if cfg.table1:
        jobs += _table1_jobs(cfg, v_odom, v_plain)
    if cfg.sites:
        jobs += _site_jobs(cfg)
    if cfg.sweeps and cfg.table1:
        jobs += _sweep_jobs(cfg)
    return jobs


def _table1_jobs(cfg: EvalConfig, v_odom, v_plain) -> list[Job]:
    jobs: list[Job] = []
    for noise in cfg.noise_db:
        for path in ds.D0_PATHS:
            for trial in range(cfg.trials_sim):
                jobs.append(Job("dataset0", f"{path}@{noise:g}dB", trial, (path, noise, ds.D0_PATH_LOSS_EXPONENT),
                                v_odom, keep_paths=(trial == 0 and noise == cfg.main_noise_db)))
    for mode in ("paper", "fitted"):
        for label, tech in ds.D1_TECHS.items():
            for trial in range(cfg.trials_real):
                jobs.append(Job(f"dataset1-{mode}", label, trial, (tech, mode), v_plain))
    for label in cfg.d2_channel_sets:
        for trial in range(cfg.trials_real):
            jobs.append(Job("dataset2", label, trial, (label,), v_plain))
    return jobs


def site_pairs(cfg: EvalConfig, ts: ds.TraceSet) -> list[tuple[str, str | None, str]]:
    """The (role, calibration run, scored run) scorings of one site in this configuration."""
    out: list[tuple[str, str | None, str]] = []
    per: defaultdict[tuple[str, str], int] = defaultdict(int)
    for role, cal, run in sites_mod.pairs(ts, cfg.calibration):
        if cfg.site_roles is not None and role not in cfg.site_roles:
            continue
        per[(role, run)] += 1
        if cfg.site_pairs is None or per[(role, run)] <= cfg.site_pairs:
            out.append((role, cal, run))
    return out


def site_experiment(site: str, role: str, run: str) -> str:
    return f"{site}|{role}|{run}"


def _site_jobs(cfg: EvalConfig) -> list[Job]:
    jobs: list[Job] = []
    for ts in cfg.sites:
        has_odometry = any(r[2] for r in ts.runs)
        # Without odometry a site's "(no odom)" rows would repeat the plain ones.
        variants = variants_for(cfg.methods, has_odometry) if cfg.site_variants is None else tuple(
            v for v in cfg.site_variants if has_odometry or not v.label.endswith("(no odom)"))
        seeded = tuple(v for v in variants if uses_rng(v.method))
        first: set[tuple[str, str]] = set()
        for role, cal, run in site_pairs(cfg, ts):
            keep = (role, run) not in first
            first.add((role, run))
            for seed in range(cfg.site_seeds):
                vs = variants if seed == 0 else seeded
                if vs:
                    jobs.append(Job("sites", site_experiment(ts.name, role, run), seed, (ts.name, role, cal, run), vs,
                                    keep_paths=keep and seed == 0))
    return jobs


def _sweep_jobs(cfg: EvalConfig) -> list[Job]:
    jobs: list[Job] = []
    if "pf-doa" in cfg.methods:
        for k in SWEEP_PARTICLES:
            vs = tuple(Variant(f"{v.label} N={k}", v.method, v.use_odometry, (("particles", k),))
                       for v in variants_for(("pf-doa",), True))
            for path in ds.D0_PATHS:
                for trial in range(cfg.trials_sweep):
                    jobs.append(Job("sweep-particles", f"{path}@N={k}", trial,
                                    (path, cfg.main_noise_db, ds.D0_PATH_LOSS_EXPONENT), vs))
    for n in SWEEP_EXPONENTS:
        grid: list[Variant] = []
        if "markov" in cfg.methods:
            grid += [Variant(f"markov res={r:g}", "markov", True, (("resolution", r),)) for r in SWEEP_RESOLUTION_M]
        if "drssi" in cfg.methods:
            grid += [Variant(f"drssi res={r:g}", "drssi", False, (("resolution", r),)) for r in SWEEP_RESOLUTION_M]
        grid += [Variant(m, m, True) for m in cfg.methods if m in ODOMETRY_METHODS]
        if not grid:
            continue
        for path in ds.D0_PATHS:
            for trial in range(cfg.trials_sweep):
                jobs.append(Job("sweep-resolution", f"{path}@n={n:g}", trial, (path, cfg.main_noise_db, n),
                                tuple(grid)))
    return jobs


# ----------------------------------------------------------------------------- job execution
_FIT_CACHE: dict = {}


def _fitted(key, fn):
    if key not in _FIT_CACHE:
        _FIT_CACHE[key] = fn()
    return _FIT_CACHE[key]


def site_by_name(cfg: EvalConfig, name: str) -> ds.TraceSet:
    for ts in cfg.sites:
        if ts.name == name:
            return ts
    raise KeyError(name)


def trace_calibration(ts: ds.TraceSet, cal_run: str):
    """The Huber fit of the site's radio model to one run (cached per process)."""
    from pfdoa.calibration.calibrate import calibrate_traces

    def fit():
        site = ds.load_site_cached(ts.site_path)
        try:
            return calibrate_traces([ds.trace_cached(ts.run(cal_run)[1])], site, robust=True, window_s=ts.window_s)
        except InputError as exc:  # kept, so that the run's other pairs do not fit it again
            return CalibrationFailed(f"{ts.name}: calibration on run {cal_run}: {exc}")

    fitted = _fitted(("traces", ts, cal_run), fit)
    if isinstance(fitted, CalibrationFailed):
        raise CalibrationFailed(str(fitted))
    return fitted


def calibrated_site(ts: ds.TraceSet, cal_run: str):
    """The site with the radio model fitted on ``cal_run`` (no uncertainty factors; cached)."""
    return _fitted(("calibrated site", ts, cal_run),
                   lambda: trace_calibration(ts, cal_run).apply(ds.load_site_cached(ts.site_path)))


def _trace_site(ts: ds.TraceSet, cal_run: str | None, scored_run: str, role: str = ""):
    """The site as every method gets it for ``scored_run``: as given, or as ``pfdoa calibrate``
    writes it from ``cal_run`` (the radio model and its map)."""
    if cal_run is None:
        return ds.load_site_cached(ts.site_path)
    return calibrated_site(ts, cal_run)


@functools.lru_cache(maxsize=32)
def _site_sequences(ts: ds.TraceSet, role: str, cal: str | None, run: str) -> tuple[ds.Sequence, ...]:
    """A scored run's windows on its calibrated site, kept for the next seeds of the same pair
    (the estimators read them, never write them)."""
    return tuple(ds.trace_sequences(ts, run, _trace_site(ts, cal, run, role)))


def _d1_site(tech: str, mode: str):
    if mode == "paper":
        return ds.d1_site(tech)

    def fit():
        from pfdoa.calibration.calibrate import fit_path_loss

        pts, idx, val = ds.d1_calibration_readings(tech)
        # 10 points x 3 anchors: too few readings for per-anchor offsets as well.
        r = fit_path_loss(pts, idx, val, ds.d1_site(tech), offsets=False, robust=True)
        return ds.d1_site(tech, r.rssi_at_1m_dbm, r.path_loss_exponent)

    return _fitted(("d1", tech), fit)


def _d2_fold_site(label: str, fold: int):
    from pfdoa.calibration.calibrate import fit_path_loss

    def fit():
        n_points = len(ds.d2_data().points)
        train = [p for p in range(n_points) if p % 2 != fold]
        pts, idx, val = ds.d2_calibration_readings(train, ds.D2_CHANNEL_SETS[label])
        r = fit_path_loss(pts, idx, val, ds.d2_site(-60.0, 2.0), robust=True)
        return ds.d2_site(r.rssi_at_1m_dbm, r.path_loss_exponent, r.offsets)

    return _fitted(("d2", label, fold), fit)


def _sequences(cfg: EvalConfig, job: Job) -> list[ds.Sequence]:
    b = job.block
    if b == "dataset0" or b.startswith("sweep-"):
        path, noise, n = job.params
        rng = np.random.default_rng(job_seed(cfg, job, "data"))
        return [ds.d0_sequence(path, noise, rng, n=n)]
    if b.startswith("dataset1-"):
        tech, mode = job.params
        return [ds.d1_sequence(tech, _d1_site(tech, mode))]
    if b == "dataset2":
        (label,) = job.params
        n_points = len(ds.d2_data().points)
        return [ds.d2_sequence([p for p in range(n_points) if p % 2 == fold], ds.D2_CHANNEL_SETS[label],
                               _d2_fold_site(label, fold), f"dataset2/{label}/fold{fold}") for fold in (0, 1)]
    if b == "sites":
        name, role, cal, run = job.params
        return list(_site_sequences(site_by_name(cfg, name), role, cal, run))
    raise ValueError(f"unknown block {b}")


def execute(cfg: EvalConfig, job: Job) -> JobResult:
    try:
        seqs = _sequences(cfg, job)
    except CalibrationFailed as exc:  # one run of someone's site too short to fit: its pairs are left out
        return JobResult(job, {}, skipped=str(exc))
    results: dict[str, RunResult] = {}
    for v in job.variants:
        # Real sites: seeded per sequence as replay seeds each beacon; otherwise one stream per job.
        shared = None if job.block == "sites" else np.random.default_rng(job_seed(cfg, job, "estimator/" + v.label))
        parts = []
        try:
            for s in seqs:
                rng = shared if shared is not None else _replay_rng(job.trial, s)
                parts.append(_run_cached(cfg.cache_dir, v, s, rng))
        except Exception as exc:  # an estimator bug must not sink the whole evaluation
            log.debug("%s %s %s: %s", job.block, job.experiment, v.label, traceback.format_exc())
            results[v.label] = RunResult(np.zeros(0), np.zeros(0), np.zeros((0, 2)), 0,
                                         f"{type(exc).__name__}: {exc}")
            continue
        r = RunResult(np.concatenate([p.errors for p in parts]), np.concatenate([p.step_ms for p in parts]),
                      _joined_paths([p.estimates for p in parts]) if job.keep_paths else np.zeros((0, 2)),
                      sum(p.held for p in parts))
        for name in ("in_cov", "lost", "r95_m"):
            cols = [getattr(p, name) for p in parts]
            if all(c is not None for c in cols):
                setattr(r, name, np.concatenate(cols))
        results[v.label] = r
    truth = _joined_paths([s.truth for s in seqs]) if job.keep_paths else None
    return JobResult(job, results, truth)


def _run_cached(folder: str | None, v: Variant, seq: ds.Sequence, rng: np.random.Generator) -> RunResult:
    """:func:`run_sequence`, its result kept in ``folder`` for a method without randomness."""
    if folder is None or uses_rng(v.method):
        return run_sequence(v, seq, rng)
    from pfdoa.evaluation import cache

    try:
        k = cache.key(v, seq)
    except (TypeError, ValueError) as exc:  # something in the site the key cannot hold: not cached
        log.debug("eval cache: %s not cached: %s", v.label, exc)
        return run_sequence(v, seq, rng)
    hit = cache.load(folder, k)
    if hit is not None:
        return hit
    r = run_sequence(v, seq, rng)
    cache.store(folder, k, r)
    return r


def _joined_paths(paths: list[np.ndarray]) -> np.ndarray:
    """The paths of a run's sequences (one per beacon) as one (k, 2) array for the plots, with
    a NaN row between two sequences so that a plotted line breaks there instead of jumping
    from one beacon's path to the next."""
    gap = np.full((1, 2), np.nan)
    out: list[np.ndarray] = []
    for k, p in enumerate(paths):
        out += [gap, p] if k else [p]
    return np.concatenate(out) if out else np.zeros((0, 2))


def _replay_rng(seed: int, seq: ds.Sequence) -> np.random.Generator:
    """A real site's estimator seed is the trial itself, as ``pfdoa replay --seed``, which
    seeds each beacon a run names with its own (:func:`pfdoa.gateway.beacons.beacon_seed`)."""
    from pfdoa.gateway.beacons import beacon_seed

    return np.random.default_rng(beacon_seed(seed, seq.beacon) if seq.beacon else seed)


def _execute_packed(args):
    cfg, job = args
    return execute(cfg, job)


# ----------------------------------------------------------------------------- aggregation
@dataclass
class Cell:
    """Every trial of one (block, experiment, variant)."""

    trial_rmse: list[float] = field(default_factory=list)
    errors: list[np.ndarray] = field(default_factory=list)
    step_ms: list[np.ndarray] = field(default_factory=list)
    held: int = 0
    failure: str = ""
    trials: list[int] = field(default_factory=list)  # the trial (seed) of each errors entry
    in_cov: list[np.ndarray | None] = field(default_factory=list)  # aligned with errors
    lost: list[np.ndarray | None] = field(default_factory=list)
    r95_m: list[np.ndarray | None] = field(default_factory=list)

    @property
    def in_r95(self) -> list[np.ndarray | None]:
        """Aligned with errors: 1.0 where the truth lies within r95 (:func:`within_r95`)."""
        return [within_r95(e, r) for e, r in zip(self.errors, self.r95_m)]

    @property
    def all_errors(self) -> np.ndarray:
        return np.concatenate(self.errors) if self.errors else np.zeros(0)

    @property
    def rmse(self) -> float:
        return float(np.mean(self.trial_rmse)) if self.trial_rmse else float("nan")

    @property
    def rmse_sd(self) -> float:
        return float(np.std(self.trial_rmse)) if self.trial_rmse else float("nan")

    @property
    def pooled_rmse(self) -> float:
        e = self.all_errors
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    def percentile(self, q: float) -> float:
        e = self.all_errors
        return float(np.percentile(e, q)) if e.size else float("nan")


@dataclass
class EvalResults:
    config: EvalConfig
    cells: dict[tuple[str, str, str], Cell]
    paths: dict[tuple[str, str], tuple[np.ndarray, dict[str, np.ndarray]]]  # (block, exp) -> truth, label->estimates
    variants: dict[str, list[str]]  # block -> row labels in order
    # (site, run) -> why that run could not calibrate its site (its pairs are not scored)
    calibration_failures: dict[tuple[str, str], str] = field(default_factory=dict)

    def cell(self, block: str, experiment: str, label: str) -> Cell | None:
        return self.cells.get((block, experiment, label))


@dataclass(frozen=True)
class SeedStats:
    """One method on a set of scored runs: statistics of the errors pooled over the runs and
    calibration pairs of each seed, as the mean over seeds and the max - min spread; the
    uncertainty checks pool every seed. A method without randomness has one seed."""

    seeds: int
    rmse: float
    rmse_spread: float
    median: float
    p90: float
    steps: int  # scored steps per seed
    in_r95: float  # fraction of steps with the truth within r95 (NaN: not reported)
    in_cov: float  # fraction within the 95 % ellipse of cov
    lost: float  # fraction of steps flagged lost


def seed_range(n: int) -> str:
    """The estimator seeds 0..n-1 as a report names them: "0-9", or "0" for one."""
    return f"0-{n - 1}" if n > 1 else "0"


def seed_stats(cells: list[Cell]) -> SeedStats | None:
    by_seed: dict[int, list[np.ndarray]] = defaultdict(list)
    unc: dict[str, list[np.ndarray]] = defaultdict(list)
    for c in cells:
        if c.failure:
            return None
        for trial, e, a, b, lo in zip(c.trials, c.errors, c.in_r95, c.in_cov, c.lost):
            by_seed[trial].append(e)
            for name, arr in (("r95", a), ("cov", b), ("lost", lo)):
                if arr is not None:
                    unc[name].append(arr)
    if not by_seed:
        return None
    pooled = [np.concatenate(v) for _, v in sorted(by_seed.items())]
    rmse = [float(np.sqrt(np.mean(e**2))) for e in pooled]

    def frac(name: str) -> float:
        v = np.concatenate(unc[name]) if unc[name] else np.zeros(0)
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else float("nan")

    return SeedStats(len(pooled), float(np.mean(rmse)), float(max(rmse) - min(rmse)),
                     float(np.mean([np.median(e) for e in pooled])), float(np.mean([np.percentile(e, 90) for e in pooled])),
                     int(pooled[0].size), frac("r95"), frac("cov"), frac("lost"))


def pooled_by_seed(cells: list[Cell], column: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per seed, the cells' errors and their per-step ``column`` (a :class:`Cell` list aligned
    with ``errors``: ``in_r95``, ``r95_m``, ...), pooled over the cells' runs and pairs; the
    parts that lack the column are left out."""
    by_seed: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for c in cells:
        for trial, e, a in zip(c.trials, c.errors, getattr(c, column)):
            if a is not None and a.size == e.size:
                by_seed.setdefault(trial, []).append((e, a))
    return [(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
            for parts in by_seed.values()]


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n, ties sharing their mean rank."""
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    ends = np.cumsum(counts)
    return (ends - (counts - 1) / 2.0)[inverse]


def r95_tracks_error(cells: list[Cell]) -> float:
    """Spearman's rank correlation of the reported r95 with the error (per seed, pooled over the
    cells' runs and pairs; the mean over seeds): how far a wider r95 means a larger error, which
    the share within r95 does not say (a constant radius can hold 95 %). NaN where the method
    reports no r95 or either side is constant."""
    rhos = []
    for e, r in pooled_by_seed(cells, "r95_m"):
        ok = np.isfinite(e) & np.isfinite(r)
        if np.count_nonzero(ok) < 3:
            continue
        a, b = _ranks(e[ok]), _ranks(r[ok])
        a -= a.mean()
        b -= b.mean()
        den = math.sqrt(float(a.dot(a)) * float(b.dot(b)))
        if den > 0.0:
            rhos.append(float(a.dot(b)) / den)
    return float(np.mean(rhos)) if rhos else math.nan


def run_all(cfg: EvalConfig, progress: bool = True) -> EvalResults:
    jobs = build_jobs(cfg)
    outcomes: list[JobResult] = []
    try:
        with Progress(len(jobs), "pfdoa eval", enabled=progress) as bar:
            if cfg.jobs > 1:
                # The workers leave SIGINT/SIGTERM to this process (pfdoa.signals.worker_init); when
                # it stops, leaving the `with` terminates them (Pool.__exit__), queued jobs and all.
                with multiprocessing.Pool(cfg.jobs, initializer=signals.worker_init) as pool:
                    for r in pool.imap(_execute_packed, [(cfg, j) for j in jobs], chunksize=4):
                        outcomes.append(r)
                        bar.update()
            else:
                for j in jobs:
                    outcomes.append(execute(cfg, j))
                    bar.update()
    except Interrupted as exc:  # how far it got, for the one line
        raise Interrupted(exc.signum, f"{exc} after {len(outcomes)} of {len(jobs)} evaluation jobs") from None
    # Aggregate in a fixed order so floating-point sums are identical run to run.
    outcomes.sort(key=lambda r: (r.job.block, r.job.experiment, repr(r.job.params), r.job.trial))
    cells: dict[tuple[str, str, str], Cell] = defaultdict(Cell)
    paths: dict = {}
    variants: dict[str, list[str]] = {}
    failed: dict[tuple[str, str], str] = {}
    for o in outcomes:
        if o.skipped:
            failed.setdefault((o.job.params[0], o.job.params[2]), o.skipped)
            continue
        labels = variants.setdefault(o.job.block, [])
        for v in o.job.variants:
            if v.label not in labels:
                labels.append(v.label)
        for label, r in o.results.items():
            c = cells[(o.job.block, o.job.experiment, label)]
            if r.failure:
                c.failure = c.failure or r.failure
                continue
            if r.errors.size:
                c.trial_rmse.append(float(np.sqrt(np.mean(r.errors**2))))
            c.errors.append(r.errors)
            c.step_ms.append(r.step_ms)
            c.held += r.held
            c.trials.append(o.job.trial)
            c.in_cov.append(r.in_cov)
            c.lost.append(r.lost)
            c.r95_m.append(r.r95_m)
        if o.truth is not None:
            key = (o.job.block, o.job.experiment)
            if key not in paths:
                paths[key] = (o.truth, {label: r.estimates for label, r in o.results.items() if not r.failure})
    for (block, exp, label), c in cells.items():
        if c.failure:
            log.warning("%s / %s / %s failed: %s", block, exp, label, c.failure)
    for why in failed.values():
        log.warning("%s (its pairs are not scored)", why)
    return EvalResults(cfg, dict(cells), paths, variants, failed)


def scored_pairs(res: EvalResults, ts: ds.TraceSet) -> list[tuple[str, str | None, str]]:
    """:func:`site_pairs` less those whose calibration run could not calibrate the site."""
    return [p for p in site_pairs(res.config, ts) if p[1] is None or (ts.name, p[1]) not in res.calibration_failures]

