"""Nothing lost, nothing harmed (issue 48, part A), through real `pfdoa` processes: every
file the product writes goes through one opening path (pfdoa.outfiles), every command stops
on SIGINT/SIGTERM with what it finished kept (pfdoa.signals), and the command-line errors
of the issue are one line. docs/security.md section 5 lists each class and its test here.

Device nodes are made for the test with os.mknod in its temporary folder (a character
device with /dev/null's numbers), never a system one; FIFOs are real FIFOs; signals are
real signals to the real process. No assertion depends on how fast anything runs: the
tests wait for what the process says or writes, and their timeouts only bound a hang.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import hostile_support as hs
import pytest

PY = sys.executable
HANG_S = 120.0  # hang guards only
NULL_DEV = os.makedev(1, 3)  # /dev/null's numbers, for nodes made in the test's own folder


def pfdoa(*args, **kw) -> subprocess.CompletedProcess:
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    kw.setdefault("timeout", HANG_S)
    return subprocess.run([PY, "-m", "pfdoa", *map(str, args)], **kw)


def start(*args, **kw) -> subprocess.Popen:
    kw.setdefault("stdout", subprocess.PIPE)
    kw.setdefault("stderr", subprocess.PIPE)
    kw.setdefault("text", True)
    return subprocess.Popen([PY, "-m", "pfdoa", *map(str, args)], **kw)


class Lines:
    """A process's stream read line by line in a thread, waited on by content."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._cv = threading.Condition()
        self._th = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._th.start()

    def _read(self, stream) -> None:
        for line in stream:
            with self._cv:
                self.lines.append(line)
                self._cv.notify_all()
        with self._cv:
            self.lines.append("")  # EOF
            self._cv.notify_all()

    def wait_for(self, pred, what: str) -> None:
        with self._cv:
            if not self._cv.wait_for(lambda: any(pred(ln) for ln in self.lines) or "" in self.lines, HANG_S):
                raise AssertionError(f"hang guard: no {what} within {HANG_S:g} s")
            if not any(pred(ln) for ln in self.lines):
                raise AssertionError(f"the stream ended without {what}: {''.join(self.lines)[-3000:]}")

    def text(self) -> str:
        self._th.join(HANG_S)
        return "".join(self.lines)


def wait_file(path: Path, pred, what: str) -> None:
    end = time.monotonic() + HANG_S
    while not (path.exists() and pred(path)):
        assert time.monotonic() < end, f"hang guard: no {what} within {HANG_S:g} s"
        time.sleep(0.02)


def node(path: Path) -> Path:
    os.mknod(path, 0o666 | stat.S_IFCHR, NULL_DEV)
    return path


def is_node(path: Path) -> bool:
    st = os.lstat(path)
    return stat.S_ISCHR(st.st_mode) and st.st_rdev == NULL_DEV


@pytest.fixture
def site(tmp_path):
    return hs.write_site(tmp_path / "site.toml")


@pytest.fixture
def trace(tmp_path):
    return hs.write_trace(tmp_path / "t.csv", 60)


@pytest.fixture
def capture(tmp_path):
    return hs.write_capture(tmp_path / "run.cap", 40)


# -- one output path: devices, links, FIFOs --------------------------------------------------
WRITERS = {  # option -> (command before the option, how its file is named)
    "replay --out": ("replay", "--out", "o.jsonl"),
    "replay --stats": ("replay", "--stats", "s.json"),
    "replay --readings-out": ("replay", "--readings-out", "r.csv"),
    "replay --record": ("replay", "--record", "run.mcap"),
    "gateway --out": ("gateway", "--out", "o.jsonl"),
    "gateway --stats": ("gateway", "--stats", "s.json"),
    "gateway --capture": ("gateway", "--capture", "c.cap"),
    "gateway --readings-out": ("gateway", "--readings-out", "r.csv"),
    "gateway --health-json": ("gateway", "--health-json", "h.jsonl"),
    "gateway --record": ("gateway", "--record", "run.mcap"),
    "calibrate --out": ("calibrate", "--out", "fitted.toml"),
    "eval --out": ("eval", "--out", "report.md"),
}


