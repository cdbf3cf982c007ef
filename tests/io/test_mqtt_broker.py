"""Against a real mosquitto started by the test (tests/mqtt_support.py), no mock of the broker:
estimates round trip, ESPresense input, our frames over MQTT, discovery, the last will,
credentials and TLS, bounded inputs, and a broker restart with every estimate delivered."""

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from pfdoa.gateway.beacons import BeaconsConfig
from pfdoa.gateway.config import GatewayConfig
from pfdoa.gateway.health import Health
from pfdoa.gateway.inputs.mqtt import FrameTransport
from pfdoa.gateway.pipeline import Gateway
from pfdoa.gateway.reassembly import SeqReassembler
from pfdoa.gateway.setup import build_named_tracker
from pfdoa.mqtt.client import ClientConfig, MqttClient
from pfdoa.mqtt.config import mqtt_settings
from pfdoa.mqtt.espresense import EspresenseInput, EspresenseParser, espresense_config
from pfdoa.mqtt.frames import FrameInput
from pfdoa.mqtt.publisher import Publisher, PublisherConfig
from pfdoa.mqtt.url import PASSWORD_ENV, parse_url
from pfdoa.output import Record, Writer
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart
from pfdoasim.fleet import FLEET_WINDOW_S, FleetConfig, FleetScenario

from mqtt_support import Recorder, wait_for

DEV = "iBeacon:e2c56db5-dffb-48d2-b060-d0f5a71096e0-1-2"


def client_for(b, prefix="pfdoa", **kw) -> MqttClient:
    kw.setdefault("reconnect_min_s", 0.1)
    kw.setdefault("reconnect_max_s", 0.5)
    c = MqttClient(ClientConfig(parse_url(b.url(prefix)), **kw)).start()
    assert c.wait_connected(10), b.log_tail()
    return c


def records(n: int, t0: float = 1700000000.0) -> list[Record]:
    return [Record(t=t0 + 0.1 * i, x=1.0 + 0.01 * i, y=2.0, sigma=0.3, doa=0.5, seq=i, anchors=(1, 2, 3),
                   missing=(4,), stale=(4,) if i % 2 else (), rebooted=()) for i in range(n)]


def test_estimates_round_trip_as_the_json_output_line_plus_beacon(broker):
    rec = Recorder(broker, "pfdoa/#")
    c = client_for(broker)
    pub = Publisher(c, PublisherConfig(discovery=False))
    rs = records(50)
    for r in rs:
        pub.estimate(DEV, r)
    assert c.flush(20)
    sock = c._paho.socket()  # estimates leave at once (no Nagle delay)
    assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1
    topic = pub.pose_topic(DEV)
    assert topic == f"pfdoa/{DEV}/pose"
    wait_for(lambda: len(rec.on(topic)) == 50, what="50 poses")
    buf = io.StringIO()
    w = Writer(buf, "jsonl")
    for r in rs:
        w.write(r)
    expected = [{**json.loads(line), "beacon": DEV} for line in buf.getvalue().splitlines()]
    assert [json.loads(p) for p in rec.on(topic)] == expected
    assert not any(r for t, _, r in rec.messages if t == topic)  # a stream: not retained
    assert rec.on(pub.state_topic(DEV)) == [b"home"] and b"online" in rec.on("pfdoa/status")
    pub.health({"estimates": 50, "per_anchor": {1: {"lost": float("nan")}}})
    assert c.flush(10)
    wait_for(lambda: rec.on("pfdoa/health"), what="health")
    h = json.loads(rec.on("pfdoa/health")[-1])
    assert h["estimates"] == 50 and h["per_anchor"] == {"1": {"lost": None}}
    assert h["mqtt"]["connected"] and h["mqtt"]["delivered"] >= 52
    # A subscriber arriving now gets the retained state (online, home, health), no old pose.
    late = Recorder(broker, "pfdoa/#")
    wait_for(lambda: late.on("pfdoa/status") and late.on("pfdoa/health") and late.on(pub.state_topic(DEV)))
    assert all(r for _, _, r in late.messages) and not late.on(topic)
    c.stop()
    wait_for(lambda: rec.on("pfdoa/status")[-1:] == [b"offline"], what="offline on a clean stop")
    rec.close()
    late.close()


