"""``pfdoa gateway --mqtt``: the real gateway process publishing to a real mosquitto (started
by the test, tests/conftest.py): estimates round trip as the JSON output lines, Home
Assistant discovery, health and anchor status, and a broker restart mid-run with every
estimate made before, during and after the outage delivered once the broker is back."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

import gateway_feed as feed
from mqtt_support import Recorder, wait_for

pytestmark = pytest.mark.io

PY = sys.executable
T0 = 1_700_000_000.0


def timed_rows(seqs) -> bytes:
    """Capture lines (the timed stream of --replay-capture -) of the feed's beacons ``seqs``."""
    from pfdoa.gateway.inputs.capture import capture_line
    from pfdoa.gateway.transports import Chunk
    from pfdoa.protocol.uart import encode_uart

    return "".join(capture_line(Chunk("serial0", T0 + 0.02 * seq, encode_uart(m, a)))
                   for seq in seqs for a, m in feed.reports(seq)).encode()


def header() -> bytes:
    from pfdoa.gateway.inputs.capture import CAPTURE_V1

    return (CAPTURE_V1 + "\n").encode()


def final_counters(err: str) -> dict:
    lines = [ln for ln in err.splitlines() if ln.startswith("pfdoa: final ")]
    assert lines, err[-2000:]
    return json.loads(lines[-1][len("pfdoa: final "):])


def lines_of(path: Path) -> list[dict]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    return [json.loads(ln) for ln in text.splitlines() if ln.endswith("}")]


def test_gateway_publishes_every_estimate_health_anchors_and_discovery(broker, site_file):
    site = site_file("[gateway]\nhealth_interval_s = 0.5\n[mqtt]\nnode_id = \"robot7\"\n")
    poses = Recorder(broker, "site7/#")
    ha = Recorder(broker, "homeassistant/#")
    r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", "-",
                        "--method", "wcl", "--seed", "1", "--mqtt", broker.url("site7")],
                       input=header() + timed_rows(range(100)), capture_output=True, timeout=120)
    err = r.stderr.decode()
    assert r.returncode == 0, err[-2000:]
    out = [json.loads(ln) for ln in r.stdout.splitlines()]
    assert len(out) == 100 and {o["beacon"] for o in out} == {"b0"}
    c = final_counters(err)["mqtt"]
    assert c["estimates"] == 100 and c["undelivered"] == 0 and c["queue_dropped"] == 0 and c["connects"] >= 1, c
    wait_for(lambda: len(poses.on("site7/b0/pose")) >= 100, what="100 poses")
    # Every pose is the JSON output line itself (same fields, same values), in order.
    assert [json.loads(p) for p in poses.on("site7/b0/pose")] == out
    assert poses.on("site7/b0/state")[-1] == b"home"
    wait_for(lambda: poses.on("site7/status")[-1:] == [b"offline"], what="offline on a clean stop")
    health = [json.loads(p) for p in poses.on("site7/health")]
    # The MQTT counters ride in each health record as they stood when it was made: on a busy
    # machine the last one can be made (and queued) before the first connection completes.
    assert health and health[-1]["estimates"] == 100 and {"connects", "delivered", "sent"} <= set(health[-1]["mqtt"])
    anchors = {t.split("/")[2] for t, _p, _r in poses.messages if t.startswith("site7/anchors/")}
    assert anchors == {"0", "1", "2", "3"}
    a0 = json.loads(poses.on("site7/anchors/0/status")[-1])
    assert a0["anchor"] == 0 and a0["received"] == 100 and a0["level"] == "OK"
    # Discovery: retained configs for the gateway and the beacon, pointing at those topics.
    wait_for(lambda: any(t.startswith("homeassistant/device_tracker/") for t, _p, _r in ha.messages),
             what="device_tracker discovery")
    cfgs = {t: json.loads(p) for t, p, _r in ha.messages}
    tracker = next(v for t, v in cfgs.items() if t.startswith("homeassistant/device_tracker/robot7/"))
    assert tracker["json_attributes_topic"] == "site7/b0/pose"
    assert tracker["state_topic"] == "site7/b0/state"
    assert tracker["availability_topic"] == "site7/status"
    sensors = [t for t in cfgs if t.startswith("homeassistant/sensor/robot7/")]
    assert len(sensors) >= 4, sensors  # x, y, sigma of the beacon and the gateway's own
    poses.close()
    ha.close()
    # A late subscriber gets the retained state at once, and no pose (poses are not retained).
    late = Recorder(broker, "site7/#")
    wait_for(lambda: late.on("site7/b0/state") == [b"home"], what="retained state")
    time.sleep(0.3)  # nothing retained on a pose topic may arrive within this
    assert late.on("site7/b0/pose") == []
    late.close()


