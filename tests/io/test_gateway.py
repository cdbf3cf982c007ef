"""`pfdoa gateway` end to end: another process writes anchor frames into a pseudo-terminal
(UART) or plays an SLCAN adapter on one (CAN); the gateway prints positions."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import can
import numpy as np
import pytest

import gateway_feed as feed

PY = sys.executable
FEED = feed.__file__


@pytest.fixture
def site(site_file):
    return site_file("[gateway]\nhealth_interval_s = 0.5\nstale_after_s = 1.0\n")


def pty_pair():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def gateway(args, **kw):
    return subprocess.Popen([PY, "-m", "pfdoa", "gateway", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def read_lines(proc, n, timeout):
    """Read up to n output lines within timeout (a thread, so a silent gateway cannot hang us)."""
    return read_until(proc, lambda lines: len(lines) >= n, timeout)


def read_until(proc, done, timeout):
    """Read output lines until done(lines) holds; timeout only bounds a hang."""
    lines = []

    def reader():
        for line in proc.stdout:
            lines.append(line)
            if done(lines):
                return

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    th.join(timeout)
    return lines


def stop(proc, sig=signal.SIGTERM):
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"gateway did not stop on {sig}: {err[-2000:]}")
    return out, err


def final_counters(err):
    lines = [ln for ln in err.splitlines() if ln.startswith("pfdoa: final ")]
    assert len(lines) == 1, err[-3000:]
    return json.loads(lines[0][len("pfdoa: final "):])


def check_positions(lines, seq_known=True):
    recs = [json.loads(ln) for ln in lines]
    assert recs
    for r in recs:
        assert set(r) >= {"t", "x", "y", "sigma", "doa", "seq", "anchors", "missing", "stale"}
    # every set complete, except perhaps the one cut short by the stop (flushed as it was)
    for r in recs[:-1]:
        assert r["anchors"] == [0, 1, 2, 3] and r["missing"] == []
        if seq_known:
            assert isinstance(r["seq"], int)
    # noise-free reports: trilateration lands on the transmitter
    assert np.hypot(recs[-2]["x"] - feed.TRUE_POS[0], recs[-2]["y"] - feed.TRUE_POS[1]) < 0.05
    return recs


def test_frames_from_another_process_through_pty_become_positions(site, tmp_path):
    master, slave, path = pty_pair()
    writer = subprocess.Popen([PY, FEED, "uart", str(master), "30"], pass_fds=[master])
    cap = tmp_path / "run.cap"
    gw = gateway(["--config", str(site), "--serial", path, "--method", "trilateration", "--capture", str(cap)])
    os.close(slave)
    try:
        lines = read_lines(gw, 40, timeout=20)
        out, err = stop(gw, signal.SIGINT)
    finally:
        writer.kill()
        writer.wait()
        os.close(master)
    assert gw.returncode == 130, err[-2000:]
    recs = check_positions(lines + out.splitlines())
    seqs = [r["seq"] for r in recs]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    c = final_counters(err)
    assert c["estimates"] == len(recs)
    assert c["reports"] >= 4 * len(recs)
    assert c["errors"].get("bad_cobs", 0) + c["errors"].get("bad_version", 0) >= 1  # the garbage
    assert "health:" in err
    # The capture replays to the same positions.
    rp = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", str(cap),
                         "--method", "trilateration"], capture_output=True, text=True, timeout=60)
    assert rp.returncode == 0, rp.stderr[-2000:]
    replayed = [json.loads(ln) for ln in rp.stdout.splitlines()]
    assert [r["seq"] for r in replayed][: len(recs)] == seqs
    assert [(r["x"], r["y"]) for r in replayed][: len(recs)] == [(r["x"], r["y"]) for r in recs]


def test_serial_port_unplugged_and_back_is_reopened(site, tmp_path):
    link = str(tmp_path / "ttyANCHORS")
    writer = subprocess.Popen([PY, FEED, "unplug", link, "120"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    assert writer.stdout.readline().strip() == "ready"
    gw = gateway(["--config", str(site), "--serial", link, "--method", "trilateration"])
    lines = []
    th = threading.Thread(target=lambda: lines.extend(gw.stdout), daemon=True)  # until EOF
    th.start()
    try:
        end = time.monotonic() + 20
        while len(lines) < 5 and time.monotonic() < end:  # positions are flowing
            time.sleep(0.05)
        assert len(lines) >= 5
        writer.stdin.write("\n")
        writer.stdin.flush()
        unplug_seq = int(writer.stdout.readline().split()[1])
        # The feed writes until told to stop: however long the reopen takes, positions come.
        end = time.monotonic() + 60
        while not any(json.loads(ln)["seq"] > unplug_seq + 50 for ln in lines[-5:]):  # positions after it
            assert time.monotonic() < end, "hang guard"
            time.sleep(0.05)
        writer.stdin.write("\n")
        writer.stdin.flush()
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=10)
        th.join(5)
        err = gw.stderr.read()
    finally:
        writer.kill()
        gw.kill()
    assert gw.returncode == 143, err[-2000:]
    c = final_counters(err)
    assert c["reconnects"].get("serial0", 0) >= 1, err[-3000:]
    seqs = [json.loads(ln)["seq"] for ln in lines]
    # positions before and after the unplug (the feed's sequence continues across it)
    assert min(seqs) < unplug_seq and max(seqs) > unplug_seq + 50, (unplug_seq, seqs[:3], seqs[-3:])


def test_slcan_adapter_on_pty_through_gateway(site):
    master, slave, path = pty_pair()
    writer = subprocess.Popen([PY, FEED, "slcan", str(master), "30"], pass_fds=[master])
    gw = gateway(["--config", str(site), "--can", f"slcan:{path}@500000", "--method", "trilateration"])
    os.close(slave)
    try:
        lines = read_lines(gw, 20, timeout=20)
        out, err = stop(gw)
    finally:
        writer.kill()
        writer.wait()
        os.close(master)
    assert gw.returncode == 143, err[-2000:]
    check_positions(lines + out.splitlines())


def test_virtual_can_bus_in_process(site, tmp_path, capsys):
    """python-can's virtual bus is per process: the anchors run in a thread here."""
    from pfdoa.cli import main
    from pfdoa.protocol.can import encode_can

    stop_ev = threading.Event()

    def anchors():
        with can.Bus(interface="virtual", channel="pfdoa_gw_vc") as bus:
            seq = 0
            while not stop_ev.is_set():
                for a, m in feed.reports(seq):
                    for cid, data in encode_can(m, a):
                        bus.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
                seq += 1
                time.sleep(0.01)

    th = threading.Thread(target=anchors, daemon=True)
    th.start()
    out = tmp_path / "pos.csv"
    try:
        rc = main(["gateway", "--config", str(site), "--can", "virtual:pfdoa_gw_vc", "--method", "trilateration",
                   "--duration", "1.5", "--format", "csv", "--out", str(out)])
    finally:
        stop_ev.set()
        th.join(2)
    assert rc == 0
    lines = out.read_text().splitlines()
    assert lines[0] == ("t,x,y,sigma,doa,seq,anchors,missing,stale,rebooted,r95,cov,lost,frame_id,stamp,beacon,heading,"
                        "heading_var,room,room_p,floor,floor_p")
    rows = [ln.split(",") for ln in lines[1:]]
    assert len(rows) > 10
    assert all(r[6] == "0;1;2;3" and r[7] == "" for r in rows)
    x, y = float(rows[-1][1]), float(rows[-1][2])
    assert np.hypot(x - feed.TRUE_POS[0], y - feed.TRUE_POS[1]) < 0.05


