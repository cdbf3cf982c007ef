"""UART framing (SPEC 2): version 2 is COBS(ver | type | anchor_id | payload) | trailer | 0x00,
the trailer carrying a CRC-16 over the encoded bytes; version 1 (SPEC 8.2) is
COBS(ver | type | anchor_id | payload | crc16) | 0x00. Every function here decodes both
and encodes either (version 2 unless told).

`StreamDecoder` is the gateway's receive path: bounded memory, every error counted, never
raises on any input, and a bad frame never swallows the next one (resync is at 0x00,
which cannot occur inside a frame).
"""

from __future__ import annotations

import binascii
import dataclasses
import functools
import struct
from typing import Any, Callable, Iterable, NamedTuple, Sequence

from . import defs
from .cobs import cobs_decode_unchecked, cobs_encode
from .defs import DecodeError
from .messages import BY_TYPE, LAYOUTS, Message, positional_maker

DELIMITER = b"\x00"
V1_OVERHEAD = defs.HEADER_LEN + defs.CRC_LEN

ANCHOR_TO_HOST = frozenset(code for code, lay in LAYOUTS.items() if lay.direction == "anchor_to_host")
HOST_TO_ANCHOR = frozenset(code for code, lay in LAYOUTS.items() if lay.direction == "host_to_anchor")
ALL_TYPES = ANCHOR_TO_HOST | HOST_TO_ANCHOR
REPORT_TYPES = frozenset(code for code, cls in BY_TYPE.items() if cls.NAME in ("RSSI_REPORT", "AUTH_REPORT"))

COUNTER_NAMES: tuple[str, ...] = tuple(e.value for e in defs.ERRORS) + ("frames_ok", "bytes_in", "bytes_discarded")

_MARK = defs.TRAILER_MARKER
_BITS = defs.TRAILER_VALUE_MASK
_SHIFT = defs.TRAILER_BITS
_LAST_BITS = defs.TRAILER_LAST_VALUE_MASK
_LAST_MASK = 0xFF ^ _LAST_BITS  # the last trailer byte: everything but its CRC bits is the marker
# defs' numbers as module constants: _decode reads them for every frame.
_V1 = defs.V1_PROTO_VERSION
_V2 = defs.PROTO_VERSION
_HEADER = defs.HEADER_LEN
_TRAILER = defs.TRAILER_LEN
_CRC_INIT = defs.CRC_INIT
_BROADCAST = defs.ANCHOR_BROADCAST
_SHIFT2 = 2 * _SHIFT


class Decoded(NamedTuple):
    anchor_id: int
    message: object  # a Message (UART) or a CanMessage (CAN)


class _TypeSpec(NamedTuple):
    cls: type[Message]
    body_len: int         # version 2: decoded body length (header + payload)
    total_len: int        # version 1: decoded frame length (header + payload + crc)
    extra: bytes          # the CRC_EXTRA byte fed to the CRC
    unpack_from: Callable[[bytes, int], tuple[Any, ...]]  # struct.Struct.unpack_from of the payload
    fields: tuple[str, ...]
    to_host: bool
    make: Callable[[Sequence[Any]], Message]  # cls(*values) of a version-2 payload (every field, in order)


def _specs(types: Iterable[int] | None, version: int) -> dict[int, _TypeSpec]:
    """The layouts a receiver knows in one version (types None: all of them)."""
    wanted = ALL_TYPES if types is None else frozenset(types)
    out = {}
    for code, lay in LAYOUTS.items():
        if code in wanted and version in lay.versions:
            out[code] = _TypeSpec(BY_TYPE[code], defs.HEADER_LEN + lay.payload_len,
                                  V1_OVERHEAD + lay.payload_len, bytes((lay.crc_extra,)),
                                  lay.struct.unpack_from, lay.fields, lay.direction == "anchor_to_host",
                                  _MAKERS[code])
    return out


def _maker(cls: type[Message], fields: tuple[str, ...]) -> Callable[[Sequence[Any]], Message]:
    # The fast constructor where a payload carries every field in order; else cls(*values).
    if fields == tuple(f.name for f in dataclasses.fields(cls)):
        return positional_maker(cls)
    return lambda values: cls(*values)


_MAKERS = {code: _maker(BY_TYPE[code], lay.fields) for code, lay in LAYOUTS.items()}


class _Receiver(NamedTuple):
    v2: dict[int, _TypeSpec]
    v1: dict[int, _TypeSpec] | None  # None: version 1 is not accepted


