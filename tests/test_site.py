import textwrap

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
