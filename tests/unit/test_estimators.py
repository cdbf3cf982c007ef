"""Estimators: factory, resampling, robustness, memory, determinism, accuracy bounds."""

import math

import numpy as np
import pytest

from pfdoa.doa import GradientFit, doa_from_gradient, wrap_angle
from pfdoa.errors import ConfigError
from pfdoa.estimators import METHODS, Observation, Odometry, drssi, make_estimator, pf_model, pf_motion, pf_uncertainty
from pfdoa.estimators.resampling import SystematicResampler, systematic_resample
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import parse_site

SIDE = 6.0
MODEL = PathLoss(-40.0, 3.0)


def square_site(offsets=(0.0, 0.0, 0.0, 0.0), **estimator):
    corners = [(0.0, 0.0), (0.0, SIDE), (SIDE, SIDE), (SIDE, 0.0)]
    doc = {
        "radio": {"rssi_at_1m_dbm": MODEL.rssi_at_1m_dbm, "path_loss_exponent": MODEL.path_loss_exponent},
        "anchors": [{"id": i, "x": x, "y": y, "rssi_offset_db": o} for i, ((x, y), o) in enumerate(zip(corners, offsets))],
    }
    if estimator:
        doc["estimator"] = estimator
    return parse_site(doc)


def cross_path(step=0.1):
    s = np.arange(0.5, SIDE - 0.5 + 1e-9, step)
    return np.concatenate([np.column_stack([s, np.full_like(s, 3.0)]), np.column_stack([np.full_like(s, 3.0), s])])


def run_with_odometry(est, path, rss) -> np.ndarray:
    """(x, y, r95) of each estimate, the true increments of ``path`` given as odometry."""
    out = []
    for i, r in enumerate(rss):
        d = path[i] - path[i - 1] if i else np.zeros(2)
        e = est.step(Observation(float(i), r), Odometry(float(d[0]), float(d[1]), 0.0))
        out.append((e.x, e.y, e.r95))
    return np.array(out)


def run(est, path, rss, dt=1.0):
    out = np.empty((len(path), 2))
    for i, r in enumerate(rss):
        e = est.step(Observation(i * dt, r))
        out[i] = e.x, e.y
    return out


def rmse(a, b):
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()))


# -- factory ---------------------------------------------------------------------------
def test_factory_builds_every_method_and_rejects_bad_options():
    site = square_site()
    for m in METHODS:
        assert make_estimator(m, site).name == m
    with pytest.raises(ConfigError, match="unknown estimator"):
        make_estimator("kalman", site)
    with pytest.raises(ConfigError) as exc:
        make_estimator("pf-doa", site, particles=0)
    assert exc.value.key == "particles"
    with pytest.raises(ConfigError):
        make_estimator("pf-doa", site, estimate="median")
    with pytest.raises(ConfigError):
        make_estimator("wcl", site, no_such_option=1)
    with pytest.raises(ConfigError) as exc:
        make_estimator("markov", site, resolution=0.0)
    assert exc.value.key == "resolution"
    with pytest.raises(ConfigError, match="cells"):
        make_estimator("drssi", site, resolution=0.001)  # 36 M cells: refused, not allocated
    with pytest.raises(ConfigError):
        make_estimator("pf-doa", site, particles=200.0)  # a float where a count is expected
    # an option of another method is accepted (one [estimator] table serves all methods)
    make_estimator("wcl", site, particles=100, resolution=0.2, method="wcl")


# -- resampling ------------------------------------------------------------------------
def test_systematic_resampling_with_round_off_stays_in_range():
    rng = np.random.default_rng(0)
    n = 1000
    w = np.zeros(n)
    w[-1] = 1.0 - 1e-12  # cumulative sum ends just below 1
    for _ in range(200):
        idx = systematic_resample(w, rng)
        assert idx.min() >= 0 and idx.max() < n
        assert (idx == n - 1).all()