def timed_stream(rows) -> bytes:
    """A v1 timed stream (the capture format) from (t, source, bytes) rows."""
    from pfdoa.gateway.inputs.capture import CAPTURE_V1, capture_line
    from pfdoa.gateway.transports import Chunk

    return (CAPTURE_V1 + "\n" + "".join(capture_line(Chunk(src, t, data)) for t, src, data in rows)).encode()


def test_timed_stream_on_stdin_and_a_stale_anchor(site):
    """A timed stream on standard input (--replay-capture -): anchor 3 stops at beacon 100;
    1 s of stream time later (stale_after_s) it is stale. The timers run on the stream's
    times: no wall-clock wait, and the same output however fast it is read."""
    from pfdoa.protocol.uart import encode_uart

    rows = [(1_700_000_000.0 + 0.02 * seq, "serial0", encode_uart(m, a))
            for seq in range(200) for a, m in feed.reports(seq) if not (a == 3 and seq >= 100)]
    outs = []
    for _ in range(2):
        r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", "-",
                            "--method", "wcl"], input=timed_stream(rows), capture_output=True, timeout=60)
        assert r.returncode == 0, r.stderr.decode()[-2000:]
        outs.append(r.stdout)
    assert outs[0] == outs[1]
    recs = [json.loads(ln) for ln in outs[0].splitlines()]
    assert len(recs) == 200
    assert recs[0]["missing"] == [] and recs[99]["missing"] == [] and recs[-1]["missing"] == [3]
    # Anchor 3 turns stale 1 s of stream time after its last report (at 1.98 s): the first
    # set flagged is the first to leave after 2.98 s, i.e. set k leaving by its 0.25 s
    # timeout at 0.02 k + 0.25 s (k = 137), not one before.
    first_stale = next(i for i, x in enumerate(recs) if x["stale"] == [3])
    assert first_stale in (137, 138), first_stale
    assert all(x["stale"] == [] for x in recs[:first_stale])
    c = final_counters(r.stderr.decode())
    assert c["anchors"]["3"]["stale"] is True and c["sets"] == 200


