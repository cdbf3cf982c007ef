"""The MQTT modules' logic without a broker: outbox policy, ESPresense parsing and its
rejections, frame sources, topic names, discovery configs, the pose payload."""

import io
import json
import math
import re

import pytest

from pfdoa.clock import FakeClock
from pfdoa.gateway.beacons import BeaconReading
from pfdoa.gateway.inputs.mqtt import READ_ITEMS as ESPRESENSE_READ_ITEMS
from pfdoa.gateway.inputs.mqtt import EspresenseTransport
from pfdoa.mqtt.discovery import beacon_configs, gateway_configs, object_id
from pfdoa.mqtt.espresense import (
    MAX_UNKNOWN_ROOMS,
    EspresenseInput,
    EspresenseParser,
    espresense_config,
)
from pfdoa.mqtt.frames import source_name
from pfdoa.mqtt.outbox import Message, Outbox
from pfdoa.mqtt.publisher import _json, _plain, pose_payload, topic_level
from pfdoa.output import FIELDS, Record, Writer

DEV = "iBeacon:e2c56db5-dffb-48d2-b060-d0f5a71096e0-1-2"


def ev(i: int) -> Message:
    return Message("p/b/pose", str(i).encode())


def test_outbox_events_in_order_and_the_oldest_dropped_when_full():
    ob = Outbox(max_events=5)
    for i in range(12):
        ob.put_event(ev(i))
    assert ob.counters.dropped == 7 and ob.counters.events == 12 and ob.pending_events == 5
    assert [m.payload for m in ob.take(3)] == [b"7", b"8", b"9"]
    assert [m.payload for m in ob.take(10)] == [b"10", b"11"]
    assert ob.take(10) == [] and len(ob) == 0


def test_outbox_state_updates_never_starve_the_events():
    """Devices coming and going change state topics (discovery, home/not_home) faster than
    a window of messages can carry: state goes first, but never more than half a window
    while events wait, so the estimates keep leaving in order; with no events, state takes
    the whole window."""
    ob = Outbox(max_events=10_000, max_state_topics=100_000)
    for i in range(200):
        ob.put_event(ev(i))
    sent: list[bytes] = []
    for k in range(20):
        for j in range(100):  # more new state each time than the window holds
            ob.put_state(Message(f"p/dev{k}-{j}/state", b"home", retain=True))
        waiting = ob.pending_events
        batch = ob.take(64)
        assert len(batch) == 64 and sum(not m.retain for m in batch) == min(32, waiting), k
        sent += [m.payload for m in batch if not m.retain]
    assert sent == [str(i).encode() for i in range(200)]  # every event, in order, while state kept coming
    assert all(m.retain for m in ob.take(64)) and ob.pending_events == 0


def test_outbox_state_latest_wins_goes_first_and_is_resent_after_reconnect():
    ob = Outbox(max_events=10, max_state_topics=2)
    ob.put_event(ev(0))
    assert ob.put_state(Message("p/health", b"1", retain=True))
    assert ob.put_state(Message("p/status", b"online", retain=True))
    assert ob.put_state(Message("p/health", b"2", retain=True))  # overwrites in place
    assert not ob.put_state(Message("p/anchors/1/status", b"x", retain=True))  # table full
    assert ob.counters.state_refused == 1
    got = ob.take(10)
    assert [(m.topic, m.payload) for m in got] == [("p/status", b"online"), ("p/health", b"2"), ("p/b/pose", b"0")]
    assert ob.take(10) == []
    ob.resend_state()
    assert sorted(m.topic for m in ob.take(10)) == ["p/health", "p/status"]
    ob.drop_state("p/health")
    ob.resend_state()
    assert [m.topic for m in ob.take(10)] == ["p/status"]


def esp_parser(**table):
    t = {"rooms": {"kitchen": 1, "hall": 2}, **table}
    return EspresenseParser(espresense_config({"espresense": t}, "s", (1, 2, 3), -59.0))


def doc(**kw) -> bytes:
    d = {"id": DEV, "mac": "e2c56db5dffb", "rssi@1m": -63, "rssi": -71.25, "rxAdj": 0, "distance": 2.1, "int": 100}
    d.update(kw)
    return json.dumps({k: v for k, v in d.items() if v is not None}).encode()