def test_espresense_nodes_on_the_broker_become_beacon_readings(broker):
    cfg = espresense_config({"espresense": {"rooms": {"kitchen": 1, "hall": 2}}}, "s", (1, 2, 3), -59.0)
    c = MqttClient(ClientConfig(parse_url(broker.url("pfdoa"))), clock=lambda: 4242.0).start()
    assert c.wait_connected(10)
    inp = EspresenseInput(c, cfg, max_queue=100).start()
    node = client_for(broker, "espresense-node")  # publishes as an ESPresense node: QoS 0, not retained

    def send(topic, payload):
        node.publish(topic, payload, qos=0)

    assert c.wait_subscribed(inp.topic_filter, 10)
    good = json.dumps({"id": DEV, "mac": "e2c56db5dffb", "rssi@1m": -63, "rssi": -71.25, "rxAdj": 0,
                       "distance": 2.1, "var": 0.3, "int": 100}).encode()
    send(f"espresense/devices/{DEV}/hall/report-1", good)  # a sub-topic: not subscribed
    send("espresense/rooms/hall/status", b"online")  # other ESPresense topics: not subscribed
    send(f"espresense/devices/{DEV}/hall", good)
    send(f"espresense/devices/{DEV}/kitchen", good)
    send(f"espresense/devices/{DEV}/cellar", good)  # no such room in the site
    send(f"espresense/devices/{DEV}/hall", b"not json")
    send(f"espresense/devices/{DEV}/hall", b'{"rssi": "strong"}')
    send(f"espresense/devices/{DEV}/hall", b'{"rssi": -60, "pad": "' + b"x" * 3000 + b'"}')
    wait_for(lambda: inp.messages == 6, what="6 messages")
    got = inp.read(1.0)
    assert [(r.beacon, r.reading.anchor_id, r.reading.rssi_dbm, r.reading.t) for r in got] == \
        [(DEV, 2, -67.25, 4242.0), (DEV, 1, -67.25, 4242.0)]
    assert inp.counters()["rejected"] == {"unknown_room": 1, "bad_json": 1, "bad_rssi": 1, "oversized": 1}
    assert inp.counters()["unknown_rooms"] == {"cellar": 1}
    assert c.stats.unexpected == 0 and c.stats.handler_errors == 0
    # Anchor status from what the nodes sent, retained on <prefix>/anchors/<id>/status.
    pub = Publisher(c, PublisherConfig(discovery=False))
    for aid, st in inp.anchor_status(now=4243.0).items():
        pub.anchor_status(aid, st)
    assert c.flush(10)
    late = Recorder(broker, "pfdoa/anchors/+/status")
    wait_for(lambda: len(late.messages) == 2, what="2 anchor status messages")
    assert {t: json.loads(p) for t, p, r in late.messages if r} == {
        "pfdoa/anchors/1/status": {"anchor": 1, "room": "kitchen", "readings": 1, "last_t": 4242.0, "age_s": 1.0},
        "pfdoa/anchors/2/status": {"anchor": 2, "room": "hall", "readings": 1, "last_t": 4242.0, "age_s": 1.0}}
    late.close()
    node.stop()
    c.stop()


def test_a_flood_on_an_input_nobody_reads_stays_bounded_and_counted(broker):
    cfg = espresense_config({"espresense": {"rooms": {"hall": 2}}}, "s", (1, 2, 3), -59.0)
    c = client_for(broker)
    inp = EspresenseInput(c, cfg, max_queue=100, qos=1).start()
    node = client_for(broker, "node")
    assert c.wait_subscribed(inp.topic_filter, 10)
    for i in range(3000):
        node.publish(f"espresense/devices/phone-{i}/hall", b'{"rssi": -70}')
    wait_for(lambda: inp.messages == 3000, what="3000 messages")
    assert inp.pending == 100 and inp.queue_drops == 2900 and inp.accepted == 100
    node.stop()
    c.stop()


def frame(seq: int, anchor: int, rssi: int = -60) -> bytes:
    return encode_uart(RssiReport(seq, 1000 + 20 * seq, rssi * 256, rssi, 3, 37, 0), anchor)


