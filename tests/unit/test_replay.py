"""`pfdoa replay`: recorded traces through the gateway's reassembly and the estimators."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pfdoa.cli import main
from pfdoa.radio import PathLoss, mean_rssi
from pfdoa.site import load_site
from pfdoa.trace import group_by_window, read_trace

import gateway_feed

DATA = Path(__file__).resolve().parents[2] / "host" / "pfdoa" / "data" / "herolab_wifi_robot"
TRACES = sorted(p for p in DATA.glob("*.csv.gz") if not p.name.endswith(".odom.csv.gz"))


def records(path):
    return [json.loads(ln) for ln in Path(path).read_text().splitlines()]


def test_committed_traces_are_present():
    assert len(TRACES) >= 9 and (DATA / "site.toml").exists()


@pytest.mark.parametrize("trace", TRACES, ids=[p.name for p in TRACES])
def test_replay_every_committed_trace(trace, tmp_path):
    out = tmp_path / "pos.jsonl"
    odom = trace.with_name(trace.name.replace(".csv.gz", ".odom.csv.gz"))
    rc = main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--odom", str(odom),
               "--seed", "1", "--out", str(out)])
    assert rc == 0
    recs = records(out)
    site = load_site(DATA / "site.toml")
    windows = list(group_by_window(read_trace(trace), site, 1.0))
    assert [r["t"] for r in recs] == [round(w.t, 6) for w in windows]
    for r in recs:
        assert r["seq"] is None
        assert r["missing"] == [a for a in site.anchor_ids if a not in r["anchors"]]
    # Accuracy against the trace's ground truth (a test bound, not a published figure: one
    # seed, the committed site file, odometry used). Measured 0.35-0.59 m RMSE on these nine
    # runs; standing at the centre of the site scores 0.88-1.09 m, so both bounds can fail.
    gt = np.array([w.gt for w in windows])
    err = np.hypot(*(np.array([[r["x"], r["y"]] for r in recs]) - gt).T)
    rmse = float(np.sqrt(np.mean(err ** 2)))
    xmin, ymin, xmax, ymax = site.bounds
    centre = float(np.sqrt(np.mean(np.sum((gt - [(xmin + xmax) / 2, (ymin + ymax) / 2]) ** 2, axis=1))))
    assert rmse < 0.8 and rmse < 0.75 * centre, (rmse, centre)


def test_replay_is_deterministic_for_a_seed(tmp_path):
    trace = TRACES[0]
    outs = []
    for k in range(2):
        out = tmp_path / f"{k}.jsonl"
        assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--seed", "5",
                     "--out", str(out)]) == 0
        outs.append(out.read_text())
    assert outs[0] == outs[1]


def test_replay_groups_by_seq_with_duplicates_late_and_wrap(tmp_path, site_file):
    site = site_file("[gateway]\nset_timeout_s = 0.5\n")
    rows = ["t,anchor,rssi_dbm,seq,extra"]
    seqs = [65534, 65535, 0, 1]
    for i, s in enumerate(seqs):
        for a in range(4):
            if (s, a) == (0, 2):
                continue  # lost
            rows.append(f"{i * 0.1 + a * 0.01:.2f},{a},{-50 - a},{s},x")
    rows.append("0.35,1,-50,1,dup")  # duplicate of (seq 1, anchor 1)
    rows.append("2.00,2,-50,0,late")  # seq 0 left long ago
    tr = tmp_path / "t.csv"
    tr.write_text("\n".join(rows) + "\n")
    out = tmp_path / "o.jsonl"
    stats = tmp_path / "s.json"
    assert main(["-q", "replay", str(tr), "--config", str(site), "--method", "wcl", "--out", str(out),
                 "--stats", str(stats)]) == 0
    recs = records(out)
    assert [r["seq"] for r in recs] == seqs
    assert [r["missing"] for r in recs] == [[], [], [2], []]
    s = json.loads(stats.read_text())
    assert s["duplicates"] == 1 and s["late"] == 1 and s["mode"] == "seq"
    assert s["anchors"]["2"]["lost"] == 0  # the late report did arrive


def test_replay_window_option(tmp_path, site_file):
    site = site_file()
    rng = np.random.default_rng(0)
    rows = ["t,anchor,rssi_dbm"]
    for k in range(40):
        for a in range(4):
            rows.append(f"{k * 0.25:.2f},{a},{-50 + rng.normal():.1f}")
    tr = tmp_path / "t.csv"
    tr.write_text("\n".join(rows) + "\n")
    out = tmp_path / "p.jsonl"
    # windows close on time: 2 s windows take eight instants each, 0.25 s windows one
    assert main(["-q", "replay", str(tr), "--config", str(site), "--window", "2.0", "--out", str(out)]) == 0
    assert [r["t"] for r in records(out)] == [1.75, 3.75, 5.75, 7.75, 9.75]
    assert main(["-q", "replay", str(tr), "--config", str(site), "--window", "0.25", "--out", str(out)]) == 0
    assert len(records(out)) == 40


def _out_and_back(tmp_path: Path, odometry: str | None) -> float:
    """RMSE (m, from the 10th estimate on) of a replay of a robot driving out and back
    along y = 1 in the 4 x 4 m test site at 0.25 m/s, 3 dB RSSI noise, one reading per anchor
    per second; ``odometry``: None, "true" (its real motion), "still" (odometry claiming it
    never moved) or "no-turn" (the 180 degree turns left out)."""
    rng = np.random.default_rng(0)
    pts, heads, x, h = [], [], 0.5, 0.0
    for _ in range(80):
        pts.append((x, 1.0))
        heads.append(h)
        if h == 0.0 and x + 0.25 > 3.5:
            h = math.pi
        elif h == math.pi and x - 0.25 < 0.5:
            h = 0.0
        else:
            x += 0.25 * math.cos(h)
    xy = np.array(pts)
    mu = mean_rssi(xy, np.array(list(gateway_feed.ANCHORS.values())), PathLoss(*gateway_feed.RADIO))
    tr = tmp_path / "t.csv"
    tr.write_text("t,anchor,rssi_dbm\n" + "".join(f"{k}.0,{a},{mu[k, a] + rng.normal(0, 3.0):.1f}\n"
                                                  for k in range(len(xy)) for a in range(4)))
    site = tmp_path / "site.toml"
    site.write_text(gateway_feed.TEST_SITE)
    out = tmp_path / f"{odometry}.jsonl"
    args = ["-q", "replay", str(tr), "--config", str(site), "--seed", "1", "--out", str(out)]
    if odometry is not None:
        od = ["t,dx,dy,dtheta"]
        for k in range(1, len(xy)):
            dx = float(np.hypot(*(xy[k] - xy[k - 1])))
            dth = math.remainder(heads[k] - heads[k - 1], 2 * math.pi)
            if odometry == "still":
                dx = dth = 0.0
            elif odometry == "no-turn":
                dth = 0.0
            od.append(f"{k}.0,{dx:.4f},0,{dth:.5f}")
        (tmp_path / "o.csv").write_text("\n".join(od) + "\n")
        args += ["--odom", str(tmp_path / "o.csv")]
    assert main(args) == 0
    est = np.array([[r["x"], r["y"]] for r in records(out)])
    assert est.shape == xy.shape  # one estimate per second
    return float(np.sqrt(np.mean(np.sum((est - xy)[10:] ** 2, axis=1))))


def test_replay_odometry_moves_the_estimate_as_the_robot_moved(tmp_path):
    """The odometry file is used, and as motion: the true motion makes the estimate better
    than the readings alone, and odometry that contradicts the motion makes it worse.
    (Measured here: true 0.42 m, none 0.67 m, still 0.83 m, no-turn 1.28 m RMSE; in a trial
    over data and filter seeds 0-3 the order never changed.)"""
    true, none = _out_and_back(tmp_path, "true"), _out_and_back(tmp_path, None)
    still, no_turn = _out_and_back(tmp_path, "still"), _out_and_back(tmp_path, "no-turn")
    assert true < 0.5 and true < 0.8 * none, (true, none)
    assert still > none and no_turn > 1.5 * none, (still, no_turn, none)


def test_replay_mode_window_ignores_seq_and_seq_needs_the_column(tmp_path, site_file):
    site = site_file()
    tr = tmp_path / "t.csv"
    # per-anchor counters that are not a common beacon sequence
    tr.write_text("t,anchor,rssi_dbm,seq\n" + "".join(f"{k}.0,{a},-50,{k * 7 + a * 1000}\n" for k in range(5) for a in range(4)))
    out = tmp_path / "o.jsonl"
    assert main(["-q", "replay", str(tr), "--config", str(site), "--mode", "window", "--method", "wcl",
                 "--out", str(out)]) == 0
    recs = records(out)
    assert len(recs) == 5 and all(r["missing"] == [] and r["seq"] is None for r in recs)
    plain = tmp_path / "p.csv"
    plain.write_text("t,anchor,rssi_dbm\n0.0,0,-50\n")
    assert main(["-q", "replay", str(plain), "--config", str(site), "--mode", "seq"]) == 2


def test_output_carries_r95_cov_and_lost_in_json_and_csv(tmp_path):
    """The uncertainty fields, read back with the standard library's csv and json readers."""
    import csv

    trace = TRACES[0]
    out_j, out_c = tmp_path / "p.jsonl", tmp_path / "p.csv"
    for out, fmt in ((out_j, "jsonl"), (out_c, "csv")):
        assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--seed", "2",
                     "--format", fmt, "--out", str(out)]) == 0
    recs = records(out_j)
    with open(out_c, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(recs) > 100
    for r, c in zip(recs, rows):
        xx, xy, yy = r["cov"]
        assert xx > 0 and yy > 0 and xx * yy - xy * xy > 0  # positive definite
        assert r["r95"] > 0 and isinstance(r["lost"], bool)
        assert [float(v) for v in c["cov"].split(";")] == pytest.approx(r["cov"], abs=1e-6)
        assert float(c["r95"]) == pytest.approx(r["r95"]) and c["lost"] == str(r["lost"]).lower()
    wcl = tmp_path / "w.jsonl"
    assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--method", "wcl",
                 "--out", str(wcl)]) == 0
    assert all(r["r95"] is None and r["cov"] is None and r["lost"] is None for r in records(wcl))


