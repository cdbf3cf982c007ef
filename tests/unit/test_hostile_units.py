"""Hostile and careless input, in process (issue 13): the command line through
``pfdoa.cli.main`` where signals and standard streams do not matter, and the pieces it is
made of (the site-file writer, the trace checks, the capture reader, the live odometry
reader, the log rate limit). tests/io/test_hostile_cli.py runs real processes; the class table
in docs/security.md names the test for each class."""

from __future__ import annotations

import json
import logging
import os
import signal

import hostile_support as hs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pfdoa import _toml as tomllib
from pfdoa.cli import RepeatFilter, main
from pfdoa.errors import ConfigError
from pfdoa.radio import PathLoss
from pfdoa.site import MAX_DEPTH, SITE_ANCHOR_ID_MAX, Anchor, Site, load_site, parse_site, site_to_toml, toml_string


@pytest.fixture
def run(capsys, caplog):
    """main(args) -> (exit status, what it said: stderr, then its log records)."""
    caplog.set_level(logging.WARNING)

    def call(args):
        caplog.clear()
        rc = main([str(a) for a in args])
        return rc, capsys.readouterr().err + caplog.text

    return call


@pytest.fixture
def site(tmp_path):
    return hs.write_site(tmp_path / "site.toml")


# -- site files -----------------------------------------------------------------------------
@pytest.mark.parametrize("body, key, words", [
    ("[radio]\nrssi_at_1m_dbm = " + "[" * 3000 + "]" * 3000 + "\n", "<syntax>", "nested too deeply"),
    ("x = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n", "<syntax>", "nested too deeply"),
    (hs.SITE + "[estimator]\nopt = " + "[" * (MAX_DEPTH + 2) + "]" * (MAX_DEPTH + 2) + "\n", "estimator.opt",
     f"nested more than {MAX_DEPTH}"),
    (hs.SITE.replace("set_timeout_s = 0.3", "set_timeout_s = 1" + "0" * 400), "gateway.set_timeout_s", "finite"),
    (hs.SITE.replace("x = 6.0\ny = 6.0", "x = 6.0\ny = 6" + "0" * 400), "anchors[2].y", "finite"),
    (hs.SITE.replace("id = 3", "id = 3" + "0" * 400), "anchors[2].id", f"0..{SITE_ANCHOR_ID_MAX}"),
    (hs.SITE + "[estimator]\nparticles = 1" + "0" * 400 + "\n", "estimator.particles", "out of range"),
    (hs.SITE + "[estimator]\nparticles = 1" + "0" * 5000 + "\n", "<syntax>", "4300"),
    ("[site]\nname = \"hall\"\nnmae = \"typo\"\n" + hs.SITE, "site.nmae", "unknown key"),
    ("[site]\nname = 3\n" + hs.SITE, "site.name", "must be a string"),
    (hs.SITE + "[gateway.extra]\nx = 1\n", "gateway.extra", "unknown key"),
    (hs.SITE + "[gatway]\nmode = \"seq\"\n", "gatway", "unknown section"),
    (hs.SITE.replace("id = 4", "id = 4\nrssi_ofset_db = 1.0"), "anchors[3].rssi_ofset_db", "unknown key"),
    (hs.SITE + "[estimator]\nparticls = 100\n", "estimator.particls", "unknown estimator option"),
    (hs.SITE + "[estimator]\nmethod = \"oracle\"\n", "estimator.method", "unknown estimator"),
])
def test_bad_site_file_is_one_line_naming_file_and_key(tmp_path, run, body, key, words):
    p = tmp_path / "bad.toml"
    p.write_text(body)
    trace = hs.write_trace(tmp_path / "t.csv", 5)
    rc, err = run(["-q", "replay", trace, "--config", p, "--method", "wcl", "--out", tmp_path / "o.jsonl"])
    assert rc == 2
    line = hs.error_line(err)
    assert f"{p}: {key}: " in line and words in line, line
    assert "0" * 100 not in line  # a 400-digit value is shortened, not echoed


@pytest.mark.parametrize("raw, ok", [
    (b"\xef\xbb\xbf" + hs.SITE.encode(), True),  # a byte order mark (Windows editors)
    (hs.SITE.replace("\n", "\r\n").encode(), True),  # CRLF
    (b"", False), (b"\x00\xff\xfe binary", False), (b"\n" * 3 + b"\xff", False),
])
def test_bom_crlf_empty_and_binary_site_files(tmp_path, raw, ok):
    p = tmp_path / "s.toml"
    p.write_bytes(raw)
    if ok:
        assert load_site(p).anchor_ids == (1, 2, 3, 4)
        return
    with pytest.raises(ConfigError) as e:
        load_site(p)
    assert e.value.source == str(p)
    if raw.endswith(b"\xff"):
        assert e.value.key == "<line 4>"  # the line of the bad byte


