"""Virtual time makes a run a function of its inputs: `make demo` twice prints the same
summary, byte for byte; a live run's capture replays to the very same positions."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.sil

ROOT = Path(__file__).resolve().parents[2]


def demo_args() -> list[str]:
    """The `pfdoa sim` arguments of the Makefile's demo target (without its --plot)."""
    text = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^demo:\n((?:\t.*\n)+)", text, re.M).group(1)
    line = " ".join(ln.strip().rstrip("\\").strip() for ln in recipe.splitlines() if "$(PY)" in ln or ln.startswith("\t  "))
    args = shlex.split(line.split(" sim ", 1)[1])
    if "--plot" in args:
        i = args.index("--plot")
        del args[i:i + 2]
    return args


def pfdoa(*args, timeout=600) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "pfdoa", *args], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


def test_make_demo_prints_the_same_summary_twice(tmp_path):
    args = demo_args()
    assert "--gateway" in args and "--realtime" not in args and "--seed" in args
    outs = [pfdoa("-q", "sim", *args, "--out-dir", str(tmp_path / f"run{k}")) for k in range(2)]
    lines = [[ln for ln in r.stdout.splitlines() if ln.startswith("demo: RMSE")] for r in outs]
    assert len(lines[0]) == 1 and lines[0] == lines[1], lines
    # byte for byte, but for where each run was asked to write (the calibration line names it)
    texts = [r.stdout.replace(str(tmp_path / f"run{k}"), "OUT") for k, r in enumerate(outs)]
    assert "OUT/calibration" in texts[0] and texts[0] == texts[1]
    a, b = ((tmp_path / f"run{k}" / "gateway.jsonl").read_bytes() for k in range(2))
    assert a == b and a.count(b"\n") > 500


def live_and_replay(tmp_path: Path, seconds: int, method: str | None) -> tuple[bytes, bytes, dict]:
    d = tmp_path / (method or "default")
    cap = d / "run.cap"
    extra = ["--gateway-arg=--method", f"--gateway-arg={method}"] if method else []
    pfdoa("-q", "sim", "--scenario", "demo", "--gateway", "--odom", "--duration", str(seconds), "--seed", "4",
          "--faults", "loss=0.02,dup=0.01,reorder=0.01,ber=1e-5,jitter=30,drift_ppm=50,silence=3@20+4",
          "--out-dir", str(d), "--gateway-arg=--capture", f"--gateway-arg={cap}", *extra)
    replayed = d / "replayed.jsonl"
    pfdoa("-q", "gateway", "--config", str(d / "site.toml"), "--replay-capture", str(cap), "--seed", "4",
          "--out", str(replayed), "--stats", str(d / "replayed.stats.json"), *(["--method", method] if method else []))
    stats = json.loads((d / "replayed.stats.json").read_text())
    return (d / "gateway.jsonl").read_bytes(), replayed.read_bytes(), stats


@pytest.mark.parametrize("method", [None, "wcl"], ids=["pf-doa", "wcl"])
def test_a_live_runs_capture_replays_to_the_same_positions(tmp_path, method):
    """The live gateway (here on the simulator's timed stream, with odometry, loss,
    duplicates, reordering, bit errors, jitter and a silent anchor) writes a capture; the
    replay applies the same timer rule to the same stamps: the same output, byte for byte
    (the default pf-doa with the same seed, and wcl), nothing dropped."""
    live, replayed, stats = live_and_replay(tmp_path, 60, method)
    assert live.count(b"\n") > 550 and replayed == live
    assert stats["queue_drops"] == 0 and stats["odometry"]["lines"] == 601


@pytest.mark.slow
def test_a_ten_minute_live_run_replays_exactly(tmp_path):
    for method in (None, "wcl"):
        live, replayed, stats = live_and_replay(tmp_path, 600, method)
        assert live.count(b"\n") > 5900 and replayed == live, method
        assert stats["queue_drops"] == 0
