"""Where the anchor firmware is: the one place the simulator looks for it.

The anchor backends run the real firmware: the C core (built into a shared library for
ctypes), the MicroPython anchor (imported by CPython), the QEMU port (Cortex-M3 images).
:func:`locate` finds the tree they come from, in this order:

1. ``$PFDOA_FIRMWARE``: a ``firmware`` folder named by the user (a checkout's, or a copy);
2. the source checkout this package runs from (``<repo>/firmware``: an editable install,
   ``make`` targets, the tests), which has the Makefiles and builds with ``make``;
3. the copy shipped inside the package (``pfdoasim/_firmware``, put there by
   ``pip install .``/a wheel; see setup.py): the core's C sources and headers and the
   MicroPython anchor, no Makefiles and no ports. The C library is then compiled on first
   use into the user cache (:func:`cache_dir`).

A missing tree, or a part a backend needs that this tree does not have (the QEMU port in
a pip installation), is one :class:`~pfdoa.errors.InputError` line saying where it looked
and what to do.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from pfdoa.errors import InputError

ENV_FIRMWARE = "PFDOA_FIRMWARE"
ENV_CACHE = "PFDOA_CACHE_DIR"
CHECKOUT = Path(__file__).resolve().parents[2] / "firmware"  # <repo>/sim/pfdoasim/firmware.py
PACKAGED = Path(__file__).resolve().parent / "_firmware"
MARKER = Path("core") / "include" / "pfdoa_anchor.h"  # a folder holding this is a firmware tree

# The parts of a tree, relative to its root; the packaged copy has only the first two.
PARTS = {
    "core": Path("core"),
    "micropython": Path("micropython"),
    "qemu port": Path("ports") / "qemu_mps2",
}


@dataclass(frozen=True)
class FirmwareTree:
    """A firmware folder. ``checkout``: it has the Makefiles (``make -C firmware host-lib``
    builds the C library into ``build/host``); otherwise it is the packaged copy."""

    root: Path
    origin: str  # how it was found: "PFDOA_FIRMWARE", "checkout" or "package"

    @property
    def checkout(self) -> bool:
        return (self.root / "Makefile").is_file()

    def part(self, name: str) -> Path:
        """The folder of one part (see :data:`PARTS`); InputError when this tree lacks it."""
        p = self.root / PARTS[name]
        if not p.is_dir():
            hint = ("the packaged firmware holds only the C core and the MicroPython anchor: run from a pfdoa "
                    f"checkout, or set {ENV_FIRMWARE} to a checkout's firmware folder"
                    if self.origin == "package" else "is the checkout complete?")
            raise InputError(f"the firmware's {name} ({PARTS[name]}) is not in {self.root} ({hint})")
        return p

    @property
    def build_dir(self) -> Path:
        """Where the checkout's Makefiles put their outputs."""
        return self.root / "build"


def locate() -> FirmwareTree:
    """The firmware tree the backends use (see the module doc); InputError if there is none."""
    env = os.environ.get(ENV_FIRMWARE)
    if env:
        root = Path(env).expanduser()
        if not (root / MARKER).is_file():
            raise InputError(f"{ENV_FIRMWARE}={env}: not a pfdoa firmware folder (no {MARKER} in it)")
        return FirmwareTree(root.resolve(), ENV_FIRMWARE)
    for root, origin in ((CHECKOUT, "checkout"), (PACKAGED, "package")):
        if (root / MARKER).is_file():
            return FirmwareTree(root, origin)
    raise InputError(f"the anchor firmware was not found (looked in {CHECKOUT} and {PACKAGED}): install pfdoa "
                     f"with 'pip install .' from a checkout, or set {ENV_FIRMWARE} to a checkout's firmware folder")


def cache_dir() -> Path:
    """The user's cache for what the simulator builds (``$PFDOA_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/pfdoa``, else ``~/.cache/pfdoa``)."""
    env = os.environ.get(ENV_CACHE)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pfdoa"


@contextmanager
def build_lock(build_dir: Path, name: str = ".lock") -> Iterator[None]:
    """Hold an exclusive lock on ``build_dir/name`` while a checkout's ``make`` runs.

    Two simulators (or two test workers) starting at once in one checkout would otherwise
    run two makes over the same objects and link a truncated library; with the lock the
    second make waits, then finds everything up to date. Where there is no ``fcntl``
    (not POSIX) the build runs unlocked, as before. Locks of other ``name``s are independent
    (the tests' own turn-taking, tests/conftest.py, holds one while the simulator takes this).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - POSIX only
        yield
        return
    build_dir.mkdir(parents=True, exist_ok=True)
    with open(build_dir / name, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