def test_our_frames_over_mqtt_decode_like_a_serial_port(broker):
    c = client_for(broker)
    inp = FrameInput(c)
    tr = FrameTransport(inp)
    tr.open()
    wifi = client_for(broker, "wifi-anchors")
    assert c.wait_subscribed(inp.topic_filter, 10)
    sets, health = [], Health()
    gw = Gateway(SeqReassembler((0, 1, 2, 3), set_timeout_s=5.0), sets.append, health)
    for seq in range(20):
        for a in range(4):
            f = frame(seq, a)
            topic = f"pfdoa/anchors/anchor-{a}/frames"
            if a == 3:  # a frame split over two messages: the per-topic decoder joins them
                wifi.publish(topic, f[:5])
                wifi.publish(topic, f[5:])
            elif a == 2 and seq == 7:
                wifi.publish(topic, b"\x13\x37garbage\x00" + f)  # line noise before a frame
            else:
                wifi.publish(topic, f)
    wifi.publish("pfdoa/anchors/anchor-0/frames", b"\x01" * 5000)  # oversized
    for extra in range(3):  # more topics: each one more source for the gateway's decoder table
        wifi.publish(f"pfdoa/anchors/other-{extra}/frames", frame(0, 9))
    wait_for(lambda: (list(map(gw.feed, tr.read(0.05))), health.reports)[1] >= 83, what="83 reports")
    assert [(s.seq, s.reason) for s in sets] == [(q, "complete") for q in range(20)]
    assert all(s.rssi == {0: -60.0, 1: -60.0, 2: -60.0, 3: -60.0} for s in sets)
    assert health.errors["bad_cobs"] + health.errors["truncated"] + health.errors["bad_crc"] >= 1
    assert set(gw._decoders) == {f"mqtt:pfdoa/anchors/{n}/frames" for n in
                                 [f"anchor-{a}" for a in range(4)] + [f"other-{x}" for x in range(3)]}
    wait_for(lambda: inp.rejected["oversized"] == 1)
    tr.close()
    wifi.stop()
    c.stop()


def test_home_assistant_discovery_retained_and_consistent(broker):
    c = client_for(broker)
    pub = Publisher(c, PublisherConfig(node_id="robot 1", expire_after_s=30))
    pub.estimate(DEV, records(1)[0])
    assert c.flush(10)
    ha = Recorder(broker, "homeassistant/#")  # Home Assistant starting after the gateway
    wait_for(lambda: len(ha.messages) == 5, what="5 discovery configs")
    assert all(retained for _, _, retained in ha.messages)
    configs = {t: json.loads(p) for t, p, _ in ha.messages}
    node = pub.node
    assert node != "robot 1" and node.startswith("robot_1_")  # a space is not allowed in the topic
    (tracker_topic, tracker), = [(t, v) for t, v in configs.items() if "/device_tracker/" in t]
    assert tracker_topic.startswith(f"homeassistant/device_tracker/{node}/")
    assert tracker["json_attributes_topic"] == pub.pose_topic(DEV)
    assert tracker["state_topic"] == pub.state_topic(DEV)
    assert tracker["availability_topic"] == c.status_topic == "pfdoa/status"
    sensors = {v["name"]: v for t, v in configs.items() if f"/sensor/{node}/" in t and v["name"] != "estimates"}
    assert set(sensors) == {"x", "y", "sigma"}
    assert {tuple(v["device"]["identifiers"]) for v in sensors.values()} == {tuple(tracker["device"]["identifiers"])}
    gateway = configs[f"homeassistant/sensor/{node}/estimates/config"]
    assert tracker["device"]["via_device"] in gateway["device"]["identifiers"]
    assert gateway["state_topic"] == pub.health_topic
    ha.close()
    c.stop()


LWT_CHILD = """
import sys, time
from pfdoa.mqtt.client import ClientConfig, MqttClient
from pfdoa.mqtt.url import parse_url
c = MqttClient(ClientConfig(parse_url(sys.argv[1]))).start()
assert c.wait_connected(10) and c.flush(10)
print("up", flush=True)
time.sleep(60)
"""


