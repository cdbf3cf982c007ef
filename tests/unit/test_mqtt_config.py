"""MQTT settings without a broker: the URL, the password's sources, the [mqtt], [espresense]
and [beacons] tables (one error line naming the key, exit status 2)."""

import os

import pytest

from pfdoa.errors import ConfigError, InputError
from pfdoa.gateway.beacons import BeaconsConfig, beacons_config
from pfdoa.mqtt.config import mqtt_settings, mqtt_table
from pfdoa.mqtt.espresense import espresense_config
from pfdoa.mqtt.url import PASSWORD_ENV, check_topic_filter, parse_url, read_password


def test_url_parts_and_defaults():
    u = parse_url("mqtt://broker.local/pfdoa")
    assert (u.host, u.port, u.prefix, u.tls, u.user) == ("broker.local", 1883, "pfdoa", False, None)
    u = parse_url("mqtts://robot@10.0.0.2:8884/site/fleet-a")
    assert (u.host, u.port, u.prefix, u.tls, u.user) == ("10.0.0.2", 8884, "site/fleet-a", True, "robot")
    assert parse_url("mqtts://h").port == 8883 and parse_url("mqtts://h").prefix == "pfdoa"
    assert parse_url("mqtt://[::1]:1884/p/").host == "::1" and parse_url("mqtt://[::1]:1884/p/").prefix == "p"
    assert parse_url("mqtt://us%40er@h/p").user == "us@er"
    assert str(parse_url("mqtt://u@h:1/p")) == "mqtt://u@h:1/p"


@pytest.mark.parametrize("url, problem", [
    ("http://h/p", "unknown scheme"),
    ("h:1883/p", "unknown scheme"),
    ("mqtt://u:secret@h/p", "a password does not belong in the URL"),
    ("mqtt:///p", "no host"),
    ("mqtt://h:99999/p", "out of range"),
    ("mqtt://h:abc/p", "Port could not be cast"),
    ("mqtt://h:0/p", "port 0"),
    ("mqtt://h/p/+/x", "wildcard"),
    ("mqtt://h/p/#", "wildcard"),
    ("mqtt://h/a//b", "empty level"),
    ("mqtt://h/p?x=1", "query"),
    ("mqtt://h/$SYS/x", "starts with '$'"),  # the broker's own topics: a publish there is dropped
    ("mqtt://h/%24SYS", "starts with '$'"),  # also spelt with a percent escape
    ("mqtt://h/p/%2B", "wildcard"),
])
def test_bad_urls_are_one_line_naming_the_option(url, problem):
    with pytest.raises(InputError) as e:
        parse_url(url)
    msg = str(e.value)
    assert msg.startswith("--mqtt ") and problem in msg and "\n" not in msg
    assert "secret" not in msg  # a password typed into the URL is not repeated
    assert e.value.exit_code == 2


def test_password_from_file_first_line_or_environment(tmp_path, caplog):
    f = tmp_path / "pw"
    f.write_bytes(b"p\xc3\xa4ss word\r\nsecond line\n")
    os.chmod(f, 0o600)
    assert read_password(str(f), {PASSWORD_ENV: "from-env"}) == "päss word"  # the file wins
    assert not [r for r in caplog.records if "readable by other users" in r.getMessage()]
    os.chmod(f, 0o644)
    assert read_password(str(f), {}) == "päss word"
    assert any("readable by other users" in r.getMessage() for r in caplog.records)
    assert read_password(None, {PASSWORD_ENV: "from-env"}) == "from-env"
    assert read_password(None, {}) is None
    assert read_password(None, {PASSWORD_ENV: ""}) is None


@pytest.mark.parametrize("content, problem", [(b"\n", "first line is empty"), (b"\xff\xfe\n", "not UTF-8")])
def test_bad_password_files(tmp_path, content, problem):
    f = tmp_path / "pw"
    f.write_bytes(content)
    with pytest.raises(InputError, match=problem):
        read_password(str(f), {})
    with pytest.raises(InputError, match="cannot read"):
        read_password(str(tmp_path / "missing"), {})