def test_bad_mqtt_options_are_one_line_and_exit_2(site_file, tmp_path):
    site = site_file()
    for args, needle in ((["--mqtt", "http://127.0.0.1/x"], "--mqtt"),
                         (["--mqtt", "mqtt://u:pw@127.0.0.1/x"], "--mqtt"),
                         (["--mqtt", "mqtt://127.0.0.1/x", "--mqtt-ca-file", str(tmp_path / "ca.pem")],
                          "--mqtt-ca-file"),
                         (["--mqtt", "mqtt://u@127.0.0.1/x", "--mqtt-password-file", str(tmp_path / "none")],
                          "--mqtt-password-file"),
                         # A broker's own topics ($SYS/...): a publish there is dropped, yet counted delivered.
                         (["--mqtt", "mqtt://127.0.0.1/$SYS/x"], "starts with '$'"),
                         (["--mqtt", "mqtt://127.0.0.1/x/+"], "wildcard")):
        r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", "-", *args],
                           input=b"", capture_output=True, timeout=60)
        lines = r.stderr.decode().strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and needle in lines[0], (args, r.stderr.decode())
    bad = site_file("[mqtt]\nqueue_size = 0\n", name="bad.toml")
    r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(bad), "--replay-capture", "-",
                        "--mqtt", "mqtt://127.0.0.1/x"], input=b"", capture_output=True, timeout=60)
    assert r.returncode == 2 and "mqtt.queue_size" in r.stderr.decode(), r.stderr.decode()
    unknown = site_file("[mqtt]\ninputs = [\"zigbee\"]\n", name="inputs.toml")
    r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(unknown), "--replay-capture", "-",
                        "--mqtt", "mqtt://127.0.0.1/x"], input=b"", capture_output=True, timeout=60)
    assert r.returncode == 2 and "mqtt.inputs" in r.stderr.decode(), r.stderr.decode()
    # Every topic the gateway builds from the site file: the same refusal, naming the key.
    for i, (extra, key) in enumerate((("[mqtt]\ndiscovery_prefix = \"$SYS/ha\"\n", "mqtt.discovery_prefix"),
                                      ("[mqtt]\nurl = \"mqtt://127.0.0.1/$SYS\"\n", "mqtt.url"),
                                      ("[mqtt]\nframes_topic = \"$share/+/frames\"\n", "mqtt.frames_topic"),
                                      ("[espresense]\nrooms = { k = 0 }\ntopic_prefix = \"$SYS\"\n",
                                       "espresense.topic_prefix"))):
        bad = site_file(extra, name=f"dollar{i}.toml")
        r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(bad), "--replay-capture", "-"]
                           + ([] if "url" in key else ["--mqtt", "mqtt://127.0.0.1/x"]),
                           input=b"", capture_output=True, timeout=60)
        lines = r.stderr.decode().strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and key in lines[0] and "'$'" in lines[0], (extra, lines)


