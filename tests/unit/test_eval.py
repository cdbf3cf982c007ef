"""`pfdoa eval`: pieces of the harness, a user's own traces, usage errors (the whole quick run:
tests/sil/test_eval_quick.py)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pfdoa.estimators import METHODS
from pfdoa.evaluation import datasets as ds
from pfdoa.evaluation.experiments import EvalConfig, Job, build_jobs, execute, job_seed
from pfdoa.evaluation.runner import Variant, run_sequence


def test_results_do_not_depend_on_method_subset_or_order():
    cfg = EvalConfig(methods=("wcl", "pf-doa"), trials_sim=1)
    job = Job("dataset0", "Inside@2dB", 0, ("Inside", 2.0, 3.0), (Variant("pf-doa", "pf-doa", True),))
    both = Job(job.block, job.experiment, 0, job.params, (Variant("wcl", "wcl"), Variant("pf-doa", "pf-doa", True)))
    a = execute(cfg, job).results["pf-doa"]
    b = execute(cfg, both).results["pf-doa"]
    np.testing.assert_array_equal(a.errors, b.errors)
    assert a.errors.size == len(ds.d0_sequence("Inside", 2.0, np.random.default_rng(0)))
    assert job_seed(cfg, job, "data").entropy == job_seed(cfg, both, "data").entropy


def test_errors_are_plain_euclidean_and_truth_is_not_passed():
    class Spy:
        seen: list = []

    from pfdoa.estimators.base import Estimate

    site = ds.d0_site()
    truth = np.array([[1.0, 1.0], [2.0, 3.0]])
    seq = ds.Sequence("x", site, np.array([0.0, 1.0]), np.full((2, 4), -50.0), truth, None)
    import pfdoa.estimators as est

    class Fixed:
        def step(self, obs, odom=None):
            Spy.seen.append(obs)
            return Estimate(obs.t, 1.0, 4.0 if obs.t else float("nan"), 0.0)

    orig = est.make_estimator
    est.make_estimator = lambda *a, **k: Fixed()
    try:
        r = run_sequence(Variant("x", "x"), seq, np.random.default_rng(0))
    finally:
        est.make_estimator = orig
    # step 0: NaN estimate -> held at the anchors' centroid (3, 3); step 1: (1, 4) vs (2, 3)
    np.testing.assert_allclose(r.errors, [np.hypot(2.0, 2.0), np.hypot(1.0, 1.0)])
    assert r.held == 1
    assert all(set(vars(o)) == {"t", "rssi", "count"} for o in Spy.seen)


def test_job_list_covers_the_table():
    from pfdoa.estimators import uses_rng
    from pfdoa.evaluation import sites

    cfg = EvalConfig(methods=METHODS, trials_sim=2, trials_real=1, sweeps=False, site_seeds=3)
    jobs = build_jobs(cfg)
    blocks = {j.block for j in jobs}
    assert blocks == {"dataset0", "dataset1-paper", "dataset1-fitted", "dataset2", "sites"}
    assert sum(j.block == "dataset0" for j in jobs) == 2 * 3 * len(cfg.noise_db)
    site_jobs = [j for j in jobs if j.block == "sites"]
    assert all(j.params[2] != j.params[3] for j in site_jobs)  # never scored on its own calibration
    robot = [j for j in site_jobs if j.params[0] == "herolab_wifi_robot" and j.trial == 0]
    proto = sites.PROTOCOLS["herolab_wifi_robot"]
    held = [j for j in robot if j.params[1] == sites.HELD_OUT]
    assert len(held) == len(proto.held_out) * len(proto.develop)
    assert {j.params[3] for j in held} == set(proto.held_out)
    assert not {j.params[2] for j in robot} & set(proto.held_out)  # a held-out run never calibrates
    # seeds 0, 1, 2 for the seeded methods; a method without randomness runs once
    for seed in (1, 2):
        later = [j for j in site_jobs if j.trial == seed]
        assert len(later) == sum(j.trial == 0 for j in site_jobs)
        assert all(uses_rng(v.method) for j in later for v in j.variants)
    assert any(not uses_rng(v.method) for j in robot for v in j.variants)


def test_dataset_loaders():
    pts, rssi = ds._d1_table("wifi", "dataset1")
    assert pts.shape == (49, 2) and rssi.shape == (49, 3) and np.all(rssi < 0)
    d2 = ds.d2_data()
    assert len(d2.points) == 11 and np.allclose(d2.points[:, 0], d2.points[:, 1])
    seq = ds.d2_sequence([0, 1], (0,), ds.d2_site(-45, 2), "t")
    assert seq.rssi.shape == (2 * ds.D2_DWELL, 4) and np.isfinite(seq.rssi).all()
    from pfdoa.evaluation import sites

    by_name = {ts.name: ts for ts in sites.committed_sites()}
    robot, kola, philo = (by_name[n] for n in ("herolab_wifi_robot", "kolakowski_ble_dev", "philotuxo_ble_dev"))
    rs = ds.trace_sequence(robot, robot.run_names[0], ds.load_site_cached(robot.site_path))
    assert rs.rssi.shape[1] == 4 and len(rs.odometry) == len(rs)
    assert np.isfinite(rs.truth).all()
    # the 1/3 s BLE grid: three readings per anchor in most 1 s windows
    ks = ds.trace_sequence(kola, "calib1", ds.load_site_cached(kola.site_path))
    assert ks.odometry is None and np.median(ks.count) == 3
    assert len(philo.runs) == 9 and ds.load_site_cached(philo.site_path).positions.shape == (12, 2)


def test_report_is_reproducible_apart_from_timing():
    from pfdoa.evaluation import sites
    from pfdoa.evaluation.experiments import run_all
    from pfdoa.evaluation.report import render, without_timing

    cfg = EvalConfig(methods=("pf-doa", "wcl"), trials_sim=1, trials_real=1, noise_db=(2.0,),
                     sites=tuple(ts for ts in sites.committed_sites() if ts.name == "herolab_wifi_robot"), site_pairs=1, site_seeds=1, sweeps=False,
                     d2_channel_sets=("Channel 0",))
    a = render(run_all(cfg, progress=False), "x", {}, [])
    b = render(run_all(cfg, progress=False), "x", {}, [])
    assert "TPI ms" in a and "TPI ms" not in without_timing(a)
    assert without_timing(a) == without_timing(b)
    assert "pf-doa" in without_timing(a)


def _write_run(d, name, pts, site, rng, odom=True):
    """A synthetic run in the common formats (ground truth + optional odometry)."""
    from pfdoa.radio import PathLoss, mean_rssi

    mu = mean_rssi(pts, site.positions, PathLoss.from_site(site), site.offsets)
    y = mu + rng.normal(0, 2.0, mu.shape)
    lines = ["t,anchor,rssi_dbm,gt_x,gt_y"]
    for i, (p, r) in enumerate(zip(pts, y)):
        lines += [f"{i}.0,{a.id},{v:.1f},{p[0]:.3f},{p[1]:.3f}" for a, v in zip(site.anchors, r)]
    (d / f"{name}.csv").write_text("\n".join(lines) + "\n")
    if odom:
        d_ = np.diff(pts, axis=0, prepend=pts[:1])
        (d / f"{name}.odom.csv").write_text("t,dx,dy,dtheta\n" + "".join(
            f"{i}.0,{np.hypot(*v):.4f},0,0\n" for i, v in enumerate(d_)))


def test_eval_on_user_traces(tmp_path):
    """--traces: any site in the common formats, cross-calibrated, every method row."""
    site_text = ("[radio]\nrssi_at_1m_dbm = -50.0\npath_loss_exponent = 2.5\n"
                 + "".join(f"\n[[anchors]]\nid = {i + 10}\nx = {x}\ny = {y}\n"
                           for i, (x, y) in enumerate([(0, 0), (12, 0), (12, 9), (0, 9), (6, -1)])))
    (tmp_path / "site.toml").write_text(site_text)
    from pfdoa.site import load_site

    site = load_site(tmp_path / "site.toml")
    rng = np.random.default_rng(7)
    for k in range(2):
        pts = np.column_stack([np.linspace(1 + k, 11, 30), np.linspace(2, 8 - k, 30)])
        _write_run(tmp_path, f"run{k}", pts, site, rng, odom=(k == 0))
    out = tmp_path / "r.md"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--traces", str(tmp_path / "run0.csv"),
                        str(tmp_path / "run1.csv"), "--config", str(tmp_path / "site.toml"), "--no-progress",
                        "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert f"### {tmp_path.name}" in text and "Dataset 0" not in text and "Calibrations" in text
    # a user's own traces get the comparison, not the project's targets (those are `make eval`'s)
    assert "PASS" not in text and "FAIL" not in text and "Project targets" not in text
    rows = {line.split("|")[1].strip() for line in text.splitlines() if line.startswith("| ")}
    assert set(METHODS) <= rows and "pf-doa (no odom)" in rows
    # how far r95 tracks the error: a correlation for the methods that report r95, "-" for the others
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("| method | pooled RMSE m"))
    col = [c.strip() for c in lines[at].split("|")].index("r95 tracks error")
    table = lines[at + 2:lines.index("", at)]
    cell = {line.split("|")[1].strip(): line.split("|")[col].strip() for line in table}
    assert -1.0 <= float(cell["pf-doa"]) <= 1.0 and cell["wcl"] == "-"
    bad = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--traces", str(tmp_path / "run0.odom.csv"),
                          "--config", str(tmp_path / "site.toml")], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "rssi_dbm" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.parametrize("args, needle", [
    (["--methods", "nope"], "unknown method"),
    (["--trials", "0"], "--trials must be >= 1"),
    (["--config", "x.toml"], "goes with --traces"),
    (["--sites", "no/such/dir"], "no such folder"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--traces", "missing.csv"], "needs --config"),
])
def test_eval_usage_errors_are_one_line(args, needle):
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--quick", "--no-progress", *args],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
