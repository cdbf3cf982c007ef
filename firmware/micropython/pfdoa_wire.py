# pfdoa wire format, version 2, for MicroPython (protocol/SPEC.md sections 2 and 4):
# CRC-16, COBS, UART frame encoding (COBS body + a CRC trailer over the encoded bytes) and
# the bounded host-to-anchor stream decoder (version-1 frames are bad_version here).
# Integer only; buffers are preallocated so the per-frame path does not allocate.
import array

import pfdoa_defs as D

_HEADER_LEN = D.HEADER_LEN  # ver, type, anchor_id
_TRAILER = D.TRAILER_LEN
_MARK = D.TRAILER_MARKER
_BITS = D.TRAILER_VALUE_MASK
_SHIFT = D.TRAILER_BITS
_LAST = D.TRAILER_LAST_VALUE_MASK

# Receiver errors are pfdoa_defs.ERR_* (negative, SPEC 2.3 order), D.ERR_COUNT of them;
# payload layouts are pfdoa_defs.*_FMT.


def can_id(can_type, anchor_id):
    return (can_type << D.CAN_ANCHOR_BITS) | anchor_id


def _make_table():
    t = array.array("H", bytearray(512))
    for b in range(256):
        c = b << 8
        for _ in range(8):
            c = ((c << 1) ^ D.CRC_POLY) if c & 0x8000 else (c << 1)
        t[b] = c & 0xFFFF
    return t


_TABLE = _make_table()


def crc16(buf, start=0, end=-1, crc=D.CRC_INIT):
    """CRC-16/CCITT-FALSE of buf[start:end] (end -1 = len(buf)), continuing from crc."""
    t = _TABLE
    if end < 0:
        end = len(buf)
    for i in range(start, end):
        crc = ((crc << 8) & 0xFFFF) ^ t[(crc >> 8) ^ buf[i]]
    return crc


def crc16_byte(crc, b):
    return ((crc << 8) & 0xFFFF) ^ _TABLE[(crc >> 8) ^ b]


def crc_extra(definition):
    c = crc16(definition.encode())
    return (c & 0xFF) ^ (c >> 8)


def cobs_encode(src, n, dst):
    """Encodes src[0:n] into dst (no delimiter); returns the encoded length.

    dst needs n + 1 + n // 254 bytes."""
    code_i = 0
    o = 1
    code = 1
    for i in range(n):
        b = src[i]
        if b:
            dst[o] = b
            o += 1
            code += 1
            if code == 255:
                # A full group ends without an implied zero; the next one starts
                # only if data follows (no dangling 0x01 at the end).
                dst[code_i] = 255
                code = 1
                code_i = o
                if i + 1 < n:
                    o += 1
        else:
            dst[code_i] = code
            code = 1
            code_i = o
            o += 1
    if code_i < o:
        dst[code_i] = code
    return o


def cobs_decode(src, n, dst):
    """Decodes the block src[0:n] into dst; returns the length, or -1 if malformed
    (an empty block is malformed: it has no code byte).

    The decoded length is at most n - 1, so dst needs n - 1 bytes."""
    if n == 0:
        return -1
    i = 0
    o = 0
    while i < n:
        code = src[i]
        if code == 0:
            return -1
        i += 1
        end = i + code - 1
        if end > n:
            return -1
        while i < end:
            b = src[i]
            if b == 0:
                return -1
            dst[o] = b
            o += 1
            i += 1
        if code != 255 and i < n:
            dst[o] = 0
            o += 1
    return o


def trailer_crc(buf, at):
    """The CRC carried by the 3 trailer bytes buf[at:at+3], or -1 when a marker bit is
    wrong (SPEC 2.1: 7 + 7 + 2 bits, bit 7 set in each byte)."""
    t0 = buf[at]
    t1 = buf[at + 1]
    t2 = buf[at + 2]
    if not (t0 & t1 & _MARK) or (t2 & ~_LAST & 0xFF) != _MARK:
        return -1
    return (t0 & _BITS) | ((t1 & _BITS) << _SHIFT) | ((t2 & _LAST) << (2 * _SHIFT))


def put_trailer(buf, at, crc):
    buf[at] = _MARK | (crc & _BITS)
    buf[at + 1] = _MARK | ((crc >> _SHIFT) & _BITS)
    buf[at + 2] = _MARK | (crc >> (2 * _SHIFT))


