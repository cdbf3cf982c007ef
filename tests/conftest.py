"""Test tiers, the unit tier's CPU budget, and the fixtures several test files share.

A test's tier is the folder it sits in (``--strict-markers`` in pyproject.toml):

* ``tests/unit``     in-process, no real time: the fast tier (``make check``);
* ``tests/io``       real endpoints (pseudo-terminals, pipes, python-can, subprocesses, brokers)
                     on the wall clock: they assert counters and liveness, never accuracy;
* ``tests/sil``      the simulator with the real firmware core driving the gateway in virtual
                     time: accuracy, determinism and timing, a function of the seed;
* ``tests/firmware`` builds and runs the C core or the MicroPython anchor (compilers needed);
* ``tests/qemu``     the Cortex-M3 images under QEMU (cross compiler and QEMU needed).

Every collected test gets its folder's marker, so ``pytest -m unit`` and ``pytest tests/unit``
select the same tests. A test file outside a tier folder, or a test marked with another tier
than its folder's, is an error at collection: a file cannot slip out of ``make check`` or into
it unnoticed. ``slow`` marks a test that takes more than ~20 s; ``make test`` still runs it.
The helper modules beside this file (gateway_feed.py, mqtt_support.py ...) are importable from
every tier folder (``pythonpath`` in pyproject.toml). A missing toolchain is a failure (the
tests say which bootstrap command installs it), never a silent skip.

A unit test whose set-up and call together take more than :data:`UNIT_CPU_BUDGET_S` of CPU
time fails, named in one line: the unit tier stays a quick loop. CPU time (the worker's and
its reaped children's user + system time, from getrusage) and not wall time, so a busy machine
does not fail it; a module- or session-scoped fixture counts towards the first test that sets
it up.
"""

from __future__ import annotations

import resource
from pathlib import Path

import pytest

from pfdoasim import firmware
from pfdoasim.fleet import Mosquitto, mosquitto_binary

import gateway_feed
from mqtt_support import make_tls_files

TIERS = ("unit", "io", "sil", "firmware", "qemu")
TESTS = Path(__file__).resolve().parent

# Generous: the slowest unit tests (the bit-error checks of test_corruption.py) take 2-4 s of
# CPU, most take well under one; a fixture of a minute (an
# evaluation run) belongs in tests/sil.
UNIT_CPU_BUDGET_S = 10.0
_CPU_S = pytest.StashKey[float]()

# `make test` runs pytest in two worker processes (pytest-xdist). The tiers that build into
# firmware/build with make (Cortex-M, nRF52840 and QEMU images, size tables) and run or
# measure what is there take turns: each such test, its fixtures' set-up and tear-down
# included, holds FIRMWARE_TREE_LOCK, so two workers never run make over one folder. Every
# other test is self-contained (temporary folders, free ports, private C harness builds; the
# simulator's own make runs under pfdoasim.firmware.build_lock). A lock and not xdist's
# --dist loadgroup: with pytest 9.2 that no longer groups (pytest-dev/pytest-xdist#1386).
FIRMWARE_TREE_TIERS = {"firmware", "qemu"}
FIRMWARE_TREE_LOCK = ".tests.lock"  # in firmware/build


def folder_tier(path: Path) -> str | None:
    """The tier folder (tests/<tier>/...) a test file sits in, or None."""
    try:
        parts = path.resolve().relative_to(TESTS).parts
    except ValueError:
        return None
    return parts[0] if len(parts) > 1 and parts[0] in TIERS else None


def pytest_collection_modifyitems(config, items):
    errors = []
    for item in items:
        tier = folder_tier(item.path)
        marked = {m.name for m in item.iter_markers() if m.name in TIERS}
        if tier is None:
            errors.append(f"{item.nodeid}: not in a tier folder (tests/{{{','.join(TIERS)}}}/)")
        elif marked - {tier}:
            errors.append(f"{item.nodeid}: marked {', '.join(sorted(marked - {tier}))} in tests/{tier}/ "
                          "(a test's tier is its folder: move it, or drop the marker)")
        else:
            item.add_marker(getattr(pytest.mark, tier))
    if errors:
        raise pytest.UsageError("test tiers (tests/conftest.py): " + "; ".join(errors[:5])
                                + (f"; and {len(errors) - 5} more" if len(errors) > 5 else ""))


def _cpu_s() -> float:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _charge(item):
    start = _cpu_s()
    try:
        return (yield)
    finally:
        item.stash[_CPU_S] = item.stash.get(_CPU_S, 0.0) + _cpu_s() - start


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item):
    return (yield from _charge(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item):
    return (yield from _charge(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if call.when == "call" and report.passed and item.get_closest_marker("unit") is not None:
        cpu = item.stash.get(_CPU_S, 0.0)
        if cpu > UNIT_CPU_BUDGET_S:
            report.outcome = "failed"
            report.longrepr = (f"{item.nodeid}: {cpu:.1f} s of CPU in set-up and call, over the unit tier's "
                               f"budget of {UNIT_CPU_BUDGET_S:g} s (tests/conftest.py): make it smaller "
                               "or move it to tests/sil")
    return report


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not any(item.get_closest_marker(t) for t in FIRMWARE_TREE_TIERS):
        return (yield)
    with firmware.build_lock(firmware.CHECKOUT / "build", FIRMWARE_TREE_LOCK):
        return (yield)


# The 4 x 4 m, four-anchor site of tests/gateway_feed.py (anchors 0..3 at the corners).
SITE_TOML = gateway_feed.TEST_SITE


@pytest.fixture
def site_file(tmp_path):
    """Write the shared site (plus any extra TOML tables) and return its path."""

    def write(extra: str = "", name: str = "site.toml") -> Path:
        p = tmp_path / name
        p.write_text(SITE_TOML + ("\n" + extra if extra else ""))
        return p

    return write


@pytest.fixture()
def browser(tmp_path):
    """Debian's headless Chromium through the DevTools protocol (tests/cdp.py)."""
    from cdp import Browser, chromium_path

    if chromium_path() is None:
        pytest.fail("Debian chromium is part of the test environment (tools/bootstrap.sh test)")
    b = Browser(tmp_path / "profile")
    yield b
    b.close()


# A real mosquitto per test (Debian's mosquitto, installed by tools/bootstrap.sh for `test`):
# a missing binary is a failure with the bootstrap command in the message, not a skip.
def _need_mosquitto() -> None:
    try:
        mosquitto_binary()
    except FileNotFoundError as exc:
        raise AssertionError(str(exc)) from None


@pytest.fixture
def broker(tmp_path):
    """An anonymous broker on a free port, no persistence."""
    _need_mosquitto()
    b = Mosquitto(tmp_path / "broker").start()
    yield b
    b.stop()


@pytest.fixture
def persistent_broker(tmp_path):
    """Keeps retained messages and persistent sessions across restart()."""
    _need_mosquitto()
    b = Mosquitto(tmp_path / "broker", persistence=True).start()
    yield b
    b.stop()


@pytest.fixture
def password_broker(tmp_path):
    """Anonymous access off; one user: fleet / s3cret-pw."""
    _need_mosquitto()
    b = Mosquitto(tmp_path / "broker", users={"fleet": "s3cret-pw"}).start()
    yield b
    b.stop()


@pytest.fixture
def tls_broker(tmp_path):
    _need_mosquitto()
    b = Mosquitto(tmp_path / "broker", tls=make_tls_files(tmp_path / "tls")).start()
    yield b
    b.stop()

