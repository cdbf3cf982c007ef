"""Real sites judged like a deployment: the figures and the report of ``--calibration walk``.

Every site is scored as a new user meets it (:func:`pfdoa.evaluation.sites.walk_pairs`):
each run calibrated on ONE other run alone, every ordered pair, and each run uncalibrated
(the site file's neutral model). Per site and scoring (:class:`SiteScore`): every method's
pooled RMSE (mean over seeds, max - min spread), the **ratio** of the default method
(``pf-doa``) to the best other method on the same runs, pairs, windows and calibration, how
often the truth lies within pf-doa's ``r95``, within it for the worst quarter of its errors,
and how far a wider ``r95`` means a larger error (a rank correlation). Over sites
(:func:`summary`): the worst ratio and the mean ratio. Decisions are made on the worst ratio
first, then the mean; the report orders sites worst ratio first.

Odometry: a site whose runs have odometry is scored both ways; its headline ratio is the one
with odometry (a robot that has it uses it), the one without is reported beside it.
Held out: the held-out roles (a held-out site, or held-out runs of a development site) are
reported apart and never enter the development figures. A site that is neither ours nor held
out (a user's, a judge's: :func:`pfdoa.evaluation.sites.decision_group`) is a **new** site,
reported in its own group: its figures are not in-sample.

How to use it (``--cache build/eval-cache`` keeps the comparison methods' results by content, so
a rerun after a pf-doa change computes pf-doa and pf-doa-paper only)::

    # every site, seeds 0-9, both cores: docs/sites.md (measured: 661 s CPU uncached, 311 s cached)
    make eval-sites
    # the local sites first (data without a licence; see host/pfdoa/data/README.md)
    python tools/convert_ble51.py CHECKOUT_OF_Byongho96/ble-localization build/sites
    # one site, one seed, one calibration per scored run: seconds
    pfdoa eval --sites host/pfdoa/data/kolakowski_ble_dev --calibration walk --quick --cache build/eval-cache
    # several folders, fewer seeds, some methods
    pfdoa eval --sites host/pfdoa/data build/sites --calibration walk --seeds 3 --methods pf-doa wcl markov \\
        --jobs 2 --cache build/eval-cache --out build/sites.md
    # development sites only (held-out sites refused, held-out runs never scored), pf-doa variants
    # against the same comparison methods: per-site ratios, then the worst and the mean over sites
    .venv/bin/python tools/sites_study.py --seeds 3 --jobs 2 --variant "name:option=value,..."
"""

from __future__ import annotations

import json
import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation import sites as sites_mod
from pfdoa.evaluation.experiments import (
    ODOMETRY_METHODS,
    Cell,
    EvalResults,
    SeedStats,
    pooled_by_seed,
    r95_tracks_error,
    scored_pairs,
    seed_range,
    seed_stats,
)

DEFAULT = "pf-doa"  # the method judged; every other method of METHODS is a comparison
NO_ODOM = " (no odom)"
ODOMETRY = "odometry"
NO_ODOMETRY = "no odometry"


def _methods() -> tuple[str, ...]:
    from pfdoa.estimators import METHODS

    return METHODS


def _base(label: str) -> str:
    return label.removesuffix(NO_ODOM)


def row_label(base: str, mode: str, has_odometry: bool) -> str:
    """The row of ``base`` in odometry ``mode``: a method with a motion model has a "(no odom)"
    row where the site has odometry; a method without one has one row, valid in both modes."""
    if has_odometry and mode == NO_ODOMETRY and (base not in _methods() or base in ODOMETRY_METHODS):
        return base + NO_ODOM
    return base


def modes(has_odometry: bool) -> tuple[str, ...]:
    """The odometry modes a site is scored in, its headline first."""
    return (ODOMETRY, NO_ODOMETRY) if has_odometry else (NO_ODOMETRY,)


