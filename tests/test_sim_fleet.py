"""The fleet simulator (ESPresense-style nodes, several beacons) and the in-process demo
through a real mosquitto: per-beacon accuracy, and results that do not depend on speed."""

import json

import numpy as np

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