def test_a_site_file_is_read_bounded(tmp_path):
    big = tmp_path / "huge.toml"
    with open(big, "wb") as fh:  # 1 GB, sparse: reading it whole would take a GB of memory
        fh.truncate(1 << 30)
    with pytest.raises(ConfigError, match="larger than 1024 KiB"):
        load_site(big)
    with pytest.raises(ConfigError, match="larger than 1024 KiB"):
        load_site("/dev/zero")
    with pytest.raises(ConfigError, match="Is a directory"):
        load_site(tmp_path)


NAMES = ['plain', 'with "quotes"', "back\\slash", "new\nline\ttab", "del\x7f and nul\x00", "caf\u00e9 \U0001F600",
         "'single' and \"\"\"triple\"\"\"", "trailing \\", "\u2028 line separator"]


@pytest.mark.parametrize("name", NAMES)
def test_one_writer_round_trips_hostile_names(tmp_path, name):
    site = Site(PathLoss(-47.25, 2.125), tuple(Anchor(a, x, y, 0.5 if a == 2 else 0.0, name=name if a == 3 else "")
                                             for a, (x, y) in hs.ANCHORS.items()),
                name=name, sections={"site": {"name": name}, "gateway": {"window_s": 0.5, "mode": "window"},
                                     "estimator": {"method": "wcl", "resolution": 0.25},
                                     "output": {"path": name.replace("\x00", "") or "-", "format": "csv"}})
    text = site_to_toml(site)
    p = tmp_path / "s.toml"
    p.write_text(text, encoding="utf-8")
    again = load_site(p)
    assert again.name == name and again.anchors == site.anchors and again.radio == site.radio
    assert again.sections == site.sections
    assert site_to_toml(again) == text


@settings(max_examples=150, deadline=None)
@given(name=st.text(st.characters(blacklist_categories=("Cs",)), max_size=20),
       key=st.text(st.characters(blacklist_categories=("Cs",)), min_size=1, max_size=8),
       value=st.recursive(st.none() | st.booleans() | st.integers(-2**63, 2**63 - 1)
                          | st.floats(allow_nan=False) | st.text(max_size=8),
                          lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=4), c, max_size=3),
                          max_leaves=6))
def test_write_load_write_is_identical_for_any_values(name, key, value):
    """The writer for whatever a site table may hold (TOML has no null: such values are left out)."""
    def strip(v):
        if isinstance(v, list):
            return [strip(x) for x in v if x is not None]
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if x is not None}
        return v

    value = strip(value)
    if value is None:
        return
    site = Site(PathLoss(-45.0, 2.0), tuple(Anchor(a, x, y) for a, (x, y) in hs.ANCHORS.items()), name=name,
                sections={"estimator": {key: value}})
    text = site_to_toml(site)
    again = parse_site(tomllib.loads(text), "<s>")
    assert again.sections["estimator"] == {key: value}
    assert site_to_toml(again) == text


def test_calibrate_writes_what_replay_accepts_whatever_the_name(tmp_path, run):
    """The hostile names crashed calibrate (an unescaped TOML string) or wrote a file that
    replay rejected; a typo in any table was carried over."""
    trace = hs.write_trace(tmp_path / "t.csv", 200)
    for i, name in enumerate(NAMES):
        src = hs.write_site(tmp_path / f"s{i}.toml", "\n[estimator]\nparticles = 300\n")
        src.write_text(f"[site]\nname = {toml_string(name)}\n\n" + src.read_text())
        out = tmp_path / f"fit{i}.toml"
        rc, err = run(["-q", "calibrate", trace, "--config", src, "--out", out])
        assert rc == 0, err
        fitted = load_site(out)
        # the input's [estimator] kept as it was
        assert fitted.name == name and fitted.sections["estimator"] == {"particles": 300}
        assert fitted.radio.path_loss_exponent == pytest.approx(hs.N, abs=1e-3)
        assert run(["-q", "replay", trace, "--config", out, "--method", "wcl", "--out", tmp_path / "o.jsonl"],
                   )[0] == 0
    bad = hs.write_site(tmp_path / "typo.toml", "baud = 9600\n")  # in [gateway], the file's last table
    out = tmp_path / "never.toml"
    rc, err = run(["-q", "calibrate", trace, "--config", bad, "--out", out])
    assert rc == 2 and f"{bad}: gateway.baud: unknown key" in hs.error_line(err) and not out.exists()