def worst_quarter_in_r95(cells: list[Cell]) -> float:
    """Share of the worst quarter of errors (per seed, pooled over the cells' runs and pairs)
    whose truth lies within the estimate's r95; NaN where the method reports no r95."""
    hits = total = 0
    for e, a in pooled_by_seed(cells, "in_r95"):
        if not e.size:
            continue
        worst = np.argsort(e, kind="stable")[-math.ceil(e.size / 4):]
        w = a[worst]
        w = w[np.isfinite(w)]
        hits += int(np.count_nonzero(w > 0.5))
        total += int(w.size)
    return hits / total if total else math.nan


@dataclass(frozen=True)
class Row:
    label: str
    stats: SeedStats
    worst_quarter: float  # truth within r95 for the worst quarter of errors
    step_ms: float  # median wall time of one step (timing: not deterministic)
    tracks: float = math.nan  # rank correlation of r95 with the error (r95_tracks_error)


@dataclass(frozen=True)
class Comparison:
    """The default method against the best comparison method, in one odometry mode."""

    mode: str
    ours: Row
    best: Row

    @property
    def ratio(self) -> float:
        return self.ours.stats.rmse / self.best.stats.rmse if self.best.stats.rmse > 0 else math.nan


@dataclass(frozen=True)
class SiteScore:
    """One site's figures in one group of roles (its development or its held-out scorings)."""

    site: str
    held_out: bool  # held-out roles: no decision may look at these figures
    has_odometry: bool
    pairs: int  # calibrated (run, other run) pairs scored
    runs: int  # runs scored
    calibrated: dict[str, Comparison]  # mode -> comparison, one calibration walk
    uncalibrated: dict[str, Comparison]  # mode -> comparison, the site file as given
    rows: dict[str, list[Row]]  # "calibrated" / "uncalibrated" -> every row

    @property
    def headline(self) -> str:
        return modes(self.has_odometry)[0]

    @property
    def ratio(self) -> float:
        c = self.calibrated.get(self.headline)
        return c.ratio if c is not None else math.nan

    @property
    def uncalibrated_ratio(self) -> float:
        c = self.uncalibrated.get(self.headline)
        return c.ratio if c is not None else math.nan


def _cells(res: EvalResults, site: str, role: str, label: str) -> list[Cell]:
    out = []
    for (b, e, lab), c in res.cells.items():
        if b == "sites" and lab == label:
            s, r, _run = e.split("|")
            if s == site and r == role:
                out.append(c)
    return out


def _rows(res: EvalResults, site: str, role: str) -> list[Row]:
    rows = []
    for label in res.variants.get("sites", []):
        cells = _cells(res, site, role, label)
        st = seed_stats(cells) if cells else None
        if st is None:
            continue
        steps = [np.concatenate(c.step_ms) for c in cells if c.step_ms]
        rows.append(Row(label, st, worst_quarter_in_r95(cells),
                        float(np.median(np.concatenate(steps))) if steps else math.nan, r95_tracks_error(cells)))
    return rows


def compare(rows: list[Row], mode: str, has_odometry: bool, ours: str = DEFAULT) -> Comparison | None:
    """``ours`` (a row's base label: the default, or a study variant) against the best
    comparison method in ``mode``; None without a comparison row or without ``ours``."""
    by = {r.label: r for r in rows}
    mine = by.get(row_label(ours, mode, has_odometry))
    others = [r for b in _methods() if b != DEFAULT
              for r in [by.get(row_label(b, mode, has_odometry))] if r is not None]
    if mine is None or not others:
        return None
    return Comparison(mode, mine, min(others, key=lambda r: r.stats.rmse))


def site_scores(res: EvalResults, ts: ds.TraceSet) -> list[SiteScore]:
    """``ts``'s development figures and its held-out figures (each where it has some)."""
    has_odometry = any(r[2] for r in ts.runs)
    scorings = scored_pairs(res, ts)
    out = []
    for held, (walk, plain) in ((False, (sites_mod.ONE_WALK, sites_mod.UNCALIBRATED)),
                                (True, (sites_mod.ONE_WALK_HELD, sites_mod.UNCALIBRATED_HELD))):
        cal_rows, plain_rows = _rows(res, ts.name, walk), _rows(res, ts.name, plain)
        if not cal_rows and not plain_rows:
            continue
        cal = {m: c for m in modes(has_odometry) if (c := compare(cal_rows, m, has_odometry)) is not None}
        unc = {m: c for m in modes(has_odometry) if (c := compare(plain_rows, m, has_odometry)) is not None}
        out.append(SiteScore(ts.name, held, has_odometry, sum(r == walk for r, _c, _s in scorings),
                             len({s for r, _c, s in scorings if r in (walk, plain)}), cal, unc,
                             {"calibrated": cal_rows, "uncalibrated": plain_rows}))
    return out


