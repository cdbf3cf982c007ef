import numpy as np
import pytest

from pfdoa.paths import PAPER_PATHS, paper_path
from pfdoasim.trajectories import random_waypoints, timed, walking_track, waypoint_path


@pytest.mark.parametrize("name", PAPER_PATHS)
def test_paper_paths_stay_in_room_with_fixed_steps(name):
    p = paper_path(name, size_m=6.0, step_m=0.1)
    assert p.ndim == 2 and p.shape[1] == 2 and len(p) > 20
    assert p.min() >= -1e-9 and p.max() <= 6.0 + 1e-9
    steps = np.hypot(*np.diff(p, axis=0).T)
    # Every step is 0.1 m except the jumps between separately drawn segments.
    assert np.sum(np.abs(steps - 0.1) > 1e-6) <= 1


def test_paper_path_shapes():
    b = paper_path("boundary")
    # On the walls: each point touches x in {0,6} or y in {0,6}.
    on_wall = np.isclose(b[:, 0], 0) | np.isclose(b[:, 0], 6) | np.isclose(b[:, 1], 0) | np.isclose(b[:, 1], 6)
    assert on_wall.all() and len(b) == 240
    assert np.allclose(b[0], [3, 6])
    d = paper_path("diagonal")
    assert np.allclose(d[0], [3, 3])
    first = d[: len(d) // 2]
    assert np.allclose(first[:, 0], first[:, 1])  # the centre -> corner diagonal
    i = paper_path("inside", size_m=10.0, step_m=0.5)
    assert np.allclose(i[0], [5, 5]) and np.allclose(i[len(i) // 2], [5, 10])
    with pytest.raises(ValueError):
        paper_path("spiral")


def test_random_waypoints_seeded_and_bounded():
    a = random_waypoints(20, (0, 0, 6, 4), rng=3, margin_m=0.5, min_leg_m=1.0)
    b = random_waypoints(20, (0, 0, 6, 4), rng=3, margin_m=0.5, min_leg_m=1.0)
    assert np.array_equal(a, b)
    assert (a[:, 0] >= 0.5).all() and (a[:, 0] <= 5.5).all() and (a[:, 1] >= 0.5).all() and (a[:, 1] <= 3.5).all()
    assert (np.hypot(*np.diff(a, axis=0).T) >= 1.0).all()
    p = waypoint_path(a, 0.1)
    assert np.allclose(p[-1], a[-1])


def test_walking_track_reaches_waypoints_with_bounded_speed():
    wp = np.array([[0.5, 0.5], [5.5, 0.5], [5.5, 3.5], [1.0, 3.0]])
    tr = walking_track(wp, rate_hz=10, speed_mps=1.0, rng=0, pause_prob=1.0, pause_s=1.0)
    t, xy = tr[:, 0], tr[:, 1:3]
    assert np.allclose(np.diff(t), 0.1)
    v = np.hypot(*np.diff(xy, axis=0).T) / 0.1
    assert v.max() < 2.0
    assert np.sum(v == 0) == 2 * 10  # pauses at the two intermediate waypoints
    assert np.hypot(*(xy[-1] - wp[-1])) < 0.3
    for w in wp:
        assert np.hypot(*(xy - w).T).min() < 0.3


def test_timed_constant_speed():
    tr = timed(np.array([[0, 0], [3, 0], [3, 4]]), speed_mps=0.5, rate_hz=2)
    assert np.allclose(np.hypot(*np.diff(tr[:, 1:3], axis=0).T)[:-1], 0.25)
    assert np.isclose(tr[-1, 0], 14.0) and np.allclose(tr[-1, 1:3], [3, 4])


@pytest.mark.parametrize("name", PAPER_PATHS)
def test_closed_paper_paths_never_jump(name):
    p = paper_path(name, closed=True)
    steps = np.hypot(*np.diff(np.vstack([p, p[:1]]), axis=0).T)
    assert steps.max() <= 0.1 + 1e-9
    # It still visits every point of the reference path.
    ref = paper_path(name)
    d = np.hypot(ref[:, None, 0] - p[None, :, 0], ref[:, None, 1] - p[None, :, 1]).min(axis=1)
    assert d.max() < 0.08
