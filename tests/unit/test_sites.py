"""Real-site folders for the evaluation: discovery, anchors.json, the held-out protocol, and
`pfdoa eval --sites` giving the same estimates as `pfdoa calibrate` + `pfdoa replay`."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoa.estimators import METHODS
from pfdoa.evaluation import sites
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import SITE_ANCHOR_ID_MAX, parse_site

ANCHORS = [(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0), (4.0, -1.0)]


def _site():
    return parse_site({"radio": {"rssi_at_1m_dbm": -55.0, "path_loss_exponent": 2.2},
                       "anchors": [{"id": i, "x": x, "y": y} for i, (x, y) in enumerate(ANCHORS)]})


def _walk(rate_hz: float, phase: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, positions) of a 40 s loop through the room, sampled ``rate_hz`` times a second."""
    t = np.arange(int(40 * rate_hz)) / rate_hz
    return t, np.column_stack([4 + 3 * np.cos(0.1 * t + phase), 3 + 2 * np.sin(0.13 * t + phase)])


def _write_run(d, name, k, rng, rate_hz=3.0, odom=False, ids=None):
    """A walk in the common format: each anchor reports ``rate_hz`` times a second; the
    anchors' ids in the trace are ``ids`` (in ANCHORS order; default 0, 1, ...)."""
    ids = list(range(len(ANCHORS))) if ids is None else ids
    site = _site()
    t, pts = _walk(rate_hz, k)
    mu = mean_rssi(pts, site.positions, PathLoss(-55.0 + k, 2.2)) + np.array([1.0, -1.0, 0.5, 0.0, -0.5])
    y = mu + rng.normal(0, 2.5, mu.shape)
    lines = ["t,anchor,rssi_dbm,gt_x,gt_y"]
    for ti, p, r in zip(t, pts, y):
        lines += [f"{ti + 0.01 * a:.3f},{ids[a]},{v:.1f},{p[0]:.3f},{p[1]:.3f}" for a, v in enumerate(r)]
    (d / f"{name}.csv").write_text("\n".join(lines) + "\n")
    if odom:
        inc = np.hypot(*np.diff(pts, axis=0, prepend=pts[:1]).T)
        (d / f"{name}.odom.csv").write_text("t,dx,dy,dtheta\n" + "".join(f"{a:.3f},{b:.4f},0,0\n" for a, b in zip(t, inc)))


@pytest.fixture(scope="module")
def site_root(tmp_path_factory):
    """Two sites: one with a site.toml and odometry, one with only an anchors.json."""
    root = tmp_path_factory.mktemp("sites")
    rng = np.random.default_rng(11)
    a = root / "hall_a"
    a.mkdir()
    (a / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS)))
    for k in range(2):
        _write_run(a, f"walk{k}", k, rng, odom=(k == 0))
    b = root / "flat_b"
    b.mkdir()
    (b / "anchors.json").write_text(json.dumps({"name": "flat_b", "technology": "ble", "anchors": ANCHORS}))
    for k in range(3):
        _write_run(b, f"r{k}", k, rng)
    (root / "not_a_site").mkdir()
    return root


def test_find_sites_reads_both_site_file_kinds(site_root):
    found = {ts.name: ts for ts in sites.find_sites(site_root)}
    assert set(found) == {"hall_a", "flat_b"}
    assert found["hall_a"].run_names == ["walk0", "walk1"]
    assert found["hall_a"].run("walk0")[2].endswith("walk0.odom.csv") and found["hall_a"].run("walk1")[2] is None
    assert found["flat_b"].site_path.endswith("anchors.json")
    s = sites.site_from_anchors_json(found["flat_b"].site_path)
    assert s.anchor_ids == (0, 1, 2, 3, 4) and s.positions.tolist() == [list(p) for p in ANCHORS]
    assert [ts.name for ts in sites.find_sites(site_root / "flat_b")] == ["flat_b"]  # a site folder itself
    assert [ts.run_names for ts in sites.find_sites(site_root, odometry=False) if ts.name == "hall_a"][0] == ["walk0", "walk1"]
    with pytest.raises(InputError, match="no site folders"):
        sites.find_sites(site_root / "not_a_site")
    bad = site_root / "not_a_site" / "anchors.json"
    bad.write_text('{"anchors": [[0, 0], "x"]}')
    (site_root / "not_a_site" / "r.csv").write_text("t,anchor,rssi_dbm,gt_x,gt_y\n0,0,-50,0,0\n")
    from pfdoa.errors import ConfigError

    with pytest.raises(ConfigError, match="anchors"):
        sites.site_from_anchors_json(bad)
    bad.unlink()
    (site_root / "not_a_site" / "r.csv").unlink()


