"""Radio-model calibration: recovers known parameters; CLI behaviour."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from pfdoa import _toml as tomllib
from pfdoa.calibration.calibrate import fit_path_loss
from pfdoa.errors import InputError
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import load_site, parse_site

SITE = parse_site({
    "radio": {"rssi_at_1m_dbm": -30.0, "path_loss_exponent": 2.0},
    "anchors": [
        {"id": 3, "x": 0.0, "y": 0.0}, {"id": 4, "x": 8.0, "y": 0.0},
        {"id": 7, "x": 8.0, "y": 6.0}, {"id": 9, "x": 0.0, "y": 6.0},
    ],
})
TRUE_A, TRUE_N = -47.0, 2.6
TRUE_OFF = np.array([1.5, -2.0, 0.25, 0.25])  # sums to zero


def synthetic(rng, k=400, sigma=2.0):
    pts = rng.uniform([0.2, 0.2], [7.8, 5.8], size=(k, 2))
    mu = mean_rssi(pts, SITE.positions, PathLoss(TRUE_A, TRUE_N), TRUE_OFF)
    idx = np.tile(np.arange(4), k)
    p = np.repeat(pts, 4, axis=0)
    y = mu.ravel() + rng.normal(0.0, sigma, size=mu.size)
    return p, idx, y


def test_recovers_known_parameters():
    p, idx, y = synthetic(np.random.default_rng(1))
    fit = fit_path_loss(p, idx, y, SITE)
    assert fit.rssi_at_1m_dbm == pytest.approx(TRUE_A, abs=0.6)
    assert fit.path_loss_exponent == pytest.approx(TRUE_N, abs=0.08)
    np.testing.assert_allclose(fit.offsets, TRUE_OFF, atol=0.3)
    assert fit.offsets.sum() == pytest.approx(0.0, abs=1e-9)
    assert fit.rms_db == pytest.approx(2.0, abs=0.15)
    assert [a.readings for a in fit.anchors] == [400] * 4


def test_reference_gauge_shifts_a_and_offsets():
    p, idx, y = synthetic(np.random.default_rng(2))
    fit = fit_path_loss(p, idx, y, SITE, reference_anchor=4)
    # Offsets relative to anchor 4; A absorbs anchor 4's offset.
    assert fit.offsets[1] == 0.0
    np.testing.assert_allclose(fit.offsets, TRUE_OFF - TRUE_OFF[1], atol=0.3)
    assert fit.rssi_at_1m_dbm == pytest.approx(TRUE_A + TRUE_OFF[1], abs=0.6)


def test_robust_fit_resists_outliers():
    rng = np.random.default_rng(3)
    p, idx, y = synthetic(rng, sigma=1.0)
    bad = rng.random(y.size) < 0.1
    y = y.copy()
    y[bad] -= 25.0  # deep fades
    plain = fit_path_loss(p, idx, y, SITE)
    robust = fit_path_loss(p, idx, y, SITE, robust=True)
    assert abs(robust.path_loss_exponent - TRUE_N) < abs(plain.path_loss_exponent - TRUE_N)
    assert robust.path_loss_exponent == pytest.approx(TRUE_N, abs=0.15)
    np.testing.assert_allclose(robust.offsets, TRUE_OFF, atol=0.5)


@pytest.mark.xfail(strict=True, reason="known: the fit takes the readings that were reported as all there "
                   "were; a censored fit recovers n but the estimators, which take the survivors as unbiased, "
                   "do worse with it (docs/estimator.md, 'Tried, not kept')")
def test_a_receiver_deaf_below_its_sensitivity_still_gives_the_true_exponent():
    """A receiver reports nothing below its sensitivity (here -66 dBm, half of the readings):
    far away only the readings that came out strong survive, so a fit that takes them as all
    there were sees RSS fall too slowly with distance (n 1.81 here against the true 2.6; 2.55
    with every reading)."""
    p, idx, y = synthetic(np.random.default_rng(4), sigma=4.0)
    heard = y >= -66.0
    fit = fit_path_loss(p[heard], idx[heard], y[heard], SITE)
    assert fit.path_loss_exponent == pytest.approx(TRUE_N, abs=0.2)


def test_no_offsets_and_degenerate_inputs():
    p, idx, y = synthetic(np.random.default_rng(4), sigma=0.5)
    fit = fit_path_loss(p, idx, y - TRUE_OFF[idx], SITE, offsets=False)
    assert np.all(fit.offsets == 0.0) and fit.gauge == "none"
    assert fit.path_loss_exponent == pytest.approx(TRUE_N, abs=0.05)
    with pytest.raises(InputError, match="reference anchor 5"):
        fit_path_loss(p, idx, y, SITE, reference_anchor=5)


def test_a_static_beacon_fits_a_and_n_without_offsets():
    # One position: each anchor's offset could explain its one distance, so the full model is
    # not determined; A and n are, from the anchors' different distances.
    at = np.array([[1.5, 1.0]])
    mu = mean_rssi(at, SITE.positions, PathLoss(TRUE_A, TRUE_N)).ravel()
    rng = np.random.default_rng(6)
    idx = np.tile(np.arange(4), 50)
    y = mu[idx] + rng.normal(0.0, 0.5, idx.size)
    fit = fit_path_loss(np.repeat(at, idx.size, axis=0), idx, y, SITE, robust=True)
    assert fit.gauge == "none" and np.all(fit.offsets == 0.0)
    assert "static beacon" in fit.note and "static beacon" in fit.report()
    assert fit.path_loss_exponent == pytest.approx(TRUE_N, abs=0.1)
    assert fit.rssi_at_1m_dbm == pytest.approx(TRUE_A, abs=1.0)
    # a moving beacon still fits every parameter, with no note
    p, i2, y2 = synthetic(np.random.default_rng(7))
    assert fit_path_loss(p, i2, y2, SITE).note == ""


def test_readings_at_one_distance_fit_a_alone_with_the_sites_exponent():
    # A beacon at the centre of the rectangle: every anchor 5 m away; A and n cannot be told apart.
    same = np.tile([[4.0, 3.0]], (8, 1))
    y = np.full(8, -60.0)
    fit = fit_path_loss(same, np.arange(8) % 4, y, SITE)
    assert fit.path_loss_exponent == SITE.radio.path_loss_exponent
    assert fit.rssi_at_1m_dbm == pytest.approx(-60.0 + 10.0 * 2.0 * np.log10(5.0))
    assert fit.gauge == "none" and "span too little" in fit.note


def write_site(tmp_path):
    text = "[radio]\nrssi_at_1m_dbm = -40.0\npath_loss_exponent = 2.0\n" + "".join(
        f"\n[[anchors]]\nid = {a.id}\nx = {a.x}\ny = {a.y}\n" for a in SITE.anchors
    )
    path = tmp_path / "site.toml"
    path.write_text(text)
    return path


def pfdoa(*args):
    return subprocess.run([sys.executable, "-m", "pfdoa", *map(str, args)], capture_output=True, text=True, timeout=60)


def test_cli_writes_complete_site_file(tmp_path):
    p, idx, y = synthetic(np.random.default_rng(5), k=100)
    trace = tmp_path / "cal.csv"
    ids = np.array(SITE.anchor_ids)[idx]
    rows = ["t,anchor,rssi_dbm,gt_x,gt_y"] + [
        f"{i // 4},{a},{r:.2f},{x:.3f},{yy:.3f}" for i, (a, r, (x, yy)) in enumerate(zip(ids, y, p))
    ]
    rows.append("99,42,-50,1,1")  # anchor not in the site: skipped with a warning
    trace.write_text("\n".join(rows) + "\n")
    out = tmp_path / "fitted.toml"
    r = pfdoa("calibrate", trace, "--config", write_site(tmp_path), "--out", out, "--robust")
    assert r.returncode == 0, r.stderr
    assert "rms" in r.stdout.lower() and "path_loss_exponent" in r.stdout
    fitted = load_site(out)
    assert fitted.anchor_ids == SITE.anchor_ids
    np.testing.assert_array_equal(fitted.positions, SITE.positions)
    assert fitted.radio.path_loss_exponent == pytest.approx(TRUE_N, abs=0.15)
    np.testing.assert_allclose(fitted.offsets, TRUE_OFF, atol=0.5)
    assert "not in" in r.stderr
    tomllib.loads(out.read_text())


def test_cli_without_ground_truth_is_one_line_error(tmp_path):
    trace = tmp_path / "nogt.csv"
    trace.write_text("t,anchor,rssi_dbm\n0,3,-50\n0,4,-60\n")
    r = pfdoa("calibrate", trace, "--config", write_site(tmp_path), "--out", tmp_path / "x.toml")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "gt_x" in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "x.toml").exists()


def _trace_with_exponent(tmp_path, name: str, n: float, seed: int) -> str:
    """A calibration trace whose readings follow distance with exponent ``n`` (offsets as TRUE_OFF)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([0.5, 0.5], [7.5, 5.5], size=(300, 2))
    mu = mean_rssi(pts, SITE.positions, PathLoss(-60.0, n), TRUE_OFF)
    rows = ["t,anchor,rssi_dbm,gt_x,gt_y"] + [
        f"{i},{a.id},{mu[i, j] + rng.normal(0, 1.0):.2f},{x:.2f},{y:.2f}"
        for i, (x, y) in enumerate(pts) for j, a in enumerate(SITE.anchors)]
    path = tmp_path / name
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def test_cli_rejects_a_fit_that_does_not_follow_distance(tmp_path):
    # RSSI rising with distance (anchors swapped, say): n < 0, which no site file accepts.
    trace = _trace_with_exponent(tmp_path, "rising.csv", -1.0, 6)
    r = pfdoa("calibrate", trace, "--config", write_site(tmp_path), "--out", tmp_path / "x.toml")
    assert r.returncode == 2 and "outside [0.5, 10]: the readings do not follow distance" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x.toml").exists()


