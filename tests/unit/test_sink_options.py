"""The sinks' command-line options (pfdoa.sinks.options): parsing, building one Fanout,
every output written, bad values as one InputError before anything is created."""

from __future__ import annotations

import argparse
import io
import json
import urllib.request

import pytest

from pfdoa.errors import InputError
from pfdoa.output import Writer
from pfdoa.sinks import options
from pfdoa.trace import read_trace

from sink_feed import SITE, scripted_run


def parse(*argv, which=options.OPTIONS):
    p = argparse.ArgumentParser(prog="pfdoa x")
    options.add_arguments(p, which)
    return p, p.parse_args(list(argv))


def test_every_option_builds_its_sink_and_gets_its_calls(tmp_path):
    run = scripted_run()
    site_path = tmp_path / "site.toml"
    site_path.write_text("# scripted\n")
    _, args = parse("--record", str(tmp_path / "run.mcap"), "--frame-id", "pfdoa_site", "--web", "127.0.0.1:0",
                    "--health-json", str(tmp_path / "health.jsonl"), "--readings-out", str(tmp_path / "r.csv"))
    out = io.StringIO()
    fan = options.open_sinks(args, SITE, site_path, Writer(out), particles=lambda: None, metadata={"seed": "3"})
    assert [s.name for s in fan.sinks] == ["output", "web", "mcap", "health-json", "readings"]
    web = fan.sinks[1]
    for r in run.readings:
        fan.reading(r)
    for rec in run.records:
        fan.write(rec)
    for snap, _ in run.snapshots:
        fan.health(snap)
    with urllib.request.urlopen(web.url + "state.json", timeout=30) as resp:
        assert json.loads(resp.read())["records"] == len(run.records)
    assert len(out.getvalue().splitlines()) == len(run.records)
    fan.close()
    assert out.closed and web.closed
    assert len((tmp_path / "health.jsonl").read_text().splitlines()) == 2
    assert len(read_trace(tmp_path / "r.csv")) == len(run.readings)
    from pfdoa.sinks.mcap import open_recording

    rec = open_recording(tmp_path / "run.mcap")
    assert rec.metadata["seed"] == "3" and rec.site_toml == "# scripted\n" and rec.metadata["frame_id"] == "pfdoa_site"
    assert sum(1 for _ in rec.readings()) == len(run.readings)


def test_only_the_options_a_command_supports():
    p, args = parse("--record", "x.mcap", which=("record",))
    assert args.record == "x.mcap" and args.frame_id is None  # the default frame (map) is decided later
    with pytest.raises(SystemExit):
        p.parse_args(["--web", "8080"])
    with pytest.raises(ValueError):
        parse(which=("nope",))
    fan = options.open_sinks(parse()[1], SITE)
    assert len(fan) == 0  # no option: an empty fan-out (and no writer)


@pytest.mark.parametrize("argv,msg", [
    (["--web", "localhost:http"], "--web .*port must be a number"),
    (["--record", "run.bag"], "--record run.bag: the file name must end in .mcap"),
    (["--frame-id", "map frame"], "--frame-id 'map frame'"),
])
def test_bad_values_fail_before_any_file_is_created(tmp_path, monkeypatch, argv, msg):
    monkeypatch.chdir(tmp_path)
    _, args = parse(*argv, "--record" if "--record" not in argv else "--health-json",
                    "out.mcap" if "--record" not in argv else "h.jsonl", "--readings-out", "r.csv")
    with pytest.raises(InputError, match=msg):
        options.open_sinks(args, SITE)
    assert list(tmp_path.iterdir()) == []


def test_a_port_in_use_creates_no_file(tmp_path):
    from pfdoa.sinks.web import WebSink

    with WebSink("0", SITE) as busy:
        _, args = parse("--web", f"127.0.0.1:{busy.port}", "--readings-out", str(tmp_path / "r.csv"))
        with pytest.raises(InputError, match="cannot listen"):
            options.open_sinks(args, SITE)
    assert list(tmp_path.iterdir()) == []


def test_ground_truth_is_interpolated_and_unknown_outside_or_across_gaps(tmp_path):
    from pfdoa.sinks.readings import MAX_GAP_S, GroundTruthFile

    p = tmp_path / "truth.csv"
    p.write_text("# a tracking system's export\nt,x,y,quality\n0.0,0.0,0.0,9\n1.0,1.0,2.0,9\n1.0,5.0,5.0,1\n"
                 f"2.0,1.0,4.0,9\n{2.0 + MAX_GAP_S + 0.5},9.0,9.0,9\n")
    gt = GroundTruthFile(str(p))
    assert gt(0.5) == pytest.approx((0.5, 1.0))
    assert gt(1.0) == (1.0, 2.0)  # the first row of a repeated time
    assert gt(1.5) == pytest.approx((1.0, 3.0))
    assert gt(2.0) == (1.0, 4.0)
    assert gt(2.5) is None  # inside a gap longer than MAX_GAP_S
    assert gt(-0.1) is None and gt(100.0) is None
    sim = tmp_path / "trace.csv"  # the simulator's trace: gt_x,gt_y, empty where unknown
    sim.write_text("t,anchor,rssi_dbm,gt_x,gt_y,seq\n0.0,1,-50,,,0\n0.1,1,-50,1.0,1.0,1\n0.3,2,-51,3.0,1.0,2\n")
    assert GroundTruthFile(str(sim))(0.2) == pytest.approx((2.0, 1.0))


