"""`pfdoa eval --quick`: the whole evaluation (simulated datasets and the committed real
sites, every method) produces every method row and its plots. Half a minute of CPU: here and not
in tests/unit (the harness's pieces are tested there, tests/unit/test_eval.py)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pfdoa.estimators import METHODS


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    out = d / "results.md"
    # ~30 s of CPU; the timeout only bounds a hang (it once hit 300 s on a loaded machine).
    r = subprocess.run([sys.executable, "-m", "pfdoa", "eval", "--quick", "--no-progress", "--out", str(out),
                        "--plots", str(d / "img")], capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr
    return out.read_text(), d


def test_quick_eval_has_every_method_row_in_every_block(quick_report):
    text, _ = quick_report
    for heading in ("## Dataset 0", "## Dataset 1 (the paper", "## Dataset 1 (radio", "## Dataset 2", "## Real sites",
                    "### herolab_wifi_robot", "### kolakowski_ble_dev", "### philotuxo_ble_dev"):
        assert heading in text
    sections = text.split("\n## ")
    for sec in sections:
        if not sec.startswith(("Dataset 0 (", "Dataset 1", "Dataset 2", "Real sites")):
            continue
        rows = {line.split("|")[1].strip() for line in sec.splitlines() if line.startswith("| ")}
        for m in METHODS:
            assert m in rows, f"{m} missing in section {sec.splitlines()[0]}"
    assert "failed" not in text
    assert "## Project targets" in text and "paper Diagonal" in text
    assert "make eval" not in text  # a quick run is not what regenerates docs/results.md


def test_quick_eval_writes_plots(quick_report):
    text, d = quick_report
    pngs = sorted(p.name for p in (d / "img").glob("*.png"))
    assert "error_cdf.png" in pngs and "paths_dataset0.png" in pngs
    for name in pngs:
        assert f"img/{name}" in text
        assert (d / "img" / name).read_bytes()[:4] == b"\x89PNG"
