"""Fixtures shared by the test files: a real mosquitto per test (tests/mqtt_support.py has the helpers).

The broker is Debian's ``mosquitto`` (tools/bootstrap.sh installs it for ``test``): a
missing binary is a failure with the bootstrap command in the message, not a skip.
"""

import pytest
from mqtt_support import make_tls_files

from pfdoasim.fleet import Mosquitto, mosquitto_binary


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

