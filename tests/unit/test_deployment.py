"""Real sites judged like a deployment (`pfdoa eval --calibration walk`, `make eval-sites`): the
pairing rules (one calibration walk, the uncalibrated case, held-out marking), the ratios and the
worst-quarter coverage, on small synthetic sites (seconds)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_sites import ANCHORS, _write_run  # the synthetic walks of the site-folder tests

from pfdoa.evaluation import deployment as dep
from pfdoa.evaluation import sites
from pfdoa.evaluation.experiments import Cell, EvalConfig, run_all, scored_pairs, seed_stats

pytestmark = pytest.mark.unit

SITE_TOML = "[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
    f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS))


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A folder of sites: a room of three walks (one with odometry) and a room of one walk."""
    r = tmp_path_factory.mktemp("walk_sites")
    rng = np.random.default_rng(4)
    for name, runs in (("room3", 3), ("room1", 1)):
        d = r / name
        d.mkdir()
        (d / "site.toml").write_text(SITE_TOML)
        for k in range(runs):
            _write_run(d, f"w{k}", k, rng, odom=(name == "room3" and k == 0))
    return r


def test_every_ordered_pair_is_one_walk_and_every_run_is_also_scored_uncalibrated(root):
    by = {ts.name: ts for ts in sites.find_sites(root)}
    ps = sites.pairs(by["room3"], "walk")
    runs = ["w0", "w1", "w2"]
    assert sorted(p for p in ps if p[0] == sites.ONE_WALK) == sorted(
        (sites.ONE_WALK, c, s) for c in runs for s in runs if c != s)
    assert sorted(p for p in ps if p[0] == sites.UNCALIBRATED) == [(sites.UNCALIBRATED, None, r) for r in runs]
    assert {p[0] for p in ps} == {sites.ONE_WALK, sites.UNCALIBRATED}  # a new site: nothing held out
    assert sites.pairs(by["room1"], "walk") == [(sites.UNCALIBRATED, None, "w0")]  # no other walk to calibrate on


def test_held_out_sites_and_runs_get_the_held_out_roles_and_never_calibrate(tmp_path):
    held = next(ts for ts in sites.committed_sites() if sites.PROTOCOLS[ts.name].whole_site)
    copy = tmp_path / "anything"
    shutil.copytree(sites.DATA_DIR / held.name, copy)  # recognised by content, whatever the name
    (ts,) = sites.find_sites(copy)
    assert sites.held_out_site(ts)
    ps = sites.pairs(ts, "walk")
    assert {p[0] for p in ps} == {sites.ONE_WALK_HELD, sites.UNCALIBRATED_HELD}
    assert len([p for p in ps if p[0] == sites.ONE_WALK_HELD]) == len(ts.runs) * (len(ts.runs) - 1)
    dev = next(t for t in sites.committed_sites() if t.name == "philotuxo_ble_dev")
    proto = sites.PROTOCOLS[dev.name]
    ps = sites.pairs(dev, "walk")
    assert not sites.held_out_site(dev)
    assert not {c for _r, c, _s in ps} & set(proto.held_out)  # a held-out run never calibrates
    assert {(r, s) for r, _c, s in ps if s in proto.held_out} == {
        (sites.ONE_WALK_HELD, s) for s in proto.held_out} | {(sites.UNCALIBRATED_HELD, s) for s in proto.held_out}
    assert {r for r, _c, s in ps if s in proto.develop} == {sites.ONE_WALK, sites.UNCALIBRATED}


def test_one_walk_calibration_is_what_pfdoa_calibrate_of_that_walk_writes(root, tmp_path):
    """The site every method gets for a pair: what `pfdoa calibrate` of that one walk writes."""
    from pfdoa.cli import main
    from pfdoa.evaluation.experiments import calibrated_site
    from pfdoa.site import load_site

    ts = next(t for t in sites.find_sites(root) if t.name == "room3")
    out = tmp_path / "fitted.toml"
    d = root / "room3"
    assert main(["-q", "calibrate", str(d / "w1.csv"), "--config", str(d / "site.toml"), "--out", str(out)]) == 0
    want, got = load_site(out), calibrated_site(ts, "w1")
    assert got.radio == want.radio and np.allclose(got.offsets, want.offsets)
    assert got.sections.get("estimator") == want.sections.get("estimator")


def _cell(trial: int, errors, in_r95) -> Cell:
    """A cell whose reported r95 puts each error inside (1), outside (0) or nowhere (NaN)."""
    e = np.asarray(errors, dtype=float)
    r95 = None if in_r95 is None else np.where(np.asarray(in_r95, dtype=float) == 1, e, 0.5 * e)
    if r95 is not None:
        r95[np.isnan(np.asarray(in_r95, dtype=float))] = np.nan
    return Cell(trial_rmse=[float(np.sqrt(np.mean(e ** 2)))], errors=[e], trials=[trial],
                in_cov=[None], lost=[None], r95_m=[r95])


