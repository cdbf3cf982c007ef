"""`pfdoa gateway --ros2` on ROS 2's default middleware: a Fast DDS node on the loopback.

The peer (tests/ros2/ros2_peer.cpp; its types are fastddsgen's code of tests/ros2/ros2_msgs.idl,
written from the .msg definitions, built with Debian's Fast DDS: tests/dds_support.py) stands
for a ROS 2 node: DDS topics rt/..., types pkg::msg::dds_::T_, reliable, keep-last. The
gateway is the real `pfdoa gateway` process reading anchor frames on its standard input
(tests/gateway_feed.py's noise-free reports, one beacon every 20 ms) and publishing through
Cyclone DDS. Both are pinned to the loopback interface on a random domain id.

* poses, diagnostics and the site frame reach the peer with the values the JSON output and the
  recording have;
* the peer's nav_msgs/msg/Odometry drives the gateway's odometry: the estimates are those of
  `pfdoa replay` with the same odometry as a file;
* with no subscriber, a stopped one and a restarted one, every estimate is in --out and the
  health counts published, dropped and matched.

Nothing waits on time: each step waits for what it needs to see (a match, a count in the
health JSON, a line of the peer); the timeouts only bound a hang.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pfdoa.odometry import increments
from pfdoa.protocol.uart import encode_uart
from pfdoa.sinks import ros

import gateway_feed
from dds_support import HANG_S, Peer, free_domain, loopback_env, peer_binary, wait_until

pytestmark = pytest.mark.io

POSE, DIAG, TF = "rt/pfdoa/pose", "rt/diagnostics", "rt/tf_static"


@pytest.fixture(scope="session")
def peer_build():
    """The Fast DDS peer, built once (and cached under build/ros2-peer across sessions)."""
    t0 = time.monotonic()
    exe = peer_binary()
    return {"exe": exe, "seconds_here": time.monotonic() - t0, "build_s": (exe.parent / ".build_s").read_text()}


def frames(seq: int) -> bytes:
    return b"".join(encode_uart(m, a) for a, m in gateway_feed.reports(seq))


class Gateway:
    """`pfdoa gateway --stdin --ros2` with its outputs in ``d``; anchor frames go to its stdin."""

    def __init__(self, d: Path, domain: int, ros2: str = "", *args: str, site: str = "") -> None:
        self.d = d
        self.site = d / "site.toml"
        self.site.write_text(gateway_feed.TEST_SITE + f"\n{site}\n[ros2]\ndomain_id = {domain}\n{ros2}\n")
        self.out, self.health_path, self.rec, self.stats = (d / "out.jsonl", d / "health.jsonl", d / "run.mcap",
                                                            d / "stats.json")
        self.log = open(d / "gateway.log", "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "pfdoa", "gateway", "--config", str(self.site), "--stdin", "--ros2",
             "--out", str(self.out), "--health", "0.1", "--health-json", str(self.health_path),
             "--record", str(self.rec), "--stats", str(self.stats), "--seed", "7", *args],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self.log, env=loopback_env())
        self.seq = 0
        self._stop = threading.Event()
        self._feeder: threading.Thread | None = None

    def health(self) -> list[dict]:
        if not self.health_path.exists():
            return []
        text = self.health_path.read_text()
        return [json.loads(s) for s in text.splitlines()[:None if text.endswith("\n") else -1]]

    def ros2(self) -> dict:
        h = self.health()
        return h[-1].get("outputs", {}).get("ros2", {}) if h else {}

    def counters(self) -> dict:
        """The latest health snapshot's counters that explain a hang."""
        last = (self.health() or [{}])[-1]
        return {k: last[k] for k in ("odometry", "errors", "queue_drops") if k in last} | {"ros2": self.ros2()}

    def wait_ros2(self, what: str, check):
        return wait_until(what, lambda: check(self.ros2()), proc=self.proc, detail=self.counters)

    def feed(self, n: int) -> None:
        """``n`` beacons, one every 20 ms (an anchor's pace)."""
        for _ in range(n):
            self.proc.stdin.write(frames(self.seq))
            self.proc.stdin.flush()
            self.seq += 1
            time.sleep(gateway_feed.PERIOD_S)

    def feed_until_stopped(self) -> None:
        def run():
            while not self._stop.is_set():
                self.feed(1)
        self._feeder = threading.Thread(target=run, daemon=True)
        self._feeder.start()

    def stop_feeding(self) -> None:
        self._stop.set()
        if self._feeder is not None:
            self._feeder.join(timeout=HANG_S)

    def lines(self) -> list[dict]:
        return [json.loads(s) for s in self.out.read_text().splitlines()] if self.out.exists() else []

    def finish(self) -> dict:
        """End of input: the gateway flushes, publishes the rest and exits 0; its final counters."""
        self.stop_feeding()
        self.proc.stdin.close()
        rc = self.proc.wait(timeout=HANG_S)
        self.log.close()
        assert rc == 0, (self.d / "gateway.log").read_text()[-3000:]
        return json.loads(self.stats.read_text())

    def kill(self) -> None:
        self.stop_feeding()
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