def test_settings_from_table_and_command_line(tmp_path):
    f = tmp_path / "pw"
    f.write_text("pw\n")
    sections = {"mqtt": {"url": "mqtt://fleet@file-host/a", "queue_size": 50, "node_id": "robot-1",
                         "inputs": ["espresense", "frames", "espresense"]}}
    s = mqtt_settings(sections, "site.toml", password_file=str(f), environ={})
    assert (s.client.url.host, s.client.password, s.client.queue_size) == ("file-host", "pw", 50)
    assert s.publisher.node_id == "robot-1" and s.table.inputs == ("espresense", "frames")
    assert s.frames_topic == "a/anchors/+/frames"
    s = mqtt_settings(sections, "site.toml", url="mqtts://fleet@cli-host/b", ca_file="/etc/ca.pem",
                      environ={PASSWORD_ENV: "env-pw"})
    assert (s.client.url.host, s.client.url.prefix, s.client.ca_file, s.client.password) == \
        ("cli-host", "b", "/etc/ca.pem", "env-pw")
    assert mqtt_settings({}, "site.toml", environ={}) is None  # no broker anywhere: MQTT off


def test_settings_refuse_a_password_without_user_and_a_ca_file_without_tls():
    with pytest.raises(InputError, match="names no user"):
        mqtt_settings({}, url="mqtt://h/p", environ={PASSWORD_ENV: "pw"})
    with pytest.raises(InputError, match="only used with mqtts"):
        mqtt_settings({}, url="mqtt://h/p", ca_file="ca.pem", environ={})


@pytest.mark.parametrize("table, key, problem", [
    ({"bogus": 1}, "mqtt.bogus", "unknown key"),
    ({"queue_size": 0}, "mqtt.queue_size", "must be in"),
    ({"queue_size": 1.5}, "mqtt.queue_size", "must be an integer"),
    ({"discovery": 1}, "mqtt.discovery", "true or false"),
    ({"node_id": 3}, "mqtt.node_id", "must be a string"),
    ({"reconnect_min_s": float("nan")}, "mqtt.reconnect_min_s", "finite"),
    ({"reconnect_min_s": 5.0, "reconnect_max_s": 1.0}, "mqtt.reconnect_max_s", ">="),
    ({"inputs": ["serial"]}, "mqtt.inputs", "unknown input"),
    ({"inputs": "frames"}, "mqtt.inputs", "list of strings"),
    ({"frames_topic": "a/#/b"}, "mqtt.frames_topic", "whole last level"),
    ({"frames_topic": "a/x+/b"}, "mqtt.frames_topic", "whole level"),
    ({"discovery_prefix": "home/+"}, "mqtt.discovery_prefix", "wildcard"),
    ({"discovery_prefix": "$SYS/ha"}, "mqtt.discovery_prefix", "starts with '$'"),
    ({"frames_topic": "$SYS/+/frames"}, "mqtt.frames_topic", "starts with '$'"),
])
def test_bad_mqtt_table(table, key, problem):
    with pytest.raises(ConfigError) as e:
        mqtt_table({"mqtt": table}, "site.toml")
    assert e.value.key == key and problem in e.value.problem
    assert str(e.value).startswith(f"site.toml: {key}: ") and e.value.exit_code == 2


def test_topic_filters():
    for ok in ("a/+/frames", "a/#", "#", "+", "a/b"):
        assert check_topic_filter(ok) == ok
    for bad in ("", "a#", "a/#/b", "a+/b", "a/\x00"):
        with pytest.raises(ValueError):
            check_topic_filter(bad)