def test_a_fit_below_the_site_files_minimum_is_held_there_and_written(tmp_path):
    """A room where the readings barely follow distance (Girolami et al.'s BLE 5.1 room fits
    0.1-0.3 on some paths) was refused by calibrate while pfdoa eval scored its fit: now the
    exponent is held at the site file's minimum and A and the offsets fitted with it, in both."""
    trace = _trace_with_exponent(tmp_path, "flat.csv", 0.25, 7)
    data = np.loadtxt(trace, delimiter=",", skiprows=1)
    idx = np.array([SITE.anchor_ids.index(int(a)) for a in data[:, 1]])
    free = fit_path_loss(data[:, 3:5], idx, data[:, 2], SITE, robust=True)
    assert free.path_loss_exponent == 0.5 and "fitted path_loss_exponent 0.2" in free.note
    np.testing.assert_allclose(free.offsets, TRUE_OFF, atol=0.3)  # the offsets still found
    # A at n = 0.5 is the mean of y + 5 log10(d^2) less the offsets: what least squares with n held gives.
    d = np.hypot(*(data[:, 3:5] - SITE.positions[idx]).T)
    assert free.rssi_at_1m_dbm == pytest.approx(float(np.mean(data[:, 2] + 5.0 * np.log10(d) - TRUE_OFF[idx])),
                                                abs=0.3)
    out = tmp_path / "fitted.toml"
    r = pfdoa("calibrate", trace, "--config", write_site(tmp_path), "--out", out, "--no-uncertainty")
    assert r.returncode == 0, r.stderr
    assert "held at the site file's minimum 0.5" in r.stderr
    assert load_site(out).radio.path_loss_exponent == 0.5
    r = pfdoa("replay", trace, "--config", out, "--method", "wcl", "--out", tmp_path / "est.jsonl")
    assert r.returncode == 0, r.stderr