def test_worst_quarter_coverage_takes_each_seeds_largest_errors_pooled_over_pairs():
    # seed 0: two pairs pooled, 8 errors; the worst quarter is 8.0 and 7.0: one inside r95
    a = _cell(0, [1, 8, 2, 3], [1, 1, 1, 1])
    b = _cell(0, [7, 4, 5, 6], [0, 1, 1, 0])
    # seed 1: the worst quarter (5 errors: ceil(5/4) = 2) is 9.0 and 6.0, both outside
    c = _cell(1, [1, 9, 2, 6, 3], [1, 0, 1, 0, 1])
    assert dep.worst_quarter_in_r95([a, b, c]) == pytest.approx(1 / 4)
    assert dep.worst_quarter_in_r95([a, b]) == pytest.approx(1 / 2)
    assert math.isnan(dep.worst_quarter_in_r95([_cell(0, [1, 2], None)]))  # no r95 reported
    nan = _cell(0, [1, 2, 3, 9], [1, 1, 1, np.nan])  # the worst step had no estimate: not counted
    assert math.isnan(dep.worst_quarter_in_r95([nan]))


def _tracked(trial: int, errors, r95) -> Cell:
    c = _cell(trial, errors, None)
    c.r95_m = [None if r95 is None else np.asarray(r95, dtype=float)]
    return c


def test_r95_tracking_is_the_rank_correlation_per_seed_pooled_over_pairs_then_averaged():
    # seed 0: two pairs pooled, r95 in the errors' order (any scale): 1
    a = _tracked(0, [1, 8, 2, 3], [0.5, 4.0, 0.6, 0.7])
    b = _tracked(0, [7, 4, 5, 6], [3.0, 0.8, 0.9, 1.0])
    assert dep.r95_tracks_error([a, b]) == pytest.approx(1.0)
    # seed 1: in the reverse order: -1; the mean over the two seeds: 0
    c = _tracked(1, [1, 2, 3, 4], [4, 3, 2, 1])
    assert dep.r95_tracks_error([c]) == pytest.approx(-1.0)
    assert dep.r95_tracks_error([a, b, c]) == pytest.approx(0.0)
    # ties share their mean rank: errors 1, 2, 3, 4 against r95 1, 1, 2, 2 -> 0.894
    assert dep.r95_tracks_error([_tracked(0, [1, 2, 3, 4], [1, 1, 2, 2])]) == pytest.approx(2 / math.sqrt(5))
    assert math.isnan(dep.r95_tracks_error([_tracked(0, [1, 2, 3], [2, 2, 2])]))  # a constant radius tells nothing
    assert math.isnan(dep.r95_tracks_error([_tracked(0, [1, 2, 3], None)]))  # no r95 reported
    # a step without an estimate (NaN r95) is left out, not ranked
    assert dep.r95_tracks_error([_tracked(0, [1, 2, 3, 9], [1, 2, 3, np.nan])]) == pytest.approx(1.0)


def _row(label: str, rmse: float) -> dep.Row:
    st = seed_stats([_cell(0, [rmse] * 4, None)])
    assert st is not None
    return dep.Row(label, st, math.nan, math.nan)


def test_the_ratio_is_the_default_over_the_best_other_method_in_the_same_odometry_mode():
    rows = [_row("pf-doa", 0.8), _row("pf-doa (no odom)", 1.1), _row("pf-doa-paper", 0.7),
            _row("pf-doa-paper (no odom)", 1.6), _row("wcl", 1.0), _row("markov", 1.2), _row("t2", 0.9),
            _row("t2 (no odom)", 0.95)]
    odo = dep.compare(rows, dep.ODOMETRY, True)
    assert odo is not None and odo.best.label == "pf-doa-paper" and odo.ratio == pytest.approx(0.8 / 0.7)
    plain = dep.compare(rows, dep.NO_ODOMETRY, True)  # wcl has no motion model: its one row counts in both modes
    assert plain is not None and plain.best.label == "wcl" and plain.ratio == pytest.approx(1.1)
    variant = dep.compare(rows, dep.NO_ODOMETRY, True, ours="t2")  # a study variant against the same methods
    assert variant is not None and variant.ratio == pytest.approx(0.95) and variant.best.label == "wcl"
    assert dep.compare([_row("pf-doa", 1.0)], dep.NO_ODOMETRY, False) is None  # nothing to compare with
    assert dep.modes(True) == (dep.ODOMETRY, dep.NO_ODOMETRY) and dep.modes(False) == (dep.NO_ODOMETRY,)