def writer_cmd(which: str, path: Path, site: Path, trace: Path, capture: Path) -> list:
    cmd, opt, _ = WRITERS[which]
    if cmd == "replay":
        base = ["replay", trace, "--config", site, "--method", "wcl"]
        return base + ([opt, path] if opt == "--out" else [opt, path, "--out", os.devnull])
    if cmd == "gateway":
        base = ["gateway", "--config", site, "--replay-capture", capture, "--method", "wcl", "--seed", "1"]
        return base + ([opt, path] if opt == "--out" else [opt, path, "--out", os.devnull])
    if cmd == "calibrate":
        return ["calibrate", trace, "--config", site, opt, path]
    return ["eval", "--quick", "--no-progress", "--methods", "wcl", "--traces", trace, "--config", site,
            "--calibration", "none", opt, path]


@pytest.mark.parametrize("which", list(WRITERS))
def test_a_device_node_is_written_through_and_a_link_followed(tmp_path, site, trace, capture, which):
    """As root, `--stats /dev/null` used to rename a plain file over /dev/null (every writer
    that wrote whole files did so). Now a device stays the device, a link stays a link and
    the file it names gets the output."""
    name = WRITERS[which][2]
    dev = node(tmp_path / f"dev-{name}")
    r = pfdoa("-q", *writer_cmd(which, dev, site, trace, capture))
    assert r.returncode == 0, r.stderr[-2000:]
    assert is_node(dev), f"{which}: the device node was replaced"
    target = tmp_path / "target" / name
    target.parent.mkdir()
    target.write_text("old\n")
    link = tmp_path / f"link-{name}"
    link.symlink_to(target)
    r = pfdoa("-q", *writer_cmd(which, link, site, trace, capture))
    assert r.returncode == 0, r.stderr[-2000:]
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_bytes() != b"old\n" and target.stat().st_size > 0


@pytest.mark.parametrize("which", ["replay --stats", "calibrate --out", "gateway --readings-out"])
def test_a_fifo_output_gets_the_bytes_and_stays_a_fifo(tmp_path, site, trace, capture, which):
    fifo = tmp_path / WRITERS[which][2]
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    r = pfdoa("-q", *writer_cmd(which, fifo, site, trace, capture))
    reader.join(HANG_S)
    assert r.returncode == 0, r.stderr[-2000:]
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and got and got[0]
    if which == "replay --stats":
        assert json.loads(got[0])["estimates"] == 60


@pytest.mark.parametrize("cmd, sig", [("replay", signal.SIGTERM), ("gateway", signal.SIGINT),
                                      ("calibrate", signal.SIGTERM), ("eval", signal.SIGINT)])
def test_a_fifo_without_a_reader_is_said_and_the_wait_ends_on_a_signal(tmp_path, site, trace, capture, cmd, sig):
    """`open()` of a FIFO nobody reads blocked silently, and `replay` ignored SIGTERM there."""
    fifo = tmp_path / "nobody.reads"
    os.mkfifo(fifo)
    which = {"replay": "replay --out", "gateway": "gateway --out", "calibrate": "calibrate --out",
             "eval": "eval --out"}[cmd]
    p = start(*writer_cmd(which, fifo, site, trace, capture))
    err = Lines(p.stderr)
    err.wait_for(lambda ln: f"waiting for a reader on {fifo}" in ln, "waiting line")
    p.send_signal(sig)
    assert p.wait(HANG_S) == 128 + sig
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert f"stopped by {signal.Signals(sig).name}" in hs.error_line(err.text())


@pytest.mark.parametrize("cmd", ["replay", "calibrate", "gateway"])
def test_an_input_fifo_nobody_writes_ends_on_sigterm(tmp_path, site, cmd):
    """Opening a FIFO with no writer blocks in the kernel; SIGTERM used to be taken as a
    flag there (replay) and the open went on waiting. The test waits until the process is
    in that open (its wchan), then signals."""
    fifo = tmp_path / "nobody.writes"
    os.mkfifo(fifo)
    args = {"replay": ["replay", fifo, "--config", site], "calibrate": ["calibrate", fifo, "--config", site],
            "gateway": ["gateway", "--config", site, "--replay-capture", fifo]}[cmd]
    p = start("-q", *args)
    wchan = Path(f"/proc/{p.pid}/wchan")
    wait_file(wchan, lambda f: f.read_text() == "wait_for_partner" or p.poll() is not None, "the blocked open")
    p.send_signal(signal.SIGTERM)
    assert p.wait(HANG_S) == 143
    assert hs.error_line(p.stderr.read()).startswith("pfdoa: error: stopped by SIGTERM")


