"""The robot outputs from a SIL run: the simulator (real firmware core per anchor, link
faults, transport jitter) drives `pfdoa gateway` (a separate process) in virtual time with
--record, --health-json, --readings-out and --capture.

* the recording is decoded by the ecosystem's reader (mcap + mcap_ros2's DecoderFactory):
  every message, the poses equal the JSON output, every covariance is symmetric positive
  definite; `pfdoa replay RUN.mcap` writes the live output again, byte for byte;
* the health JSON records carry the numbers of the health lines printed beside them;
* the readings trace is the recording's readings and is read by `pfdoa replay`, and (with
  ground truth added by --ground-truth) by `pfdoa calibrate` and `pfdoa eval`.

One 20 s run (about a second of CPU) is shared by the tests; everything compared is a
function of the stream, except the health rates (wall-clock periods), which are compared
with their own lines, never with a bound.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pfdoa.sinks import ros
from pfdoa.sinks.mcap import open_recording
from pfdoa.site import load_site
from pfdoa.trace import read_trace

pytestmark = pytest.mark.sil

SEED = 3
FAULTS = "loss=0.02,dup=0.01,reorder=0.01,jitter=20"


def pfdoa(*args, timeout=300) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "pfdoa", "-q", *args], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("robot-sil")
    pfdoa("sim", "--scenario", "demo", "--gateway", "--odom", "--duration", "20", "--seed", str(SEED),
          "--faults", FAULTS, "--out-dir", str(d),
          f"--gateway-arg=--record={d / 'run.mcap'}", f"--gateway-arg=--health-json={d / 'health.jsonl'}",
          f"--gateway-arg=--readings-out={d / 'live.csv'}", f"--gateway-arg=--capture={d / 'run.cap'}",
          "--gateway-arg=--health=0.2")
    return d


def json_lines(path: Path) -> list[dict]:
    return [json.loads(s) for s in path.read_text().splitlines()]


def decoded(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=False):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    return out


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_every_message_decodes_and_the_poses_are_the_json_output(run):
    msgs = decoded(run / "run.mcap")
    est = json_lines(run / "gateway.jsonl")
    stats = json.loads((run / "gateway.stats.json").read_text())
    assert {t: {m[0] for m in v} for t, v in msgs.items()} == {
        "/pfdoa/pose": {ros.POSE_TYPE}, "/pfdoa/readings": {ros.READING_TYPE},
        "/pfdoa/odometry": {ros.ODOMETRY_TYPE}, "/pfdoa/odom": {ros.NAV_ODOMETRY_TYPE}, "/pfdoa/timer": {ros.TIMER_TYPE},
        "/diagnostics": {ros.DIAGNOSTICS_TYPE}, "/pfdoa/anchors": {ros.MARKERS_TYPE},
    }
    assert len(est) == stats["estimates"] > 150
    assert len(msgs["/pfdoa/readings"]) == stats["readings"]
    assert len(msgs["/pfdoa/odometry"]) == len(msgs["/pfdoa/odom"]) == stats["odometry"]["lines"]
    poses = msgs["/pfdoa/pose"]
    assert len(poses) == len(est)
    for rec, (_, log_time, m) in zip(est, poses):
        assert m.header.frame_id == rec["frame_id"] == "map"
        assert stamp_ns(m.header) == log_time
        assert round(log_time * 1e-9, 6) == rec["t"]  # the JSON time has microseconds
        p = m.pose.pose
        assert (round(p.position.x, 4), round(p.position.y, 4), p.position.z) == (rec["x"], rec["y"], 0.0)
        c = np.array(m.pose.covariance).reshape(6, 6)
        assert [round(c[0, 0], 6), round(c[0, 1], 6), round(c[1, 1], 6)] == rec["cov"]
        assert np.array_equal(c, c.T) and np.linalg.eigvalsh(c).min() > 0.0
        np.linalg.cholesky(c)
        q = p.orientation
        if rec.get("heading") is not None:  # filters that track a heading (with odometry)
            assert 2.0 * math.atan2(q.z, q.w) == pytest.approx(rec["heading"], abs=1e-4)
            assert round(c[5, 5], 6) == rec["heading_var"]  # the JSON value has 6 decimals, like cov
        else:
            assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0) and c[5, 5] == ros.UNKNOWN_VARIANCE
        assert rec["stamp"] >= rec["t"]  # made after the beacon event it estimates
    site = load_site(run / "site.toml")
    first = msgs["/pfdoa/anchors"][0][2]
    assert sorted((mk.id, mk.pose.position.x, mk.pose.position.y) for mk in first.markers if mk.ns == ros.ANCHOR_NS) \
        == sorted((a.id, a.x, a.y) for a in site.anchors)
    last = msgs["/diagnostics"][-1][2]
    assert [s.name for s in last.status] == ["pfdoa: gateway"] + [f"pfdoa: anchor {a}" for a in site.anchor_ids]
    for s in last.status[1:]:  # the final diagnostics are the final counters
        kv = {v.key: v.value for v in s.values}
        a = stats["anchors"][s.name.rsplit(" ", 1)[1]]
        assert (int(kv["received"]), int(kv["lost"]), int(kv["duplicates"])) == \
            (a["received"], a["lost"], a["duplicates"])


def test_replaying_the_recording_writes_the_live_output_again(run, tmp_path):
    rec = open_recording(run / "run.mcap")
    assert rec.metadata["seed"] == str(SEED) and rec.metadata["method"] == "pf-doa"
    assert rec.metadata["odometry"] == "stream" and rec.metadata["mode"] == "seq"
    assert rec.site_toml == (run / "site.toml").read_text()
    again = tmp_path / "again.jsonl"
    pfdoa("replay", str(run / "run.mcap"), "--out", str(again))  # no --config: the recording's own site
    assert again.read_bytes() == (run / "gateway.jsonl").read_bytes()
    # Another seed gives other estimates: the seed is what the recording's replay used.
    other = tmp_path / "other.jsonl"
    pfdoa("replay", str(run / "run.mcap"), "--seed", str(SEED + 1), "--out", str(other))
    assert other.read_bytes() != again.read_bytes()


def test_a_drawn_seed_is_printed_and_recorded(run, tmp_path):
    """A gateway without --seed (here on the run's capture) draws one, says it, records it."""
    out, mcap = tmp_path / "drawn.jsonl", tmp_path / "drawn.mcap"
    r = pfdoa("gateway", "--config", str(run / "site.toml"), "--replay-capture", str(run / "run.cap"),
              "--out", str(out), "--record", str(mcap), "--health", "0")
    (seed,) = re.findall(r"estimator seed (\d+) \(drawn; --seed \1 repeats this run\)", r.stderr)
    assert open_recording(mcap).metadata["seed"] == seed
    assert json.loads(r.stderr.split("pfdoa: final ", 1)[1].splitlines()[0])["seed"] == int(seed)
    again = tmp_path / "again.jsonl"
    pfdoa("replay", str(mcap), "--out", str(again))
    assert again.read_bytes() == out.read_bytes()


HEALTH_LINE = re.compile(
    r"pfdoa: health: (?P<frames>[\d.]+) frames/s (?P<sets>[\d.]+) sets/s (?P<est>[\d.]+) est/s \| "
    r"errors (?P<errors>.*?) \| loss (?P<loss>.*?) \| stale (?P<stale>.*?) \| open sets (?P<open>\d+)$")


def test_health_json_records_carry_the_health_lines_numbers(run):
    lines = [m for s in (run / "gateway.log").read_text().splitlines() if (m := HEALTH_LINE.match(s))]
    docs = json_lines(run / "health.jsonl")
    assert docs and len(docs) == len(lines)  # one snapshot each: the periods and the final one
    for doc, m in zip(docs, lines):
        # The line shows one decimal of the same numbers the record holds to three.
        for key, group in (("frames_per_s", "frames"), ("sets_per_s", "sets"), ("estimates_per_s", "est")):
            assert abs(doc[key] - float(m[group])) <= 0.05 + 1e-9, (key, doc, m[0])
        errors = dict(kv.split("=") for kv in m["errors"].split()) if m["errors"] != "none" else {}
        assert {k: int(v) for k, v in errors.items()} == doc["errors"]
        loss = dict(kv.split("=") for kv in m["loss"].split())
        assert list(loss) == [f"a{a}" for a in doc["anchors"]]
        for a, h in doc["anchors"].items():
            assert abs(float(loss[f"a{a}"].rstrip("%")) - h["loss_pct"]) <= 0.05 + 1e-9
        assert doc["stale"] == ([] if m["stale"] == "none" else [int(a) for a in m["stale"].split(",")])
        assert doc["open_sets"] == int(m["open"])
    stats = json.loads((run / "gateway.stats.json").read_text())
    final = docs[-1]  # the last snapshot is taken after the last set left
    assert (final["frames"], final["sets"], final["estimates"]) == (stats["frames"], stats["sets"], stats["estimates"])
    assert {a: (h["received"], h["lost"]) for a, h in final["anchors"].items()} == \
        {a: (h["received"], h["lost"]) for a, h in stats["anchors"].items()}


def test_the_readings_trace_is_the_recordings_readings_and_replays(run, tmp_path):
    tr = read_trace(run / "live.csv")
    recorded = list(open_recording(run / "run.mcap").readings())
    assert tr.seq is not None and not tr.has_ground_truth and len(tr) == len(recorded)
    # read_trace sorts by time (receive times of several links interleave); as a multiset:
    got = sorted(zip(tr.t.tolist(), tr.anchor.tolist(), tr.rssi_dbm.tolist(), tr.seq.tolist()))
    assert got == sorted((r.t, r.anchor_id, r.rssi_dbm, r.seq) for r in recorded)  # bit-exact floats
    out = tmp_path / "replayed.jsonl"
    pfdoa("replay", str(run / "live.csv"), "--config", str(run / "site.toml"), "--odom", str(run / "trace.odom.csv"),
          "--seed", str(SEED), "--out", str(out))
    live = {r["seq"]: r for r in json_lines(run / "gateway.jsonl")}
    replayed = json_lines(out)
    assert {r["seq"] for r in replayed} == set(live)  # the same sets (by beacon)
    # Stamped with receive times instead of the anchors' event times: close, not equal.
    err = [math.dist((r["x"], r["y"]), (live[r["seq"]]["x"], live[r["seq"]]["y"])) for r in replayed]
    assert float(np.median(err)) < 0.1


def test_with_ground_truth_the_trace_calibrates_and_evaluates(run, tmp_path):
    """The run's capture replayed with the simulator's ground truth (--ground-truth): the
    same readings, now with gt_x, gt_y; calibrate and eval read it."""
    gt = tmp_path / "gt.csv"
    pfdoa("gateway", "--config", str(run / "site.toml"), "--replay-capture", str(run / "run.cap"), "--seed", "1",
          "--out", str(tmp_path / "est.jsonl"), "--readings-out", str(gt), "--ground-truth", str(run / "trace.csv"),
          "--health", "0")
    tr, live = read_trace(gt), read_trace(run / "live.csv")
    assert tr.t.tolist() == live.t.tolist() and tr.rssi_dbm.tolist() == live.rssi_dbm.tolist()
    assert tr.has_ground_truth
    truth = read_trace(run / "trace.csv")
    known = ~np.isnan(tr.gt_x)
    assert known.mean() > 0.95
    # Interpolated truth stays within the simulated track's span.
    assert truth.gt_x.min() <= tr.gt_x[known].min() and tr.gt_x[known].max() <= truth.gt_x.max()
    fitted = tmp_path / "fitted.toml"
    r = pfdoa("calibrate", str(gt), "--config", str(run / "site.toml"), "--out", str(fitted))
    assert f"{int(known.sum())} readings" in r.stdout
    assert [(a.id, a.x, a.y) for a in load_site(fitted).anchors] == \
        [(a.id, a.x, a.y) for a in load_site(run / "site.toml").anchors]
    report = tmp_path / "report.md"
    pfdoa("eval", "--traces", str(gt), "--config", str(run / "site.toml"), "--calibration", "none", "--seeds", "1",
          "--methods", "wcl", "pf-doa", "--no-progress", "--out", str(report))
    text = report.read_text()
    assert "pf-doa" in text and "wcl" in text and "RMSE" in text
