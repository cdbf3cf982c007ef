"""Message dataclasses of protocol v1 (SPEC section 1), one per message type.

Field order is wire order; `pack()` gives the payload, `unpack(payload)` parses it.
Layouts come from the generated `defs` (messages.json); a test checks the field names.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Union

from . import defs


def _msg_struct(name: str) -> struct.Struct:
    return struct.Struct(getattr(defs, f"MSG_{name}_FMT"))


class _Message:
    TYPE: ClassVar[int]
    NAME: ClassVar[str]
    STRUCT: ClassVar[struct.Struct]

    def pack(self) -> bytes:
        try:
            return self.STRUCT.pack(*[getattr(self, f) for f in self.__slots__])
        except struct.error as e:
            raise ValueError(f"{self.NAME}: field out of range: {e}") from None

    @classmethod
    def unpack(cls, payload: bytes):
        return cls(*cls.STRUCT.unpack(payload))


@dataclass(frozen=True, slots=True)
class RssiReport(_Message):
    """RSSI_REPORT (0x01). `tick_ms` is None when received over CAN (no tick there)."""

    TYPE: ClassVar[int] = defs.MSG_RSSI_REPORT
    NAME: ClassVar[str] = "RSSI_REPORT"
    STRUCT: ClassVar[struct.Struct] = _msg_struct("RSSI_REPORT")

    seq: int
    tick_ms: int | None
    rssi_q8: int
    raw_dbm: int
    n_readings: int
    channel: int
    flags: int

    @property
    def rssi_dbm(self) -> float:
        return self.rssi_q8 / 256.0


@dataclass(frozen=True, slots=True)
class Status(_Message):
    TYPE: ClassVar[int] = defs.MSG_STATUS
    NAME: ClassVar[str] = "STATUS"
    STRUCT: ClassVar[struct.Struct] = _msg_struct("STATUS")

    fw_major: int
    fw_minor: int
    uptime_s: int
    config_hash: int
    dropped_events: int
    rx_errors: int
    spikes: int
    defs_hash: int

    @classmethod
    def from_halves(cls, a: "StatusA", b: "StatusB") -> "Status":
        """Join the two CAN halves of a STATUS (the caller pairs them by anchor)."""
        return cls(a.fw_major, a.fw_minor, a.uptime_s, a.config_hash,
                   b.dropped_events, b.rx_errors, b.spikes, b.defs_hash)


@dataclass(frozen=True, slots=True)
class ConfigSet(_Message):
    TYPE: ClassVar[int] = defs.MSG_CONFIG_SET
    NAME: ClassVar[str] = "CONFIG_SET"
    STRUCT: ClassVar[struct.Struct] = _msg_struct("CONFIG_SET")

    token: int
    offset_q8: int = defs.DEFAULT_OFFSET_Q8
    alpha_q8: int = defs.DEFAULT_ALPHA_Q8
    spike_db: int = defs.DEFAULT_SPIKE_DB
    report_mode: int = defs.DEFAULT_REPORT_MODE
    decimation: int = defs.DEFAULT_DECIMATION


@dataclass(frozen=True, slots=True)
class ConfigAck(_Message):
    TYPE: ClassVar[int] = defs.MSG_CONFIG_ACK
    NAME: ClassVar[str] = "CONFIG_ACK"
    STRUCT: ClassVar[struct.Struct] = _msg_struct("CONFIG_ACK")

    token: int
    result: int
    config_hash: int


@dataclass(frozen=True, slots=True)
class RadioInject(_Message):
    TYPE: ClassVar[int] = defs.MSG_RADIO_INJECT
    NAME: ClassVar[str] = "RADIO_INJECT"
    STRUCT: ClassVar[struct.Struct] = _msg_struct("RADIO_INJECT")

    seq: int
    tick_ms: int
    rssi_dbm: int
    channel: int
    lqi: int
    radio: int


@dataclass(frozen=True, slots=True)
class StatusA:
    """First CAN half of STATUS (can_type 0x5)."""

    fw_major: int
    fw_minor: int
    uptime_s: int
    config_hash: int


@dataclass(frozen=True, slots=True)
class StatusB:
    """Second CAN half of STATUS (can_type 0x6)."""

    dropped_events: int
    rx_errors: int
    spikes: int
    defs_hash: int


Message = Union[RssiReport, Status, ConfigSet, ConfigAck, RadioInject]
CanMessage = Union[RssiReport, ConfigSet, ConfigAck, StatusA, StatusB]

MESSAGE_CLASSES: tuple[type, ...] = (RssiReport, Status, ConfigSet, ConfigAck, RadioInject)
BY_TYPE: dict[int, type] = {cls.TYPE: cls for cls in MESSAGE_CLASSES}
BY_NAME: dict[str, type] = {cls.NAME: cls for cls in MESSAGE_CLASSES}