def test_systematic_resampling_counts_are_proportional():
    rng = np.random.default_rng(1)
    w = np.array([0.5, 0.25, 0.125, 0.125]) * (1 - 1e-12)
    r = SystematicResampler(4000)
    big = np.repeat(w / 1000.0, 1000)
    counts = np.bincount(r(big, rng) // 1000, minlength=4)
    np.testing.assert_allclose(counts, [2000, 1000, 500, 500], atol=1)  # systematic: within 1


# -- robustness ------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["pf-doa", "pf-doa-paper"])
def test_all_nan_or_zero_likelihood_recovers(method):
    site = square_site()
    est = make_estimator(method, site, rng=np.random.default_rng(2))
    est.step(Observation(0.0, mean_rssi(np.array([2.0, 2.0]), site.positions, MODEL)))
    est.logw.fill(np.nan)  # what a NaN likelihood leaves behind
    if method == "pf-doa-paper":
        est.ring.fill(-np.inf)
    e = est.step(Observation(1.0, mean_rssi(np.array([2.0, 2.0]), site.positions, MODEL)))
    assert e.extra.get("recovered")
    assert np.isfinite([e.x, e.y, e.sigma]).all()
    assert abs(est.w.sum() - 1.0) < 1e-9 and np.isfinite(est.w).all()
    e = est.step(Observation(2.0, mean_rssi(np.array([2.0, 2.0]), site.positions, MODEL)))
    assert np.isfinite([e.x, e.y]).all()


@pytest.mark.parametrize("method", METHODS)
def test_missing_anchors(method):
    site = square_site()
    target = np.array([3.5, 2.5])
    est = make_estimator(method, site, rng=np.random.default_rng(3))
    r = mean_rssi(target, site.positions, MODEL)
    r[1] = np.nan  # one anchor missing: 3 remain
    for i in range(30):
        e = est.step(Observation(float(i), r))
    assert e.anchors_used == (0, 2, 3)
    assert "degraded" not in e.extra
    check_localised(method, site, e, target)
    r2 = r.copy()
    r2[2] = np.nan  # two missing: no update, but an answer, flagged
    e2 = est.step(Observation(30.0, r2))
    assert "degraded" in e2.extra and np.isfinite([e2.x, e2.y]).all()
    assert e2.anchors_used == (0, 3)


# -- memory and determinism ------------------------------------------------------------
@pytest.mark.parametrize("method,options", [("pf-doa", {}), ("pf-doa-paper", {}), ("pf-doa", {"leap_rate": 1.0})])
def test_arrays_keep_identity_and_shape_over_1000_steps(method, options):
    site = square_site()
    est = make_estimator(method, site, rng=np.random.default_rng(4), particles=50, **options)
    rng = np.random.default_rng(5)
    path = cross_path(0.05)

    def owned():
        """Every buffer the filter and its parts own; ``_op`` only refers to the GradientFit's
        operator in use, the leaps' ``idx`` is a window of their pool."""
        parts = [("", est)] + [(f"{k}.", v) for k, v in vars(est).items() if k in ("rss", "leaps", "misfit", "noise")]
        return {p + k: (id(v), v.shape) for p, obj in parts for k, v in vars(obj).items()
                if isinstance(v, np.ndarray) and k not in ("_op", "idx")}

    before = owned()
    for i in range(1000):
        r = mean_rssi(path[i % len(path)], site.positions, MODEL) + 3 * rng.standard_normal(4)
        if i % 7 == 0:
            r[i % 4] = np.nan
        est.step(Observation(0.2 * i, r), Odometry(0.05, 0.0, 0.01) if i % 2 else None)
        assert before == owned(), i  # every step: buffers swapped back and forth would pass at the end
    if method == "pf-doa-paper":
        assert est.smoother._ring.shape == (est.smoother.window, 2)


@pytest.mark.parametrize("method", ["pf-doa", "pf-doa-paper"])
@pytest.mark.parametrize("particles", [1, 2, 3, 5])
def test_a_cloud_of_a_few_particles_keeps_reporting_finite_estimates(method, particles):
    """The schema allows any particle count from 1: a cloud of a few equal particles has
    variances that underflow (two of them once made the report's truncation divide by 0)."""
    site = square_site()
    rng = np.random.default_rng(particles)
    for seed in range(4):
        est = make_estimator(method, site, rng=np.random.default_rng(seed), particles=particles)
        for i in range(300):
            p = (1.0 + 0.002 * i, 1.5)  # near a corner, slowly: the cloud collapses onto a few copies
            r = mean_rssi(np.array(p), site.positions, MODEL) + 2.0 * rng.standard_normal(4)
            e = est.step(Observation(0.1 * i, r), Odometry(0.002, 0.0, 0.0) if seed % 2 else None)
            assert math.isfinite(e.x) and math.isfinite(e.y) and math.isfinite(e.sigma), (seed, i)
            assert e.r95 is None or e.r95 >= 0.0, (seed, i)


@pytest.mark.parametrize("method", METHODS)
def test_same_seed_same_output_and_reset_replays(method):
    site = square_site()
    path = cross_path(0.2)
    rss = mean_rssi(path, site.positions, MODEL) + 2 * np.random.default_rng(6).standard_normal((len(path), 4))
    a = make_estimator(method, site, rng=np.random.default_rng(7))
    b = make_estimator(method, site, rng=np.random.default_rng(7))
    ra, rb = run(a, path, rss), run(b, path, rss)
    np.testing.assert_array_equal(ra, rb)
    a.reset()
    np.testing.assert_array_equal(run(a, path, rss), ra)


# -- accuracy --------------------------------------------------------------------------
# Noise-free static target, 30 observations. Distance bounds (m) per method; the DOA-only
# methods (the paper's PF, Markov) get a bearing and no range from a static target, so for
# them the estimate's predicted DOA must match the true one. pf-doa's leaps keep a few
# particles 2.5 m out, which move its mean by a few centimetres from one observation to the
# next (with three anchors, whose differential RSS leaves a curve, up to 0.12 m).
BOUNDS = {"pf-doa": 0.15, "trilateration": 0.01, "wcl": 1.0, "drssi": 0.01}
BEARING_ONLY = {"pf-doa-paper": 0.3, "markov": 0.3}  # rad


def model_doa(site, p):
    return doa_from_gradient(GradientFit(site.positions).gradient(mean_rssi(np.asarray(p), site.positions, MODEL)))


def check_localised(method, site, e, target):
    if method in BEARING_ONLY:
        assert abs(wrap_angle(model_doa(site, (e.x, e.y)) - model_doa(site, target))) < BEARING_ONLY[method]
        assert e.doa is not None and abs(wrap_angle(e.doa - model_doa(site, target))) < 1e-6
    else:
        assert math.hypot(e.x - target[0], e.y - target[1]) < BOUNDS[method]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("target", [(1.3, 4.1), (4.5, 2.0), (3.5, 2.5)])
def test_noise_free_static_target_is_localised(method, target):
    site = square_site(offsets=(2.0, -1.0, 0.5, 0.0))
    t = np.array(target)
    r = mean_rssi(t, site.positions, MODEL, site.offsets)  # estimators must remove the offsets
    est = make_estimator(method, site, rng=np.random.default_rng(8))
    # A minute: pf-doa counts a standing target's expected observations for a share of their
    # likelihood (pf_model.EVIDENCE_SHARE_MIN), so its cloud settles over more of them.
    for i in range(60):
        e = est.step(Observation(float(i), r))
    check_localised(method, square_site(), e, t)
    assert e.anchors_used == (0, 1, 2, 3)


def test_drssi_scored_in_blocks_picks_the_whole_grids_least_cost_cell():
    """drssi scores a grid larger than its block (58,081 cells at 2.5 cm) block by block: the
    cell and cost it reports are those of the whole grid's differential-RSS cost, computed
    here from the model in one piece, with noisy readings and an anchor missing."""
    site = square_site()
    est = make_estimator("drssi", site, resolution=0.025)
    for present in (4, 3):  # the blocks of four and of three anchors present
        block = drssi.BLOCK_VALUES // present
        assert est.points.shape[0] > block and est.points.shape[0] % block
    table = mean_rssi(est.points, site.positions, MODEL)
    rng = np.random.default_rng(3)
    for i, present in enumerate(([0, 1, 2, 3], [0, 2, 3], [1, 2, 3])):
        r = mean_rssi(np.array([1.7 + i, 4.2 - i]), site.positions, MODEL) + rng.normal(0.0, 3.0, 4)
        obs = np.full(4, np.nan)
        obs[present] = r[present]
        e = est.step(Observation(float(i), obs))
        ref = present[int(np.argmax(r[present]))]
        cost = (((table[:, present] - table[:, [ref]]) - (r[present] - r[ref])) ** 2).sum(axis=1)
        best = int(np.argmin(cost))
        assert (e.x, e.y) == tuple(est.points[best])
        assert e.extra["cost"] == pytest.approx(float(cost[best]), rel=1e-12)


def test_pf_doa_beats_wcl_on_a_noisy_path():
    site = square_site()
    path = cross_path(0.1)
    rss = mean_rssi(path, site.positions, MODEL) + 2 * np.random.default_rng(9).standard_normal((len(path), 4))
    pf = rmse(run(make_estimator("pf-doa", site, rng=np.random.default_rng(10)), path, rss), path)
    wcl = rmse(run(make_estimator("wcl", site), path, rss), path)
    assert pf < 0.8 * wcl
    assert pf < 0.6


def test_pf_doa_sigma_shrinks_as_evidence_accumulates():
    site = square_site()
    t = np.array([2.0, 2.5])
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(11))
    first = est.step(Observation(0.0, mean_rssi(t, site.positions, MODEL))).sigma
    for i in range(1, 40):  # a standing target's observations count for a share (tempered)
        last = est.step(Observation(float(i), mean_rssi(t, site.positions, MODEL))).sigma
    assert last < 0.5 * first


def test_pf_doa_recovers_from_a_jump():
    """The target teleports across the room (kidnap): the jump test re-seeds the cloud. After
    half a minute standing, the cloud's tempered likelihood (pf_model.EVIDENCE_SHARE_MIN) has
    left it wider, its evidence at the new place is less poor, and the test re-seeds fewer
    particles (73 here against 195 untempered): within 0.7 m after eight observations (0.9 m
    for the first five), where untempered it was within 0.5 m from the first."""
    site = square_site()
    rng = np.random.default_rng(12)
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(13))
    a, b = np.array([1.0, 1.0]), np.array([5.0, 5.0])
    for i in range(30):
        est.step(Observation(float(i), mean_rssi(a, site.positions, MODEL) + rng.normal(0, 1, 4)))
    jumped = False
    for i in range(30, 38):
        e = est.step(Observation(float(i), mean_rssi(b, site.positions, MODEL) + rng.normal(0, 1, 4)))
        jumped |= "jumped" in e.extra
    assert jumped
    assert math.hypot(e.x - b[0], e.y - b[1]) < 0.7


