#!/usr/bin/env python3
"""Flash an nRF52840 image with pyocd (PyPI `pyocd`, built-in target `nrf52840`).

Usage: flash.py [--pyocd PATH] IMAGE.hex

Runs `pyocd flash --target nrf52840 --no-wait --erase sector IMAGE` (sector erase keeps
the store pages at 0xFE000 and 0xFF000, configuration and filter table, since link.ld
keeps the image out of them). Without a probe pyocd would wait forever; with --no-wait it
fails, and this prints one line saying so.
Exit 0 when flashed, 1 when no probe or flashing failed, 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

NO_PROBE = ("No connected debug probes", "No target device available", "No available debug probes")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("image", type=Path, help="Intel hex image (firmware/build/nrf52840/...)")
    p.add_argument("--pyocd", default="pyocd", help="the pyocd executable")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds before giving up")
    args = p.parse_args()
    if not args.image.is_file():
        print(f"flash: {args.image}: no such image (run make firmware)")
        return 2
    exe = shutil.which(args.pyocd)
    if exe is None:
        print(f"flash: {args.pyocd} not found: install it with `pip install pyocd` (make flash does)")
        return 1
    cmd = [exe, "flash", "--target", "nrf52840", "--no-wait", "--erase", "sector", str(args.image)]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
    except subprocess.TimeoutExpired:
        print(f"flash: pyocd did not finish within {args.timeout:.0f} s")
        return 1
    out = (r.stdout + r.stderr).strip()
    if r.returncode == 0:
        print(f"flash: {args.image.name} written and the target reset")
        return 0
    if any(s in out for s in NO_PROBE):
        print("flash: no debug probe found - connect the nRF52840 DK's interface MCU USB connector J2 (not J3, "
              "marked nRF USB), switch the DK on (SW8), and check with `pyocd list`")
        return 1
    last = out.splitlines()[-1] if out else f"exit status {r.returncode}"
    print(f"flash: pyocd failed: {last}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
