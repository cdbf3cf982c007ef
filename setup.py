"""Packaging hook: ship the anchor firmware the simulator runs inside the pfdoasim package.

Everything else is declared in pyproject.toml. The simulator's backends run the real
firmware (pfdoasim.firmware finds it); in a checkout that is ``firmware/``, but a wheel or
``pip install .`` has no checkout beside it, so the sources the c and mpy backends need
are copied into ``pfdoasim/_firmware`` of the build: the C core (compiled on first use into
the user cache) and the MicroPython anchor. Editable installs use the checkout itself.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
# What the c and mpy backends load, relative to firmware/ (not the ports, Makefiles or tests).
FIRMWARE_FILES = ("core/include/*.h", "core/src/*.c", "core/src/*.h", "micropython/pfdoa_*.py")


class BuildPyWithFirmware(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install runs from the checkout, which has firmware/
        src = HERE / "firmware"
        dst = Path(self.build_lib) / "pfdoasim" / "_firmware"
        files = [p for pattern in FIRMWARE_FILES for p in sorted(src.glob(pattern))]
        if not files:
            raise SystemExit(f"setup.py: no firmware sources under {src} to ship with pfdoasim")
        shutil.rmtree(dst, ignore_errors=True)
        for p in files:
            out = dst / p.relative_to(src)
            out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(p, out)
        shutil.copy2(HERE / "LICENSE", dst / "LICENSE")


setup(cmdclass={"build_py": BuildPyWithFirmware})