def _survey(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A survey of a 40 x 16 m floor: twelve anchors along its long sides, a phone held 10 s
    at each of 30 points drawn anywhere on it (so the next point is often tens of metres
    away), one scan a second with 6 dB of noise. The truth, and pf-doa's (x, y, r95) of each
    scan."""
    rng = np.random.default_rng(100 + seed)
    xs = np.linspace(4.0, 36.0, 6)
    anchors = np.vstack([np.column_stack([xs, np.full(6, 2.4)]), np.column_stack([xs + 3.3, np.full(6, 13.6)])])
    site = parse_site({"radio": {"rssi_at_1m_dbm": -62.0, "path_loss_exponent": 2.2},
                       "anchors": [{"id": i, "x": float(x), "y": float(y)} for i, (x, y) in enumerate(anchors)]})
    points = np.column_stack([rng.uniform(2.0, 38.0, 30), rng.uniform(1.0, 15.0, 30)])
    path = np.repeat(points, 10, axis=0)
    rss = np.round(mean_rssi(path, anchors, PathLoss(-62.0, 2.2)) + 6.0 * rng.standard_normal((len(path), 12)))
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
    out = [est.step(Observation(float(i), r)) for i, r in enumerate(rss)]
    return path, np.array([(e.x, e.y, e.r95) for e in out])


def _survey_rmse(seed: int) -> float:
    """pf-doa's RMSE over :func:`_survey`."""
    path, est = _survey(seed)
    return float(np.sqrt(np.mean(((est[:, :2] - path) ** 2).sum(axis=1))))


def test_pf_doa_follows_a_survey_from_point_to_distant_point(monkeypatch):
    """A survey's next point is metres away and the phone stands there: the online noise
    scale grows with such moves, and the evidence falls only about half a nat per anchor below
    its level, short of the 1-nat gate that the test with odometry keeps (JUMP_GATE). Without
    odometry the jump test runs from half a nat (JUMP_GATE_FREE) and re-seeds the cloud at the
    new point; with the 1-nat gate the leaps follow after several observations, metres behind
    (RMSE over three seeds 2.8 against 5.2 m when this was written)."""
    low = np.mean([_survey_rmse(s) for s in range(3)])
    monkeypatch.setattr(pf_uncertainty, "JUMP_GATE_FREE", pf_uncertainty.JUMP_GATE)
    high = np.mean([_survey_rmse(s) for s in range(3)])
    assert low < 0.75 * high, (low, high)


def test_the_report_covers_a_cloud_that_trails_the_target(monkeypatch):
    """After each of the survey's moves (:func:`_survey`) the cloud trails the phone for some
    scans, each update shifting it the same way: the lag's term (pf_uncertainty.Lag) widens
    r95 along that shift. Over three seeds the truth of the worst quarter of errors was
    within r95 for 78 % of them with it and 64 % without (91 -> 95 % of all scans, when this
    was written); no estimate moves."""

    def report() -> tuple[float, float, list[np.ndarray]]:
        inside, worst, estimates = [], [], []
        for seed in range(3):
            path, est = _survey(seed)
            err = np.hypot(*(est[:, :2] - path).T)
            hit = err <= est[:, 2]
            inside.append(hit.mean())
            worst.append(hit[err >= np.quantile(err, 0.75)].mean())
            estimates.append(est[:, :2])
        return float(np.mean(inside)), float(np.mean(worst)), estimates

    inside, worst, estimates = report()
    monkeypatch.setattr(pf_uncertainty, "LAG_SHARE", 0.0)
    inside_without, worst_without, estimates_without = report()
    assert all(np.array_equal(a, b) for a, b in zip(estimates, estimates_without))
    assert worst >= worst_without + 0.1, (worst, worst_without)
    assert inside_without < inside <= 0.98


def test_pf_doa_finds_a_target_that_walks_off_the_mirror_image_it_settled_on():
    """Twelve anchors on a circle (a 30 m hall): the differential RSS of a point and of its
    inversion in the circle are the same, so a target standing at (8, 8) can hold the cloud
    at its image beyond the anchors, (-1, -1), with the transmitter's power learnt to match.
    When the target walks off (1 m/s), the image stops fitting and the noise scale grows to
    explain the readings; counted with the Gaussian's normaliser, the evidence falls, the
    jump test runs and the cloud is re-seeded at the target. Without the normaliser the
    growing noise scale hid the misfit: two of these five seeds stayed 27 m away."""
    ang = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    anchors = np.column_stack([15.0 * (1.0 + np.cos(ang)), 15.0 * (1.0 + np.sin(ang))])
    model = PathLoss(-62.0, 2.2)
    site = parse_site({"radio": {"rssi_at_1m_dbm": -62.0, "path_loss_exponent": 2.2},
                       "anchors": [{"id": i, "x": float(x), "y": float(y)} for i, (x, y) in enumerate(anchors)]})
    start = np.array([8.0, 8.0])
    walk = np.minimum(np.arange(60.0), 14.0) / math.sqrt(2.0)  # 1 m/s to the north-east, then still
    path = np.vstack([np.tile(start, (30, 1)), start + walk[:, None]])
    mirrored = 0
    for seed in range(5):
        rng = np.random.default_rng(seed)
        rss = mean_rssi(path, anchors, model) + rng.standard_normal((len(path), 12))
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
        xy = run(est, path, rss)
        mirrored += math.hypot(*(xy[29] - (-1.0, -1.0))) < 2.0
        assert math.hypot(*(xy[-1] - path[-1])) < 1.0, seed
    assert mirrored >= 2  # the trap is there to be left


def errors_after_a_jump_the_gate_misses(**options) -> list[float]:
    """pf-doa (seed 13, ``options``) after 30 observations of a target at (1, 1) (1 dB
    noise), then its errors over 4 observations at (5, 5); the jump test's gate must be
    shut by the caller (pf_uncertainty.JUMP_GATE_FREE), so nothing jumps."""
    site = square_site()
    a, b = np.array([1.0, 1.0]), np.array([5.0, 5.0])
    rng = np.random.default_rng(12)
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(13), **options)
    for i in range(30):
        est.step(Observation(float(i), mean_rssi(a, site.positions, MODEL) + rng.normal(0, 1, 4)))
    errs = []
    for i in range(30, 34):
        e = est.step(Observation(float(i), mean_rssi(b, site.positions, MODEL) + rng.normal(0, 1, 4)))
        assert "jumped" not in e.extra
        errs.append(math.hypot(e.x - b[0], e.y - b[1]))
    return errs


def test_pf_doa_leaps_bring_the_cloud_back_without_the_jump_test(monkeypatch):
    """The target jumps across the room while the jump test's gate stays shut (as it does
    for a self-consistent wrong solution): the particles that leap land near it and take the
    weight, so the filter is there within a few observations; without leaps the cloud walks.
    (The pull towards the anchors' centroid is off: this is about the cloud, and the pull
    moves a cloud left behind part of the way, 2.7 m off in place of 4.1 m without leaps.)"""
    monkeypatch.setattr(pf_uncertainty, "JUMP_GATE_FREE", 1e9)
    monkeypatch.setattr(pf_uncertainty, "PULL_FLOOR", 1.0)
    err = {rate: errors_after_a_jump_the_gate_misses(leap_rate=rate)[-1] for rate in (0.0, 0.1)}
    assert err[0.1] < 1.5
    assert err[0.0] > 3.0


def _pause_then_walk() -> np.ndarray:
    """30 s standing at (1, 1), a walk to (5, 5) at about 0.5 m/s, 20 s standing there."""
    walk = np.array([1.0, 1.0]) + np.linspace(0.0, 1.0, 12)[1:, None] * np.array([4.0, 4.0])
    return np.vstack([np.tile([[1.0, 1.0]], (30, 1)), walk, np.tile([[5.0, 5.0]], (20, 1))])


def test_pf_doa_leaps_follow_a_walk_that_sets_off_after_a_pause(monkeypatch):
    """While the target stands the cloud narrows and its velocities decay; when it sets off,
    the speed prior alone lets the cloud drift after it. Leaps keep a few particles where it
    would be had it moved further, so the walk is followed closer (mean error over the walk
    and the next 4 s, 20 noise draws and seeds, 4 dB noise). The jump test's gate is shut:
    it re-seeds part of a cloud left behind too (1.13 -> 0.87 m without leaps)."""
    monkeypatch.setattr(pf_uncertainty, "JUMP_GATE_FREE", 1e9)
    site = square_site()
    path = _pause_then_walk()
    walk = slice(30, 45)
    err = {}
    for rate in (0.0, 0.1):
        per_seed = []
        for seed in range(20):
            rss = mean_rssi(path, site.positions, MODEL) + np.random.default_rng(100 + seed).normal(0, 4, (len(path), 4))
            xy = run(make_estimator("pf-doa", site, rng=np.random.default_rng(seed), leap_rate=rate), path, rss)
            per_seed.append(float(np.hypot(*(xy[walk] - path[walk]).T).mean()))
        err[rate] = float(np.mean(per_seed))
    assert err[0.1] < 0.8 * err[0.0]


def test_pf_doa_leaps_follow_their_law_and_stay_out_of_the_noise_scale_and_odometry():
    """Each particle leaps at ``rate`` per second (a Poisson process: the cloud's leaps come at
    N rate dt per step), by 1-sigma leap_m per axis (a filter whose speed prior is nil moves
    particles only by leaping). The online noise scale leaves the leapt particles out: on a
    noise-free static target it stays where a filter without leaps has it, not at the leaps'
    residuals. With odometry nothing leaps."""
    site = square_site()
    target = np.array([2.0, 2.5])
    reading = mean_rssi(target, site.positions, MODEL)
    rate, dt, size = 0.3, 0.5, 0.4
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(3), leap_rate=rate, leap_m=size, speed=1e-9,
                         jump_probability=1e-9, resample_threshold=0.0)
    moved, steps = [], 200
    before = est.xy.copy()
    for i in range(steps):
        est.step(Observation(i * dt, reading))
        d = est.xy - before
        moved.append(d[np.hypot(*d.T) > 1e-6])
        before = est.xy.copy()
    d = np.concatenate(moved)
    # N rate dt draws per step, with replacement: N (1 - exp(-rate dt)) distinct particles
    expected = est.N * steps * (1.0 - math.exp(-rate * dt))
    assert abs(d.shape[0] - expected) < 5.0 * math.sqrt(expected)  # within 5 sigma
    assert d.std() == pytest.approx(size, rel=0.1)  # (a leap out of the box is reflected at its wall)

    # Untempered (pf_model.EVIDENCE_SHARE_MIN 1): a standing target's tempered likelihood keeps
    # the leapt particles' descendants a while, and they reach the scale at later steps (from
    # its floor of 1.0 to 1.36 dB here at the default rate, 1.75 at 0.5; docs/estimator.md).
    sig = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pf_model, "EVIDENCE_SHARE_MIN", 1.0)
        for r in (0.0, 0.5):
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(4), leap_rate=r)
            for i in range(60):
                est.step(Observation(float(i), reading))
            sig[r] = est.noise.sigma
    assert sig[0.5] < 1.3 * sig[0.0]

    path = cross_path(0.2)[:30]
    rss = mean_rssi(path, site.positions, MODEL) + np.random.default_rng(5).normal(0, 2, (len(path), 4))
    out = {r: run_with_odometry(make_estimator("pf-doa", site, rng=np.random.default_rng(6), leap_rate=r), path, rss)
           for r in (0.0, 0.5)}
    assert np.array_equal(out[0.0], out[0.5])