def test_window_mode_over_stdin(site):
    """--mode window: sets by receive time. The 30 beacons arrive in one burst, so they fall
    in one window, which averages each anchor's 30 reports and closes at the end of input."""
    from pfdoa.protocol.uart import encode_uart

    data = b"".join(encode_uart(m, a) for seq in range(30) for a, m in feed.reports(seq))
    r = subprocess.run([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--stdin", "--mode", "window",
                        "--method", "trilateration"], input=data, capture_output=True, timeout=60)
    assert r.returncode == 0, r.stderr.decode()[-2000:]
    recs = [json.loads(ln) for ln in r.stdout.decode().splitlines()]
    assert len(recs) == 1
    assert all(x["seq"] is None and x["missing"] == [] for x in recs)
    assert np.hypot(recs[-1]["x"] - feed.TRUE_POS[0], recs[-1]["y"] - feed.TRUE_POS[1]) < 0.05


def test_two_serial_ports_at_once(site):
    """Anchors 0 and 2 on one port, 1 and 3 on another: the sets are complete."""
    (m1, s1, p1), (m2, s2, p2) = pty_pair(), pty_pair()
    writer = subprocess.Popen([PY, FEED, "uart", f"{m1},{m2}", "120"], pass_fds=[m1, m2])
    gw = gateway(["--config", str(site), "--serial", p1, "--serial", p2, "--method", "trilateration"])
    os.close(s1)
    os.close(s2)

    # The two ports open in their own threads: until both are open, sets time out partial
    # (how many depends on the machine's load), so wait for the first complete set and 30 more.
    def first_complete(lines):
        return next((i for i, ln in enumerate(lines) if json.loads(ln)["missing"] == []), None)

    try:
        lines = read_until(gw, lambda ls: (i := first_complete(ls)) is not None and len(ls) - i > 30, timeout=90)
        out, err = stop(gw)
    finally:
        writer.kill()
        writer.wait()
        os.close(m1)
        os.close(m2)
    assert gw.returncode == 143, err[-2000:]
    lines = lines + out.splitlines()
    first = first_complete(lines)
    assert first is not None, f"no complete set in {len(lines)} lines: {err[-2000:]}"
    recs = check_positions(lines[first:])
    assert len(recs) >= 20
    c = final_counters(err)
    assert c["errors"].get("bad_cobs", 0) + c["errors"].get("bad_version", 0) >= 2  # garbage on both


def test_capture_replay_runs_timers_on_recorded_time(site, tmp_path):
    """Anchor 3 reports 0.1 s after the others (within set_timeout_s), then falls silent:
    the replayed sets are complete until then, and later ones leave by timeout, not late.
    (A v1 stream: its timers run at each chunk's time.)"""
    from pfdoa.protocol.uart import encode_uart

    cap = tmp_path / "old.cap"
    t0 = 1_600_000_000.0  # long ago: the wall clock must not drive the replay's timers
    rows = [(t0 + seq * 0.2 + (0.1 if a == 3 else 0.0), "serial0", encode_uart(m, a))
            for seq in range(40) for a, m in feed.reports(seq) if not (a == 3 and seq >= 30)]
    cap.write_bytes(timed_stream(sorted(rows, key=lambda r: r[0])))
    stats = tmp_path / "s.json"
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(site), "--replay-capture", str(cap),
                        "--method", "trilateration", "--stats", str(stats)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    recs = [json.loads(ln) for ln in r.stdout.splitlines()]
    assert [x["seq"] for x in recs] == list(range(40))
    assert all(x["missing"] == [] for x in recs[:30]) and all(x["missing"] == [3] for x in recs[30:])
    s = json.loads(stats.read_text())
    # The first sets without anchor 3 time out as the recorded clock passes; once anchor 3 is
    # stale (stale_after_s = 1 s of recorded time) the next ones leave without waiting.
    assert s["late"] == 0 and s["evicted"] == 0 and 3 <= s["timeouts"] < 8
    assert recs[-2]["stale"] == [3] and recs[30]["stale"] == []