def test_the_simulator_writes_its_site_file_with_the_one_writer():
    from pfdoasim.harness import gateway_site_toml
    from pfdoasim.scenario import build

    sc = build("demo", seed=1)
    text = gateway_site_toml(sc, 1.0)
    s = parse_site(tomllib.loads(text), "<sim>")
    assert s.sections["gateway"]["set_timeout_s"] == 0.3 and site_to_toml(s) == text


# -- traces and odometry ----------------------------------------------------------------
@pytest.mark.parametrize("column, value, words", [
    ("t", "nan", "column t: not a finite number"), ("t", "inf", "column t: not a finite number"),
    ("anchor", "nan", "column anchor: not an integer"), ("anchor", "1e400", "column anchor: not an integer"),
    ("rssi_dbm", "-inf", "column rssi_dbm: not a finite number"), ("rssi_dbm", "nan", "not a finite number"),
    ("seq", "inf", "column seq: not an integer"), ("seq", "9" * 30, "integer out of range"),
    ("gt_x", "inf", "column gt_x: not a finite number"), ("gt_y", "-inf", "column gt_y: not a finite number"),
])
def test_non_finite_values_in_every_trace_column(tmp_path, run, site, column, value, words):
    rows = hs.trace_rows(5)
    names = rows[0].split(",")
    fields = rows[3].split(",")
    fields[names.index(column)] = value
    rows[3] = ",".join(fields)
    p = tmp_path / "t.csv"
    p.write_text("\n".join(rows) + "\n")
    rc, err = run(["-q", "replay", p, "--config", site, "--out", tmp_path / "o.jsonl"])
    line = hs.error_line(err)
    assert rc == 2 and line.startswith(f"pfdoa: error: {p}:4: ") and words in line, line


@pytest.mark.parametrize("column", ["t", "dx", "dy", "dtheta"])
@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "x"])
def test_non_finite_values_in_every_odometry_column(tmp_path, run, site, column, value):
    trace = hs.write_trace(tmp_path / "t.csv", 5)
    odom = hs.write_odometry(tmp_path / "o.csv", 5)
    rows = odom.read_text().splitlines()
    fields = rows[2].split(",")
    fields[["t", "dx", "dy", "dtheta"].index(column)] = value
    rows[2] = ",".join(fields)
    odom.write_text("\n".join(rows) + "\n")
    rc, err = run(["-q", "replay", trace, "--config", site, "--odom", odom, "--out", tmp_path / "o.jsonl"])
    assert rc == 2 and f"{odom}:3: column {column}: " in hs.error_line(err)


def test_duplicate_column_names_are_refused(tmp_path, run, site):
    """The last of two rssi_dbm columns used to win silently."""
    p = tmp_path / "dup.csv"
    p.write_text("t,anchor,rssi_dbm,rssi_dbm\n0,1,-60,-200\n")
    rc, err = run(["-q", "replay", p, "--config", site])
    assert rc == 2 and hs.error_line(err).endswith(f"{p}:1: header names column 'rssi_dbm' twice (fields 3 and 4)")
    o = tmp_path / "dup.odom.csv"
    o.write_text("t,dx,dy,dx,dtheta\n0,1,0,0,0\n")
    rc, err = run(["-q", "replay", hs.write_trace(tmp_path / "t.csv", 3), "--config", site, "--odom", o])
    assert rc == 2 and "header names column 'dx' twice" in hs.error_line(err)


def test_crlf_bom_and_unsorted_traces_give_the_same_estimates(tmp_path, run, site):
    rows = hs.trace_rows(40, dt=1.0)
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(rows) + "\n")
    crlf = tmp_path / "crlf.csv"
    crlf.write_bytes(b"\xef\xbb\xbf" + ("\r\n".join(rows) + "\r\n").encode())
    shuffled = tmp_path / "shuffled.csv"
    body = rows[1:]
    np.random.default_rng(3).shuffle(body)
    shuffled.write_text("\n".join([rows[0]] + sorted(body, key=lambda r: float(r.split(",")[0]))[::-1]) + "\n")
    outs = []
    for p in (plain, crlf, shuffled):
        out = tmp_path / (p.stem + ".jsonl")
        rc, err = run(["-q", "replay", p, "--config", site, "--method", "wcl", "--mode", "window", "--out", out])
        assert rc == 0, err
        outs.append(out.read_text())
        assert ("not in time order" in err) == (p is shuffled)
    assert outs[0] == outs[1] == outs[2] and outs[0].count("\n") == 40