def _receiver(types: Iterable[int] | None, versions: Iterable[int] | None) -> _Receiver:
    """The receiver for these types and versions, built once per distinct pair: a call of
    decode_frame that names them does not rebuild its layout tables (they cost most of a
    frame's decoding)."""
    return _built_receiver(None if types is None else frozenset(types),
                           None if versions is None else frozenset(versions))


@functools.lru_cache(maxsize=32)
def _built_receiver(types: frozenset[int] | None, versions: frozenset[int] | None) -> _Receiver:
    vs = frozenset(defs.VERSIONS if versions is None else versions)
    if not vs <= frozenset(defs.VERSIONS) or defs.PROTO_VERSION not in vs:
        raise ValueError(f"versions must include {defs.PROTO_VERSION} and be among {defs.VERSIONS}")
    return _Receiver(_specs(types, defs.PROTO_VERSION),
                     _specs(types, defs.V1_PROTO_VERSION) if defs.V1_PROTO_VERSION in vs else None)


_DEFAULT = _receiver(None, None)
_CRC = struct.Struct("<H")


# ------------------------------------------------------------------------- encoding

def trailer(crc: int) -> bytes:
    """The 3 trailer bytes carrying a CRC-16 (SPEC 2.1): 7 + 7 + 2 bits, bit 7 set in each."""
    return bytes((_MARK | (crc & _BITS), _MARK | ((crc >> _SHIFT) & _BITS), _MARK | (crc >> (2 * _SHIFT))))


def trailer_value(t: bytes) -> int | None:
    """The CRC a trailer carries, or None when a marker bit is wrong."""
    if not t[0] & t[1] & _MARK or t[2] & _LAST_MASK != _MARK:
        return None
    return (t[0] & _BITS) | ((t[1] & _BITS) << _SHIFT) | ((t[2] & _LAST_BITS) << (2 * _SHIFT))


def seal(body: bytes, crc_extra: int, version: int = defs.PROTO_VERSION) -> bytes:
    """The COBS block (no delimiter) of any body `ver | type | anchor_id | payload`, with the
    CRC of `version`'s framing over it: for tests and tools that need frames no message
    gives (wrong versions, types, lengths)."""
    if version == defs.V1_PROTO_VERSION:
        return cobs_encode(body + _CRC.pack(binascii.crc_hqx(bytes((crc_extra,)),
                                                             binascii.crc_hqx(body, defs.CRC_INIT))))
    enc = cobs_encode(body)
    return enc + trailer(binascii.crc_hqx(bytes((crc_extra,)), binascii.crc_hqx(enc, defs.CRC_INIT)))


def encode_raw(msg: Message, anchor_id: int, version: int = defs.PROTO_VERSION) -> bytes:
    """What the receiver decodes from the COBS block: the body `ver | type | anchor_id |
    payload` (version 2), or the body and its crc16 (version 1)."""
    if not 0 <= anchor_id <= defs.ANCHOR_BROADCAST:
        raise ValueError(f"anchor id {anchor_id} out of range 0..{defs.ANCHOR_BROADCAST}")
    lay = msg.layout(version)
    body = bytes((version, lay.type, anchor_id)) + msg.pack(version)
    if version == defs.V1_PROTO_VERSION:
        crc = binascii.crc_hqx(bytes((lay.crc_extra,)), binascii.crc_hqx(body, defs.CRC_INIT))
        return body + _CRC.pack(crc)
    return body


def encode_block(msg: Message, anchor_id: int, version: int = defs.PROTO_VERSION) -> bytes:
    """The bytes of the frame between its delimiters."""
    if version == defs.V1_PROTO_VERSION:
        return cobs_encode(encode_raw(msg, anchor_id, version))
    return seal(encode_raw(msg, anchor_id, version), msg.layout(version).crc_extra, version)


def encode_uart(msg: Message, anchor_id: int, version: int = defs.PROTO_VERSION) -> bytes:
    """The bytes on the wire for `msg` from/to `anchor_id`, including the 0x00 delimiter."""
    return encode_block(msg, anchor_id, version) + DELIMITER


# ------------------------------------------------------------------------- inspection

def frame_type(frame: bytes) -> int | None:
    """The message type of a COBS frame (without its delimiter) without decoding or checking
    it: ver and type are the first two body bytes and never zero, so they sit in the first
    COBS group (code byte >= 3). None when the frame cannot be a valid one."""
    if len(frame) >= 3 and frame[0] >= 3:
        return frame[2]
    return None


