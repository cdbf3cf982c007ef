"""``pfdoa gateway --mqtt-input espresense``: the real gateway process on a real mosquitto
(started by the test, tests/conftest.py), ESPresense nodes of the fleet simulator publishing
several beacons in simulated time; hostile messages among them; the demo's Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mqtt_support import Recorder, wait_for

pytestmark = pytest.mark.io

PY = sys.executable


def hostile(sc) -> list[tuple[str, bytes]]:
    """Messages a home's broker carries besides good readings: each rejected by its kind."""
    b = sc.beacons[0]
    room = next(iter(sc.rooms))
    dev = f"espresense/devices/{b}"
    return [
        (f"{dev}/{room}", b"{" + b" " * 3000 + b"}"),  # oversized (> 2048 bytes)
        (f"{dev}/{room}", b"{not json"),  # bad_json
        (f"{dev}/{room}", b"\xff\xfe\x00"),  # bad_json (not UTF-8)
        (f"{dev}/{room}", b"[1, 2]"),  # bad_json (not an object)
        (f"{dev}/{room}", b'{"rssi": "loud", "t": 1.0}'),  # bad_rssi
        (f"{dev}/{room}", b'{"rssi": NaN, "t": 1.0}'),  # bad_rssi
        (f"{dev}/{room}", b'{"rssi": -60.0, "rssi@1m": true, "t": 1.0}'),  # bad_rssi_1m
        (f"{dev}/{room}", b'{"rssi": -60.0}'),  # bad_time (the site's time_field is "t")
        (f"{dev}/cellar", b'{"rssi": -60.0, "t": 1.0}'),  # unknown_room
        (f"espresense/devices/{'x' * 200}/{room}", b'{"rssi": -60.0, "t": 1.0}'),  # bad_device
    ]


def test_espresense_devices_tracked_by_the_gateway_process_through_the_broker(broker, tmp_path):
    from pfdoa.mqtt.publisher import topic_level
    from pfdoasim.fleet import FLEET_WINDOW_S, GATEWAY_PREFIX, FleetConfig, FleetScenario, run_fleet, run_gateway_fleet

    cfg = FleetConfig(n_beacons=3, duration_s=12.0, seed=2)
    sc = FleetScenario(cfg)
    bad = hostile(sc)
    r = run_gateway_fleet(cfg, tmp_path / "gw", broker=broker, warmup_s=4.0, extra=tuple(bad))
    c = r.counters
    good = 3 * 8 * 120  # every node reports every beacon 10 times a second
    assert c["messages"] == good + len(bad)
    inp = c["input"]
    assert inp["messages"] == good + len(bad) and inp["accepted"] == good and inp["queue_drops"] == 0, inp
    assert inp["rejected"] == {"oversized": 1, "bad_json": 3, "bad_rssi": 2, "bad_rssi_1m": 1, "bad_time": 1,
                               "unknown_room": 1, "bad_device": 1}, inp
    assert inp["unknown_rooms"] == {"cellar": 1}
    # One estimator per device: about one estimate per window and device, each on its topic,
    # the same records on the gateway's standard output and on the broker.
    per_beacon = int(12 / FLEET_WINDOW_S)
    assert c["tracker"]["created"] == 3 and c["tracker"]["evicted"] == 0 and c["tracker"]["readings"] == good
    assert c["estimates"] == c["poses"] == c["output_lines"] >= 3 * (per_beacon - 1) and c["estimator_errors"] == 0
    assert c["same_on_stdout"] and c["published_all"] and c["queue_drops"] == 0
    assert c["pose_topics"] == {b: f"{GATEWAY_PREFIX}/{topic_level(b)}/pose" for b in sc.beacons}
    for beacon, v in r.per_beacon.items():  # against the simulator's truth
        assert v["n"] >= per_beacon * (12 - 4) / 12 - 2 and v["mean_m"] < 0.6, (beacon, v)
    # Retained: each room's anchor status, each device's state, the health with the input.
    late = Recorder(broker, f"{GATEWAY_PREFIX}/#")
    wait_for(lambda: len([t for t, _p, _r in late.messages if t.startswith(f"{GATEWAY_PREFIX}/anchors/")]) == 8,
             what="the eight anchors' status")
    status = {json.loads(p)["anchor"]: json.loads(p) for t, p, _r in late.messages
              if t.startswith(f"{GATEWAY_PREFIX}/anchors/")}
    # Each room's accepted readings (the rejected messages are not among them).
    assert {a: (s["room"], s["readings"]) for a, s in status.items()} == {
        aid: (room, 3 * 120) for room, aid in sc.rooms.items()}
    assert all(s["received"] == 360 and s["last_t"] <= 12.0 for s in status.values())
    states = {t: p for t, p, _r in late.messages if t.endswith("/state")}
    assert states == {f"{GATEWAY_PREFIX}/{topic_level(b)}/state": b"home" for b in sc.beacons}
    health = json.loads(late.on(f"{GATEWAY_PREFIX}/health")[-1])
    assert health["inputs"]["espresense"]["accepted"] == good and health["estimates"] == c["estimates"]
    late.close()
    # The same chain in one process gives the same estimates: the process, the broker and
    # the machine's speed change nothing (timers on the messages' time).
    assert run_fleet(cfg, tmp_path / "ip", broker=broker, warmup_s=4.0).per_beacon == r.per_beacon