def test_espresense_table():
    cfg = espresense_config({"espresense": {"rooms": {"kitchen": 1, "living_room": 2}, "devices": ["iBeacon:*"],
                                            "time_field": "t"}}, "s.toml", (1, 2, 3), -59.0)
    assert dict(cfg.rooms) == {"kitchen": 1, "living_room": 2} and cfg.devices == ("iBeacon:*",)
    assert cfg.topic_filter == "espresense/devices/+/+" and cfg.normalize_1m and cfg.rssi_at_1m_dbm == -59.0


@pytest.mark.parametrize("table, key, problem", [
    (None, "espresense", "missing table"),
    ({"rooms": {}}, "espresense.rooms", "non-empty"),
    ({"rooms": {"kitchen": "3"}}, "espresense.rooms.kitchen", "anchor id"),
    ({"rooms": {"kitchen": 9}}, "espresense.rooms.kitchen", "not in the site"),
    ({"rooms": {"kitchen": 1, "hall": 1}}, "espresense.rooms.hall", "another room"),
    ({"rooms": {"a/b": 1}}, "espresense.rooms.a/b", "one topic level"),
    ({"rooms": {"k": 1}, "extra": 1}, "espresense.extra", "unknown key"),
    ({"rooms": {"k": 1}, "devices": "x"}, "espresense.devices", "list"),
    ({"rooms": {"k": 1}, "topic_prefix": "a/#"}, "espresense.topic_prefix", "wildcard"),
    ({"rooms": {"k": 1}, "topic_prefix": "$SYS"}, "espresense.topic_prefix", "starts with '$'"),
    ({"rooms": {"k": 1}, "normalize_1m": "yes"}, "espresense.normalize_1m", "true or false"),
])
def test_bad_espresense_table(table, key, problem):
    sections = {} if table is None else {"espresense": table}
    with pytest.raises(ConfigError) as e:
        espresense_config(sections, "s.toml", (1, 2, 3), -59.0)
    assert e.value.key == key and problem in e.value.problem


def test_beacons_table():
    assert beacons_config({}) == BeaconsConfig()
    assert beacons_config({"beacons": {"max_beacons": 20, "idle_timeout_s": 5}}) == BeaconsConfig(20, 5.0)
    for table, key in (({"max_beacons": 0}, "beacons.max_beacons"), ({"max_beacons": 2.0}, "beacons.max_beacons"),
                       ({"idle_timeout_s": True}, "beacons.idle_timeout_s"), ({"x": 1}, "beacons.x")):
        with pytest.raises(ConfigError) as e:
            beacons_config({"beacons": table}, "s.toml")
        assert e.value.key == key


def test_a_missing_ca_file_is_an_input_error(tmp_path):
    from pfdoa.mqtt.client import ClientConfig, MqttClient

    with pytest.raises(InputError, match="--mqtt-ca-file .*missing.pem"):
        MqttClient(ClientConfig(parse_url("mqtts://h/p"), ca_file=str(tmp_path / "missing.pem")))


def test_a_topic_that_is_not_utf8_is_counted_as_unexpected_not_a_handler_error():
    """MQTT forbids non-UTF-8 topics and mosquitto refuses them, but a broker that passed one
    on must not reach a handler: paho cannot decode it, matches it to no subscription and
    hands it to the client's catch-all, which counts it (`unexpected`)."""
    import paho.mqtt.client as paho

    from pfdoa.mqtt.client import ClientConfig, MqttClient

    client = MqttClient(ClientConfig(parse_url("mqtt://localhost/p")))
    seen = []
    client.subscribe("espresense/#", lambda topic, payload, t: seen.append(topic))
    for raw in (b"espresense/devices/\xff\xfe/room", b"espresense/devices/tag/room"):
        msg = paho.MQTTMessage(topic=raw)
        msg.payload = b"{}"
        client._paho._handle_on_message(msg)
    assert seen == ["espresense/devices/tag/room"]
    assert client.stats.unexpected == 1 and client.stats.handler_errors == 0 and client.stats.received == 1
