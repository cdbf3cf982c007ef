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


@pytest.mark.sil
def test_calibration_walks_make_the_demo_rooms_uncertainty_honest(tmp_path):
    """The demo room's walls (1 dB shadowing, the same at every pass): the gateway given the
    room's true model, its walls' size included (shadowing_db; without it the filter takes
    them for noise that averages out: test_estimators), reports a covariance that holds the
    truth at least 88 % of the time. Two calibration walks, fitted by pfdoa calibrate (radio
    model, radio map, factors measured per beacon with odometry), give the same run a
    smaller error, still with a covariance that holds the truth at least 88 % of the time."""
    plain = _sim_json(tmp_path, "--out-dir", str(tmp_path / "plain"))["demo"]["score"]
    docs = _sim_json(tmp_path, "--out-dir", str(tmp_path / "cal"), "--calibrate", "2")
    cal, info = docs["demo"]["score"], docs["calibration"]
    assert load_site(tmp_path / "plain" / "site.toml").sections["estimator"]["shadowing_db"] == 1.0
    assert plain["in_cov"] >= 0.88 and plain["in_r95"] >= 0.88
    assert cal["in_cov"] >= 0.88 and cal["in_r95"] >= 0.88
    assert cal["rmse_m"] < 0.85 * plain["rmse_m"]
    assert len(info["walks"]) == 2 and any("radio map" in line for line in info["report"])
    fitted = load_site(info["site"])
    est = fitted.sections["estimator"]
    assert {"r95_scale", "cov_scale", "r95_scale_odometry", "cov_scale_odometry", "factor_rule"} <= set(est)
    assert "radio_map" in fitted.sections
    given = load_site(tmp_path / "cal" / "site.toml")  # what the run's gateway was given
    assert given.radio == fitted.radio and given.sections["radio_map"] == fitted.sections["radio_map"]
    assert given.sections["estimator"] == est and given.sections["gateway"]["set_timeout_s"] == 0.3
    assert given.radio.rssi_at_1m_dbm != load_site(tmp_path / "plain" / "site.toml").radio.rssi_at_1m_dbm
    walk = load_site(tmp_path / "cal" / "calibration" / "walk1" / "site.toml")
    assert "radio_map" not in walk.sections  # the walks were recorded with the room's site file
