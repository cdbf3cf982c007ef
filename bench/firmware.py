"""Firmware size (arm-none-eabi-size) and instruction counts (valgrind callgrind; QEMU -icount).

Sizes: the objects ``firmware/Makefile`` builds for each Cortex-M (``-Os -mthumb
-mfloat-abi=soft -ffunction-sections``). ``text`` is what ``arm-none-eabi-size`` prints
(code + read-only data, the number the Makefile's 4 KB budget checks); ``code`` is the
``.text*`` sections alone. ``budget_core`` = crc16 cobs config msg frame filter (filter +
framing + config decode); ``whole_core`` adds anchor.c (event logic, STATUS, CONFIG_SET).

Instructions: the host build of the core (x86-64, gcc -O2, so the counts are x86-64
instructions: a proxy for the work done, not Cortex-M cycles) under callgrind, collecting
only inside ``pfdoa_anchor_on_radio`` and ``pfdoa_anchor_poll`` and not inside the script
harness's UART write callback (``env_uart_write``, which formats hex for printing). A
fixed script of BLE events (3 readings on channels 37/38/39 each, seeded RSSI, one poll per
event, 20 ms apart) runs with E1 and E2 events: per event = the difference / (E2 - E1),
so start-up and the first STATUS cancel. Per report = (reports on) - (report_mode silent)
at E2, divided by the reports sent: packing, CRC-16, COBS and the hand-over to the HAL.

Our authenticated beacon (protocol/SPEC.md 9) on the Cortex-M images themselves
(:func:`auth_instructions`): ``firmware/bench/auth_bench.c`` built for Cortex-M4 and M0+
(-Os -mthumb, as the size images) runs under ``qemu-system-arm -icount shift=0``
(mps2-an386 for M4, mps2-an385 for M0+, which runs v6-M code): Thumb instructions per
operation, deterministic (SysTick counts virtual time, calibrated by a loop of known
length), 64 repetitions each.
"""

from __future__ import annotations

import random
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware"
CPUS = ("cortex-m0plus", "cortex-m4")
BUDGET_OBJS = ("crc16", "cobs", "config", "msg", "frame", "filter")
CORE_OBJS = BUDGET_OBJS + ("anchor",)
BUDGET_BYTES = 4096
TOGGLES = ("pfdoa_anchor_on_radio", "pfdoa_anchor_poll", "env_uart_write")
SILENT_CONFIG = "0,64,12,2,1"  # offset_q8, alpha_q8, spike_db, report_mode = silent, decimation


def _make(*targets: str) -> None:
    proc = subprocess.run(["make", "-s", "-C", str(FW), *targets], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"make -C firmware {' '.join(targets)} failed: {proc.stderr.strip()[-2000:]}")


def _sections(size_tool: str, obj: Path) -> dict[str, int]:
    out = subprocess.run([size_tool, "-A", str(obj)], capture_output=True, text=True, check=True).stdout
    sec: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sec[parts[0]] = sec.get(parts[0], 0) + int(parts[1])
    return sec


def sizes() -> dict:
    size_tool = shutil.which("arm-none-eabi-size")
    if size_tool is None or shutil.which("arm-none-eabi-gcc") is None:
        raise RuntimeError("arm-none-eabi-gcc/size not installed (tools/bootstrap.sh bench)")
    _make(*[f"build/cortex-m/{c}/{o}.o" for c in CPUS for o in CORE_OBJS])
    res: dict = {}
    for cpu in CPUS:
        per = {}
        for o in CORE_OBJS:
            sec = _sections(size_tool, FW / "build" / "cortex-m" / cpu / f"{o}.o")
            code = sum(v for k, v in sec.items() if k == ".text" or k.startswith(".text."))
            ro = sum(v for k, v in sec.items() if k == ".rodata" or k.startswith(".rodata."))
            per[o] = {"text": code + ro, "code": code, "rodata": ro}
        res[cpu] = {
            "budget_core": sum(per[o]["text"] for o in BUDGET_OBJS),
            "budget_core_code": sum(per[o]["code"] for o in BUDGET_OBJS),
            "whole_core": sum(per[o]["text"] for o in CORE_OBJS),
            "whole_core_code": sum(per[o]["code"] for o in CORE_OBJS),
            "objects": per,
        }
    res["budget_bytes"] = BUDGET_BYTES
    return res


