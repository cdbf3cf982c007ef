"""``mpy``: the MicroPython anchor (firmware/micropython/pfdoa_anchor.py) run by CPython.

It is the same SPEC section 3 state machine as the C core, written in the integer subset
that MicroPython and CPython share; only ``micropython.const`` needs a stand-in here. A
second, independent implementation behind the simulator's anchor interface: a scenario
run with ``--anchor-backend mpy`` must give the gateway the same frames as with ``c``.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

from pfdoa.protocol.config import AnchorConfig
from pfdoasim import firmware
from pfdoasim.backends.base import AUTH_REASONS, Backend, OutboxCore, sil_peer_address


def _module() -> types.ModuleType:
    if "micropython" not in sys.modules:
        shim = types.ModuleType("micropython")
        shim.const = lambda x: x  # type: ignore[attr-defined]  # compile-time constant in MicroPython
        sys.modules["micropython"] = shim
    mpy_dir = str(firmware.locate().part("micropython"))
    if mpy_dir not in sys.path:
        sys.path.append(mpy_dir)
    return importlib.import_module("pfdoa_anchor")


class MpyFactory:
    """An :data:`AnchorFactory` for one simulation, with each anchor's flash (as the C one)."""

    def __init__(self) -> None:
        self.flash: dict[int, bytes] = {}
        self.filter_flash: dict[int, bytes] = {}  # the stored beacon filter tables
        self.peer_radio: int | None = None  # the radio anchors send their advertisement on (None: none)

    def __call__(self, anchor_id: int, can: bool, settings: Any, boot_tick: int) -> MpyAnchor:
        if settings is not None and anchor_id not in self.flash:
            self.flash[anchor_id] = AnchorConfig.of(settings).pack()
        return MpyAnchor(anchor_id, can, self.flash, boot_tick, self.filter_flash, self.peer_radio)


class MpyAnchor(OutboxCore):
    def __init__(self, anchor_id: int, can: bool, flash: dict[int, bytes], boot_tick: int = 0,
                 filter_flash: dict[int, bytes] | None = None, peer_radio: int | None = None) -> None:
        super().__init__()
        m = _module()
        self.anchor_id = anchor_id
        filter_flash = filter_flash if filter_flash is not None else {}

        def store(cfg: bytes) -> bool:
            flash[anchor_id] = bytes(cfg)
            return True

        def store_filters(table: bytes) -> bool:
            filter_flash[anchor_id] = bytes(table)
            return True

        def peer_send(mv) -> bool:
            assert peer_radio is not None
            self._radio.append((peer_radio, bytes(mv)))
            return True

        peer = {} if peer_radio is None else {"peer_send": peer_send, "peer_radio": peer_radio,
                                              "peer_address": sil_peer_address(peer_radio, anchor_id)}

        self.core = m.Anchor(
            anchor_id, boot_tick & 0xFFFFFFFF,
            uart_write=None if can else (lambda mv: self._uart.extend(bytes(mv))),
            can_send=(lambda cid, mv: self._can.append((int(cid), bytes(mv)))) if can else None,
            config=flash.get(anchor_id), store=store,
            filters=filter_flash.get(anchor_id), store_filters=store_filters, **peer,
        )

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        self.core.reading(seq & 0xFFFF, rssi_dbm, channel, lqi, radio, tick_ms & 0xFFFFFFFF)

    # Raw receptions, matched by the core against its beacon filter table (SPEC 3.1-3.3).
    def ble_adv(self, adv_a: bytes, adv_data: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        return int(self.core.ble_adv(bytes(adv_a), bytes(adv_data), rssi_dbm, channel, tick_ms & 0xFFFFFFFF))

    def ble_pdu(self, pdu: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        return int(self.core.ble_pdu(bytes(pdu), len(pdu), rssi_dbm, channel, tick_ms & 0xFFFFFFFF))

    def ieee802154(self, mpdu: bytes, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> int:
        return int(self.core.ieee802154(bytes(mpdu), len(mpdu), rssi_dbm, channel, lqi, tick_ms & 0xFFFFFFFF))

    def poll(self, tick_ms: int) -> None:
        self.core.poll(tick_ms & 0xFFFFFFFF)

    def uart_rx(self, data: bytes, tick_ms: int) -> None:
        self.core.uart_rx(data)
        self.poll(tick_ms)

    def can_rx(self, can_id: int, data: bytes) -> None:
        self.core.can_rx(can_id, data)

    def auth_rejected(self) -> dict[str, int]:
        """Its authenticated beacons' advertisements it rejected, by reason (SPEC 9.4)."""
        return {name: int(self.core.auth_rejected[code - AUTH_REASONS[0][1]]) for name, code in AUTH_REASONS}


class MpyBackend(Backend):
    name = "mpy"

    def factory(self, core_lib: str | None = None) -> MpyFactory:
        return MpyFactory()