@pytest.fixture
def gateways():
    started: list = []
    yield started
    for g in started:
        if isinstance(g, Gateway):
            g.kill()
        else:
            g.stop()


def as_dict(m):
    """A message decoded by mcap_ros2 as the plain dict the peer prints."""
    if isinstance(m, (list, tuple)):
        return [as_dict(x) for x in m]
    slots = getattr(type(m), "__slots__", None)
    if slots:
        return {k: as_dict(getattr(m, k)) for k in slots}
    if hasattr(m, "__dict__"):
        return {k: as_dict(v) for k, v in vars(m).items()}
    return m


def recorded(path: Path, topic: str) -> list[dict]:
    with open(path, "rb") as fh:
        return [as_dict(msg) for _, ch, _, msg in
                make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(log_time_order=False)
                if ch.topic == topic]


def stamp_s(msg: dict) -> float:
    st = msg["header"]["stamp"]
    return ros.stamp_seconds(st["sec"], st["nanosec"])


def test_poses_diagnostics_and_the_site_frame_reach_a_fast_dds_node_with_the_outputs_values(tmp_path, peer_build,
                                                                                             gateways):
    domain = free_domain()
    gw = Gateway(tmp_path, domain, "", "--frame-id", "pfdoa_site", site="[site]\nmap_pose = [1.5, -2.25, 0.3]")
    gateways.append(gw)
    peer = Peer(domain, "sub", f"pose:{POSE}", f"diagnostics:{DIAG}", f"tf:{TF}")
    gateways.append(peer)
    # Matched both ways (the peer's readers, the gateway's pose writer): no pose is lost to discovery.
    peer.wait("the peer's readers matched", lambda p: p.matched(POSE) and p.matched(DIAG) and p.matched(TF))
    gw.wait_ros2("the gateway's pose writer matched", lambda c: c.get("matched", 0) >= 1)
    gw.feed(120)
    stats = gw.finish()

    out = gw.lines()
    poses = peer.wait("every pose", lambda p: len(p.samples(POSE)) >= len(out) and p.samples(POSE))
    assert len(poses) == len(out) == stats["estimates"] >= 100
    assert stats["ros2"]["published"] == len(out) and stats["ros2"]["dropped"] == 0
    # Bit for bit the recording's messages (the same conversion), and the JSON output's values as it rounds them.
    assert poses == recorded(gw.rec, "/pfdoa/pose")
    for m, o in zip(poses, out):
        assert m["header"]["frame_id"] == o["frame_id"] == "pfdoa_site"
        assert round(stamp_s(m), 6) == o["t"]
        p = m["pose"]["pose"]["position"]
        assert (round(p["x"], 4), round(p["y"], 4), p["z"]) == (o["x"], o["y"], 0.0)
        c = m["pose"]["covariance"]
        assert [round(c[0], 6), round(c[1], 6), round(c[7], 6)] == o["cov"] and c[6] == c[1]
        assert c[14] == c[21] == c[28] == ros.UNKNOWN_VARIANCE

    # Every health period the peer saw is the recording's (one snapshot for both), the last one the final counters.
    diags = peer.samples(DIAG)
    by_stamp = {json.dumps(d["header"]["stamp"]): d for d in recorded(gw.rec, "/diagnostics")}
    assert len(diags) >= 3 and all(d == by_stamp[json.dumps(d["header"]["stamp"])] for d in diags)
    gateway_status = {v["key"]: v["value"] for v in diags[-1]["status"][0]["values"]}
    assert int(gateway_status["estimates"]) == stats["estimates"]
    assert int(gateway_status["ros2.published"]) == stats["estimates"]
    assert diags[-1]["status"][0]["message"] in [h for h in (gw.d / "gateway.log").read_text().splitlines()
                                                 if h.startswith("pfdoa: health: ")][-1]

    # The site frame in the map, once, to a subscriber that came after it was sent (transient-local),
    # the transform the recording has (each stamped when it was sent).
    (tf,) = peer.samples(TF)
    ((rt,),) = [m["transforms"] for m in recorded(gw.rec, "/tf_static")]
    (t,) = tf["transforms"]
    assert {**t, "header": None} == {**rt, "header": None} and t["header"]["frame_id"] == rt["header"]["frame_id"]
    assert (t["header"]["frame_id"], t["child_frame_id"]) == ("map", "pfdoa_site")
    assert t["transform"] == {"translation": {"x": 1.5, "y": -2.25, "z": 0.0},
                              "rotation": {"x": 0.0, "y": 0.0, "z": math.sin(0.15), "w": math.cos(0.15)}}