def event_script(events: int, seed: int = 1) -> str:
    rng = random.Random(seed)
    lines = []
    for k in range(events):
        t = 20 * k
        for j, ch in enumerate((37, 38, 39)):
            lines.append(f"R {t + j} {k & 0xFFFF} {rng.randint(-72, -48)} {ch} 0 0")
        lines.append(f"P {t + 10}")
    return "\n".join(lines) + "\n"


def _callgrind(binary: Path, script: str, args: list[str]) -> tuple[int, list[str]]:
    """(instructions collected, output lines of the harness)."""
    with tempfile.TemporaryDirectory() as tmp:
        out_file = Path(tmp) / "cg.out"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out_file}"]
        cmd += [f"--toggle-collect={f}" for f in TOGGLES]
        proc = subprocess.run(cmd + [str(binary), *args], input=script, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"callgrind run failed: {proc.stderr.strip()[-2000:]}")
        m = re.search(r"Collected\s*:\s*(\d+)", proc.stderr)
        if m is None:
            raise RuntimeError("callgrind printed no 'Collected' line")
        return int(m.group(1)), proc.stdout.splitlines()


def instructions(quick: bool = False) -> dict:
    if shutil.which("valgrind") is None:
        raise RuntimeError("valgrind not installed (tools/bootstrap.sh bench)")
    _make("script")
    binary = FW / "build" / "host" / "anchor_script"
    e1, e2 = (50, 150) if quick else (1000, 3000)
    i1, _ = _callgrind(binary, event_script(e1), [])
    i2, lines2 = _callgrind(binary, event_script(e2), [])
    i2s, lines2s = _callgrind(binary, event_script(e2), ["-c", SILENT_CONFIG])
    reports = len(lines2) - len(lines2s)  # the same STATUS frames in both runs
    if reports <= 0:
        raise RuntimeError("the silent run emitted as many frames as the reporting one")
    return {
        "per_event": round((i2 - i1) / (e2 - e1), 1),
        "per_reading": round((i2 - i1) / (3 * (e2 - e1)), 1),
        "per_report": round((i2 - i2s) / reports, 1),
        "per_event_silent": round(i2s / e2, 1),
        "events": [e1, e2],
        "reports": reports,
        "isa": "x86-64 host build (gcc -O2), callgrind Ir",
        "collected": TOGGLES[:2],
    }


QEMU_MACHINE = {"cortex-m4": "mps2-an386", "cortex-m0plus": "mps2-an385"}  # an385 runs v6-M code


def auth_instructions() -> dict:
    """Thumb instructions per operation of the authenticated beacon on each CPU:
    ``beacon_advertisement`` (tag, payload, PDU, within a period), ``period_identifiers``
    (the derivation, once per 4.096 s), ``anchor_reception`` (a PDU verified and folded by
    ``pfdoa_anchor_on_ble_pdu``), ``anchor_replay_rejected``, and ``static_beacon_reception``
    (our static beacon's PDU through the same entry point, for comparison)."""
    qemu = shutil.which("qemu-system-arm")
    if qemu is None:
        raise RuntimeError("qemu-system-arm not installed (tools/bootstrap.sh qemu)")
    _make("auth-bench")
    out: dict = {}
    for cpu, machine in QEMU_MACHINE.items():
        elf = FW / "build" / "bench" / cpu / "auth_bench.elf"
        proc = subprocess.run([qemu, "-M", machine, "-display", "none", "-monitor", "none", "-serial", "null",
                               "-semihosting-config", "enable=on,target=native", "-icount", "shift=0",
                               "-kernel", str(elf)], capture_output=True, text=True, timeout=120, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"{elf.name} ({cpu}) exited {proc.returncode}: {proc.stdout[-500:]}{proc.stderr[-500:]}")
        # Semihosting console output (SYS_WRITE0) goes to QEMU's standard error.
        out[cpu] = {k: int(v) for k, v in (line.split() for line in proc.stderr.splitlines()
                                           if len(line.split()) == 2 and line.split()[1].isdigit())}
    return out