def test_pf_doa_leaps_take_any_interval_between_observations():
    """Observation times a rounding step apart (a trace's float times): nothing leaps and
    nothing fails; the longest interval (MAX_DT_S, 10 s) draws N rate MAX_DT_S = N leaps,
    which land on 1 - exp(-1) of the particles."""
    site = square_site()
    reading = mean_rssi(np.array([2.0, 2.5]), site.positions, MODEL)
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(7))
    t = 1.0
    for step in (0.0, 1.0, math.ulp(2.0), 5e-324, 1.0):
        t += step
        e = est.step(Observation(t, reading))
        assert math.isfinite(e.x) and math.isfinite(e.y)
        if 0.0 < step < 1e-9:
            assert est.leaps.idx.size == 0
    est.step(Observation(t + 1e6, reading))  # clamped to MAX_DT_S
    assert 0.5 * est.N < len(set(est.leaps.idx.tolist())) < 0.75 * est.N

    # More leaps than a pool holds: 5,000 particles after the longest interval draw N of them
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(8), particles=5000)
    est.step(Observation(0.0, reading))
    e = est.step(Observation(1e6, reading))
    assert math.isfinite(e.x) and math.isfinite(e.y)
    assert est.leaps.idx.size > pf_motion.Leaps.POOL
    assert 0.5 * est.N < len(set(est.leaps.idx.tolist())) < 0.75 * est.N


def test_pf_doa_with_odometry_tracks_better_than_without():
    site = square_site()
    path = cross_path(0.1)[: len(cross_path(0.1)) // 2]  # one straight leg, heading +x
    rng = np.random.default_rng(14)
    rss = mean_rssi(path, site.positions, MODEL) + 3 * rng.standard_normal((len(path), 4))
    odo = [Odometry()] + [Odometry(float(np.hypot(*(path[i] - path[i - 1]))), 0.0, 0.0) for i in range(1, len(path))]
    with_odo, without = [], []
    for seed in range(3):
        for use, out in ((True, with_odo), (False, without)):
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
            xy = np.array([[e.x, e.y] for e in (est.step(Observation(float(i), rss[i]), odo[i] if use else None)
                                                for i in range(len(path)))])
            out.append(rmse(xy, path))
    assert np.mean(with_odo) < np.mean(without)


def test_pf_doa_keeps_the_path_loss_exponent_in_its_physical_range():
    from pfdoa.estimators.pf_doa import MIN_EXPONENT

    corners = [(0.0, 0.0), (0.0, SIDE), (SIDE, SIDE), (SIDE, 0.0)]
    for n_site, n_used in ((0.9, MIN_EXPONENT), (3.0, 3.0)):
        site = parse_site({"radio": {"rssi_at_1m_dbm": -40.0, "path_loss_exponent": n_site},
                           "anchors": [{"id": i, "x": x, "y": y} for i, (x, y) in enumerate(corners)]})
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(0))
        if n_site < MIN_EXPONENT:  # an unreliable fit: the exponent is a per-particle unknown ...
            assert est.rss.exponent.min() == MIN_EXPONENT and est.rss.exponent.std() > 0.1
            assert est.rss.weight == pytest.approx(n_site / MIN_EXPONENT)  # ... and its evidence weighed
        else:
            np.testing.assert_array_equal(est.rss.exponent, n_used)
            assert est.rss.weight == 1.0


# -- uncertainty and online learning ------------------------------------------------------
def test_misfit_is_each_anchors_persistent_residual_and_the_position_error_it_makes():
    """The misfit is each anchor's running lag-1 and lag-2 autocovariances of the centred
    posterior-mean residual (a common offset removed): for AR(1) deviations of correlation rho
    they are rho and rho^2 times their centred variance, and nothing for noise new at each
    observation. Its covariance at a point is MISFIT_SHARE A J^T V J A with V the lag-2 levels,
    A = (J^T J)^-1, J the centred Jacobian of the model RSS with the site's fitted slope
    (checked by finite differences); none where the anchors' geometry gives no bound (two
    anchors)."""
    from pfdoa.estimators.pf_uncertainty import MISFIT_SHARE, Misfit

    site = square_site()
    rng = np.random.default_rng(20)
    sd = np.array([1.0, 2.0, 3.0, 4.0])
    for rho in (0.0, 0.8):
        mf = Misfit(site.positions, site.heights, MODEL.path_loss_exponent, MODEL.min_distance_m)
        e = rng.normal(0.0, 1.0, 4) * sd
        level, level2 = [], []
        for _ in range(20000):  # the level's time average: within about 0.1 dB^2 of its mean
            e = rho * e + math.sqrt(1 - rho * rho) * rng.normal(0.0, 1.0, 4) * sd
            r = e + 40.0  # a common offset: removed by the centring
            mf.push(r.tolist(), (0, 1, 2, 3), float(r.mean()))
            level.append(list(mf.var))
            level2.append(list(mf.var2))
        # what the centred residual shows (the differential RSS the filter scores):
        # rho m / (m - 1) (s_k^2 (1 - 2 / m) + sum s^2 / m^2), rho s_k^2 for equal deviations
        m, v = 4, sd * sd
        centred = m / (m - 1) * (v * (1 - 2 / m) + v.sum() / m ** 2)
        for got, lag in ((level, 1), (level2, 2)):
            want = rho ** lag * centred
            np.testing.assert_allclose(np.mean(got[1000:], axis=0), want, atol=0.3 + 0.05 * want.max())
    p, eps = np.array([1.5, 4.0]), 1e-6
    jac = np.column_stack([(mean_rssi((p + d)[None], site.positions, MODEL)[0]
                            - mean_rssi((p - d)[None], site.positions, MODEL)[0]) / (2 * eps)
                           for d in (np.array([eps, 0.0]), np.array([0.0, eps]))])
    jac -= jac.mean(axis=0)
    a = np.linalg.inv(jac.T @ jac)
    want = MISFIT_SHARE * a @ jac.T @ np.diag(np.maximum(mf.var2, 0.0)) @ jac @ a
    np.testing.assert_allclose(mf.cov_at(*p, (0, 1, 2, 3)), [want[0, 0], want[0, 1], want[1, 1]], rtol=1e-5)
    assert mf.cov_at(*p, (0, 1)) is None


def test_persistence_is_the_share_of_residual_power_that_repeats_and_counts_the_centroids_term():
    """The misfit's persistence is its lag-1 levels over the residuals' powers (both averaged
    alike): about rho for AR(1) deviations of correlation rho, 1 at the first residual (nothing
    has shown yet that it decorrelates). The centroid's term is CENTROID_SHARE x persistence x
    d d^T along the disagreement d between the estimate and the centroid: nothing where the
    residuals are new noise at each observation."""
    from pfdoa.estimators.pf_uncertainty import CENTROID_SHARE, Misfit, centroid_cov

    site = square_site()
    rng = np.random.default_rng(21)
    for rho in (0.0, 0.5, 0.9):
        mf = Misfit(site.positions, site.heights, MODEL.path_loss_exponent, MODEL.min_distance_m)
        e = rng.normal(0.0, 2.0, 4)
        mf.push(e.tolist(), (0, 1, 2, 3), float(e.mean()))
        assert mf.persistence == 1.0
        seen = []
        for _ in range(4000):
            e = rho * e + math.sqrt(1 - rho * rho) * rng.normal(0.0, 2.0, 4)
            mf.push(e.tolist(), (0, 1, 2, 3), float(e.mean()))
            seen.append(mf.persistence)
        assert abs(float(np.mean(seen[500:])) - rho) < 0.08
    got = centroid_cov((1.0, 0.5, 2.0), 4.0, 3.0, (1.0, 1.0), 0.5)
    want = np.array([1.0, 0.5, 2.0]) + CENTROID_SHARE * 0.5 * np.array([9.0, 6.0, 4.0])
    np.testing.assert_allclose(got, want)
    assert centroid_cov(None, 4.0, 3.0, (1.0, 1.0), 0.0) == (0.0, 0.0, 0.0)


