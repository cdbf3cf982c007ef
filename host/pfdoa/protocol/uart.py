"""UART framing (SPEC 2): COBS(ver | type | anchor_id | payload | crc16) | 0x00.

`StreamDecoder` is the gateway's receive path: bounded memory, every error counted, never
raises on any input, and a bad frame never swallows the next one (resync is at 0x00,
which cannot occur inside a frame).
"""

from __future__ import annotations

import binascii
import struct
from typing import Iterable, NamedTuple

from . import defs
from .cobs import cobs_decode_unchecked, cobs_encode
from .defs import DecodeError
from .messages import BY_TYPE, Message

DELIMITER = b"\x00"
OVERHEAD = defs.HEADER_LEN + defs.CRC_LEN

ANCHOR_TO_HOST = frozenset(
    spec[0] for spec in defs.MESSAGES.values() if spec[1] == "anchor_to_host")
HOST_TO_ANCHOR = frozenset(
    spec[0] for spec in defs.MESSAGES.values() if spec[1] == "host_to_anchor")
ALL_TYPES = ANCHOR_TO_HOST | HOST_TO_ANCHOR

COUNTER_NAMES: tuple[str, ...] = tuple(e.value for e in defs.ERRORS) + ("frames_ok", "bytes_in", "bytes_discarded")


class Decoded(NamedTuple):
    anchor_id: int
    message: object  # a Message (UART) or a CanMessage (CAN)


class _TypeSpec(NamedTuple):
    cls: type
    total_len: int        # decoded frame length: header + payload + crc
    extra: bytes          # the CRC_EXTRA byte fed to the CRC
    unpack_from: object   # struct.Struct.unpack_from of the payload
    to_host: bool


def _specs(types: Iterable[int]) -> dict[int, _TypeSpec]:
    out = {}
    for name, (code, direction, plen, extra, _fields, _d) in defs.MESSAGES.items():
        if code in types:
            cls = BY_TYPE[code]
            out[code] = _TypeSpec(cls, OVERHEAD + plen, bytes([extra]),
                                  cls.STRUCT.unpack_from, direction == "anchor_to_host")
    return out


_ALL_SPECS = _specs(ALL_TYPES)
_CRC = struct.Struct("<H")


REPORT_TYPES = frozenset((defs.MSG_RSSI_REPORT,))


def frame_type(frame: bytes) -> int | None:
    """The message type of a COBS frame (without its delimiter) without decoding or checking
    it: ver and type are the first two raw bytes and never zero, so they sit in the first
    COBS group (code byte >= 3). None when the frame cannot be a valid one."""
    if len(frame) >= 3 and frame[0] >= 3:
        return frame[2]
    return None


def is_report_type(msg_type: int | None) -> bool:
    """True for the type code of an RSSI report (any protocol version)."""
    return msg_type in REPORT_TYPES


def encode_raw(msg: Message, anchor_id: int) -> bytes:
    """The decoded frame: ver | type | anchor_id | payload | crc16 (no COBS)."""
    if not 0 <= anchor_id <= defs.ANCHOR_BROADCAST:
        raise ValueError(f"anchor id {anchor_id} out of range 0..{defs.ANCHOR_BROADCAST}")
    body = bytes((defs.PROTO_VERSION, msg.TYPE, anchor_id)) + msg.pack()
    crc = binascii.crc_hqx(bytes((defs.MESSAGES[msg.NAME][3],)), binascii.crc_hqx(body, defs.CRC_INIT))
    return body + _CRC.pack(crc)


def encode_uart(msg: Message, anchor_id: int) -> bytes:
    """The bytes on the wire for `msg` from/to `anchor_id`, including the 0x00 delimiter."""
    return cobs_encode(encode_raw(msg, anchor_id)) + DELIMITER


