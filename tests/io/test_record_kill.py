"""``pfdoa gateway --record`` killed with SIGKILL (a crash, or a power cut as far as the file
can tell): the real gateway process, cut at a seeded random point, leaves a recording that the
mcap package's own linear reader and ours read up to its last complete chunk, and that
``pfdoa replay`` turns into exactly the estimates the gateway had written by then."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys

import pytest

import gateway_feed as feed
from mqtt_support import wait_for

pytestmark = pytest.mark.io

PY = sys.executable
T0 = 1_700_000_000.0


def _lines(path) -> list[str]:
    try:
        return [ln for ln in path.read_text().splitlines() if ln.endswith("}")]  # a line cut mid-write is not one
    except FileNotFoundError:
        return []


def _capture(path, seqs: int) -> None:
    """The feed's beacons every 20 ms, some reports lost (sets that time out), timer marks."""
    from pfdoa.gateway.inputs.capture import CAPTURE_V2, capture_line
    from pfdoa.gateway.transports import Chunk, TimeMark
    from pfdoa.protocol.uart import encode_uart

    lines = [CAPTURE_V2 + "\n"]
    for seq in range(seqs):
        for a, m in feed.reports(seq):
            if (seq * 7 + a) % 13:
                lines.append(capture_line(Chunk("serial0", T0 + 0.02 * seq + 0.001 * a, encode_uart(m, a))))
        lines.append(capture_line(TimeMark(T0 + 0.02 * seq + 0.015)))
    path.write_text("".join(lines))


def _ecosystem_poses(path) -> tuple[list[tuple[float, float, float]], bool]:
    """(t, x, y) of every pose the mcap package's StreamReader reads, decoded by
    mcap-ros2-support, and whether it stopped at a cut (an exception where the file ends)."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    factory, schemas, channels, out = DecoderFactory(), {}, {}, []
    with open(path, "rb") as fh:
        try:
            for rec in StreamReader(fh, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message) and channels[rec.channel_id].topic == "/pfdoa/pose":
                    ch = channels[rec.channel_id]
                    m = factory.decoder_for(ch.message_encoding, schemas[ch.schema_id])(rec.data)
                    out.append((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.pose.pose.position.x,
                                m.pose.pose.position.y))
        except Exception:  # the reader's way of meeting the end of a cut file
            return out, True
    return out, False


def test_a_recording_of_a_killed_gateway_replays_to_exactly_its_estimates(tmp_path):
    from pfdoa.sinks.mcap import open_recording

    rng = random.Random(48)
    kill_after = rng.randrange(100, 300)  # estimates on the gateway's output when it is killed
    site = tmp_path / "site.toml"
    site.write_text(feed.TEST_SITE + "[gateway]\nhealth_interval_s = 0.5\n")
    cap, rec, live = tmp_path / "run.cap", tmp_path / "run.mcap", tmp_path / "live.jsonl"
    _capture(cap, 1500)  # 30 s at the recorded pace: killed long before its end
    err = tmp_path / "err"
    with err.open("wb") as fh:
        proc = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site), "--replay-capture", str(cap),
                                 "--realtime", "--method", "pf-doa", "--seed", "3", "--record", str(rec),
                                 "--out", str(live)], stdout=subprocess.DEVNULL, stderr=fh)
    try:
        wait_for(lambda: len(_lines(live)) >= kill_after, timeout_s=120, what=f"{kill_after} estimates")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    written = _lines(live)
    assert len(written) >= kill_after and "final" not in err.read_text()  # no clean stop: nothing finished it

    # Both readers: the poses of the complete chunks, the same ones, the gateway's first estimates.
    eco, stopped = _ecosystem_poses(rec)
    recording = open_recording(rec)
    ours = list(recording.poses())
    assert stopped and recording.cut and recording.extent.truncated
    assert [(p.t, p.x, p.y) for p in ours] == eco and len(ours) > 0
    n = len(ours)
    assert [(r["t"], r["x"], r["y"]) for r in map(json.loads, written[:n])] == \
        [(round(t, 6), round(x, 4), round(y, 4)) for t, x, y in eco]
    assert n <= len(written)

    out, stats = tmp_path / "replayed.jsonl", tmp_path / "stats.json"
    r = subprocess.run([PY, "-m", "pfdoa", "replay", str(rec), "--out", str(out), "--stats", str(stats)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "the recording was cut" in r.stderr and r.stderr.count("WARNING") == 1, r.stderr[-2000:]
    assert out.read_text().splitlines() == written[:n]  # exactly, every field, nothing more
    s = json.loads(stats.read_text())
    # The writer writes whole chunks: a kill leaves whole records (a power cut may leave part of one).
    assert s["estimates"] == n and s["cut"]["bytes_read"] <= s["cut"]["bytes"] == rec.stat().st_size
    print(f"killed after {len(written)} estimates written; the recording ({rec.stat().st_size} bytes) "
          f"replays to the first {n}")
