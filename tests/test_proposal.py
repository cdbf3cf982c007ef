"""pf-doa's defensive mixture proposal (pfdoa.estimators.proposal, option ``defensive_share``,
off by default): its likelihood is the filter's, its weights are the posterior of the jump
prior, and it pulls a cloud off a wrong solution that the jump test's gate does not see."""

import math

import numpy as np
import pytest
from test_estimators import MODEL, cross_path, errors_after_a_jump_the_gate_misses, run_with_odometry, square_site

import pfdoa.estimators.pf_doa as pf_doa
from pfdoa.estimators import Observation, Odometry, make_estimator
from pfdoa.radio import mean_rssi

pytestmark = pytest.mark.unit


def _walked(seed=3, steps=20, **options):
    """A filter after a few observations of a target at (2, 3), and the next observation's
    offset-free RSS minus A, mask and count as step() hands them to the proposal."""
    site = square_site()
    rng = np.random.default_rng(seed)
    est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed + 1), defensive_share=0.1, **options)
    t = np.array([2.0, 3.0])
    for i in range(steps):
        est.step(Observation(float(i), mean_rssi(t, site.positions, MODEL) + rng.normal(0, 2, 4)))
    rssi = mean_rssi(t, site.positions, MODEL) + rng.normal(0, 2, 4)
    return est, rssi - MODEL.rssi_at_1m_dbm - est.power.offset


def _reference_log_likelihood(est, rssi_c, mask):
    """The filter's likelihood at the proposal's candidates, written out: the residual over
    the present anchors, a share gamma of its mean removed (the filter's cached gamma, as its
    hot path uses), Gaussian or Student-t in the filter's noise scale."""
    prop = est.proposal
    idx = np.flatnonzero(mask)
    d2 = ((prop.pts[:, None, :] - est.anchors[idx][None]) ** 2).sum(axis=2)
    res = -5.0 * prop.expo[:, None] * np.log10(np.maximum(d2, est.dist.dmin2)) - rssi_c[idx]
    gamma, _ = est._centre_for(mask, idx.size)
    res -= gamma * res.mean(axis=1, keepdims=True)
    z = res ** 2 / est.sigma_rss ** 2
    return -0.5 * z.sum(axis=1) if est.gaussian else -0.5 * (est.nu + 1) * np.log1p(z / est.nu).sum(axis=1)


@pytest.mark.parametrize("tail_dof", [1e6, 4.0])
@pytest.mark.parametrize("missing", [None, 2])
def test_candidate_likelihood_is_the_filters_own(tail_dof, missing):
    """The grid's cached model RSS gives the same log-likelihood as the filter's reference
    (uncached) one at the same points and exponents, with an anchor missing or not."""
    est, rssi_c = _walked(tail_dof=tail_dof, exponent_spread=0.3)
    prop = est.proposal
    mask = np.ones(4, dtype=bool)
    if missing is not None:
        mask[missing] = False
        rssi_c[missing] = 123.0  # any finite value where an anchor is missing
    count = int(mask.sum())
    got = prop._log_likelihood(est, rssi_c, mask, count).copy()
    want = _reference_log_likelihood(est, rssi_c, mask)
    assert np.allclose(got, want, rtol=1e-9, atol=1e-9)
    assert np.ptp(prop.expo) > 0.5  # the exponents follow the prior's spread


def test_drawn_particles_carry_the_uniform_parts_posterior_mass():
    """After mix the drawn particles hold s = eps L_u / (eps L_u + (1 - eps) L_c) in equal
    shares at candidate points, the others the cloud's posterior scaled to 1 - s; logw is
    the log of the weights."""
    est, rssi_c = _walked()
    prop = est.proposal
    mask = np.ones(4, dtype=bool)
    # the cloud's update, as step() does it
    ll = est._log_likelihood(rssi_c, mask, 4)
    logw = est.logw + ll
    top = float(logw.max())
    w = np.exp(logw - top)
    log_c = top + math.log(float(w.sum()))
    est.w[:] = w / w.sum()
    cloud = est.w.copy()
    out = prop.mix(est, log_c, rssi_c, mask, 4)
    lu = _reference_log_likelihood(est, rssi_c, mask)
    log_u = float(np.log(np.mean(np.exp(lu - lu.max())))) + float(lu.max())
    eps = est.jump_probability
    s = eps * math.exp(log_u) / (eps * math.exp(log_u) + (1 - eps) * math.exp(log_c))
    assert prop.last_share == pytest.approx(s, rel=1e-9)
    drawn = np.zeros(est.N, dtype=bool)
    drawn[out] = True
    assert drawn.sum() == prop.k == 20
    on_grid = (np.abs(est.xy[drawn][:, None, :] - prop.pts[None]).sum(axis=2) < 1e-12).any(axis=1)
    assert on_grid.all()
    assert est.w[drawn] == pytest.approx(np.full(prop.k, s / prop.k), rel=1e-12)
    assert est.w.sum() == pytest.approx(1.0)
    kept = ~drawn
    assert est.w[kept] == pytest.approx(cloud[kept] * (1 - s) / cloud[kept].sum(), rel=1e-9)
    assert np.allclose(est.logw, np.log(est.w))


