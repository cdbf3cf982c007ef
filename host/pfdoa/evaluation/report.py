"""Markdown report of an evaluation: Table I side by side with the paper, targets, details.

Everything but the timing columns is a deterministic function of the seeds, so the report
is identical across runs apart from those columns (no dates, no host names).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation import sites as sites_mod
from pfdoa.evaluation.experiments import (
    Cell,
    EvalResults,
    SeedStats,
    r95_tracks_error,
    scored_pairs,
    seed_range,
    seed_stats,
)
from pfdoa.evaluation.paper import paper_entry

COMPARISON_EXCLUDE = ("pf-doa",)  # rows that are the subject, not a comparison


# What the authors' scripts (github.com/herolab-uga/cdoa-localization, commit aa763de) do,
# read there, so that the paper's columns are not mistaken for like-for-like numbers.
PAPER_CAVEATS = [
    "**About the paper's numbers.** They come from the authors' scripts "
    "(github.com/herolab-uga/cdoa-localization, commit aa763de), which differ from this harness:",
    "`simulation/PFLocalizationBoundry.py` simulates a 60 x 60 m square with anchors at (±36, ±36) m",
    "and divides the errors by 10 to report a \"6 by 6\" result, adds uniform (not Gaussian) noise,",
    "keeps one fixed random draw of particles on an integer grid, and prints the *mean* error ± sd",
    "(not the RMSE); `dataset2/PFLocalization-DataSet2.py` fits the path-loss exponent by regression on",
    "every reading against the true `distance` column and takes RSS0 from readings at a true distance",
    "of ~1.41 m (calibration on the scored data, using ground truth). Here every error is the plain",
    "Euclidean distance in metres, RMSE is a root mean square, and radio parameters of real data are",
    "fitted on data that is not scored.",
    "",
]


def _fmt(c: Cell | None) -> str:
    if c is None:
        return "-"
    if c.failure:
        return "failed"
    if not c.trial_rmse:
        return "-"
    return f"{c.rmse:.2f} ± {c.rmse_sd:.2f}"


def _ms(v: float) -> str:
    return "-" if not math.isfinite(v) else (f"{v:.2f}" if v < 10 else f"{v:.0f}")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]], align: str | None = None) -> list[str]:
    align = align or ("l" + "r" * (len(header) - 1))
    sep = ["---:" if a == "r" else ":---" for a in align]
    return [_row(header), _row(sep)] + [_row(r) for r in rows]


def _mean_cells(cells: list[Cell | None]) -> tuple[float, float]:
    """The paper's "Average" row: mean of the per-experiment mean RMSEs and of their sds."""
    ok = [c for c in cells if c is not None and c.trial_rmse and not c.failure]
    if len(ok) != len(cells):
        return math.nan, math.nan
    return float(np.mean([c.rmse for c in ok])), float(np.mean([c.rmse_sd for c in ok]))


def _steps_ms(cells: Sequence[Cell | None]) -> float:
    arrs = [np.concatenate(c.step_ms) for c in cells if c is not None and c.step_ms]
    return float(np.median(np.concatenate(arrs))) if arrs else math.nan


def _variant_info(res: EvalResults, block: str, label: str) -> tuple[str, bool]:
    method = label.split(" ")[0]
    return method, not label.endswith("(no odom)") and block in ("dataset0", "sites")


def block_table(res: EvalResults, block: str, experiments: list[str], paper_block: str | None,
                paper_names: list[str] | None = None, average: bool = True) -> list[str]:
    """Rows = methods; our RMSE ± sd per experiment (+ Average), the paper's, then timing."""
    paper_names = paper_names or experiments
    cols = list(experiments) + (["Average"] if average else [])
    header = ["method"] + cols
    if paper_block:
        header += [f"paper {c}" for c in (paper_names + (["Average"] if average else []))]
    header += ["TPI ms (median)"]
    if paper_block:
        header += ["paper TPI ms"]
    rows = []
    for label in res.variants.get(block, []):
        cells = [res.cell(block, e, label) for e in experiments]
        row = [label] + [_fmt(c) for c in cells]
        if average:
            m, s = _mean_cells(cells)
            row.append("-" if math.isnan(m) else f"{m:.2f} ± {s:.2f}")
        if paper_block:
            method, odom = _variant_info(res, block, label)
            tpis = []
            for name in paper_names + (["Average"] if average else []):
                pe = paper_entry(paper_block, name, method, odom)
                row.append("-" if pe is None else f"{pe[0]:.2f} ± {pe[1]:.2f}")
                if pe is not None and name != "Average":
                    tpis.append(pe[2])
        row.append(_ms(_steps_ms(cells)))
        if paper_block:
            row.append(f"{np.mean(tpis):.0f}" if tpis else "-")
        rows.append(row)
    return _table(header, rows)


