import textwrap

import numpy as np
import pytest

from pfdoa.errors import ConfigError
from pfdoa.site import load_site, parse_site, site_to_toml

GOOD = textwrap.dedent(
    """
    [radio]
    rssi_at_1m_dbm = -45.0
    path_loss_exponent = 2.2
    [[anchors]]
    id = 0
    x = 0.0
    y = 0.0
    [[anchors]]
    id = 1
    x = 0.0
    y = 4.0
    [[anchors]]
    id = 2
    x = 4.0
    y = 0.0
    rssi_offset_db = -1.5
    """
)


def write(tmp_path, text):
    p = tmp_path / "site.toml"
    p.write_text(text)
    return p


def test_good_site(tmp_path):
    site = load_site(write(tmp_path, GOOD))
    assert site.anchor_ids == (0, 1, 2)
    assert site.radio.path_loss_exponent == 2.2
    assert site.offsets.tolist() == [0.0, 0.0, -1.5]
    assert site.index_of(2) == 2
    again = load_site(write(tmp_path, site_to_toml(site)))
    assert again.anchors == site.anchors and again.radio == site.radio


@pytest.mark.parametrize(
    "edit,key,words",
    [
        (lambda t: t.replace("path_loss_exponent = 2.2\n", ""), "radio.path_loss_exponent", "missing"),
        (lambda t: t.replace("y = 4.0", "y = 0.0").replace("x = 4.0\ny = 0.0", "x = 4.0\ny = 0.0"), "anchors", "collinear"),
        (lambda t: t.replace("id = 1", "id = 0"), "anchors[1].id", "duplicate"),
        (lambda t: t.replace("x = 4.0", "x = nan"), "anchors[2].x", "finite"),
        (lambda t: t.replace("rssi_at_1m_dbm = -45.0", 'rssi_at_1m_dbm = "loud"'), "radio.rssi_at_1m_dbm", "number"),
        (lambda t: t.replace("id = 2", "id = 2.5"), "anchors[2].id", "integer"),
        (lambda t: t.replace("[radio]", "[radio\n"), "<syntax>", ""),
        (lambda t: "[site]\narea = [0, 0, 5]\n" + t, "site.area", "[xmin, ymin, xmax, ymax]"),
        (lambda t: "[site]\narea = [5, 0, 0, 5]\n" + t, "site.area", "xmin < xmax"),
        (lambda t: "[site]\narea = [0, 0, 5, inf]\n" + t, "site.area", "finite"),
        (lambda t: "[site]\narea = [0, 0, 1e6, 5]\n" + t, "site.area", "longer than"),
        (lambda t: t.replace("x = 4.0", "x = 4.0\nz = 1e5"), "anchors[2].z", "within"),
        (lambda t: t.replace("x = 4.0", 'x = 4.0\nz = "high"'), "anchors[2].z", "number"),
        (lambda t: "[site]\ntarget_z = -2000.0\n" + t, "site.target_z", "within"),
    ],
)
def test_bad_site(tmp_path, edit, key, words):
    with pytest.raises(ConfigError) as err:
        load_site(write(tmp_path, edit(GOOD)))
    assert err.value.key == key
    assert words in err.value.problem


def test_two_anchors_rejected():
    with pytest.raises(ConfigError, match="at least 3"):
        parse_site({"radio": {"rssi_at_1m_dbm": -40, "path_loss_exponent": 2}, "anchors": [{"id": 0, "x": 0, "y": 0}]})


def test_area_is_where_the_estimators_look_and_survives_the_writer(tmp_path):
    from pfdoa.estimators import make_estimator

    site = load_site(write(tmp_path, "[site]\narea = [-3.0, -2.0, 9.0, 7.5]\n" + GOOD))
    assert site.area == (-3.0, -2.0, 9.0, 7.5)
    assert load_site(write(tmp_path, site_to_toml(site))).area == site.area
    for method in ("pf-doa", "markov", "drssi"):
        est = make_estimator(method, site)
        pts = est.points if hasattr(est, "points") else np.column_stack([est.lo, est.hi]).T
        assert pts.min(axis=0).tolist() == pytest.approx([-3.0, -2.0], abs=1e-9), method
        assert pts.max(axis=0).tolist() == pytest.approx([9.0, 7.5], abs=0.11), method
    # without an area: around the anchors (0..4 m) with a small margin
    plain = make_estimator("pf-doa", load_site(write(tmp_path, GOOD)))
    assert plain.lo.tolist() == pytest.approx([-0.2, -0.2]) and plain.hi.tolist() == pytest.approx([4.2, 4.2])


def test_heights_default_to_the_plane_and_survive_the_writer(tmp_path):
    plain = load_site(write(tmp_path, GOOD))
    assert plain.target_z == 0.0 and plain.heights.tolist() == [0.0, 0.0, 0.0]
    assert "z =" not in site_to_toml(plain) and "target_z" not in site_to_toml(plain)  # old files stay as they were
    text = "[site]\ntarget_z = 1.0\n" + GOOD.replace("x = 4.0", "x = 4.0\nz = 2.5")
    site = load_site(write(tmp_path, text))
    assert [a.z for a in site.anchors] == [0.0, 0.0, 2.5]
    assert site.heights.tolist() == [-1.0, -1.0, 1.5]  # above the beacon's plane
    again = load_site(write(tmp_path, site_to_toml(site)))
    assert again.anchors == site.anchors and again.target_z == 1.0
    assert site_to_toml(again) == site_to_toml(site)