def test_pairs_follow_the_protocol():
    by = {ts.name: ts for ts in sites.committed_sites()}
    for name in sites.DEVELOPMENT_SITES:
        proto = sites.PROTOCOLS[name]
        ps = sites.pairs(by[name])
        assert all(cal != run for _r, cal, run in ps)
        held = [p for p in ps if p[0] == sites.HELD_OUT]
        assert {run for _r, _c, run in held} == set(proto.held_out)
        assert not {cal for _r, cal, _run in ps} & set(proto.held_out)  # held-out runs never calibrate
        assert {run for _r, _c, run in ps} == set(proto.develop) | set(proto.held_out)
    assert {r for r, _c, _s in sites.pairs(by["kolakowski_ble_dev"])} == {sites.CROSS}
    # a site without a protocol: every ordered pair; "none": the site file as given
    ts = by["philotuxo_ble_dev"]
    assert len(sites.pairs(ts, "cross")) == 9 * 8 and {r for r, _c, _s in sites.pairs(ts, "cross")} == {sites.CROSS}
    assert sites.pairs(ts, "none") == [(sites.AS_GIVEN, None, r) for r in ts.run_names]


def test_a_held_out_site_is_cross_calibrated_and_every_figure_held_out(tmp_path):
    """A committed site without development runs: each run calibrated on each other run,
    every scoring held out (so the study tools, which score development pairs only, never see
    it), the factors measured on its other runs, never the scored one; recognised by content
    in a folder of any name, and refused by the study tool."""
    held = [n for n, p in sites.PROTOCOLS.items() if p.whole_site]
    assert held and not set(held) & set(sites.DEVELOPMENT_SITES)
    by = {ts.name: ts for ts in sites.committed_sites()}
    for name in held:
        ts, runs = by[name], sites.PROTOCOLS[name].held_out
        assert set(ts.run_names) == set(runs)
        ps = sites.pairs(ts)
        assert sorted((c, s) for _r, c, s in ps) == sorted((c, s) for c in runs for s in runs if c != s)
        assert {r for r, _c, _s in ps} == {sites.HELD_OUT}
        assert sites.headline_role({r for r, _c, _s in ps}) == sites.HELD_OUT
        assert sites.in_sample(sites.HELD_OUT, ts).startswith("not in-sample")
        assert {r for r, _c, _s in sites.pairs(ts, "cross")} == {sites.CROSS}  # forced: still no decision saw it
        assert sites.in_sample(sites.CROSS, ts) == ("not in-sample: no decision looked at these runs "
                                                    f"(the room is held-out site {name}'s)")
    # the same runs under other names: the same protocol
    src = sites.DATA_DIR / held[0]
    copy = tmp_path / "renamed"
    shutil.copytree(src, copy)
    for p in copy.glob("*.csv.gz"):
        p.rename(copy / ("x_" + p.name))
    (ts2,) = sites.find_sites(copy)
    assert {r for r, _c, _s in sites.pairs(ts2)} == {sites.HELD_OUT}
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(copy), "--quick", "--methods", "wcl",
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"Protocol of held-out site {held[0]} (recognised by its runs' contents): every run held out" in r.stdout
    assert "**held-out (headline)**" in r.stdout and "cross-calibrated" not in r.stdout
    assert "make eval" not in r.stdout  # it regenerates docs/results.md, not a report of these sites
    r = subprocess.run([sys.executable, str(Path(__file__).resolve().parents[2] / "tools" / "sites_study.py"), "--sites", held[0], "--seeds", "1"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "not development sites" in r.stderr


def test_a_new_run_of_a_committed_site_is_scored_as_held_out(tmp_path):
    import gzip
    from dataclasses import replace

    ts = next(t for t in sites.committed_sites() if t.name == "kolakowski_ble_dev")
    lines = gzip.open(ts.runs[0][1], "rt").read().splitlines(keepends=True)
    new = tmp_path / "calib3.csv"
    new.write_text("".join(lines[:1] + lines[100:]))  # another recording: not a development run's content
    more = replace(ts, runs=ts.runs + (("calib3", str(new), None),))
    ps = sites.pairs(more)
    assert sorted((c, r) for role, c, r in ps if role == sites.HELD_OUT) == [("calib1", "calib3"), ("calib2", "calib3")]
    assert sites.headline_role({role for role, _c, _r in ps}) == sites.HELD_OUT


def _copy_run(src: str, dst, *, crlf: bool = False) -> None:
    import gzip

    text = gzip.open(src, "rt", newline="").read() if src.endswith(".gz") else open(src, newline="").read()
    dst.write_bytes(text.replace("\n", "\r\n").encode() if crlf else text.encode())


def test_a_committed_site_is_recognised_by_its_runs_contents(tmp_path):
    """Renamed folder and files, plain csv with CRLF line endings: the same protocol."""
    import shutil

    ts = next(t for t in sites.committed_sites() if t.name == "philotuxo_ble_dev")
    d = tmp_path / "hall_copy"
    d.mkdir()
    shutil.copy(sites.DATA_DIR / ts.name / "anchors.json", d / "anchors.json")
    renamed = {}
    for k, (run, path, _odo) in enumerate(ts.runs):
        _copy_run(path, d / f"track{k}.csv", crlf=(k == 0))
        renamed[run] = f"track{k}"
    copy = sites.site_folder(d)
    name, proto = sites.protocol_for(copy)
    assert name == "philotuxo_ble_dev"
    assert set(proto.develop) == {renamed[r] for r in sites.PROTOCOLS[name].develop}
    assert set(proto.held_out) == {renamed[r] for r in sites.PROTOCOLS[name].held_out}
    assert sorted(sites.pairs(copy)) == sorted((role, renamed[c], renamed[s]) for role, c, s in sites.pairs(ts))
    assert sites.in_sample(sites.DEVELOPMENT, copy).startswith("in-sample")
    assert sites.in_sample(sites.HELD_OUT, copy).startswith("not in-sample")


def test_other_tracks_of_a_development_room_are_held_out_and_calibrated_on_its_development_runs(tmp_path):
    """Other tracks of a development room, in a folder with its site file and none of its
    development runs (how a judge's other tracks come): `pfdoa eval --sites` calibrates them on
    the room's committed development runs and scores them as held out (not in-sample), as the
    room's own held-out track is; a single such track is no longer scored with the site file's
    neutral radio guess. The plain loader still sees only the folder (a new site, cross-calibrated)."""
    ts = next(t for t in sites.committed_sites() if t.name == "philotuxo_ble_dev")
    dev_runs = sites.PROTOCOLS[ts.name].develop
    d = tmp_path / "philotuxo_ble_dev"
    d.mkdir()
    shutil.copy(sites.DATA_DIR / ts.name / "anchors.json", d / "anchors.json")
    held = ts.run(sites.PROTOCOLS[ts.name].held_out[0])[1]
    _copy_run(held, d / "track_a.csv")
    dev = ts.run(dev_runs[0])[1]
    _copy_run(dev, d / "track_b.csv")
    lines = (d / "track_b.csv").read_text().splitlines(keepends=True)
    (d / "track_b.csv").write_text("".join(lines[:1] + lines[200:]))  # not the development run any more
    plain = sites.site_folder(d)
    assert sites.protocol_for(plain) is None
    assert sorted(sites.pairs(plain)) == [(sites.CROSS, "track_a", "track_b"), (sites.CROSS, "track_b", "track_a")]
    assert "the room is development site philotuxo_ble_dev's" in sites.in_sample(sites.CROSS, plain)
    assert sites.known_room(plain) == "philotuxo_ble_dev"

    (found,) = sites.find_sites(tmp_path)
    assert sorted(found.run_names) == sorted(["track_a", "track_b", *dev_runs])
    held_pairs = sorted(p for p in sites.pairs(found) if p[0] == sites.HELD_OUT)
    assert held_pairs == sorted((sites.HELD_OUT, c, s) for s in ("track_a", "track_b") for c in dev_runs)
    assert {p[2] for p in sites.pairs(found)} == {"track_a", "track_b", *dev_runs}  # theirs: development rows
    assert sites.in_sample(sites.HELD_OUT, found).startswith("not in-sample")
    assert sites.headline_role({p[0] for p in sites.pairs(found)}) == sites.HELD_OUT

    (d / "track_b.csv").unlink()
    one = sites.find_sites(d)[0]  # a single track: held out and calibrated, not "as given"
    assert sorted(p for p in sites.pairs(one) if p[0] == sites.HELD_OUT) == \
        sorted((sites.HELD_OUT, c, "track_a") for c in dev_runs)
    assert sites.AS_GIVEN not in {p[0] for p in sites.pairs(one)}
    # pfdoa eval --traces with the room's site file: the same
    from pfdoa.evaluation.datasets import trace_set

    given = trace_set("given", d / "anchors.json", [d / "track_a.csv"])
    assert sites.with_room_runs(given).runs == one.runs


def test_eval_sites_folder_reports_every_method_and_the_uncertainty_checks(site_root, tmp_path):
    out = tmp_path / "r.md"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(site_root), "--seeds", "2",
                        "--methods", "pf-doa", "wcl", "markov", "--no-progress", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "Dataset 0" not in text and "### hall_a" in text and "### flat_b" in text
    hall = text.split("### hall_a")[1].split("### ")[0]
    rows = {line.split("|")[1].strip() for line in hall.splitlines() if line.startswith("| ")}
    assert {"pf-doa", "pf-doa (no odom)", "wcl", "markov"} <= rows
    flat = text.split("### flat_b")[1].split("### ")[0]
    assert "6 pair(s)" in flat and "pf-doa (no odom)" not in flat  # no odometry: no duplicate rows
    pf = next(line for line in flat.splitlines() if line.startswith("| pf-doa |")).split("|")
    assert pf[10].strip() == "2"  # seeds
    assert pf[6].strip().endswith("%") and pf[7].strip().endswith("%")  # r95 and cov checks reported
    assert -1.0 <= float(pf[8]) <= 1.0  # how far r95 tracks the error


def test_eval_scores_what_calibrate_and_replay_give(site_root, tmp_path):
    """A site's evaluation is `pfdoa calibrate` on one run + `pfdoa replay --seed s` of another."""
    from pfdoa.cli import main
    from pfdoa.evaluation import datasets as ds
    from pfdoa.evaluation.experiments import EvalConfig, run_all, site_experiment

    ts = next(t for t in sites.find_sites(site_root) if t.name == "flat_b")
    cfg = EvalConfig(methods=("pf-doa",), sites=(ts,), site_seeds=2, table1=False, sweeps=False)
    res = run_all(cfg, progress=False)
    cell = res.cell("sites", site_experiment("flat_b", sites.CROSS, "r2"), "pf-doa")
    got = dict(zip(zip(cell.trials, range(len(cell.trials))), cell.errors))
    fitted = tmp_path / "fitted.toml"
    d = site_root / "flat_b"
    assert main(["-q", "calibrate", str(d / "r0.csv"), "--config", str(d / "anchors.json"), "--out", str(fitted)]) == 0
    truth = ds.trace_sequence(ts, "r2", ds.load_site_cached(ts.site_path)).truth
    for seed in (0, 1):
        out = tmp_path / f"e{seed}.jsonl"
        assert main(["-q", "replay", str(d / "r2.csv"), "--config", str(fitted), "--seed", str(seed),
                     "--out", str(out)]) == 0
        est = np.array([[r["x"], r["y"]] for r in map(json.loads, out.read_text().splitlines())])
        err = np.hypot(*(est - truth).T)
        # the pair calibrated on r0 is the first of r2's pairs for each seed
        first = next(e for (trial, _i), e in got.items() if trial == seed)
        np.testing.assert_allclose(err, first, atol=2e-4)  # output rounds to 0.1 mm
    assert set(METHODS) >= {"pf-doa"}


def _write_static_run(d, name, at, rng, seconds=30, rate_hz=3.0):
    """A beacon left at ``at``: every reading has the same ground truth."""
    site = _site()
    mu = mean_rssi(np.array([at]), site.positions, PathLoss(-55.0, 2.2)).ravel()
    lines = ["t,anchor,rssi_dbm,gt_x,gt_y"]
    for i in range(int(seconds * rate_hz)):
        lines += [f"{i / rate_hz + 0.01 * a:.3f},{a},{mu[a] + rng.normal(0, 2.0):.1f},{at[0]},{at[1]}"
                  for a in range(len(ANCHORS))]
    (d / f"{name}.csv").write_text("\n".join(lines) + "\n")


def test_eval_scores_static_beacon_runs_and_a_site_of_one_run(tmp_path):
    """A site of static-beacon runs (a calibration on one cannot separate the per-anchor
    offsets from the distances) and a site of one run are both scored, each labelled, instead
    of failing the whole folder."""
    rng = np.random.default_rng(12)
    toml = "[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS))
    static, single = tmp_path / "static", tmp_path / "single"
    for d in (static, single):
        d.mkdir()
        (d / "site.toml").write_text(toml)
    for k, at in enumerate([(2.0, 2.0), (6.0, 4.5), (3.0, 4.0)]):
        _write_static_run(static, f"spot{k}", at, rng)
    _write_run(single, "walk", 0, rng)
    out = tmp_path / "r.md"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(tmp_path), "--seeds", "2",
                        "--methods", "pf-doa", "wcl", "--no-progress", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "single: one run" in r.stderr
    text = out.read_text()
    st = text.split("### static")[1].split("### ")[0]
    assert "6 pair(s)" in st
    cal = [line for line in st.splitlines() if line.startswith("| spot")]
    assert len(cal) == 3 and all("| none |" in line for line in cal)  # no offsets fitted
    assert "static beacon" in st
    pf = float(next(line for line in st.splitlines() if line.startswith("| pf-doa |")).split("|")[2])
    assert pf < 0.6  # the beacons are found (wcl, which ignores the calibration, is ~1.5 m here)
    one = text.split("### single")[1].split("### ")[0]
    assert "site as given (headline)" in one and "1 pair(s)" in one



def test_slow_reporters_get_windows_of_their_interval_in_eval_calibrate_and_replay(tmp_path):
    """Anchors that report every 3 s, staggered: 1 s windows would hold one or two of the five
    anchors each; eval and calibrate take 3 s windows, and the fitted site carries them to replay."""
    from pfdoa import _toml as tomllib

    rng = np.random.default_rng(13)
    site, d = _site(), tmp_path / "slow"
    d.mkdir()
    (d / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS)))
    for k in range(2):
        lines = ["t,anchor,rssi_dbm,gt_x,gt_y"]
        for i in range(60):
            for a in range(len(ANCHORS)):
                t = 3.0 * i + 0.6 * a
                p = np.array([4 + 3 * np.cos(0.02 * t + k), 3 + 2 * np.sin(0.026 * t + k)])
                mu = mean_rssi(p[None], site.positions, PathLoss(-55.0, 2.2))[0, a]
                lines.append(f"{t:.3f},{a},{mu + rng.normal(0, 2.0):.1f},{p[0]:.3f},{p[1]:.3f}")
        (d / f"walk{k}.csv").write_text("\n".join(lines) + "\n")
    (ts,) = sites.find_sites(d)
    assert ts.window_s == 3.0
    assert sites.find_sites(d, window_s=1.0)[0].window_s == 1.0  # an explicit window wins
    out = tmp_path / "r.md"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(d), "--seeds", "1",
                        "--methods", "pf-doa", "--no-progress", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "same windows (3 s:" in text
    assert "estimator seed 0 per (calibration run" in text and "0-0" not in text  # one seed, named as one
    fitted = tmp_path / "fitted.toml"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "calibrate", str(d / "walk0.csv"), "--config",
                        str(d / "site.toml"), "--out", str(fitted)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert tomllib.loads(fitted.read_text())["gateway"]["window_s"] == 3.0
    r = subprocess.run([sys.executable, "-m", "pfdoa", "replay", str(d / "walk1.csv"), "--config", str(fitted),
                        "--seed", "0"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert 55 <= len(r.stdout.splitlines()) <= 61  # one estimate per 3 s, not one or two anchors per second


def test_an_unreadable_site_in_a_folder_of_sites_is_named_and_the_others_are_scored(tmp_path):
    """One bad site folder (an anchor id beyond any trace's; a header-only trace) used to stop the
    whole folder's evaluation with exit 2 and no report. Now the readable site is scored, the
    bad ones are named on stderr and in the report, and the exit status is still 2."""
    rng = np.random.default_rng(5)
    good = tmp_path / "good"
    good.mkdir()
    (good / "anchors.json").write_text(json.dumps({"anchors": ANCHORS}))
    for k in range(2):
        _write_run(good, f"w{k}", k, rng)
    ids = tmp_path / "big_ids"
    ids.mkdir()
    (ids / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {2**31 + i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS)))
    _write_run(ids, "w0", 0, rng)
    empty = tmp_path / "empty_run"
    empty.mkdir()
    (empty / "anchors.json").write_text(json.dumps({"anchors": ANCHORS}))
    _write_run(empty, "w0", 0, rng)
    (empty / "w1.csv").write_text("t,anchor,rssi_dbm,gt_x,gt_y\n")
    out = tmp_path / "r.md"
    cmd = [sys.executable, "-m", "pfdoa", "eval", "--seeds", "1", "--methods", "wcl", "--no-progress"]
    r = subprocess.run(cmd + ["--sites", str(tmp_path), "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    text = out.read_text()
    assert "### good" in text and "### big_ids" not in text and "### empty_run" not in text
    good_rows = text.split("### good")[1]
    assert any(line.startswith("| wcl |") for line in good_rows.splitlines())
    refused = text.split("**Not evaluated**: 2 site folder(s)")[1].split("###")[0]
    assert f"big_ids/site.toml: anchors[0].id: must be in 0..{SITE_ANCHOR_ID_MAX}, got {2**31}" in refused
    assert "empty_run/w1.csv" in refused
    assert "site big_ids not evaluated" in r.stderr and "site empty_run not evaluated" in r.stderr
    # A folder that is itself a site must still read whole: one line, exit 2, no report.
    r = subprocess.run(cmd + ["--sites", str(empty), "--out", str(tmp_path / "e.md")], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 2 and "empty_run/w1.csv" in r.stderr and not (tmp_path / "e.md").exists()
    # Nothing readable at all: one line naming the folder.
    shutil.rmtree(good)
    r = subprocess.run(cmd + ["--sites", str(tmp_path), "--out", str(tmp_path / "n.md")], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 2 and "none of its 2 site folder(s) could be read" in r.stderr


def test_a_site_whose_anchor_ids_only_a_recording_can_hold_is_scored_as_if_numbered_from_0(tmp_path):
    """Anchor ids are the dataset's own (a BLE receiver's number, 6501...), not our frames'
    0..126: eval of a site with such ids gives the report of the same site numbered 0..4."""
    rows = {}
    for name, ids in (("small", list(range(len(ANCHORS)))), ("large", [6501, 6502, 2**31 - 1, 200, 127])):
        root = tmp_path / name
        d = root / "room"
        d.mkdir(parents=True)
        (d / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
            f"\n[[anchors]]\nid = {a}\nx = {x}\ny = {y}\n" for a, (x, y) in zip(ids, ANCHORS)))
        rng = np.random.default_rng(3)
        for k in range(3):
            _write_run(d, f"w{k}", k, rng, ids=ids)
        out = tmp_path / f"{name}.md"
        r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(root), "--seeds", "2",
                            "--methods", "pf-doa", "wcl", "--no-progress", "--out", str(out)],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        section = out.read_text().split("### room")[1].split("### ")[0]
        scores, per_run = section.split("Per scored run")
        rows[name] = [line for line in scores.splitlines() if line.startswith(("| pf-doa |", "| wcl |"))] + [
            line.rsplit("|", 2)[0] for line in per_run.splitlines()  # not its last column, the step time
            if line.startswith(("| pf-doa |", "| wcl |"))]
    assert len(rows["small"]) == 4 and {line.split("|")[1].strip() for line in rows["small"]} == {"pf-doa", "wcl"}
    assert rows["large"] == rows["small"]


def test_the_targets_line_says_above_when_pf_doa_is_behind():
    """docs/results.md said "-5 % below the best other method" for a site pf-doa loses."""
    from pfdoa.evaluation.report import _below

    assert _below(0.18) == "18 % below" and _below(-0.05) == "5 % above" and _below(0.0) == "0 % below"


def _write_two_beacon_run(d, name, k, rng, rate_hz=3.0):
    """Two beacons walking apart in one trace (a beacon column), each reading with its own
    beacon's ground truth, as a gateway's --readings-out of two named beacons writes."""
    site = _site()
    rows = []
    for b, phase in (("b1", k), ("b2", k + 2.5)):
        t, pts = _walk(rate_hz, phase)
        y = mean_rssi(pts, site.positions, PathLoss(-55.0 - 2 * (b == "b2"), 2.2)) + rng.normal(0, 2.5, (t.size, 5))
        rows += [(ti + 0.01 * a + 0.005 * (b == "b2"), a, v, p, b) for ti, p, r in zip(t, pts, y) for a, v in enumerate(r)]
    rows.sort(key=lambda r: r[0])
    (d / f"{name}.csv").write_text("t,anchor,rssi_dbm,gt_x,gt_y,beacon\n" + "".join(
        f"{ti:.3f},{a},{v:.1f},{p[0]:.3f},{p[1]:.3f},{b}\n" for ti, a, v, p, b in rows))


def test_eval_scores_each_beacon_of_a_run_as_replay_tracks_it(tmp_path):
    """A run whose readings name two beacons is scored as `pfdoa replay` tracks it: each beacon
    alone with its own seed, the errors pooled; a run whose odometry has no readings to go
    with (every reading names one of several beacons) is one clear line, exit 2."""
    from pfdoa.cli import main
    from pfdoa.evaluation import datasets as ds
    from pfdoa.evaluation.experiments import EvalConfig, run_all, site_experiment

    d = tmp_path / "two_tags"
    d.mkdir()
    (d / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(ANCHORS)))
    rng = np.random.default_rng(5)
    for k in range(3):
        _write_two_beacon_run(d, f"r{k}", k, rng)
    (ts,) = sites.find_sites(d)
    res = run_all(EvalConfig(methods=("pf-doa", "wcl"), sites=(ts,), site_seeds=2, table1=False, sweeps=False),
                  progress=False)
    cell = res.cell("sites", site_experiment("two_tags", sites.CROSS, "r2"), "pf-doa")
    assert not cell.failure
    parts = ds.trace_sequences(ts, "r2", ds.load_site_cached(ts.site_path))
    assert [p.beacon for p in parts] == ["b1", "b2"]
    fitted = tmp_path / "fitted.toml"
    assert main(["-q", "calibrate", str(d / "r0.csv"), "--config", str(d / "site.toml"), "--out", str(fitted)]) == 0
    for seed in (0, 1):
        out = tmp_path / f"e{seed}.jsonl"
        assert main(["-q", "replay", str(d / "r2.csv"), "--config", str(fitted), "--seed", str(seed),
                     "--out", str(out)]) == 0
        rows = [json.loads(ln) for ln in out.read_text().splitlines()]
        err = np.concatenate([np.hypot(*(np.array([[r["x"], r["y"]] for r in rows if r["beacon"] == p.beacon])
                                          - p.truth).T) for p in parts])
        first = cell.errors[cell.trials.index(seed)]  # the pair calibrated on r0 is r2's first
        np.testing.assert_allclose(err, first, atol=2e-4)  # output rounds to 0.1 mm
    # the path plot's arrays: each tag's path, a NaN row between them (the line breaks there)
    truth, est = res.paths[("sites", site_experiment("two_tags", sites.CROSS, "r2"))]
    gap = np.flatnonzero(np.isnan(truth).all(axis=1))
    assert gap.tolist() == [len(parts[0].truth)] and len(truth) == len(parts[0].truth) + 1 + len(parts[1].truth)
    np.testing.assert_array_equal(truth[gap[0] + 1:], parts[1].truth)
    assert est["pf-doa"].shape == truth.shape and np.isnan(est["pf-doa"][gap[0]]).all()
    assert not np.isnan(np.delete(est["pf-doa"], gap, axis=0)).any()
    # each tag tracked alone: far better than one filter fed both tags' readings could do
    assert cell.pooled_rmse < 0.8 < res.cell("sites", site_experiment("two_tags", sites.CROSS, "r2"), "wcl").pooled_rmse
    (d / "r0.odom.csv").write_text("t,dx,dy,dtheta\n0,0,0,0\n1,0.1,0,0\n")
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--sites", str(d), "--quick", "--no-progress"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "r0.csv" in r.stderr and "2 beacons" in r.stderr and "no beacon name" in r.stderr