def test_espresense_message_becomes_a_beacon_reading():
    p = esp_parser()
    r = p.parse(f"espresense/devices/{DEV}/hall", doc(), 123.5)
    assert isinstance(r, BeaconReading) and r.beacon == DEV
    # normalized to the site's radio model: -71.25 + (-59 - -63)
    assert (r.reading.anchor_id, r.reading.rssi_dbm, r.reading.t, r.reading.seq) == (2, -67.25, 123.5, None)
    raw = esp_parser(normalize_1m=False).parse(f"espresense/devices/{DEV}/hall", doc(), 1.0)
    assert raw.reading.rssi_dbm == -71.25
    no_ref = p.parse(f"espresense/devices/{DEV}/kitchen", doc(**{"rssi@1m": None}), 1.0)
    assert no_ref.reading.rssi_dbm == -71.25 and no_ref.reading.anchor_id == 1



class _NoBroker:
    """The client an input subscribes through; these tests put messages in by hand."""

    prefix = "pfdoa"

    def subscribe(self, *_a) -> None:
        pass

    def unsubscribe(self, *_a) -> None:
        pass


def test_live_timers_follow_a_busy_inbox_up_to_the_last_reading_returned():
    # At 1600 messages/s the inbox is seldom empty; "caught up" only when it is would hold
    # the timers (and every window's close) back until a quiet moment.
    clock = FakeClock(start=1000.0)
    cfg = espresense_config({"espresense": {"rooms": {"kitchen": 1, "hall": 2}}}, "s", (1, 2, 3), -59.0)
    inp = EspresenseInput(_NoBroker(), cfg)
    tr = EspresenseTransport(inp)
    tr.clock = clock
    tr.open()
    n = ESPRESENSE_READ_ITEMS + 6
    for k in range(n):
        inp._on_message(f"espresense/devices/{DEV}/hall", doc(), 990.0 + 0.01 * k)
    clock.advance(1.0)
    (batch,) = tr.read(0.0)
    assert len(batch.readings) == ESPRESENSE_READ_ITEMS
    assert tr.caught_up_to == batch.readings[-1].t == 990.0 + 0.01 * (ESPRESENSE_READ_ITEMS - 1)
    (rest,) = tr.read(0.0)
    assert len(rest.readings) == 6 and tr.caught_up_to == clock.now() == 1001.0
    assert tr.read(0.0) == [] and tr.caught_up_to == 1001.0

def test_espresense_anchor_status_per_room():
    p = esp_parser()
    p.parse(f"espresense/devices/{DEV}/hall", doc(), 10.0)
    p.parse("espresense/devices/other/hall", doc(), 12.0)
    p.parse(f"espresense/devices/{DEV}/hall", b"{", 13.0)  # rejected: not counted for the room
    assert p.anchor_status(now=15.0) == {
        1: {"room": "kitchen", "readings": 0, "last_t": None, "age_s": None},
        2: {"room": "hall", "readings": 2, "last_t": 12.0, "age_s": 3.0}}


def test_espresense_time_from_the_message_when_configured():
    p = esp_parser(time_field="t")
    assert p.parse(f"espresense/devices/{DEV}/hall", doc(t=17.25), 999.0).reading.t == 17.25
    for bad in (None, "17", float("inf"), -1.0, True, 10 ** 400):
        assert p.parse(f"espresense/devices/{DEV}/hall", doc(t=bad), 999.0) == "bad_time"


@pytest.mark.parametrize("topic, payload, kind", [
    (f"espresense/devices/{DEV}/cellar", doc(), "unknown_room"),
    ("espresense/devices/x/y/z", doc(), "bad_topic"),
    ("espresense/rooms/x/y", doc(), "bad_topic"),
    (f"espresense/devices/{'x' * 129}/hall", doc(), "bad_device"),
    (f"espresense/devices/{DEV}/hall", b"{", "bad_json"),
    (f"espresense/devices/{DEV}/hall", b"\xff\xfe", "bad_json"),
    (f"espresense/devices/{DEV}/hall", b"[1, 2]", "bad_json"),
    (f"espresense/devices/{DEV}/hall", b"[" * 1500 + b"]" * 1500, "bad_json"),
    (f"espresense/devices/{DEV}/hall", b"{\"rssi\": " + b"[" * 1000 + b"]" * 1000 + b"}", "bad_json"),
    (f"espresense/devices/{DEV}/hall", doc(rssi=None), "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", doc(rssi="-70"), "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", doc(rssi=True), "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", doc(rssi=-500), "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", b'{"rssi": NaN}', "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", b'{"rssi": 1e999}', "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", doc(**{"rssi@1m": "x"}), "bad_rssi_1m"),
    # a JSON integer beyond float range (fuzz/regressions/espresense): float() raises
    (f"espresense/devices/{DEV}/hall", b'{"rssi": -1' + b"0" * 400 + b"}", "bad_rssi"),
    (f"espresense/devices/{DEV}/hall", doc(**{"rssi@1m": -10 ** 400}), "bad_rssi_1m"),
])
def test_espresense_rejections_by_kind(topic, payload, kind):
    assert esp_parser().parse(topic, payload, 0.0) == kind


