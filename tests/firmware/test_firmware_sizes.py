"""The size tables in the docs are what `make firmware` measures: the Cortex-M core table
and stack bounds in firmware/README.md, the QEMU mps2-an385 image table in
firmware/ports/README.md, the board image sentence in firmware/README.md and the core
budget line of README.md. A change to the firmware that moves a size fails here until the
docs say the new number. (The nRF52840 table: tests/firmware/test_nrf52840_port.py.)"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

REPO = Path(__file__).resolve().parents[2]
FIRMWARE_README = REPO / "firmware" / "README.md"
PORTS_README = REPO / "firmware" / "ports" / "README.md"
CORE_OBJECTS = ("crc16.o", "cobs.o", "config.o", "msg.o", "frame.o", "filter.o", "match.o", "peer.o")
# Outside the 4 KB budget, measured apart: the state machine, and the authenticated beacon's
# SHA-256/HMAC module (protocol/SPEC.md 9).
APART = ("auth.o", "anchor.o")
CPUS = ("cortex-m4", "cortex-m0plus")


def make(*args: str) -> str:
    if shutil.which("arm-none-eabi-gcc") is None:
        raise AssertionError("arm-none-eabi-gcc not found: run tools/bootstrap.sh firmware")
    r = subprocess.run(["make", "-s", "-C", str(REPO / "firmware"), *args], capture_output=True, text=True,
                       timeout=600, env=dict(os.environ, MAKEFLAGS=""))
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def size_rows(out: str) -> list[tuple[str, int, int, int]]:
    """(file, text, data, bss) of every arm-none-eabi-size line, in order."""
    rows = []
    for line in out.splitlines():
        f = line.split()
        if len(f) == 6 and f[0].isdigit() and (f[5].endswith(".o") or f[5].endswith(".elf")):
            rows.append((f[5], int(f[0]), int(f[1]), int(f[2])))
    return rows


def table_row(doc: str, first_cell: str) -> list[str]:
    """The cells after the first of the markdown row whose first cell starts with first_cell."""
    for line in doc.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0].startswith(first_cell):
            return cells[1:]
    raise AssertionError(f"no row {first_cell!r} in the table")


def numbers(cell: str) -> list[int]:
    return [int(x) for x in re.findall(r"\d+", cell.replace(",", ""))]


@pytest.fixture(scope="module")
def cortex_m() -> str:
    return make("cortex-m")


@pytest.fixture(scope="module")
def qemu_sizes() -> dict[str, tuple[int, int, int]]:
    out = make("-C", "ports/qemu_mps2", "size")
    return {Path(f).name: (t, d, b) for f, t, d, b in size_rows(out)}


def core_sizes(out: str) -> dict[str, dict[str, int]]:
    """cpu -> object -> text bytes, from the "-- cpu" blocks of the core objects."""
    by_cpu: dict[str, dict[str, int]] = {}
    cpu = None
    for line in out.splitlines():
        if line.startswith("-- "):
            cpu = line[3:].strip()
            by_cpu[cpu] = {}
        elif line.startswith("=="):
            cpu = None
        elif cpu is not None:
            for f, t, _, _ in size_rows(line):
                by_cpu[cpu][f] = t
    return by_cpu


def test_cortex_m_core_table_is_the_build(cortex_m):
    doc = FIRMWARE_README.read_text()
    core = core_sizes(cortex_m)
    assert set(core) == set(CPUS) and all(set(core[c]) == set(CORE_OBJECTS) | set(APART) for c in CPUS), core
    for obj in (*CORE_OBJECTS, *APART):
        assert numbers(" ".join(table_row(doc, obj)[:2]))[-2:] == [core[c][obj] for c in CPUS], obj
    budget = {c: sum(core[c][o] for o in CORE_OBJECTS) for c in CPUS}
    whole = {c: budget[c] + sum(core[c][o] for o in APART) for c in CPUS}
    assert numbers(" ".join(table_row(doc, "**budget set**"))) == [budget["cortex-m4"], 4096, budget["cortex-m0plus"]]
    assert numbers(" ".join(table_row(doc, "**whole core**"))) == [whole["cortex-m4"], whole["cortex-m0plus"]]
    # The build's own line agrees with the sum (the table cannot drift from the budget check either).
    m4 = core["cortex-m4"]
    assert (f"{budget['cortex-m4']} bytes, budget 4096; anchor.o adds {m4['anchor.o']}, auth.o (the authenticated "
            f"beacon, measured apart) {m4['auth.o']} (whole core {whole['cortex-m4']})") in cortex_m

    images = {Path(f).parent.name: (t, b) for f, t, _, b in size_rows(cortex_m) if f.endswith("anchor.elf")}
    assert numbers(" ".join(table_row(doc, "whole image"))) == [*images["cortex-m4"], *images["cortex-m0plus"]]
    beacon = {Path(f).parent.name: t for f, t, _, _ in size_rows(cortex_m) if f.endswith("beacon.o")}
    assert numbers(" ".join(table_row(doc, "beacon.o")[:2])) == [beacon[c] for c in CPUS]


def test_stack_bounds_in_the_docs_are_the_build(cortex_m):
    # Per cpu: the anchor core's worst case, then the beacon's (the Makefile's order).
    worst = [int(x) for x in re.findall(r"^worst case: (\d+) bytes", cortex_m, re.M)]
    assert len(worst) == 4, worst
    doc = " ".join(FIRMWARE_README.read_text().split())
    assert f"{worst[0]} bytes on M4 and {worst[2]} on M0+" in doc
    assert f"the beacon's worst is {worst[1]} / {worst[3]} bytes" in doc
    ports = " ".join(PORTS_README.read_text().split())  # the QEMU port's stack sum quotes it
    assert f"the core's worst {worst[0]} (the Cortex-M4 figure there" in ports


def test_qemu_image_table_is_the_build(qemu_sizes):
    assert set(qemu_sizes) == {"pfdoa_anchor_sil.elf", "pfdoa_anchor.elf", "port_selftest.elf"}
    doc = PORTS_README.read_text()
    for name, sizes in qemu_sizes.items():
        rows = re.findall(rf"^\| `{re.escape(name)}` \| (\d+) \| (\d+) \| (\d+) \|$", doc, re.M)
        assert [tuple(map(int, r)) for r in rows] == [sizes], (name, rows)


def test_board_image_sentence_is_the_port_tables(qemu_sizes):
    """firmware/README.md's summary of the board images repeats the ports' tables (the
    nRF52840 table itself is checked against its build in test_nrf52840_port.py)."""
    doc = " ".join(FIRMWARE_README.read_text().split())
    ports = PORTS_README.read_text()
    prod, sil = qemu_sizes["pfdoa_anchor.elf"], qemu_sizes["pfdoa_anchor_sil.elf"]
    assert f"QEMU mps2-an385 production {prod[0]} / {prod[2]}, SIL {sil[0]} / {sil[2]};" in doc
    for label, name in (("UART", "uart"), ("CAN (MCP2515)", "can"), ("IEEE 802.15.4", "154"),
                        ("the authenticated beacon", "beacon")):
        text, _, bss = numbers(" ".join(table_row(ports, f"`pfdoa_nrf52840_{name}.elf`")[-3:]))
        assert f"{label} {text} / {bss}" in doc, label


def test_readme_core_budget_line_is_the_build(cortex_m):
    core = core_sizes(cortex_m)
    budget = {c: sum(core[c][o] for o in CORE_OBJECTS) for c in CPUS}
    row = table_row((REPO / "README.md").read_text(), "Anchor core .text")
    m = re.search(r"([\d,]+) B Cortex-M4, ([\d,]+) B Cortex-M0\+", row[0])
    assert m is not None, row
    assert [int(x.replace(",", "")) for x in m.groups()] == [budget["cortex-m4"], budget["cortex-m0plus"]], row
    assert f"SHA-256/HMAC apart: {core['cortex-m4']['auth.o']:,} B M4" in row[0], row
