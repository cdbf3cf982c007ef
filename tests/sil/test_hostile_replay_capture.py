"""The hostile-input issue's first example (issue 13) end to end in virtual time: a live
simulated run's capture replayed gives every position the live run gave. The other cases run
real processes on the wall clock (tests/io/test_hostile_cli.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def pfdoa(*args, timeout: float):
    return subprocess.run([sys.executable, "-m", "pfdoa", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_replaying_a_live_runs_capture_keeps_every_position(tmp_path):
    """The issue's first row: 1,073 of 3,001 positions, queue_drops 1,928, exit 0. Now every
    position, byte for byte the live ones (a 300 s demo run)."""
    cap = tmp_path / "run.cap"
    r = pfdoa("-q", "sim", "--scenario", "demo", "--gateway", "--duration", "300", "--out-dir", tmp_path / "sim",
              "--gateway-arg=--capture", f"--gateway-arg={cap}", "--gateway-arg=--method", "--gateway-arg=wcl",
              timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    live = (tmp_path / "sim" / "gateway.jsonl").read_text()
    out, stats = tmp_path / "replayed.jsonl", tmp_path / "s.json"
    r = pfdoa("-q", "gateway", "--config", tmp_path / "sim" / "site.toml", "--replay-capture", cap, "--method", "wcl",
              "--out", out, "--stats", stats, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads(stats.read_text())
    assert out.read_text() == live and live.count("\n") == 3001 == s["estimates"]
    assert s["queue_drops"] == 0 and s["inputs"][str(cap)]["bad_lines"] == 0
