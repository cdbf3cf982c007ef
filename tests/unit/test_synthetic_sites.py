"""tools/synthetic_sites.py: the walls' place-fixed deviations have the spread and the
correlation length they are said to have, and stay where they are from run to run."""

from __future__ import annotations

import numpy as np
import pytest
from tools_support import tool_module

from pfdoa.radio import mean_rssi
from pfdoa.site import load_site
from pfdoa.trace import read_trace


@pytest.fixture(scope="module")
def tool():
    with tool_module("synthetic_sites") as module:
        yield module


@pytest.mark.unit
def test_the_walls_field_has_its_spread_and_correlation_length(tool) -> None:
    rng = np.random.default_rng(0)
    field = tool._shadowing(8, 4.0, 2.0, rng)
    p = rng.uniform(0.0, 60.0, (20000, 2))
    step = rng.normal(size=p.shape)
    step /= np.linalg.norm(step, axis=1)[:, None]
    v = field(p)
    assert v.shape == (20000, 8)
    assert 3.6 < float(v.std()) < 4.4
    power = float(np.mean(v * v))
    for d in (1.0, 2.0, 4.0):  # exp(-d^2 / (2 l^2)) with l = 2 m: 0.88, 0.61, 0.14
        corr = float(np.mean(v * field(p + d * step))) / power
        assert abs(corr - np.exp(-d * d / 8.0)) < 0.05, d
    np.testing.assert_array_equal(field(p[:5]), field(p[:5]))  # a place keeps its deviation


@pytest.mark.unit
@pytest.mark.parametrize("walls_db", [4.0, 0.0])
def test_a_walls_room_reads_the_same_deviation_at_a_place_in_every_run(tool, tmp_path, walls_db: float) -> None:
    """Two runs of a walking room pass the same places: per anchor, the readings' mean
    deviation from the model in a 1 m cell agrees between the runs and varies from place to
    place by the walls; without walls only the noise's share of it is left."""
    rng = np.random.default_rng(3)
    tool._site(tmp_path, "w", 4, 8.0, 5.0, 200.0, 2, tool._walk(8.0, 0.5), rng, shadow_db=walls_db, jitter=0.1)
    site = load_site(tmp_path / "w" / "site.toml")
    anchors = site.positions
    heights = np.array([a.z for a in site.anchors]) - site.target_z
    means: list[dict] = []
    for run in (0, 1):
        tr = read_trace(tmp_path / "w" / f"run{run}.csv")
        gt = np.column_stack([tr.gt_x, tr.gt_y])
        a = tr.anchor.astype(int)
        dev = tr.rssi_dbm - mean_rssi(gt, anchors, tool.MODEL, None, heights)[np.arange(a.size), a]
        keys = np.column_stack([a, np.floor(gt)]).astype(int)
        cells: dict = {}
        for key, d in zip(map(tuple, keys.tolist()), dev.tolist()):
            cells.setdefault(key, []).append(d)
        means.append({k: float(np.mean(v)) for k, v in cells.items() if len(v) >= 15})
    both = sorted(set(means[0]) & set(means[1]))
    assert len(both) >= 40
    a0 = np.array([means[0][k] for k in both])
    a1 = np.array([means[1][k] for k in both])
    anchor = np.array([k[0] for k in both])
    for arr in (a0, a1):  # each anchor's own offset out: what is left varies with the place
        for i in np.unique(anchor):
            arr[anchor == i] -= arr[anchor == i].mean()
    if walls_db > 0.0:
        assert float(a0.std()) > 2.0  # 4 dB walls, where noise alone leaves about 4 / sqrt(15) dB
        assert float(np.corrcoef(a0, a1)[0, 1]) > 0.9
    else:
        assert float(a0.std()) < 1.0
        assert float(np.corrcoef(a0, a1)[0, 1]) < 0.5
