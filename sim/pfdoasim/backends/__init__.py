"""The simulator's anchor backends (``pfdoa sim --anchor-backend NAME``), one module each.

As python-can lays out its interfaces: :mod:`~pfdoasim.backends.base` holds the shared
base classes, each backend is one module here, and :data:`BACKENDS` maps a name to the
module and class that implement it, imported only when used (``--help`` loads none).

* ``c`` - the real firmware core, built into a shared library and loaded with ctypes
  (:mod:`~pfdoasim.backends.c`). The demo and the end-to-end tests use this one.
* ``mpy`` - the MicroPython anchor (firmware/micropython) run by CPython
  (:mod:`~pfdoasim.backends.mpy`): the same state machine, independently written.
* ``py-mean`` - a test double that reports each beacon event's mean reading with no
  filtering (:mod:`~pfdoasim.backends.py_mean`). For developing transports without a C
  toolchain; never a stand-in for the firmware's behaviour.
* ``qemu`` - the Cortex-M3 firmware image under QEMU, one serial port per anchor
  (:mod:`~pfdoasim.backends.qemu`; its runs: :mod:`pfdoasim.qemu_harness`).
"""

from __future__ import annotations

import importlib

from pfdoa.errors import InputError
from pfdoasim.backends.base import AnchorFactory, Backend

# name -> (module, class, one line for --help)
BACKENDS: dict[str, tuple[str, str, str]] = {
    "c": ("pfdoasim.backends.c", "CBackend", "the firmware core via ctypes (default)"),
    "mpy": ("pfdoasim.backends.mpy", "MpyBackend", "the MicroPython anchor under CPython"),
    "py-mean": ("pfdoasim.backends.py_mean", "MeanBackend", "unfiltered test double"),
    "qemu": ("pfdoasim.backends.qemu", "QemuBackend",
             "the Cortex-M3 firmware image under QEMU, one serial port per anchor"),
}
DEFAULT = "c"


def names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def backend(name: str) -> Backend:
    """The named backend (InputError for an unknown name)."""
    if name not in BACKENDS:
        raise InputError(f"unknown anchor backend {name!r} (known: {', '.join(BACKENDS)})")
    module, cls, _ = BACKENDS[name]
    impl: type[Backend] = getattr(importlib.import_module(module), cls)
    return impl()


def anchor_factory(name: str = DEFAULT, core_lib: str | None = None) -> AnchorFactory:
    """A factory of anchors for one run with the named in-process backend (InputError if unavailable)."""
    return backend(name).factory(core_lib)