def is_report_type(msg_type: int | None) -> bool:
    """True for the type code of an RSSI report (any protocol version)."""
    return msg_type in REPORT_TYPES


# ------------------------------------------------------------------------- decoding

def decode_frame(frame: bytes, types: Iterable[int] | None = None,
                 versions: Iterable[int] | None = None) -> Decoded | DecodeError:
    """Check one frame (the bytes between two delimiters) in SPEC 2.3 order.

    Returns Decoded, or the first failed check (a DecodeError, which is also its name).
    `types` restricts the type codes this receiver knows (default: all), `versions` the
    protocol versions it accepts (default: all of defs.VERSIONS; an anchor: only 2).
    """
    rx = _DEFAULT if types is None and versions is None else _receiver(types, versions)
    if len(frame) > defs.MAX_ENCODED:
        return DecodeError.OVERLONG
    if b"\x00" in frame:
        return DecodeError.BAD_COBS
    return _decode(bytes(frame), rx)


def _decode(frame: bytes, rx: _Receiver, crc_hqx=binascii.crc_hqx, new=tuple.__new__) -> Decoded | DecodeError:
    # Checks 2..11 of SPEC 2.3 on a frame of 1..MAX_ENCODED bytes without zeros.
    n = len(frame)
    if n >= 2 and frame[1] == _V1 and frame[0] >= 2:
        return _decode_v1(frame, rx.v1) if rx.v1 is not None else DecodeError.BAD_VERSION
    if n < 1 + _TRAILER:
        return DecodeError.TRUNCATED
    enc = frame[:-_TRAILER]  # the COBS block, which the CRC covers too
    body = cobs_decode_unchecked(enc)
    if body is None:
        return DecodeError.BAD_COBS
    m = len(body)
    if m < _HEADER:
        return DecodeError.TRUNCATED
    if body[0] != _V2:
        return DecodeError.BAD_VERSION
    spec = rx.v2.get(body[1])
    if spec is None:
        return DecodeError.UNKNOWN_TYPE
    if m != spec.body_len:
        return DecodeError.TRUNCATED if m < spec.body_len else DecodeError.BAD_LENGTH
    t0, t1, t2 = frame[n - 3], frame[n - 2], frame[n - 1]
    if (t0 & t1 & _MARK == 0 or t2 & _LAST_MASK != _MARK
            or crc_hqx(spec.extra, crc_hqx(enc, _CRC_INIT))
            != (t0 & _BITS) | ((t1 & _BITS) << _SHIFT) | ((t2 & _LAST_BITS) << _SHIFT2)):
        return DecodeError.BAD_CRC
    anchor = body[2]
    if anchor > _BROADCAST or (anchor == _BROADCAST and spec.to_host):
        return DecodeError.BAD_ANCHOR
    # tuple.__new__: Decoded(anchor, ...) without the named tuple's Python-level __new__.
    return new(Decoded, (anchor, spec.make(spec.unpack_from(body, _HEADER))))


def _decode_v1(frame: bytes, specs: dict[int, _TypeSpec], crc_hqx=binascii.crc_hqx) -> Decoded | DecodeError:
    # SPEC 8.2: the version-1 checks after the routing.
    raw = cobs_decode_unchecked(frame)
    if raw is None:
        return DecodeError.BAD_COBS
    n = len(raw)
    if n < V1_OVERHEAD:
        return DecodeError.TRUNCATED
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
    values = spec.unpack_from(raw, defs.HEADER_LEN)
    return Decoded(anchor, spec.cls(**dict(zip(spec.fields, values))))


class StreamDecoder:
    """Incremental UART receiver: feed() any chunks, get the decoded frames in order.

    Memory is bounded by MAX_ENCODED bytes of pending partial frame. `counters` holds one
    entry per error kind plus frames_ok, bytes_in and bytes_discarded (non-delimiter
    bytes of rejected frames). Chunk boundaries never change the output or the final
    counters. `types` and `versions` as for decode_frame.
    """

    __slots__ = ("_rx", "_pending", "_discarding", "counters")

    def __init__(self, types: Iterable[int] | None = None, versions: Iterable[int] | None = None) -> None:
        self._rx = _DEFAULT if types is None and versions is None else _receiver(types, versions)
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
            rx = self._rx
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
                    r = decode(frame, rx)
                if r.__class__ is Decoded:
                    append(r)
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
