"""Reassembly of anchor reports into synchronized sets (pfdoa.gateway.reassembly)."""

from pathlib import Path

import numpy as np
import pytest

from pfdoa.gateway.reassembly import Reading, SeqReassembler, WindowGrouper, seq_diff

IDS = (0, 1, 2, 3)


def run(g, readings, poll_times=()):
    out = []
    for r in readings:
        out += g.push(r)
    for t in poll_times:
        out += g.poll(t)
    return out


def rd(a, seq, t=None, rssi=-50.0, tick=None):
    return Reading(a, rssi, seq * 0.02 if t is None else t, seq, tick)


def test_seq_diff_wraps():
    assert seq_diff(0, 65535) == 1
    assert seq_diff(65535, 0) == -1
    assert seq_diff(5, 3) == 2
    assert seq_diff(3, 5) == -2
    assert seq_diff(32767, 0) == 32767
    assert seq_diff(32768, 0) == -32768


def test_complete_sets_leave_at_once_in_order():
    g = SeqReassembler(IDS)
    out = run(g, [rd(a, s, rssi=-40.0 - a) for s in range(3) for a in IDS])
    assert [s.seq for s in out] == [0, 1, 2]
    assert all(s.reason == "complete" and s.missing == () for s in out)
    assert out[0].rssi == {0: -40.0, 1: -41.0, 2: -42.0, 3: -43.0}
    assert g.open_sets == 0


def test_lost_report_releases_set_when_anchor_moved_on():
    g = SeqReassembler(IDS, set_timeout_s=100.0)
    rs = [rd(a, s) for s in range(3) for a in IDS if (s, a) != (1, 2)]
    out = run(g, rs)
    assert [s.seq for s in out] == [0, 1, 2]
    assert out[1].missing == (2,) and out[1].reason == "lost"
    assert g.tracker.stats(2).lost == 1
    assert g.tracker.stats(0).lost == 0


def test_timeout_names_missing_anchor():
    g = SeqReassembler(IDS, set_timeout_s=0.1)
    out = run(g, [rd(a, 7, t=1.0) for a in (0, 1, 3)])
    assert out == []
    assert g.poll(1.05) == []
    out = g.poll(1.2)
    assert len(out) == 1 and out[0].missing == (2,) and out[0].reason == "timeout"
    assert g.counters.timeouts == 1


def test_sets_wait_for_older_incomplete_set():
    # seq 1 is complete, but seq 0 still waits for anchor 3 (which has not moved on).
    g = SeqReassembler(IDS, set_timeout_s=0.5)
    out = run(g, [rd(a, 0, t=0.0) for a in (0, 1, 2)] + [rd(a, 1, t=0.02) for a in (0, 1, 2)])
    assert out == []
    out = g.push(rd(3, 0, t=0.03))  # the late-but-in-time report completes seq 0
    assert [s.seq for s in out] == [0]
    out = g.push(rd(3, 1, t=0.04))
    assert [s.seq for s in out] == [1]
    assert g.counters.late == 0


def test_duplicates_dropped_and_counted_open_and_closed():
    g = SeqReassembler(IDS)
    out = run(g, [rd(0, 0), rd(0, 0)])  # duplicate while open
    out += run(g, [rd(a, 0) for a in (1, 2, 3)])
    out += run(g, [rd(2, 0)])  # duplicate after the set left
    assert len(out) == 1
    assert g.counters.duplicates == 2
    assert g.tracker.stats(0).duplicates == 1 and g.tracker.stats(2).duplicates == 1
    assert g.tracker.stats(0).received == 1


def test_late_report_dropped_and_counted():
    g = SeqReassembler(IDS, set_timeout_s=0.1)
    run(g, [rd(a, 0, t=0.0) for a in (0, 1, 2)])
    out = g.poll(0.2)
    assert out[0].missing == (3,)
    assert g.push(rd(3, 0, t=0.25)) == []
    assert g.counters.late == 1 and g.tracker.stats(3).late == 1
    # received in the end: not lost
    assert g.tracker.stats(3).lost == 0


def test_wraparound_keeps_order_and_counts_loss():
    g = SeqReassembler(IDS)
    seqs = [65533, 65534, 65535, 0, 1, 3]  # 2 missing for every anchor
    out = run(g, [rd(a, s, t=i * 0.02) for i, s in enumerate(seqs) for a in IDS])
    assert [s.seq for s in out] == seqs
    assert all(g.tracker.stats(a).lost == 1 for a in IDS)


def test_eviction_bounds_open_sets():
    g = SeqReassembler(IDS, max_open_sets=8, set_timeout_s=1e9)
    # Anchor 3 reports nothing new: each set stays incomplete and not provably lost.
    out = []
    for s in range(100):
        out += g.push(rd(0, s))
        assert g.open_sets <= 8
    assert g.counters.evicted == 92
    assert [s.seq for s in out] == list(range(92))
    assert all(s.reason == "evicted" and s.missing == (1, 2, 3) for s in out)


