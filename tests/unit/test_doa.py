"""DOA of the RSS gradient (paper Eqs. 1-5) and odometry composition."""

import math

import numpy as np
import pytest

from pfdoa.doa import (
    DoaSmoother,
    GradientFit,
    central_differences,
    doa_from_gradient,
    plane_fit_operator,
    wrap_angle,
)
from pfdoa.estimators.base import Odometry
from pfdoa.odometry import apply, apply_poses, compose, compose_all
from pfdoa.radio import PathLoss, mean_rssi

LX, LY = 6.0, 4.0
RECT = np.array([[0.0, 0.0], [0.0, LY], [LX, LY], [LX, 0.0]])  # N1..N4 as in the paper


def test_plane_fit_equals_central_differences_on_a_rectangle():
    rng = np.random.default_rng(3)
    op = plane_fit_operator(RECT)
    for _ in range(50):
        s = rng.uniform(-90, -30, 4)
        gx, gy = central_differences(s, LX, LY)
        np.testing.assert_allclose(op @ s, [gx, gy], rtol=1e-12, atol=1e-12)


def test_plane_fit_recovers_an_exact_plane_for_any_layout():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 20, (7, 2))
    rss = -50 + 1.5 * pts[:, 0] - 0.7 * pts[:, 1]
    np.testing.assert_allclose(plane_fit_operator(pts) @ rss, [1.5, -0.7], atol=1e-9)


def test_collinear_or_too_few_anchors_have_no_operator():
    with pytest.raises(ValueError):
        plane_fit_operator(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]))
    fit = GradientFit(RECT)
    assert fit.operator(np.array([True, True, False, False])) is None
    # three of four rectangle corners are not collinear: still a plane
    assert fit.operator(np.array([True, True, True, False])) is not None


@pytest.mark.parametrize("angle", [0.3, 1.9, -2.5, -0.8, math.pi / 2, -math.pi / 2, math.pi - 1e-3])
def test_doa_keeps_the_quadrant(angle):
    g = np.array([math.cos(angle), math.sin(angle)]) * 3.0
    assert doa_from_gradient(g) == pytest.approx(angle, abs=1e-12)


def test_zero_gradient_gives_no_doa_and_the_smoother_keeps_its_value():
    assert doa_from_gradient(np.zeros(2)) is None
    assert doa_from_gradient(None) is None
    fit = GradientFit(RECT)
    assert doa_from_gradient(fit.gradient(np.full(4, -60.0))) is None
    sm = DoaSmoother(3)
    assert sm.push(None) is None
    sm.push(1.0)
    assert sm.push(None) == pytest.approx(1.0)
    assert sm.count == 1


def test_noise_free_doa_points_from_the_centroid_towards_the_transmitter():
    model = PathLoss(-40.0, 3.0)
    fit = GradientFit(RECT)
    c = RECT.mean(axis=0)
    for bearing in np.linspace(-math.pi, math.pi, 16, endpoint=False):
        p = c + 1.5 * np.array([math.cos(bearing), math.sin(bearing)])
        doa = doa_from_gradient(fit.gradient(mean_rssi(p, RECT, model)))
        # the plane fit of a log-distance field is not exactly radial; it stays within 25 deg
        assert abs(wrap_angle(doa - bearing)) < math.radians(25)


def test_smoother_averages_unit_vectors_across_the_wrap():
    sm = DoaSmoother(2)
    sm.push(math.pi - 0.1)
    out = sm.push(-math.pi + 0.1)
    assert abs(wrap_angle(out - math.pi)) < 0.01  # near +-pi, not near 0


def test_smoother_weights_newest_most_and_forgets_after_k():
    sm = DoaSmoother(3)
    for a in (0.0, 0.0, 1.0):
        out = sm.push(a)
    expected = math.atan2(math.sin(1.0), math.cos(1.0) + 0.99 + 0.99**2)
    assert out == pytest.approx(expected, abs=1e-12)
    for _ in range(3):
        out = sm.push(2.0)  # the window is full of 2.0 only
    assert out == pytest.approx(2.0, abs=1e-12)


def test_compose_matches_applying_increments_one_by_one():
    rng = np.random.default_rng(5)
    incs = [Odometry(*rng.normal(0, [0.3, 0.1, 0.4])) for _ in range(6)]
    pose = np.array([[1.0, 2.0, 0.7]])
    seq = pose.copy()
    for inc in incs:
        apply_poses(seq, inc.dx, inc.dy, inc.dtheta)
    total = compose_all(incs)
    once = pose.copy()
    apply_poses(once, total.dx, total.dy, total.dtheta)
    np.testing.assert_allclose(once[0, :2], seq[0, :2], atol=1e-12)
    assert abs(wrap_angle(once[0, 2] - seq[0, 2])) < 1e-12
    assert compose(Odometry(), Odometry(1.0, 0.0, 0.0)) == Odometry(1.0, 0.0, 0.0)


def test_apply_moves_each_pose_in_its_own_frame():
    xy = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]])
    heading = np.array([0.0, math.pi / 2, math.pi])
    apply(xy, heading, np.array([1.0, 1.0, 1.0]), 0.0, np.array([0.1, 0.0, 0.0]))
    np.testing.assert_allclose(xy, [[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(heading, [0.1, math.pi / 2, -math.pi], atol=1e-12)