def test_espresense_input_mistakes_are_one_line_and_exit_2(site_file, tmp_path):
    url = ["--mqtt", "mqtt://127.0.0.1:1/x"]
    esp = "[espresense]\nrooms = { kitchen = 0, hall = 1 }\n"
    cases = [
        ("", ["--mqtt-input", "espresense"], "espresense"),  # no [espresense] table
        ("[mqtt]\ninputs = [\"espresense\"]\n", [], "espresense"),  # [mqtt] inputs is read: the same
        ("[espresense]\nrooms = { kitchen = 9 }\n", ["--mqtt-input", "espresense"], "espresense.rooms.kitchen"),
        ("[espresense]\nrooms = { kitchen = 0 }\ncolour = 1\n", ["--stdin"], "espresense.colour"),  # always checked
        (esp + "time_field = \"t\"\n", ["--mqtt-input", "espresense", "--stdin"], "espresense.time_field"),
        (esp, ["--mqtt-input", "espresense", "--capture", str(tmp_path / "c.cap")], "--capture"),
        (esp, ["--mqtt-input", "espresense", "--replay-capture", "-"], "--mqtt-input"),
    ]
    for i, (extra, args, needle) in enumerate(cases):
        site = site_file(extra, name=f"s{i}.toml")
        r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), *url, *args],
                           input=b"", capture_output=True, timeout=60)
        lines = r.stderr.decode().strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and needle in lines[0], (extra, args, r.stderr.decode())
        if needle.startswith("espresense"):
            assert str(site) in lines[0]  # the site file is named with the key


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def test_the_fleet_demo_stops_gateway_and_broker_on_ctrl_c(tmp_path):
    """SIGINT (Ctrl-C) to the demo while it runs: it exits 130 and neither the gateway nor
    the broker it started is left running."""
    proc = subprocess.Popen([PY, "-m", "pfdoasim.fleet", "--beacons", "2", "--duration", "600", "--seeds", "1",
                             "--workdir", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    gw_pid = broker_pid = 0
    try:
        assert proc.stderr is not None
        line = ""
        deadline = time.monotonic() + 120
        while "gateway pid" not in line and time.monotonic() < deadline:
            line = proc.stderr.readline()
            assert line or proc.poll() is None, "the demo ended before starting the gateway"
        words = line.split()
        gw_pid, broker_pid = int(words[words.index("gateway") + 2].rstrip(",")), int(words[-1])
        assert _alive(gw_pid) and _alive(broker_pid)
        wait_for(lambda: (tmp_path / "gateway-1.jsonl").exists() and (tmp_path / "gateway-1.jsonl").stat().st_size > 0,
                 timeout_s=120, what="the first estimates")
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGUSR1)  # the demo dumps every thread's stack, then goes
            time.sleep(2.0)
            proc.kill()
            _out, err = proc.communicate()
            raise AssertionError(f"the demo did not stop within 120 s of SIGINT; its threads:\n{err[-6000:]}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.returncode != 130:
            # Killed, the demo cannot stop what it started (both in sessions of their own):
            # a failing run must not leave a gateway and a broker behind on the CI machine.
            for pid in (gw_pid, broker_pid):
                if pid and _alive(pid):
                    os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted" in err
    wait_for(lambda: not _alive(gw_pid) and not _alive(broker_pid), timeout_s=10, what="no leftover processes")


class _NamedRun:
    """The ``pfdoa gateway --mqtt-input espresense`` process on message time (``wcl`` unless
    told, seed 1), a recorder of its health on the broker, and a publisher of noise-free ESPresense
    readings from the test feed's anchors: ``publish`` sends a round, ``finish`` waits until the
    gateway has read every message, stops it with SIGINT and returns its stdout."""

    def __init__(self, broker, site, tmp_path, method: str = "wcl") -> None:
        import numpy as np
        import paho.mqtt.client as paho

        import gateway_feed as feed

        self.broker, self.err, self.stats = broker, tmp_path / "err", tmp_path / "s.json"
        self.out = tmp_path / "out.jsonl"  # a file: a pipe nobody reads until the end would fill and stop it
        self.feed, self.anchors = feed, np.array(list(feed.ANCHORS.values()))
        self.health = Recorder(broker, "pfdoa/health")
        self.proc = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--method", method,
                                      "--seed", "1", "--mqtt", broker.url(), "--mqtt-input", "espresense",
                                      "--stats", str(self.stats), "--out", str(self.out)],
                                     stdout=subprocess.DEVNULL, stderr=self.err.open("wb"))
        self.pub = paho.Client(paho.CallbackAPIVersion.VERSION2)
        self.sent = 0

    def records(self) -> list[dict]:
        return [json.loads(p) for p in self.health.on("pfdoa/health")]

    def esp(self) -> dict:
        last = self.records()[-1:]
        return last[0].get("inputs", {}).get("espresense", {}) if last else {}

    def start(self) -> None:
        wait_for(lambda: self.esp().get("subscribed") is True, timeout_s=60, what="the gateway's subscription")
        self.pub.connect("127.0.0.1", self.broker.port)
        self.pub.loop_start()

    def publish(self, dev: str, pos, t0: float) -> None:
        """One reading per anchor of ``dev`` at ``pos``, anchor a at ``t0 + 0.01 a``."""
        import numpy as np

        from pfdoa.radio import PathLoss, mean_rssi

        for a, r in zip(self.feed.ANCHORS, mean_rssi(np.asarray(pos, dtype=float), self.anchors,
                                                      PathLoss(*self.feed.RADIO))):
            doc = {"rssi": round(float(r), 2), "t": round(t0 + 0.01 * a, 4)}
            self.pub.publish(f"espresense/devices/{dev}/r{a}", json.dumps(doc), qos=1)
            self.sent += 1

    def processed(self) -> bool:
        """Every message sent has arrived and reached the tracker: none waits in the input's
        inbox or the gateway's queue, where a stop would take it without running the timers."""
        last = self.records()[-1:]
        if not last:
            return False
        esp = last[0].get("inputs", {}).get("espresense", {})
        return (esp.get("messages") == self.sent and esp.get("pending") == 0
                and last[0].get("named_beacons", {}).get("readings") == esp.get("accepted"))

    def finish(self) -> list[dict]:
        wait_for(self.processed, timeout_s=60, what="every message read and taken by the tracker")
        self.proc.send_signal(signal.SIGINT)
        self.proc.communicate(timeout=60)
        assert self.proc.returncode == 130, self.err.read_text()[-2000:]  # stopped by SIGINT, outputs whole
        return [json.loads(ln) for ln in self.out.read_text().splitlines()]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.pub.loop_stop()