def test_broker_restart_mid_run_every_estimate_is_delivered(persistent_broker, site_file, tmp_path):
    """Through the real process: a third of the run with the broker up, a third with it
    stopped (the gateway keeps estimating, the estimates wait in its outbox), a third after
    it is back on the same port. A persistent QoS 1 subscriber (the broker keeps its
    session) then has exactly the (beacon, t) of every estimate written to --out."""
    b = persistent_broker
    N = 64  # beacons a third: 256 capture lines, whole batches of the capture reader (64 lines)
    site = site_file("[gateway]\nhealth_interval_s = 0\n[mqtt]\nreconnect_min_s = 0.1\nreconnect_max_s = 0.5\n"
                     "discovery = false\n")
    rec = Recorder(b, "fleet/#", client_id="restart-recorder", clean_session=False)
    out = tmp_path / "out.jsonl"
    proc = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", "-",
                             "--method", "wcl", "--seed", "1", "--out", str(out), "--mqtt", b.url("fleet")],
                            stdin=subprocess.PIPE, stderr=(tmp_path / "err").open("wb"))
    assert proc.stdin is not None
    try:
        proc.stdin.write(header() + timed_rows(range(0, N)))
        proc.stdin.flush()
        wait_for(lambda: len(lines_of(out)) == N and len(rec.poses()) >= N, what="first third")
        b.stop()
        proc.stdin.write(timed_rows(range(N, 2 * N)))
        proc.stdin.flush()
        wait_for(lambda: len(lines_of(out)) == 2 * N, what="estimates while the broker is away")
        during = len(rec.poses())
        b.start()
        proc.stdin.write(timed_rows(range(2 * N, 3 * N)))
        proc.stdin.close()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = (tmp_path / "err").read_text()
    assert proc.returncode == 0, err[-2000:]
    made = {(o["beacon"], o["t"]) for o in lines_of(out)}
    assert len(made) == 3 * N
    wait_for(lambda: {(json.loads(p)["beacon"], json.loads(p)["t"]) for p in rec.poses()} >= made,
             what="every estimate after the restart")
    got = [json.loads(p) for p in rec.poses()]
    assert {(g["beacon"], g["t"]) for g in got} == made
    c = final_counters(err)["mqtt"]
    assert c["estimates"] == 3 * N and c["queue_dropped"] == 0 and c["undelivered"] == 0, c
    assert c["connects"] >= 2 and c["disconnects"] >= 1, c
    assert during == N  # nothing arrived while the broker was down
    print(f"restart: {3 * N} estimates, {N} made while the broker was down, {len(got) - 3 * N} duplicates (QoS 1)")
    rec.close()


def test_our_frames_over_mqtt_into_the_gateway_process(broker, site_file):
    """--mqtt-input frames: each anchor publishes its UART bytes on its own topic (frames split
    across messages, line noise, an oversized message); the real gateway decodes them like
    serial ports, estimates and publishes; the rejections are in the final counters."""
    import signal
    import threading

    import paho.mqtt.client as paho

    from pfdoa.protocol.uart import encode_uart

    site = site_file("[gateway]\nhealth_interval_s = 0\n[mqtt]\ndiscovery = false\n")
    poses = Recorder(broker, "pfdoa/+/pose")
    proc = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--method", "wcl", "--seed", "1",
                             "--mqtt", broker.url(), "--mqtt-input", "frames"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2)
    pub.connect("127.0.0.1", broker.port)
    pub.loop_start()
    stop = threading.Event()

    def anchors() -> None:  # until the test has its estimates: the gateway subscribes when it is up
        seq = 0
        while not stop.is_set():
            for a, m in feed.reports(seq):
                data = encode_uart(m, a)
                topic = f"pfdoa/anchors/a{a}/frames"
                if a == 1:  # a frame split over two messages is joined by the topic's decoder
                    pub.publish(topic, data[:5], qos=1)
                    pub.publish(topic, data[5:], qos=1)
                else:
                    pub.publish(topic, (b"\x17noise\x00" if seq % 10 == 0 else b"") + data, qos=1)
            if seq % 25 == 0:
                pub.publish("pfdoa/anchors/a0/frames", b"\x00" * 5000, qos=1)  # oversized: rejected
            seq += 1
            stop.wait(0.02)

    th = threading.Thread(target=anchors, daemon=True)
    th.start()
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if len(lines) >= 40:
                break
        stop.set()
        th.join(5)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        stop.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        pub.loop_stop()
        pub.disconnect()
    assert proc.returncode == 143, err[-2000:]  # stopped by SIGTERM, after its final counters
    recs = [json.loads(ln) for ln in lines]
    assert len(recs) == 40
    assert all(r["anchors"] == [0, 1, 2, 3] and r["missing"] == [] for r in recs[2:]), recs[:3]  # the first may have started mid-set
    c = final_counters(err)
    frames = c["inputs"]["mqtt-frames"]
    assert frames["rejected"].get("oversized", 0) >= 1 and frames["accepted"] > 0, frames
    assert sum(c["errors"].values()) >= 1, c["errors"]  # the noise, counted by the decoder
    wait_for(lambda: len(poses.poses()) >= 40, what="the poses on the broker")
    assert [json.loads(p) for p in poses.poses()[:40]] == recs
    poses.close()