def test_cli_keeps_the_optional_tables(tmp_path):
    p, idx, y = synthetic(np.random.default_rng(8), k=60)
    ids = np.array(SITE.anchor_ids)[idx]
    rows = [f"{i // 4},{a},{r:.2f},{x:.3f},{yy:.3f}\n" for i, (a, r, (x, yy)) in enumerate(zip(ids, y, p))]
    trace, trace2 = tmp_path / "cal.csv", tmp_path / "cal2.csv"
    trace.write_text("t,anchor,rssi_dbm,gt_x,gt_y\n" + "".join(rows))
    trace2.write_text("t,anchor,rssi_dbm,gt_x,gt_y\n" + "".join(rows))  # a second run (same walk)
    site = write_site(tmp_path)
    site.write_text(site.read_text() + '\n[estimator]\nmethod = "pf-doa"\nparticles = 300\n\n[gateway]\nwindow_s = 0.5\n')
    one, out = tmp_path / "one.toml", tmp_path / "fitted.toml"
    for traces, path in (((trace,), one), ((trace, trace2), out)):
        r = pfdoa("calibrate", *traces, "--config", site, "--out", path)
        assert r.returncode == 0, r.stderr
        fitted = load_site(path)
        assert fitted.sections["estimator"] == {"method": "pf-doa", "particles": 300}  # nothing measured into it
        assert fitted.sections["gateway"] == {"window_s": 0.5}
    # the flags of the retired uncertainty factors: accepted, one warning, nothing else changes
    plain = tmp_path / "plain.toml"
    r = pfdoa("calibrate", trace, "--config", site, "--out", plain, "--no-uncertainty", "--mode", "seq")
    assert r.returncode == 0 and "--mode, --no-uncertainty: retired" in r.stderr, r.stderr
    assert plain.read_text() == one.read_text()