def test_reordered_report_not_counted_lost():
    g = SeqReassembler(IDS, set_timeout_s=1.0)
    rs = [rd(a, s) for s in range(4) for a in IDS]
    # anchor 1's report of seq 2 arrives after anchor 0's report of seq 3
    i, j = rs.index(rd(1, 2)), rs.index(rd(0, 3))
    rs.insert(j, rs.pop(i))
    out = run(g, rs)
    assert [s.seq for s in out] == [0, 1, 2, 3]
    assert all(s.missing == () for s in out)
    assert sum(st.lost for st in g.tracker.all_stats().values()) == 0


def test_reboot_detected_from_tick_and_flagged_once():
    g = SeqReassembler(IDS)
    out = run(g, [rd(a, 0, tick=100000 + a) for a in IDS])
    out += run(g, [rd(a, 1, tick=(150 if a == 2 else 100020 + a)) for a in IDS])
    out += run(g, [rd(a, 2, tick=(170 if a == 2 else 100040 + a)) for a in IDS])
    assert [s.rebooted for s in out] == [(), (2,), ()]
    assert g.tracker.stats(2).reboots == 1
    assert g.tracker.stats(1).reboots == 0


def test_tick_wrap_is_not_a_reboot():
    g = SeqReassembler(IDS)
    run(g, [rd(a, 0, tick=2**32 - 10) for a in IDS])
    out = run(g, [rd(a, 1, tick=10) for a in IDS])
    assert out[0].rebooted == ()


def test_uptime_backwards_is_a_reboot():
    g = SeqReassembler(IDS)
    g.tracker.uptime(1, 500, 0.0)
    g.tracker.uptime(1, 501, 1.0)
    g.tracker.uptime(1, 2, 2.0)
    out = run(g, [rd(a, 0) for a in IDS])
    assert out[0].rebooted == (1,)


def test_sequence_restart_recovers():
    g = SeqReassembler(IDS, history=16)
    out = run(g, [rd(a, s) for s in range(5000, 5040) for a in IDS])
    assert [s.seq for s in out] == list(range(5000, 5040))
    out2 = run(g, [rd(a, s, t=10 + s * 0.02) for s in range(0, 5) for a in IDS])
    assert g.counters.seq_restarts == 1
    assert [s.seq for s in out2] == [0, 1, 2, 3, 4]
    assert g.counters.late == 0


def test_stale_anchor_reported_and_recovers():
    g = SeqReassembler(IDS, stale_after_s=1.0, set_timeout_s=0.05)
    run(g, [rd(a, 0, t=0.0) for a in IDS])
    for k in range(1, 80):  # anchor 3 goes silent
        run(g, [rd(a, k, t=k * 0.02) for a in (0, 1, 2)])
        g.poll(k * 0.02)
    out = run(g, [rd(a, 80, t=1.6) for a in (0, 1, 2)]) + g.poll(1.7)
    assert out[-1].stale == (3,)
    assert g.tracker.stats(3).stale and g.tracker.stats(3).stale_events == 1
    g.push(rd(3, 81, t=1.8))
    assert not g.tracker.stats(3).stale


def test_unknown_anchor_counted_with_bounded_ids():
    g = SeqReassembler(IDS)
    for a in range(1000, 2000):
        g.push(rd(a, 0))
    assert g.counters.unknown_anchor == 1000
    assert len(g.counters.unknown_ids) == 256


def test_reading_without_seq_counted_in_seq_mode():
    g = SeqReassembler(IDS)
    assert g.push(Reading(0, -50.0, 0.0)) == []
    assert g.counters.no_seq == 1


# --- window mode ----------------------------------------------------------------------


def test_window_groups_by_time_and_combines_repeats():
    g = WindowGrouper(IDS, window_s=1.0)
    rs = [Reading(0, -40, 0.0), Reading(1, -41, 0.0), Reading(2, -42, 0.3), Reading(0, -44, 0.5),
          Reading(0, -60, 0.6), Reading(1, -44, 2.0), Reading(3, -45, 2.0)]
    out = run(g, rs) + g.flush()
    assert [(s.t, s.anchors) for s in out] == [(0.6, (0, 1, 2)), (2.0, (1, 3))]
    assert out[0].rssi == {0: -44.0, 1: -41.0, 2: -42.0}  # median of -40, -44, -60
    assert out[0].counts == {0: 3, 1: 1, 2: 1} and out[0].missing == (3,)
    assert out[0].count_vector(IDS).tolist() == [3, 1, 1, 0]
    assert g.combined == 2


def test_window_live_closes_on_the_timer():
    g = WindowGrouper(IDS, window_s=1.0)
    out = run(g, [Reading(a, -40, 0.1 * a) for a in IDS])
    assert out == [] and g.poll(0.9) == []  # complete, but more readings may still come
    out = g.poll(1.0)
    assert len(out) == 1 and out[0].missing == () and out[0].t == pytest.approx(0.3)
    out = run(g, [Reading(0, -40, 1.0)])
    assert out == [] and g.poll(1.5) == []
    out = g.poll(2.1)
    assert len(out) == 1 and out[0].missing == (1, 2, 3)