def _d0_exp(path: str, noise: float) -> str:
    return f"{path}@{noise:g}dB"


def targets(res: EvalResults) -> tuple[list[str], dict[str, bool]]:
    """The project's accuracy targets, checked on this run."""
    cfg = res.config
    lines, verdict = [], {}
    ok = lambda b: "**PASS**" if b else "**FAIL**"  # noqa: E731
    main = cfg.main_noise_db
    if "pf-doa" in cfg.methods and main in cfg.noise_db and "dataset0" in res.variants:
        cells = [res.cell("dataset0", _d0_exp(p, main), "pf-doa") for p in ds.D0_PATHS]
        m, _ = _mean_cells(cells)
        verdict["d0_rmse"] = m <= 0.40
        lines.append(f"* Dataset 0 at {main:g} dB, pf-doa RMSE averaged over the three paths <= 0.40 m: "
                     f"{m:.3f} m {ok(verdict['d0_rmse'])}")
        losses = []
        for noise in cfg.noise_db:
            for p in ds.D0_PATHS:
                ours = res.cell("dataset0", _d0_exp(p, noise), "pf-doa")
                for label in res.variants.get("dataset0", []):
                    if label.split(" ")[0] in COMPARISON_EXCLUDE:
                        continue
                    other = res.cell("dataset0", _d0_exp(p, noise), label)
                    if ours is None or other is None or other.failure or not other.trial_rmse:
                        continue
                    if not ours.rmse < other.rmse:
                        losses.append(f"{p} {noise:g} dB: {label} {other.rmse:.3f} <= pf-doa {ours.rmse:.3f}")
        verdict["d0_best"] = not losses
        lines.append(f"* Dataset 0, pf-doa (with odometry) better than every comparison method on every path "
                     f"and noise level: {ok(verdict['d0_best'])}"
                     + ("" if not losses else " - not on: " + "; ".join(losses)))
        cells = [res.cell("dataset0", _d0_exp(p, main), "pf-doa (no odom)") for p in ds.D0_PATHS]
        if all(c is not None for c in cells):
            m, _ = _mean_cells(cells)
            verdict["d0_no_odom"] = m <= 0.40
            lines.append(f"* Dataset 0 at {main:g} dB without odometry, pf-doa RMSE averaged over the three paths "
                         f"<= 0.40 m: {m:.3f} m {ok(verdict['d0_no_odom'])}")
        _no_odom_line(res, lines)
        for label in ("pf-doa", "pf-doa (no odom)"):
            st = seed_stats([c for p in ds.D0_PATHS for c in [res.cell("dataset0", _d0_exp(p, main), label)] if c])
            if st is not None and math.isfinite(st.in_r95):
                key = f"d0_r95 {label}"
                verdict[key] = _coverage_ok(st)
                lines.append(f"* Dataset 0 at {main:g} dB, {label}: truth within r95 for {_pct(st.in_r95)}, within "
                             f"the 95 % ellipse of cov for {_pct(st.in_cov)} of estimates (target 88-98 % each) "
                             f"{ok(verdict[key])}")
    if "pf-doa" in cfg.methods and "sites" in res.variants:
        _site_targets(res, lines, verdict)
    return lines, verdict


COVERAGE_RANGE = (0.88, 0.98)  # truth within r95 / within the 95 % ellipse: honest, not inflated
MARGIN = 0.15  # pf-doa at least this much below the best other method on every site
SPREAD = 0.10  # max - min over seeds at most this share of the mean
ROBOT_SITE = "herolab_wifi_robot"
ROBOT_RMSE_M = 0.50


