"""The fleet simulator (ESPresense-style nodes, several beacons) and the in-process demo
through a real mosquitto: per-beacon accuracy, and results that do not depend on speed."""

import json
from dataclasses import replace

import numpy as np
import pytest

from pfdoa.mqtt.espresense import EspresenseParser, espresense_config
from pfdoasim.fleet import (
    ESPRESENSE_ABSORPTION,
    FLEET_WINDOW_S,
    FleetConfig,
    FleetScenario,
    perimeter_anchors,
    run_fleet,
)


def test_anchors_along_the_walls():
    assert perimeter_anchors(4, 6.0, 4.0) == [(0.0, 0.0), (5.0, 0.0), (6.0, 4.0), (1.0, 4.0)]
    pts = perimeter_anchors(8, 12.0, 8.0)
    assert len(set(pts)) == 8 and all(x in (0.0, 12.0) or y in (0.0, 8.0) for x, y in pts)


def test_messages_are_seeded_time_ordered_and_shaped_like_an_espresense_node():
    cfg = FleetConfig(n_beacons=3, duration_s=3.0, seed=5)
    a, b = FleetScenario(cfg), FleetScenario(cfg)
    ma, mb = list(a.messages()), list(b.messages())
    assert [(m.t, m.topic, m.payload) for m in ma] == [(m.t, m.topic, m.payload) for m in mb]
    other = list(FleetScenario(FleetConfig(n_beacons=3, duration_s=3.0, seed=6)).messages())
    assert [m.payload for m in other] != [m.payload for m in ma]
    ts = [m.t for m in ma]
    assert ts == sorted(ts) and 0.0 <= ts[0] and ts[-1] < 3.0
    assert len(ma) == 3 * 8 * 30  # every node reports every beacon 10 times a second (no misses here)
    room_of = {v: k for k, v in a.rooms.items()}
    for m in ma[:200]:
        prefix, devices, device, room = m.topic.split("/")
        d = json.loads(m.payload)
        assert (prefix, devices, device, room) == ("espresense", "devices", m.beacon, room_of[m.anchor])
        assert d["id"] == m.beacon and d["t"] == round(m.t, 6)
        assert d["rssi@1m"] == round(cfg.rssi_at_1m_dbm + a.tx_offset[m.beacon], 2)
        dist = 10 ** ((d["rssi@1m"] - d["rssi"]) / (10 * ESPRESENSE_ABSORPTION))
        assert abs(d["distance"] - dist) <= 0.006 + 1e-3 * dist  # both rounded to 2 decimals
    # Normalized by rssi@1m, the readings follow the site's radio model around the truth.
    parser = EspresenseParser(espresense_config({"espresense": a.espresense_table()}, "s", a.site.anchor_ids,
                                                cfg.rssi_at_1m_dbm))
    resid = []
    for m in ma:
        r = parser.parse(m.topic, m.payload, 0.0).reading
        p = a.truth(m.beacon, r.t)
        anchor = a.site.anchors[a.site.index_of(r.anchor_id)]
        d = max(np.hypot(p[0] - anchor.x, p[1] - anchor.y), 0.1)
        resid.append(r.rssi_dbm - (cfg.rssi_at_1m_dbm - 10 * cfg.path_loss_exponent * np.log10(d)))
    resid = np.array(resid)
    assert abs(np.median(resid)) < 0.7 and 1.0 < np.std(resid) < 3.5  # 2.5 dB noise / sqrt(3) + bursts


def test_fleet_demo_through_the_broker_localizes_every_beacon_and_repeats_exactly(broker, tmp_path):
    cfg = FleetConfig(n_beacons=3, duration_s=12.0, seed=2)
    r1 = run_fleet(cfg, tmp_path, broker=broker, warmup_s=4.0)
    c = r1.counters
    assert c["messages"] == 3 * 8 * 120 and c["input"]["accepted"] == c["messages"]
    assert c["input"]["rejected"] == {} and c["input"]["queue_drops"] == 0
    # One estimate per beacon per time window (an anchor's readings in it are combined).
    per_beacon = int(12 / FLEET_WINDOW_S)
    assert c["estimates"] == c["tracker"]["records"] >= 3 * (per_beacon - 1) and c["estimator_errors"] == 0
    assert c["published_all"] and c["mqtt"]["queue_dropped"] == 0
    for beacon, v in r1.per_beacon.items():
        assert v["n"] >= per_beacon * (12 - 4) / 12 - 2 and v["mean_m"] < 0.6, (beacon, v)
    r2 = run_fleet(cfg, tmp_path, broker=broker, warmup_s=4.0)  # a second run: same numbers exactly
    assert r2.per_beacon == r1.per_beacon


def test_the_example_home_s_site_file_places_the_nodes_of_the_demo(tmp_path):
    """make demo-fleet reads examples/espresense/site.toml: its anchors, radio model, node
    names and rooms. Its nodes stand where the built-in layout puts them, so the readings
    (and so the demo's numbers) are the same; only the nodes' names in the topics differ."""
    from pathlib import Path

    from pfdoa.errors import ConfigError
    from pfdoa.rooms import site_plan
    from pfdoa.site import load_site
    from pfdoasim.fleet import fleet_site_toml

    example = Path(__file__).resolve().parents[2] / "examples" / "espresense" / "site.toml"
    cfg = FleetConfig(n_beacons=2, duration_s=2.0, seed=7)
    built_in, home = FleetScenario(cfg), FleetScenario(replace(cfg, site_file=str(example)))
    site = load_site(example)
    assert home.site.anchors == site.anchors and home.site.radio == site.radio
    assert home.rooms == {a.name: a.id for a in site.anchors}  # each node named after itself
    a, b = list(built_in.messages()), list(home.messages())
    assert [(m.t, m.payload, m.anchor) for m in a] == [(m.t, m.payload, m.anchor) for m in b]
    name = {aid: room for room, aid in home.rooms.items()}
    assert all(m.topic.endswith("/" + name[m.anchor]) for m in b)
    # The gateway's site file keeps the home's rooms.
    p = tmp_path / "gw.toml"
    p.write_text(fleet_site_toml(home))
    assert site_plan(load_site(p)) == site_plan(site) and len(site_plan(site).rooms) == 6
    # Every anchor of a fleet's site file must be a node the [espresense] table names.
    p.write_text(example.read_text().replace("dining_west = 8", "attic = 8").replace("dining = 7, ", ""))
    with pytest.raises(ConfigError, match=r"anchors\[6\]: anchor 7 is no ESPresense node"):
        FleetScenario(replace(cfg, site_file=str(p)))