# -- an output that is an input --------------------------------------------------------------
@pytest.mark.parametrize("opt", ["--out", "--stats", "--capture", "--readings-out", "--health-json"])
def test_the_gateway_never_truncates_its_own_standard_input(tmp_path, site, capture, opt):
    """`pfdoa gateway --stdin --stats X < X` (and the other outputs) destroyed X."""
    x = tmp_path / "x.bin"
    x.write_bytes(b"\x00\x01\x02 anchor bytes\n" * 50)
    before = x.read_bytes()
    with open(x, "rb") as stdin:
        r = pfdoa("-q", "gateway", "--config", site, "--stdin", opt, x, stdin=stdin)
    assert r.returncode == 2 and hs.error_line(r.stderr) == \
        f"pfdoa: error: {opt} {x} is also standard input: it would be overwritten"
    assert x.read_bytes() == before
    with open(capture, "rb") as stdin:  # the timed stream on standard input: the same
        r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", "-", opt, capture, stdin=stdin)
    assert r.returncode == 2 and "is also" in hs.error_line(r.stderr)


def test_standard_output_that_is_an_input_is_refused(tmp_path, site, trace):
    before = trace.read_bytes()
    with open(trace, "a") as out:  # `pfdoa replay t.csv ... >> t.csv`
        r = subprocess.run([PY, "-m", "pfdoa", "-q", "replay", str(trace), "--config", str(site)], stdout=out,
                           stderr=subprocess.PIPE, text=True, timeout=HANG_S)
    assert r.returncode == 2 and hs.error_line(r.stderr) == \
        "pfdoa: error: --out standard output is also the trace: it would be overwritten"
    assert trace.read_bytes() == before


# -- outputs that fail -----------------------------------------------------------------------
@pytest.mark.parametrize("opt", ["--capture", "--readings-out", "--health-json", "--record", "--stats"])
def test_every_output_that_fails_is_exit_1_after_the_final_counters(tmp_path, site, capture, opt):
    """They used to log one ERROR and exit 0 (only --out gave 1)."""
    full = tmp_path / ("full.mcap" if opt == "--record" else "full")
    full.symlink_to("/dev/full")  # reading /dev/full's node through a link: no system file is written
    out = tmp_path / "o.jsonl"
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", capture, "--method", "wcl", "--out", out,
              opt, full)
    assert r.returncode == 1, r.stderr[-2000:]
    assert hs.final_counters(r.stderr)["estimates"] == 40 == len(out.read_text().splitlines())
    assert "No space left on device" in r.stderr and hs.error_line(r.stderr).startswith(f"pfdoa: error: {opt} ")


@pytest.mark.parametrize("args", [
    ["replay", "{trace}", "--config", "{site}", "--method", "wcl", "--stats", "-", "--out", os.devnull],
    ["calibrate", "{trace}", "--config", "{site}"],
    ["calibrate", "{trace}", "--config", "{site}", "--out", "{tmp}/fitted.toml"],
    ["eval", "--quick", "--no-progress", "--methods", "wcl", "--traces", "{trace}", "--config", "{site}",
     "--calibration", "none"],
    ["anchors", "list", "--serial", "loop://", "--listen", "0.05"],
])
def test_standard_output_on_a_full_disk_is_one_line_and_exit_1(tmp_path, site, trace, args):
    """`> /dev/full` gave OSError tracebacks."""
    argv = [a.format(trace=trace, site=site, tmp=tmp_path) for a in args]
    with open("/dev/full", "w") as full:
        r = subprocess.run([PY, "-m", "pfdoa", "-q", *argv], stdout=full, stderr=subprocess.PIPE, text=True,
                           timeout=HANG_S)
    assert r.returncode == 1 and "No space left on device" in hs.error_line(r.stderr)
    if "--out" in argv and argv[0] == "calibrate":  # the fitted site is written before the report fails
        assert "[radio]" in (tmp_path / "fitted.toml").read_text()


