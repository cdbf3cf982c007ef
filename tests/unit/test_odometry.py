"""Odometry by its own timestamps: the buffer's interval composition, the live reader, and
the localizer's bounded wait for the odometry of a set (timer time, not sleeps)."""

from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
import pytest

from pfdoa.estimators.base import Estimate
from pfdoa.gateway.localizer import Localizer
from pfdoa.gateway.odomsource import MAX_LINE, OdometryReader, load_odometry
from pfdoa.gateway.reassembly import AnchorSet
from pfdoa.gateway.transports import OdomLine
from pfdoa.odometry import OdometryBuffer, compose
from pfdoa.site import parse_site

SITE = parse_site({"radio": {"rssi_at_1m_dbm": -45.0, "path_loss_exponent": 2.0},
                   "anchors": [{"id": 0, "x": 0, "y": 0}, {"id": 1, "x": 0, "y": 4}, {"id": 2, "x": 4, "y": 0}]},
                  "<test>")


def test_motion_over_exactly_the_interval_between_two_estimates():
    b = OdometryBuffer()
    assert b.take(1.0) is None  # nothing ever arrived: no odometry (not zero motion)
    for k in range(5):
        b.add(0.1 * k, 0.1, 0.0, 0.0)  # 1 m/s, each increment covering the 0.1 s before its t
    assert b.take(0.05).dx == pytest.approx(0.15)  # the first (an instant) + half of (0, 0.1]
    assert b.take(0.25).dx == pytest.approx(0.2)  # (0.05, 0.25]: 0.1 + 0.1 + half of (0.2, 0.3]
    assert b.take(0.25).dx == 0.0  # nothing in between
    assert b.take(1.0).dx == pytest.approx(0.15)  # the rest up to the newest (0.4)
    b.add(1.5, 1.1, 0.0, 0.0)  # covers (0.4, 1.5]: the motion after 0.4 is carried, not lost
    assert b.take(1.2).dx == pytest.approx(0.8)
    assert b.take(2.0).dx == pytest.approx(0.3)
    assert not b.add(1.5, 1.0, 0.0, 0.0) and b.out_of_order == 1


def test_a_turn_is_composed_in_order():
    b = OdometryBuffer()
    b.add(0.0, 1.0, 0.0, math.pi / 2)
    b.add(0.1, 1.0, 0.0, 0.0)
    total = b.take(0.1)
    want = compose(compose(type(total)(), type(total)(1.0, 0.0, math.pi / 2)), type(total)(1.0, 0.0, 0.0))
    assert (total.dx, total.dy, total.dtheta) == pytest.approx((want.dx, want.dy, want.dtheta))
    assert (total.dx, total.dy) == pytest.approx((1.0, 1.0))


def test_bounded_and_the_bound_is_counted():
    b = OdometryBuffer(max_len=100)
    for k in range(250):
        b.add(float(k), 0.0, 0.0, 0.0)
    assert len(b) == 100 and b.dropped == 150


def test_odometry_file_read_whole_into_an_ended_buffer(tmp_path):
    p = tmp_path / "o.csv"
    p.write_text("t,dx,dy,dtheta\n0.0,0.5,0,0\n0.1,0.25,0,0\n")
    b = load_odometry(str(p))
    assert b.ended and b.lines == 2 and b.take(0.1).dx == pytest.approx(0.75)


def _read_items(reader: OdometryReader, n: int, hang_s: float = 10.0) -> list[OdomLine]:
    got: list[OdomLine] = []
    end = time.monotonic() + hang_s
    while len(got) < n:
        assert time.monotonic() < end, "hang guard"
        got += reader.read(0.05)
    return got


def test_live_odometry_from_a_fifo_and_a_growing_file(tmp_path):
    fifo = tmp_path / "odom.fifo"
    os.mkfifo(fifo)
    r = OdometryReader(str(fifo))
    th = threading.Thread(target=r.open)  # a FIFO's open waits for its writer
    th.start()
    with open(fifo, "w") as w:
        th.join(10.0)
        w.write("t,dx,dy,dtheta\n0.0,1.0,0.0,1.5707963267948966\n0.1,1.0,0.0,0.0\nbad,line\n")
        w.flush()
        items = _read_items(r, 2)
    r.close()
    assert [(i.t_odom, i.dx, i.dtheta) for i in items] == [(0.0, 1.0, math.pi / 2), (0.1, 1.0, 0.0)]
    assert r.bad_lines == 1

    grow = tmp_path / "odom.csv"
    grow.write_text("0.0,0.5,0,0\n")
    r = OdometryReader(str(grow))
    r.open()
    assert [i.dx for i in _read_items(r, 1)] == [0.5]
    with open(grow, "a") as fh:
        fh.write("0.1,0.25,0,0\n0.2,0.1")  # the last line is still being written
    assert [i.dx for i in _read_items(r, 1)] == [0.25]
    with open(grow, "a") as fh:
        fh.write("25,0,0\n" + "9" * (MAX_LINE + 10) + "\n0.3,1,0,0\n")
    assert [(i.t_odom, i.dx) for i in _read_items(r, 2)] == [(0.2, 0.125), (0.3, 1.0)]
    assert r.bad_lines == 1  # the overlong line, skipped: memory stays bounded
    r.close()


