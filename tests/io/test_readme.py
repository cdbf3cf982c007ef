"""The README's "Using it" commands run as written (from a fresh checkout state).

Every command of the section's ``sh`` blocks is run, in order, by bash in a scratch
directory holding what a fresh clone has for them (``examples/``, and ``.venv`` from the
test environment); only lines naming a live device (``/dev/tty...``) are skipped. Then each
file a command wrote with ``--out``/``--out-dir`` (and the recording of ``--record``) exists
and is what it should be, and what the comments promise holds (the recording's replay is
the gateway's output).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from pfdoa.site import load_site

REPO = Path(__file__).resolve().parents[2]
LIVE_HARDWARE = re.compile(r"/dev/tty")


def using_it_commands(markdown: str, source: str) -> list[str]:
    """The shell commands of the "## Using it" section (continuations joined, comments kept
    out, live-hardware lines skipped)."""
    m = re.search(r"^## Using it\s*$(.*?)(?=^## |\Z)", markdown, re.M | re.S)
    assert m, f"{source}: no '## Using it' section"
    blocks = re.findall(r"^```(?:sh|bash|console)\s*$(.*?)^```\s*$", m.group(1), re.M | re.S)
    assert blocks, f"{source}: 'Using it' has no sh block"
    commands, current = [], ""
    for line in "\n".join(blocks).splitlines():
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        words = shlex.split(current, comments=True)
        if words and not LIVE_HARDWARE.search(current):
            commands.append(shlex.join(words))
        current = ""
    return commands


def run_commands(commands: list[str], tmp_path: Path) -> Path:
    work = tmp_path / "checkout"
    work.mkdir()
    shutil.copytree(REPO / "examples", work / "examples")
    venv = Path(sys.prefix)
    if (venv / "bin" / "activate").exists():
        (work / ".venv").symlink_to(venv)
    else:  # not in a virtualenv: an activate that puts this interpreter's scripts first
        (work / ".venv" / "bin").mkdir(parents=True)
        (work / ".venv" / "bin" / "activate").write_text(f'export PATH="{Path(sys.executable).parent}:$PATH"\n')
    script = "set -euo pipefail\n" + "\n".join(f"echo '+ {c}' >&2\n{c}" for c in commands) + "\n"
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV",)}
    r = subprocess.run(["bash", "-c", script], cwd=work, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, f"{r.stderr[-4000:]}"
    for c in commands:
        words = shlex.split(c)
        outs = [words[i + 1] for i, w in enumerate(words[:-1]) if w in ("--out", "--out-dir")]
        outs += [w.split("=", 2)[2] for w in words if w.startswith("--gateway-arg=--record=")]
        for o in outs:
            out = work / o
            assert out.exists(), f"{c}: wrote no {out}"
            check_output(out)
    return work


def check_output(path: Path) -> None:
    if path.is_dir():
        assert any(path.iterdir()), path
    elif path.suffix == ".jsonl":
        lines = path.read_text().splitlines()
        assert len(lines) >= 10, path
        for line in lines:
            rec = json.loads(line)
            assert isinstance(rec["x"], float) and isinstance(rec["y"], float)
    elif path.suffix == ".toml":
        assert len(load_site(path).anchors) >= 3
    elif path.suffix == ".mcap":
        from pfdoa.sinks.mcap import open_recording

        rec = open_recording(path)
        assert sum(1 for _ in rec.poses()) >= 10 and rec.anchors()
    else:
        assert path.stat().st_size > 0, path


README = REPO / "README.md"


def test_extraction_skips_only_live_hardware_lines():
    cmds = using_it_commands(README.read_text(encoding="utf-8"), str(README))
    assert cmds[0] == ". .venv/bin/activate" and cmds[1] == "pfdoa --help"
    assert not any(c.startswith("pfdoa gateway") for c in cmds)  # the /dev/ttyACM* line
    assert any("--config build/sim/demo/site.toml --odom build/sim/demo/trace.odom.csv" in c for c in cmds)
    assert len(cmds) == 10


def test_readme_using_it_runs_as_written(tmp_path):
    work = run_commands(using_it_commands(README.read_text(encoding="utf-8"), str(README)), tmp_path)
    # "the gateway's estimates again": the recording replays to the live output, byte for byte.
    assert (work / "sim-again.jsonl").read_bytes() == (work / "build/sim/demo/gateway.jsonl").read_bytes()
