"""Provisioning an authenticated beacon (protocol/SPEC.md 9) over its UART: the key and the
time, in the line protocol of the nRF52840 beacon image (firmware/ports/nrf52840/beacon_app.h):

    K <32 hex digits>       -> OK K <key check value, 8 hex digits>
    T <counter> <phase_ms>  -> OK T <counter>
    S                       -> S <key check or -> <counter or -> <sent> <failures>

anything refused is answered ``ERR <why>``. :func:`provision` sends the key (unless
``key`` is None: only the time), then the time, then asks for the status, and checks every
answer: the key check value the beacon computed must be the key file's (the key itself is
never echoed, logged or printed), and its counter must be the one sent. The time is read
from ``clock_ms`` (Unix ms) just before the ``T`` line goes out.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pfdoa.errors import PfdoaError
from pfdoa.protocol import auth, defs

LINE_MAX = 96  # bytes of an answer at most (the beacon's are under 64)


class BeaconError(PfdoaError):
    """The beacon did not answer, or answered something else than it should."""


@dataclass(frozen=True)
class BeaconState:
    key_check: str | None  # 8 hex digits, None: no key
    counter: int | None  # None: no time
    sent: int
    failures: int

    def as_dict(self) -> dict[str, Any]:
        return {"key_check": self.key_check, "counter": self.counter, "sent": self.sent, "failures": self.failures}


def _wall_ms() -> int:
    return time.time_ns() // 1_000_000


class BeaconLink:
    """One line out, one line back, on a pyserial port (any object with ``write`` and a
    ``read(1)`` that returns b"" on its timeout)."""

    def __init__(self, port: Any, timeout_s: float = 2.0, monotonic: Callable[[], float] = time.monotonic) -> None:
        self.port = port
        self.timeout_s = timeout_s
        self._monotonic = monotonic

    def ask(self, line: str, what: str) -> str:
        self.port.write(line.encode("ascii") + b"\n")
        got = bytearray()
        deadline = self._monotonic() + self.timeout_s
        while self._monotonic() < deadline:
            b = self.port.read(1)
            if not b:
                continue
            if b == b"\n":
                text = got.decode("ascii", errors="replace").strip("\r")
                if text:
                    return text
                continue
            if len(got) >= LINE_MAX:
                raise BeaconError(f"beacon: {what}: an answer longer than {LINE_MAX} bytes (not a beacon?)")
            got += b
        raise BeaconError(f"beacon: {what}: no answer within {self.timeout_s:g} s (is it the beacon image, "
                          "at 115200 baud?)")


def _expect(answer: str, prefix: str, what: str) -> str:
    if answer.startswith("ERR"):
        raise BeaconError(f"beacon: {what}: refused: {answer[3:].strip() or 'ERR'}")
    if not answer.startswith(prefix):
        raise BeaconError(f"beacon: {what}: unexpected answer {answer[:40]!r}")
    return answer[len(prefix):].strip()


def parse_state(answer: str) -> BeaconState:
    f = _expect(answer, "S ", "status").split()
    if len(f) != 4 or not (f[2].isdigit() and f[3].isdigit()) or not (f[1] == "-" or f[1].isdigit()):
        raise BeaconError(f"beacon: status: unexpected answer {answer[:40]!r}")
    return BeaconState(None if f[0] == "-" else f[0], None if f[1] == "-" else int(f[1]), int(f[2]), int(f[3]))


def provision(link: BeaconLink, key: bytes | None, clock_ms: Callable[[], int] = _wall_ms) -> BeaconState:
    """Key (unless None) and time to the beacon on ``link``; its state afterwards."""
    if key is not None:
        want = auth.key_check(auth.check_key(key))[:4].hex()
        got = _expect(link.ask(f"K {key.hex()}", "key"), "OK K ", "key")
        if got != want:
            raise BeaconError(f"beacon: key: it holds key check {got[:8]!r}, the key file's is {want}")
    now = clock_ms()
    counter, phase = auth.counter_at(now), now & (defs.AUTH_PERIOD_MS - 1)
    got = _expect(link.ask(f"T {counter} {phase}", "time"), "OK T ", "time")
    if got != str(counter):
        raise BeaconError(f"beacon: time: it answered counter {got[:12]!r}, sent {counter}")
    state = parse_state(link.ask("S", "status"))
    if state.key_check is None:
        raise BeaconError("beacon: status: it has no key (give --key-file)")
    if key is not None and state.key_check != auth.key_check(key)[:4].hex():
        raise BeaconError("beacon: status: its key check is not the key file's")
    return state