class Recorder:
    """An estimator double that records the odometry it is given."""

    name = "recorder"

    def __init__(self) -> None:
        self.calls: list[tuple[float, object]] = []

    def reset(self) -> None:
        self.calls.clear()

    def step(self, obs, odom=None):
        self.calls.append((obs.t, odom))
        return Estimate(obs.t, 0.0, 0.0, 0.1)


def aset(t: float, seq: int) -> AnchorSet:
    return AnchorSet(t=t, rssi={0: -50.0, 1: -50.0, 2: -50.0}, missing=(), seq=seq)


def test_a_set_waits_for_its_odometry_then_goes_on_without_it():
    od = OdometryBuffer()
    est = Recorder()
    loc = Localizer(SITE, est, None, od, odom_wait_s=0.25)
    od.add(0.0, 0.0, 0.0, 0.0)
    loc.release(0.0)
    loc.handle(aset(0.05, 0))
    assert est.calls == []  # the motion up to 0.05 is not known yet
    od.add(0.1, 0.1, 0.0, 0.0)
    loc.release(0.06)
    assert [(t, o.dx) for t, o in est.calls] == [(0.05, pytest.approx(0.05))]
    # The odometry stalls: the next set waits 0.25 s of timer time, then goes on with what
    # is known; the rest of the motion goes into the following estimate.
    loc.handle(aset(0.15, 1))
    loc.release(0.39)
    assert len(est.calls) == 1
    loc.release(0.40)
    assert est.calls[1][1].dx == pytest.approx(0.05) and loc.odom_gave_up == 1
    od.add(0.3, 0.2, 0.0, 0.0)
    loc.handle(aset(0.25, 2))
    loc.release(0.41)
    assert est.calls[2][1].dx == pytest.approx(0.15)  # (0.1, 0.25] of the increment covering (0.1, 0.3]


def test_odometry_gone_or_on_another_clock_is_no_odometry(caplog):
    od = OdometryBuffer()
    est = Recorder()
    loc = Localizer(SITE, est, None, od, odom_fresh_s=1.0)
    od.add(0.0, 0.1, 0.0, 0.0)
    loc.handle(aset(5.0, 0))  # 5 s after the newest increment: the stream is gone, no waiting
    assert est.calls == [(5.0, None)]
    od2 = OdometryBuffer()
    est2 = Recorder()
    loc2 = Localizer(SITE, est2, None, od2)
    od2.add(1_700_000_000.0, 0.1, 0.0, 0.0)  # Unix time, while the sets run on stream seconds
    loc2.handle(aset(12.0, 0))
    assert est2.calls == [(12.0, None)]
    assert "host clock" in caplog.text


def test_replay_with_odometry_gives_the_interval_motion(tmp_path, site_file):
    """pfdoa replay: the estimator gets exactly the composed increments of each interval."""
    import pfdoa.gateway.localizer as L
    from pfdoa.cli import main

    site = site_file()
    tr = tmp_path / "t.csv"
    tr.write_text("t,anchor,rssi_dbm\n" + "".join(f"{k * 0.5:.1f},{a},-50\n" for k in range(6) for a in range(4)))
    od = tmp_path / "o.csv"
    od.write_text("t,dx,dy,dtheta\n" + "".join(f"{k * 0.1:.1f},0.01,0,0\n" for k in range(30)))
    seen = []
    orig = L.Localizer._odometry_for

    def spy(self, t):
        o = orig(self, t)
        seen.append((t, None if o is None else round(o.dx, 9)))
        return o

    L.Localizer._odometry_for = spy
    try:
        assert main(["-q", "replay", str(tr), "--config", str(site), "--odom", str(od), "--method", "wcl",
                     "--window", "0.5", "--out", str(tmp_path / "e.jsonl")]) == 0
    finally:
        L.Localizer._odometry_for = orig
    # One window per 0.5 s instant. 0.0: the first increment; then 5 increments (0.01 m each) per 0.5 s window
    assert seen == [(0.0, 0.01)] + [(k * 0.5, 0.05) for k in range(1, 6)]
    assert np.isfinite([t for t, _ in seen]).all()
