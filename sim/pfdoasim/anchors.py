"""Emulated anchors: one anchor core instance per simulated anchor, behind one interface.

The simulator drives a core the way an anchor's radio driver and main loop do:
``radio(...)`` per reading of our beacon matched by the board (protocol/SPEC.md 1.7
fields; filter entry 0), ``poll(tick)`` from the main loop, ``uart_rx(bytes)`` /
``can_rx(id, data)`` for what the host sends; it collects what the core sent with
``take_uart()`` (whole COBS frames with their delimiters) or ``take_can()``. The firmware
backends (``c``, ``mpy``) also take raw receptions that the core matches against its
beacon filter table - ``ble_adv(adv_a, adv_data, ...)``, ``ble_pdu(pdu, ...)``,
``ieee802154(mpdu, ...)`` (see :class:`RawReceiver`) - for scenarios with several or
standard beacons (build what they send with :mod:`pfdoa.protocol.beacons`).

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

from collections.abc import Callable
from typing import Protocol

from pfdoa.protocol import defs
from pfdoa.protocol.anchor_model import fold_q8
from pfdoa.protocol.can import encode_can
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart, frame_type, is_report_type


class AnchorCore(Protocol):
    anchor_id: int

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None: ...

    def poll(self, tick_ms: int) -> None: ...

    def uart_rx(self, data: bytes, tick_ms: int) -> None: ...

    def can_rx(self, can_id: int, data: bytes) -> None: ...

    def take_uart(self) -> bytes: ...

    def take_can(self) -> list[tuple[int, bytes]]: ...


class RawReceiver(Protocol):
    """What the firmware backends add: receptions the core matches itself (SPEC 3.1-3.3).
    Each returns 1 (matched and used), 0 (no filter entry matched) or a negative error
    (a matched reading that was dropped)."""

    def ble_adv(self, adv_a: bytes, adv_data: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int: ...

    def ble_pdu(self, pdu: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int: ...

    def ieee802154(self, mpdu: bytes, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> int: ...


# (anchor_id, can, settings, boot tick) -> core
AnchorFactory = Callable[[int, bool, object, int], AnchorCore]

def classify_uart_frames(data: bytes) -> list[tuple[bytes, bool]]:
    """Split whole frames (each ending with 0x00) -> [(frame with delimiter, is_report)]."""
    out = []
    for piece in data.split(b"\x00")[:-1]:
        if piece:
            out.append((piece + b"\x00", is_report_type(frame_type(piece))))
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
        self._open[1].append(max(defs.RSSI_MIN_DBM, min(defs.RSSI_MAX_DBM, rssi_dbm)))
        if radio == defs.RADIO_IEEE802154 or len(self._open[1]) >= defs.BLE_EVENT_MAX_READINGS:
            self._close(tick_ms)

    def poll(self, tick_ms: int) -> None:
        if self._open is not None and ((tick_ms - self._open[2]) & 0xFFFFFFFF) >= defs.EVENT_TIMEOUT_MS:
            self._close(tick_ms)

    def uart_rx(self, data: bytes, tick_ms: int) -> None:
        pass

    def can_rx(self, can_id: int, data: bytes) -> None:
        pass

    def _close(self, tick_ms: int) -> None:
        seq, rs, _, channel, radio = self._open
        self._open = None
        flags = defs.FLAG_ZIGBEE if radio == defs.RADIO_IEEE802154 else 0
        msg = RssiReport(seq, tick_ms & 0xFFFFFFFF, fold_q8(sum(rs), len(rs)), rs[-1], len(rs), channel, flags)
        if self.can:
            self._can += encode_can(msg, self.anchor_id)
        else:
            self._uart += encode_uart(msg, self.anchor_id)


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
