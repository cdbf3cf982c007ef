"""Emulated anchors: one anchor core instance per simulated anchor, behind one interface.

The simulator drives a core the way an anchor's radio driver and main loop do:
``radio(...)`` per radio reading (protocol/SPEC.md 1.5 fields), ``poll(tick)`` from the
main loop, ``uart_rx(bytes)`` / ``can_rx(id, data)`` for what the host sends; it collects
what the core sent with ``take_uart()`` (whole COBS frames with their delimiters) or
``take_can()``.

Backends (``--anchor-backend``):

* ``c`` - the real firmware core, ``firmware/build/host/libpfdoa_anchor.so`` loaded with
  ctypes (see :mod:`pfdoasim.ccore`). The demo and the end-to-end tests use this one.
* ``mpy`` - the MicroPython anchor (firmware/micropython) run by CPython
  (:mod:`pfdoasim.mpyanchor`): the same state machine, independently written.
* ``py-mean`` - a test double that reports each beacon event's mean reading with no
  filtering (framing by :mod:`pfdoa.protocol`). For developing transports without a C
  toolchain; never a stand-in for the firmware's behaviour.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Protocol

from pfdoa.protocol.cobs import cobs_encode
from pfdoa.protocol.crc import crc16


class AnchorCore(Protocol):
    anchor_id: int

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None: ...

    def poll(self, tick_ms: int) -> None: ...

    def uart_rx(self, data: bytes, tick_ms: int) -> None: ...

    def can_rx(self, can_id: int, data: bytes) -> None: ...

    def take_uart(self) -> bytes: ...

    def take_can(self) -> list[tuple[int, bytes]]: ...


# (anchor_id, can, settings, boot tick) -> core
AnchorFactory = Callable[[int, bool, object, int], AnchorCore]

MSG_RSSI_REPORT = 0x01
CAN_TYPE_RSSI_REPORT = 0x2


def uart_frame_type(frame: bytes) -> int | None:
    """Message type of a COBS frame without decoding it all: raw = ver | type | ..., and ver
    and type are non-zero, so they sit in the first COBS group (code byte >= 3)."""
    if len(frame) >= 3 and frame[0] >= 3:
        return frame[2]
    return None


def classify_uart_frames(data: bytes) -> list[tuple[bytes, bool]]:
    """Split whole frames (each ending with 0x00) -> [(frame with delimiter, is_report)]."""
    out = []
    for piece in data.split(b"\x00")[:-1]:
        if piece:
            out.append((piece + b"\x00", uart_frame_type(piece) == MSG_RSSI_REPORT))
    return out


class _Outbox:
    """Byte/frame collection shared by the backends (bounded by the caller's per-step take)."""

    def __init__(self) -> None:
        self._uart = bytearray()
        self._can: list[tuple[int, bytes]] = []

    def take_uart(self) -> bytes:
        # Only whole frames: a partial one stays until its delimiter is written.
        end = self._uart.rfind(b"\x00") + 1
        out = bytes(self._uart[:end])
        del self._uart[:end]
        return out

    def take_can(self) -> list[tuple[int, bytes]]:
        out, self._can = self._can, []
        return out


class MeanAnchor(_Outbox):
    """Test double: one report per beacon event with the event's mean reading (see module doc)."""

    # crc_extra of RSSI_REPORT (messages.json); the double only ever sends this type
    CRC_EXTRA = 145

    def __init__(self, anchor_id: int, can: bool, settings=None, boot_tick: int = 0) -> None:
        super().__init__()
        self.anchor_id = anchor_id
        self.can = can
        self._open: tuple[int, list[int], int, int, int] | None = None  # seq, readings, tick, channel, radio

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        if self._open is not None and self._open[0] != seq:
            self._close(self._open[2])
        if self._open is None:
            self._open = (seq, [], tick_ms, channel, radio)
        self._open[1].append(max(-128, min(20, rssi_dbm)))
        if radio == 1 or len(self._open[1]) >= 3:
            self._close(tick_ms)

    def poll(self, tick_ms: int) -> None:
        if self._open is not None and ((tick_ms - self._open[2]) & 0xFFFFFFFF) >= 20:
            self._close(tick_ms)

    def uart_rx(self, data: bytes, tick_ms: int) -> None:
        pass

    def can_rx(self, can_id: int, data: bytes) -> None:
        pass

    def _close(self, tick_ms: int) -> None:
        seq, rs, _, channel, radio = self._open
        self._open = None
        n = len(rs)
        mean_q8 = (512 * sum(rs) + n) // (2 * n)
        flags = 16 if radio == 1 else 0
        if self.can:
            data = struct.pack("<HhbBBB", seq, mean_q8, rs[-1], n, channel, flags)
            self._can.append(((CAN_TYPE_RSSI_REPORT << 7) | self.anchor_id, data))
            return
        payload = struct.pack("<HIhbBBB", seq, tick_ms & 0xFFFFFFFF, mean_q8, rs[-1], n, channel, flags)
        raw = bytes([1, MSG_RSSI_REPORT, self.anchor_id]) + payload
        crc = crc16(raw + bytes([self.CRC_EXTRA]))
        self._uart += cobs_encode(raw + struct.pack("<H", crc)) + b"\x00"


BACKENDS = ("c", "mpy", "py-mean")


def anchor_factory(backend: str = "c", library: str | None = None) -> AnchorFactory:
    """A factory for the named backend (raises :class:`pfdoa.errors.InputError` if unavailable)."""
    if backend == "py-mean":
        return MeanAnchor
    if backend == "mpy":
        from pfdoasim.mpyanchor import MpyFactory

        return MpyFactory()
    if backend == "c":
        from pfdoasim.ccore import CoreLibrary

        return CoreLibrary.load(library).factory()
    from pfdoa.errors import InputError

    raise InputError(f"unknown anchor backend {backend!r} (known: {', '.join(BACKENDS)})")