def test_junk_on_64_frames_topics_never_locks_the_real_anchors_out(broker, site_file, tmp_path):
    """One junk message on each of 64 frames topics fills the gateway's decoder table; then
    the four real anchors publish: each takes the place of a topic that never sent a valid
    frame (counted and said), and their beacons are estimated and published as if the junk
    had not been there."""
    import signal

    import paho.mqtt.client as paho

    from pfdoa.protocol.uart import encode_uart

    site = site_file("[gateway]\nhealth_interval_s = 0.2\n[mqtt]\ndiscovery = false\n")
    health = Recorder(broker, "pfdoa/health")
    poses = Recorder(broker, "pfdoa/+/pose")
    err, out = tmp_path / "err", tmp_path / "out.jsonl"
    proc = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--method", "wcl", "--seed", "1",
                             "--mqtt", broker.url(), "--mqtt-input", "frames", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=err.open("wb"))
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2)

    def frames_input() -> dict:
        last = health.on("pfdoa/health")[-1:]
        return json.loads(last[0]).get("inputs", {}).get("frames", {}) if last else {}

    try:
        wait_for(lambda: frames_input().get("subscribed") is True, timeout_s=60, what="the subscription")
        pub.connect("127.0.0.1", broker.port)
        pub.loop_start()
        for i in range(64):
            pub.publish(f"pfdoa/anchors/junk{i}/frames", b"\x13\x37 not a frame", qos=1)
        wait_for(lambda: frames_input().get("messages") == 64, what="the junk read")
        for seq in range(30):
            for a, m in feed.reports(seq):
                pub.publish(f"pfdoa/anchors/a{a}/frames", encode_uart(m, a), qos=1)
        wait_for(lambda: frames_input().get("messages") == 64 + 120 and frames_input().get("pending") == 0,
                 what="every frame read")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        pub.loop_stop()
        health.close()
    text = err.read_text()
    assert proc.returncode == 130, text[-2000:]  # stopped by SIGINT, its outputs whole
    c = final_counters(text)
    assert c["sources_evicted"] == 4 and c["sources_dropped"] == 0 and c["reports"] == 120, c
    assert text.count("let go for it (it never sent a valid frame; sources_evicted)") == 4
    recs = lines_of(out)
    assert len(recs) == c["estimates"] == 30 and all(r["anchors"] == [0, 1, 2, 3] for r in recs)
    wait_for(lambda: len(poses.poses()) == 30, what="the poses on the broker")
    poses.close()


def _replay_with(site, url: str, *extra: str, env: dict | None = None):
    import os

    return subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", "-",
                           "--method", "wcl", "--seed", "1", "--mqtt", url, *extra],
                          input=header() + timed_rows(range(20)), capture_output=True, timeout=120,
                          env={**os.environ, **(env or {})})


def test_password_from_a_file_or_the_environment_through_the_process(password_broker, site_file, tmp_path):
    from pfdoa.mqtt.url import PASSWORD_ENV

    b = password_broker
    site = site_file("[mqtt]\ndiscovery = false\n")
    pw = tmp_path / "pw"
    pw.write_text("s3cret-pw\n")
    pw.chmod(0o600)
    for extra, env in ((("--mqtt-password-file", str(pw)), {PASSWORD_ENV: "wrong"}),  # the file wins
                       ((), {PASSWORD_ENV: "s3cret-pw"})):
        r = _replay_with(site, b.url("pfdoa", user="fleet"), *extra, env=env)
        assert r.returncode == 0, r.stderr.decode()[-2000:]
        c = final_counters(r.stderr.decode())["mqtt"]
        assert c["connects"] >= 1 and c["refused"] == 0 and c["estimates"] == 20 and c["undelivered"] == 0, c
        assert "s3cret" not in r.stderr.decode()  # the password is never logged