def test_whole_second_timestamps_are_said_and_counted(tmp_path, run, site):
    """The issue's case: 61 estimates from 7,212 readings, `replaced` counted, never said."""
    rows = hs.trace_rows(300, per_anchor=6, seq=False)
    p = tmp_path / "whole.csv"
    p.write_text("\n".join([rows[0]] + [f"{int(float(r.split(',')[0]))}," + r.split(",", 1)[1] for r in rows[1:]])
                 + "\n")
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "replay", p, "--config", site, "--method", "wcl", "--out", tmp_path / "o.jsonl",
                   "--stats", stats])
    assert rc == 0, err
    s = json.loads(stats.read_text())
    assert s["readings"] == 300 * 6 * 4 and s["sets"] == 30 and s["combined"] == 7200 - 30 * 4 and s["dropped"] == 0
    assert "every t is a whole number" in err and "were combined with another of the same anchor" in err
    assert "7080 of 7200 readings (98 %)" in err and "60 readings per anchor and second" in err


def test_fast_reporters_are_combined_without_a_warning(tmp_path, run, site):
    """A BLE site at ~37 readings per anchor and second (the issue's case) is combined by
    design: no unit warning. The same readings with t in tenths of seconds read as seconds
    (370 per anchor and second) are warned about."""
    for name, n, warned in (("fast", 370, False), ("tenths", 3700, True)):
        p = hs.write_trace(tmp_path / f"{name}.csv", n, dt=10.0 / n, seq=False)  # 10 s
        stats = tmp_path / f"{name}.json"
        rc, err = run(["-q", "replay", p, "--config", site, "--method", "wcl", "--out", tmp_path / f"{name}.jsonl",
                       "--stats", stats])
        assert rc == 0, err
        s = json.loads(stats.read_text())
        assert s["readings"] == 4 * n and s["combined"] + s["dropped"] > 0.9 * s["readings"]  # both mostly merged
        assert ("were combined with another of the same anchor" in err) == warned, (name, err)


def test_milliseconds_and_odometry_on_another_clock_are_said(tmp_path, run, site):
    ms = hs.write_trace(tmp_path / "ms.csv", 100, t_scale=1000.0)
    rc, err = run(["-q", "replay", ms, "--config", site, "--method", "wcl", "--out", tmp_path / "o.jsonl"])
    assert rc == 0 and f"{ms}: successive times are a median 100 apart: are they milliseconds?" in err
    trace = hs.write_trace(tmp_path / "t.csv", 100)
    odom = hs.write_odometry(tmp_path / "o.csv", 100, t0=1.7e9)
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "replay", trace, "--config", site, "--odom", odom, "--method", "wcl",
                   "--out", tmp_path / "o.jsonl", "--stats", stats])
    assert rc == 0 and f"{odom}: odometry t 1700000000.000..1700000009.900 never overlaps" in err
    assert json.loads(stats.read_text())["odometry"]["without"] == 100
    epoch_ms = hs.write_trace(tmp_path / "epoch.csv", 20)
    epoch_ms.write_text("\n".join([r if i == 0 else f"{1.7e12 + i:.0f}," + r.split(",", 1)[1]
                                   for i, r in enumerate(epoch_ms.read_text().splitlines())]) + "\n")
    rc, err = run(["-q", "replay", epoch_ms, "--config", site, "--method", "wcl", "--out", tmp_path / "o.jsonl"])
    assert rc == 0 and "milliseconds (or finer) since 1970" in err


def test_anchor_ids_that_match_no_site_anchor(tmp_path, run, site):
    """Exit 0, no output and nothing said (without -v) before: now an error naming both id
    sets; some unknown ids are a warning with their counts in the final counters."""
    none = hs.write_trace(tmp_path / "none.csv", 10, ids=(11, 12, 13, 14))
    out = tmp_path / "o.jsonl"
    rc, err = run(["-q", "replay", none, "--config", site, "--out", out])
    assert rc == 2 and hs.error_line(err) == (f"pfdoa: error: {none}: no reading is from an anchor of {site} "
                                               "(trace anchor ids 11, 12, 13, 14; site ids 1, 2, 3, 4)")
    some = hs.write_trace(tmp_path / "some.csv", 10, ids=(1, 2, 3, 9))
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "replay", some, "--config", site, "--method", "wcl", "--out", out, "--stats", stats])
    assert rc == 0 and f"{some}: 10 of 40 readings are from anchor id(s) 9, not in {site}" in err
    s = json.loads(stats.read_text())
    assert s["unknown_anchor"] == 10 and s["unknown_ids"] == {"9": 10} and s["estimates"] == 10
    rc, err = run(["-q", "calibrate", none, "--config", site])
    assert rc == 2 and "no reading is from an anchor of" in hs.error_line(err)


