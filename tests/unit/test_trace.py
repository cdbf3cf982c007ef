"""Trace / odometry readers and time-window grouping."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoa.site import parse_site
from pfdoa.trace import GroupingCounts, group_by_window, read_odometry, read_trace

SITE = parse_site({
    "radio": {"rssi_at_1m_dbm": -40.0, "path_loss_exponent": 2.0},
    "anchors": [{"id": 1, "x": 0.0, "y": 0.0}, {"id": 2, "x": 4.0, "y": 0.0}, {"id": 5, "x": 0.0, "y": 4.0}],
})


def write(tmp_path, text, name="t.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reads_columns_and_ignores_extra(tmp_path):
    p = write(tmp_path, "# comment\nrssi_dbm,extra,anchor,t,gt_x,gt_y,seq\n-50,zz,1,0.5,1.0,2.0,7\n\n-60.5,q,2,0.5,,,8\n")
    tr = read_trace(p)
    assert len(tr) == 2
    assert tr.t.tolist() == [0.5, 0.5]
    assert tr.anchor.tolist() == [1, 2]
    assert tr.rssi_dbm.tolist() == [-50.0, -60.5]
    assert tr.seq.tolist() == [7, 8]
    assert tr.gt_x[0] == 1.0 and math.isnan(tr.gt_x[1])


def test_gzip_and_no_optional_columns(tmp_path):
    p = tmp_path / "t.csv.gz"
    with gzip.open(p, "wt") as fh:
        fh.write("t,anchor,rssi_dbm\n0,1,-40\n1,2,-41\n")
    tr = read_trace(p)
    assert len(tr) == 2 and tr.seq is None and tr.gt_x is None and not tr.has_ground_truth


def test_optional_beacon_column(tmp_path):
    """Named beacons' ids, quoted or not, empty = none; sorting and select keep them with
    their rows; a file without the column has none (old files read as before)."""
    tr = read_trace(write(tmp_path, 't,anchor,rssi_dbm,beacon\n2,1,-1,dev-a\n1,2,-2,"x, ""y"""\n1.5,1,-3,\n'))
    assert tr.t.tolist() == [1, 1.5, 2] and tr.beacon.tolist() == ['x, "y"', "", "dev-a"]
    assert tr.select(tr.anchor == 1).beacon.tolist() == ["", "dev-a"]
    assert read_trace(write(tmp_path, "t,anchor,rssi_dbm\n0,1,-40\n", "old.csv")).beacon is None


def test_unsorted_rows_are_sorted_stably(tmp_path):
    tr = read_trace(write(tmp_path, "t,anchor,rssi_dbm\n2,1,-1\n1,2,-2\n1,1,-3\n"))
    assert tr.t.tolist() == [1, 1, 2]
    assert tr.rssi_dbm.tolist() == [-2, -3, -1]


@pytest.mark.parametrize(
    "text, needle",
    [
        ("t,anchor\n0,1\n", "rssi_dbm"),
        ("", "empty file"),
        ("t,anchor,rssi_dbm\n", "no readings"),
        ("t,anchor,rssi_dbm\n0,1,-40\n0,1,abc\n", ":3: column rssi_dbm: not a number"),
        ("t,anchor,rssi_dbm\n0,x,-40\n", ":2: column anchor: not an integer"),
        ("t,anchor,rssi_dbm\n0,1.5,-40\n", ":2: column anchor"),
        ("t,anchor,rssi_dbm\nnan,1,-40\n", ":2: column t: not a finite"),
        ("t,anchor,rssi_dbm\n0,1\n", ":2: expected at least 3 fields"),
        ("t,anchor,rssi_dbm\n0,1,-400\n", "outside"),
        ("t,anchor,rssi_dbm,gt_x\n0,1,-40,1\n", "gt_x, gt_y"),
        ("t,anchor,rssi_dbm\n0,1,-40," + "x" * 5000 + "\n", "longer than"),
        ("t,anchor,rssi_dbm,beacon\n0,1,-40," + "b" * 129 + "\n", ":2: column beacon: an id longer than 128"),
        ("t,anchor,rssi_dbm,beacon\n0,1,-40\n", ":2: expected at least 4 fields"),
    ],
)
def test_bad_trace_is_input_error_with_location(tmp_path, text, needle):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as ei:
        read_trace(p)
    assert str(p) in str(ei.value)
    assert needle in str(ei.value)


