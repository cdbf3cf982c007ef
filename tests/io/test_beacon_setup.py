"""`pfdoa anchors beacon`: an authenticated beacon's key and time over its UART
(pfdoa.beacon_setup), in the nRF52840 beacon image's line protocol. The answers here are
the ones firmware/ports/nrf52840/tests/test_nrf_beacon.c gets from the image itself on the
register fake (key 00 01 .. 0f: key check ec5ad48c); the command runs on a real
pseudo-terminal against a peer that answers in that protocol."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from pfdoa.beacon_setup import BeaconError, BeaconLink, parse_state, provision
from pfdoa.gateway.auth import write_key_file
from pfdoa.protocol import auth

pytestmark = pytest.mark.io

KEY = bytes(range(16))
NOW_MS = 432900100 * 4096 + 17


class LinePeer:
    """The beacon's side: answers each line as beacon_app.c does (or as told)."""

    def __init__(self, answers: dict[str, str] | None = None) -> None:
        self.lines: list[str] = []
        self.answers = answers or {}
        self.key_check = "-"
        self.counter = "-"
        self._out = bytearray()
        self._in = bytearray()

    def answer(self, line: str) -> str | None:
        self.lines.append(line)
        cmd = line.split(" ", 1)[0]
        if cmd in self.answers:
            return self.answers[cmd]
        if cmd == "K" and len(line) == 34:
            self.key_check = auth.key_check(bytes.fromhex(line[2:]))[:4].hex()
            return f"OK K {self.key_check}"
        if cmd == "T":
            if self.key_check == "-":
                return "ERR no key"
            self.counter = line.split()[1]
            return f"OK T {self.counter}"
        if line == "S":
            return f"S {self.key_check} {self.counter} 3 0"
        return "ERR unknown command (K, T, S)"

    # the port object BeaconLink uses
    def write(self, data: bytes) -> None:
        self._in += data
        while b"\n" in self._in:
            line, _, rest = bytes(self._in).partition(b"\n")
            self._in = bytearray(rest)
            reply = self.answer(line.decode())
            if reply is not None:
                self._out += reply.encode() + b"\r\n"

    def read(self, n: int) -> bytes:
        out, self._out = bytes(self._out[:n]), self._out[n:]
        return out


def test_key_check_is_the_firmwares():
    assert auth.key_check(KEY)[:4].hex() == "ec5ad48c"  # test_nrf_beacon.c's "OK K ec5ad48c"


def test_provision_sends_key_then_time_and_checks_the_answers():
    peer = LinePeer()
    state = provision(BeaconLink(peer), KEY, clock_ms=lambda: NOW_MS)
    assert peer.lines == [f"K {KEY.hex()}", "T 432900100 17", "S"]
    assert state.key_check == "ec5ad48c" and state.counter == 432900100 and state.sent == 3
    # Time only: the beacon keeps its key across a power cycle.
    peer.lines.clear()
    assert provision(BeaconLink(peer), None, clock_ms=lambda: NOW_MS + 4096).counter == 432900101
    assert peer.lines == ["T 432900101 17", "S"]


@pytest.mark.parametrize("answers, needle", [
    ({"K": "OK K 00000000"}, "it holds key check '00000000', the key file's is ec5ad48c"),
    ({"K": "ERR key not stored"}, "key: refused: key not stored"),
    ({"T": "OK T 5"}, "it answered counter '5', sent 432900100"),
    ({"S": "S - - 0 0"}, "it has no key"),
    ({"S": "S ec5ad48c x 0 0"}, "status: unexpected answer"),
    ({"K": "hello"}, "key: unexpected answer 'hello'"),
])
def test_wrong_answers_are_errors(answers, needle):
    with pytest.raises(BeaconError, match="beacon: ") as e:
        provision(BeaconLink(LinePeer(answers)), KEY, clock_ms=lambda: NOW_MS)
    assert needle in str(e.value)
    assert KEY.hex() not in str(e.value)


def test_silence_and_an_endless_line_end_in_time():
    class Silent:
        def write(self, data: bytes) -> None:
            pass

        def read(self, n: int) -> bytes:
            return b""

    t = [0.0]

    def tick() -> float:
        t[0] += 0.25
        return t[0]

    with pytest.raises(BeaconError, match="no answer within 2 s"):
        BeaconLink(Silent(), 2.0, monotonic=tick).ask("S", "status")

    class Chatty(Silent):
        def read(self, n: int) -> bytes:
            return b"x"

    with pytest.raises(BeaconError, match="longer than"):
        BeaconLink(Chatty(), 2.0, monotonic=lambda: 0.0).ask("S", "status")
    assert parse_state("S - 12 0 1").counter == 12


def test_cli_on_a_pseudo_terminal(tmp_path):
    key_file = tmp_path / "robot.key"
    write_key_file(key_file, KEY)
    master, slave = os.openpty()
    peer = LinePeer()
    stop = threading.Event()

    def serve() -> None:
        buf = b""
        while not stop.is_set():
            try:
                chunk = os.read(master, 256)
            except OSError:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = peer.answer(line.decode().strip("\r"))
                os.write(master, reply.encode() + b"\n")

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        r = subprocess.run([sys.executable, "-m", "pfdoa", "anchors", "beacon", "--serial", os.ttyname(slave),
                            "--key-file", str(key_file), "--json"], capture_output=True, text=True, timeout=60)
    finally:
        stop.set()
        os.close(slave)
        os.close(master)
        th.join(5)
    assert r.returncode == 0, r.stderr
    state = json.loads(r.stdout)
    assert state["key_check"] == "ec5ad48c" and state["sent"] == 3
    assert peer.lines[0] == f"K {KEY.hex()}" and peer.lines[1].startswith("T ") and peer.lines[2] == "S"
    assert KEY.hex() not in r.stdout + r.stderr  # the key goes to the beacon only


def test_cli_refuses_a_key_file_others_can_read(tmp_path):
    key_file = tmp_path / "robot.key"
    write_key_file(key_file, KEY)
    key_file.chmod(0o644)
    r = subprocess.run([sys.executable, "-m", "pfdoa", "anchors", "beacon", "--serial", "/dev/null",
                        "--key-file", str(key_file)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "chmod 600" in r.stderr and r.stderr.count("\n") == 1
    assert KEY.hex() not in r.stderr
