"""Sinks: the health snapshot (same numbers as the health line), health JSON lines, the
readings trace writer (read back by pfdoa.trace.read_trace), the fan-out."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from pfdoa.errors import InputError, OutputError
from pfdoa.gateway.health import OK, STALE, WARN
from pfdoa.sinks import SINKS, Fanout, Sink, sink_class
from pfdoa.sinks.base import record_cov
from pfdoa.sinks.healthjson import HealthJsonSink
from pfdoa.sinks.readings import ReadingsCsvSink
from pfdoa.trace import read_trace

from sink_feed import SITE, scripted_run


@pytest.fixture(scope="module")
def run():
    return scripted_run()


def test_snapshot_line_is_the_health_line(run):
    assert len(run.snapshots) == 2
    for snap, line in run.snapshots:
        assert snap.line() == line
    first, last = run.snapshots[0][0], run.snapshots[1][0]
    assert "duplicates=1" in run.snapshots[0][1] and first.errors["duplicates"] == 1
    # 20 beacon periods of 4 anchors in the first 2 s: 80 - 1 lost + 1 duplicate frames.
    assert first.frames_per_s == pytest.approx(80 / 2.0)
    assert last.period_s == pytest.approx(2.0)


def test_snapshot_levels_and_counts(run):
    first, last = run.snapshots[0][0], run.snapshots[1][0]
    assert first.anchors[1].lost == 1 and first.anchors[1].period_lost == 1
    assert {a: h.level for a, h in first.anchors.items()} == {0: OK, 1: OK, 2: OK, 3: OK}
    # Second period: anchor 3 silent (stale), anchor 2 rebooted; anchor 1's loss is old news.
    assert last.anchors[3].stale and last.stale == (3,)
    assert last.anchors[2].reboots == 1 and last.anchors[2].period_reboots == 1
    assert {a: h.level for a, h in last.anchors.items()} == {0: OK, 1: OK, 2: WARN, 3: STALE}
    assert last.anchors[1].period_lost == 0 and last.anchors[1].lost == 1


def test_health_json_lines_carry_the_snapshot(run):
    buf = io.StringIO()
    sink = HealthJsonSink(buf)
    for snap, _ in run.snapshots:
        sink.health(snap)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 2
    docs = [json.loads(s) for s in lines]
    for (snap, line), doc in zip(run.snapshots, docs):
        assert doc["frames_per_s"] == round(snap.frames_per_s, 3)
        assert f"{doc['frames_per_s']:.1f} frames/s" in line
        assert f"{doc['sets_per_s']:.1f} sets/s" in line and f"{doc['estimates_per_s']:.1f} est/s" in line
        assert f"open sets {doc['open_sets']}" in line
        for a, h in doc["anchors"].items():
            assert (f"a{a}={h['loss_pct']:.1f}%" if h["loss_pct"] is not None else f"a{a}=-") in line
        assert doc["errors"] == dict(sorted(snap.errors.items()))
    assert docs[1]["stale"] == [3] and docs[1]["anchors"]["3"]["level"] == "STALE"
    assert docs[1]["anchors"]["2"]["reboots"] == 1 and docs[1]["anchors"]["1"]["lost"] == 1


def test_health_json_to_a_file_flushes_each_line(tmp_path, run):
    path = tmp_path / "health.jsonl"
    sink = HealthJsonSink(str(path))
    sink.health(run.snapshots[0][0])
    assert len(path.read_text().splitlines()) == 1  # readable before close
    sink.close()
    sink.close()
    with pytest.raises(OutputError, match="--health-json .*cannot write"):
        HealthJsonSink(str(tmp_path / "no" / "such" / "dir.jsonl"))


def test_readings_csv_reads_back_as_the_same_trace(tmp_path, run):
    path = tmp_path / "live.csv"
    with ReadingsCsvSink(str(path)) as sink:
        for r in run.readings:
            sink.reading(r)
    tr = read_trace(path)
    assert not tr.has_ground_truth and tr.seq is not None
    assert len(tr) == len(run.readings)
    assert tr.t.tolist() == [r.t for r in run.readings]  # bit-exact times
    assert tr.anchor.tolist() == [r.anchor_id for r in run.readings]
    assert tr.rssi_dbm.tolist() == [r.rssi_dbm for r in run.readings]
    assert tr.seq.tolist() == [r.seq for r in run.readings]
    assert max(tr.seq.tolist()) == 65535 and min(tr.seq.tolist()) == 0  # wrapped as on the wire


def test_readings_csv_ground_truth_only_when_given_and_empty_when_unknown(tmp_path, run):
    path = tmp_path / "sim.csv"
    gt = lambda t: None if t < run.readings[10].t else (t - run.readings[0].t, 2.0)  # noqa: E731
    with ReadingsCsvSink(str(path), ground_truth=gt) as sink:
        for r in run.readings[:20]:
            sink.reading(r)
    tr = read_trace(path)
    assert tr.has_ground_truth
    known = ~np.isnan(tr.gt_x)
    assert known.tolist() == [r.t >= run.readings[10].t for r in run.readings[:20]]
    assert tr.gt_x[known].tolist() == [r.t - run.readings[0].t for r in run.readings[:20] if r.t >= run.readings[10].t]


def test_readings_without_seq_and_an_empty_run(tmp_path):
    from pfdoa.gateway.reassembly import Reading

    path = tmp_path / "window.csv"
    with ReadingsCsvSink(str(path)) as sink:
        sink.reading(Reading(0, -50.5, 1.0))
        sink.reading(Reading(1, -60.0, 1.0, seq=4))  # the file has no seq column: written without
    tr = read_trace(path)
    assert tr.seq is None and tr.anchor.tolist() == [0, 1]
    with ReadingsCsvSink(str(path)) as sink:
        sink.reading(Reading(0, -50.5, 1.0, seq=3))
        sink.reading(Reading(1, -60.0, 1.0))  # no seq in a file with one: skipped, counted
    assert sink.skipped == 1 and read_trace(path).anchor.tolist() == [0]
    empty = tmp_path / "empty.csv"
    ReadingsCsvSink(str(empty)).close()
    assert empty.read_text() == "t,anchor,rssi_dbm,seq\n"
    with pytest.raises(InputError, match="no readings"):
        read_trace(empty)


def test_named_beacon_readings_get_a_beacon_column_read_back_by_the_trace_reader(tmp_path):
    """A named beacon's reading is written with its id (CSV-quoted when it must be); the
    trace reader gives the ids back; what one CSV line cannot hold is skipped, counted."""
    from pfdoa.gateway.reassembly import Reading

    path = tmp_path / "named.csv"
    ids = ["iBeacon:e2c5-1-2", 'name:a, "b"', " edge ", "x" * 128]
    with ReadingsCsvSink(str(path)) as sink:
        for i, b in enumerate(ids):
            sink.reading(Reading(i % 2, -50.0 - i, 0.1 * i), b)
        sink.reading(Reading(0, -70.0, 1.0))  # one of our frames' readings: an empty beacon field
        sink.reading(Reading(1, -71.0, 1.1), "two\nlines")  # cannot be one CSV line: skipped
        sink.reading(Reading(1, -72.0, 1.2, seq=5), "seq-ignored")  # no seq column: written without
    assert sink.count == 6 and sink.skipped == 1
    assert path.read_text().splitlines()[0] == "t,anchor,rssi_dbm,beacon"
    tr = read_trace(path)
    assert tr.beacon is not None and tr.beacon.tolist() == ids + ["", "seq-ignored"]
    assert tr.rssi_dbm.tolist() == [-50.0, -51.0, -52.0, -53.0, -70.0, -72.0] and tr.seq is None
    # A file started by our frames' readings has no beacon column: a named reading is skipped.
    plain = tmp_path / "plain.csv"
    with ReadingsCsvSink(str(plain)) as sink:
        sink.reading(Reading(0, -50.0, 0.0, seq=1))
        sink.reading(Reading(1, -50.0, 0.1), "dev")
    assert sink.skipped == 1 and read_trace(plain).beacon is None


def test_fanout_drops_a_failing_sink_and_keeps_the_others(run):
    class Broken(Sink):
        name = "broken"

        def write(self, record):
            raise OSError(28, "No space left on device")

    class Keep(Sink):
        name = "keep"

        def __init__(self):
            self.got = []

        def write(self, record):
            self.got.append(record)

    keep = Keep()
    fan = Fanout([Broken(), keep])
    for rec in run.records[:3]:
        fan.write(rec)
    assert keep.got == run.records[:3]
    assert fan.failed == {"broken": 1} and len(fan) == 1
    fan.close()
    assert keep.closed


def test_record_cov_falls_back_to_sigma():
    from pfdoa.output import Record

    assert record_cov(Record(t=0.0, x=1.0, y=1.0, sigma=0.2)) == pytest.approx((0.02, 0.0, 0.02))
    assert record_cov(Record(t=0.0, x=1.0, y=1.0, sigma=math.nan)) is None
    assert record_cov(Record(t=0.0, x=1.0, y=1.0)) is None


def test_registry_names_every_sink_module():
    assert set(SINKS) == {"output", "mcap", "web", "health-json", "readings", "mqtt", "ros2"}
    for name in SINKS:
        assert issubclass(sink_class(name), Sink)
    with pytest.raises(ValueError, match="unknown sink"):
        sink_class("nope")


def test_site_fixture_is_valid():
    assert SITE.anchor_ids == (0, 1, 2, 3)