def test_the_centroid_is_the_anchors_weighted_by_inverse_model_distance():
    """wcl's estimate and pf-doa's centroid (one class): the present anchors' positions with
    weights 1 / d_i, d_i = 10 ** ((A - RSSI_i) / (10 n)), a reading stronger than 1 mm allows
    weighted as 1 mm."""
    from pfdoa.estimators.wcl import Centroid

    site = square_site()
    c = Centroid(site.positions, MODEL)
    rssi = np.array([-50.0, -61.0, np.nan, -55.0])
    present = (0, 1, 3)
    d = 10.0 ** ((MODEL.rssi_at_1m_dbm - rssi[list(present)]) / (10.0 * MODEL.path_loss_exponent))
    want = (site.positions[list(present)] / d[:, None]).sum(axis=0) / (1.0 / d).sum()
    np.testing.assert_allclose(c(rssi, present), want)
    loud = np.array([MODEL.rssi_at_1m_dbm + 100.0, -61.0, -70.0, -70.0])  # d far below 1 mm
    lo = 1.0 / 1e-3
    w = np.array([lo, *(1.0 / 10.0 ** ((MODEL.rssi_at_1m_dbm - loud[1:]) / (10.0 * MODEL.path_loss_exponent)))])
    np.testing.assert_allclose(c(loud, (0, 1, 2, 3)), (site.positions * w[:, None]).sum(axis=0) / w.sum())
    est = make_estimator("wcl", site).step(Observation(0.0, rssi))
    np.testing.assert_allclose((est.x, est.y), want)


def test_pf_doas_centroid_weighs_by_a_power_of_the_model_distance_and_draws_less_to_the_middle():
    """With weights 1 / d^p (pf-doa's report and pull: CENTROID_POWER) the centroid of a
    target near one end of a long row of anchors is nearer the target than wcl's 1 / d."""
    from pfdoa.estimators.pf_uncertainty import CENTROID_POWER
    from pfdoa.estimators.wcl import Centroid
    from pfdoa.radio import mean_rssi

    anchors = np.array([[0.0, 0.0], [4.0, 3.0], [8.0, 0.0], [12.0, 3.0], [16.0, 0.0]])
    rssi = np.array([-50.0, -61.0, -64.0, -70.0, -72.0])
    d = 10.0 ** ((MODEL.rssi_at_1m_dbm - rssi) / (10.0 * MODEL.path_loss_exponent))
    w = d ** -CENTROID_POWER
    got = Centroid(anchors, MODEL, CENTROID_POWER)(rssi, tuple(range(5)))
    np.testing.assert_allclose(got, (anchors * w[:, None]).sum(axis=0) / w.sum())
    target = np.array([[1.0, 1.0]])
    clean = mean_rssi(target, anchors, MODEL)[0]
    near = np.hypot(*(np.array(Centroid(anchors, MODEL, CENTROID_POWER)(clean, tuple(range(5)))) - target[0]))
    far = np.hypot(*(np.array(Centroid(anchors, MODEL)(clean, tuple(range(5)))) - target[0]))
    assert near < 0.8 * far


def test_how_much_the_target_moves_whatever_the_observation_rate_and_the_offsets_learn_by_it():
    """MovingShare: 1 until its track spans SPEED_WINDOW_S, then the estimate's speed since the
    oldest estimate it keeps (about one a second), over MOVING_SPEED, up to 1: 0 for a standing
    target, 1 at that speed or faster, at one observation a second and at ten alike. The
    anchors' offsets learn at OFFSET_RATE times it: nothing while the target stands (its
    residual is its place's walls)."""
    from pfdoa.estimators.pf_model import MOVING_SPEED, OFFSET_RATE, SPEED_WINDOW_S, AnchorOffsets, MovingShare

    r = np.array([1.0, -1.0, 0.5, -0.5])
    for per_second in (1, 10):
        dt = 1.0 / per_second
        n = int(3 * SPEED_WINDOW_S * per_second)
        still, walking, ambling = MovingShare(), MovingShare(), MovingShare()
        shares: dict[str, list[float]] = {"still": [], "walking": [], "ambling": []}
        for k in range(n):
            t = k * dt
            shares["still"].append(still.push(t, 2.0, 2.0))
            shares["walking"].append(walking.push(t, 2.0 * MOVING_SPEED * t, 0.0))
            shares["ambling"].append(ambling.push(t, 0.0, 0.25 * MOVING_SPEED * t))
        warm = int(SPEED_WINDOW_S * per_second) + per_second  # the track spans SPEED_WINDOW_S by then
        assert shares["still"][0] == 1.0 and set(shares["still"][warm:]) == {0.0}
        assert still.share == 0.0
        assert shares["walking"] == pytest.approx([1.0] * n)
        assert shares["ambling"][warm:] == pytest.approx([0.25] * (n - warm))
        still.reset()
        assert still.share == 1.0 and still.push(0.0, 2.0, 2.0) == 1.0  # a reset forgets the track
    offsets = AnchorOffsets(4)
    offsets.push(r.tolist(), None, 0.0, 0.0)
    assert np.array_equal(offsets.db, np.zeros(4))  # standing: the offsets keep what they learnt
    offsets.push(r.tolist(), None, 0.0, 0.25)
    assert offsets.db == pytest.approx(-0.25 * OFFSET_RATE * r)


def test_with_odometry_how_much_the_target_moves_is_the_odometrys():
    """Once odometry is seen, MovingShare reads the odometry's dead-reckoned path, not the
    estimate: a robot turning on the spot whose estimate wanders by its readings' deviations
    stands (0), one driving at MOVING_SPEED whose estimate stays at one place moves (1), and
    one driving a loop in exactly SPEED_WINDOW_S (0.4 m/s along it) is back where it was: the
    net motion, composed with the odometry's own turns. Odometry that starts late starts a
    new track (its frame is not the estimates')."""
    from pfdoa.estimators.pf_model import MOVING_SPEED, SPEED_WINDOW_S, MovingShare
    from pfdoa.types import Odometry

    rng = np.random.default_rng(3)
    turning, driving, loop = MovingShare(), MovingShare(), MovingShare()
    window = int(SPEED_WINDOW_S)  # steps of a second in the track's span
    for k in range(3 * window):
        t = float(k)
        turning.odometry(Odometry(0.0, 0.0, 0.4))
        driving.odometry(Odometry(MOVING_SPEED, 0.0, 0.0))
        loop.odometry(Odometry(0.4, 0.0, 2.0 * math.pi / window))
        wander = rng.normal(0.0, 0.5, 2)
        turning.push(t, float(wander[0]), float(wander[1]))
        driving.push(t, 1.0, 1.0)
        loop.push(t, 5.0 * t, 0.0)  # an estimate racing away is not read
    assert turning.share == 0.0
    assert driving.share == pytest.approx(1.0)
    assert loop.share == pytest.approx(0.0, abs=1e-9)
    late = MovingShare()  # odometry that starts late: a new track, not estimates mixed with it
    for k in range(2 * window):
        late.push(float(k), 0.1, 0.0)
    assert late.share == 0.0
    late.odometry(Odometry(0.0, 0.0, 0.0))
    # mixed with the estimates' track, 0.1 m in 10 s would read 0.05
    assert late.push(float(2 * window), 0.1, 0.0) == 1.0
    for k in range(2 * window + 1, 3 * window + 2):
        late.odometry(Odometry(0.0, 0.0, 0.0))
        late.push(float(k), 0.1, 0.0)
    assert late.share == 0.0
    turning.reset()  # forgets the odometry too: estimates again
    assert turning.push(0.0, 0.0, 0.0) == 1.0
    for k in range(1, window + 1):
        turning.push(float(k), 0.25 * MOVING_SPEED * k, 0.0)
    assert turning.share == pytest.approx(0.25)


def test_r95_of_a_gaussian_and_the_truncated_mean_match_simulation():
    """r95 from a covariance holds 95 % of that Gaussian's draws, isotropic or not; the mean
    and variance of a Gaussian truncated to an interval are those of its draws inside it."""
    from pfdoa.estimators.pf_uncertainty import r95_of, truncated_mean

    rng = np.random.default_rng(8)
    for cov in ((1.0, 0.0, 1.0), (4.0, 0.0, 0.04), (2.0, 1.2, 1.0), (0.3, -0.1, 0.5)):
        c = np.array([[cov[0], cov[1]], [cov[1], cov[2]]])
        z = rng.multivariate_normal([0.0, 0.0], c, 400_000)
        assert np.mean(np.hypot(*z.T) <= r95_of(*cov)) == pytest.approx(0.95, abs=0.002)
    for mu, var, lo, hi in ((0.0, 1.0, -1.0, 2.0), (3.0, 4.0, 0.0, 2.0), (0.5, 0.01, 0.0, 6.0)):
        x = rng.normal(mu, math.sqrt(var), 2_000_000)
        x = x[(x >= lo) & (x <= hi)]
        m, v = truncated_mean(mu, var, lo, hi)
        assert m == pytest.approx(x.mean(), abs=0.01) and v == pytest.approx(x.var(), rel=0.02)


