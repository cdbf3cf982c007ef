"""Calibration walks (`pfdoa sim --calibrate N`): the same room walked again, recorded through
the gateway with ground truth, fitted by `pfdoa calibrate`, and the run given the fitted site."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from pfdoa.site import load_site


def _sim_json(tmp_path, *args):
    cmd = [sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--gateway", "--odom", "--duration", "40",
           "--seed", "5", "--json", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return {d["label"]: d for d in json.loads(r.stdout)}


@pytest.fixture(scope="module")
def demo_runs(tmp_path_factory):
    """The demo room (walls: 1 dB shadowing, the same at every pass), seed 5, 40 s with
    odometry: given the room's true path-loss model alone, and after two calibration walks."""
    tmp = tmp_path_factory.mktemp("demo")
    plain = _sim_json(tmp, "--out-dir", str(tmp / "plain"))["demo"]["score"]
    docs = _sim_json(tmp, "--out-dir", str(tmp / "cal"), "--calibrate", "2")
    return tmp, plain, docs


@pytest.mark.sil
def test_calibration_walks_fit_the_demo_rooms_walls(demo_runs):
    """Two calibration walks, fitted by pfdoa calibrate (radio model, radio map), give the run
    a smaller error than the room's true path-loss model alone, and a covariance that holds
    the truth more often (measured 0.31 -> 0.22 m, 59 -> 68 %, seed 5)."""
    tmp_path, plain, docs = demo_runs
    cal, info = docs["demo"]["score"], docs["calibration"]
    assert "estimator" not in load_site(tmp_path / "plain" / "site.toml").sections  # nothing declared
    assert cal["rmse_m"] < 0.85 * plain["rmse_m"]
    assert cal["in_cov"] > plain["in_cov"] + 0.05 and cal["in_r95"] > plain["in_r95"]
    assert len(info["walks"]) == 2 and any("radio map" in line for line in info["report"])
    fitted = load_site(info["site"])
    est = fitted.sections.get("estimator", {})
    assert "radio_map" in fitted.sections
    given = load_site(tmp_path / "cal" / "site.toml")  # what the run's gateway was given
    assert given.radio == fitted.radio and given.sections["radio_map"] == fitted.sections["radio_map"]
    assert given.sections.get("estimator", {}) == est and given.sections["gateway"]["set_timeout_s"] == 0.3
    assert given.radio.rssi_at_1m_dbm != load_site(tmp_path / "plain" / "site.toml").radio.rssi_at_1m_dbm
    walk = load_site(tmp_path / "cal" / "calibration" / "walk1" / "site.toml")
    assert "radio_map" not in walk.sections  # the walks were recorded with the room's site file


@pytest.mark.sil
def test_the_demo_rooms_covariance_holds_the_truth_95_percent_of_the_time(demo_runs):
    """The simulated demo room (10 observations a second, walls that persist over many of
    them, odometry) after two calibration walks: the misfit term and the centroid's put the
    truth within the cov ellipse for most estimates and within r95 for at least the band's
    85 % (the cov ellipse 68 % with the misfit at 0.5 alone). Its top: below."""
    _, _, docs = demo_runs
    # measured: cov 84.8 %, r95 94.0 % (88.2 and 91.9 % before a slow target's likelihood was
    # tempered, RMSE 0.221 -> 0.216 m; 90.6 and 92.4 % with the misfit at 1.3 x)
    score = docs["demo"]["score"]
    assert score["in_cov"] >= 0.84 and score["in_r95"] >= 0.85


@pytest.mark.sil
def test_the_demo_rooms_r95_is_no_wider_than_the_band(demo_runs):
    """Its top (94.0 %; 98.2 % while the anchors' offsets learnt at the same rate whatever the
    estimate's speed, docs/estimator.md, "Likelihood")."""
    _, _, docs = demo_runs
    assert docs["demo"]["score"]["in_r95"] <= 0.98