def test_espresense_device_patterns_and_the_unknown_room_cap():
    p = esp_parser(devices=["iBeacon:*-1-?", "robot-*"])
    assert isinstance(p.parse(f"espresense/devices/{DEV}/hall", doc(), 0.0), BeaconReading)
    assert isinstance(p.parse("espresense/devices/robot-7/hall", doc(), 0.0), BeaconReading)
    assert p.parse("espresense/devices/apple:1005:9-26/hall", doc(), 0.0) == "ignored_device"
    for i in range(MAX_UNKNOWN_ROOMS + 100):
        assert p.parse(f"espresense/devices/{DEV}/room{i}", doc(), 0.0) == "unknown_room"
    assert len(p.unknown_rooms) == MAX_UNKNOWN_ROOMS and sum(p.unknown_rooms.values()) == MAX_UNKNOWN_ROOMS


def test_frame_source_names_are_capture_safe():
    assert source_name("pfdoa/anchors/a 1\t/frames") == "mqtt:pfdoa/anchors/a_1_/frames"
    assert len(source_name("x" * 1000)) == len("mqtt:") + 200


def test_topic_level_and_object_id_are_safe_and_distinct():
    assert topic_level("robot-1") == "robot-1" and topic_level(DEV) == DEV  # ':' and '-' are fine in topics
    for name in ("a/b", "a+b", "a#b", "a\x00b", ""):
        level = topic_level(name)
        assert not set("/+#\x00") & set(level) and level
    assert topic_level("a/b") != topic_level("a_b") != topic_level("a+b")
    assert object_id("robot-1") == "robot-1"
    ids = {object_id(n) for n in (DEV, DEV.replace(":", "_"), "a.b", "a_b", "a b")}
    assert len(ids) == 5 and all(re.fullmatch(r"[a-zA-Z0-9_-]+", i) for i in ids)


def test_pose_payload_is_the_json_output_line_plus_beacon():
    rec = Record(t=1700000000.123456, x=1.23456, y=-0.5, sigma=float("nan"), doa=0.25, seq=None,
                 anchors=(1, 2, 4), missing=(3,), stale=(3,), rebooted=())
    buf = io.StringIO()
    Writer(buf, "jsonl").write(rec)
    line = json.loads(buf.getvalue())
    got = json.loads(pose_payload(DEV, rec))
    assert got == {**line, "beacon": DEV}
    assert list(got) == list(FIELDS) and got["sigma"] is None


def test_counters_become_plain_json():
    body = _plain({"a": {1: 2.0}, "s": {3, 1}, "n": float("nan"), "t": (1, 2), "i": math.inf})
    assert json.loads(_json(body)) == {"a": {"1": 2.0}, "s": [1, 3], "n": None, "t": [1, 2], "i": None}


def test_discovery_configs():
    pose, state, status = f"pfdoa/{DEV}/pose", f"pfdoa/{DEV}/state", "pfdoa/status"
    cfgs = beacon_configs("robot-1", DEV, "homeassistant", pose, state, status, expire_after_s=30)
    topics = [t for t, _ in cfgs]
    assert len(topics) == 4
    for t in topics:
        assert re.fullmatch(r"homeassistant/(device_tracker|sensor)/robot-1/[a-zA-Z0-9_-]+/config", t), t
    tracker = cfgs[0][1]
    assert topics[0].startswith("homeassistant/device_tracker/")
    assert tracker["json_attributes_topic"] == pose and tracker["state_topic"] == state
    assert tracker["availability_topic"] == status and tracker["source_type"] == "bluetooth_le"
    assert tracker["device"]["name"] == DEV and tracker["device"]["via_device"] == "pfdoa_robot-1"
    uids = [c["unique_id"] for _, c in cfgs]
    assert len(set(uids)) == len(uids)
    for _, c in cfgs[1:]:
        assert c["device"]["identifiers"] == tracker["device"]["identifiers"]
        field = re.fullmatch(r"\{\{ value_json\.(\w+) \}\}", c["value_template"]).group(1)
        assert field in FIELDS and c["name"] == field and c["state_topic"] == pose and c["expire_after"] == 30
    (gtopic, g), = gateway_configs("robot-1", "homeassistant", "pfdoa/health", status)
    assert g["device"]["identifiers"] == ["pfdoa_robot-1"] and gtopic == "homeassistant/sensor/robot-1/estimates/config"
