"""Shared by the tests/qemu/test_qemu*.py files: build the firmware images they run.

Builds are incremental (make). A missing cross compiler or QEMU is a failure with the
bootstrap command in the message, not a skip: `make test` installs both.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from c_harness import script_harness

REPO = Path(__file__).resolve().parents[1]


def _need(tool: str) -> None:
    if shutil.which(tool) is None:
        raise AssertionError(f"{tool} not found: run tools/bootstrap.sh test")


def build_qemu_images() -> Path:
    """firmware/build/qemu_mps2/{pfdoa_anchor_sil,pfdoa_anchor,port_selftest}.elf."""
    _need("arm-none-eabi-gcc")
    _need("qemu-system-arm")
    from pfdoasim.backends.qemu import build_images

    return build_images()


def build_host_script() -> Path:
    """The host build's event-script runner with RADIO_INJECT, built in a private directory
    (a concurrent rebuild of firmware/build must not swap it mid-test: tests/c_harness.py)."""
    return script_harness(sil=True)
