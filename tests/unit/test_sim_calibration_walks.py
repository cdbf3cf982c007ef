"""Calibration walks (`pfdoa sim --calibrate N`) in-process: a walk is the same room (walls,
anchors' clocks) walked again with a walk and noise of its own. The walks through the gateway
and the fitted site are tests/sil/test_sim_calibration.py."""

from __future__ import annotations

import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoasim.backends import anchor_factory
from pfdoasim.runner import Simulation
from pfdoasim.scenario import build
from pfdoasim.transports import Transport


def _sim(sc) -> Simulation:
    return Simulation(sc, Transport(), anchor_factory("py-mean", None), speed=0.0)


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


def test_only_a_seeded_walk_can_be_walked_again():
    with pytest.raises(InputError, match="fixed track"):
        build("espresense-6x4", seed=1, walk=1)
    with pytest.raises(InputError, match="fixed track"):
        build("paper-inside", seed=1, walk=2)