@pytest.mark.parametrize("text,msg", [
    ("t,a,b\n0,1,2\n", r"truth.csv:1: the header needs t and gt_x,gt_y \(or x,y\)"),
    ("t,x,y\n0,1,oops\n", r"truth.csv:2: not a number"),
    ("t,x,y\n0,1,nan\n", r"truth.csv:2: not finite"),
    ("t,x,y\n", "no positions"),
    ("t,x,y\n0,1\n", r"truth.csv:2: too few columns"),
])
def test_a_bad_ground_truth_file_is_one_error_naming_it(tmp_path, text, msg):
    from pfdoa.sinks.readings import GroundTruthFile

    p = tmp_path / "truth.csv"
    p.write_text(text)
    with pytest.raises(InputError, match="--ground-truth .*" + msg):
        GroundTruthFile(str(p))


def test_readings_get_ground_truth_from_the_option(tmp_path):
    truth = tmp_path / "truth.csv"
    truth.write_text("t,x,y\n" + "".join(f"{1_700_000_000 + 0.5 * k!r},{0.5 * k},{0.25 * k}\n" for k in range(21)))
    _, args = parse("--readings-out", str(tmp_path / "r.csv"), "--ground-truth", str(truth))
    run = scripted_run()
    with options.open_sinks(args, SITE) as fan:
        for r in run.readings:
            fan.reading(r)
    tr = read_trace(tmp_path / "r.csv")
    assert tr.has_ground_truth
    assert tr.gt_x.tolist() == pytest.approx([r.t - 1_700_000_000.0 for r in run.readings])
    _, args = parse("--ground-truth", str(truth))
    with pytest.raises(InputError, match="--ground-truth .*give that too"):
        options.open_sinks(args, SITE)


def cli(*argv) -> tuple[int, str]:
    import contextlib

    from pfdoa.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(list(argv))
    return rc, err.getvalue()


def test_the_commands_refuse_outputs_that_are_inputs_or_each_other(tmp_path, site_file):
    site = site_file()
    trace = tmp_path / "t.csv"
    trace.write_text("t,anchor,rssi_dbm\n0.0,0,-50\n")
    rc, err = cli("replay", str(trace), "--config", str(site), "--out", str(tmp_path / "x.jsonl"),
                  "--readings-out", str(trace))
    assert rc == 2 and "--readings-out" in err and "would be overwritten" in err and err.count("\n") == 1
    rc, err = cli("gateway", "--config", str(site), "--replay-capture", str(trace), "--out", str(tmp_path / "a.mcap"),
                  "--record", str(tmp_path / "a.mcap"))
    assert rc == 2 and "same file" in err and err.count("\n") == 1
    rc, err = cli("gateway", "--config", str(site), "--replay-capture", str(trace), "--out", "-", "--health-json", "-")
    assert rc == 2 and "--out and --health-json are standard output" in err and err.count("\n") == 1
    assert sorted(tmp_path.iterdir()) == sorted([trace, site])  # nothing created


def test_replay_needs_a_site_for_a_trace_and_a_readable_recording(tmp_path, site_file):
    trace = tmp_path / "t.csv"
    trace.write_text("t,anchor,rssi_dbm\n0.0,0,-50\n")
    rc, err = cli("replay", str(trace))
    assert rc == 2 and "needs --config" in err and err.count("\n") == 1
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n not really")
    rc, err = cli("replay", str(bad))
    assert rc == 2 and "bad.mcap: not a readable MCAP recording" in err and err.count("\n") == 1
    rc, err = cli("replay", str(trace), "--config", str(site_file()), "--frame-id", "no spaces")
    assert rc == 2 and "--frame-id 'no spaces'" in err


def test_a_trace_replay_records_what_a_recording_replay_reproduces(tmp_path):
    """pfdoa replay TRACE --record: its recording replays to the same output (window mode,
    odometry read whole: the recording says so), and its frame id is the recording's."""
    from pathlib import Path

    ex = Path(__file__).resolve().parents[2] / "examples"
    out, mcap, again = tmp_path / "est.jsonl", tmp_path / "run.mcap", tmp_path / "again.jsonl"
    rc, err = cli("-q", "replay", str(ex / "run.csv"), "--config", str(ex / "site.toml"), "--odom",
                  str(ex / "run.odom.csv"), "--seed", "4", "--frame-id", "pfdoa_site", "--out", str(out),
                  "--record", str(mcap))
    assert rc == 0, err
    from pfdoa.sinks.mcap import open_recording

    rec = open_recording(mcap)
    assert (rec.metadata["mode"], rec.metadata["odometry"], rec.metadata["seed"]) == ("window", "file", "4")
    rc, err = cli("-q", "replay", str(mcap), "--out", str(again))
    assert rc == 0, err
    assert again.read_bytes() == out.read_bytes()
    first = json.loads(out.read_text().splitlines()[0])
    assert first["frame_id"] == "pfdoa_site" and first["stamp"] >= first["t"]