def _pct(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{100 * v:.1f} %"


def _coverage_ok(st: SeedStats) -> bool:
    lo, hi = COVERAGE_RANGE
    return lo <= st.in_r95 <= hi and lo <= st.in_cov <= hi


def site_cells(res: EvalResults, site: str, role: str, label: str, runs: list[str] | None = None) -> list[Cell]:
    out = []
    for (b, e, lab), c in res.cells.items():
        if b != "sites" or lab != label:
            continue
        s, r, run = e.split("|")
        if s == site and r == role and (runs is None or run in runs):
            out.append(c)
    return out


def site_roles(res: EvalResults, site: str) -> list[str]:
    roles = {e.split("|")[1] for (b, e, _l) in res.cells if b == "sites" and e.split("|")[0] == site}
    order = (sites_mod.HELD_OUT, sites_mod.CROSS, sites_mod.AS_GIVEN, sites_mod.DEVELOPMENT)
    return [r for r in order if r in roles]


def site_runs(res: EvalResults, site: str, role: str) -> list[str]:
    return sorted({e.split("|")[2] for (b, e, _l) in res.cells
                   if b == "sites" and e.split("|")[0] == site and e.split("|")[1] == role})


def _site_targets(res: EvalResults, lines: list[str], verdict: dict[str, bool]) -> None:
    ok = lambda b: "**PASS**" if b else "**FAIL**"  # noqa: E731
    labels = res.variants["sites"]
    for ts in res.config.sites:
        roles = site_roles(res, ts.name)
        if not roles:
            continue
        role = sites_mod.headline_role(set(roles))
        for ours in ("pf-doa", "pf-doa (no odom)"):
            if ours not in labels:
                continue
            st = seed_stats(site_cells(res, ts.name, role, ours))
            others = [(lab, o) for lab in labels if lab.split(" ")[0] not in COMPARISON_EXCLUDE
                      if (o := seed_stats(site_cells(res, ts.name, role, lab))) is not None]
            if st is None or not others:
                continue
            best_label, best = min(others, key=lambda lo: lo[1].rmse)
            margin = 1.0 - st.rmse / best.rmse
            key = f"site {ts.name} {ours}"
            verdict[key] = margin >= MARGIN and st.rmse_spread <= SPREAD * st.rmse
            lines.append(f"* {ts.name} ({role}), {ours}: pooled RMSE {st.rmse:.3f} m (seed spread "
                         f"{st.rmse_spread:.3f}), {_below(margin)} the best other method "
                         f"({best_label} {best.rmse:.3f} m); target >= {100 * MARGIN:.0f} % below, spread <= "
                         f"{100 * SPREAD:.0f} % of the mean {ok(verdict[key])}")
            if math.isfinite(st.in_r95):
                key = f"site {ts.name} {ours} coverage"
                verdict[key] = _coverage_ok(st)
                lines.append(f"* {ts.name} ({role}), {ours}: truth within r95 for {_pct(st.in_r95)}, within the "
                             f"95 % ellipse of cov for {_pct(st.in_cov)} of estimates (target 88-98 % each) "
                             f"{ok(verdict[key])}")
        if ts.name == ROBOT_SITE and "pf-doa" in labels:
            st = seed_stats(site_cells(res, ts.name, role, "pf-doa"))
            if st is not None:
                verdict["robot_rmse"] = st.rmse <= ROBOT_RMSE_M
                lines.append(f"* Robot traces ({role} runs), pooled pf-doa RMSE with odometry <= {ROBOT_RMSE_M:.2f} m: "
                             f"{st.rmse:.3f} m {ok(verdict['robot_rmse'])}")
            if "pf-doa (no odom)" in labels and "wcl" in labels:
                worse = []
                for run in site_runs(res, ts.name, role):
                    a = seed_stats(site_cells(res, ts.name, role, "pf-doa (no odom)", [run]))
                    b = seed_stats(site_cells(res, ts.name, role, "wcl", [run]))
                    if a is None or b is None or not a.rmse < b.rmse:
                        worse.append(f"{run} ({a.rmse if a else math.nan:.3f} vs {b.rmse if b else math.nan:.3f})")
                verdict["robot_vs_wcl"] = not worse
                lines.append(f"* Robot traces ({role} runs), pf-doa without odometry below wcl on every run: "
                             f"{ok(verdict['robot_vs_wcl'])}" + ("" if not worse else " - not on: " + "; ".join(worse)))


def _no_odom_line(res: EvalResults, lines: list[str]) -> None:
    """Information, not a target: the comparison methods get no motion model, so also say how
    pf-doa fares without odometry."""
    won = total = 0
    for noise in res.config.noise_db:
        for p in ds.D0_PATHS:
            ours = res.cell("dataset0", _d0_exp(p, noise), "pf-doa (no odom)")
            if ours is None or not ours.trial_rmse:
                return
            cells = [res.cell("dataset0", _d0_exp(p, noise), label) for label in res.variants["dataset0"]
                     if label.split(" ")[0] not in COMPARISON_EXCLUDE]
            others = [c for c in cells if c is not None and c.trial_rmse and not c.failure]
            total += 1
            won += all(ours.rmse < c.rmse for c in others)
    lines.append(f"* (information) Dataset 0 without odometry: pf-doa (no odom) beats every comparison method "
                 f"on {won} of {total} path/noise cells")


def _sweep_tables(res: EvalResults) -> list[str]:
    from pfdoa.evaluation.experiments import SWEEP_EXPONENTS, SWEEP_PARTICLES, SWEEP_RESOLUTION_M

    out: list[str] = []
    noise = res.config.main_noise_db

    def mean3(block: str, fmt: str, label: str) -> str:
        m, s = _mean_cells([res.cell(block, fmt.format(path=p), label) for p in ds.D0_PATHS])
        return "-" if math.isnan(m) else f"{m:.2f} ± {s:.2f}"

    if res.variants.get("sweep-particles") or res.variants.get("sweep-resolution"):
        out += ["## Sweeps behind the plots", ""]
    if res.variants.get("sweep-particles"):
        out += [f"### Number of particles (Dataset 0, {noise:g} dB, mean of the three paths, "
                f"{res.config.trials_sweep} trials)", ""]
        rows = [[base] + [mean3("sweep-particles", "{path}@N=" + str(k), f"{base} N={k}") for k in SWEEP_PARTICLES]
                for base in ("pf-doa", "pf-doa (no odom)")]
        out += _table(["method"] + [f"N={k}" for k in SWEEP_PARTICLES], rows) + [""]
    labels = res.variants.get("sweep-resolution")
    if labels:
        out += [f"### Grid resolution and path-loss exponent (Dataset 0, {noise:g} dB, mean of the three "
                f"paths, {res.config.trials_sweep} trials; pf-doa has no grid)", ""]
        rows = []
        for n in SWEEP_EXPONENTS:
            fmt = "{path}@n=" + f"{n:g}"
            for method in ("markov", "drssi"):
                if f"{method} res={SWEEP_RESOLUTION_M[0]:g}" in labels:
                    rows.append([f"{method}, n={n:g}"] + [mean3("sweep-resolution", fmt, f"{method} res={r:g}")
                                                          for r in SWEEP_RESOLUTION_M] + ["-"])
            for m in ("pf-doa", "pf-doa-paper"):
                if m in labels:
                    rows.append([f"{m}, n={n:g}"] + ["-"] * len(SWEEP_RESOLUTION_M) + [mean3("sweep-resolution", fmt, m)])
        out += _table(["method"] + [f"{r:g} m" for r in SWEEP_RESOLUTION_M] + ["no grid"], rows) + [""]
    return out


def _percentile_table(res: EvalResults, block: str, experiments: list[str]) -> list[str]:
    rows = []
    for label in res.variants.get(block, []):
        pooled = Cell()
        held = 0
        for e in experiments:
            c = res.cell(block, e, label)
            if c is not None and not c.failure:
                pooled.errors += c.errors
                held += c.held
        if not pooled.errors:
            continue
        rows.append([label, f"{pooled.pooled_rmse:.3f}", f"{pooled.percentile(50):.3f}",
                     f"{pooled.percentile(90):.3f}", f"{pooled.percentile(95):.3f}",
                     f"{float(pooled.all_errors.max()):.3f}", str(pooled.all_errors.size), str(held)])
    return _table(["method", "pooled RMSE m", "p50 m", "p90 m", "p95 m", "max m", "scored steps", "held steps"], rows)


def render(res: EvalResults, command: str, fits: dict[str, list[str]], plots: list[str]) -> str:
    cfg = res.config
    if cfg.calibration == "walk" and not cfg.table1:
        from pfdoa.evaluation.deployment import render as render_walk

        return render_walk(res, command)
    title = "reproduction of Table I and real sites" if cfg.table1 else "real sites"
    out = [f"# PF-DOA evaluation: {title}", ""]
    regenerated = "; `make eval` regenerates this file" if cfg.table1 and not cfg.quick else ""  # docs/results.md
    out += [
        "Generated by `" + command + "` (`pfdoa eval --help` for the options; `--jobs N` runs N",
        f"processes and does not change any number{regenerated}). Every number except",
        "the timing columns is a deterministic function of the fixed seeds; rerunning gives an",
        "identical file apart from those columns. Errors are plain Euclidean distances in metres",
        "between each estimate and the ground truth at that step, with no rescaling; the estimators",
        "never see the ground truth.",
        "",
        "Configuration: "
        + (f"Dataset 0 trials per path and noise level = {cfg.trials_sim}; seeds per real-data "
           f"experiment = {cfg.trials_real}; " if cfg.table1 else "")
        + f"real sites: estimator seed{'s' if cfg.site_seeds > 1 else ''} {seed_range(cfg.site_seeds)} per (calibration run, scored run) pair; "
        f"base seed {cfg.seed}{'; QUICK run (few trials, not the reference numbers)' if cfg.quick else ''}.",
        "",
        "**RMSE ± sd**: RMSE of one trial (one noise draw / seed / calibration pair) over all its",
        "steps, averaged over trials, ± the standard deviation across trials. \"Average\" columns",
        "follow the paper: the mean of the experiments' RMSEs and of their sds. **TPI**: median wall",
        "time of one `step()` call in milliseconds on this machine (the paper's TPI was measured on",
        "its authors' Python code and is not comparable in absolute terms). The paper's numbers are",
        "copied from its Table I; the paper's PF-DOA is compared with both `pf-doa` (this project's",
        "filter) and `pf-doa-paper` (the paper's algorithm as published).",
        "",
    ]
    if cfg.table1:
        out += PAPER_CAVEATS
    # The project's targets are `make eval`'s (Table I and the committed sites), never a
    # verdict on a user's own sites or traces.
    lines = targets(res)[0] if cfg.table1 else []
    if lines:
        out += ["## Project targets", ""] + lines + [""]

    main = cfg.main_noise_db
    if "dataset0" in res.variants:
        exps = [_d0_exp(p, main) for p in ds.D0_PATHS]
        out += [f"## Dataset 0 (simulation), RSS noise {main:g} dB", "",
                "6 x 6 m, anchors at the corners, paths at 0.1 m steps (one observation per step, 1 s apart),",
                f"A = {ds.D0_RSSI_AT_1M_DBM:g} dBm, n = {ds.D0_PATH_LOSS_EXPONENT:g}, zero-mean Gaussian RSS noise. "
                "Estimators know A and n (as in the paper).",
                "Rows without a suffix get odometry (true increments with 5 % slip noise; methods without a",
                "motion model ignore it); \"(no odom)\" rows do not. The paper's paths jump between separately",
                "drawn segments (as in the authors' data); odometry reports each jump as one straight drive.",
                "The paper's PF-DOA wo/ odom numbers are beside the \"(no odom)\" rows.", ""]
        tab = block_table(res, "dataset0", exps, "dataset0", list(ds.D0_PATHS))
        out += tab + [""]
        if len(cfg.noise_db) > 1:
            out += ["### Dataset 0: RMSE vs RSS noise (mean over the three paths)", ""]
            header = ["method"] + [f"{n:g} dB" for n in cfg.noise_db]
            rows = []
            for label in res.variants["dataset0"]:
                row = [label]
                for n in cfg.noise_db:
                    m, s = _mean_cells([res.cell("dataset0", _d0_exp(p, n), label) for p in ds.D0_PATHS])
                    row.append("-" if math.isnan(m) else f"{m:.2f} ± {s:.2f}")
                rows.append(row)
            out += _table(header, rows) + [""]
            out += ["### Dataset 0: every path and noise level", ""]
            header = ["method"] + [f"{p[:4]}. {n:g} dB" for n in cfg.noise_db for p in ds.D0_PATHS]
            rows = [[label] + [_fmt(res.cell("dataset0", _d0_exp(p, n), label)) for n in cfg.noise_db for p in ds.D0_PATHS]
                    for label in res.variants["dataset0"]]
            out += _table(header, rows) + [""]
        out += [f"### Dataset 0 at {main:g} dB: error percentiles (all paths, all trials)", ""]
        out += _percentile_table(res, "dataset0", exps) + [""]

    for mode, title in (("paper", "the paper's radio parameters"), ("fitted", "radio parameters fitted on the 10 test points")):
        block = f"dataset1-{mode}"
        if block not in res.variants:
            continue
        out += [f"## Dataset 1 ({title})", ""]
        if mode == "paper":
            out += ["Pachos et al. scenario 1: anchors A, B, C at (0,0), (0,4), (4,0) m; the 49 fingerprint points",
                    "in file order as a trajectory, no odometry. Radio parameters as used by the paper's authors",
                    "(wifi A = -45.73 dBm n = 2.162, ble A = -75.48 n = 2.271, zigbee A = -50.33 n = 2.935),",
                    "which were probably fitted on these same points.", ""]
        else:
            out += ["Same trajectory; A and n fitted (Huber IRLS, no per-anchor offsets: only 30 readings) on the",
                    "10 points of `*-testdata.csv`, which are not scored: an out-of-sample calibration. The test",
                    "files give x and y transposed relative to the fingerprint file (for all three technologies",
                    "the fit as given has n = 0.4-1.3 and a larger residual; swapped, n = 1.4-2.2), so they are",
                    "read with x and y swapped.", ""]
        out += block_table(res, block, list(ds.D1_TECHS), "dataset1") + [""]
        if fits.get(block):
            out += fits[block] + [""]

    if "dataset2" in res.variants:
        exps = list(cfg.d2_channel_sets)
        out += ["## Dataset 2 (multi-channel BLE, diagonal points)", "",
                "Szelinski & Nikodem: anchors at (0,0), (10,0), (10,10), (0,10) m, 11 static points on the",
                "diagonal, visited in order. The anchors' readings have no timestamps, so an observation",
                f"pairs the j-th reading of each anchor at one point and channel: {ds.D2_DWELL} observations per",
                "point for a single channel, one per channel (channel order) for channels 0-39. Radio model",
                "fitted honestly: two folds of alternating points; each fold is scored with A, n and",
                "per-anchor offsets fitted (Huber IRLS) on the raw readings of the other fold (same",
                "channels). Only the diagonal points are public, so only the paper's Diagonal rows compare.", ""]
        out += block_table(res, "dataset2", exps, "dataset2", average=False) + [""]
        if fits.get("dataset2"):
            out += fits["dataset2"] + [""]

    if "sites" in res.variants:
        out += _sites_section(res, fits)

    out += _sweep_tables(res)
    if plots:
        out += ["## Plots", ""] + [f"![{p.rsplit('/', 1)[-1]}]({p})" for p in plots] + [""]
    fails = sorted({(b, label, c.failure) for (b, _, label), c in res.cells.items() if c.failure})
    if fails or res.calibration_failures:
        out += ["## Failures", ""] + [f"* {b} / {label}: {f}" for b, label, f in fails] + [
            f"* sites: {why} (its pairs are not scored)" for why in res.calibration_failures.values()] + [""]
    return "\n".join(out)


def _describe(ts: ds.TraceSet) -> str:
    site = ds.load_site_cached(ts.site_path)
    x0, y0, x1, y1 = site.bounds
    meta = _anchors_meta(ts)
    tech = f"{meta['technology']}, " if meta.get("technology") else ""
    odo = sum(1 for r in ts.runs if r[2])
    return (f"{tech}{len(site.anchors)} anchors spanning {x1 - x0:.1f} x {y1 - y0:.1f} m, {len(ts.runs)} runs"
            + (f", {odo} with odometry" if odo else ", no odometry"))


def _anchors_meta(ts: ds.TraceSet) -> dict:
    import json
    from pathlib import Path

    p = Path(ts.site_path).parent / "anchors.json"
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _site_table(res: EvalResults, site: str, role: str) -> list[str]:
    rows = []
    for label in res.variants["sites"]:
        cells = site_cells(res, site, role, label)
        st = seed_stats(cells)
        if st is None:
            continue
        tracks = r95_tracks_error(cells)
        rows.append([label, f"{st.rmse:.3f}", f"{st.rmse_spread:.3f}", f"{st.median:.2f}", f"{st.p90:.2f}",
                     _pct(st.in_r95), _pct(st.in_cov), f"{tracks:.2f}" if math.isfinite(tracks) else "-",
                     _pct(st.lost) if math.isfinite(st.lost) else "-", str(st.seeds), str(st.steps)])
    return _table(["method", "pooled RMSE m", "max - min m", "p50 m", "p90 m", "in r95", "in cov 95 %",
                   "r95 tracks error", "lost", "seeds", "steps/seed"], rows)


def _run_table(res: EvalResults, site: str, role: str) -> list[str]:
    runs = site_runs(res, site, role)
    rows = []
    for label in res.variants["sites"]:
        if not site_cells(res, site, role, label):
            continue  # a row of another site (e.g. "(no odom)" where this one has no odometry)
        row = [label]
        for run in runs:
            st = seed_stats(site_cells(res, site, role, label, [run]))
            row.append("-" if st is None else f"{st.rmse:.2f}")
        row.append(_ms(_steps_ms(site_cells(res, site, role, label))))
        rows.append(row)
    return _table(["method"] + runs + ["TPI ms (median)"], rows)


def _below(margin: float) -> str:
    """A relative difference to the best other method, said the right way round."""
    return f"{100 * margin:.0f} % below" if margin >= 0 else f"{100 * -margin:.0f} % above"


def _sites_section(res: EvalResults, fits: dict[str, list[str]]) -> list[str]:
    cfg = res.config
    out = ["## Real sites", "",
           "Recorded runs in the common formats, one folder per site (`pfdoa.evaluation.sites`). Each",
           "scored run is calibrated (Huber IRLS: A, n, per-anchor offsets) on ANOTHER run of its site, and",
           f"every method gets the same windows ({', '.join(sorted({f'{ts.window_s:g} s' for ts in cfg.sites}))}:"
           " an anchor's readings in a window are combined, median in dB) and the same calibration. Rows",
           "without a suffix get the site's odometry where it has some (methods without a motion model",
           "ignore it); \"(no odom)\" rows do not. **pooled RMSE**: RMSE of the errors pooled over every scored",
           f"run and calibration pair, for each estimator seed {seed_range(cfg.site_seeds)} (seed s is `pfdoa replay",
           "--seed s`); the mean over seeds and the max - min spread; p50 and p90 likewise means over seeds.",
           "A method that draws no random numbers has one seed. **in r95** / **in cov 95 %**: share of the",
           "estimates (all seeds) whose true position lies within the reported `r95`, and within the 95 %",
           "ellipse of the reported covariance `cov` (Mahalanobis distance squared <= 5.991); **r95 tracks",
           "error**: Spearman's rank correlation of the reported r95 with the error (per seed, pooled over the",
           "runs and pairs, then the mean; 0: a wider r95 says nothing of a larger error); **lost**: share",
           "flagged `lost`.", ""]
    if cfg.refused:
        out += [f"**Not evaluated**: {len(cfg.refused)} site folder(s) could not be read (every other site "
                "is scored as usual):", ""] + [f"* {why}" for why in cfg.refused] + [""]
    for ts in cfg.sites:
        roles = site_roles(res, ts.name)
        if not roles:
            continue
        found = sites_mod.protocol_for(ts) if cfg.calibration == "auto" else None
        note = ""
        if found is not None:
            name, protocol = found
            if name == ts.name:
                note = f" Protocol: {protocol.note}."
            elif protocol.whole_site:
                note = (f" Protocol of held-out site {name} (recognised by its runs' contents): every run held out, "
                        "each calibrated on each other run.")
            else:
                note = (f" Protocol of development site {name} (recognised by its runs' contents): development runs "
                        f"{', '.join(protocol.develop)}, every other run held out.")
        out += [f"### {ts.name}", "", _describe(ts) + "." + note, ""]
        for role in roles:
            pairs = [(c, r) for ro, c, r in scored_pairs(res, ts) if ro == role]
            cals = sorted({c for c, _r in pairs if c is not None})
            head = " (headline)" if role == sites_mod.headline_role(set(roles)) else ""
            out += [f"**{role}{head}**: {len(site_runs(res, ts.name, role))} scored run(s) "
                    + (f"calibrated on each of {', '.join(cals)} (never on itself)" if cals else "with the site file as given")
                    + f", {len(pairs)} pair(s); {sites_mod.in_sample(role, ts)}.", ""]
            out += _site_table(res, ts.name, role) + [""]
            out += ["Per scored run (pooled RMSE m, mean over seeds):", ""] + _run_table(res, ts.name, role) + [""]
        if fits.get(f"sites/{ts.name}"):
            out += fits[f"sites/{ts.name}"] + [""]
    out += _lost_section(res)
    return out


def lost_check(cells: list[Cell]) -> tuple[float, int, float, float]:
    """(share flagged lost, estimates flagged, median error when lost, median error otherwise)
    over every seed of ``cells``; NaN where the method does not judge or never said lost."""
    err, lost = [], []
    for c in cells:
        for e, lo in zip(c.errors, c.lost):
            if lo is not None and e.size == lo.size:
                err.append(e)
                lost.append(lo)
    if not err:
        return math.nan, 0, math.nan, math.nan
    e, lo = np.concatenate(err), np.concatenate(lost) > 0.5
    med = lambda v: float(np.median(v)) if v.size else math.nan  # noqa: E731
    return float(lo.mean()), int(lo.sum()), med(e[lo]), med(e[~lo])


def _lost_section(res: EvalResults) -> list[str]:
    """`lost` against the ground truth: how often it is raised, and the error when it is."""
    rows = []
    if "dataset0" in res.variants:
        main = res.config.main_noise_db
        for label in ("pf-doa", "pf-doa (no odom)"):
            cells = [c for p in ds.D0_PATHS for c in [res.cell("dataset0", _d0_exp(p, main), label)] if c]
            rows.append((f"Dataset 0 at {main:g} dB", label, cells))
    for ts in res.config.sites:
        for role in site_roles(res, ts.name):
            for label in ("pf-doa", "pf-doa (no odom)"):
                cells = site_cells(res, ts.name, role, label)
                if cells:
                    rows.append((f"{ts.name} ({role})", label, cells))
    table = []
    for where, label, cells in rows:
        share, n, e_lost, e_ok = lost_check(cells)
        if not math.isfinite(share):
            continue
        f = lambda v: "-" if not math.isfinite(v) else f"{v:.2f}"  # noqa: E731
        table.append([where, label, _pct(share), str(n), f(e_lost), f(e_ok)])
    if not table:
        return []
    return ["### `lost` against the ground truth", "",
            "How often pf-doa flags `lost` (its recent evidence per anchor fell 1 nat below its running",
            "level), and the median error of the flagged estimates against the others (all seeds).", ""] + _table(
        ["data", "method", "lost", "estimates", "p50 error lost m", "p50 error otherwise m"], table, "llrrrr") + [""]


def fit_tables(res: EvalResults) -> dict[str, list[str]]:
    """What was fitted on what: the calibrations behind the real-data blocks."""
    from pfdoa.evaluation import experiments as ex

    out: dict[str, list[str]] = {}
    if "dataset1-fitted" in res.variants:
        rows = []
        for label, tech in ds.D1_TECHS.items():
            s = ex._d1_site(tech, "fitted")
            pa, pn = ds.D1_PAPER_RADIO[tech]
            rows.append([label, f"{s.radio.rssi_at_1m_dbm:.2f}", f"{s.radio.path_loss_exponent:.3f}", f"{pa:.2f}", f"{pn:.3f}"])
        out["dataset1-fitted"] = ["Fitted on the test points:", ""] + _table(
            ["technology", "A dBm", "n", "paper A dBm", "paper n"], rows)
    if "dataset2" in res.variants:
        rows = []
        for label in res.config.d2_channel_sets:
            for fold in (0, 1):
                s = ex._d2_fold_site(label, fold)
                rows.append([label, "odd points -> scores even" if fold == 0 else "even points -> scores odd",
                             f"{s.radio.rssi_at_1m_dbm:.2f}", f"{s.radio.path_loss_exponent:.3f}",
                             " ".join(f"{o:+.1f}" for o in s.offsets)])
        out["dataset2"] = ["Calibrations (fitted on -> scored on):", ""] + _table(
            ["channels", "fold", "A dBm", "n", "offsets s0..s3 dB"], rows, "llrrl")
    if "sites" in res.variants and res.config.calibration != "walk":  # walk: the deployment report lists its own
        from pfdoa.evaluation.experiments import trace_calibration

        for ts in res.config.sites:
            rows, notes = [], []
            scorings = scored_pairs(res, ts)
            for cal in sorted({cal for _r, cal, _run in scorings if cal is not None}):
                fit = trace_calibration(ts, cal)
                offsets = "none" if fit.gauge == "none" else " ".join(f"{o:+.1f}" for o in fit.offsets)
                if fit.note:  # fewer parameters than the full model: say which and why
                    notes.append(f"* {cal}: {fit.note.removeprefix('calibration: ')}.")
                rows.append([cal, f"{fit.rssi_at_1m_dbm:.2f}", f"{fit.path_loss_exponent:.3f}",
                             offsets, f"{fit.rms_db:.2f}"])
            if rows:
                out[f"sites/{ts.name}"] = [
                    "Calibrations (Huber IRLS, offsets summing to zero), the model fitted on each calibration run:",
                    ""] + _table(["calibration run", "A dBm", "n", "offsets dB", "residual RMS dB"], rows,
                                 "lrrlr") + ([""] + notes if notes else [])
    return out


def without_timing(text: str) -> str:
    """The report with every timing column removed (what must be identical across runs)."""
    out, drop = [], None
    for line in text.splitlines():
        if not line.startswith("| "):
            drop = None
            out.append(line)
            continue
        cells = line.strip().strip("|").split("|")
        if drop is None:  # a table's header row
            drop = {i for i, c in enumerate(cells) if "TPI" in c}
        out.append("|" + "|".join(c for i, c in enumerate(cells) if i not in drop) + "|")
    return "\n".join(out)
