#!/usr/bin/env python3
"""Differential check: the C anchor (build/host/anchor_script) against the Python
reference model (pfdoa.protocol.script.run_script) on seeded random event scripts.

    python3 tools/diffcheck.py [--scripts 500] [--lines 300] [--seed 1] [--save DIR]

Each script gets a random `init` (anchor id, transport, boot tick near the u32 wrap or
not, stored configuration, failing store) and a random mix of BLE beacon events on 1..3
channels, 802.15.4 readings, invalid readings, polls, tick jumps and wraps, CONFIG_SETs
(valid, invalid, broadcast, other anchors) over UART and CAN, corrupted and split
frames, random bytes and random CAN frames. Any difference in the emitted frames fails
(exit 1) and prints the seed, the first differing line and, with --save, writes the
script for replay: `anchor_script <options> < DIR/fail-SEED.txt`. A quarter as many
scripts again run through anchor_script_sil (PFDOA_SIL_INJECT) with most readings sent as
RADIO_INJECT frames. All scripts go through one harness process (batch mode).
Stdlib only; the reference is imported from ../host.
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent / "host"))

from pfdoa.protocol import ConfigSet, RadioInject, RssiReport, defs, encode_uart  # noqa: E402
from pfdoa.protocol.anchor_model import AnchorConfig, AnchorModel  # noqa: E402
from pfdoa.protocol.script import format_unit, run_script, step  # noqa: E402

U32 = 0xFFFFFFFF


def random_config(rng: random.Random, valid: bool = True) -> dict:
    cfg = {
        "offset_q8": rng.choice([0, 0, rng.randint(-1024, 1024), rng.randint(-32768, 32767)]),
        "alpha_q8": rng.choice([64, 256, 1, rng.randint(1, 256)]),
        "spike_db": rng.choice([12, 0, rng.randint(0, 30)]),
        "report_mode": rng.choice([0, 0, 0, 1, 1, 2]),
        "decimation": rng.choice([1, 2, 3, rng.randint(1, 255)]),
    }
    if not valid:
        key, bad = rng.choice([("alpha_q8", 0), ("alpha_q8", 257), ("alpha_q8", 65535),
                               ("report_mode", 3), ("report_mode", 255), ("decimation", 0)])
        cfg[key] = bad
    return cfg


def gen_script(rng: random.Random, n_lines: int, sil: bool = False) -> tuple[dict, list[str]]:
    """sil=True: a PFDOA_SIL_INJECT anchor, most readings arriving as RADIO_INJECT frames."""
    anchor = rng.randint(0, defs.ANCHOR_ID_MAX)
    init = {"anchor_id": anchor, "transport": rng.choice(["uart", "uart", "can"]),
            "boot_tick_ms": rng.choice([0, rng.randint(0, U32), U32 - rng.randint(0, 3000)])}
    if sil:
        init["sil_inject"] = True
    if rng.random() < 0.3:
        init["config"] = random_config(rng)
    if rng.random() < 0.15:
        init["store_ok"] = False
    tick = (init["boot_tick_ms"] + rng.randint(0, 50)) & U32
    seq = rng.randint(0, 0xFFFF)
    level = rng.randint(-95, -40)
    lines: list[str] = []
    pending = b""  # a frame split across U lines

    def reading(t: int, sq: int, rssi: int, ch: int, lqi: int, radio: int) -> None:
        if sil and rng.random() < 0.7:  # the same reading through RADIO_INJECT
            to = anchor if rng.random() < 0.95 else rng.choice([127, (anchor + 1) % 127])
            lines.append(f"U {t} {encode_uart(RadioInject(sq, t, rssi, ch, lqi, radio), to).hex()}")
        else:
            lines.append(f"R {t} {sq} {rssi} {ch} {lqi} {radio}")

    while len(lines) < n_lines:
        tick = (tick + rng.choice([0, 1, 2, 5, 10, 19, 20, 21, 30])) & U32
        if rng.random() < 0.02:
            tick = (tick + rng.randint(900, 5000)) & U32
        x = rng.random()
        if x < 0.45:  # a beacon event: BLE on 1..3 channels, or one 802.15.4 reading
            seq = (seq + rng.choice([1, 1, 1, 2, 5, 0, 65535])) & 0xFFFF
            level = max(-128, min(30, level + rng.randint(-3, 3)))
            if rng.random() < 0.25:
                ch = rng.randint(11, 26)
                rssi = level + (rng.randint(-40, 40) if rng.random() < 0.1 else rng.randint(-2, 2))
                reading(tick, seq, max(-128, min(127, rssi)), ch, rng.randint(0, 255), 1)
            else:
                for ch in rng.sample([37, 38, 39, rng.randint(0, 36)], rng.randint(1, 4)):
                    rssi = level + (rng.randint(-40, 40) if rng.random() < 0.1 else rng.randint(-3, 3))
                    reading(tick, seq, max(-128, min(127, rssi)), ch, 0, 0)
                    tick = (tick + rng.choice([0, 1, 2])) & U32
        elif x < 0.52:  # invalid readings
            rssi, ch, radio = rng.choice([(127, 37, 0), (-60, 40, 0), (-60, 10, 1), (-60, 27, 1),
                                          (-60, 15, rng.randint(2, 255)), (-60, 255, 0)])
            reading(tick, seq, rssi, ch, 0, radio)
        elif x < 0.75:
            lines.append(f"P {tick}")
        elif x < 0.88:  # host frames on the UART
            to = rng.choice([anchor, anchor, 127, rng.randint(0, 127)])
            kind = rng.random()
            if kind < 0.6:
                cfg = random_config(rng, valid=rng.random() < 0.75)
                frame = encode_uart(ConfigSet(rng.randint(0, 255), **cfg), to)
            elif kind < 0.75:
                frame = encode_uart(RssiReport(seq, tick, -1000, -60, 1, 37, 0), min(to, 126))
            else:
                frame = encode_uart(RadioInject(seq, tick, -60, 37, 0, 0), to)
            data = bytearray(pending + frame)
            pending = b""
            if rng.random() < 0.15:  # corrupt one byte (may turn into 0x00)
                i = rng.randrange(len(data))
                data[i] = rng.randint(0, 255)
            if rng.random() < 0.2:  # split: keep the tail for the next U line
                cut = rng.randint(1, len(data) - 1)
                data, pending = data[:cut], bytes(data[cut:])
            lines.append(f"U {tick} {bytes(data).hex()}")
        elif x < 0.93:  # raw garbage, sometimes long (overlong)
            n = rng.choice([1, 3, 10, 66, 70, 200])
            data = bytes(rng.choice([0, rng.randint(1, 255)]) if rng.random() < 0.05 else rng.randint(1, 255)
                         for _ in range(n))
            lines.append(f"U {tick} {data.hex()}")
        else:  # CAN frames
            to = rng.choice([anchor, 127, rng.randint(0, 127)])
            if rng.random() < 0.7:
                cfg = random_config(rng, valid=rng.random() < 0.75)
                data = ConfigSet(rng.randint(0, 255), **cfg).pack()
                if rng.random() < 0.2:
                    data = data[:rng.randint(1, 7)]
                can_id = (defs.CAN_CONFIG_SET << 7) | to
            else:
                can_id = rng.randint(0, 0x7FF)
                data = bytes(rng.randint(0, 255) for _ in range(rng.randint(1, 8)))
            lines.append(f"C {tick} {can_id:03x} {data.hex()}")
    return init, lines


def run_model(init: dict, lines: list[str]) -> list[str]:
    if not init.get("sil_inject"):
        return run_script(init, lines)
    cfg = AnchorConfig(**init["config"]) if "config" in init else None  # run_script: production only
    model = AnchorModel(init["anchor_id"], init.get("transport", "uart"),
                        boot_tick_ms=init.get("boot_tick_ms", 0), config=cfg,
                        store_ok=init.get("store_ok", True), sil_inject=True)
    return [format_unit(u) for ln in lines for u in step(model, ln)]


def run_batch(exe: Path, scripts: list[tuple[dict, list[str]]]) -> list[list[str]]:
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
    ap.add_argument("--lines", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--exe", type=Path, default=HERE.parent / "build" / "host" / "anchor_script")
    ap.add_argument("--save", type=Path, default=None)
    a = ap.parse_args()
    frames = 0
    for sil in (False, True):
        exe = a.exe.with_name(a.exe.name + "_sil") if sil else a.exe
        n = a.scripts if not sil else max(1, a.scripts // 4)
        seeds = [a.seed * 1_000_003 + k + (500_000 if sil else 0) for k in range(n)]
        scripts = [gen_script(random.Random(sd), a.lines, sil) for sd in seeds]
        outs = run_batch(exe, scripts)
        for seed, (init, lines), got in zip(seeds, scripts, outs):
            want = run_model(init, lines)
            if got != want:
                first = next((i for i, (g, w) in enumerate(zip(got, want)) if g != w), min(len(got), len(want)))
                print(f"diffcheck: MISMATCH seed {seed} ({exe.name} {' '.join(harness_args(exe, init)[1:])}"
                      f"{' sil_inject' if sil else ''})")
                print(f"  output line {first + 1}: C      {got[first] if first < len(got) else '<none>'}")
                print(f"  output line {first + 1}: Python {want[first] if first < len(want) else '<none>'}")
                if a.save:
                    a.save.mkdir(parents=True, exist_ok=True)
                    (a.save / f"fail-{seed}.txt").write_text("\n".join(lines) + "\n")
                return 1
            frames += len(want)
        print(f"diffcheck: {n} random scripts x {a.lines} lines through {exe.name}: "
              f"C anchor == Python reference")
    print(f"diffcheck: {frames} frames compared")
    return 0


if __name__ == "__main__":
    sys.exit(main())
