#!/usr/bin/env python3
"""Differential check: the C anchor (build/host/anchor_script) against the Python
reference model (pfdoa.protocol) on seeded random event scripts.

    python3 tools/diffcheck.py [--scripts 500] [--seed 1] [--save DIR]

The scripts come from pfdoa.protocol.scriptgen, the generator tests/firmware/test_differential.py
uses too (random `init`, BLE and 802.15.4 events, invalid readings, polls, tick jumps and
wraps, CONFIG_SETs over UART and CAN, corrupted, split and over-long frames, garbage,
random CAN ids). Any difference in the emitted frames fails (exit 1) and prints the seed,
the first differing line and, with --save, writes the script for replay:
`anchor_script <options> < DIR/fail-SEED.txt`. A quarter as many scripts again run
through anchor_script_sil (PFDOA_SIL_INJECT) with most readings sent as RADIO_INJECT
frames. All scripts go through one harness process (batch mode). Needs the pfdoa package
(the project's virtualenv, or `pip install -e .`).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

try:
    from pfdoa.protocol.scriptgen import Script, generate, run_model
except ImportError as exc:  # pragma: no cover - a usage error, not a test path
    raise SystemExit(f"diffcheck: the pfdoa package is not importable ({exc}); run it with the "
                     "project's .venv/bin/python (make test-c does) or `pip install -e .`") from None

HERE = Path(__file__).resolve().parent


def run_batch(exe: Path, scripts: list[Script]) -> list[list[str]]:
    """All scripts through one harness process (batch mode: `@ <json init>` lines)."""
    text = "".join("@ " + json.dumps(init) + "\n" + "".join(ln + "\n" for ln in lines)
                   for init, lines in scripts)
    proc = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"diffcheck: {exe.name} failed ({proc.returncode}): {proc.stderr.strip()}")
    out: list[list[str]] = []
    for line in proc.stdout.splitlines():
        if line == "@":
            out.append([])
        else:
            out[-1].append(line)
    if len(out) != len(scripts):
        raise SystemExit(f"diffcheck: {len(out)} outputs for {len(scripts)} scripts")
    return out


def harness_args(exe: Path, init: dict) -> list[str]:
    args = [str(exe), "-a", str(init["anchor_id"]), "-t", init.get("transport", "uart"),
            "-b", str(init.get("boot_tick_ms", 0))]
    if "config" in init:
        c = init["config"]
        args += ["-c", ",".join(str(c[k]) for k in ("offset_q8", "alpha_q8", "spike_db",
                                                    "report_mode", "decimation"))]
    if not init.get("store_ok", True):
        args.append("-s")
    return args


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scripts", type=int, default=500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--exe", type=Path, default=HERE.parent / "build" / "host" / "anchor_script")
    ap.add_argument("--save", type=Path, default=None)
    a = ap.parse_args()
    frames = 0
    for sil in (False, True):
        exe = a.exe.with_name(a.exe.name + "_sil") if sil else a.exe
        n = a.scripts if not sil else max(1, a.scripts // 4)
        seed = a.seed * 1_000_003 + (500_000 if sil else 0)
        scripts = generate(n, seed, inject=sil)
        outs = run_batch(exe, scripts)
        for k, ((init, lines), got) in enumerate(zip(scripts, outs)):
            want = run_model(init, lines)
            if got != want:
                first = next((i for i, (g, w) in enumerate(zip(got, want)) if g != w), min(len(got), len(want)))
                print(f"diffcheck: MISMATCH seed {seed} script {k} ({exe.name} "
                      f"{' '.join(harness_args(exe, init)[1:])}{' sil_inject' if sil else ''})")
                print(f"  output line {first + 1}: C      {got[first] if first < len(got) else '<none>'}")
                print(f"  output line {first + 1}: Python {want[first] if first < len(want) else '<none>'}")
                if a.save:
                    a.save.mkdir(parents=True, exist_ok=True)
                    (a.save / f"fail-{seed}-{k}.txt").write_text("\n".join(lines) + "\n")
                return 1
            frames += len(want)
        print(f"diffcheck: {n} random scripts ({sum(len(ln) for _, ln in scripts)} lines) through "
              f"{exe.name}: C anchor == Python reference")
    print(f"diffcheck: {frames} frames compared")
    return 0


if __name__ == "__main__":
    sys.exit(main())
