"""Calibration walks (`pfdoa sim --calibrate N`): the same room walked again, recorded through
the gateway with ground truth, fitted by `pfdoa calibrate`, and the run given the fitted site."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoa.site import load_site
from pfdoasim.backends import anchor_factory
from pfdoasim.runner import Simulation
from pfdoasim.scenario import build
from pfdoasim.transports import Transport


def _sim(sc) -> Simulation:
    return Simulation(sc, Transport(), anchor_factory("py-mean", None), speed=0.0)


@pytest.mark.unit
def test_a_calibration_walk_is_the_same_room_with_a_walk_and_noise_of_its_own():
    run, walk1, walk2 = (build("demo", seed=3, duration_s=20.0, walk=k) for k in (0, 1, 2))
    assert run.site == walk1.site == walk2.site and (run.walk, walk1.walk, walk2.walk) == (0, 1, 2)
    assert not np.allclose(run.track[:50, 1:3], walk1.track[:50, 1:3])
    assert not np.allclose(walk1.track[:50, 1:3], walk2.track[:50, 1:3])
    a, b = _sim(run), _sim(walk1)
    pts = np.random.default_rng(0).uniform(0.0, 6.0, (200, 2))
    np.testing.assert_array_equal(a.channel.shadowing(pts), b.channel.shadowing(pts))  # the same walls
    assert a.drift == b.drift and a.boot_ms == b.boot_ms  # the same anchors' clocks
    p, ch = np.array([2.0, 3.0]), run.channels
    ra = np.concatenate([a.channel.sample(p, ch)[0] for _ in range(20)], axis=1)
    rb = np.concatenate([b.channel.sample(p, ch)[0] for _ in range(20)], axis=1)
    assert not np.array_equal(ra, rb)  # noise of its own
    again = _sim(build("demo", seed=3, duration_s=20.0))  # the run itself draws as it always did
    np.testing.assert_array_equal(ra, np.concatenate([again.channel.sample(p, ch)[0] for _ in range(20)], axis=1))


@pytest.mark.unit
def test_only_a_seeded_walk_can_be_walked_again():
    with pytest.raises(InputError, match="fixed track"):
        build("espresense-6x4", seed=1, walk=1)
    with pytest.raises(InputError, match="fixed track"):
        build("paper-inside", seed=1, walk=2)


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
    the truth more often (measured 0.35 -> 0.22 m, 57 -> 68 %)."""
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
@pytest.mark.xfail(strict=True, reason="known: in the simulated demo room (10 observations a second, walls "
                   "that persist over many of them, odometry) pf-doa's misfit term, chosen on real sites "
                   "observed once a second, is too narrow: truth within the cov ellipse for 68 % after two "
                   "calibration walks (docs/estimator.md); strict, so a fix shows here")
def test_the_demo_rooms_covariance_holds_the_truth_95_percent_of_the_time(demo_runs):
    _, _, docs = demo_runs
    assert docs["demo"]["score"]["in_cov"] >= 0.88