# -- one calibration walk and another run -------------------------------------------------
def _walk(rng, seconds, rate=4.0, speed=0.5, lo=(0.5, 0.5), hi=(7.5, 5.5)):
    """A walk between random waypoints of an area (SITE's by default) from its centre:
    (t, x, y) at ``rate`` Hz."""
    pts, t = [(np.array(lo) + hi) / 2.0], 0.0
    out = []
    while t < seconds:
        goal = rng.uniform(lo, hi)
        d = np.linalg.norm(goal - pts[-1])
        for s in np.arange(0.0, d, speed / rate):
            out.append((t, *(pts[-1] + (goal - pts[-1]) * s / d)))
            t += 1.0 / rate
        pts.append(goal)
    return np.array(out)


def _trace(rng, walk, bias_db, sigma=2.0, site=SITE):
    """Readings of every anchor of ``site`` (four) at each walk point: the true model, a
    smooth per-anchor bias field of ``bias_db`` (walls and furniture) and noise."""
    from pfdoa.trace import Trace

    xy = walk[:, 1:]
    mu = mean_rssi(xy, site.positions, PathLoss(TRUE_A, TRUE_N), TRUE_OFF)
    phase = np.arange(4)[None, :]
    mu = mu + bias_db * np.sin(0.9 * xy[:, :1] + 1.7 * phase) * np.cos(0.7 * xy[:, 1:] + phase)
    y = mu + rng.normal(0.0, sigma, mu.shape)
    k = len(walk)
    return Trace(np.repeat(walk[:, 0], 4), np.tile(np.array(site.anchor_ids), k), y.ravel(),
                 gt_x=np.repeat(xy[:, 0], 4), gt_y=np.repeat(xy[:, 1], 4), source="synthetic")


def _rmse_and_coverage(site, trace, seeds=(0, 1), odometry=None):
    """pf-doa's RMSE, share of estimates with the truth within r95, and that share among the
    worst quarter of errors, over ``trace``'s 1 s windows (``odometry``, an OdometryTrace,
    driving it)."""
    from pfdoa.estimators import Observation, make_estimator
    from pfdoa.evaluation.datasets import odometry_between
    from pfdoa.trace import group_by_window

    table = site.sections.get("estimator", {})
    windows = list(group_by_window(trace, site, 1.0))
    steps = (odometry_between(odometry, np.array([w.t for w in windows])) if odometry is not None
             else [None] * len(windows))
    err, hits = [], []
    for seed in seeds:
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed), **table)
        for w, o in zip(windows, steps):
            e = est.step(Observation(w.t, w.rssi, w.count), o)
            err.append(np.hypot(w.gt[0] - e.x, w.gt[1] - e.y))
            hits.append(err[-1] <= e.r95)
    e, h = np.array(err), np.array(hits)
    worst = e >= np.quantile(e, 0.75)
    return float(np.sqrt(np.mean(e ** 2))), float(h.mean()), float(h[worst].mean())


