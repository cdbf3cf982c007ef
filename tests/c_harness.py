"""The C core's host event-script harness (firmware/host/anchor_script.c), built for tests
in a private build directory.

Tests never execute or copy firmware/build/host/*: other `make` runs (make test-c, a
concurrent rebuild) rewrite those files at any moment, and exec'ing a binary the linker
still has open fails with ETXTBSY ("Text file busy"), copying it may take a half-written
file, and two makes compiling the same objects can link a truncated one. A private BUILD
shares nothing with them; the core is small, so the extra build takes a few seconds.
"""

from __future__ import annotations

import atexit
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_BUILD: list[Path] = []
_MADE: set[str] = set()


def _private_build(target: str) -> Path:
    """``make -C firmware BUILD=<private dir> <target>``, once per process and target; the
    private build/host directory."""
    if not _BUILD:
        tmp = Path(tempfile.mkdtemp(prefix="pfdoa-harness-"))
        atexit.register(shutil.rmtree, tmp, True)
        _BUILD.append(tmp / "host")
    if target not in _MADE:
        p = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware"), f"BUILD={_BUILD[0].parent}", target],
                           capture_output=True, text=True, timeout=600)
        if p.returncode != 0:
            raise AssertionError(f"`make -C firmware {target}` failed:\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
        _MADE.add(target)
    return _BUILD[0]


def script_harness(sil: bool = False) -> Path:
    """``anchor_script`` (``anchor_script_sil`` with RADIO_INJECT), built once per process
    from the current sources (``make -C firmware BUILD=<private dir> script``)."""
    exe = _private_build("script") / ("anchor_script_sil" if sil else "anchor_script")
    if not exe.exists():
        raise AssertionError(f"C harness {exe} missing after `make -C firmware script`")
    return exe


def core_library() -> Path:
    """``libpfdoa_anchor.so`` (the core with its auth module) from a private build, for ctypes."""
    lib = _private_build("host-lib") / "libpfdoa_anchor.so"
    if not lib.exists():
        raise AssertionError(f"{lib} missing after `make -C firmware host-lib`")
    return lib