def test_an_empty_odometry_file_is_an_error(tmp_path, run, site):
    odom = tmp_path / "o.csv"
    odom.write_text("t,dx,dy,dtheta\n# nothing\n")
    rc, err = run(["-q", "replay", hs.write_trace(tmp_path / "t.csv", 3), "--config", site, "--odom", odom])
    assert rc == 2 and hs.error_line(err) == f"pfdoa: error: {odom}: no increments after the header"


def test_a_long_trace_line_or_a_huge_file_is_read_bounded(tmp_path, run, site):
    big = tmp_path / "huge.csv"
    with open(big, "wb") as fh:
        fh.write(b"t,anchor,rssi_dbm\n")
        fh.truncate(1 << 30)  # 1 GB of NUL after the header, sparse
    rc, err = run(["-q", "replay", big, "--config", site])
    assert rc == 2 and hs.error_line(err) == f"pfdoa: error: {big}:2: line longer than 4096 characters"


# -- option values ------------------------------------------------------------------------
@pytest.mark.parametrize("extra, words", [
    (["--seed", "-1"], "--seed must be an integer >= 0, got -1"),
    (["--window", "nan"], "--window must be a finite number > 0, got nan"),
    (["--window", "inf"], "--window must be a finite number > 0, got inf"),
    (["--window", "-1"], "--window must be a finite number > 0, got -1.0"),
    (["--method", "oracle"], "--method oracle: unknown estimator"),
])
def test_replay_option_values(tmp_path, run, site, extra, words):
    rc, err = run(["-q", "replay", hs.write_trace(tmp_path / "t.csv", 3), "--config", site, *extra])
    assert rc == 2 and hs.error_line(err).startswith(f"pfdoa: error: {words}")


@pytest.mark.parametrize("extra, words", [
    (["--seed", "-5"], "--seed must be an integer >= 0"),
    (["--duration", "nan"], "--duration must be a finite number > 0"),
    (["--duration", "inf"], "--duration must be a finite number > 0"),
    (["--duration", "-2"], "--duration must be a finite number > 0"),
    (["--window", "0"], "--window must be a finite number > 0"),
    (["--health", "-1"], "--health must be a finite number >= 0"),
    (["--health", "nan"], "--health must be a finite number >= 0"),
    (["--health", "inf"], "--health must be a finite number >= 0"),
])
def test_gateway_option_values(tmp_path, run, site, extra, words):
    cap = tmp_path / "x.cap"
    cap.write_text("# pfdoa capture v2\n")
    rc, err = run(["-q", "gateway", "--config", site, "--replay-capture", cap, *extra])
    assert rc == 2 and words in hs.error_line(err)


def test_more_byte_stream_inputs_than_decoders(tmp_path, run, site):
    args = ["-q", "gateway", "--config", site]
    for i in range(65):
        args += ["--serial", f"loop://{i}"]
    rc, err = run(args)
    assert rc == 2 and "65 byte-stream inputs: the gateway decodes at most 64" in hs.error_line(err)


@pytest.mark.parametrize("extra, words", [
    (["--seed", "-1"], "--seed must be an integer >= 0"),
    (["--duration", "nan"], "--duration must be a finite number > 0"),
    (["--duration", "inf"], "--duration must be a finite number > 0"),
    (["--duration", "0"], "--duration must be a finite number > 0"),
    (["--shadowing-db", "inf"], "--shadowing-db must be a finite number >= 0"),
    (["--noise-db", "nan"], "--noise-db must be a finite number >= 0"),
    (["--wait", "-1"], "--wait must be a finite number >= 0"),
    (["--track", "5"], "--track must be 0 or 1"),
])
def test_sim_option_values(tmp_path, run, extra, words):
    rc, err = run(["-q", "sim", "--scenario", "demo", "--transport", "timed", "--out-dir", tmp_path, *extra])
    assert rc == 2 and words in hs.error_line(err)


def test_sim_paths_that_are_not_files(tmp_path, run):
    rc, err = run(["-q", "sim", "--transport", "timed", "--trace-out", tmp_path])
    assert rc == 2 and f"--trace-out {tmp_path}: is a directory" in hs.error_line(err)
    f = tmp_path / "file"
    f.write_text("")
    rc, err = run(["-q", "sim", "--transport", "timed", "--out-dir", f])
    assert rc == 2 and "not a directory" in hs.error_line(err)