def test_window_may_close_once_every_anchor_reported_for_slow_anchors():
    """Opt-in: anchors that report once per window get their set without waiting."""
    g = WindowGrouper(IDS, window_s=1.0, close_when_complete=True)
    out = run(g, [Reading(a, -40 - a, 0.1 * a) for a in IDS])
    assert len(out) == 1 and out[0].reason == "complete" and out[0].t == pytest.approx(0.3)
    assert run(g, [Reading(0, -40, 1.0), Reading(1, -40, 1.1)]) == [] and g.open_sets == 1


def test_window_memory_is_bounded_per_anchor():
    from pfdoa.trace import MAX_READINGS_PER_WINDOW

    g = WindowGrouper(IDS, window_s=10.0)
    for k in range(3 * MAX_READINGS_PER_WINDOW):
        assert g.push(Reading(k % 2, -50.0, k * 1e-4)) == []
        assert all(len(v) <= MAX_READINGS_PER_WINDOW for v in g._values.values())
    (s,) = g.flush()
    assert s.counts == {0: MAX_READINGS_PER_WINDOW, 1: MAX_READINGS_PER_WINDOW}
    assert g.dropped == MAX_READINGS_PER_WINDOW


def _traces():
    here = Path(__file__).resolve().parents[2] / "host" / "pfdoa" / "data" / "herolab_wifi_robot"
    return sorted(p for p in here.glob("*.csv.gz") if not p.name.endswith(".odom.csv.gz"))


def _ble_trace():
    """A high-rate BLE run (6 anchors, each every 1/3 s: three readings per anchor and window)."""
    return Path(__file__).resolve().parents[2] / "host" / "pfdoa" / "data" / "kolakowski_ble_dev" / "calib2.csv.gz"


def test_window_grouper_matches_trace_group_by_window():
    """The streaming grouper and pfdoa.trace.group_by_window give the same sets."""
    from pfdoa.trace import Trace, group_by_window, read_trace

    rng = np.random.default_rng(3)
    n = 400
    t = np.round(np.cumsum(rng.choice([0.0, 0.0, 0.1, 0.4, 1.3], size=n)), 3)
    synthetic = Trace(t=t, anchor=rng.integers(0, 5, size=n), rssi_dbm=rng.normal(-60, 5, size=n))
    traces = [synthetic] + [read_trace(p) for p in _traces()[:3]] + [read_trace(_ble_trace())]
    from pfdoa.site import parse_site

    # Six anchors: the BLE run's; the robot runs use the first four (readings of 4, 5 from
    # the synthetic trace are spread over two more).
    site = parse_site({"radio": {"rssi_at_1m_dbm": -40.0, "path_loss_exponent": 2.0},
                       "anchors": [{"id": i, "x": float(x), "y": float(y)}
                                   for i, (x, y) in enumerate([(0, 0), (0, 2), (2, 2), (2, 0), (1, 3), (3, 1)])]})
    combined = 0
    for tr in traces:
        for w in (0.5, 1.0, 3.0):
            ref = list(group_by_window(tr, site, w))
            g = WindowGrouper(site.anchor_ids, window_s=w)
            got = []
            for i in range(len(tr)):
                got += g.push(Reading(int(tr.anchor[i]), float(tr.rssi_dbm[i]), float(tr.t[i])))
            got += g.flush()
            assert len(got) == len(ref)
            for a, b in zip(got, ref):
                assert a.t == b.t
                np.testing.assert_array_equal(a.vector(site.anchor_ids), b.rssi)
                np.testing.assert_array_equal(a.count_vector(site.anchor_ids), b.count)
            combined += g.combined
    assert combined > 10000  # the BLE run's repeated readings were combined, not replaced


def test_anchor_never_heard_goes_stale_from_start():
    g = SeqReassembler(IDS, stale_after_s=1.0)
    g.poll(100.0)
    assert g.tracker.stale_ids() == ()
    g.poll(100.5)
    run(g, [rd(a, 0, t=100.6) for a in (0, 1, 2)])
    g.poll(101.2)
    assert g.tracker.stale_ids() == (3,)


def test_stale_anchor_is_not_waited_for():
    g = SeqReassembler(IDS, stale_after_s=0.5, set_timeout_s=0.25)
    run(g, [rd(a, 0, t=0.0) for a in IDS])
    g.poll(0.6)  # nothing for 0.6 s: everyone stale
    out = []
    for k in range(1, 5):  # anchors 0-2 come back, 3 does not: sets leave at the next beacon
        out += run(g, [rd(a, k, t=0.6 + 0.02 * k) for a in (0, 1, 2)])
    assert [s.seq for s in out] == [1, 2, 3]
    assert all(s.reason == "lost" and s.missing == (3,) and s.stale == (3,) for s in out)
    assert g.counters.late == 0