def decode_frame(frame: bytes, types: Iterable[int] | None = None) -> Decoded | DecodeError:
    """Check one frame (the bytes between two delimiters) in SPEC 2.3 order.

    Returns Decoded, or the first failed check (a DecodeError, which is also its name).
    `types` restricts the types this receiver knows (default: all of version 1).
    """
    specs = _ALL_SPECS if types is None else _specs(types)
    if len(frame) > defs.MAX_ENCODED:
        return DecodeError.OVERLONG
    if b"\x00" in frame:
        return DecodeError.BAD_COBS
    return _decode(bytes(frame), specs)


def _decode(frame: bytes, specs: dict[int, _TypeSpec], crc_hqx=binascii.crc_hqx) -> Decoded | DecodeError:
    # Checks 2..9 of SPEC 2.3 on a frame of <= MAX_ENCODED bytes without zeros.
    raw = cobs_decode_unchecked(frame)
    if raw is None:
        return DecodeError.BAD_COBS
    n = len(raw)
    if n < OVERHEAD:
        return DecodeError.TRUNCATED
    if raw[0] != defs.PROTO_VERSION:
        return DecodeError.BAD_VERSION
    spec = specs.get(raw[1])
    if spec is None:
        return DecodeError.UNKNOWN_TYPE
    if n != spec.total_len:
        return DecodeError.TRUNCATED if n < spec.total_len else DecodeError.BAD_LENGTH
    if crc_hqx(spec.extra, crc_hqx(raw[:-2], defs.CRC_INIT)) != raw[-2] | (raw[-1] << 8):
        return DecodeError.BAD_CRC
    anchor = raw[2]
    if anchor > defs.ANCHOR_BROADCAST or (anchor == defs.ANCHOR_BROADCAST and spec.to_host):
        return DecodeError.BAD_ANCHOR
    return Decoded(anchor, spec.cls(*spec.unpack_from(raw, defs.HEADER_LEN)))


class StreamDecoder:
    """Incremental UART receiver: feed() any chunks, get the decoded frames in order.

    Memory is bounded by MAX_ENCODED bytes of pending partial frame. `counters` holds one
    entry per error kind plus frames_ok, bytes_in and bytes_discarded (non-delimiter
    bytes of rejected frames). Chunk boundaries never change the output or the final
    counters.
    """

    __slots__ = ("_specs", "_pending", "_discarding", "counters")

    def __init__(self, types: Iterable[int] | None = None) -> None:
        self._specs = _ALL_SPECS if types is None else _specs(types)
        self._pending = b""
        self._discarding = False  # inside an over-long frame: drop up to the next 0x00
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)

    @property
    def pending(self) -> int:
        """Bytes of an incomplete frame held for the next feed()."""
        return len(self._pending)

    def feed(self, data: bytes) -> list[Decoded]:
        counters = self.counters
        counters["bytes_in"] += len(data)
        if self._pending:
            data = self._pending + data
        parts = bytes(data).split(b"\x00")
        tail = parts.pop()
        out: list[Decoded] = []
        if parts:
            if self._discarding:
                counters["bytes_discarded"] += len(parts[0])
                parts[0] = b""
                self._discarding = False
            specs = self._specs
            decode = _decode
            max_len = defs.MAX_ENCODED
            ok = 0
            append = out.append
            for frame in parts:
                if not frame:
                    continue  # empty frames (back-to-back delimiters) are skipped silently
                if len(frame) > max_len:
                    r: Decoded | DecodeError = DecodeError.OVERLONG
                else:
                    r = decode(frame, specs)
                if r.__class__ is Decoded:
                    append(r)  # type: ignore[arg-type]
                    ok += 1
                else:
                    counters[r] += 1  # type: ignore[index]
                    counters["bytes_discarded"] += len(frame)
            counters["frames_ok"] += ok
        if self._discarding:
            counters["bytes_discarded"] += len(tail)
            tail = b""
        elif len(tail) > defs.MAX_ENCODED:
            counters[DecodeError.OVERLONG] += 1
            counters["bytes_discarded"] += len(tail)
            self._discarding = True
            tail = b""
        self._pending = tail
        return out