def _score(site: str, ratio: float, unc: float) -> dep.SiteScore:
    def comp(r: float) -> dep.Comparison:
        return dep.Comparison(dep.NO_ODOMETRY, _row("pf-doa", r), _row("wcl", 1.0))

    return dep.SiteScore(site, False, False, 2, 2, {dep.NO_ODOMETRY: comp(ratio)}, {dep.NO_ODOMETRY: comp(unc)},
                         {"calibrated": [], "uncalibrated": []})


def test_over_sites_the_worst_ratio_comes_first_then_the_mean():
    scores = [_score("a", 0.8, 1.2), _score("b", 1.1, 0.9), _score("c", 0.6, 1.0)]
    s = dep.summary(scores)
    assert s is not None and (s.worst, s.worst_site, s.best_on, s.sites) == (pytest.approx(1.1), "b", 2, 3)
    assert s.mean == pytest.approx((0.8 + 1.1 + 0.6) / 3)
    u = dep.summary(scores, calibrated=False)
    assert u is not None and (u.worst_site, u.best_on) == ("a", 1)
    assert [x.site for x in dep.worst_first(scores)] == ["b", "a", "c"]


def _listed(monkeypatch, *folders):
    """List the runs of ``folders`` as local development runs (as data/local_development.json does)."""
    digests = {sites._content_digest(str(p)): f.name for f in folders for p in sites.runs_in(f)}
    monkeypatch.setattr(sites, "_local_development", lambda: digests)


def test_a_site_is_development_held_out_or_new_by_its_runs_contents(root, tmp_path, monkeypatch, caplog):
    """A judge's own site must not be reported as one our decisions looked at: a site is
    development only when its runs are ours (committed) or listed (the local rooms)."""
    by = {ts.name: ts for ts in sites.find_sites(root)}
    assert sites.decision_group(by["room3"]) == sites.NEW == sites.decision_group(by["room1"])
    assert "in-sample unknown" in sites.in_sample(sites.ONE_WALK, by["room3"])
    dev = next(t for t in sites.committed_sites() if t.name == "kolakowski_ble_dev")
    assert sites.decision_group(dev) == sites.DEVELOPMENT
    held = next(n for n, p in sites.PROTOCOLS.items() if p.whole_site)
    shutil.copytree(sites.DATA_DIR / held, tmp_path / "renamed")
    assert sites.decision_group(sites.find_sites(tmp_path / "renamed")[0]) == sites.HELD_OUT
    with caplog.at_level("WARNING", logger="pfdoa.evaluation.sites"):
        names = {ts.name for ts in sites.development_sites(root)}
    assert "room3" not in names and "kolakowski_ble_dev" in names and held not in names
    assert "room1, room3" in caplog.text  # skipped, and said so
    _listed(monkeypatch, root / "room3")
    assert sites.decision_group(sites.find_sites(root / "room3")[0]) == sites.DEVELOPMENT
    assert sites.in_sample(sites.ONE_WALK, by["room3"]).startswith("in-sample:")
    assert {ts.name for ts in sites.development_sites(root)} >= {"room3", "kolakowski_ble_dev"}


def test_the_listed_local_development_runs_are_the_converted_rooms_runs():
    import json

    doc = json.loads(sites.LOCAL_DEVELOPMENT_FILE.read_text())
    assert set(doc["sites"]) == {"girolami_room", "byongho_corner", "byongho_edge"}
    digests = [d for runs in doc["sites"].values() for d in runs.values()]
    assert len(digests) == len(set(digests)) == 33
    assert all(len(d) == 64 and int(d, 16) >= 0 for d in digests)
    assert (Path(__file__).resolve().parents[2] / doc["converter"]).is_file()
    assert set(sites._local_development()) == set(digests)