@pytest.mark.parametrize("extra, words", [
    (["--seed", "-1"], "--seed must be an integer >= 0"),
    (["--window", "nan"], "--window must be a finite number > 0"),
    (["--window", "inf"], "--window must be a finite number > 0"),
])
def test_eval_option_values(tmp_path, run, site, extra, words):
    rc, err = run(["-q", "eval", "--traces", hs.write_trace(tmp_path / "t.csv", 3), "--config", site,
                   "--calibration", "none", *extra])
    assert rc == 2 and words in hs.error_line(err)


# -- outputs and inputs ---------------------------------------------------------------------
def test_no_output_may_be_an_input(tmp_path, run, site):
    """Every pair: each was exit 0 with the input gone."""
    trace = hs.write_trace(tmp_path / "t.csv", 10)
    odom = hs.write_odometry(tmp_path / "o.csv", 10)
    stats = tmp_path / "s.json"
    before = {p: p.read_bytes() for p in (trace, odom, site)}
    cases = [
        (["replay", trace, "--config", site, "--out", trace], "--out", "the trace"),
        (["replay", trace, "--config", site, "--out", site], "--out", "--config"),
        (["replay", trace, "--config", site, "--odom", odom, "--out", odom], "--out", "--odom"),
        (["replay", trace, "--config", site, "--stats", trace], "--stats", "the trace"),
        (["replay", trace, "--config", site, "--out", stats, "--stats", stats], "--out and --stats", ""),
        (["replay", trace, "--config", site, "--stats", "-"], "--out and --stats are standard output", ""),
        (["calibrate", trace, "--config", site, "--out", trace], "--out", "a trace"),
        (["calibrate", trace, "--config", site, "--out", site], "--out", "--config"),
        (["eval", "--traces", trace, "--config", site, "--out", trace], "--out", "a trace"),
        (["eval", "--traces", trace, "--config", site, "--out", site], "--out", "a site file"),
    ]
    for args, first, second in cases:
        rc, err = run(["-q", *args])
        line = hs.error_line(err)
        assert rc == 2 and first in line and second in line, (args, line)
    assert {p: p.read_bytes() for p in before} == before


def test_stats_dash_is_standard_output_not_a_file_named_dash(tmp_path, capsys, site, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "o.jsonl"
    rc = main(["-q", "replay", str(hs.write_trace(tmp_path / "t.csv", 10)), "--config", str(site), "--method", "wcl",
               "--out", str(out), "--stats", "-"])
    captured = capsys.readouterr()
    assert rc == 0 and not (tmp_path / "-").exists()
    assert json.loads(captured.out)["estimates"] == 10 == out.read_text().count("\n")


def test_calibrate_and_eval_replace_their_output_whole(tmp_path, run, site, monkeypatch):
    """A signal or an error during the work leaves the old file as it was and no temporary
    file behind (they used to write the file in place)."""
    trace = hs.write_trace(tmp_path / "t.csv", 200)
    report = tmp_path / "report.md"
    report.write_text("old report\n")
    import pfdoa.evaluation

    def interrupted(cfg, out=None, **kw):
        from pfdoa.outfiles import write_whole

        fsync = os.fsync

        def stopped_on_the_way(fd):  # the report's temporary file is written ...
            fsync(fd)
            os.kill(os.getpid(), signal.SIGTERM)  # ... and the run is stopped before the rename

        monkeypatch.setattr(os, "fsync", stopped_on_the_way)
        write_whole(out, "half a rep", "--out")
        raise AssertionError("the signal did not stop it")

    monkeypatch.setattr(pfdoa.evaluation, "evaluate", interrupted)
    rc, err = run(["-q", "eval", "--traces", trace, "--config", site, "--calibration", "none", "--out", report])
    assert rc == 143 and hs.error_line(err) == f"pfdoa: error: stopped by SIGTERM: {report} is left as it was"
    assert report.read_text() == "old report\n" and sorted(os.listdir(tmp_path)) == ["report.md", "site.toml", "t.csv"]
    monkeypatch.undo()
    fitted = tmp_path / "fitted.toml"
    fitted.write_text("old\n")
    os.chmod(fitted, 0o640)
    rc, err = run(["-q", "calibrate", trace, "--config", site, "--out", fitted])
    assert rc == 0, err
    assert load_site(fitted).anchor_ids == (1, 2, 3, 4) and (os.stat(fitted).st_mode & 0o777) == 0o640
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_write_whole_leaves_the_old_file_when_the_write_fails(tmp_path, monkeypatch):
    from pfdoa.errors import OutputError
    from pfdoa.outfiles import write_whole

    p = tmp_path / "x.json"
    p.write_text("old")

    def boom(*a):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match=f"--stats {p}: cannot write: No space left on device"):
        write_whole(p, "new", "--stats")
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["x.json"]