def test_reflection_keeps_particles_in_the_box_without_piling_them_on_its_edges():
    """The box reflects: a point past an edge comes back by as much (one beyond twice the box
    ends on an edge); a clamp would leave a share of the cloud exactly on the edge."""
    lo, hi = np.tile([0.0, 0.0], 3), np.tile([6.0, 4.0], 3)
    flat = np.array([-0.5, 1.0, 6.5, 4.2, 20.0, -9.0])
    pf_motion.reflect_into(flat, lo, hi, np.empty(6))
    np.testing.assert_allclose(flat, [0.5, 1.0, 5.5, 3.8, 0.0, 4.0])
    est = make_estimator("pf-doa", square_site(), rng=np.random.default_rng(1), speed=2.0)
    reading = mean_rssi(np.array([0.2, 3.0]), est.anchors, MODEL)
    for i in range(40):
        est.step(Observation(float(i), reading))
    on_edge = np.isclose(est.xy, est.lo) | np.isclose(est.xy, est.hi)
    assert on_edge.mean() < 0.01


def test_power_tracker_learns_the_transmitters_offset_and_helps_with_three_anchors(monkeypatch):
    from pfdoa.estimators.pf_model import PowerTracker

    """The transmitter is 6 dB louder than the site file says. After a walk with four anchors
    the filter knows it, so with one anchor silenced it localises better than a filter that
    does not learn (whose three-anchor differential RSS leaves a curve of positions). Leaps
    are off: they also pull the filter that does not learn back from the wrong part of that
    curve (0.73 -> 0.57 m here), which would hide what the tracker does; so are the anchors'
    offsets learnt online (a share of a common shift is theirs before the tracker is warm), and
    the tempering of a slow target's evidence (this walk's 0.1 m/s is at its edge, where it
    narrows the gap: 0.52 -> 0.54 m with the tracker, 0.64 -> 0.62 m without)."""
    from pfdoa.estimators import pf_model

    monkeypatch.setattr(pf_model, "OFFSET_RATE", 0.0)
    monkeypatch.setattr(pf_model, "EVIDENCE_SHARE_MIN", 1.0)
    site = square_site()
    rng = np.random.default_rng(21)
    path = cross_path(0.1)
    loud = PathLoss(MODEL.rssi_at_1m_dbm + 6.0, MODEL.path_loss_exponent)
    rss = mean_rssi(path, site.positions, loud) + rng.normal(0, 2, (len(path), 4))
    rss[len(path) // 2:, 2] = np.nan  # anchor 2 silent for the second half
    errs = {}
    for learn in (True, False):
        if not learn:  # never warm: the differential RSS alone
            monkeypatch.setattr(PowerTracker, "WARM", 10**9)
        e_all = []
        for seed in range(3):
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed), leap_rate=0.0)
            xy = run(est, path, rss)
            e_all.append(rmse(xy[len(path) // 2:], path[len(path) // 2:]))
            assert est.rss.power.offset == pytest.approx(6.0, abs=1.5)
        errs[learn] = np.mean(e_all)
    assert errs[True] < 0.85 * errs[False]  # measured 0.52 against 0.64 m


def test_anchor_offsets_learn_another_devices_offsets_and_cost_nothing(monkeypatch):
    """The beacon has its own per-anchor offsets (+-1.5-2.5 dB) that the site file does not
    hold. Walking the cross twice, the filter learns them online (measured: within 2.2 dB of
    the device's as a vector of norm 4.1 dB) and localises the second pass as well as a filter
    that does not learn them. Here, with i.i.d. noise and an exact model, learning them gains
    nothing that holds across noise draws (second pass, 6 seeds each, three draws: 0.595 /
    0.589, 0.618 / 0.620, 0.653 / 0.634 m; with leaps at 0.1 a second 0.626 / 0.643, 0.639 /
    0.614, 0.657 / 0.630 m): the gain was measured on real rooms (docs/estimator.md,
    "Likelihood"). The pull towards the anchors' centroid is off here: the offsets that a
    filter does not learn are a persistent misfit that pulls its estimate, which does better
    on this exact model (0.56 / 0.60, 0.56 / 0.61, 0.59 / 0.66 m); on the development sites
    learning them still wins with the pull (one walk, seeds 0-2, worst / mean ratio 0.981 /
    0.829 against 0.989 / 0.838 without them)."""
    from pfdoa.estimators import pf_model

    monkeypatch.setattr(pf_uncertainty, "PULL_FLOOR", 1.0)
    site = square_site()
    path = np.concatenate([cross_path(0.1)] * 2)
    device = np.array([2.5, -2.5, 1.5, -1.5])
    rss = mean_rssi(path, site.positions, MODEL) + device + np.random.default_rng(5).normal(0, 2, (len(path), 4))
    half = len(path) // 2
    errs, learnt = {}, []
    for rate in (pf_model.OFFSET_RATE, 0.0):
        monkeypatch.setattr(pf_model, "OFFSET_RATE", rate)
        e_all = []
        for seed in range(3):
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
            xy = run(est, path, rss)
            e_all.append(rmse(xy[half:], path[half:]))
            if rate:
                learnt.append(est.rss.offsets.db.copy())
        errs[rate > 0.0] = np.mean(e_all)
    assert np.linalg.norm(np.mean(learnt, axis=0) - device) < 0.7 * np.linalg.norm(device)
    assert errs[True] < 1.05 * errs[False]


def _coverage_on_a_noisy_path() -> tuple[float, float]:
    """(share within r95, share within cov's 95 % ellipse) of pf-doa without odometry on
    i.i.d. 2 dB noise, seeds 0-2, after the first 10 steps; every cov positive definite."""
    from pfdoa.evaluation.runner import CHI2_2DOF_95, mahalanobis2

    site = square_site()
    path = cross_path(0.1)
    inside, ell = [], []
    for seed in range(3):
        rng = np.random.default_rng(30 + seed)
        rss = mean_rssi(path, site.positions, MODEL) + rng.normal(0, 2, (len(path), 4))
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed))
        for i, r in enumerate(rss):
            e = est.step(Observation(float(i), r))
            dx, dy = path[i, 0] - e.x, path[i, 1] - e.y
            xx, xy, yy = e.cov
            assert xx > 0 and yy > 0 and xx * yy > xy * xy
            assert e.r95 > 0 and isinstance(e.lost, bool)
            if i >= 10:
                inside.append(math.hypot(dx, dy) <= e.r95)
                ell.append(mahalanobis2(dx, dy, e.cov) <= CHI2_2DOF_95)
    return float(np.mean(inside)), float(np.mean(ell))


def test_pf_doa_reports_r95_and_cov_that_hold_the_truth_on_a_noisy_path():
    """On i.i.d. noise the truth lies within r95 and cov's 95 % ellipse for most estimates,
    and cov is a positive definite matrix about the estimate."""
    inside, ell = _coverage_on_a_noisy_path()
    assert inside >= 0.88 and ell >= 0.88


@pytest.mark.xfail(strict=True, reason="known: on this 4-anchor square without odometry, i.i.d. noise and a model "
                   "that fits exactly, r95 and cov are too wide (100 / 100 %; 99.6 / 100 % before the lag's term): the model's terms add what a real "
                   "room's deviations need (docs/estimator.md); strict, so a fix shows here")
def test_pf_doa_r95_and_cov_are_not_wider_than_95_percent_needs():
    inside, ell = _coverage_on_a_noisy_path()
    assert inside <= 0.98 and ell <= 0.98


def test_pf_doa_noise_share_narrows_the_cloud_in_the_report():
    """On i.i.d. 2 dB noise the online noise scale (prior-predictive) is wider than 2 dB by
    the cloud's own spread, the posterior-weighted estimate is near 2 dB, and their ratio
    narrows the cloud's part of the report."""
    site = square_site()
    path = cross_path(0.1)
    rss = mean_rssi(path, site.positions, MODEL) + np.random.default_rng(30).normal(0, 2, (len(path), 4))
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(0))
    shares, prior_db, post_db = [], [], []
    for i, r in enumerate(rss):
        est.step(Observation(float(i), r))
        if i >= 10:
            shares.append(est.noise.share())
            prior_db.append(est.noise.sigma)
            post_db.append(math.sqrt(est.noise.post_var))
    assert np.median(prior_db) > 2.4
    assert 1.8 <= np.median(post_db) <= 2.4
    assert np.median(shares) < 0.85 and min(shares) > 0.0


