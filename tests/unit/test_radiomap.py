"""The radio map from the calibration trace (pfdoa.radiomap): learnt where residuals repeat at
a place, refused where they come with the moment, used by pf-doa, safe as a site-file table."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from pfdoa.calibrate import calibrate_traces
from pfdoa.errors import ConfigError
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.radiomap import MapLookup, parse_radio_map
from pfdoa.site import load_site, parse_site, site_to_toml
from pfdoa.trace import Trace

pytestmark = pytest.mark.unit

SITE = parse_site({
    "site": {"name": "wall"},
    "radio": {"rssi_at_1m_dbm": -45.0, "path_loss_exponent": 2.0},
    "anchors": [{"id": i + 1, "x": x, "y": y} for i, (x, y) in
                enumerate([(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0), (4.0, 0.0), (4.0, 6.0)])],
})
TRUE = PathLoss(-45.0, 2.0)
WALL_X = 4.0  # a wall across the room between x < 4 and x > 4 (anchors 5 and 6 sit on it)
WALL_DB = 8.0


def wall(xy: np.ndarray) -> np.ndarray:
    """Loss (dB) of each anchor's signal from points xy: the wall's, when on the other side."""
    ax = SITE.positions[:, 0]
    far = (xy[:, :1] < WALL_X) != (ax[None, :] < WALL_X)
    far &= np.abs(ax[None, :] - WALL_X) > 0.01
    return -WALL_DB * far


def walk(rng, seconds: int, legs: list | None = None) -> np.ndarray:
    """(t, x, y) at 1 Hz, 0.5 m/s between random waypoints (or the given ``legs``)."""
    p, out, t = np.array([2.0, 3.0]), [], 0.0
    goals = iter(legs) if legs is not None else None
    while t < seconds:
        goal = np.array(next(goals, None) if goals is not None else rng.uniform([0.3, 0.3], [7.7, 5.7]))
        if goal.ndim == 0:  # the legs are walked
            break
        d = float(np.linalg.norm(goal - p))
        for s in np.arange(0.0, d, 0.5):
            out.append((t, *(p + (goal - p) * s / d)))
            t += 1.0
        p = goal
    return np.array(out[:seconds])


def trace(rng, w: np.ndarray, *, field: bool = True, iid_db: float = 2.0, ar_db: float = 0.0) -> Trace:
    """One reading per anchor per second: the true model, the wall (or not), i.i.d. noise and
    an AR(1) noise per anchor (rho 0.95: correlated in time, not tied to a place)."""
    xy = w[:, 1:]
    mu = mean_rssi(xy, SITE.positions, TRUE) + (wall(xy) if field else 0.0)
    ar = np.zeros_like(mu)
    if ar_db:
        e = rng.normal(0.0, ar_db * math.sqrt(1 - 0.95**2), mu.shape)
        for i in range(1, len(ar)):
            ar[i] = 0.95 * ar[i - 1] + e[i]
    y = np.round(mu + ar + rng.normal(0.0, iid_db, mu.shape))
    k, n = mu.shape
    return Trace(np.repeat(w[:, 0], n), np.tile(np.array(SITE.anchor_ids), k), y.ravel(),
                 gt_x=np.repeat(xy[:, 0], n), gt_y=np.repeat(xy[:, 1], n), source="synthetic")


def test_a_wall_walked_past_many_times_is_learnt():
    rng = np.random.default_rng(3)
    fit = calibrate_traces([trace(rng, walk(rng, 600))], SITE, robust=True)
    rmap = fit.radio_map
    assert rmap is not None and rmap.trust > 0.5, fit.radio_map_note
    assert "radio map:" in fit.report()
    # The map holds what the fitted model misses (the fit takes part of the wall for distance):
    # at probes on each side, the noise-free residual under the fitted model, as the filter
    # sees it (each point's mean over anchors removed).
    fitted = fit.apply(SITE)
    grid_probe = np.array([[1.5, 1.5], [2.0, 4.5], [6.0, 1.5], [6.5, 4.5], [3.0, 3.0], [5.0, 3.0]])
    _, table = rmap.table(SITE.anchor_ids)
    lookup = MapLookup(rmap, SITE.anchor_ids, len(grid_probe))
    got = lookup.at(grid_probe) / rmap.trust
    want = (mean_rssi(grid_probe, SITE.positions, TRUE) + wall(grid_probe)
            - mean_rssi(grid_probe, SITE.positions, fitted.radio, fitted.offsets))
    want -= want.mean(axis=1, keepdims=True)
    corr = np.corrcoef(got.ravel(), want.ravel())[0, 1]
    assert corr > 0.9, (got, want)
    assert table.shape == (lookup.grid.nx * lookup.grid.ny + 1, len(SITE.anchors)) and not table[-1].any()


def test_residuals_that_come_with_the_moment_give_no_map():
    """Noise correlated in time (20 s) but not tied to a place, over a walk that passes every
    place many times, and a single straight pass whose residuals cannot be checked against
    another pass: neither is a map (without the block cross-validation both would be: a
    kernel smoother explains much of its own data)."""
    rng = np.random.default_rng(4)
    many = calibrate_traces([trace(rng, walk(rng, 600), field=False, ar_db=5.0)], SITE, robust=True)
    assert many.radio_map is None or many.radio_map.trust < 0.1, many.radio_map_note
    once = walk(rng, 200, legs=[(0.5, 0.5), (7.5, 0.5), (7.5, 5.5), (0.5, 5.5)])
    single = calibrate_traces([trace(rng, once, ar_db=5.0)], SITE, robust=True)
    assert single.radio_map is None or single.radio_map.trust < 0.1, single.radio_map_note
    assert calibrate_traces([trace(rng, walk(rng, 600))], SITE, robust=True, radio_map=False).radio_map is None


def _rmse(site, tr, seeds=(0, 1), **options) -> float:
    from pfdoa.estimators import Observation, make_estimator
    from pfdoa.trace import group_by_window

    err = []
    for seed in seeds:
        est = make_estimator("pf-doa", site, rng=np.random.default_rng(seed), **options)
        for w in group_by_window(tr, site, 1.0):
            e = est.step(Observation(w.t, w.rssi, w.count))
            err.append(math.hypot(w.gt[0] - e.x, w.gt[1] - e.y))
    return float(np.sqrt(np.mean(np.square(err[20:]))))


def test_pf_doa_with_the_map_locates_better_on_another_run():
    rng = np.random.default_rng(5)
    fitted = calibrate_traces([trace(rng, walk(rng, 600))], SITE, robust=True).apply(SITE)
    assert "radio_map" in fitted.sections
    scored = trace(rng, walk(rng, 300))
    with_map, without = _rmse(fitted, scored), _rmse(fitted, scored, radio_map=False)
    assert with_map < 0.75 * without, (with_map, without)


def test_the_map_round_trips_through_the_one_site_writer(tmp_path):
    rng = np.random.default_rng(6)
    fitted = calibrate_traces([trace(rng, walk(rng, 400))], SITE, robust=True).apply(SITE)
    text = site_to_toml(fitted)
    p = tmp_path / "site.toml"
    p.write_text(text)
    again = load_site(p)
    assert again.sections["radio_map"] == fitted.sections["radio_map"]
    assert site_to_toml(again) == text
    # A recalibration without a map drops the old one: it belonged to the old model.
    plain = calibrate_traces([trace(rng, walk(rng, 400))], again, robust=True, radio_map=False).apply(again)
    assert "radio_map" not in plain.sections


def test_the_hot_path_lookup_equals_the_plain_one_and_keeps_its_buffer():
    rng = np.random.default_rng(7)
    rmap = calibrate_traces([trace(rng, walk(rng, 400))], SITE, robust=True).radio_map
    assert rmap is not None
    lookup = MapLookup(rmap, SITE.anchor_ids, 500)
    pts = rng.uniform([-20.0, -20.0], [30.0, 30.0], (500, 2))  # many off the grid
    g = lookup.grid
    x0, y0, c = g.origin[0], g.origin[1], g.cell_m
    edges = [(x0, y0), (x0 + g.nx * c, y0), (x0, y0 + g.ny * c), (np.nextafter(x0, -1e9), y0 + c),
             (np.nextafter(x0 + g.nx * c, -1e9), y0 + 2 * c), (x0 + 3 * c, y0 + 2 * c)]  # on and by the borders
    pts[: len(edges)] = edges
    out = lookup.into(pts)
    assert out is lookup.out and np.array_equal(out, lookup.at(pts))
    _, plain = rmap.table(SITE.anchor_ids)  # the map's own grid, its off-grid row of zeros last
    assert np.array_equal(out, plain[g.flat_index(pts)])
    assert not lookup.at(np.array([[np.nan, 1.0], [1.0, np.inf]])).any()  # not finite: no correction
    assert out[4].any() and out[5].any() and not out[1:4].any()  # inside the far border; on or past the borders
    off = (pts[:, 0] < g.origin[0]) | (pts[:, 1] < g.origin[1]) | (pts[:, 0] >= g.origin[0] + g.nx * g.cell_m)
    assert off.any() and not out[off].any()


def _table() -> dict:
    return {"trust": 0.5, "length_m": 1.0, "prior_windows": 5.0, "anchors": [1, 2, 3],
            "x": [1.0, 2.0], "y": [1.0, 1.5], "residual_db": [[1.0, -1.0], [0.5, 0.0], [0.0, 2.0]],
            "count": [[3, 1], [2, 0], [1, 4]]}


@pytest.mark.parametrize("key,value", [
    ("trust", 1.5), ("trust", "high"), ("length_m", 0.0), ("prior_windows", -1.0),
    ("anchors", [1, 1, 2]), ("anchors", [1, 2, 99]), ("anchors", []), ("anchors", "1"),
    ("y", [1.0]), ("y", [1.0, float("nan")]), ("x", [1.0, 1e9]), ("x", [True, 2.0]),
    ("residual_db", [[1.0, -1.0], [0.5, 0.0]]), ("residual_db", [[1.0, -1.0], [0.5, 0.0], [0.0, 1e6]]),
    ("count", [[3, 1], [2, -1], [1, 4]]), ("count", [[3, 1.5], [2, 0], [1, 4]]),
    ("extra", 1), ("count", None),
])
def test_a_bad_radio_map_table_is_one_config_error_naming_the_key(key, value):
    t = _table()
    if value is None:
        del t[key]
    else:
        t[key] = value
    with pytest.raises(ConfigError) as exc:
        parse_radio_map(t, SITE.anchor_ids, "site.toml")
    assert f"radio_map.{key}" in str(exc.value) or (key == "anchors" and "radio_map.anchors" in str(exc.value))


def test_too_many_cells_are_refused_and_a_wide_map_stays_bounded_in_memory():
    t = _table()
    n = 40_000 // 3 + 1
    t.update(x=[0.0] * n, y=[0.0] * n, residual_db=[[0.0] * n] * 3, count=[[1] * n] * 3)
    with pytest.raises(ConfigError, match="radio_map.x"):
        parse_radio_map(t, SITE.anchor_ids, "site.toml")
    t = _table()
    t.update(x=[-90_000.0, 90_000.0], y=[-90_000.0, 90_000.0])  # accepted, but 180 km across
    rmap = parse_radio_map(t, SITE.anchor_ids)
    lookup = MapLookup(rmap, SITE.anchor_ids, 10)
    k = len(SITE.anchors)

    def bounded(lookup):  # the lookup's one table: the grid's cells and their zero border
        g = lookup.grid
        return lookup.table.shape == ((g.nx + 2) * (g.ny + 2), k) and g.nx * g.ny * k <= 1 << 18

    assert bounded(lookup)
    t.update(x=[-90_000.0, 90_000.0], y=[1.0, 1.0])  # a thin line 180 km long: each axis bounded too
    lookup = MapLookup(parse_radio_map(t, SITE.anchor_ids), SITE.anchor_ids, 10)
    assert max(lookup.grid.nx, lookup.grid.ny) <= 1024 and bounded(lookup)


def test_cli_calibrate_writes_the_map_and_replay_loads_it(tmp_path):
    rng = np.random.default_rng(8)
    tr = trace(rng, walk(rng, 500))
    csv = tmp_path / "run.csv"
    rows = ["t,anchor,rssi_dbm,gt_x,gt_y"] + [f"{t:.1f},{a},{r:.0f},{x:.3f},{y:.3f}" for t, a, r, x, y in
                                              zip(tr.t, tr.anchor, tr.rssi_dbm, tr.gt_x, tr.gt_y)]
    csv.write_text("\n".join(rows) + "\n")
    site = tmp_path / "site.toml"
    site.write_text(site_to_toml(SITE))

    def run(*args):
        return subprocess.run([sys.executable, "-m", "pfdoa", *map(str, args)], capture_output=True, text=True,
                              timeout=300)

    out = tmp_path / "fitted.toml"
    r = run("calibrate", csv, "--config", site, "--out", out, "--no-uncertainty")
    assert r.returncode == 0, r.stderr
    assert "radio map:" in r.stdout and "trust" in r.stdout
    assert "radio_map" in load_site(out).sections
    rep = run("-q", "replay", csv, "--config", out, "--method", "pf-doa", "--seed", "1")
    assert rep.returncode == 0 and rep.stdout.count("\n") > 100, rep.stderr
    plain = tmp_path / "plain.toml"
    assert run("calibrate", csv, "--config", site, "--out", plain, "--no-uncertainty", "--no-radio-map").returncode == 0
    assert "radio_map" not in load_site(plain).sections
    bad = tmp_path / "bad.toml"
    bad.write_text(out.read_text().replace("trust = ", "trust = 7.0 #", 1))
    r = run("replay", csv, "--config", bad)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "radio_map.trust" in r.stderr
