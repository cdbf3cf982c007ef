"""Hostile and careless input through real `pfdoa` processes (issue 13): signals, closed
and odd standard streams, a terminal, pipes as files, huge files, log floods, and the
issue's first example (a live run's capture replayed). In-process cases are in
tests/unit/test_hostile_units.py; docs/security.md lists every class and its test."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import tty
from pathlib import Path

import hostile_support as hs
import pytest

PY = sys.executable
ROOT = Path(__file__).resolve().parents[2]


def pfdoa(*args, **kw):
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    kw.setdefault("timeout", 120)
    return subprocess.run([PY, "-m", "pfdoa", *map(str, args)], **kw)


@pytest.fixture
def site(tmp_path):
    return hs.write_site(tmp_path / "site.toml")


def _interrupt_replay(tmp_path, site, sig, via_fifo):
    """Start a long replay whose output the test reads slowly (a pipe: the replay blocks
    once it is full, so it is surely running), signal it after 50 records, read the rest."""
    trace = hs.write_trace(tmp_path / "long.csv", 4000)
    stats = tmp_path / "s.json"
    args = [PY, "-m", "pfdoa", "-q", "replay", str(trace), "--config", str(site), "--method", "wcl",
            "--stats", str(stats)]
    if via_fifo:
        fifo = tmp_path / "out.fifo"
        os.mkfifo(fifo)
        proc = subprocess.Popen(args + ["--out", str(fifo)], stderr=subprocess.PIPE, text=True)
        out = open(fifo)  # the replay opens it for writing; this open waits for that
    else:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out = proc.stdout
    try:
        lines = [out.readline() for _ in range(50)]
        proc.send_signal(sig)
        lines += out.readlines()
    finally:
        out.close()
    err = proc.stderr.read()
    rc = proc.wait(timeout=60)
    return rc, err, lines, json.loads(stats.read_text())


@pytest.mark.parametrize("sig, code, via_fifo", [(signal.SIGTERM, 143, True), (signal.SIGINT, 130, False)])
def test_a_signal_during_replay_keeps_what_was_estimated(tmp_path, site, sig, code, via_fifo):
    """The issue: `timeout` on a long replay left an empty output file (exit 143)."""
    rc, err, lines, stats = _interrupt_replay(tmp_path, site, sig, via_fifo)
    recs = [json.loads(ln) for ln in lines]  # every record whole
    assert rc == code, err
    assert 50 <= len(recs) == stats["estimates"] < 4000
    assert [r["t"] for r in recs] == [round(0.1 * k, 6) for k in range(len(recs))]
    name = signal.Signals(sig).name
    assert stats["interrupted"]["signal"] == name and stats["interrupted"]["readings_done"] < 16000
    assert hs.error_line(err).startswith(f"pfdoa: error: stopped by {name} after ")


def _closed(cmd: str, **kw):
    """Run `sh -c 'exec pfdoa ... <redirections>'` (closing descriptors needs a shell)."""
    return subprocess.run(["sh", "-c", f"exec {PY} -m pfdoa {cmd}"], capture_output=True, text=True, timeout=120,
                          cwd=kw.get("cwd"))


def test_closed_standard_streams(tmp_path, site):
    trace = hs.write_trace(tmp_path / "t.csv", 30)
    out = tmp_path / "o.jsonl"
    # all three closed, output to a file: the file gets every record (nothing printed lands in it)
    r = _closed(f"replay {trace} --config {site} --method wcl --out {out} <&- >&- 2>&-")
    assert r.returncode == 0 and [json.loads(ln)["t"] for ln in out.read_text().splitlines()] == \
        [round(0.1 * k, 6) for k in range(30)]
    cap = tmp_path / "c.cap"
    cap.write_text("# pfdoa capture v2\n")
    r = _closed(f"-q gateway --config {site} --replay-capture {cap} --out {out} --stats {tmp_path / 's.json'} "
                "<&- >&- 2>&-")
    assert r.returncode == 0 and json.loads((tmp_path / "s.json").read_text())["estimates"] == 0
    # output to standard output while it is closed: one line, exit 2
    r = _closed(f"-q replay {trace} --config {site} --method wcl >&-")
    assert r.returncode == 2 and hs.error_line(r.stderr) == \
        "pfdoa: error: --out -: standard output is closed; give --out FILE"
    r = _closed(f"-q calibrate {trace} --config {site} >&-")
    assert r.returncode == 2 and "standard output is closed" in hs.error_line(r.stderr)
    for inp in ("--stdin", "--replay-capture -"):
        r = _closed(f"-q gateway --config {site} {inp} --out {out} <&-")
        assert r.returncode == 2 and "standard input is closed" in hs.error_line(r.stderr)
    r = _closed(f"-q replay {tmp_path / 'missing.csv'} --config {site} <&- >&- 2>&-")
    assert r.returncode == 2


def test_a_terminal_as_stdin_is_refused(site):
    """Cooked mode would eat the binary frames."""
    master, slave = os.openpty()
    tty.setraw(master)
    try:
        r = pfdoa("-q", "gateway", "--config", site, "--stdin", stdin=slave)
    finally:
        os.close(slave)
        os.close(master)
    assert r.returncode == 2 and "--stdin is a terminal" in hs.error_line(r.stderr)


def test_a_pipe_is_read_like_a_file(tmp_path):
    """`--config <(...)`: the site file and the trace from pipes (/dev/fd/N)."""
    site_r, site_w = os.pipe()
    trace_r, trace_w = os.pipe()
    rows = "\n".join(hs.trace_rows(20)) + "\n"

    def feed(fd, text):
        with os.fdopen(fd, "w") as fh:
            fh.write(text)

    writers = [threading.Thread(target=feed, args=(site_w, hs.SITE)), threading.Thread(target=feed, args=(trace_w, rows))]
    for w in writers:
        w.start()
    r = pfdoa("-q", "replay", f"/dev/fd/{trace_r}", "--config", f"/dev/fd/{site_r}", "--method", "wcl",
              pass_fds=(site_r, trace_r))
    for w in writers:
        w.join(10)
    os.close(site_r)
    os.close(trace_r)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()) == 20


def test_a_huge_capture_line_is_skipped_with_bounded_memory(tmp_path, site):
    cap = tmp_path / "huge.cap"
    with open(cap, "wb") as fh:
        fh.write(b"# pfdoa capture v2\n(0.5) serial0 S ")
        fh.truncate(256 << 20)  # one 256 MB line (sparse)
        fh.seek(0, 2)
        fh.write(b"\n(1.0) - T\n")
    # VmHWM: this process's peak resident memory (ru_maxrss would carry the forking parent's over exec)
    code = ("import sys; from pfdoa.cli import main; rc = main(sys.argv[1:]); "
            "hwm = [ln for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0].split()[1]; "
            "print('maxrss_kb', hwm, file=sys.stderr); sys.exit(rc)")
    stats = tmp_path / "s.json"
    r = subprocess.run([PY, "-c", code, "-q", "gateway", "--config", str(site), "--replay-capture", str(cap),
                        "--stats", str(stats)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(stats.read_text())["inputs"][str(cap)]["bad_lines"] == 1
    assert "malformed capture line skipped (longer than 8448 characters)" in r.stderr
    rss_mb = int(r.stderr.split("maxrss_kb ")[1].split()[0]) / 1024
    assert rss_mb < 200, rss_mb  # the interpreter, numpy and the estimators: ~100 MB; the line is not held


def test_a_flood_of_one_log_message_is_rate_limited(tmp_path, site):
    """A capture whose times jump by days makes every anchor stale again and again (1,600
    warnings): the log gets ten of those lines and a note, the counters the totals."""
    from pfdoa.protocol.messages import RssiReport
    from pfdoa.protocol.uart import encode_uart

    lines = ["# pfdoa capture v2"]
    for k in range(400):
        t = 130000.0 * k
        for a in hs.ANCHORS:
            frame = encode_uart(RssiReport(k, 1000 + 100 * k, -60 * 256, -60, 1, 37, 0), a)
            lines.append(f"({t + 0.001 * a:.6f}) serial{a} S {frame.hex()}")
        lines.append(f"({t + 3.0:.6f}) - T")  # the timers 3 s on: every anchor stale (stale_after_s 2)
    cap = tmp_path / "jumps.cap"
    cap.write_text("\n".join(lines) + "\n")
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", cap, "--method", "wcl", "--out", os.devnull)
    assert r.returncode == 0, r.stderr[-2000:]
    stale = [ln for ln in r.stderr.splitlines() if " stale: no report for " in ln]
    assert len(stale) == 10 and stale[-1].endswith("(more like this: at most one per 60 s)")
    c = hs.final_counters(r.stderr)
    assert c["inputs"][str(cap)]["time_jumps"] == 399 and c["estimates"] == 400


def test_capture_dash_is_standard_output_not_a_file_named_dash(tmp_path, site):
    cap = tmp_path / "in.cap"
    cap.write_text("# pfdoa capture v2\n(0.5) serial0 S 00\n(1.0) - T\n")
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", cap, "--capture", "-", "--out", tmp_path / "o",
              cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "# pfdoa capture v2\n(0.5) serial0 S 00\n(1) - T\n" and not (tmp_path / "-").exists()
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", cap, "--capture", "-", cwd=tmp_path)
    assert r.returncode == 2 and hs.error_line(r.stderr) == "pfdoa: error: --out and --capture are standard output"