def test_drawn_particles_follow_the_observation_likelihood():
    """Over many mixes the drawn particles land in proportion to the candidates'
    likelihood: most of them near the target, few in the far corner."""
    est, rssi_c = _walked()
    prop = est.proposal
    mask = np.ones(4, dtype=bool)
    xs = []
    for _ in range(50):
        xs.append(est.xy[prop.mix(est, 0.0, rssi_c, mask, 4)].copy())
    pts = np.concatenate(xs)
    d = np.hypot(pts[:, 0] - 2.0, pts[:, 1] - 3.0)
    lu = _reference_log_likelihood(est, rssi_c, mask)
    p = np.exp(lu - lu.max())
    near = np.hypot(prop.pts[:, 0] - 2.0, prop.pts[:, 1] - 3.0) < 1.0
    expected = float(p[near].sum() / p.sum())
    assert abs(float(np.mean(d < 1.0)) - expected) < 0.1
    assert expected > 0.3


def test_a_cloud_on_a_wrong_solution_comes_back_without_the_jump_gate(monkeypatch):
    """The target jumps across the room while the jump test's gate stays shut (as it does
    for a self-consistent wrong solution): with the proposal the filter is there within a
    few observations; without it the cloud has to walk. Leaps are off: they bring the cloud
    back as well (tests/test_estimators.py), which would hide what the proposal does."""
    monkeypatch.setattr(pf_doa, "JUMP_GATE", 1e9)
    err = {share: errors_after_a_jump_the_gate_misses(defensive_share=share, leap_rate=0.0) for share in (0.0, 0.1)}
    assert err[0.1][-1] < 0.7
    assert err[0.0][-1] > 2.0


def test_steps_with_odometry_are_unchanged():
    """With odometry the proposal stays out (a drawn particle has no heading for the next
    increment) and its grid takes nothing from the random stream: the same estimates."""
    site = square_site()
    path = cross_path(0.2)[:20]
    rng = np.random.default_rng(5)
    rss = mean_rssi(path, site.positions, MODEL) + rng.normal(0, 2, (len(path), 4))
    out = {share: run_with_odometry(make_estimator("pf-doa", site, rng=np.random.default_rng(6),
                                                  defensive_share=share), path, rss)
           for share in (0.0, 0.1)}
    assert np.array_equal(out[0.0], out[0.1])


def _radius95(xy, w, centre):
    """The radius around ``centre`` holding 95 % of the weight ``w`` (as the filter reports)."""
    r = np.hypot(xy[:, 0] - centre[0], xy[:, 1] - centre[1])
    order = np.argsort(r)
    k = int(np.searchsorted(np.cumsum(w[order]), 0.95))
    return float(r[order[min(k, r.size - 1)]])


def test_reported_spread_is_the_clouds_part_where_the_likelihood_is_flat(monkeypatch):
    """Where the observation says nothing about the position (the grid's likelihood flat at
    the cloud's evidence, so the uniform part keeps its prior share eps), the drawn particles
    spread over the whole area with eps of the mass. The estimate stays the whole mixture's
    mean, but sigma, r95 and cov are the cloud's part alone (the posterior given no jump at
    this step): r95 is the tight cloud's, not the radius reaching into the drawn particles."""
    eps = 0.2
    est, _ = _walked(jump_probability=eps)
    prop = est.proposal
    evidence = {}
    mix = prop.mix
    drawn = {}

    def spy_mix(pf, log_evidence, *args):
        evidence["log"] = log_evidence
        out = mix(pf, log_evidence, *args)
        drawn["xy"] = pf.xy[out].copy()
        return out

    monkeypatch.setattr(prop, "mix", spy_mix)
    monkeypatch.setattr(prop, "_log_likelihood", lambda pf, *a: np.full(prop.pts.shape[0], evidence["log"]))
    site = square_site()
    rng = np.random.default_rng(9)
    e = est.step(Observation(20.0, mean_rssi(np.array([2.0, 3.0]), site.positions, MODEL) + rng.normal(0, 2, 4)))
    assert prop.last_share == pytest.approx(eps, rel=1e-6)
    # the drawn particles do spread over the area: far from the cloud on average
    assert np.hypot(drawn["xy"][:, 0] - 2.0, drawn["xy"][:, 1] - 3.0).mean() > 1.5
    # the estimate is the whole mixture's weighted mean
    assert (e.x, e.y) == pytest.approx(tuple(np.dot(est.w, est.xy)), abs=1e-12)
    k, kc = est._uncertainty_scale()
    whole = _radius95(est.xy, est.w, (e.x, e.y))
    assert e.r95 / k < 0.5 * whole
    cloud = est._report_weights()
    assert cloud is not est.w
    assert cloud.sum() == pytest.approx(1.0)
    assert e.r95 == pytest.approx(k * _radius95(est.xy, cloud, (e.x, e.y)), rel=1e-12)
    d = est.xy - np.array([e.x, e.y])
    assert e.cov[0] == pytest.approx(kc * float(np.dot(cloud, d[:, 0] ** 2)), rel=1e-12)
    m = np.dot(cloud, est.xy)
    assert e.sigma == pytest.approx(math.sqrt(float(np.dot(cloud, ((est.xy - m) ** 2).sum(axis=1)))), rel=1e-9)


def test_without_a_mix_the_reported_spread_is_the_whole_clouds():
    """No mix at this step (odometry given): the report uses the particles' own weights."""
    est, _ = _walked()
    site = square_site()
    e = est.step(Observation(20.0, mean_rssi(np.array([2.0, 3.0]), site.positions, MODEL)), Odometry(0.0, 0.0, 0.0))
    k, _ = est._uncertainty_scale()
    assert e.r95 == pytest.approx(k * _radius95(est.xy, est.w, (e.x, e.y)), rel=1e-12)
