"""`pfdoa replay`: recorded traces through the gateway's reassembly and the estimators."""

import json
from pathlib import Path

import numpy as np
import pytest

from pfdoa.cli import main
from pfdoa.site import load_site
from pfdoa.trace import group_by_window, read_trace

DATA = Path(__file__).resolve().parents[1] / "host" / "pfdoa" / "data" / "herolab_wifi_robot"
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
    xmin, ymin, xmax, ymax = site.bounds
    for r in recs:
        assert r["seq"] is None
        assert xmin - 2 <= r["x"] <= xmax + 2 and ymin - 2 <= r["y"] <= ymax + 2
        assert r["missing"] == [a for a in site.anchor_ids if a not in r["anchors"]]


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


def test_replay_window_option_and_odometry(tmp_path, site_file):
    site = site_file()
    rng = np.random.default_rng(0)
    rows = ["t,anchor,rssi_dbm"]
    for k in range(40):
        for a in range(4):
            rows.append(f"{k * 0.25:.2f},{a},{-50 + rng.normal():.1f}")
    tr = tmp_path / "t.csv"
    tr.write_text("\n".join(rows) + "\n")
    od = tmp_path / "o.csv"
    od.write_text("t,dx,dy,dtheta\n" + "".join(f"{k * 0.25:.2f},0.05,0,0\n" for k in range(40)))
    out = tmp_path / "p.jsonl"
    # windows close on time: 2 s windows take eight instants each, 0.25 s windows one
    assert main(["-q", "replay", str(tr), "--config", str(site), "--window", "2.0", "--odom", str(od),
                 "--out", str(out)]) == 0
    assert [r["t"] for r in records(out)] == [1.75, 3.75, 5.75, 7.75, 9.75]
    assert main(["-q", "replay", str(tr), "--config", str(site), "--window", "0.25", "--odom", str(od),
                 "--out", str(out)]) == 0
    assert len(records(out)) == 40


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
        assert reader.fieldnames[-3:] == ["lost", "heading", "heading_var"]
        rows = list(reader)
    assert len(rows) == len(recs) > 100
    for r, c in zip(recs, rows):
        assert -math.pi <= r["heading"] <= math.pi and 0.0 <= r["heading_var"] <= math.pi ** 2 / 3
        assert float(c["heading"]) == pytest.approx(r["heading"]) and float(c["heading_var"]) == pytest.approx(r["heading_var"])
    assert recs[-1]["heading_var"] < recs[0]["heading_var"]  # the start is uniform, the end is not
    assert main(["-q", "replay", str(trace), "--config", str(DATA / "site.toml"), "--seed", "2",
                 "--out", str(plain)]) == 0
    assert all(r["heading"] is None and r["heading_var"] is None for r in records(plain))
