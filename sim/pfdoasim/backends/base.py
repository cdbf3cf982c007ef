"""What every emulated anchor implements, and what every backend provides.

The simulator drives a core the way an anchor's radio driver and main loop do:
``radio(...)`` per reading of our beacon matched by the board (protocol/SPEC.md 1.7
fields; filter entry 0), ``poll(tick)`` from the main loop, ``uart_rx(bytes)`` /
``can_rx(id, data)`` for what the host sends; it collects what the core sent with
``take_uart()`` (whole COBS frames with their delimiters) or ``take_can()``. The firmware
backends (``c``, ``mpy``) also take raw receptions that the core matches against its
beacon filter table - ``ble_adv(adv_a, adv_data, ...)``, ``ble_pdu(pdu, ...)``,
``ieee802154(mpdu, ...)`` (see :class:`RawReceiver`) - for scenarios with several or
standard beacons (build what they send with :mod:`pfdoa.protocol.beacons`).

A backend (:class:`Backend`, one module each under :mod:`pfdoasim.backends`, named in its
registry) makes a run's anchors: an :data:`AnchorFactory` called as
``factory(anchor_id, can, settings, boot_tick)`` for each boot of each anchor.

Anchors that hear each other (protocol/SPEC.md 3.5): a factory whose ``peer_radio``
attribute the simulator sets (``RADIO_BLE`` or ``RADIO_IEEE802154``) gives every anchor a
radio to send its own advertisement on, from :func:`sil_peer_address`; ``take_radio()``
returns what each sent since the last call, which the simulator delivers to the others.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar, Protocol, runtime_checkable

from pfdoa.protocol import defs
from pfdoa.protocol.uart import frame_type, is_report_type

# The reasons an anchor rejects an authenticated beacon's advertisement (SPEC 9.4), with
# their codes: what ``auth_rejected()`` of the firmware backends counts.
AUTH_REASONS = (("bad_tag", defs.AUTH_BAD_TAG), ("stale", defs.AUTH_STALE), ("replayed", defs.AUTH_REPLAYED))

SIL_ADDRESS_TOP = 0xC5  # the top byte: a random static BLE address (its two top bits set)


def sil_peer_address(radio: int, anchor_id: int) -> bytes:
    """A simulated anchor's radio address, on-air order (least significant byte first):
    ``<id> 00 .. 00 C5``, 6 bytes for BLE, 8 for IEEE 802.15.4 (the QEMU SIL image's and the
    nRF52840 port's are the same)."""
    n = defs.BLE_ADV_A_LEN if radio == defs.RADIO_BLE else defs.IEEE802154_EXT_ADDR_LEN
    return bytes((anchor_id,)) + bytes(n - 2) + bytes((SIL_ADDRESS_TOP,))


class AnchorCore(ABC):
    """One emulated anchor (see the module doc)."""

    anchor_id: int

    @abstractmethod
    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None: ...

    @abstractmethod
    def poll(self, tick_ms: int) -> None: ...

    @abstractmethod
    def uart_rx(self, data: bytes, tick_ms: int) -> None: ...

    @abstractmethod
    def can_rx(self, can_id: int, data: bytes) -> None: ...

    @abstractmethod
    def take_uart(self) -> bytes: ...

    @abstractmethod
    def take_can(self) -> list[tuple[int, bytes]]: ...

    def take_radio(self) -> list[tuple[int, bytes]]:
        """(radio, frame) of every advertisement of its own the anchor sent since the last call."""
        return []


class OutboxCore(AnchorCore):
    """An anchor whose output is collected in memory (bounded by the caller's per-step take)."""

    def __init__(self) -> None:
        self._uart = bytearray()
        self._can: list[tuple[int, bytes]] = []
        self._radio: list[tuple[int, bytes]] = []

    def take_uart(self) -> bytes:
        # Only whole frames: a partial one stays until its delimiter is written.
        end = self._uart.rfind(b"\x00") + 1
        out = bytes(self._uart[:end])
        del self._uart[:end]
        return out

    def take_can(self) -> list[tuple[int, bytes]]:
        out, self._can = self._can, []
        return out

    def take_radio(self) -> list[tuple[int, bytes]]:
        out, self._radio = self._radio, []
        return out


@runtime_checkable
class RawReceiver(Protocol):
    """What the firmware backends add: receptions the core matches itself (SPEC 3.1-3.3).
    Each returns 1 (matched and used), 0 (no filter entry matched) or a negative error
    (a matched reading that was dropped)."""

    def ble_adv(self, adv_a: bytes, adv_data: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int: ...

    def ble_pdu(self, pdu: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int: ...

    def ieee802154(self, mpdu: bytes, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> int: ...


# (anchor_id, can, settings (AnchorConfig's fields, or None: the firmware's defaults), boot tick) -> core
AnchorFactory = Callable[[int, bool, Any, int], AnchorCore]


class Backend(ABC):
    """One kind of emulated anchor. ``in_process`` backends hand the simulation an
    :data:`AnchorFactory`; the others (QEMU: each anchor is its own process on its own
    serial port) are run by their own harness, which the command dispatches to."""

    name: ClassVar[str]
    in_process: ClassVar[bool] = True

    @abstractmethod
    def factory(self, core_lib: str | None = None) -> AnchorFactory:
        """A fresh set of anchors for one run (``core_lib``: the C library, for the c backend)."""


def classify_uart_frames(data: bytes) -> list[tuple[bytes, bool]]:
    """Split whole frames (each ending with 0x00) -> [(frame with delimiter, is_report)]."""
    out = []
    for piece in data.split(b"\x00")[:-1]:
        if piece:
            out.append((piece + b"\x00", is_report_type(frame_type(piece))))
    return out