def test_mahalanobis2_of_many_rows_is_the_scalar_one_row_by_row():
    from pfdoa.estimators.base import mahalanobis2, mahalanobis2_many

    rng = np.random.default_rng(2)
    d = rng.normal(0.0, 1.0, (50, 2))
    a = rng.normal(0.0, 1.0, (50, 2, 2))
    c = np.einsum("kij,klj->kil", a, a)  # positive semi-definite
    cov = np.stack([c[:, 0, 0], c[:, 0, 1], c[:, 1, 1]], axis=1)
    cov[3] = (1.0, 1.0, 1.0)  # singular: inf, as the scalar one says
    got = mahalanobis2_many(d, cov)
    want = [mahalanobis2(float(x), float(y), tuple(cv)) for (x, y), cv in zip(d, cov)]
    assert got[3] == math.inf
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_pf_doa_flags_lost_when_the_readings_stop_fitting():
    """Readings that no position explains (each anchor's RSS shuffled at random) make the
    filter's evidence collapse: it says so, and stops saying so once they fit again."""
    site = square_site()
    rng = np.random.default_rng(40)
    t = np.array([2.0, 3.0])
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(41), jump_probability=1e-9)
    good = lambda: mean_rssi(t, site.positions, MODEL) + rng.normal(0, 1, 4)  # noqa: E731
    flags = [est.step(Observation(float(i), good())).lost for i in range(40)]
    assert not any(flags[10:])
    bad = [est.step(Observation(40.0 + i, rng.uniform(-90, -30, 4))).lost for i in range(10)]
    assert any(bad)
    again = [est.step(Observation(50.0 + i, good())).lost for i in range(60)]
    assert not any(again[-10:])


def test_paper_filter_never_uses_a_derived_matrix_of_a_freed_operator():
    """The predicted-DOA matrix is derived from the plane-fit operator once per operator. A
    cache keyed on ``id(op)`` without holding ``op`` used a stale matrix when a freed
    operator's id was reused (GradientFit clears its cache beyond 256 anchor masks; here
    each operator is a fresh array dropped right after use, which recycles ids at once)."""
    site = square_site()
    est = make_estimator("pf-doa-paper", site, rng=np.random.default_rng(0))
    fit = GradientFit(site.positions)
    masks = [np.array(m, dtype=bool) for m in ([1, 1, 1, 1], [0, 1, 1, 1], [1, 0, 1, 1], [1, 1, 0, 1], [1, 1, 1, 0])]
    for k in range(40):
        op = fit.operator(masks[k % len(masks)]).copy()  # a new object each time
        got = est._predicted_doa(op).copy()
        g = -(est.dist.log10(est.xy) @ op.T)
        assert np.allclose(got, np.arctan2(g[:, 1], g[:, 0])), k
        del op


def test_the_reported_covariance_is_the_cloud_and_the_misfit_truncated_to_the_box():
    """Far from the box's edges the sum is reported as it is; a misfit wider than a small room
    is bounded by it (a uniform over a 2 m side: variance 1/3 m^2), its correlation kept."""
    from pfdoa.estimators.pf_uncertainty import report_cov

    cloud, misfit = (0.04, 0.01, 0.09), (0.02, -0.005, 0.01)
    assert report_cov(5.0, 5.0, cloud, None, (0.0, 0.0, 10.0, 10.0)) == cloud
    got = report_cov(5.0, 5.0, cloud, misfit, (0.0, 0.0, 10.0, 10.0))
    assert np.allclose(got, (0.06, 0.005, 0.1))
    vx, cxy, vy = report_cov(1.0, 1.0, (0.0, 0.0, 0.0), (1e4, 5e3, 1e4), (0.0, 0.0, 2.0, 2.0))
    assert abs(vx - 1.0 / 3.0) < 0.01 and abs(vy - 1.0 / 3.0) < 0.01
    assert abs(cxy / math.sqrt(vx * vy) - 0.5) < 1e-9
    vx, _, vy = report_cov(1.0, 1.0, (0.0, 0.0, 0.0), (0.01, 0.0, 0.01), (0.0, 0.0, 2.0, 2.0))
    assert abs(vx - 0.01) < 1e-6 and abs(vy - 0.01) < 1e-6


def _walls_at_static_points(walls_db: float = 2.0) -> list[tuple[float, float]]:
    """Walls: each anchor's RSS off the model by a constant (1-sigma ``walls_db``) at a place,
    which the readings cannot average out, at a static target (nothing averages them along a
    path); 150 draws of 30 observations, 1 dB of new noise each. The final estimate's error
    and r95 of each draw."""
    site = square_site()
    rng = np.random.default_rng(11)
    out = []
    for k in range(150):
        truth = rng.uniform(1.0, 5.0, 2)
        bias = walls_db * rng.standard_normal(4)
        f = make_estimator("pf-doa", site, rng=np.random.default_rng(k))
        for i in range(30):
            rss = mean_rssi(truth[None], site.positions, MODEL)[0] + bias + rng.standard_normal(4)
            e = f.step(Observation(float(i), rss))
        out.append((math.hypot(truth[0] - e.x, truth[1] - e.y), e.r95))
    return out


def test_place_fixed_deviations_widen_the_report_of_a_standing_target(monkeypatch):
    """Walls at static points (:func:`_walls_at_static_points`): a target that stands repeats
    its place's deviations, which the cloud, narrowed as if each observation were new, does not
    hold. The report widens the cloud by how little the estimate moves (STANDING_SHARE_MIN), and
    adds the misfit the filter measures at its estimate and the estimate's disagreement with the
    anchors' weighted centroid: the truth is within r95 for 99 % of the final estimates, 97 %
    with the widened cloud alone, 72 % with the two terms alone and 59 % with none (docs/estimator.md,
    "Uncertainty"; the tempered likelihood already leaves a standing target's cloud wider, and the
    widening is what it leaves). No estimate moves."""
    from pfdoa.estimators import pf_doa

    def coverage() -> float:
        return float(np.mean([err <= r95 for err, r95 in _walls_at_static_points()]))

    share, centroid = pf_uncertainty.MISFIT_SHARE, pf_uncertainty.CENTROID_SHARE
    errors = [err for err, _ in _walls_at_static_points()]
    with_lag = coverage()
    # The lag's term (its own test) apart: the cloud still settling when a run ends
    monkeypatch.setattr(pf_uncertainty, "LAG_SHARE", 0.0)
    every = coverage()
    monkeypatch.setattr(pf_doa, "STANDING_SHARE_MIN", 1.0)
    terms_alone = coverage()
    assert [err for err, _ in _walls_at_static_points()] == errors
    monkeypatch.setattr(pf_uncertainty, "MISFIT_SHARE", 0.0)
    monkeypatch.setattr(pf_uncertainty, "CENTROID_SHARE", 0.0)
    neither = coverage()
    monkeypatch.setattr(pf_doa, "STANDING_SHARE_MIN", pf_uncertainty.STANDING_SHARE_MIN)
    widened_alone = coverage()
    monkeypatch.setattr(pf_uncertainty, "MISFIT_SHARE", share)
    monkeypatch.setattr(pf_uncertainty, "CENTROID_SHARE", centroid)
    assert 0.9 <= every <= with_lag <= 0.99
    assert every >= terms_alone + 0.25 and widened_alone >= neither + 0.35
    assert every > widened_alone and terms_alone > neither + 0.1


def test_a_standing_targets_expected_observations_count_for_a_share(monkeypatch):
    """Walls at static points (:func:`_walls_at_static_points`): the readings of a target that
    stands repeat its place's deviations, so the observations the cloud expected count for a
    share of their likelihood (the speed over FULL_EVIDENCE_SPEED, at least
    EVIDENCE_SHARE_MIN). The final estimates' RMSE: 0.67 m against 0.69 m untempered at walls
    of 2 dB, 1.15 against 1.18 m at 4 dB."""
    def rmse(walls_db: float) -> float:
        return math.sqrt(float(np.mean([err * err for err, _ in _walls_at_static_points(walls_db)])))

    tempered = {w: rmse(w) for w in (2.0, 4.0)}
    monkeypatch.setattr(pf_model, "EVIDENCE_SHARE_MIN", 1.0)
    for w in (2.0, 4.0):
        assert tempered[w] < 0.98 * rmse(w), w


def test_a_target_setting_off_surprises_the_tempered_cloud(monkeypatch):
    """A target that stood for 30 s walks off at 0.5 m/s: the speed the tempering goes by is
    the estimate's over the last 10 s, which lags, but an observation whose evidence falls
    SURPRISE_GATE below the running level counts whole. RMSE over the walk and the 5 s after,
    ten draws of 2 dB noise: 0.58 m, against 0.60 m never counting one whole and 0.56 m
    untempered."""
    site = square_site()
    a, b = np.array([1.5, 1.5]), np.array([4.5, 4.5])
    span = float(np.hypot(*(b - a)))
    walk = [a + (b - a) * min(1.0, 0.5 * (k + 1) / span) for k in range(int(span / 0.5) + 1)]
    path = np.array([a] * 30 + walk + [b] * 5)

    def rmse() -> float:
        errs = []
        for seed in range(10):
            rss = mean_rssi(path, site.positions, MODEL) + np.random.default_rng(seed).normal(0, 2, (len(path), 4))
            est = make_estimator("pf-doa", site, rng=np.random.default_rng(100 + seed))
            for i, (p, r) in enumerate(zip(path, rss)):
                e = est.step(Observation(float(i), r))
                if i >= 30:
                    errs.append(math.hypot(e.x - p[0], e.y - p[1]))
        return math.sqrt(float(np.mean(np.square(errs))))

    gated = rmse()
    monkeypatch.setattr(pf_uncertainty, "SURPRISE_GATE", math.inf)
    never = rmse()
    monkeypatch.setattr(pf_model, "EVIDENCE_SHARE_MIN", 1.0)
    untempered = rmse()
    assert gated < 0.97 * never and gated < 1.1 * untempered