def test_retired_estimator_options_load_with_one_warning_and_are_dropped(tmp_path, caplog):
    """A site file written by an earlier pfdoa (uncertainty factors, an estimate gain, residual
    whitening, options retired with them) still loads: one warning names the file and the
    retired keys, they are dropped (a file written back no longer carries them), and the
    estimator builds from what is left."""
    from pfdoa.estimators import make_estimator
    from pfdoa.site import site_to_toml

    old = tmp_path / "old.toml"
    old.write_text(write_site(tmp_path).read_text() + "\n[estimator]\nparticles = 300\nr95_scale = 0.8\n"
                   "cov_scale = 0.7\nestimate_gain = [0.6, 0.1, 0.4]\nfactor_rule = 2\nresidual_rho = 0.5\n")
    with caplog.at_level("WARNING", logger="pfdoa.site"):
        site = load_site(old)
    (msg,) = [r.getMessage() for r in caplog.records]
    assert msg.startswith(str(old))
    assert all(k in msg for k in ("cov_scale", "estimate_gain", "factor_rule", "r95_scale", "residual_rho"))
    assert site.sections["estimator"] == {"particles": 300}
    assert "r95_scale" not in site_to_toml(site)
    assert make_estimator("pf-doa", site, rng=np.random.default_rng(0), **site.sections["estimator"]).N == 300


@pytest.fixture(scope="module")
def one_walk_coverage():
    """Walks through rooms whose walls bend each anchor's RSS by up to 3 dB, calibrated on one
    walk alone (nothing measured across runs): pf-doa's (in r95, worst quarter in r95) on
    another walk, the mean over two rooms and seeds 0-2."""
    from pfdoa.calibration.calibrate import calibrate_traces

    shares = []
    for room in (11, 12):  # two rooms (walls), a calibration walk and a scored walk in each
        rng = np.random.default_rng(room)
        cal, scored = (_trace(rng, _walk(rng, 240), 3.0) for _ in range(2))
        fitted = calibrate_traces([cal], SITE, robust=True).apply(SITE)
        shares.append(_rmse_and_coverage(fitted, scored, seeds=(0, 1, 2))[1:])
    return tuple(np.mean(shares, axis=0))


def test_one_calibration_walk_gives_another_run_an_honest_r95(one_walk_coverage):
    """r95 holds the truth for at least 85 % of the estimates, and for at least half of its
    worst quarter of errors (measured 99.9 % and 99.7 %; 96.5 % and 86 % with the misfit at
    half its single-observation error, before static points asked for twice it)."""
    inside, worst = one_walk_coverage
    assert inside >= 0.85 and worst >= 0.5


@pytest.mark.xfail(strict=True, reason="known: the report that holds static points (the misfit at "
                   "1.5 x and the centroid's term) over-covers a walker in these rooms, 99.9 % within r95 "
                   "(docs/estimator.md, \"Uncertainty\"); strict, so a "
                   "report that tells the two apart shows here")
def test_one_calibration_walks_r95_is_no_wider_than_the_band(one_walk_coverage):
    assert one_walk_coverage[0] <= 0.98


# -- traces that name several beacons (the beacon column) ---------------------------------
def _two_beacons(seed=21, seconds=120.0, unnamed_first=False):
    """Two beacons walking apart, their readings interleaved in one trace (b 0.1 s after a):
    (a's trace, b's trace, the trace naming both)."""
    from pfdoa.trace import Trace

    rng = np.random.default_rng(seed)
    wa, wb = _walk(rng, seconds), _walk(rng, seconds)
    wb[:, 0] += 0.1
    a, b = _trace(rng, wa, 3.0), _trace(rng, wb, 3.0)
    order = np.argsort(np.concatenate([a.t, b.t]), kind="stable")

    def cat(x, y):
        return np.concatenate([x, y])[order]

    names = np.array(["" if unnamed_first else "a"] * len(a) + ["b"] * len(b), dtype=object)
    both = Trace(cat(a.t, b.t), cat(a.anchor, b.anchor), cat(a.rssi_dbm, b.rssi_dbm), gt_x=cat(a.gt_x, b.gt_x),
                 gt_y=cat(a.gt_y, b.gt_y), source="two-beacons", beacon=names[order])
    return a, b, both


