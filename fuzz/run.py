#!/usr/bin/env python3
"""Build and run every fuzz target for a fixed time, then print one summary line each.

    python fuzz/run.py [--seconds 30] [--only stream,cobs] [--seed 1]

C targets (clang -fsanitize=fuzzer,address,undefined, libFuzzer) fuzz the firmware core;
Python targets (atheris) fuzz the gateway. Each run starts from the committed corpus
fuzz/corpus/<target>/ (read only) plus a scratch corpus under build/fuzz/; crashing inputs
land in build/fuzz/crashes/<target>/: copy them to fuzz/regressions/<target>/ with a name
saying what they found, fix the bug, and `make test` replays them from then on.
Exit status 1 if any target crashed.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware"
BUILD = ROOT / "build" / "fuzz"
CORE = sorted(p.stem for p in (FW / "core" / "src").glob("*.c"))  # every core module (match.c came later)
C_TARGETS = {
    "cobs": ROOT / "fuzz/c/fuzz_cobs.c",
    "uart_rx": ROOT / "fuzz/c/fuzz_uart_rx.c",
    "can_rx": ROOT / "fuzz/c/fuzz_can_rx.c",
    "match": ROOT / "fuzz/c/fuzz_match.c",  # v2: raw BLE PDU / AdvA + AdvData / 802.15.4 MAC frame
    "filter_set": ROOT / "fuzz/c/fuzz_filter_set.c",  # v2: FILTER_SET through the UART path
    "auth": ROOT / "fuzz/c/fuzz_auth.c",  # our authenticated beacon's parsers and verifier (SPEC 9)
    "anchor": FW / "tests/fuzz_anchor.c",  # the firmware's whole-anchor harness
}
PY_TARGETS = ["auth_py", "stream", "can", "reassembler", "trace", "site", "capture", "espresense", "recording",
              "cli_site", "cli_trace", "cli_odometry", "cli_capture"]  # the last four: the commands' file inputs
MAX_LEN = {"recording": 65536}  # an MCAP recording's schemas alone take ~10 kB; the others 4096 bytes
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wconversion", "-Wshadow",
          "-Wno-unused-command-line-argument", "-g", "-O1", "-fsanitize=fuzzer,address,undefined",
          "-fno-sanitize-recover=all", f"-I{FW}/core/include", f"-I{FW}/core/src"]


def build_c(name: str, clang: str) -> Path:
    out = BUILD / "bin" / f"fuzz_{name}"
    srcs = [C_TARGETS[name]] + [FW / f"core/src/{m}.c" for m in CORE]
    newest = max(p.stat().st_mtime for p in srcs + list((FW / "core/include").glob("*.h")))
    if not out.exists() or out.stat().st_mtime < newest:
        out.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([clang, *CFLAGS, *map(str, srcs), "-o", str(out)], check=True)
    return out


def run_target(name: str, cmd: list[str], seconds: int, seed: int) -> dict:
    work = BUILD / "work" / name
    crashes = BUILD / "crashes" / name
    seeds = ROOT / "fuzz" / "corpus" / name
    for d in (work, crashes):
        d.mkdir(parents=True, exist_ok=True)
    before = set(os.listdir(crashes))
    log_path = BUILD / f"{name}.log"
    args = [*cmd, f"-max_total_time={seconds}", f"-seed={seed}", "-print_final_stats=1", "-timeout=10",
            "-rss_limit_mb=2048", f"-max_len={MAX_LEN.get(name, 4096)}", f"-artifact_prefix={crashes}/", str(work)]
    if seeds.is_dir():
        args.append(str(seeds))
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        rc = subprocess.run(args, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT).returncode
    text = log_path.read_text(errors="replace")
    m = re.findall(r"stat::number_of_executed_units:\s*(\d+)", text)
    execs = int(m[-1]) if m else sum(int(x) for x in re.findall(r"Done (\d+) runs", text)[-1:])
    new = sorted(set(os.listdir(crashes)) - before)
    return {"target": name, "rc": rc, "seconds": time.monotonic() - t0, "execs": execs,
            "corpus": len(os.listdir(work)), "crashes": len(new), "files": [str(crashes / f) for f in new],
            "log": str(log_path)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=int, default=int(os.environ.get("FUZZ_SECONDS", 30)))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default="", help="comma-separated target names")
    ap.add_argument("--clang", default=os.environ.get("CLANG", "clang"))
    ap.add_argument("--python", default=sys.executable)
    a = ap.parse_args()
    only = set(filter(None, a.only.split(",")))
    plan: list[tuple[str, str, list[str]]] = []
    for name in C_TARGETS:
        if not only or name in only:
            plan.append((name, "C/libFuzzer", [str(build_c(name, a.clang))]))
    for name in PY_TARGETS:
        if not only or name in only:
            plan.append((name, "Py/atheris", [a.python, str(ROOT / "fuzz/py/run_atheris.py"), name]))
    results = []
    for name, kind, cmd in plan:
        print(f"fuzz: {name} ({kind}) for {a.seconds} s ...", flush=True)
        r = run_target(name, cmd, a.seconds, a.seed)
        r["kind"] = kind
        results.append(r)
        if r["crashes"] or (r["rc"] != 0):
            print(f"  CRASH: {', '.join(r['files']) or 'exit ' + str(r['rc'])} (log {r['log']})", flush=True)
    print(f"\n{'target':<12} {'engine':<12} {'seconds':>7} {'executions':>11} {'exec/s':>8} {'corpus':>7} {'crashes':>7}")
    for r in results:
        print(f"{r['target']:<12} {r['kind']:<12} {r['seconds']:7.0f} {r['execs']:11d} "
              f"{r['execs'] / max(r['seconds'], 1e-9):8.0f} {r['corpus']:7d} {r['crashes']:7d}")
    total = sum(r["crashes"] for r in results)
    failed = [r["target"] for r in results if r["crashes"] or r["rc"] != 0]
    print(f"total: {sum(r['execs'] for r in results)} executions, {total} crash(es)"
          + (f" in {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