def test_place_fixed_deviations_draw_the_estimate_towards_the_anchors_centroid(monkeypatch):
    """Where the misfit persists, the estimate moves towards the anchors' weighted centroid by
    the persistence above PULL_FLOOR: at static points with walls of 4 dB the final estimates'
    RMSE is 1.15 m against 1.28 m without the pull (PULL_FLOOR 1, never reached). The move is
    a share of the way, nothing at or below the floor, in proportion to a persistent part
    smaller than PULL_LEVEL, and held in the box."""
    from pfdoa.estimators.pf_uncertainty import PULL_FLOOR, PULL_LEVEL, pulled_to_centroid

    def rmse() -> float:
        return math.sqrt(float(np.mean([err * err for err, _ in _walls_at_static_points(4.0)])))

    pulled = rmse()
    monkeypatch.setattr(pf_uncertainty, "PULL_FLOOR", 1.0)
    assert pulled < 0.95 * rmse()
    monkeypatch.setattr(pf_uncertainty, "PULL_FLOOR", PULL_FLOOR)
    box = (0.0, 0.0, 6.0, 6.0)
    assert pulled_to_centroid(1.0, 2.0, (3.0, 3.0), PULL_FLOOR, PULL_LEVEL, box) == (1.0, 2.0)
    x, y = pulled_to_centroid(1.0, 2.0, (3.0, 3.0), PULL_FLOOR + 0.5, PULL_LEVEL, box)
    assert x == pytest.approx(2.0) and y == pytest.approx(2.5)
    x, y = pulled_to_centroid(1.0, 2.0, (3.0, 3.0), PULL_FLOOR + 0.5, 0.5 * PULL_LEVEL, box)
    assert x == pytest.approx(1.5) and y == pytest.approx(2.25)
    assert pulled_to_centroid(5.0, 5.0, (9.0, 7.0), PULL_FLOOR + 0.5, PULL_LEVEL, box) == (6.0, 6.0)


def test_regularisation_with_odometry_jitters_the_heading_and_keeps_the_spread():
    """After resampling, pf-doa jitters its particles (regularised PF). With odometry the
    heading is jittered too and both are shrunk towards their means first (Liu and West),
    so ten regularisations leave the cloud's spread as it was, headings either side of +-pi
    included; without odometry the kernel adds its variance (about 17 % a time at N = 200,
    the study's choice there) and leaves the heading alone."""
    n = 20000
    h = (1.0 / n) ** (1.0 / 6.0)

    def wrap(a):
        return np.remainder(a + np.pi, 2 * np.pi) - np.pi

    def about_pi(a):
        return wrap(a - np.pi)  # deviation from the headings' circular mean, pi

    def cloud(odometry):
        est = make_estimator("pf-doa", square_site(), particles=n, rng=np.random.default_rng(5))
        rng = np.random.default_rng(6)
        est.xy[:] = 3.0 + 0.4 * rng.standard_normal((n, 2))
        est.heading[:] = wrap(np.pi + 0.3 * rng.standard_normal(n))  # straddles +-pi
        before = est.heading.copy()
        est.w.fill(1.0 / n)
        est._odometry_seen = odometry
        for _ in range(10):
            pf_motion.roughen(est, est._mean_and_sigma()[2])
        return est.xy.var(axis=0), before, est.heading.copy()

    var, before, after = cloud(True)
    np.testing.assert_allclose(var, 0.16, rtol=0.05)
    assert abs(np.std(about_pi(after)) / np.std(about_pi(before)) - 1.0) < 0.05
    assert abs(np.mean(about_pi(after))) < 0.01
    assert np.mean(np.abs(wrap(after - before))) > 0.1  # the headings moved
    var, before, after = cloud(False)
    assert np.all(var > 0.16 * (1.0 + h * h) ** 10 * 0.9)
    assert np.array_equal(after, before)


@pytest.mark.parametrize("method", ["pf-doa", "pf-doa-paper"])
def test_heading_is_reported_with_odometry_and_converges_to_the_truth(method):
    """With odometry the heading is a particle state (uniform at the start): the estimate
    carries its circular mean and variance, which find the true heading as the robot drives
    a loop; without odometry there is no heading."""
    from pfdoa.doa import wrap_angle

    site = square_site()
    corners = np.array([(1.0, 1.0), (5.0, 1.0), (5.0, 5.0), (1.0, 5.0)])
    path, heading = [], []
    for _lap in range(2):
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            for s in np.arange(0.0, 1.0, 0.05):
                path.append(a + s * (b - a))
                heading.append(math.atan2(*(b - a)[::-1]))
    path, heading = np.array(path), np.array(heading)
    rng = np.random.default_rng(7)
    rss = mean_rssi(path, site.positions, MODEL) + 2 * rng.standard_normal((len(path), 4))
    odo = [Odometry()] + [Odometry(float(np.hypot(*(path[i] - path[i - 1]))), 0.0,
                                   float(wrap_angle(heading[i] - heading[i - 1]))) for i in range(1, len(path))]
    est = make_estimator(method, site, rng=np.random.default_rng(3))
    errs, var = [], []
    for i in range(len(path)):
        e = est.step(Observation(float(i), rss[i]), odo[i])
        assert e.heading is not None and 0.0 <= e.heading_var <= math.pi ** 2 / 3
        errs.append(abs(float(wrap_angle(e.heading - heading[i]))))
        var.append(e.heading_var)
    half = len(path) // 2
    late_err, late_sd = np.array(errs[half:]), np.sqrt(var[half:])
    assert np.median(var[half:]) < 0.5 * np.median(var[:5])  # the spread shrinks from uniform
    assert np.mean(late_err <= 3 * late_sd + 0.05) >= 0.8  # and is honest
    if method == "pf-doa":  # the paper's DOA-only weights pin a heading far less (0.5 rad here)
        assert np.median(late_err) < 0.2
    plain = make_estimator(method, site, rng=np.random.default_rng(3)).step(Observation(0.0, rss[0]))
    assert plain.heading is None and plain.heading_var is None


class _NoJitter:
    """A normal pool that draws zeros: the kernel's shrinkage alone is left to see."""

    def take(self, k, rng):
        return np.zeros(k)


@pytest.mark.parametrize("centre", [1.0, math.pi])  # pi: the cloud straddles the wrap
def test_heading_shrinkage_keeps_a_concentrated_cloud_about_its_circular_mean(centre):
    """Liu and West's shrinkage (with odometry): each heading's deviation from the circular mean
    is scaled by sqrt(1 - h^2), measured around the circle (a cloud about pi is not pulled
    towards 0)."""
    est = make_estimator("pf-doa", square_site(), rng=np.random.default_rng(3), particles=400)
    est.normals = _NoJitter()
    dev = np.random.default_rng(4).normal(0.0, 0.3, est.N)
    dev -= dev.mean()
    est.heading[:] = wrap_angle(centre + dev)
    est.w.fill(1.0 / est.N)
    shrink = math.sqrt(1.0 - est.h ** 2)
    pf_motion._roughen_heading(est, shrink)
    got = wrap_angle(est.heading - centre)
    np.testing.assert_allclose(got, shrink * dev, atol=0.01 * 0.3)  # the mean direction is not quite centre
    assert shrink < 0.95


def test_heading_shrinkage_leaves_a_two_mode_cloud_alone():
    """Headings split between two opposite directions have no meaningful mean direction (mean
    resultant length below HEADING_MEAN_MIN_R): they are not drawn towards one, so each mode
    stays where it is (the jitter alone moves them)."""
    est = make_estimator("pf-doa", square_site(), rng=np.random.default_rng(3), particles=400)
    est.normals = _NoJitter()
    spread = np.random.default_rng(5).normal(0.0, 0.2, est.N)
    before = wrap_angle(np.where(np.arange(est.N) % 2 == 0, 0.5, 0.5 + math.pi) + spread)
    est.heading[:] = before
    est.w.fill(1.0 / est.N)
    assert est._circular_mean()[1] < 0.1
    pf_motion._roughen_heading(est, math.sqrt(1.0 - est.h ** 2))
    np.testing.assert_allclose(wrap_angle(est.heading - before), 0.0, atol=1e-12)