def test_a_multi_beacon_trace_is_fitted_jointly_but_windowed_per_beacon(monkeypatch):
    """Every reading has its own ground truth: the radio model is one fit over both beacons'
    readings (as two traces give it). The radio map's windows group each beacon's readings
    alone (4 per anchor and window here; mixed they would be 8, at the other beacon's place)."""
    import pfdoa.calibration.calibrate as cal
    from pfdoa.trace import group_by_window

    a, b, both = _two_beacons()
    joint = cal.calibrate_traces([both], SITE, robust=True, radio_map=False)
    apart = cal.calibrate_traces([a, b], SITE, robust=True, radio_map=False)
    assert joint.rssi_at_1m_dbm == pytest.approx(apart.rssi_at_1m_dbm, abs=1e-9)
    assert joint.path_loss_exponent == pytest.approx(apart.path_loss_exponent, abs=1e-9)
    seen = []
    real = cal.fit_radio_map
    monkeypatch.setattr(cal, "fit_radio_map", lambda site, runs, exp: seen.append([list(r) for r in runs])
                        or real(site, seen[-1], exp))
    cal.calibrate_traces([both], SITE, robust=True, window_s=1.0)
    (windows,) = seen[-1]  # one trace, one run of windows (its blocks of time shared by its beacons)
    per_beacon = [w for part in (a, b) for w in group_by_window(part, SITE, 1.0)]
    assert len(windows) == len(per_beacon)
    assert max(int(w.count.max()) for w in windows) == 4


def test_calibration_grows_the_area_to_where_the_target_was_seen():
    """Anchors inset from the walls: the calibration's ground truth reaches past their
    bounding box, so the fitted site's area covers it (with the estimators' margin), and
    pf-doa then follows a walk there instead of stopping at the anchors' box."""
    from pfdoa.calibration.calibrate import covering_area
    from pfdoa.estimators import make_estimator
    from pfdoa.estimators.base import Observation

    inner = parse_site({"radio": {"rssi_at_1m_dbm": -30.0, "path_loss_exponent": 2.0},
                        "anchors": [{"id": i, "x": x, "y": y} for i, (x, y) in
                                    enumerate([(3, 3), (13, 3), (13, 9), (3, 9), (8, 6)])]})
    # search box without an area: the anchors' 3..13 x 3..9 m grown by 5 % of 10 m
    assert covering_area(inner, (4.0, 4.0, 12.0, 8.0)) is None  # inside it: unchanged
    assert covering_area(inner, (2.3, 2.5, 13.8, 9.5)) is None  # 5 % more area: left to the margin
    assert covering_area(inner, (0.5, 2.9, 15.0, 11.0)) == (0.5, 2.5, 15.0, 11.0)
    rng = np.random.default_rng(8)
    t = np.arange(400) * 0.5
    walk = np.column_stack([8 + 7 * np.cos(0.05 * t), 6 + 5 * np.sin(0.05 * t)])  # x 1..15, y 1..11
    mu = mean_rssi(walk, inner.positions, PathLoss(TRUE_A, TRUE_N))
    y = mu + rng.normal(0.0, 1.0, mu.shape)
    idx = np.tile(np.arange(5), len(t))
    fit = fit_path_loss(np.repeat(walk, 5, axis=0), idx, y.ravel(), inner, robust=True)
    fitted = fit.apply(inner)
    assert fitted.area == pytest.approx((1.0, 1.0, 15.0, 11.0), abs=1e-3)

    def worst_x_error(site):
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(0))
        xs = np.array([est.step(Observation(ti, r)).x for ti, r in zip(t, y)])
        far = walk[:, 0] > 14.0  # 1 m and more beyond the anchors' box (13 m + 0.5 m margin)
        return float(np.median(np.abs(xs[far] - walk[far, 0])))

    assert worst_x_error(fitted) < 0.6
    assert worst_x_error(dataclasses.replace(fitted, area=None)) > 0.8  # held inside the anchors' box