def test_a_lossless_stream_on_stdin_gives_whole_sets(site, tmp_path):
    """25,000 beacons, in order, nothing lost, from a file on standard input: every set is
    complete, none timed out, no report late, nothing dropped (the timers run only as far
    as the input has been read, and a finite input waits instead of being dropped)."""
    from pfdoa.protocol.uart import encode_uart

    burst = tmp_path / "burst.bin"
    with open(burst, "wb") as fh:
        for seq in range(25_000):
            fh.write(b"".join(encode_uart(m, a) for a, m in feed.reports(seq)))
    stats = tmp_path / "s.json"
    with open(burst, "rb") as stdin:
        r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(site), "--stdin", "--method", "wcl",
                            "--stats", str(stats)], stdin=stdin, capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr.decode()[-2000:]
    s = json.loads(stats.read_text())
    assert r.stdout.count(b"\n") == 25_000 == s["estimates"] == s["sets"] == s["complete"]
    assert s["timeouts"] == 0 and s["late"] == 0 and s["queue_drops"] == 0 and s["reports"] == 100_000


@pytest.mark.parametrize("inputs, message", [
    (["--serial", "nonsense://x"], "invalid URL"),
    (["--serial", "loop://@0"], "baudrate"),
    (["--serial", "README.md"], "not a serial device"),
    (["--can", "nope:x"], "unknown interface"),
])
def test_an_input_that_can_never_open_is_one_line_and_exit_2(site, inputs, message):
    """Permanent errors are not retried (they used to warn forever and exit 0)."""
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(site), *inputs], capture_output=True,
                       text=True, timeout=60, cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 2, r.stderr[-2000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("pfdoa: error: ") and message in last and "Traceback" not in r.stderr


@pytest.mark.parametrize("inputs, named", [
    (["--stdin"], "--stdin"),
    (["--replay-capture", "-"], "--replay-capture"),
    (["--serial", "loop://", "--can", "virtual:x"], "--serial / --can"),
])
def test_a_site_whose_anchor_ids_our_frames_cannot_carry_is_refused_for_frame_inputs(site_file, inputs, named):
    """A site file may hold a recorded dataset's ids (6501...); anchors that speak our
    frames cannot have them, so a frame input with such a site is one line and exit 2."""
    from pfdoa.protocol.defs import ANCHOR_ID_MAX

    big = site_file().read_text().replace("id = 2\n", f"id = {ANCHOR_ID_MAX + 1}\n", 1)
    path = site_file(name="big.toml")
    path.write_text(big)
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(path), *inputs], capture_output=True,
                       text=True, timeout=60, input="")
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.strip() == (f"pfdoa: error: {path}: anchors[2].id: {ANCHOR_ID_MAX + 1} cannot come from {named}: "
                                f"our frames carry anchor ids 0..{ANCHOR_ID_MAX} (larger ids are for recorded traces "
                                "and ESPresense rooms)")


def test_a_full_disk_keeps_the_counters_and_says_so(site, tmp_path):
    from pfdoa.protocol.uart import encode_uart

    rows = [(0.02 * seq, "serial0", encode_uart(m, a)) for seq in range(50) for a, m in feed.reports(seq)]
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(site), "--replay-capture", "-", "--method",
                        "wcl", "--out", "/dev/full"], input=timed_stream(rows), capture_output=True, timeout=60)
    err = r.stderr.decode()
    assert r.returncode == 1 and "Traceback" not in err
    assert final_counters(err)["estimates"] == 50
    assert err.strip().splitlines()[-1] == "pfdoa: error: --out /dev/full: cannot write: No space left on device"


def test_an_output_that_is_an_input_is_refused(site, tmp_path):
    cap = tmp_path / "x.cap"
    cap.write_text("# pfdoa capture v2\n")
    for extra in (["--capture", str(cap)], ["--out", str(cap)]):
        r = subprocess.run([PY, "-m", "pfdoa", "-q", "gateway", "--config", str(site), "--replay-capture", str(cap),
                            *extra], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "would be overwritten" in r.stderr, r.stderr
    assert cap.read_text() == "# pfdoa capture v2\n"