@dataclass(frozen=True)
class Summary:
    sites: int
    worst: float
    worst_site: str
    mean: float
    best_on: int  # sites where the default's ratio is below 1


def summary(scores: list[SiteScore], calibrated: bool = True) -> Summary | None:
    """Worst and mean headline ratio over ``scores`` (None if none has one)."""
    vals = [(s.ratio if calibrated else s.uncalibrated_ratio, s.site) for s in scores]
    vals = [(v, n) for v, n in vals if math.isfinite(v)]
    if not vals:
        return None
    worst, site = max(vals)
    return Summary(len(vals), worst, site, float(np.mean([v for v, _n in vals])), sum(v < 1.0 for v, _n in vals))


def worst_first(scores: list[SiteScore]) -> list[SiteScore]:
    """Sites ordered as decisions read them: worst calibrated ratio first (no ratio last)."""
    return sorted(scores, key=lambda s: (-s.ratio if math.isfinite(s.ratio) else math.inf, s.site))


# ----------------------------------------------------------------------------- the report
def site_meta(ts: ds.TraceSet) -> dict:
    """The site folder's anchors.json (source, licence, technology, target, ...), if any."""
    try:
        doc = json.loads((Path(ts.site_path).parent / "anchors.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _pct(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{100 * v:.0f} %"


def _m(v: float, digits: int = 3) -> str:
    return "-" if not math.isfinite(v) else f"{v:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]], align: str) -> list[str]:
    sep = ["---:" if a == "r" else ":---" for a in align]
    return [_row(header), _row(sep)] + [_row(r) for r in rows]


def _ratio_cell(c: Comparison | None) -> str:
    return "-" if c is None else f"{c.ratio:.3f}"


def _best_cell(c: Comparison | None) -> str:
    return "-" if c is None else f"{c.best.label} {c.best.stats.rmse:.3f}"


def _site_table(scores: list[SiteScore], info: dict[str, dict]) -> list[str]:
    rows = []
    for s in worst_first(scores):
        cal = s.calibrated.get(s.headline)
        unc = s.uncalibrated.get(s.headline)
        alt = s.calibrated.get(NO_ODOMETRY) if s.has_odometry else None
        ours = cal.ours if cal is not None else None
        name = s.site + (" (held-out runs)" if s.held_out and not info[s.site]["held_out_site"] else "")
        rows.append([name, info[s.site]["radio"], info[s.site]["target"],
                     "with" if s.has_odometry else "-", f"{s.runs} / {s.pairs}",
                     "-" if ours is None else f"{ours.stats.rmse:.3f} ({ours.stats.rmse_spread:.3f})",
                     _best_cell(cal), _ratio_cell(cal), _ratio_cell(alt),
                     "-" if ours is None else _pct(ours.stats.in_r95), "-" if ours is None else _pct(ours.worst_quarter),
                     "-" if ours is None else _m(ours.tracks, 2), _ratio_cell(unc), _best_cell(unc)])
    return _table(["site", "radio", "target", "odometry", "runs / pairs", "pf-doa RMSE m (seed spread)",
                   "best other m", "ratio", "ratio without odometry", "in r95", "worst quarter in r95",
                   "r95 tracks error", "uncalibrated ratio", "uncalibrated: best other m"], rows, "lllllrlrrrrrrl")


def _summary_rows(label: str, scores: list[SiteScore]) -> list[list[str]]:
    rows = []
    for calibrated, how in ((True, "one calibration walk"), (False, "uncalibrated")):
        sm = summary(scores, calibrated)
        if sm is None:
            continue
        ours = [c.ours for s in scores
                for c in [(s.calibrated if calibrated else s.uncalibrated).get(s.headline)] if c is not None]
        cov = [o.stats.in_r95 for o in ours if math.isfinite(o.stats.in_r95)]
        wq = [o.worst_quarter for o in ours if math.isfinite(o.worst_quarter)]
        tr = [o.tracks for o in ours if math.isfinite(o.tracks)]
        rows.append([label, how, f"{sm.worst:.3f} ({sm.worst_site})", f"{sm.mean:.3f}", f"{sm.best_on} of {sm.sites}",
                     f"{_pct(min(cov))} - {_pct(max(cov))}" if cov else "-",
                     f"{_pct(min(wq))} - {_pct(max(wq))}" if wq else "-",
                     f"{min(tr):.2f} - {max(tr):.2f}" if tr else "-"])
    return rows


def _method_table(rows: list[Row]) -> list[str]:
    out = []
    for r in rows:
        st = r.stats
        out.append([r.label, f"{st.rmse:.3f}", f"{st.rmse_spread:.3f}", f"{st.median:.2f}", f"{st.p90:.2f}",
                    _pct(st.in_r95), _pct(r.worst_quarter), _m(r.tracks, 2),
                    _pct(st.lost) if math.isfinite(st.lost) else "-",
                    str(st.seeds), str(st.steps), "-" if not math.isfinite(r.step_ms) else f"{r.step_ms:.2f}"])
    return _table(["method", "pooled RMSE m", "max - min m", "p50 m", "p90 m", "in r95", "worst quarter in r95",
                   "r95 tracks error", "lost", "seeds", "steps/seed", "TPI ms (median)"], out, "lrrrrrrrrrrr")


def _info(res: EvalResults, ts: ds.TraceSet) -> dict:
    meta = site_meta(ts)
    site = ds.load_site_cached(ts.site_path)
    found = sites_mod.protocol_for(ts)
    known = found[0] if found is not None else None
    group = sites_mod.decision_group(ts)
    return {
        "radio": str(meta.get("technology") or sites_mod.SITE_KINDS.get(known or "", ("-", "-"))[0]),
        "target": str(meta.get("target") or sites_mod.SITE_KINDS.get(known or "", ("-", "-"))[1]),
        "source": str(meta.get("source") or "-"),
        "licence": str(meta.get("license") or "-"),
        "anchors": len(site.anchors),
        "held_out_site": group == sites_mod.HELD_OUT,
        "group": group,
        "committed": known is not None and Path(ts.site_path).resolve().parent == (ds.DATA_DIR / known).resolve(),
        "protocol": found,
    }


def render(res: EvalResults, command: str) -> str:
    """The Markdown report of a ``--calibration walk`` evaluation."""
    cfg = res.config
    info = {ts.name: _info(res, ts) for ts in cfg.sites}
    scores = {ts.name: site_scores(res, ts) for ts in cfg.sites}
    dev = [s for ss in scores.values() for s in ss if not s.held_out and info[s.site]["group"] != sites_mod.NEW]
    new = [s for ss in scores.values() for s in ss if not s.held_out and info[s.site]["group"] == sites_mod.NEW]
    held_sites = [s for ss in scores.values() for s in ss if s.held_out and info[s.site]["held_out_site"]]
    held_runs = [s for ss in scores.values() for s in ss if s.held_out and not info[s.site]["held_out_site"]]
    odo_sites = sorted({s.site for s in dev + new + held_sites + held_runs if s.has_odometry})
    seeds = seed_range(cfg.site_seeds)
    out = ["# pfdoa on sites, judged like a deployment", "",
           "Generated by `" + command + "` (`pfdoa eval --help`; `--jobs N` runs N processes and changes no",
           "number). Every number but the timing column is a deterministic function of the data and the",
           "fixed seeds" + ("; QUICK run: one seed, one calibration run per scored run, not the reference "
                            "numbers" if cfg.quick else "") + ".", "",
           "**Protocol** (`pfdoa.evaluation.sites.walk_pairs`): each run of a site is calibrated on ONE other",
           "run alone, as a new user's one calibration walk (`pfdoa calibrate` of that run: the radio model",
           "fitted, Huber IRLS; nothing measured on further runs), and scored; every ordered pair. Each run is",
           "also scored **uncalibrated**, with the site file's neutral radio model and no walk. Every method",
           "gets the same windows, runs and calibration; the estimators never see the ground truth.",
           f"**pooled RMSE**: RMSE of the errors pooled over every scored run and pair, for each estimator seed {seeds}",
           "(`pfdoa replay --seed s`), then the mean over seeds (a method without randomness has one seed);",
           "**ratio**: pf-doa's pooled RMSE over the best other method's (pf-doa-paper, trilateration, wcl,",
           "drssi, markov), below 1 where pf-doa is ahead; **in r95**: share of pf-doa's estimates (all seeds)",
           "whose truth lies within the reported r95 (target 85-98 %); **worst quarter in r95**: the same for the",
           "quarter of its estimates with the largest errors (per seed); **r95 tracks error**: Spearman's rank",
           "correlation of the reported r95 with the error (per seed, then the mean; 1: the wider the r95, the",
           "larger the error, 0: unrelated). Decisions are made on the worst ratio first, then the mean: the",
           "tables list sites worst ratio first.", ""]
    if odo_sites:
        out += [f"Sites with odometry ({', '.join(odo_sites)}): the headline figures give pf-doa and pf-doa-paper",
                "the odometry (the other methods have no motion model); \"ratio without odometry\" is the same",
                "comparison with none.", ""]
    if cfg.refused:
        out += [f"**Not evaluated**: {len(cfg.refused)} site folder(s) could not be read:", ""]
        out += [f"* {why}" for why in cfg.refused] + [""]
    out += ["## Over sites", ""]
    rows = _summary_rows(f"development ({_sites(len(dev))})", dev) if dev else []
    rows += _summary_rows(f"new ({_sites(len(new))})", new) if new else []
    rows += _summary_rows(f"held out ({_sites(len(held_sites))})", held_sites) if held_sites else []
    out += _table(["sites", "scoring", "worst ratio (site)", "mean ratio", "pf-doa ahead on",
                   "pf-doa in r95 (range over sites)", "worst quarter in r95 (range)", "r95 tracks error (range)"],
                  rows, "llrrrlll") + [""]
    if held_runs:
        out += [f"Held-out runs of development sites ({', '.join(s.site for s in held_runs)}) are listed with the "
                "held-out sites and enter neither summary.", ""]
    sections = (
        ("Development sites", dev, "In-sample: decisions look at these sites (the committed development runs since the "
         "held-out protocol of issue 12, every other site from issue 47 on; the local ones are listed in "
         "`host/pfdoa/data/local_development.json`)."),
        ("New sites", new, "Not in-sample, as far as their contents tell: no run of these sites is one that a "
         "decision here looked at (neither a committed site's nor a listed local room's; a cut or an edit of one "
         "of ours would not be recognised)."),
        ("Held out", held_sites + held_runs, "Not in-sample: no decision looks at these sites or runs "
         "(`pfdoa.evaluation.sites.PROTOCOLS`; `tools/sites_study.py` refuses to score them)."),
    )
    for title, group, intro in sections:
        if group:
            out += [f"## {title} (worst ratio first)", "", *_wrap(intro), ""] + _site_table(group, info) + [""]
    if not (dev or new or held_sites or held_runs):
        out += ["(no site was scored)", ""]
    out += ["## Sites, sources and licences", "",
            "Committed sites are in `pfdoa/data` (`host/pfdoa/data/README.md`); local ones are converted by the",
            "`tools/convert_*.py` script their source names from a checkout of a dataset that states no licence",
            "(`build/sites/`).", ""]
    srows = []
    for ts in cfg.sites:
        i = info[ts.name]
        srows.append([ts.name, i["source"], i["licence"], i["radio"], i["target"], str(i["anchors"]),
                      str(len(ts.runs)), "committed" if i["committed"] else "local",
                      "held out" if i["held_out_site"] else "new" if i["group"] == sites_mod.NEW else (
                          "development" + (", held-out runs" if any(s.held_out for s in scores[ts.name]) else ""))])
    out += _table(["site", "source", "licence", "radio", "target", "anchors", "runs", "data", "decisions"], srows,
                  "lllllrrll") + [""]
    out += ["## Per site (in the tables' order)", ""]
    by_name = {ts.name: ts for ts in cfg.sites}
    for s in worst_first(dev) + worst_first(new) + worst_first(held_sites + held_runs):
        ts = by_name[s.site]
        title = ts.name + (" (held-out runs)" if s.held_out and not info[ts.name]["held_out_site"] else "")
        found = info[ts.name]["protocol"]
        note = f" Protocol note: {found[1].note}." if found is not None and found[1].note else ""
        role = sites_mod.ONE_WALK_HELD if s.held_out else sites_mod.ONE_WALK
        cals = sorted({c for r, c, _s in scored_pairs(res, ts) if r == role and c is not None})
        out += [f"### {title}", "", _describe(ts) + "." + note, "",
                f"**One calibration walk**: {s.pairs} pair(s), calibrated on each of {', '.join(cals) or '-'} "
                "(never on itself); " + _group_phrase(s, info[ts.name]["group"]) + ".", ""]
        out += (_method_table(s.rows["calibrated"]) if s.rows["calibrated"] else ["(no pair: one run)"]) + [""]
        radio = ds.load_site_cached(ts.site_path).radio
        out += [f"**Uncalibrated** (the site file as given: A = {radio.rssi_at_1m_dbm:g} dBm, n = "
                f"{radio.path_loss_exponent:g}): {s.runs} run(s).", ""]
        out += _method_table(s.rows["uncalibrated"]) + [""]
        if cals and not s.held_out:
            out += _calibration_table(ts, cals) + [""]
    fails = sorted({(label, c.failure) for (b, _e, label), c in res.cells.items() if b == "sites" and c.failure})
    if fails or res.calibration_failures:
        out += ["## Failures", ""] + [f"* {label}: {f}" for label, f in fails] + [
            f"* {why} (its pairs are not scored)" for why in res.calibration_failures.values()] + [""]
    return "\n".join(out)


def _wrap(text: str, width: int = 100) -> list[str]:
    return textwrap.wrap(text, width, break_on_hyphens=False)


def _group_phrase(s: SiteScore, group: str) -> str:
    if s.held_out:
        return "held out: not in-sample, no decision looks at these runs"
    if group == sites_mod.NEW:
        return "a new site: not in-sample, no decision here looked at these runs"
    return "development: in-sample, decisions look at these runs"


def _calibration_table(ts: ds.TraceSet, cals: list[str]) -> list[str]:
    """What each one-walk calibration fitted (the site as `pfdoa calibrate` of that run writes it)."""
    from pfdoa.evaluation.experiments import trace_calibration

    rows, notes = [], []
    for cal in cals:
        fit = trace_calibration(ts, cal)
        if fit.note:
            notes.append(f"* {cal}: {fit.note.removeprefix('calibration: ')}.")
        rows.append([cal, f"{fit.rssi_at_1m_dbm:.2f}", f"{fit.path_loss_exponent:.3f}",
                     "none" if fit.gauge == "none" else " ".join(f"{o:+.1f}" for o in fit.offsets), f"{fit.rms_db:.2f}"])
    return (["Calibrations (Huber IRLS; offsets sum to zero):", ""]
            + _table(["calibration run", "A dBm", "n", "offsets dB", "residual RMS dB"], rows, "lrrlr")
            + ([""] + notes if notes else []))


def _sites(n: int) -> str:
    return f"{n} site" + ("" if n == 1 else "s")


def _describe(ts: ds.TraceSet) -> str:
    site = ds.load_site_cached(ts.site_path)
    x0, y0, x1, y1 = site.bounds
    odo = sum(1 for r in ts.runs if r[2])
    return (f"{len(site.anchors)} anchors spanning {x1 - x0:.1f} x {y1 - y0:.1f} m, {len(ts.runs)} runs"
            + (f", {odo} with odometry" if odo else ", no odometry") + f", {ts.window_s:g} s windows")
