"""`pfdoa replay` runs with examples/site.full.toml, the generated reference site file with
every key (pfdoa.schema), and exits 0 with an estimate per window."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from pfdoa import schema

pytestmark = pytest.mark.io


def test_replay_runs_with_the_full_example(tmp_path):
    out = tmp_path / "est.jsonl"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "replay", str(schema.ROOT / "examples" / "run.csv"), "--config",
                        str(schema.EXAMPLE_PATH), "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(recs) == 41  # one per window of the 41 s trace
    # [[floors]] and [[rooms]] of the example name every estimate's floor and room, inside the area.
    assert all(r["floor"] == "ground" and r["floor_p"] == 1.0 for r in recs)
    assert sum(r["room"] == "lab" for r in recs) == len(recs)
    assert all(-0.5 <= r["x"] <= 2.84 and -0.5 <= r["y"] <= 2.25 for r in recs)
