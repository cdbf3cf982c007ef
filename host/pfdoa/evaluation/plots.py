"""PNG plots in the spirit of the paper's Figs. 3-4, plus error CDFs and robot paths."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation.experiments import SWEEP_EXPONENTS, SWEEP_PARTICLES, SWEEP_RESOLUTION_M, Cell, EvalResults

log = logging.getLogger(__name__)

COLOURS = {"pf-doa": "C0", "pf-doa-paper": "C1", "trilateration": "C2", "wcl": "C3", "drssi": "C4", "markov": "C5"}
DPI = 100


def _plt():
    from pfdoa.plotting import pyplot

    plt = pyplot("--plots")
    plt.rcParams.update({"font.size": 9, "svg.hashsalt": "pfdoa", "figure.max_open_warning": 0})
    return plt


def _d0_cells(res: EvalResults, exps: list[str]) -> Callable[[str], Sequence[Cell | None]]:
    return lambda label: [res.cell("dataset0", e, label) for e in exps]


def _site_cells(res: EvalResults, site: str, role: str) -> Callable[[str], Sequence[Cell | None]]:
    from pfdoa.evaluation.report import site_cells

    return lambda label: site_cells(res, site, role, label)


def _style(label: str) -> dict:
    method = label.split(" ")[0]
    return {"color": COLOURS.get(method, "k"), "linestyle": "--" if "no odom" in label else "-"}


def _mean_over_paths(res: EvalResults, block: str, fmt: str, label: str) -> tuple[float, float]:
    cells = [res.cell(block, fmt.format(path=p), label) for p in ds.D0_PATHS]
    done = [c for c in cells if c is not None and not c.failure and c.trial_rmse]
    if len(done) < len(cells):
        return math.nan, math.nan
    return float(np.mean([c.rmse for c in done])), float(np.mean([c.rmse_sd for c in done]))


def _save(fig, path: Path) -> None:
    from pfdoa.outfiles import figure_bytes, write_whole

    # Fixed metadata so identical results give identical bytes; written as every output is (pfdoa.outfiles).
    write_whole(path, figure_bytes(fig, path, dpi=DPI, metadata={"Software": None}), "--plots")


def plot_particles(res: EvalResults, path: Path) -> bool:
    labels = res.variants.get("sweep-particles")
    if not labels:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for base in ("pf-doa", "pf-doa (no odom)"):
        ys = [_mean_over_paths(res, "sweep-particles", "{path}@N=" + str(k), f"{base} N={k}") for k in SWEEP_PARTICLES]
        m = np.array([y[0] for y in ys])
        s = np.array([y[1] for y in ys])
        ax.errorbar(SWEEP_PARTICLES, m, yerr=s, marker="o", capsize=3, label=base.replace("pf-doa", "pf-doa w/ odom")
                    if base == "pf-doa" else base, **_style(base))
    ax.set_xscale("log")
    ax.xaxis.set_minor_locator(plt.NullLocator())
    ax.set_xticks(SWEEP_PARTICLES, [str(k) for k in SWEEP_PARTICLES])
    ax.set_xlabel("number of particles")
    ax.set_ylabel("RMSE (m), mean of 3 paths")
    ax.set_title(f"Dataset 0, {res.config.main_noise_db:g} dB noise: particles")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def plot_resolution(res: EvalResults, path: Path) -> bool:
    labels = res.variants.get("sweep-resolution")
    if not labels:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.4, 3.6))
    for i, n in enumerate(SWEEP_EXPONENTS):
        fmt = "{path}@n=" + f"{n:g}"
        for method, marker in (("markov", "o"), ("drssi", "s")):
            lab = [f"{method} res={r:g}" for r in SWEEP_RESOLUTION_M]
            if lab[0] not in labels:
                continue
            m = [_mean_over_paths(res, "sweep-resolution", fmt, la)[0] for la in lab]
            ax.plot(SWEEP_RESOLUTION_M, m, marker=marker, color=f"C{i}", linestyle="-" if method == "markov" else ":",
                    label=f"{method} n={n:g}")
        if "pf-doa" in labels:
            pf = _mean_over_paths(res, "sweep-resolution", fmt, "pf-doa")[0]
            ax.axhline(pf, color=f"C{i}", linestyle="--", linewidth=1, label=f"pf-doa n={n:g} (no grid)")
    ax.set_xlabel("grid resolution (m)")
    ax.set_ylabel("RMSE (m), mean of 3 paths")
    ax.set_title(f"Dataset 0, {res.config.main_noise_db:g} dB: path-loss exponent and grid resolution")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def plot_noise(res: EvalResults, path: Path) -> bool:
    noise = res.config.noise_db
    if "dataset0" not in res.variants or len(noise) < 2:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.4, 3.6))
    for label in res.variants["dataset0"]:
        ys = [_mean_over_paths(res, "dataset0", "{path}@" + f"{n:g}dB", label) for n in noise]
        ax.errorbar(noise, [y[0] for y in ys], yerr=[y[1] for y in ys], marker="o", capsize=3, label=label, **_style(label))
    ax.set_xlabel("RSS noise sd (dB)")
    ax.set_ylabel("RMSE (m), mean of 3 paths")
    ax.set_title("Dataset 0: performance under RSS noise")
    ax.set_xticks(noise)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def plot_d0_paths(res: EvalResults, path: Path, methods=("pf-doa", "pf-doa-paper", "markov")) -> bool:
    keys = [("dataset0", f"{p}@{res.config.main_noise_db:g}dB") for p in ds.D0_PATHS]
    if not all(k in res.paths for k in keys):
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.6))
    anchors = ds.d0_site().positions
    for ax, key, name in zip(axes, keys, ds.D0_PATHS):
        truth, est = res.paths[key]
        # The paths have teleports between drawn segments: draw segments separately.
        jumps = np.flatnonzero(np.hypot(*np.diff(truth, axis=0).T) > 2 * ds.D0_STEP_M) + 1
        for seg in np.split(truth, jumps):
            ax.plot(seg[:, 0], seg[:, 1], "k-", linewidth=2, label="_truth")
        for m in methods:
            if m in est and est[m].size:
                ax.scatter(est[m][:, 0], est[m][:, 1], s=6, color=COLOURS[m], alpha=0.7, label=m)
        ax.scatter(anchors[:, 0], anchors[:, 1], marker="^", s=50, color="k", label="anchors")
        ax.set_title(f"{name} ({res.config.main_noise_db:g} dB, trial 0)")
        ax.set_aspect("equal")
        ax.set_xlim(-0.5, ds.D0_SIZE_M + 0.5)
        ax.set_ylim(-0.5, ds.D0_SIZE_M + 0.5)
        ax.grid(alpha=0.3)
    axes[0].plot([], [], "k-", linewidth=2, label="true path")
    axes[0].legend(fontsize=7, loc="center left")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def _site_panels(res: EvalResults) -> list[tuple[str, str, list[str]]]:
    """(site, headline role, scored runs) for every evaluated site."""
    from pfdoa.evaluation import sites as sites_mod
    from pfdoa.evaluation.report import site_roles, site_runs

    out = []
    for ts in res.config.sites:
        roles = site_roles(res, ts.name)
        if roles:
            role = sites_mod.headline_role(set(roles))
            out.append((ts.name, role, site_runs(res, ts.name, role)))
    return out


def plot_site_paths(res: EvalResults, path: Path, methods=("pf-doa", "wcl")) -> bool:
    panels = [(site, role, runs[0]) for site, role, runs in _site_panels(res)
              if runs and ("sites", f"{site}|{role}|{runs[0]}") in res.paths]
    if not panels:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(3.8 * len(panels), 3.6), squeeze=False)
    for ax, (site, role, run) in zip(axes[0], panels):
        ts = next(t for t in res.config.sites if t.name == site)
        truth, est = res.paths[("sites", f"{site}|{role}|{run}")]
        ax.plot(truth[:, 0], truth[:, 1], "k-", linewidth=1.5, label="ground truth")
        for m in methods:
            if m in est and est[m].size:
                ax.plot(est[m][:, 0], est[m][:, 1], ".-", markersize=2, linewidth=0.5, color=COLOURS[m], label=m)
        anchors = ds.load_site_cached(ts.site_path).positions
        ax.scatter(anchors[:, 0], anchors[:, 1], marker="^", s=40, color="k")
        ax.set_title(f"{site}: {run}\n({role}, seed 0)", fontsize=8)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("real sites: true vs estimated paths (calibrated on another run)", fontsize=9)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def plot_cdf(res: EvalResults, path: Path) -> bool:

    panels: list[tuple[str, str, Callable[[str], Sequence[Cell | None]]]] = []
    main = res.config.main_noise_db
    if "dataset0" in res.variants:
        exps = [f"{p}@{main:g}dB" for p in ds.D0_PATHS]
        panels.append((f"Dataset 0, {main:g} dB, all paths", "dataset0", _d0_cells(res, exps)))
    for site, role, _runs in _site_panels(res):
        panels.append((f"{site}, {role} runs", "sites", _site_cells(res, site, role)))
    if not panels:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.4 * len(panels), 3.6), squeeze=False)
    for ax, (title, block, cells_of) in zip(axes[0], panels):
        for label in res.variants[block]:
            pooled = Cell()
            for c in cells_of(label):
                if c is not None and not c.failure:
                    pooled.errors += c.errors
            e = np.sort(pooled.all_errors)
            if e.size:
                ax.plot(e, np.arange(1, e.size + 1) / e.size, label=label, **_style(label))
        ax.set_xlabel("position error (m)")
        ax.set_ylabel("fraction of steps")
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
        ax.set_ylim(0, 1)
        ax.legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


PLOTS = {
    "rmse_vs_particles.png": plot_particles,
    "rmse_vs_resolution.png": plot_resolution,
    "rmse_vs_noise.png": plot_noise,
    "paths_dataset0.png": plot_d0_paths,
    "paths_sites.png": plot_site_paths,
    "error_cdf.png": plot_cdf,
}


def make_plots(res: EvalResults, out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    made = []
    for name, fn in PLOTS.items():
        p = out_dir / name
        if fn(res, p):
            made.append(p)
            log.info("wrote %s", p)
    return made