def test_last_will_says_offline_when_the_gateway_process_dies(broker):
    rec = Recorder(broker, "pfdoa/status")
    p = subprocess.Popen([sys.executable, "-c", LWT_CHILD, broker.url("pfdoa")], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "up"
        wait_for(lambda: rec.on("pfdoa/status")[-1:] == [b"online"], what="online")
        os.kill(p.pid, signal.SIGKILL)  # no clean disconnect: the broker sends the will
        wait_for(lambda: rec.on("pfdoa/status")[-1:] == [b"offline"], what="the last will")
    finally:
        p.kill()
        p.wait()
        rec.close()


def test_password_from_a_file_connects_and_bad_credentials_are_refused_and_counted(password_broker, tmp_path):
    b = password_broker
    pw = tmp_path / "pw"
    pw.write_text("s3cret-pw\n")
    os.chmod(pw, 0o600)
    s = mqtt_settings({}, url=b.url("pfdoa", user="fleet"), password_file=str(pw), environ={})
    good = MqttClient(s.client).start()
    assert good.wait_connected(10) and good.stats.refused == 0
    for label, settings in (
            ("wrong password", mqtt_settings({}, url=b.url("pfdoa", user="fleet"), environ={PASSWORD_ENV: "nope"})),
            ("anonymous", mqtt_settings({}, url=b.url("pfdoa"), environ={}))):
        bad = MqttClient(ClientConfig(settings.client.url, settings.client.password, reconnect_min_s=0.1,
                                      reconnect_max_s=0.2)).start()
        # Refused for good: said once, and paho's network loop ends (no more attempts).
        assert not bad.wait_connected(10) and bad.fatal is not None and "authori" in bad.fatal.lower(), label
        wait_for(lambda: not bad._paho._thread or not bad._paho._thread.is_alive(),  # noqa: B023 (called here)
                 what=f"{label}: the client gives up")
        assert bad.stats.refused == 1 and bad.stats.connects == 0 and "authori" in bad.stats.last_refusal.lower()
        bad.stop(0.1)
    good.stop()


def test_a_broker_that_is_down_is_retried_and_said_at_a_slow_rate(tmp_path, caplog):
    """No broker on the port: the client keeps trying with backoff; the log says so once when
    the outage starts, then once per RETRY_LOG_S of the (injected) monotonic clock, with the
    number of attempts; never a permanent failure. A broker started there later is used."""
    import logging

    from pfdoa.mqtt import client as client_mod
    from pfdoasim.fleet import Mosquitto, free_port

    now = [0.0]
    port = free_port()
    c = MqttClient(ClientConfig(parse_url(f"mqtt://127.0.0.1:{port}/pfdoa"), reconnect_min_s=0.05,
                                reconnect_max_s=0.1), monotonic=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="pfdoa.mqtt.client"):
        c.start()
        wait_for(lambda: c.stats.connect_failures >= 4, what="several failed attempts")
        said = [r.getMessage() for r in caplog.records]
        assert len(said) == 1 and "cannot connect" in said[0] and c.fatal is None, said
        now[0] = client_mod.RETRY_LOG_S  # a minute later, still down: one more line, with the count
        wait_for(lambda: len(caplog.records) == 2, what="the repeated line")
        assert "still cannot connect" in caplog.records[1].getMessage() and "attempts" in caplog.records[1].getMessage()
        b = Mosquitto(tmp_path / "late", port=port).start()
        try:
            assert c.wait_connected(30) and c.fatal is None
        finally:
            c.stop()
            b.stop()


def test_mqtts_with_a_ca_file_and_an_unverifiable_broker(tls_broker):
    b = tls_broker
    s = mqtt_settings({}, url=b.url("pfdoa"), ca_file=b.tls.cafile, environ={})
    assert s.client.url.tls
    c = MqttClient(s.client).start()
    assert c.wait_connected(10), b.log_tail()
    pub = Publisher(c, PublisherConfig(discovery=False))
    pub.estimate("b1", records(1)[0])
    assert c.flush(10) and c.stats.delivered >= 2
    c.stop()
    # The system's CA store does not know our test CA: never connected, failures counted.
    s = mqtt_settings({}, url=b.url("pfdoa"), environ={})
    untrusted = MqttClient(ClientConfig(s.client.url, reconnect_min_s=0.1, reconnect_max_s=0.2)).start()
    wait_for(lambda: untrusted.stats.connect_failures >= 2, what="TLS verification failures")
    assert not untrusted.connected and untrusted.stats.connects == 0
    assert untrusted.stop(0.1) == 1  # its "online" was never delivered, and it says so


def fleet_estimates(n_beacons: int, duration_s: float, on_record):
    """Real estimates: the fleet simulator's node messages -> ESPresense parser -> tracker -> pf-doa."""
    sc = FleetScenario(FleetConfig(n_beacons=n_beacons, duration_s=duration_s, seed=4))
    site = sc.site
    parser = EspresenseParser(espresense_config({"espresense": sc.espresense_table()}, "s", site.anchor_ids,
                                                site.radio.rssi_at_1m_dbm))
    gcfg = GatewayConfig(mode="window", window_s=FLEET_WINDOW_S)
    tracker = build_named_tracker(site, gcfg, BeaconsConfig(), method="pf-doa", seed=4, on_record=on_record)
    return sc, parser, tracker


def test_broker_restart_every_estimate_made_before_during_and_after_is_delivered(persistent_broker):
    """QoS 1 end to end. The gateway holds what it cannot send (outbox + paho's unacknowledged
    window, re-sent after the reconnect); the broker keeps the recorder's persistent session
    (clean_session false, QoS 1 subscription) across its restart (persistence on), and
    queues for it whatever arrives before the recorder is back."""
    b = persistent_broker
    rec = Recorder(b, "pfdoa/+/pose", client_id="fleet-recorder", clean_session=False, qos=1)
    c = client_for(b, queue_size=100_000)
    pub = Publisher(c, PublisherConfig(discovery=False))
    made: list[tuple[str, float]] = []
    phase: list[str] = []

    def on_record(beacon, r):
        made.append((beacon, round(r.t, 6)))
        phase.append("down" if not b.running else "up")
        pub.estimate(beacon, r)

    sc, parser, tracker = fleet_estimates(3, 12.0, on_record)
    msgs = list(sc.messages())
    thirds = [msgs[: len(msgs) // 3], msgs[len(msgs) // 3: 2 * len(msgs) // 3], msgs[2 * len(msgs) // 3:]]

    def run(part):
        for m in part:
            br = parser.parse(m.topic, m.payload, 0.0)
            tracker.push(br.beacon, br.reading)

    run(thirds[0])
    wait_for(lambda: len(rec.poses()) >= len(made), what="live delivery before the outage")
    b.stop()
    wait_for(lambda: not c.connected, what="the client to see the outage")
    run(thirds[1])  # estimates keep coming while the broker is away
    during = phase.count("down")
    assert during > 30 and c.outbox.pending_events + c.inflight >= during - c.cfg.inflight
    b.start()
    run(thirds[2])
    tracker.flush()
    assert c.flush(60), c.summary()
    wait_for(lambda: len(set((json.loads(p)["beacon"], json.loads(p)["t"]) for p in rec.poses()))
             >= len(set(made)), timeout_s=60, what="every estimate at the recorder")
    got = [json.loads(p) for p in rec.poses()]
    keys = [(g["beacon"], g["t"]) for g in got]
    assert set(keys) == set(made) and len(made) == len(set(made)) > 100
    s = c.summary()
    assert s["queue_dropped"] == 0 and s["connects"] >= 2 and s["disconnects"] >= 1
    print(f"\nrestart: {len(made)} estimates ({during} while the broker was down), {len(keys)} deliveries "
          f"({len(keys) - len(set(keys))} duplicates), client {s}")
    rec.close()
    c.stop()


def test_outbox_overflow_while_the_broker_is_away_drops_the_oldest_and_counts_them(persistent_broker):
    b = persistent_broker
    rec = Recorder(b, "pfdoa/+/pose", client_id="overflow-recorder", clean_session=False, qos=1)
    c = client_for(b, queue_size=10)
    pub = Publisher(c, PublisherConfig(discovery=False))
    b.stop()
    wait_for(lambda: not c.connected)
    rs = records(25)
    for r in rs:
        pub.estimate("b1", r)
    s = c.summary()
    assert s["queue_dropped"] == 15 and s["queued"] == 10
    b.start()
    assert c.flush(30)
    wait_for(lambda: len(rec.poses()) >= 10, what="the 10 kept estimates")
    time.sleep(0.2)  # nothing else may follow
    assert [json.loads(p)["seq"] for p in rec.poses()] == list(range(15, 25))
    rec.close()
    c.stop()


def test_a_broker_whose_picked_port_is_taken_first_starts_on_another(broker, tmp_path, monkeypatch):
    """Two test workers can pick the same free port; the one that binds second used to exit
    ("Address already in use") and fail its test. It now picks again, and a given port is kept."""
    import pfdoasim.fleet as fleet

    picks = iter([broker.port])  # the first pick is the running broker's port; later picks are free
    real_free_port = fleet.free_port
    monkeypatch.setattr(fleet, "free_port", lambda: next(picks, None) or real_free_port())
    second = fleet.Mosquitto(tmp_path / "second").start()
    try:
        assert second.port != broker.port
        assert second.running and broker.running
        assert fleet.PORT_IN_USE in second.log.read_text(errors="replace")  # it did meet the taken port
        c = client_for(second)
        c.stop()
    finally:
        second.stop()
    with pytest.raises(RuntimeError, match="could not listen"):
        fleet.Mosquitto(tmp_path / "third", port=broker.port).start()