class FrameEncoder:
    """Builds `COBS(ver|type|id|payload) trailer 0x00` in preallocated buffers.

    extra[t] is the CRC_EXTRA of type t. Usage: fill .payload (a memoryview into the raw
    frame), then finish(type, anchor_id, payload_len) returns a memoryview of the
    encoded frame, valid until the next call."""

    def __init__(self, extra):
        self._extra = extra
        self._raw = bytearray(D.MAX_BODY)
        self._enc = bytearray(D.MAX_ENCODED + 1)
        self._enc_mv = memoryview(self._enc)
        self._views = {}  # encoded length -> memoryview: no allocation per frame
        self.payload = memoryview(self._raw)[_HEADER_LEN:]

    def finish(self, msg_type, anchor_id, payload_len):
        raw = self._raw
        raw[0] = D.PROTO_VERSION
        raw[1] = msg_type
        raw[2] = anchor_id
        enc = self._enc
        m = cobs_encode(raw, _HEADER_LEN + payload_len, enc)
        # The CRC covers the bytes as they are sent (SPEC 2.1).
        put_trailer(enc, m, crc16_byte(crc16(enc, 0, m), self._extra[msg_type]))
        m += _TRAILER
        enc[m] = 0
        v = self._views.get(m)
        if v is None:
            v = self._views[m] = self._enc_mv[: m + 1]
        return v


class FrameDecoder:
    """Splits a byte stream at 0x00 delimiters and checks each frame (SPEC 2.3).

    plen[t] is the payload length of each type this receiver knows (255 = unknown),
    extra[t] its CRC_EXTRA, to_host[t] nonzero for anchor-to-host types (id 127 is then
    bad_anchor). on_frame(type, anchor_id, payload_memoryview, payload_len) is called
    for good frames, on_error(err) once per rejected frame. Memory is fixed: one
    MAX_ENCODED buffer and one MAX_BODY buffer."""

    def __init__(self, plen, extra, to_host, on_frame, on_error):
        self._plen = plen
        self._extra = extra
        self._to_host = to_host
        self._on_frame = on_frame
        self._on_error = on_error
        self._buf = bytearray(D.MAX_ENCODED)
        self._raw = bytearray(D.MAX_BODY)
        self._payload = memoryview(self._raw)[_HEADER_LEN:]
        self._n = 0
        self._skipping = False

    def reset(self):
        self._n = 0
        self._skipping = False

    def feed(self, data):
        buf = self._buf
        n = self._n
        cap = len(buf)
        for b in data:
            if b == 0:
                if self._skipping:
                    self._skipping = False
                elif n:
                    self._n = 0
                    self._frame(n)
                n = 0
            elif self._skipping:
                pass
            elif n == cap:
                # Check 1 (overlong): counted once, the rest up to the next 0x00 dropped.
                n = 0
                self._skipping = True
                self._on_error(D.ERR_OVERLONG)
            else:
                buf[n] = b
                n += 1
        self._n = n

    def check(self, frame):
        """Checks one complete frame given out of stream (the bytes between two
        delimiters), exactly as feed() would."""
        n = len(frame)
        if n > len(self._buf):
            self._on_error(D.ERR_OVERLONG)
            return
        self._buf[:n] = frame
        self._frame(n)

    def _frame(self, n):
        buf = self._buf
        if n >= 2 and buf[0] >= 2 and buf[1] == D.V1_PROTO_VERSION:
            self._on_error(D.ERR_BAD_VERSION)  # a version-1 frame (SPEC 2.3 check 2)
            return
        if n < 1 + _TRAILER:
            self._on_error(D.ERR_TRUNCATED)
            return
        e = n - _TRAILER
        raw = self._raw
        m = cobs_decode(buf, e, raw)
        if m < 0:
            self._on_error(D.ERR_BAD_COBS)
            return
        if m < _HEADER_LEN:
            self._on_error(D.ERR_TRUNCATED)
            return
        if raw[0] != D.PROTO_VERSION:
            self._on_error(D.ERR_BAD_VERSION)
            return
        t = raw[1]
        pl = self._plen[t]
        if pl == 255:
            self._on_error(D.ERR_UNKNOWN_TYPE)
            return
        if m < _HEADER_LEN + pl:
            self._on_error(D.ERR_TRUNCATED)
            return
        if m > _HEADER_LEN + pl:
            self._on_error(D.ERR_BAD_LENGTH)
            return
        if trailer_crc(buf, e) != crc16_byte(crc16(buf, 0, e), self._extra[t]):
            self._on_error(D.ERR_BAD_CRC)
            return
        aid = raw[2]
        if aid > D.ANCHOR_BROADCAST or (aid == D.ANCHOR_BROADCAST and self._to_host[t]):
            self._on_error(D.ERR_BAD_ANCHOR)
            return
        self._on_frame(t, aid, self._payload, pl)