def test_a_fast_dds_odometry_publisher_drives_the_estimates_as_the_same_odometry_file_does(tmp_path, peer_build,
                                                                                           gateways):
    domain = free_domain()
    gw = Gateway(tmp_path, domain, 'odom_reliability = "reliable"')
    gateways.append(gw)
    odom = Peer(domain, "pub-odom", "rt/odom", stdin=subprocess.PIPE)
    gateways.append(odom)
    # Matched both ways: what is sent before the gateway's reader knows the publisher is not
    # for it (a volatile subscription).
    odom.wait("the odometry publisher matched the gateway", lambda p: p.matched("rt/odom"))
    gw.wait_ros2("the gateway's reader matched the publisher", lambda c: c.get("odom_publishers", 0) >= 1)

    # The robot drives a circle of radius 1 m at 0.5 m/s, 25 Hz odometry, from a second ago
    # to 100 s ahead: every set the gateway makes has its motion already.
    t0 = time.time() - 1.0
    k = np.arange(0, 101 * 25)
    ts = np.round((t0 + k * 0.04) * 1e9).astype(np.int64)
    th = 0.5 * k * 0.04
    xs, ys, yaws = np.sin(th), 1.0 - np.cos(th), th
    lines = [f"{n // 10**9} {n % 10**9} {x!r} {y!r} 0.0 0.0 {math.sin(a / 2)!r} {math.cos(a / 2)!r}"
             for n, x, y, a in zip(ts.tolist(), xs.tolist(), ys.tolist(), yaws.tolist())]
    odom.proc.stdin.write("\n".join(lines) + "\n")
    odom.proc.stdin.close()
    assert odom.wait("acknowledged", lambda p: p.event("acked"))["ok"]
    h = wait_until("the gateway's localizer has every increment",
                   lambda: (gw.health() or [{}])[-1].get("odometry", {}).get("lines") == len(lines), proc=gw.proc,
                   detail=gw.counters)
    assert gw.ros2()["odom_lost"] == 0
    gw.feed(120)
    stats = gw.finish()
    assert h and stats["odometry"]["waited"] == stats["odometry"]["gave_up"] == stats["odometry"]["without"] == 0
    assert stats["ros2"]["odom_messages"] == stats["ros2"]["odom_increments"] == len(lines)
    assert stats["queue_drops"] == 0

    # The same odometry as a file: the poses as the gateway reads them (pfdoa.sinks.ros's
    # stamp and yaw), turned into t,dx,dy,dtheta by the file path's own conversion.
    track = np.array([[ros.stamp_seconds(n // 10**9, n % 10**9), x, y,
                       ros.quaternion_yaw(0.0, 0.0, math.sin(a / 2), math.cos(a / 2))]
                      for n, x, y, a in zip(ts.tolist(), xs.tolist(), ys.tolist(), yaws.tolist())])
    inc = increments(track)
    odom_csv = tmp_path / "odom.csv"
    odom_csv.write_text("t,dx,dy,dtheta\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in inc))
    # what the gateway recorded as it received it is that file, increment for increment
    rec_inc = [(m["t"], m["dx"], m["dy"], m["dtheta"]) for m in recorded(gw.rec, "/pfdoa/odometry")]
    assert rec_inc == [tuple(float(v) for v in row) for row in inc]

    replay = tmp_path / "replay.jsonl"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "-q", "replay", str(gw.rec), "--odom", str(odom_csv),
                        "--out", str(replay)], capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr[-3000:]
    out = gw.out.read_text()
    assert out == replay.read_text() and out.count("\n") == stats["estimates"] >= 100
    assert any(json.loads(s)["heading"] is not None for s in out.splitlines())  # the filter used the odometry


def test_every_estimate_is_kept_with_no_subscriber_a_stopped_one_and_a_restarted_one(tmp_path, peer_build, gateways):
    domain = free_domain()
    gw = Gateway(tmp_path, domain)
    gateways.append(gw)
    gw.feed_until_stopped()
    # No subscriber: published all the same, matched 0.
    gw.wait_ros2("estimates published to nobody", lambda c: c.get("published", 0) >= 30 and c["matched"] == 0)

    first = Peer(domain, "sub", f"pose:{POSE}")
    gateways.append(first)
    gw.wait_ros2("the subscriber matched", lambda c: c["matched"] == 1)
    first.wait("poses", lambda p: len(p.samples(POSE)) >= 10)
    # A subscriber that takes nothing (stopped): the gateway goes on; its keep-last history
    # replaces what the subscriber has not acknowledged.
    first.signal(signal.SIGSTOP)
    at_stop = gw.ros2()["published"]
    gw.wait_ros2("estimates while the subscriber is stopped", lambda c: c["published"] >= at_stop + 100)
    first.signal(signal.SIGCONT)
    seen = len(first.samples(POSE))
    first.wait("poses after it went on", lambda p: len(p.samples(POSE)) > seen + 10)
    first.stop()
    gw.wait_ros2("the subscriber left", lambda c: c["matched"] == 0)

    second = Peer(domain, "sub", f"pose:{POSE}")
    gateways.append(second)
    gw.wait_ros2("the restarted subscriber matched", lambda c: c["matched"] == 1)
    second.wait("poses to the restarted subscriber", lambda p: len(p.samples(POSE)) >= 10)
    stats = gw.finish()
    second.stop()

    out = gw.lines()
    assert len(out) == stats["estimates"] == stats["ros2"]["published"] > at_stop + 100
    assert stats["ros2"]["dropped"] == 0
    assert [o["seq"] for o in out] == list(range(len(out)))  # every beacon, in order
    # What each subscriber got are estimates of the recording (and the JSON output), bit for bit, in order.
    recorded_poses = recorded(gw.rec, "/pfdoa/pose")
    assert len(recorded_poses) == len(out)
    for peer in (first, second):
        got = peer.samples(POSE)
        assert len(got) >= 10
        i = 0
        for m in got:
            i = next(k for k in range(i, len(recorded_poses)) if recorded_poses[k] == m) + 1
            assert round(m["pose"]["pose"]["position"]["x"], 4) == out[i - 1]["x"]
    # the health said so while it ran: nothing dropped, the matched count followed the subscribers
    matched = [h["outputs"]["ros2"]["matched"] for h in gw.health()]
    assert {0, 1} <= set(matched) and all(h["outputs"]["ros2"]["dropped"] == 0 for h in gw.health())


def test_ros2_without_cyclonedds_is_one_line_and_exit_2(tmp_path):
    site = tmp_path / "site.toml"
    site.write_text(gateway_feed.TEST_SITE)
    code = ("import sys; sys.modules['cyclonedds'] = None; from pfdoa.cli import main; "
            f"sys.exit(main(['gateway', '--config', {str(site)!r}, '--stdin', '--ros2']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, stdin=subprocess.PIPE)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'pfdoa[ros2]'" in lines[0], r.stderr
    # the same command without --ros2 runs (and ends with its empty input)
    r = subprocess.run([sys.executable, "-c", code.replace(", '--ros2'", "")], capture_output=True, text=True,
                       timeout=60, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr


def test_several_beacons_each_have_a_pose_topic_that_goes_with_the_beacon(monkeypatch, peer_build):
    from pfdoa.output import Record
    from pfdoa.ros2.config import Ros2Settings, name_token
    from pfdoa.sinks.ros2 import Ros2Sink

    monkeypatch.setenv("CYCLONEDDS_URI", loopback_env()["CYCLONEDDS_URI"])
    domain = free_domain()
    sink = Ros2Sink(Ros2Settings(domain_id=domain, namespace="/robot7"), per_beacon=True, default_beacon="b0")
    token = name_token("phone:1")  # an ESPresense device id is no ROS name
    topics = {"b0": "rt/robot7/pfdoa/b0/pose", "kitchen": "rt/robot7/pfdoa/kitchen/pose",
              "phone:1": f"rt/robot7/pfdoa/{token}/pose"}
    peer = Peer(domain, "sub", *(f"pose:{t}" for t in topics.values()))
    try:
        # a record names its beacon; one that names none (a replay's) is the primary's
        for beacon in ("kitchen", "phone:1", None):
            sink.write(Record(t=1.0, x=1.0, y=2.0, beacon=beacon))
        peer.wait("every beacon's topic matched", lambda p: all(p.matched(t) for t in topics.values()))
        wait_until("matched both ways", lambda: sink.health_counters()["matched"] == 3)
        for i, beacon in enumerate(("kitchen", "phone:1", None)):
            sink.write(Record(t=2.0 + i, x=float(i), y=0.5, beacon=beacon))
        for i, b in enumerate(("kitchen", "phone:1", "b0")):
            # (the first records went before the match; one may have reached the subscriber)
            (m,) = peer.wait(f"{b}'s pose", lambda p, b=b: [m for m in p.samples(topics[b]) if stamp_s(m) >= 2.0])
            assert (stamp_s(m), m["pose"]["pose"]["position"]["x"]) == (2.0 + i, float(i))
        # the gateway lets a beacon go: its topic goes, the others stay
        sink.beacon_gone("phone:1", "timed_out")
        peer.wait("the beacon's topic left", lambda p: p.matched(topics["phone:1"]) == 0)
        assert sink.health_counters()["matched"] == 2 and peer.matched(topics["kitchen"]) == 1
        assert sink.health_counters()["published"] == 6
    finally:
        sink.close()
        peer.stop()


HOSTILE_PUBLISHER = r"""
import sys, time
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from pfdoa.ros2.dds import Types, matched
from pfdoa.sinks import ros

domain, env_config = int(sys.argv[1]), sys.argv[2]
# Its own Cyclone DDS, which sends samples of up to 4 MiB.
Domain(domain, env_config + ',<CycloneDDS><Domain id="any"><Internal><MaxSampleSize>4MiB</MaxSampleSize>'
       '</Internal></Domain></CycloneDDS>')
types = Types(ros.LIVE_MSGDEFS)
dp = DomainParticipant(domain)
w = DataWriter(dp, Topic(dp, "rt/odom", types.classes[ros.NAV_ODOMETRY_TYPE]),
               Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll))
while not matched(w):
    time.sleep(0.02)

def odom(sec, nanosec, x, frame=""):
    return types.sample(ros.NAV_ODOMETRY_TYPE, {"header": {"stamp": {"sec": sec, "nanosec": nanosec}},
                        "child_frame_id": frame, "pose": {"pose": {"position": {"x": x}, "orientation": {"w": 1.0}},
                                                          "covariance": [0.0] * 36},
                        "twist": {"covariance": [0.0] * 36}})

w.write(odom(100, 0, float("nan")))              # a non-finite pose
w.write(odom(100, 2_000_000_000, 0.0))            # nanosec out of range
w.write(odom(100, 0, 0.0, frame="x" * 1_000_000)) # a megabyte
for k in range(3):
    w.write(odom(101 + k, 0, 0.5 * k))
w.wait_for_acks(duration(seconds=60))
print("sent", flush=True)
sys.stdin.read()
"""


def test_hostile_odometry_is_counted_and_skipped_and_an_oversized_message_never_read(monkeypatch):
    from pfdoa.ros2.dds import Node, Types
    from pfdoa.sinks.ros2odom import Ros2OdometrySource

    env = loopback_env()
    monkeypatch.setenv("CYCLONEDDS_URI", env["CYCLONEDDS_URI"])
    domain = free_domain()
    node = Node(domain, Types(ros.LIVE_MSGDEFS))
    src = Ros2OdometrySource(node, "/odom", reliable=True)
    src.open()
    pub = subprocess.Popen([sys.executable, "-c", HOSTILE_PUBLISHER, str(domain), env["CYCLONEDDS_URI"]],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        items: list = []
        wait_until("the good odometry", lambda: items.extend(src.read(0.05)) or len(items) >= 3, proc=pub)
        assert [(i.t_odom, i.dx) for i in items] == [(101.0, 0.0), (102.0, 0.5), (103.0, 0.5)]
        c = src.counters()
        assert (c["odom_messages"], c["odom_bad"], c["odom_increments"]) == (5, 2, 3)  # the megabyte never came in
    finally:
        pub.stdin.close()
        pub.wait(timeout=HANG_S)
        src.close()
        node.close()
