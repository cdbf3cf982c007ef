"""Test tiers, and the site file several test files share.

Every test belongs to exactly one tier (``--strict-markers`` in pyproject.toml):

* ``unit``     in-process, no real time: the fast tier (``make test-fast``, under a minute);
* ``io``       real endpoints (pseudo-terminals, pipes, python-can, subprocesses) on the wall
               clock: they assert counters and liveness, never accuracy;
* ``sil``      the simulator with the real firmware core driving the gateway in virtual
               time: accuracy, determinism and timing, a function of the seed;
* ``firmware`` builds and runs the C core or the MicroPython anchor (compilers needed);
* ``qemu``     the Cortex-M3 images under QEMU (cross compiler and QEMU needed).

``slow`` marks a test that takes more than ~20 s; ``make test`` still runs it. A module
declares its tier with ``pytestmark``, or gets the one :data:`MODULE_TIERS` names; a test
with no tier is an error at collection, so a new file cannot slip out of ``make test-fast``
or into it unnoticed. A missing toolchain is a failure (the tests say which bootstrap
command installs it), never a silent skip.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pfdoasim import firmware
from pfdoasim.fleet import Mosquitto, mosquitto_binary

import gateway_feed
from mqtt_support import make_tls_files

TIERS = ("unit", "io", "sil", "firmware", "qemu")

# `make test` runs pytest in two worker processes (pytest-xdist). The tiers that build into
# firmware/build with make (Cortex-M, nRF52840 and QEMU images, size tables) and run or
# measure what is there take turns: each such test, its fixtures' set-up and tear-down
# included, holds FIRMWARE_TREE_LOCK, so two workers never run make over one folder. Every
# other test is self-contained (temporary folders, free ports, private C harness builds; the
# simulator's own make runs under pfdoasim.firmware.build_lock). A lock and not xdist's
# --dist loadgroup: with pytest 9.2 that no longer groups (pytest-dev/pytest-xdist#1386).
FIRMWARE_TREE_TIERS = {"firmware", "qemu"}
FIRMWARE_TREE_LOCK = ".tests.lock"  # in firmware/build

MODULE_TIERS = {
    "test_accuracy": "sil",
    "test_anchors_manage": "unit",
    "test_anchors_sil": "io",
    "test_anchorclock": "unit",
    "test_beacons": "unit",
    "test_bench": "firmware",
    "test_bench_fleet": "unit",
    "test_bench_hotpaths": "unit",
    "test_calibrate": "unit",
    "test_cli": "io",
    "test_corruption": "unit",
    "test_differential": "firmware",
    "test_doa": "unit",
    "test_estimators": "unit",
    "test_eval": "unit",
    "test_faults_sil": "sil",
    "test_fuzz_regressions": "unit",
    "test_gateway": "io",
    "test_gateway_beacons": "unit",
    "test_gateway_fuzz": "unit",
    "test_hostile_cli": "io",
    "test_hostile_units": "unit",
    "test_mqtt_broker": "io",
    "test_mqtt_config": "unit",
    "test_mqtt_units": "unit",
    "test_nrf52840_port": "firmware",
    "test_odometry": "unit",
    "test_outputs_hostile": "io",
    "test_protocol_filters": "unit",
    "test_protocol_gen": "unit",
    "test_protocol_hand": "unit",
    "test_protocol_model": "unit",
    "test_protocol_numbers": "unit",
    "test_protocol_stream": "unit",
    "test_protocol_vectors": "unit",
    "test_python310": "io",
    "test_qemu_anchors": "qemu",
    "test_qemu_e2e": "qemu",
    "test_qemu_identity": "qemu",
    "test_qemu_peers": "qemu",
    "test_qemu_port": "qemu",
    "test_readme": "io",
    "test_reassembly": "unit",
    "test_robot_sil": "sil",
    "test_replay": "unit",
    "test_runner": "unit",
    "test_security": "unit",
    "test_sim_backends": "sil",
    "test_sim_beacons": "sil",
    "test_sim_channel": "unit",
    "test_sim_cli": "io",
    "test_sim_determinism": "sil",
    "test_sim_e2e": "sil",
    "test_sim_espresense": "sil",
    "test_sim_faults": "unit",
    "test_sim_fleet": "io",
    "test_sim_realtime": "io",
    "test_sim_timing": "sil",
    "test_sim_trajectories": "unit",
    "test_sim_transports": "io",
    "test_sink_mcap": "unit",
    "test_sink_options": "unit",
    "test_sink_web": "io",
    "test_live_view": "io",
    "test_sinks": "unit",
    "test_site": "unit",
    "test_sites": "unit",
    "test_trace": "unit",
    "test_transports": "io",
}


def pytest_collection_modifyitems(config, items):
    missing = []
    for item in items:
        tiers = {m.name for m in item.iter_markers() if m.name in TIERS}
        if not tiers:
            tier = MODULE_TIERS.get(Path(str(item.fspath)).stem)
            if tier is None:
                missing.append(item.nodeid)
                continue
            item.add_marker(getattr(pytest.mark, tier))
        elif len(tiers) > 1:
            raise pytest.UsageError(f"{item.nodeid}: more than one test tier ({', '.join(sorted(tiers))})")
    if missing:
        raise pytest.UsageError("tests without a tier (add pytestmark = pytest.mark.<tier>, or the module to "
                                f"MODULE_TIERS in tests/conftest.py; tiers: {', '.join(TIERS)}): " + ", ".join(missing[:5]))


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