def test_a_silent_device_is_let_go_and_turns_not_home(broker, site_file, tmp_path):
    """[beacons] idle_timeout_s through the process, on message time: a device that stops
    reporting is let go (its last window estimated first) and its state turns not_home."""
    site = site_file("[gateway]\nwindow_s = 0.1\nhealth_interval_s = 0.2\n[beacons]\nidle_timeout_s = 3.0\n"
                     "[mqtt]\ndiscovery = false\n[espresense]\nrooms = { r0 = 0, r1 = 1, r2 = 2, r3 = 3 }\n"
                     "normalize_1m = false\ntime_field = \"t\"\n")
    run = _NamedRun(broker, site, tmp_path)
    try:
        run.start()
        for k in range(100):  # 10 s; "quiet" stops after 2 s
            for dev, pos, until in (("busy", (1.0, 1.0), 100), ("quiet", (3.0, 3.0), 20)):
                if k < until:
                    run.publish(dev, pos, 0.1 * k)
        recs = run.finish()
    finally:
        run.close()
    assert {r["beacon"] for r in recs} == {"busy", "quiet"}
    assert len([r for r in recs if r["beacon"] == "quiet"]) == 20  # its last window too
    named = json.loads(run.stats.read_text())["named_beacons"]
    assert named["timed_out"] == 1 and named["tracked"] == 1 and set(named["beacons"]) == {"busy"}
    run.health.close()
    states = Recorder(broker, "pfdoa/+/state")
    wait_for(lambda: len(states.messages) == 2, what="the retained states")
    assert dict((t, p) for t, p, _r in states.messages) == {"pfdoa/busy/state": b"home",
                                                            "pfdoa/quiet/state": b"not_home"}
    states.close()