def test_the_walk_report_orders_sites_worst_first_and_keeps_held_out_and_new_figures_apart(root, tmp_path,
                                                                                           monkeypatch):
    from pfdoa.evaluation.report import render

    held = next(n for n, p in sites.PROTOCOLS.items() if p.whole_site)
    shutil.copytree(sites.DATA_DIR / held, tmp_path / held)
    _listed(monkeypatch, root / "room3")  # room3 a development site, room1 new
    found = sites.find_sites(root) + sites.find_sites(tmp_path)
    cfg = EvalConfig(methods=("pf-doa", "wcl"), sites=found, calibration="walk", site_seeds=2, site_pairs=1,
                     table1=False, sweeps=False)
    res = run_all(cfg, progress=False)
    text = render(res, "pfdoa eval --calibration walk", {}, [])
    scores = {s.site: s for ts in found for s in dep.site_scores(res, ts)}
    assert scores[held].held_out and not scores["room3"].held_out and scores["room3"].has_odometry
    assert scores["room3"].headline == dep.ODOMETRY and dep.NO_ODOMETRY in scores["room3"].calibrated
    assert scores["room1"].pairs == 0 and math.isnan(scores["room1"].ratio)  # one run: uncalibrated only
    assert math.isfinite(scores["room1"].uncalibrated_ratio)
    dev_table = text.split("## Development sites")[1].split("## New sites")[0]
    new_table = text.split("## New sites")[1].split("## Held out")[0]
    held_table = text.split("## Held out")[1].split("## Sites, sources")[0]
    assert f"| {held} |" in held_table and f"| {held} |" not in dev_table + new_table
    assert "| room3 |" in dev_table and "| room1 |" in new_table and "| room1 |" not in dev_table
    over = text.split("## Over sites")[1].split("##")[0]
    assert "development (1 site) | one calibration walk" in over and "held out (1 site)" in over
    assert "new (1 site) | uncalibrated" in over
    assert f"{scores['room3'].ratio:.3f} (room3)" in over
    # r95 against the error, from the runs' own reports, in the table and over the sites
    tracks = scores["room3"].calibrated[dep.ODOMETRY].ours.tracks
    assert -1.0 <= tracks <= 1.0 and f"| {tracks:.2f} |" in dev_table.split("| room3 |")[1].splitlines()[0] + "|"
    assert "r95 tracks error (range)" in over
    assert "a new site: not in-sample" in text.split("### room1")[1]
    assert "PASS" not in text and "FAIL" not in text


def test_a_judges_sites_alone_are_reported_as_new_never_as_in_sample(root):
    from pfdoa.evaluation.report import render

    found = sites.find_sites(root)
    cfg = EvalConfig(methods=("pf-doa", "wcl"), sites=found, calibration="walk", site_seeds=1, site_pairs=1,
                     table1=False, sweeps=False)
    text = render(run_all(cfg, progress=False), "pfdoa eval --calibration walk", {}, [])
    assert "## Development sites" not in text and "In-sample" not in text and "development (" not in text
    order = [ln.split("|")[1].strip() for ln in text.split("## New sites")[1].split("##")[0].splitlines()
             if ln.startswith("| room")]
    assert order == ["room3", "room1"]  # the site with a ratio first, the one without last


def test_a_room_is_still_recognised_by_the_site_file_it_had_before_its_heights(tmp_path):
    """The shared data's copies of the philotuxo and kolakowski site files have no heights."""
    old = tmp_path / "hall"
    old.mkdir()
    text = (sites.DATA_DIR / "philotuxo_ble_dev" / "site.toml").read_text()
    kept = [ln for ln in text.splitlines() if not ln.startswith(("z = ", "target_z", "[site]", "# Heights"))]
    # the file as committed before: no [site] table, no z lines (and the blank line after [site] gone)
    (old / "site.toml").write_text("\n".join(kept).replace("\n\n[radio]", "\n[radio]", 1) + "\n")
    from pfdoa.evaluation.datasets import trace_set

    ts = trace_set("hall", old / "site.toml", [sites.DATA_DIR / "philotuxo_ble_dev" / "straight_01.csv.gz"])
    assert sites.known_room(ts) == "philotuxo_ble_dev"


def test_the_cache_keeps_only_methods_without_randomness_and_keys_them_on_everything_they_depend_on(tmp_path):
    from dataclasses import replace

    from pfdoa.evaluation import cache
    from pfdoa.evaluation import datasets as ds
    from pfdoa.evaluation.experiments import _run_cached
    from pfdoa.evaluation.runner import Variant, run_sequence

    seq = ds.d0_sequence("Inside", 2.0, np.random.default_rng(1))
    wcl, pf = Variant("wcl", "wcl"), Variant("pf-doa", "pf-doa")
    first = _run_cached(str(tmp_path), wcl, seq, np.random.default_rng(0))
    entries = sorted(tmp_path.rglob("*.npz"))
    assert len(entries) == 1
    again = _run_cached(str(tmp_path), wcl, seq, np.random.default_rng(0))
    np.testing.assert_array_equal(again.errors, first.errors)
    np.testing.assert_array_equal(again.errors, run_sequence(wcl, seq, np.random.default_rng(0)).errors)
    _run_cached(str(tmp_path), pf, seq, np.random.default_rng(0))
    assert len(sorted(tmp_path.rglob("*.npz"))) == 1  # pf-doa draws random numbers: never cached
    k = cache.key(wcl, seq)
    other_site = replace(seq, site=replace(seq.site, target_z=1.0))
    assert cache.key(wcl, other_site) != k  # the site it ran with (its calibration, its heights)
    assert cache.key(Variant("wcl", "wcl", False, (("wcl_exponent", 2.0),)), seq) != k
    assert cache.key(wcl, replace(seq, rssi=seq.rssi + 0.5)) != k
    modules = cache.code_modules("pfdoa.estimators.markov")
    assert {"pfdoa.estimators.markov", "pfdoa.radio", "pfdoa.doa", "pfdoa.estimators.common"} <= set(modules)
    assert "pfdoa.estimators.pf_doa" not in modules  # a pf-doa change keeps markov's results
    entries[0].write_bytes(b"not an npz")  # a damaged entry is computed again
    np.testing.assert_array_equal(_run_cached(str(tmp_path), wcl, seq, np.random.default_rng(0)).errors, first.errors)