# -- a restarted gateway ---------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["jsonl", "csv"])
def test_a_restarted_gateway_continues_its_logs(tmp_path, site, capture, fmt):
    """`--out` and `--capture` wiped the previous log of a restarted gateway."""
    out, cap, rd, health = (tmp_path / n for n in ("o.out", "c.cap", "r.csv", "h.jsonl"))
    args = ["-q", "gateway", "--config", site, "--replay-capture", capture, "--method", "wcl", "--seed", "1",
            "--format", fmt, "--out", out, "--capture", cap, "--readings-out", rd, "--health-json", health]
    first = pfdoa(*args)
    assert first.returncode == 0, first.stderr[-2000:]
    one = out.read_text().splitlines()
    cap_one = cap.read_text().splitlines()
    second = pfdoa(*args)
    assert second.returncode == 0, second.stderr[-2000:]
    both = out.read_text().splitlines()
    assert both == one + (one[1:] if fmt == "csv" else one)  # the CSV header once
    assert cap.read_text().splitlines()[: len(cap_one)] == cap_one
    assert cap.read_text().count("# pfdoa capture v2") == 1 and "# pfdoa: a new run at " in cap.read_text()
    from pfdoa.trace import read_trace

    assert len(read_trace(rd)) == 2 * 40 * 4  # one trace, both runs' readings, one header
    assert len(health.read_text().splitlines()) >= 2
    assert cap.read_text().count(" S ") == 2 * 40 * 4  # both runs' chunks


def test_a_file_the_gateway_cannot_continue_is_moved_aside(tmp_path, site, capture):
    out, rec = tmp_path / "o.jsonl", tmp_path / "run.mcap"
    out.write_text("t,x,y\n1,2,3\n")  # a CSV where JSON lines go
    rec.write_bytes(b"an earlier recording")
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", capture, "--method", "wcl", "--out", out,
              "--record", rec)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "o.jsonl.1").read_text() == "t,x,y\n1,2,3\n"
    assert (tmp_path / "run.mcap.1").read_bytes() == b"an earlier recording"
    assert len(out.read_text().splitlines()) == 40 and rec.read_bytes()[:5] == b"\x89MCAP"
    assert "kept as" in r.stderr