def test_credentials_the_broker_refuses_end_the_run_with_exit_2(password_broker, site_file, tmp_path):
    """A wrong password or no user at all: the broker's refusal cannot change by retrying,
    so the live gateway (standard input kept open: it would run for ever) stops by itself
    with the final counters and one error line naming --mqtt and the broker's reason, exit
    status 2; the broker saw one connection attempt."""
    from pfdoa.mqtt.url import PASSWORD_ENV

    b = password_broker
    site = site_file("[mqtt]\ndiscovery = false\nreconnect_min_s = 0.05\nreconnect_max_s = 0.1\n")
    for label, url, env in (("wrong password", b.url("pfdoa", user="fleet"), {PASSWORD_ENV: "wrong"}),
                            ("anonymous", b.url("pfdoa"), {})):
        before = b.log_tail(100_000).count("not authorised")
        err = tmp_path / f"{label}.err"
        with err.open("wb") as fh:
            p = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--stdin", "--method", "wcl",
                                  "--seed", "1", "--mqtt", url], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                 stderr=fh, env={**__import__("os").environ, **env})
        try:
            p.wait(timeout=60)  # standard input stays open: only the refusal ends the run
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
            assert p.stdin is not None
            p.stdin.close()
        text = err.read_text()
        errors = [ln for ln in text.splitlines() if "ERROR" in ln or ln.startswith("pfdoa: error")]
        assert p.returncode == 2, (label, text[-2000:])
        assert len(errors) == 1 and errors[0].startswith("pfdoa: error: --mqtt mqtt://"), (label, errors)
        assert "refused the connection: Not authorized" in errors[0], (label, errors)
        assert text.splitlines()[-1] == errors[0]  # the last line, after the final counters
        c = final_counters(text)["mqtt"]
        assert c["refused"] == 1 and c["connects"] == 0, (label, c)
        # One attempt, not retried (the process has ended: none can follow; the broker's log may lag).
        wait_for(lambda: b.log_tail(100_000).count("not authorised") >= before + 1,  # noqa: B023 (called here)
                 what=f"{label}: the broker's line")
        assert b.log_tail(100_000).count("not authorised") == before + 1, label


def test_a_broker_that_is_down_is_waited_for_and_then_used(site_file, tmp_path):
    """The gateway starts before its broker: one line says it cannot connect and retries
    (not an error: the run goes on); once the broker is up every estimate reaches it."""
    from pfdoasim.fleet import Mosquitto, free_port

    port = free_port()
    site = site_file("[mqtt]\ndiscovery = false\nreconnect_min_s = 0.05\nreconnect_max_s = 0.2\n")
    err = tmp_path / "err"
    with err.open("wb") as fh:
        p = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--stdin", "--method", "wcl",
                              "--seed", "1", "--mqtt", f"mqtt://127.0.0.1:{port}/pfdoa"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=fh)
    b = None
    try:
        wait_for(lambda: "cannot connect" in err.read_text(), timeout_s=60, what="the gateway's first attempt")
        b = Mosquitto(tmp_path / "broker", port=port).start()
        poses = Recorder(b, "pfdoa/+/pose")
        from pfdoa.protocol.uart import encode_uart

        out, _ = p.communicate(b"".join(encode_uart(m, a) for seq in range(20) for a, m in feed.reports(seq)),
                               timeout=120)
        assert p.returncode == 0, err.read_text()[-2000:]
        wait_for(lambda: len(poses.poses()) == 20, what="every estimate on the broker")
        poses.close()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        if b is not None:
            b.stop()
    text = err.read_text()
    assert text.count("cannot connect") == 1 and "ERROR" not in text and "pfdoa: error" not in text, text[-2000:]
    c = final_counters(text)["mqtt"]
    assert c["connect_failures"] >= 1 and c["connects"] >= 1 and c["estimates"] == 20 and c["undelivered"] == 0, c


def test_mqtts_with_a_ca_file_through_the_process(tls_broker, site_file):
    b = tls_broker
    site = site_file("[mqtt]\ndiscovery = false\n")
    r = _replay_with(site, b.url("pfdoa"), "--mqtt-ca-file", b.tls.cafile)
    assert r.returncode == 0, r.stderr.decode()[-2000:]
    c = final_counters(r.stderr.decode())["mqtt"]
    assert c["connects"] >= 1 and c["estimates"] == 20 and c["undelivered"] == 0, c