def test_named_beacon_readings_recorded_by_the_process_replay_to_its_estimates(broker, tmp_path):
    """``--readings-out`` and ``--record`` of an ESPresense run through the real process
    carry each reading's device id; ``pfdoa replay`` of either tracks every device with its
    own estimator (seeded as the gateway seeds it) and writes exactly the live records."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from pfdoa.trace import read_trace
    from pfdoasim.fleet import FleetConfig, FleetScenario, run_gateway_fleet

    cfg = FleetConfig(n_beacons=3, duration_s=6.0, seed=3)
    sc = FleetScenario(cfg)
    work = tmp_path / "gw"
    trace, rec = tmp_path / "trace.csv", tmp_path / "run.mcap"
    r = run_gateway_fleet(cfg, work, broker=broker, warmup_s=2.0,
                          gateway_args=("--readings-out", str(trace), "--record", str(rec)))
    good = 3 * 8 * 60
    assert r.counters["input"]["accepted"] == good and r.counters["tracker"]["created"] == 3
    live = [json.loads(ln) for ln in (work / "gateway-3.jsonl").read_text().splitlines()]
    assert len(live) == r.counters["estimates"] > 3 * 15 and {x["beacon"] for x in live} == set(sc.beacons)

    # The trace, read by the trace reader: every accepted reading with its device id.
    tr = read_trace(trace)
    assert len(tr) == good and tr.beacon is not None and tr.seq is None
    assert {b: int((tr.beacon == b).sum()) for b in sc.beacons} == {b: 8 * 60 for b in sc.beacons}
    # The recording, decoded by mcap-ros2-support's reader: the same readings, named.
    with open(rec, "rb") as fh:
        got = [(m.beacon, m.anchor_id, m.rssi_dbm, m.t) for _s, ch, _m, m in
               make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/pfdoa/readings"])]
    assert got == list(zip(tr.beacon.tolist(), tr.anchor.tolist(), tr.rssi_dbm.tolist(), tr.t.tolist()))

    site = work / "gateway-3.toml"
    for name, args in (("trace", [str(trace), "--config", str(site), "--method", "pf-doa", "--seed", "3"]),
                       ("mcap", [str(rec)])):
        out, stats = tmp_path / f"{name}.jsonl", tmp_path / f"{name}.stats.json"
        p = subprocess.run([PY, "-m", "pfdoa", "replay", *args, "--out", str(out), "--stats", str(stats)],
                           capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, (name, p.stderr[-2000:])
        again = [json.loads(ln) for ln in out.read_text().splitlines()]
        assert again == live, name  # every field of every record, in the gateway's order
        named = json.loads(stats.read_text())["named_beacons"]
        assert named["created"] == 3 and named["readings"] == good and named["records"] == len(live), name


def test_devices_beyond_max_beacons_evict_the_least_recently_heard(broker, site_file, tmp_path):
    """``[beacons] max_beacons = 2`` through the process, on message time, with six devices
    reporting in turn (two at a time, each for 2 s): each new device evicts the one heard
    least recently (its last window estimated first); the tracker never holds more than 2
    (every health record on the broker), the evictions are in the health record and the
    final counters, and the evicted devices turn not_home."""
    site = site_file("[gateway]\nwindow_s = 0.1\nhealth_interval_s = 0.2\n[beacons]\nmax_beacons = 2\n"
                     "idle_timeout_s = 600.0\n[mqtt]\ndiscovery = false\n"
                     "[espresense]\nrooms = { r0 = 0, r1 = 1, r2 = 2, r3 = 3 }\nnormalize_1m = false\n"
                     "time_field = \"t\"\n")
    run = _NamedRun(broker, site, tmp_path)
    records = run.records
    devices = [f"dev{i}" for i in range(6)]
    try:
        run.start()
        for k in range(70):  # 7 s: dev<i> reports during [i, i + 2) s
            for i, dev in enumerate(devices):
                if 10 * i <= k < 10 * i + 20:
                    run.publish(dev, (1.0 + 0.3 * i, 1.0 + 0.2 * i), 0.1 * k + 0.001 * i)
        recs = run.finish()
    finally:
        run.close()
    per = {d: sum(r["beacon"] == d for r in recs) for d in devices}
    assert per == {d: 20 for d in devices}, per  # every window of every device, the evicted ones' last too
    named = json.loads(run.stats.read_text())["named_beacons"]
    assert named["created"] == 6 and named["evicted"] == 4 and named["timed_out"] == 0, named
    assert named["tracked"] == 2 and named["peak"] == 2 and set(named["beacons"]) == {"dev4", "dev5"}
    # Every health record: never more than 2 tracked; the evictions counted as they happened.
    wait_for(lambda: records()[-1].get("named_beacons", {}).get("evicted") == 4, what="the last health record")
    seen = [r["named_beacons"] for r in records() if "named_beacons" in r]
    assert seen and max(s["tracked"] for s in seen) <= 2 and seen[-1]["peak"] == 2 and seen[-1]["created"] == 6
    evicted = [s["evicted"] for s in seen]
    assert evicted == sorted(evicted) and evicted[-1] == 4
    # The totals do not go back when a beacon leaves (its grouper's counts are kept).
    sets = [r["sets"] for r in records()]
    assert sets == sorted(sets) and sets[-1] == len(recs) and min(r["sets_per_s"] for r in records()) >= 0.0
    run.health.close()
    states = Recorder(broker, "pfdoa/+/state")
    wait_for(lambda: len(states.messages) == 6, what="the retained states")
    assert dict((t, p) for t, p, _r in states.messages) == {
        f"pfdoa/{d}/state": b"home" if d in ("dev4", "dev5") else b"not_home" for d in devices}
    states.close()


def test_home_assistant_gets_each_device_s_room_and_confidence(broker, tmp_path):
    """The fleet simulator in the example home (examples/espresense/site.toml: six rooms)
    through the real gateway process on a real mosquitto: Home Assistant's discovery holds
    the companion's shape (a device tracker whose state is the room, the pose with x, y, room,
    floor and confidence as its attributes, a confidence sensor in %), the retained state of
    each device is the room of its last pose, and the rooms are the ones the beacons were in."""
    from pfdoa.mqtt.publisher import topic_level
    from pfdoa.rooms import site_plan
    from pfdoa.site import load_site
    from pfdoasim.fleet import GATEWAY_PREFIX, FleetConfig, FleetScenario, run_gateway_fleet

    example = str(Path(__file__).resolve().parents[2] / "examples" / "espresense" / "site.toml")
    cfg = FleetConfig(n_beacons=3, duration_s=12.0, seed=4, site_file=example)
    sc = FleetScenario(cfg)
    plan = site_plan(load_site(example))
    ha = Recorder(broker, "homeassistant/#")
    out = Recorder(broker, f"{GATEWAY_PREFIX}/#")
    try:
        r = run_gateway_fleet(cfg, tmp_path, broker=broker, warmup_s=3.0)
        made = r.counters["estimates"]
        wait_for(lambda: len(out.poses()) >= made, what=f"{made} poses")
        configs = {t: json.loads(p) for t, p, _r in ha.messages if p}
        poses = [json.loads(p) for p in out.poses()]
        states = {t: p for t, p, _r in out.messages if t.endswith("/state")}
    finally:
        ha.close()
        out.close()
    assert poses and len({(p["beacon"], p["t"]) for p in poses}) == made
    for b in sc.beacons:
        obj = next(t.split("/")[3] for t, c in configs.items() if "/device_tracker/" in t and c["device"]["name"] == b)
        tracker = configs[f"homeassistant/device_tracker/fleet-demo/{obj}/config"]
        pose_topic = f"{GATEWAY_PREFIX}/{topic_level(b)}/pose"
        assert tracker["state_topic"] == f"{GATEWAY_PREFIX}/{topic_level(b)}/state"
        assert tracker["json_attributes_topic"] == pose_topic
        conf = configs[f"homeassistant/sensor/fleet-demo/{obj}_confidence/config"]
        assert (conf["state_topic"], conf["value_template"], conf["unit_of_measurement"]) == (
            pose_topic, "{{ value_json.confidence }}", "%")
        mine = [p for p in poses if p["beacon"] == b]
        last = max(mine, key=lambda p: p["t"])
        assert states[tracker["state_topic"]] == (last["room"] or "home").encode()
    rooms = {room.name: room for room in plan.rooms}
    right = scored = 0
    for p in poses:
        assert p["floor"] is None and p["floor_p"] is None  # one floor: none declared
        if p["room"] is None:
            assert p["room_p"] is None and "confidence" not in p
            continue
        assert rooms[p["room"]].contains(np.array([[p["x"], p["y"]]]))[0]
        assert 0.0 <= p["room_p"] <= 1.0 and p["confidence"] == round(100 * p["room_p"])
        x, y = sc.truth(p["beacon"], p["t"])
        truth = [n for n, room in rooms.items() if room.contains(np.array([[x, y]]))[0]]
        (x0, y0), (x1, y1) = rooms[truth[0]].polygon[0], rooms[truth[0]].polygon[2]
        if p["t"] >= 3.0 and min(x - x0, x1 - x, y - y0, y1 - y) > 0.5:
            scored += 1
            right += p["room"] == truth[0]
    print(f"rooms right: {right}/{scored}")
    assert scored > 30 and right >= 0.9 * scored


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError(f"no VmRSS for {pid}")


def test_a_flood_of_60000_device_ids_keeps_memory_bounded_and_every_estimate_of_the_tracked_devices_delivered(
        broker, site_file, tmp_path):
    """60,000 ESPresense device ids heard once each (a busy street, a forged burst) among
    three real devices, through the real gateway process (pf-doa, message time) on a real
    mosquitto, fed by one paho client at QoS 0 as fast as it goes. The gateway's RSS never
    exceeds 1.2 x its idle RSS plus max_beacons x the documented per-device bound; the
    three devices keep their places (the new ids make room for each other) and every one
    of their estimates reaches a subscriber on the broker (counted there by paho); the
    counters reconcile exactly: messages = accepted + rejected, offered - processed = lost,
    every id that came and went counted."""
    import threading

    import numpy as np

    from pfdoa.gateway.beacons import MAX_BEACON_BYTES
    from pfdoa.radio import PathLoss, mean_rssi

    import gateway_feed as feed

    max_beacons, n_junk, per_round = 8, 60_000, 100
    site = site_file(f"[gateway]\nwindow_s = 0.1\nhealth_interval_s = 0.2\n[beacons]\nmax_beacons = {max_beacons}\n"
                     "[mqtt]\ndiscovery = false\n[espresense]\nrooms = { r0 = 0, r1 = 1, r2 = 2, r3 = 3 }\n"
                     "normalize_1m = false\ntime_field = \"t\"\n")
    real = {"robot": (1.0, 1.0), "cart": (3.0, 1.2), "badge": (2.0, 3.0)}
    anchors = np.array(list(feed.ANCHORS.values()))
    rssi = {d: mean_rssi(np.asarray(p), anchors, PathLoss(*feed.RADIO)) for d, p in real.items()}
    poses = Recorder(broker, "pfdoa/+/pose")
    run = _NamedRun(broker, site, tmp_path, method="pf-doa")
    peak = [0.0]
    sampling = threading.Event()

    def sample() -> None:
        while not sampling.is_set():
            try:
                peak[0] = max(peak[0], _rss_mib(run.proc.pid))
            except (OSError, AssertionError):
                return
            sampling.wait(0.02)

    sampler = threading.Thread(target=sample, daemon=True)
    try:
        run.start()
        idle = _rss_mib(run.proc.pid)
        sampler.start()
        pub = run.pub
        rounds = 0
        for i in range(n_junk):
            t = 0.001 * i
            if i % per_round == 0:  # one round of every real device from every room, 0.1 s of message time
                for d, r in rssi.items():
                    for a in range(4):
                        pub.publish(f"espresense/devices/{d}/r{a}", json.dumps({"rssi": round(float(r[a]), 2),
                                                                                "t": t + 0.0001 * a}), qos=0)
                        run.sent += 1
                rounds += 1
            pub.publish(f"espresense/devices/junk-{i:05d}/r{i % 4}", json.dumps({"rssi": -75.0, "t": t + 0.0005}),
                        qos=0)
            run.sent += 1
        recs = run.finish()
    finally:
        sampling.set()
        run.close()
    sampler.join(5)
    bound = 1.2 * idle + max_beacons * MAX_BEACON_BYTES / 2**20
    print(f"flood RSS: idle {idle:.1f} MiB, peak {peak[0]:.1f} MiB, bound {bound:.1f} MiB")
    assert peak[0] <= bound, (idle, peak[0], bound)
    s = json.loads(run.stats.read_text())
    inp, named = s["inputs"]["mqtt-espresense"], s["named_beacons"]
    sent_real = rounds * 3 * 4
    assert inp["messages"] == run.sent == n_junk + sent_real and inp["rejected"] == {}, inp
    assert inp["offered"] == inp["accepted"] + inp["queue_drops"] == inp["messages"] - sum(inp["rejected"].values())
    # What the gateway could not keep up with is lost in the input's inbox, counted by the reading.
    assert inp["offered"] - named["readings"] == inp["lost"] == inp["queue_drops"] + inp["unread"], (inp, named)
    # Every id counted: the three devices created once and never let go, each junk id that
    # got through created, then let go unestimated for a newer one (the last few still tracked).
    assert named["evicted"] == 0 and named["peak"] == max_beacons and set(real) <= set(named["beacons"])
    assert named["created"] - named["dropped_new"] - named["timed_out"] == named["tracked"] == max_beacons
    junk_read = named["readings"] - sum(named["beacons"][d]["readings"] for d in real)  # one per junk id
    assert named["created"] == 3 + junk_read and named["dropped_readings"] == named["dropped_new"], named
    per_device = {d: [r for r in recs if r["beacon"] == d] for d in real}
    for d, mine in per_device.items():
        assert len(mine) == named["beacons"][d]["records"] > 0, (d, len(mine), rounds)
    # Every estimate of the real devices on the broker (QoS 1 poses; a duplicate allowed).
    want = {(r["beacon"], r["t"]) for mine in per_device.values() for r in mine}
    wait_for(lambda: want <= {(p["beacon"], p["t"]) for p in map(json.loads, poses.poses())}, timeout_s=60,
             what="every estimate of the tracked devices on the broker")
    poses.close()
    print(f"flood: {inp['messages']} messages, {inp['lost']} readings lost (counted), "
          f"{sum(map(len, per_device.values()))} estimates of the tracked devices, all on the broker")
    mqtt = s["mqtt"]
    assert mqtt["queue_dropped"] == 0 and mqtt["undelivered"] == 0 and mqtt["estimates"] == len(recs), mqtt


def test_implausible_message_times_are_refused_per_device_and_move_nothing(broker, site_file, tmp_path):
    """Message time (``time_field``) through the process: device "a" sends one message
    stamped 9e10, device "b" one an hour ahead and one 13 s in the past. Each is refused
    and counted against its device (final counters and the health on the broker); nothing
    else changes: no device times out, and the estimates are exactly those of the same
    run without the three messages."""

    def run_once(sub: str, bad: bool) -> tuple[list[dict], dict, _NamedRun]:
        site = site_file("[gateway]\nwindow_s = 0.1\nhealth_interval_s = 0.2\n[beacons]\nidle_timeout_s = 3.0\n"
                         "[mqtt]\ndiscovery = false\n[espresense]\nrooms = { r0 = 0, r1 = 1, r2 = 2, r3 = 3 }\n"
                         "normalize_1m = false\ntime_field = \"t\"\n", name=f"{sub}.toml")
        (tmp_path / sub).mkdir()
        run = _NamedRun(broker, site, tmp_path / sub)
        try:
            run.start()
            for k in range(150):  # 15 s of two devices
                run.publish("a", (1.0, 1.0), 0.1 * k)
                run.publish("b", (3.0, 2.5), 0.1 * k + 0.001)
                if bad and k in (10, 60, 140):
                    dev, t = {10: ("a", 9e10), 60: ("b", 0.1 * k + 3600.0), 140: ("b", 0.1 * k - 13.0)}[k]
                    run.pub.publish(f"espresense/devices/{dev}/r2", json.dumps({"rssi": -60.0, "t": t}), qos=1)
                    run.sent += 1
            recs = run.finish()
        finally:
            run.close()
        return recs, json.loads(run.stats.read_text())["named_beacons"], run

    clean, _, clean_run = run_once("clean", False)
    clean_run.health.close()
    recs, named, run = run_once("bad", True)
    assert recs == clean and len(recs) >= 2 * 148  # every window of both devices, as without them
    assert named["time_ahead"] == 2 and named["time_behind"] == 1 and named["timed_out"] == 0, named
    assert named["beacons"]["a"]["refused"] == 1 and named["beacons"]["b"]["refused"] == 2
    assert named["message_clock"]["resets"] == 0 and named["message_clock"]["now"] < 15.0
    last = run.records()[-1]["named_beacons"]
    assert last["bad_time_by_beacon"] == {"b": 2, "a": 1} and (last["time_ahead"], last["time_behind"]) == (2, 1)
    run.health.close()
