"""The nRF52840 port's flashing path without a board: firmware/ports/nrf52840/tools/flash.py
(the pyocd wrapper `make flash BOARD=nrf52840dk` runs) against stand-in pyocd executables,
and the Makefile's argument checks. The port's drivers are tested in C against the register
fake (firmware/ports/nrf52840/tests, run by `make test-c`)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

from pfdoa.protocol import defs

REPO = Path(__file__).resolve().parents[2]
PORT = REPO / "firmware" / "ports" / "nrf52840"
FLASH = PORT / "tools" / "flash.py"


def stand_in(tmp_path: Path, body: str) -> Path:
    """An executable 'pyocd' that records its arguments and then runs body (shell)."""
    exe = tmp_path / "pyocd"
    exe.write_text(f'#!/bin/sh\necho "$@" > "{tmp_path}/args"\n{body}\n')
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return exe


def flash(tmp_path: Path, pyocd: str, image: Path | None = None) -> subprocess.CompletedProcess:
    if image is None:
        image = tmp_path / "pfdoa_nrf52840_uart.hex"
        image.write_text(":00000001FF\n")
    return subprocess.run([sys.executable, str(FLASH), "--pyocd", pyocd, str(image)], capture_output=True,
                          text=True, timeout=60)


def test_no_probe_is_one_line_and_exit_1(tmp_path):
    # What pyocd 0.46 prints with --no-wait and nothing connected.
    exe = stand_in(tmp_path, 'echo "No connected debug probes"\necho "0000272 E No target device available" >&2\nexit 1')
    r = flash(tmp_path, str(exe))
    assert r.returncode == 1
    assert r.stdout.splitlines() == [r.stdout.strip()]
    assert r.stdout.startswith("flash: no debug probe found")
    assert r.stderr == ""


def test_flash_runs_pyocd_for_the_nrf52840_without_waiting(tmp_path):
    exe = stand_in(tmp_path, "exit 0")
    r = flash(tmp_path, str(exe))
    assert r.returncode == 0, r.stdout
    args = (tmp_path / "args").read_text().split()
    assert args[:2] == ["flash", "--target"] and args[2] == "nrf52840"
    assert "--no-wait" in args  # pyocd would otherwise wait forever for a probe
    assert args[args.index("--erase") + 1] == "sector"  # keeps the configuration page
    assert args[-1].endswith("pfdoa_nrf52840_uart.hex")


def test_other_pyocd_failure_reports_its_last_line(tmp_path):
    exe = stand_in(tmp_path, 'echo "0001234 E Flash algorithm failed at 0x1000" >&2\nexit 1')
    r = flash(tmp_path, str(exe))
    assert r.returncode == 1
    assert r.stdout.strip() == "flash: pyocd failed: 0001234 E Flash algorithm failed at 0x1000"


def test_missing_pyocd_or_image(tmp_path):
    r = flash(tmp_path, str(tmp_path / "no-such-pyocd"))
    assert r.returncode == 1 and r.stdout.count("\n") == 1 and "pip install pyocd" in r.stdout
    r = flash(tmp_path, str(stand_in(tmp_path, "exit 0")), image=tmp_path / "missing.hex")
    assert r.returncode == 2 and "no such image" in r.stdout


def test_make_flash_checks_its_arguments_first():
    env = dict(os.environ, MAKEFLAGS="")
    for args, needle in ((["IMAGE=ble"], "IMAGE must be uart, can, 154 or beacon"),
                         ([f"ANCHOR_ID={defs.ANCHOR_ID_MAX + 1}"], f"ANCHOR_ID must be 0..{defs.ANCHOR_ID_MAX}"),
                         (["ANCHOR_ID=x"], "ANCHOR_ID must be a number")):
        r = subprocess.run(["make", "-s", "-C", str(PORT), "flash", *args], capture_output=True, text=True,
                           timeout=60, env=env)
        assert r.returncode != 0
        assert needle in r.stdout
    r = subprocess.run(["make", "-s", "-C", str(REPO), "flash", "BOARD=pca10040"], capture_output=True, text=True,
                       timeout=60, env=env)
    assert r.returncode != 0 and "BOARD=nrf52840dk" in r.stdout


def test_make_flash_beacon_flashes_the_beacon_image(tmp_path):
    """IMAGE=beacon: the authenticated beacon's image (no anchor id in it), sector erase
    (its key's flash page stays)."""
    exe = stand_in(tmp_path, "exit 0")
    r = subprocess.run(["make", "-s", "-C", str(PORT), "flash", "IMAGE=beacon", f"PYOCD={exe}",
                        f"PYTHON={sys.executable}"], capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, MAKEFLAGS=""))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "the authenticated beacon image" in r.stdout
    args = (tmp_path / "args").read_text().split()
    assert args[args.index("--erase") + 1] == "sector"
    assert args[-1].endswith("pfdoa_nrf52840_beacon.hex")


def test_size_table_in_the_docs_is_the_images():
    """firmware/ports/README.md's nRF52840 size table is what `make firmware` measures."""
    r = subprocess.run(["make", "-s", "-C", str(PORT), "size"], capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, MAKEFLAGS=""))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "ok: no floating point in the nRF52840 images" in r.stdout
    measured = {}
    for line in r.stdout.splitlines():
        f = line.split()
        if len(f) == 6 and f[5].endswith(".elf"):
            measured[Path(f[5]).name] = (int(f[0]), int(f[1]), int(f[2]))
    assert set(measured) == {"pfdoa_nrf52840_uart.elf", "pfdoa_nrf52840_can.elf", "pfdoa_nrf52840_154.elf",
                             "pfdoa_nrf52840_beacon.elf"}
    doc = (REPO / "firmware" / "ports" / "README.md").read_text()
    for name, (text, data, bss) in measured.items():
        assert f"| `{name}` |" in doc, name
        row = next(line for line in doc.splitlines() if line.startswith(f"| `{name}` |"))
        assert row.rstrip().endswith(f"| {text} | {data} | {bss} |"), (row, measured[name])