# -- captures and live odometry --------------------------------------------------------------
def _capture(tmp_path, lines):
    return hs.write_capture_lines(tmp_path / "in.cap", lines)


_report_lines = hs.report_lines


def test_capture_sources_beyond_the_decoder_table_are_counted_and_said(tmp_path, run, site):
    lines = []
    for k in range(100):  # every beacon's frames under a new source name
        lines += _report_lines(k, 0.1 * k, source=lambda a, k=k: f"port{k}-{a}")
    cap = _capture(tmp_path, lines)
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "gateway", "--config", site, "--replay-capture", cap, "--method", "wcl",
                   "--out", tmp_path / "o.jsonl", "--stats", stats])
    assert rc == 0, err
    s = json.loads(stats.read_text())
    # Every source decodes and none is idle within the capture's 10 s: the first 64 keep
    # their decoders and the others' chunks are dropped, counted and said by the gateway.
    assert s["sources_dropped"] == 400 - 64 and s["sources_evicted"] == 0
    assert s["reports"] == 64 and s["estimates"] == 16
    assert "byte-stream source 'port16-1': not decoded: the decoder table holds 64 sources" in err


def test_implausible_capture_times_are_counted_and_the_log_is_rate_limited(tmp_path, run, site):
    lines = []
    for k in range(200):  # every beacon a day and a half later than the one before
        lines += _report_lines(k, 130000.0 * k)
    cap = _capture(tmp_path, lines)
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "gateway", "--config", site, "--replay-capture", cap, "--method", "wcl",
                   "--out", tmp_path / "o.jsonl", "--stats", stats])
    assert rc == 0, err
    s = json.loads(stats.read_text())
    assert s["inputs"][str(cap)]["time_jumps"] == 199 and s["estimates"] == 200
    jumps = [ln for ln in err.splitlines() if "capture time jumps" in ln]
    assert len(jumps) == 5 and "more capture times jump; counting them silently (time_jumps)" in err


def test_repeat_filter_limits_one_message_kind_by_the_records_time():
    f = RepeatFilter(burst=3, period_s=60.0)

    def rec(msg, t, args=()):
        r = logging.LogRecord("pfdoa.x", logging.WARNING, __file__, 1, msg, args, None)
        r.created = t
        return r

    shown = [f.filter(rec("anchor %d stale", t, (t,))) for t in range(10)]
    assert shown == [True] * 3 + [False] * 7 and f.suppressed == 7
    assert f.filter(rec("another kind", 5.0))
    late = rec("anchor %d stale", 100.0, (1,))
    assert f.filter(late) and late.getMessage() == "anchor 1 stale (7 more like this suppressed)"


def test_a_live_odometry_line_never_grows_past_the_bound():
    """A 100 kB line arriving in pieces: held to MAX_LINE, counted once, the next line read."""
    from pfdoa.gateway.odomsource import MAX_LINE, OdometryReader
    from pfdoa.gateway.transports import TransportError

    r, w = os.pipe()
    reader = OdometryReader(f"/dev/fd/{r}")
    reader.open()
    items = []
    try:
        os.write(w, b"t,dx,dy,dtheta\n0.0,0.01,0,0\n")
        items += reader.read(0.0)
        for _ in range(50):  # 50 pieces of 2,000 characters, no newline
            os.write(w, b"7" * 2000)
            items += reader.read(0.0)
            assert len(reader._buf) <= MAX_LINE
        os.write(w, b"77\n0.2,0.03,0,0\n")
        os.close(w)
        w = -1
        with pytest.raises(TransportError, match="writer closed"):
            while True:
                items += reader.read(0.0)
    finally:
        reader.close()
        os.close(r)
        if w >= 0:
            os.close(w)
    assert [(i.t_odom, i.dx) for i in items] == [(0.0, 0.01), (0.2, 0.03)]
    assert reader.bad_lines == 1 and reader.lines == 2