def test_eval_takes_several_site_folders_and_refuses_two_sites_of_one_name(root, tmp_path):
    import subprocess
    import sys

    other = tmp_path / "more" / "room3"
    shutil.copytree(root / "room3", other)
    cmd = [sys.executable, "-m", "pfdoa", "eval", "--calibration", "walk", "--quick", "--methods", "wcl", "markov",
           "--no-progress"]
    (tmp_path / "more" / "hall").mkdir()
    for f in ("site.toml", "w0.csv", "w1.csv"):
        shutil.copy(root / "room3" / f, tmp_path / "more" / "hall" / f)
    shutil.rmtree(other)
    r = subprocess.run(cmd + ["--sites", str(root), str(tmp_path / "more")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "| hall |" in r.stdout and "| room3 |" in r.stdout and "PASS" not in r.stdout
    shutil.copytree(root / "room3", other)
    r = subprocess.run(cmd + ["--sites", str(root), str(tmp_path / "more")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "two site folders named 'room3'" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(cmd + ["--plots", str(tmp_path / "img"), "--sites", str(root)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and "--plots goes with" in r.stderr


def test_a_run_that_cannot_calibrate_its_site_leaves_out_its_pairs_not_the_evaluation(root, tmp_path, caplog):
    """Someone's site folder with one run too short to fit (two readings at known positions):
    the pairs calibrated on it are not scored, the others are, and the report says why."""
    from pfdoa.evaluation.report import render

    room = tmp_path / "room3"
    shutil.copytree(root / "room3", room)
    lines = (room / "w2.csv").read_text().splitlines()
    (room / "w2.csv").write_text("\n".join(lines[:3]) + "\n")  # the header and two readings
    found = sites.find_sites(tmp_path) + tuple(ts for ts in sites.find_sites(root) if ts.name == "room1")
    cfg = EvalConfig(methods=("pf-doa", "wcl"), sites=found, calibration="walk", site_seeds=1, table1=False,
                     sweeps=False)
    res = run_all(cfg, progress=False)
    (ts,) = [t for t in found if t.name == "room3"]
    scored = [(c, s) for r, c, s in scored_pairs(res, ts) if r == sites.ONE_WALK]
    assert sorted(scored) == [("w0", "w1"), ("w0", "w2"), ("w1", "w0"), ("w1", "w2")]  # none calibrated on w2
    score = next(s for s in dep.site_scores(res, ts))
    assert score.pairs == 4 and math.isfinite(score.ratio) and score.runs == 3
    assert "room3: calibration on run w2" in caplog.text
    text = render(res, "pfdoa eval --calibration walk", {}, [])
    failures = text.split("## Failures")[1]
    assert "room3: calibration on run w2: calibration needs readings at known positions" in failures
    assert "| room1 |" in text  # the other site is judged as before


def test_readings_of_an_anchor_the_site_does_not_know_are_warned_about_once_per_file(root, tmp_path):
    """Each run is grouped once per calibration it is scored with; the warning is the loading's,
    once, not once per grouping (a site of 16 runs said it 16 times a run)."""
    import subprocess
    import sys

    room = tmp_path / "room3"
    shutil.copytree(root / "room3", room)
    with (room / "w1.csv").open("a") as f:
        f.write("0.5,42,-60.0,1.0,1.0\n")
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--calibration", "walk", "--quick", "--methods", "wcl",
                        "markov", "--no-progress", "--sites", str(room)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "42" in line and "w1.csv" in line]
    assert len(said) == 1 and "not in" in said[0], r.stderr
    assert "| room3 |" in r.stdout