def test_corrupt_gzip_is_input_error(tmp_path):
    good = gzip.compress(b"t,anchor,rssi_dbm\n" + b"0,1,-40\n" * 2000)
    for name, data in (("cut.csv.gz", good[: len(good) // 2]), ("junk.csv.gz", good[:10] + b"garbage" * 20)):
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(InputError, match=name):
            read_trace(p)


def test_a_file_of_too_many_rows_is_refused_however_well_it_compresses(tmp_path, monkeypatch):
    """A .gz of one repeated row inflates without end (here 2 MB of rows from a few kB): the
    readers stop at MAX_ROWS rows, one InputError naming the line, instead of growing their
    columns with it; exactly MAX_ROWS rows still read."""
    import pfdoa.trace as trace_mod

    monkeypatch.setattr(trace_mod, "MAX_ROWS", 1000)
    ok = tmp_path / "ok.csv"
    ok.write_text("t,anchor,rssi_dbm\n" + "1.0,1,-50\n" * 1000)
    assert read_trace(ok).t.size == 1000
    bomb = tmp_path / "bomb.csv.gz"
    with gzip.open(bomb, "wt") as fh:
        fh.write("t,anchor,rssi_dbm\n# a comment is not a row\n")
        fh.write("1.0,1,-50\n" * 200_000)
    assert bomb.stat().st_size < 10_000
    with pytest.raises(InputError, match=r"bomb.csv.gz:1003: more than 1,000 rows; split the recording"):
        read_trace(bomb)
    odo = tmp_path / "odo.csv.gz"
    with gzip.open(odo, "wt") as fh:
        fh.write("t,dx,dy,dtheta\n" + "0.1,0.0,0.0,0.0\n" * 200_000)
    with pytest.raises(InputError, match=r"odo.csv.gz:1002: more than 1,000 rows"):
        read_odometry(odo)


def test_missing_file_is_input_error(tmp_path):
    with pytest.raises(InputError):
        read_trace(tmp_path / "nope.csv")
    with pytest.raises(InputError):
        read_odometry(tmp_path / "nope.csv")


def test_odometry_reader(tmp_path):
    p = write(tmp_path, "t,dx,dy,dtheta,junk\n0,0,0,0,a\n1,0.1,0,0.05,b\n")
    t, dx, dy, dth = read_odometry(p)
    assert t.tolist() == [0, 1] and dx.tolist() == [0, 0.1] and dth.tolist() == [0, 0.05]
    with pytest.raises(InputError, match=r":3: column dy: not a number"):
        read_odometry(write(tmp_path, "t,dx,dy,dtheta\n0,0,0,0\n1,0,?,0\n", "o.csv"))
    with pytest.raises(InputError, match="dtheta"):
        read_odometry(write(tmp_path, "t,dx,dy\n0,0,0\n", "o2.csv"))


def test_grouping_by_window(tmp_path):
    # Anchor 9 is not in the site. The first window takes 0.0, 0.3 and 0.9 (anchor 1 twice:
    # their median); 1.0 is within 5 % of its end, so it opens the next one; 2.5 opens a new
    # one, where anchor 2 comes twice at one instant (both are combined).
    text = (
        "t,anchor,rssi_dbm,gt_x,gt_y\n"
        "0.0,1,-41,0,0\n0.0,9,-99,0,0\n0.3,2,-42,0.1,0\n"
        "0.9,1,-51,1,1\n1.0,5,-55,1.5,1\n"
        "2.5,2,-62,2,2\n2.5,2,-63,2,2\n"
        "3.0,9,-1,3,3\n"
    )
    tr = read_trace(write(tmp_path, text))
    c = GroupingCounts()
    w = list(group_by_window(tr, SITE, 1.0, c))
    assert [x.t for x in w] == [0.9, 1.0, 2.5]
    np.testing.assert_array_equal(w[0].rssi, [-46, -42, np.nan])
    np.testing.assert_array_equal(w[1].rssi, [np.nan, np.nan, -55])
    np.testing.assert_array_equal(w[2].rssi, [np.nan, -62.5, np.nan])
    assert [x.count.tolist() for x in w] == [[2, 1, 0], [0, 0, 1], [0, 2, 0]]
    assert [x.gt for x in w] == [(1.0, 1.0), (1.5, 1.0), (2.0, 2.0)]
    assert c.unknown_anchor_readings == 2 and c.unknown_anchors == {9}
    assert c.combined_readings == 2 and c.windows == 3 and c.readings_used == 6


def test_calibrate_groups_by_beacon_sequence_as_the_gateway_does(tmp_path):
    """`pfdoa calibrate --mode seq` scores pf-doa on the sets the gateway's SeqReassembler
    makes (pfdoa.calibrate.gateway_sets): the same sets, at the same times, as `pfdoa replay`
    gives. Here: a set complete at once; an anchor's repeated report of one seq is a
    duplicate; a set timed out (0.25 s) with one anchor missing; a report for a seq whose
    set has left is late; the 16-bit wrap (65535 -> 0); anchor 9 is not in the site."""
    from pfdoa.calibrate import gateway_sets
    from pfdoa.cli import main

    text = (
        "t,anchor,rssi_dbm,gt_x,gt_y,seq\n"
        "0.00,1,-41,0,0,65533\n0.01,2,-42,0,0,65533\n0.01,9,-99,0,0,65533\n0.02,5,-43,0.1,0,65533\n"
        "0.03,1,-45,0.1,0,65533\n"
        "1.00,1,-50,1,0,65534\n1.01,2,-51,1.1,0,65534\n"
        "1.60,5,-60,2,0,65534\n"
        "2.00,2,-61,3,0,65535\n2.01,1,-62,3,0,65535\n2.02,5,-63,3.5,0,65535\n"
        "3.00,1,-64,4,0,0\n3.01,2,-65,4,0,0\n3.02,5,-66,4.5,0,0\n"
    )
    site = write(tmp_path, '[radio]\nrssi_at_1m_dbm = -40.0\npath_loss_exponent = 2.0\n\n'
                           '[[anchors]]\nid = 1\nx = 0.0\ny = 0.0\n\n[[anchors]]\nid = 2\nx = 4.0\ny = 0.0\n\n'
                           '[[anchors]]\nid = 5\nx = 0.0\ny = 4.0\n', "site.toml")
    path = write(tmp_path, text)
    w = gateway_sets(read_trace(path), SITE)
    assert [round(x.t, 3) for x in w] == [0.01, 1.005, 2.01, 3.01]
    np.testing.assert_array_equal(w[0].rssi, [-41, -42, -43])  # the repeated -45 of anchor 1: a duplicate
    np.testing.assert_array_equal(w[1].rssi, [-50, -51, np.nan])  # timed out; -60 came late
    assert [x.count.tolist() for x in w] == [[1, 1, 1], [1, 1, 0], [1, 1, 1], [1, 1, 1]]
    assert [x.gt for x in w] == [(0.0, 0.0), (1.0, 0.0), (3.0, 0.0), (4.0, 0.0)]
    out = tmp_path / "o.jsonl"
    assert main(["-q", "replay", str(path), "--config", str(site), "--method", "wcl", "--out", str(out)]) == 0
    recs = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert [r["t"] for r in recs] == [round(x.t, 6) for x in w]
    assert [r["anchors"] for r in recs] == [[a for a, v in zip(SITE.anchor_ids, x.rssi) if v == v] for x in w]
    with pytest.raises(InputError, match="seq column"):
        gateway_sets(read_trace(write(tmp_path, "t,anchor,rssi_dbm\n0,1,-40\n", "noseq.csv")), SITE)


def test_high_rate_readings_are_combined_and_the_window_closes_on_time(tmp_path):
    # 37 readings a second per anchor (one anchor with a -30 dB multipath dip now and then)
    # give one estimate per window (0.95 s of readings: WINDOW_JITTER), each the median of
    # the window's readings.
    rng = np.random.default_rng(0)
    rows = []
    for k in range(37 * 5):
        t = round(k / 37, 4)
        for a, level in ((1, -50.0), (2, -60.0), (5, -70.0)):
            dip = -30.0 if (a == 2 and k % 10 == 0) else 0.0
            rows.append(f"{t + 0.001 * a:.4f},{a},{level + dip + rng.normal(0, 1):.2f},0,0")
    tr = read_trace(write(tmp_path, "t,anchor,rssi_dbm,gt_x,gt_y\n" + "\n".join(rows) + "\n"))
    w = list(group_by_window(tr, SITE, 1.0))
    assert len(w) == 6  # 5 s / 0.95 s
    assert all(35 <= c <= 36 for x in w[:-1] for c in x.count)
    med = np.array([x.rssi for x in w[:-1]])  # a mean would sit ~3 dB low for anchor 2
    np.testing.assert_allclose(med, np.tile([-50.0, -60.0, -70.0], (5, 1)), atol=0.8)


def test_jittered_periodic_readings_give_one_window_per_period(tmp_path):
    # 1 Hz with +-2 ms timestamp jitter (the robot traces): never two periods in one window.
    ts = np.arange(50) * 1.0 + np.tile([0.0, -0.002, 0.002, 0.001], 13)[:50]
    text = "t,anchor,rssi_dbm\n" + "".join(f"{t:.3f},{a},-50\n" for t in ts for a in (1, 2, 5))
    w = list(group_by_window(read_trace(write(tmp_path, text)), SITE, 1.0))
    assert len(w) == 50 and all(x.count.tolist() == [1, 1, 1] for x in w)


def test_readings_beyond_the_per_window_bound_are_counted_not_kept(tmp_path):
    from pfdoa.trace import MAX_READINGS_PER_WINDOW

    k = MAX_READINGS_PER_WINDOW + 10
    text = "t,anchor,rssi_dbm\n" + "".join(f"{i * 1e-4:.4f},1,-50\n" for i in range(k))
    c = GroupingCounts()
    w = list(group_by_window(read_trace(write(tmp_path, text)), SITE, 1.0, c))
    assert len(w) == 1 and w[0].count[0] == MAX_READINGS_PER_WINDOW
    assert c.dropped_readings == 10 and c.readings_used == MAX_READINGS_PER_WINDOW


def test_grouping_short_window_and_no_gt(tmp_path):
    tr = read_trace(write(tmp_path, "t,anchor,rssi_dbm\n0,1,-40\n0.3,2,-41\n0.6,5,-42\n"))
    w = list(group_by_window(tr, SITE, 0.5))
    assert [x.t for x in w] == [0.3, 0.6]
    assert all(x.gt is None for x in w)
    with pytest.raises(InputError):
        list(group_by_window(tr, SITE, 0.0))


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_LINE = st.lists(st.sampled_from(["0", "1", "-40", "1e3", "nan", "x", "", " ", '"', "\x00", "é", "3.5"]), max_size=6)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.one_of(st.binary(max_size=300), st.lists(_LINE, max_size=8).map(
    lambda rows: ("t,anchor,rssi_dbm,gt_x,gt_y\n" + "\n".join(",".join(r) for r in rows)).encode("utf-8"))))
def test_arbitrary_bytes_give_a_trace_or_input_error(tmp_path, body):
    p = tmp_path / "fuzz.csv"
    p.write_bytes(body)
    try:
        tr = read_trace(p)
    except InputError as exc:
        assert str(p) in str(exc)
        return
    assert np.all(np.isfinite(tr.t)) and np.all(np.isfinite(tr.rssi_dbm))
    list(group_by_window(tr, SITE, 1.0))


def test_reporting_window_is_one_second_or_the_anchors_longer_interval():
    from pfdoa.trace import Trace, reporting_window

    def trace(period, n_anchors=4, seconds=60.0, beacon=None):
        rows = [(k * period + 0.1 * a, a) for a in range(n_anchors) for k in range(int(seconds / period))]
        t = np.array([r[0] for r in rows])
        return Trace(t, np.array([r[1] for r in rows]), np.full(t.size, -60.0),
                     beacon=None if beacon is None else np.array([beacon] * t.size, dtype=object))

    assert reporting_window([trace(0.333)]) == 1.0  # fast reporters: the default
    assert reporting_window([trace(1.0)]) == 1.0
    assert reporting_window([trace(3.0)]) == 3.0  # every window holds each anchor's reading
    assert reporting_window([trace(2.04), trace(3.0), trace(2.0)]) == 2.0  # the median over anchors and runs
    assert reporting_window([trace(60.0, seconds=600.0)]) == 10.0  # bounded
    assert reporting_window([trace(3.0, beacon="b1")]) == 3.0
    assert reporting_window([trace(3.0, seconds=6.0)]) == 1.0  # too few readings to tell


def test_whole_second_warning_counts_readings_per_time_and_anchor():
    from pfdoa.trace import time_unit_warnings

    # (t, anchor) pairs: (0,1) (0,2) (1,1) (2,3): 8 readings over 4 pairs, 2 on average
    t = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 2.0, 2.0])
    a = np.array([1, 2, 1, 2, 1, 1, 3, 3])
    (w,) = time_unit_warnings(t, "x.csv", a)
    assert "each anchor has 2 readings per time on average" in w
    # one reading per (t, anchor): nothing to say
    assert time_unit_warnings(np.array([0.0, 0.0, 1.0, 1.0]), "x.csv", np.array([1, 2, 1, 2])) == []
    # unsorted input counts the same pairs
    order = np.array([5, 0, 7, 2, 4, 1, 6, 3])
    assert time_unit_warnings(t[order], "x.csv", a[order]) == [w]
