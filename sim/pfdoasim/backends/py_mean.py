"""``py-mean``: a test double that reports each beacon event's mean reading, unfiltered.

Framing by :mod:`pfdoa.protocol` (the same encoders as the gateway decodes). For
developing transports without a C toolchain; never a stand-in for the firmware's behaviour.
"""

from __future__ import annotations

from typing import Any

from pfdoa.protocol import defs
from pfdoa.protocol.anchor_model import fold_q8
from pfdoa.protocol.can import encode_can
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart
from pfdoasim.backends.base import AnchorFactory, Backend, OutboxCore


class MeanAnchor(OutboxCore):
    """One report per beacon event with the event's mean reading (see the module doc)."""

    def __init__(self, anchor_id: int, can: bool, settings: Any = None, boot_tick: int = 0) -> None:
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
        if self._open is None:
            return
        seq, rs, _, channel, radio = self._open
        self._open = None
        flags = defs.FLAG_ZIGBEE if radio == defs.RADIO_IEEE802154 else 0
        msg = RssiReport(seq, tick_ms & 0xFFFFFFFF, fold_q8(sum(rs), len(rs)), rs[-1], len(rs), channel, flags)
        if self.can:
            self._can += encode_can(msg, self.anchor_id)
        else:
            self._uart += encode_uart(msg, self.anchor_id)


class MeanBackend(Backend):
    name = "py-mean"

    def factory(self, core_lib: str | None = None) -> AnchorFactory:
        return MeanAnchor