# -- signals, every command ------------------------------------------------------------------
def test_the_gateway_stops_on_sigterm_with_its_counters_and_outputs(tmp_path, site):
    """A live gateway (a timed stream on a pipe that stays open) stopped by SIGTERM: 143,
    the final counters, every estimate it made in its --out and --readings-out."""
    out, rd = tmp_path / "o.jsonl", tmp_path / "r.csv"
    p = start("-q", "gateway", "--config", site, "--replay-capture", "-", "--method", "wcl", "--out", out,
              "--readings-out", rd, stdin=subprocess.PIPE)
    err = Lines(p.stderr)
    lines = [ln for k in range(30) for ln in hs.report_lines(k, 0.1 * k)]
    p.stdin.write("# pfdoa capture v2\n" + "".join(ln + "\n" for ln in lines))
    p.stdin.flush()
    wait_file(out, lambda f: len(f.read_text().splitlines()) >= 29, "estimates")
    p.send_signal(signal.SIGTERM)
    assert p.wait(HANG_S) == 143
    p.stdin.close()
    text = err.text()
    c = hs.final_counters(text)
    assert c["estimates"] == len(out.read_text().splitlines()) >= 29
    assert hs.error_line(text).startswith("pfdoa: error: stopped by SIGTERM after ")
    from pfdoa.trace import read_trace

    assert len(read_trace(rd)) == c["readings"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_eval_stops_its_pool_on_a_signal(tmp_path, site, sig):
    """Each signal used to abort only the running task; the evaluation ran on for minutes
    and exited 0. SIGINT goes to the whole process group, as a terminal's Ctrl-C does."""
    report = tmp_path / "report.md"
    report.write_text("old report\n")
    p = start("eval", "--jobs", "2", "--out", report, start_new_session=True)  # minutes of work
    err = Lines(p.stderr)
    err.wait_for(lambda ln: ln.startswith("pfdoa eval ["), "progress line")
    workers = Path(f"/proc/{p.pid}/task/{p.pid}/children").read_text().split()
    assert workers  # the pool is running
    if sig == signal.SIGINT:
        os.killpg(p.pid, sig)
    else:
        p.send_signal(sig)
    assert p.wait(HANG_S) == 128 + sig
    line = hs.error_line(err.text())
    assert line.startswith(f"pfdoa: error: stopped by {signal.Signals(sig).name} after ") and \
        line.endswith(f"evaluation jobs: {report} is left as it was")
    assert report.read_text() == "old report\n" and sorted(os.listdir(tmp_path)) == ["report.md", "site.toml"]
    assert not [w for w in workers if Path(f"/proc/{w}").exists()], "pool workers left running"


def _pty():
    import pty
    import tty

    master, slave = pty.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


@pytest.mark.parametrize("action, sig", [("list", signal.SIGINT), ("set", signal.SIGTERM),
                                         ("apply", signal.SIGINT)])
def test_anchors_stop_listening_and_retrying_on_a_signal(tmp_path, site, action, sig):
    """`pfdoa anchors list/set` ignored Ctrl-C until their listen time or retries ended."""
    master, slave, path = _pty()
    try:
        extra = {"list": ["--listen", "600"], "set": ["--anchor", "1", "--offset-db", "1"],
                 "apply": [site]}[action]
        p = start("anchors", action, *extra, "--serial", path, "--timeout", "600", "--reply-timeout", "300")
        err = Lines(p.stderr)
        if action == "list":
            err.wait_for(lambda ln: "listening up to 600 s" in ln, "listening line")
        else:  # its first CONFIG_SET reaches the anchors' line
            os.set_blocking(master, True)
            assert os.read(master, 1)
        p.send_signal(sig)
        rc = p.wait(HANG_S)
        out = p.stdout.read()
    finally:
        os.close(master)
        os.close(slave)
    text = err.text()
    assert rc == 128 + sig, text[-3000:]
    assert "Traceback" not in text and f"stopped by {signal.Signals(sig).name}" in hs.error_line(text)
    if action == "list":
        assert out.startswith("anchor  link") and "no anchor heard before the stop" in text
    else:
        assert "0 of" in out and "stopped: waiting for its acks" in text


def test_sim_stops_on_sigterm_with_its_trace_and_summary(tmp_path):
    """SIGTERM killed `pfdoa sim` with nothing written."""
    out_dir = tmp_path / "sim"
    p = start("-q", "sim", "--scenario", "demo", "--transport", "timed", "--duration", "600", "--out-dir",
              out_dir)
    # Not reading on: its stream (about 1 MB) fills the pipe, so the run cannot end before the signal.
    assert " S " in p.stdout.readline() + p.stdout.readline()
    p.send_signal(signal.SIGTERM)
    drain = threading.Thread(target=p.stdout.read, daemon=True)
    drain.start()
    assert p.wait(HANG_S) == 143
    err = p.stderr.read()
    assert hs.error_line(err).startswith("pfdoa: error: stopped by SIGTERM")
    summary = json.loads((out_dir / "trace.summary.json").read_text())
    from pfdoa.trace import read_trace

    tr = read_trace(out_dir / "trace.csv")
    assert 0 < summary["beacons"] < 6000 and tr.seq is not None and int(tr.seq.max()) == summary["beacons"] - 1
    assert f"demo: {summary['beacons']} beacons" in err


# -- command-line errors ---------------------------------------------------------------------
@pytest.mark.parametrize("stdin", ["devnull", "pipe"])
def test_anchors_list_on_standard_input_that_ends(tmp_path, stdin):
    """A TransportEOF traceback."""
    kw = {"stdin": subprocess.DEVNULL} if stdin == "devnull" else {"input": "not anchors\n"}
    r = pfdoa("anchors", "list", "--stdin", "--listen", "600", **kw)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "pfdoa: anchors: no anchor heard before the input ended" in r.stderr


@pytest.mark.parametrize("what", ["anchors", "truth"])
def test_absurd_coordinates_are_one_line(tmp_path, site, trace, what):
    """Anchors at +-1e308 or ground truth at 1e200: LinAlgError tracebacks in calibrate (and replay)."""
    if what == "anchors":
        site.write_text(site.read_text().replace("x = 6.0", "x = 1e308").replace("y = 0.0", "y = -1e308"))
        cmds = [["calibrate", trace, "--config", site], ["replay", trace, "--config", site, "--out", os.devnull]]
        want = "must be within +-1e+07 m"
    else:
        rows = trace.read_text().splitlines()
        trace.write_text("\n".join([rows[0]] + [",".join(r.split(",")[:3] + ["1e200"] + r.split(",")[4:])
                                                for r in rows[1:]]) + "\n")
        cmds = [["calibrate", trace, "--config", site]]
        want = "column gt_x: 1e+200 m is beyond"
    for cmd in cmds:
        r = pfdoa("-q", *cmd)
        assert r.returncode == 2 and want in hs.error_line(r.stderr), r.stderr[-2000:]


def test_anchors_apply_checks_offsets_as_set_does_and_notes_only_what_applied(tmp_path, site):
    """apply clamped 200 dB to -128 and said it was done; after 0 of N it still told the user
    to zero the site's offsets."""
    bad = tmp_path / "bad.toml"
    bad.write_text(site.read_text().replace("id = 2\n", "id = 2\nrssi_offset_db = 200\n"))
    r = pfdoa("anchors", "apply", bad, "--serial", "loop://")
    s = pfdoa("anchors", "set", "--anchor", "2", "--offset-db", "-200", "--serial", "loop://")
    assert r.returncode == s.returncode == 2
    assert hs.error_line(r.stderr).endswith("must be in [-128, 127.996] dB, got -200")
    assert hs.error_line(s.stderr) == "pfdoa: error: --offset-db must be in [-128, 127.996] dB, got -200"
    fitted = tmp_path / "fitted.toml"
    fitted.write_text(site.read_text().replace("id = 2\n", "id = 2\nrssi_offset_db = 1.5\n"))
    # loop:// hears only its own frames: no anchor acks, 0 of 4 done
    r = pfdoa("anchors", "apply", fitted, "--serial", "loop://", "--retries", "1", "--reply-timeout", "0.05")
    assert r.returncode == 1 and "offsets: 0 of 4 anchors done" in r.stdout
    assert "note:" not in r.stdout and "rssi_offset_db = 0" not in r.stdout


def test_the_csv_beacon_column_is_quoted_and_safe_in_a_spreadsheet(tmp_path, site):
    """Beacon ids with commas, quotes and formulas were written raw into --format csv."""
    from pfdoa.output import csv_text

    ids = ["a,b", 'say "hi"', '=HYPERLINK("http://x","y")', "+1", "-2", "@SUM(A1)", "'quoted", "plain"]
    rows = ["t,anchor,rssi_dbm,beacon"]
    for k, b in enumerate(ids):  # the trace as our writers write it (a leading ' is the reader's to remove)
        quoted = '"' + csv_text(b).replace('"', '""') + '"'
        rows += [f"{k}.{a},{a},{hs.rssi(a, (3.0, 3.0))},{quoted}" for a in hs.ANCHORS]
    trace = tmp_path / "b.csv"
    trace.write_text("\n".join(rows) + "\n")
    out, rd = tmp_path / "o.csv", tmp_path / "r.csv"
    r = pfdoa("-q", "replay", trace, "--config", site, "--method", "wcl", "--format", "csv", "--out", out,
              "--readings-out", rd)
    assert r.returncode == 0, r.stderr[-2000:]
    with open(out, newline="") as fh:
        got = [row["beacon"] for row in csv.DictReader(fh)]
    assert set(got) == {csv_text(b) for b in ids}
    assert all(not g.startswith(("=", "+", "-", "@")) for g in got)
    assert csv_text("=x") == "'=x" and csv_text("'q") == "''q" and csv_text("a,b") == "a,b"
    from pfdoa.trace import read_trace

    assert sorted(set(read_trace(rd).beacon.tolist())) == sorted(ids)  # the trace reads back every id as it was


@pytest.mark.parametrize("kind", ["trace", "gz", "mcap"])
def test_replay_capture_of_a_trace_or_a_recording_says_what_it_is(tmp_path, site, trace, kind):
    """Warnings, 0 estimates, exit 0."""
    if kind == "mcap":
        path = tmp_path / "run.mcap"
        assert pfdoa("-q", "replay", trace, "--config", site, "--method", "wcl", "--record", path,
                     "--out", os.devnull).returncode == 0
        want = f"an MCAP recording, not a capture; replay it with 'pfdoa replay {path}'"
    elif kind == "gz":
        import gzip

        path = tmp_path / "t.csv.gz"
        path.write_bytes(gzip.compress(trace.read_bytes()))
        want = f"compressed (gzip), and a capture is plain text; a trace (.csv.gz) is replayed with 'pfdoa replay {path} --config SITE.toml'"
    else:
        path = trace
        want = f"a trace (t,anchor,rssi_dbm), not a capture; replay it with 'pfdoa replay {path} --config SITE.toml'"
    r = pfdoa("-q", "gateway", "--config", site, "--replay-capture", path)
    assert r.returncode == 2 and hs.error_line(r.stderr) == f"pfdoa: error: --replay-capture {path}: {want}"


def test_a_serial_port_that_is_not_there_is_waited_for_then_given_up(tmp_path, site):
    """It was retried for ever with the unplugged cable's message."""
    absent = tmp_path / "ttyACM9"
    r = pfdoa("-q", "gateway", "--config", site, "--serial", absent, "--wait-for-device", "0")
    assert r.returncode == 2 and hs.error_line(r.stderr) == \
        f"pfdoa: error: --serial {absent}: not present (--wait-for-device 0)"
    p = start("-q", "gateway", "--config", site, "--serial", absent, "--health", "0")
    err = Lines(p.stderr)
    err.wait_for(lambda ln: f"waiting for {absent} (not present)" in ln, "waiting line")
    p.send_signal(signal.SIGTERM)
    assert p.wait(HANG_S) == 143
    text = err.text()
    assert text.count("(not present)") == 1 and "retrying" not in text  # said once a minute, not per retry
    assert hs.final_counters(text)["frames"] == 0


def test_a_device_this_user_may_not_open_is_exit_2_not_retried(tmp_path, site):
    """Permission denied is for ever. Root may open anything, so the process runs without
    the capabilities that let it (setpriv, util-linux) on a node made for the test."""
    dev = tmp_path / "ttyLOCKED"
    os.mknod(dev, 0o000 | stat.S_IFCHR, NULL_DEV)
    caps = "-dac_override,-dac_read_search"
    r = subprocess.run(["setpriv", "--bounding-set", caps, "--inh-caps", caps, PY, "-m", "pfdoa", "-q", "gateway",
                        "--config", str(site), "--serial", str(dev)], capture_output=True, text=True,
                       timeout=HANG_S)
    assert r.returncode == 2 and hs.error_line(r.stderr).startswith(
        f"pfdoa: error: --serial {dev}: permission denied"), r.stderr[-2000:]


def test_sim_without_calibration_leaves_a_calibrated_runs_site_file(tmp_path):
    """`make demo` (calibrated) wrote build/sim/demo/site.toml, which the next `pfdoa sim`
    of the scenario replaced with the room's true model: the two now have their own folders."""
    r = pfdoa("-q", "sim", "--scenario", "demo", "--gateway", "--duration", "4", "--calibrate", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    calibrated = tmp_path / "build/sim/demo-calibrated/site.toml"
    fitted = calibrated.read_text()
    assert "[radio]" in fitted and (tmp_path / "build/sim/demo-calibrated/calibration/fitted.toml").exists()
    r = pfdoa("-q", "sim", "--scenario", "demo", "--transport", "timed", "--duration", "2", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert calibrated.read_text() == fitted
    assert (tmp_path / "build/sim/demo/site.toml").read_text() != fitted
