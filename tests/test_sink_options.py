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
    assert args.record == "x.mcap" and args.frame_id == "map"
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
