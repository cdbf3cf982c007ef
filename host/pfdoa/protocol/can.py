"""CAN mapping (SPEC 4): classic CAN 2.0A, can_id = (can_type << 7) | anchor_id.

No application CRC on CAN (CRC-15 protects each frame). STATUS travels as STATUS_A +
STATUS_B; decode_can returns the halves and the caller joins them (Status.from_halves).
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from . import defs
from .defs import DecodeError
from .messages import (CanMessage, ConfigAck, ConfigSet, Message, RadioInject, RssiReport,
                       Status, StatusA, StatusB)
from .uart import Decoded


class _CanSpec(NamedTuple):
    can_type: int
    dlc: int
    fields: tuple[str, ...]
    struct: struct.Struct
    to_host: bool


def _spec(name: str) -> _CanSpec:
    can_type, dlc, fields = defs.CAN_TYPES[name]
    st = struct.Struct(getattr(defs, f"CAN_{name}_FMT"))
    return _CanSpec(can_type, dlc, fields, st, name != "CONFIG_SET")


_REPORT = _spec("RSSI_REPORT")
_SET = _spec("CONFIG_SET")
_ACK = _spec("CONFIG_ACK")
_STATUS_A = _spec("STATUS_A")
_STATUS_B = _spec("STATUS_B")


def _make_report(seq, rssi_q8, raw_dbm, n_readings, channel, flags) -> RssiReport:
    return RssiReport(seq, None, rssi_q8, raw_dbm, n_readings, channel, flags)


# can_type -> (spec, constructor from the unpacked fields)
_DECODERS = {
    _REPORT.can_type: (_REPORT, _make_report),
    _SET.can_type: (_SET, ConfigSet),
    _ACK.can_type: (_ACK, ConfigAck),
    _STATUS_A.can_type: (_STATUS_A, StatusA),
    _STATUS_B.can_type: (_STATUS_B, StatusB),
}

GATEWAY_CAN_FILTERS: list[dict] = [
    {"can_id": t << defs.CAN_ANCHOR_BITS, "can_mask": defs.CAN_TYPE_MASK, "extended": False}
    for t in (defs.CAN_RSSI_REPORT, defs.CAN_CONFIG_ACK, defs.CAN_STATUS_A, defs.CAN_STATUS_B)
]
"""python-can `can_filters` for a gateway: reports, acks and both STATUS halves."""


def anchor_can_filters(anchor_id: int) -> list[dict]:
    """python-can `can_filters` an anchor uses: its own CONFIG_SET and the broadcast one."""
    return [
        {"can_id": can_id_for(defs.CAN_CONFIG_SET, anchor_id), "can_mask": defs.CAN_ID_MASK, "extended": False},
        {"can_id": can_id_for(defs.CAN_CONFIG_SET, defs.ANCHOR_BROADCAST), "can_mask": defs.CAN_ID_MASK,
         "extended": False},
    ]


def is_report_id(can_id: int) -> bool:
    """True for the CAN identifier of an RSSI report (any anchor)."""
    return (can_id & defs.CAN_ID_MASK) >> defs.CAN_ANCHOR_BITS == defs.CAN_RSSI_REPORT


def can_id_for(can_type: int, anchor_id: int) -> int:
    if not 0 <= anchor_id <= defs.ANCHOR_BROADCAST:
        raise ValueError(f"anchor id {anchor_id} out of range 0..{defs.ANCHOR_BROADCAST}")
    return (can_type << defs.CAN_ANCHOR_BITS) | anchor_id


def _pack(spec: _CanSpec, msg: object) -> bytes:
    try:
        return spec.struct.pack(*[getattr(msg, f) for f in spec.fields])
    except struct.error as e:
        raise ValueError(f"field out of range: {e}") from None


def encode_can(msg: Message | CanMessage, anchor_id: int) -> list[tuple[int, bytes]]:
    """CAN frames (can_id, data) for `msg`: one frame, or two (STATUS_A, STATUS_B) for Status."""
    if isinstance(msg, RssiReport):
        specs = (_REPORT,)
    elif isinstance(msg, ConfigSet):
        specs = (_SET,)
    elif isinstance(msg, ConfigAck):
        specs = (_ACK,)
    elif isinstance(msg, Status):
        specs = (_STATUS_A, _STATUS_B)
    elif isinstance(msg, StatusA):
        specs = (_STATUS_A,)
    elif isinstance(msg, StatusB):
        specs = (_STATUS_B,)
    elif isinstance(msg, RadioInject):
        raise ValueError("RADIO_INJECT has no CAN mapping")
    else:
        raise TypeError(f"not a protocol message: {msg!r}")
    if anchor_id == defs.ANCHOR_BROADCAST and specs[0].to_host:
        raise ValueError(f"anchor id {defs.ANCHOR_BROADCAST} is host-to-anchor only")
    return [(can_id_for(s.can_type, anchor_id), _pack(s, msg)) for s in specs]


def decode_can(can_id: int, data: bytes) -> Decoded | DecodeError:
    """Check and decode one classic CAN frame: Decoded, or a DecodeError (also its name).

    Checks in order: unknown can_type -> unknown_type; DLC -> bad_length; anchor id 127
    in an anchor-to-host type -> bad_anchor.
    """
    entry = _DECODERS.get(can_id >> defs.CAN_ANCHOR_BITS) if 0 <= can_id <= defs.CAN_ID_MASK else None
    if entry is None:
        return DecodeError.UNKNOWN_TYPE
    spec, make = entry
    if len(data) != spec.dlc:
        return DecodeError.BAD_LENGTH
    anchor = can_id & defs.CAN_ANCHOR_MASK
    if anchor == defs.ANCHOR_BROADCAST and spec.to_host:
        return DecodeError.BAD_ANCHOR
    return Decoded(anchor, make(*spec.struct.unpack(bytes(data))))