def test_eval_sites_with_a_broken_site_or_trace_names_it_and_scores_the_others(tmp_path, run):
    """Every file is read before any work; a broken site in a folder of sites is named (one
    error record each, no traceback), the good site is still scored, and the exit status is 2.
    A folder that is itself the broken site stays one line and exit 2."""
    def sites(case: str):  # a folder of two sites, the second broken (a new path each: the loaders cache)
        root = tmp_path / case
        for name in ("a_good", "b_bad"):
            d = root / name
            d.mkdir(parents=True)
            hs.write_site(d / "site.toml")
            hs.write_trace(d / "r1.csv", 30)
            hs.write_trace(d / "r2.csv", 30)
        return root, root / "b_bad"

    def check(root, bad, why):
        rc, err = run(["-q", "eval", "--sites", root, "--quick", "--methods", "wcl", "--no-progress",
                       "--out", root / "r.md"])
        assert rc == 2 and "Traceback" not in err and f"{why} (site b_bad not evaluated)" in err, err
        report = (root / "r.md").read_text()
        assert "### a_good" in report and "### b_bad" not in report and f"* {why}" in report
        rc, err = run(["-q", "eval", "--sites", bad, "--quick", "--methods", "wcl", "--no-progress"])
        assert rc == 2 and hs.error_line(err) == f"pfdoa: error: {why}"

    root, bad = sites("trace")
    (bad / "r2.csv").write_text("t,anchor,rssi_dbm,gt_x,gt_y\n0,1,-60,1,1\n0,2,loud,1,1\n")
    check(root, bad, f"{bad / 'r2.csv'}:3: column rssi_dbm: not a number: 'loud'")
    root, bad = sites("toml")
    (bad / "site.toml").write_text("[radio]\nrssi_at_1m_dbm = " + "[" * 2000 + "]" * 2000 + "\n")
    check(root, bad, f"{bad / 'site.toml'}: <syntax>: values nested too deeply")
    root, bad = sites("json")
    (bad / "site.toml").unlink()
    (bad / "anchors.json").write_text('{"anchors": ' + "[" * 100000 + "]" * 100000 + "}")
    check(root, bad, f"{bad / 'anchors.json'}: <file>: cannot read JSON: nested too deeply")


def test_security_doc_states_the_input_bounds_of_the_code():
    from pathlib import Path

    from pfdoa import site as site_mod
    from pfdoa.commands._common import MAX_READING_RATE_HZ
    from pfdoa.gateway import odomsource
    from pfdoa.gateway.inputs import capture as transports
    from pfdoa.trace import UNITS_STEP_S, UNIX_MS

    doc = (Path(__file__).resolve().parents[2] / "docs" / "security.md").read_text()
    for text in (f"{site_mod.MAX_FILE_BYTES // 1024} KiB read at most (`site.MAX_FILE_BYTES`)",
                 f"values nested {site_mod.MAX_DEPTH} deep (`site.MAX_DEPTH`)",
                 f"{odomsource.MAX_LINE} bytes (`odomsource.MAX_LINE`)",
                 f"more than {transports.CAPTURE_BACK_S:g} s back or a day ahead",
                 f"more than {MAX_READING_RATE_HZ:g} per second (a BLE advertiser's fastest", f"median step >= {UNITS_STEP_S:g} s",
                 "t beyond 10^11"):
        assert text in doc, text
    assert transports.CAPTURE_LEAP_S == 86400.0 and UNIX_MS == 1e11
    f = RepeatFilter()
    assert f"10, then one per {f.period_s:g} s" in doc and f.burst == 10 and f"<= {f.max_keys} kinds" in doc


def test_replay_to_a_full_disk_says_so_and_exits_1(tmp_path, run, site):
    """It used to exit 0 (the localizer counted the error, nobody said it)."""
    stats = tmp_path / "s.json"
    rc, err = run(["-q", "replay", hs.write_trace(tmp_path / "t.csv", 20), "--config", site, "--method", "wcl",
                   "--out", "/dev/full", "--stats", stats])
    assert rc == 1 and hs.error_line(err) == "pfdoa: error: --out /dev/full: cannot write: No space left on device"
    s = json.loads(stats.read_text())
    assert s["output_error"] == "No space left on device" and s["estimates"] == 20


def test_a_directory_as_live_odometry_is_refused_not_retried(tmp_path, run, site):
    rc, err = run(["-q", "gateway", "--config", site, "--serial", "loop://", "--odom", tmp_path])
    assert rc == 2 and hs.error_line(err) == (f"pfdoa: error: --odom {tmp_path}: is a directory (a file, FIFO or "
                                               "pipe of t,dx,dy,dtheta lines)")


def test_a_device_that_is_not_a_terminal_is_refused_not_retried(tmp_path, run, site):
    """/dev/null opens, but pyserial cannot configure it (ENOTTY): retried for ever before."""
    rc, err = run(["-q", "gateway", "--config", site, "--serial", "/dev/null", "--out", tmp_path / "o.jsonl"])
    assert rc == 2 and hs.error_line(err).startswith("pfdoa: error: --serial /dev/null: not a serial device (")
