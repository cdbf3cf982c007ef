"""The anchor's stored configuration (SPEC 1.3 without `token`): the one Python type for it.

The gateway, the simulator's anchors, the tools and the reference model all use
:class:`AnchorConfig`; its defaults and valid ranges come from messages.json (through the
generated `defs`), its bytes are the stored/wire form the firmware keeps in flash.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields

from . import defs
from .crc import crc16

_STRUCT = struct.Struct(defs.CONFIG_FMT)


@dataclass(frozen=True)
class AnchorConfig:
    """The active configuration (CONFIG_SET without its token)."""

    offset_q8: int = defs.DEFAULT_OFFSET_Q8
    alpha_q8: int = defs.DEFAULT_ALPHA_Q8
    spike_db: int = defs.DEFAULT_SPIKE_DB
    report_mode: int = defs.DEFAULT_REPORT_MODE
    decimation: int = defs.DEFAULT_DECIMATION

    def pack(self) -> bytes:
        """The CONFIG_LEN bytes stored in flash and hashed into config_hash."""
        try:
            return _STRUCT.pack(self.offset_q8, self.alpha_q8, self.spike_db, self.report_mode,
                                self.decimation)
        except struct.error as e:
            raise ValueError(f"configuration field out of range: {e}") from None

    @classmethod
    def unpack(cls, data: bytes) -> "AnchorConfig":
        """From the stored form (not validated: see :meth:`is_valid`)."""
        if len(data) != defs.CONFIG_LEN:
            raise ValueError(f"a stored configuration is {defs.CONFIG_LEN} bytes, not {len(data)}")
        return cls(*_STRUCT.unpack(data))

    @classmethod
    def of(cls, settings: object) -> "AnchorConfig":
        """An AnchorConfig from any object with the same field names (e.g. a scenario's)."""
        if isinstance(settings, cls):
            return settings
        return cls(**{f.name: getattr(settings, f.name) for f in fields(cls)})

    @property
    def hash(self) -> int:
        """config_hash of STATUS and CONFIG_ACK."""
        return crc16(self.pack())

    def is_valid(self) -> bool:
        return (defs.VALID_ALPHA_Q8_MIN <= self.alpha_q8 <= defs.VALID_ALPHA_Q8_MAX
                and defs.VALID_REPORT_MODE_MIN <= self.report_mode <= defs.VALID_REPORT_MODE_MAX
                and defs.VALID_DECIMATION_MIN <= self.decimation <= defs.VALID_DECIMATION_MAX)


__all__ = ["AnchorConfig"]