def test_output_carries_the_heading_with_odometry_only(tmp_path):
    """With odometry the particle filter tracks the heading: every record carries it (rad,
    wrapped) and its variance, in JSON and CSV (columns appended after lost); without
    odometry both are null / empty."""
    import csv
    import math

    trace = TRACES[0]
    odom = trace.with_name(trace.name.replace(".csv.gz", ".odom.csv.gz"))
    out_j, out_c, plain = tmp_path / "h.jsonl", tmp_path / "h.csv", tmp_path / "n.jsonl"
    for out, fmt in ((out_j, "jsonl"), (out_c, "csv")):
        assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--odom", str(odom),
                     "--seed", "2", "--format", fmt, "--out", str(out)]) == 0
    recs = records(out_j)
    with open(out_c, newline="") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames[-7:-4] == ["beacon", "heading", "heading_var"]
        rows = list(reader)
    assert len(rows) == len(recs) > 100
    for r, c in zip(recs, rows):
        assert -math.pi <= r["heading"] <= math.pi and 0.0 <= r["heading_var"] <= math.pi ** 2 / 3
        assert float(c["heading"]) == pytest.approx(r["heading"]) and float(c["heading_var"]) == pytest.approx(r["heading_var"])
    # The start is uniform, the second half is not (its median: a jump test that re-seeds part of
    # the cloud reports that part's uniform headings, as this seed's last step does).
    late = sorted(r["heading_var"] for r in recs[len(recs) // 2:])
    assert late[len(late) // 2] < 0.25 * recs[0]["heading_var"]
    assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--seed", "2",
                 "--out", str(plain)]) == 0
    assert all(r["heading"] is None and r["heading_var"] is None for r in records(plain))


@pytest.mark.parametrize("mode", ["seq", "window"])
def test_replay_in_blocks_gives_the_same_records(tmp_path, site_file, monkeypatch, mode):
    """Replay turns a trace into Python values block by block (the memory of a long trace);
    block edges change nothing, for one beacon and for named beacons (the timers, the
    reassembly and each beacon's estimator run across the edges)."""
    import pfdoa.commands.replay as replay_cmd

    site = site_file("[gateway]\nset_timeout_s = 0.5\n")
    rows = ["t,anchor,rssi_dbm,seq,beacon"]
    for s in range(40):
        for b, name in enumerate(("", "tag-a", "tag-b")):
            for a in range(4):
                if (s + a + b) % 9:
                    rows.append(f"{s * 0.2 + b * 0.05 + a * 0.01:.2f},{a},{-50 - a - 3 * ((s + b) % 4)},{s},{name}")
    tr = tmp_path / "t.csv"
    tr.write_text("\n".join(rows) + "\n")
    outs = []
    for block in (replay_cmd.REPLAY_BLOCK, 7):
        monkeypatch.setattr(replay_cmd, "REPLAY_BLOCK", block)
        out = tmp_path / f"o{block}.jsonl"
        assert main(["-q", "replay", str(tr), "--config", str(site), "--mode", mode, "--seed", "3",
                     "--out", str(out)]) == 0
        outs.append(out.read_text())
    assert outs[0] == outs[1]
    recs = records(tmp_path / "o7.jsonl")
    assert {r["beacon"] for r in recs} == {None, "tag-a", "tag-b"} and len(recs) >= 24
