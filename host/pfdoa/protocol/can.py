"""CAN mapping (SPEC 4): classic CAN 2.0A, can_id = (can_type << 7) | anchor_id.

No application CRC on CAN (CRC-15 protects each frame). STATUS travels as STATUS_A +
STATUS_B (+ STATUS_C in version 2); decode_can returns the parts and the caller joins them
(Status.from_halves). A report's DLC tells its version (7: version 2, 8: version 1).
"""

from __future__ import annotations

import struct
from typing import Callable, NamedTuple

from . import defs
from .defs import DecodeError
from .messages import (
    CanMessage,
    ConfigAck,
    ConfigSet,
    Message,
    RssiReport,
    Status,
    StatusA,
    StatusB,
    StatusC,
    positional_maker,
)
from .uart import Decoded


class _CanSpec(NamedTuple):
    can_type: int
    dlc: int
    fields: tuple[str, ...]
    struct: struct.Struct
    to_host: bool
    versions: tuple[int, ...]


def _spec(name: str) -> _CanSpec:
    can_type, dlc, fields, versions = defs.CAN_TYPES[name]
    st = struct.Struct(getattr(defs, f"CAN_{name}_FMT"))
    return _CanSpec(can_type, dlc, fields, st, name != "CONFIG_SET", versions)


_new_decoded = tuple.__new__
_REPORT = _spec("RSSI_REPORT")
_V1_REPORT = _spec("V1_RSSI_REPORT")
_SET = _spec("CONFIG_SET")
_ACK = _spec("CONFIG_ACK")
_STATUS_A = _spec("STATUS_A")
_STATUS_B = _spec("STATUS_B")
_STATUS_C = _spec("STATUS_C")


_new_report = positional_maker(RssiReport)  # RssiReport(*values) without the frozen __init__'s per-field cost


def _make_report(seq, rssi_q8, raw_dbm, flags, beacon) -> RssiReport:
    return _new_report((seq, None, rssi_q8, raw_dbm, None, None, flags, beacon))


def _make_v1_report(seq, rssi_q8, raw_dbm, n_readings, channel, flags) -> RssiReport:
    return RssiReport(seq, None, rssi_q8, raw_dbm, n_readings, channel, flags)


# can_type -> {dlc: (spec, constructor from the unpacked fields)}
_DECODERS: dict[int, dict[int, tuple[_CanSpec, Callable[..., CanMessage]]]] = {}
for _s, _make in ((_REPORT, _make_report), (_V1_REPORT, _make_v1_report), (_SET, ConfigSet),
                  (_ACK, ConfigAck), (_STATUS_A, StatusA), (_STATUS_B, StatusB), (_STATUS_C, StatusC)):
    _DECODERS.setdefault(_s.can_type, {})[_s.dlc] = (_s, _make)

GATEWAY_CAN_FILTERS: list[dict] = [
    {"can_id": t << defs.CAN_ANCHOR_BITS, "can_mask": defs.CAN_TYPE_MASK, "extended": False}
    for t in (defs.CAN_RSSI_REPORT, defs.CAN_CONFIG_ACK, defs.CAN_STATUS_A, defs.CAN_STATUS_B,
              defs.CAN_STATUS_C)
]
"""python-can `can_filters` for a gateway: reports, acks and the STATUS parts."""


def anchor_can_filters(anchor_id: int) -> list[dict]:
    """python-can `can_filters` an anchor uses: its own CONFIG_SET and the broadcast one."""
    return [
        {"can_id": can_id_for(defs.CAN_CONFIG_SET, anchor_id), "can_mask": defs.CAN_ID_MASK, "extended": False},
        {"can_id": can_id_for(defs.CAN_CONFIG_SET, defs.ANCHOR_BROADCAST), "can_mask": defs.CAN_ID_MASK,
         "extended": False},
    ]


def is_report_id(can_id: int) -> bool:
    """True for the CAN identifier of an RSSI report (any anchor, either version)."""
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


def encode_can(msg: Message | CanMessage, anchor_id: int,
               version: int = defs.PROTO_VERSION) -> list[tuple[int, bytes]]:
    """CAN frames (can_id, data) for `msg`: one frame, or the STATUS parts (A, B, and C in
    version 2) for a Status."""
    v1 = version == defs.V1_PROTO_VERSION
    if isinstance(msg, RssiReport):
        if v1 and msg.beacon != 0:
            raise ValueError("a version-1 RSSI_REPORT is about beacon 0 only")
        specs: tuple[_CanSpec, ...] = (_V1_REPORT,) if v1 else (_REPORT,)
    elif isinstance(msg, ConfigSet):
        specs = (_SET,)
    elif isinstance(msg, ConfigAck):
        specs = (_ACK,)
    elif isinstance(msg, Status):
        specs = (_STATUS_A, _STATUS_B) if v1 else (_STATUS_A, _STATUS_B, _STATUS_C)
    elif isinstance(msg, StatusA):
        specs = (_STATUS_A,)
    elif isinstance(msg, StatusB):
        specs = (_STATUS_B,)
    elif isinstance(msg, StatusC):
        specs = (_STATUS_C,)
    elif hasattr(msg, "NAME"):
        raise ValueError(f"{msg.NAME} has no CAN mapping")
    else:
        raise TypeError(f"not a protocol message: {msg!r}")
    if anchor_id == defs.ANCHOR_BROADCAST and specs[0].to_host:
        raise ValueError(f"anchor id {defs.ANCHOR_BROADCAST} is host-to-anchor only")
    return [(can_id_for(s.can_type, anchor_id), _pack(s, msg)) for s in specs]


def decode_can(can_id: int, data: bytes, versions: tuple[int, ...] | None = None) -> Decoded | DecodeError:
    """Check and decode one classic CAN frame: Decoded, or a DecodeError (also its name).

    Checks in order: unknown can_type -> unknown_type; a DLC no accepted version has for
    the type -> bad_length; anchor id 127 in an anchor-to-host type -> bad_anchor.
    `versions` are the protocol versions accepted (default: all; an anchor: only 2).
    """
    by_dlc = _DECODERS.get(can_id >> defs.CAN_ANCHOR_BITS) if 0 <= can_id <= defs.CAN_ID_MASK else None
    if by_dlc is not None and versions is not None:
        by_dlc = {dlc: e for dlc, e in by_dlc.items() if set(e[0].versions) & set(versions)} or None
    if by_dlc is None:
        return DecodeError.UNKNOWN_TYPE
    entry = by_dlc.get(len(data))
    if entry is None:
        return DecodeError.BAD_LENGTH
    spec, make = entry
    anchor = can_id & defs.CAN_ANCHOR_MASK
    if anchor == defs.ANCHOR_BROADCAST and spec.to_host:
        return DecodeError.BAD_ANCHOR
    return _new_decoded(Decoded, (anchor, make(*spec.struct.unpack(bytes(data)))))  # Decoded(...), no Python __new__
