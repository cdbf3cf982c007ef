import numpy as np
import pytest

from pfdoa.odometry import OdometryNoise, increments, noisy_increments
from pfdoa.radio import PathLoss, mean_rssi
from pfdoasim.channel import Channel, ChannelConfig

ANCHORS = np.array([[0.0, 0.0], [0.0, 6.0], [6.0, 6.0], [6.0, 0.0]])
MODEL = PathLoss(-45.0, 3.0)


def make(cfg, seed=1, offsets=None):
    return Channel(ANCHORS, MODEL, offsets, cfg, np.random.default_rng(seed))


def test_readings_are_whole_dbm_around_the_shared_radio_model():
    offsets = np.array([1.0, -2.0, 0.0, 3.0])
    ch = make(ChannelConfig(noise_db=2.5), offsets=offsets)
    p = np.array([2.0, 1.5])
    r = np.concatenate([ch.sample(p, np.array([37, 38, 39]))[0] for _ in range(2000)], axis=1)
    assert np.all(r == np.round(r))
    expect = mean_rssi(p, ANCHORS, MODEL, offsets)
    assert np.allclose(r.mean(axis=1), expect, atol=0.15)
    # 2.5 dB Gaussian plus uniform rounding error (1/12 dB^2)
    assert np.allclose(r.std(axis=1), np.sqrt(2.5**2 + 1 / 12), atol=0.12)


def test_multipath_bursts_hit_the_configured_fraction():
    ch = make(ChannelConfig(noise_db=0.0, multipath_prob=0.1, multipath_db=6.0, quantize_db=0.0))
    p = np.array([3.0, 3.0])
    base = mean_rssi(p, ANCHORS, MODEL)[:, None]
    hits = total = 0
    for _ in range(3000):
        r, counts = ch.sample(p, np.array([37]))
        d = base - r
        assert np.all(np.isclose(d, 0) | np.isclose(d, 6.0))
        hits += int(np.isclose(d, 6.0).sum())
        assert counts["multipath"] == int(np.isclose(d, 6.0).sum())
        total += d.size
    assert 0.085 < hits / total < 0.115


def test_shadowing_is_seeded_smooth_and_has_the_configured_spread():
    cfg = ChannelConfig(shadowing_db=3.0, shadowing_corr_m=1.0)
    a, b = make(cfg, seed=5), make(cfg, seed=5)
    pts = np.random.default_rng(0).uniform(-50, 50, size=(4000, 2))
    s = a.shadowing(pts)
    assert np.array_equal(s, b.shadowing(pts))
    assert 2.5 < s.std() < 3.5
    near = a.shadowing(pts + [0.05, 0.0])
    far = a.shadowing(pts + [5.0, 0.0])
    assert np.corrcoef(s.ravel(), near.ravel())[0, 1] > 0.95
    assert abs(np.corrcoef(s.ravel(), far.ravel())[0, 1]) < 0.15
    assert not np.array_equal(s, make(cfg, seed=6).shadowing(pts))


def test_missed_and_below_sensitivity_readings_are_nan():
    ch = make(ChannelConfig(noise_db=0.0, miss_prob=0.3, floor_dbm=-200))
    r = np.concatenate([ch.sample(np.array([1.0, 1.0]), np.array([37]))[0] for _ in range(2000)])
    assert 0.25 < np.isnan(r).mean() < 0.35
    deaf = make(ChannelConfig(noise_db=0.0, floor_dbm=-40))
    assert np.isnan(deaf.sample(np.array([3.0, 3.0]), np.array([37]))[0]).all()


def test_odometry_increments_are_in_the_robot_frame():
    # Heading north (pi/2), moving 1 m north then turning left: dx forward = 1, dy = 0.
    track = np.array([[0.0, 0.0, 0.0, np.pi / 2], [1.0, 0.0, 1.0, np.pi / 2], [2.0, -1.0, 1.0, np.pi]])
    inc = increments(track)
    assert np.allclose(inc[0, 1:], 0)
    assert np.allclose(inc[1, 1:], [1.0, 0.0, 0.0])
    assert np.allclose(inc[2, 1:], [0.0, 1.0, np.pi / 2])  # 1 m to the robot's left, then turned
    noisy = noisy_increments(np.repeat(track[1:2], 4000, axis=0) * [1, 1, 1, 1], OdometryNoise(trans_abs_m=0.01), np.random.default_rng(1))
    assert noisy[:, 1].std() == pytest.approx(0.01, rel=0.1)
