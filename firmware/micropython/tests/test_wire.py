# Unit tests of pfdoa_wire (CRC-16, COBS, frame encoder, stream decoder) on the
# MicroPython unix port. Run by run_tests.py.
import json
import random

import pfdoa_defs as D
import pfdoa_wire as W


def _msgs():
    with open(_root() + "protocol/messages.json") as f:
        return json.load(f)


def _root():
    import run_tests
    return run_tests.ROOT


def test_crc_check_value():
    assert W.crc16(b"123456789") == 0x29B1
    assert W.crc16(b"") == 0xFFFF
    # split computation continues where it stopped
    assert W.crc16(b"6789", crc=W.crc16(b"12345")) == 0x29B1
    assert W.crc16(b"xx123456789yy", 2, 11) == 0x29B1


def test_crc_matches_bitwise():
    random.seed(7)
    for n in range(0, 40):
        data = bytes(random.getrandbits(8) for _ in range(n))
        c = 0xFFFF
        for b in data:
            c ^= b << 8
            for _ in range(8):
                c = ((c << 1) ^ 0x1021) & 0xFFFF if c & 0x8000 else (c << 1) & 0xFFFF
        assert W.crc16(data) == c, data


def test_crc_extra_and_defs_hash_match_messages_json():
    m = _msgs()
    by_type = {}
    for msg in m["messages"]:
        assert W.crc_extra(msg["definition"]) == msg["crc_extra"], msg["name"]
        if D.PROTO_VERSION in msg["versions"] and not msg.get("test_only"):
            by_type[msg["type"]] = msg["definition"]
    defs = "".join(by_type[t] for t in sorted(by_type))
    assert W.crc16(defs.encode()) == m["defs_hash"][str(D.PROTO_VERSION)] == D.DEFS_HASH


def _enc(data):
    dst = bytearray(len(data) + 2 + len(data) // 254)
    n = W.cobs_encode(data, len(data), dst)
    return bytes(dst[:n])


def _dec(block):
    dst = bytearray(len(block))
    n = W.cobs_decode(block, len(block), dst)
    return None if n < 0 else bytes(dst[:n])


def test_cobs_known_vectors():
    # Cheshire & Baker examples as commonly tabulated
    r254 = bytes(range(1, 255))
    cases = (
        (b"", b"\x01"),
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        (r254, b"\xff" + r254),
        (b"\x00" + r254, b"\x01\xff" + r254),
        (bytes(range(1, 256)), b"\xff" + r254 + b"\x02\xff"),
        (bytes(range(2, 256)) + b"\x00", b"\xff" + bytes(range(2, 256)) + b"\x01\x01"),
        (bytes(range(3, 256)) + b"\x00\x01", b"\xfe" + bytes(range(3, 256)) + b"\x02\x01"),
    )
    for raw, enc in cases:
        assert _enc(raw) == enc, raw
        assert _dec(enc) == raw, enc


def test_cobs_roundtrip_random():
    random.seed(11)
    for _ in range(300):
        n = random.getrandbits(9) % 300
        zeros = random.getrandbits(2)
        data = bytes(0 if (zeros and random.getrandbits(3) < zeros) else
                     random.getrandbits(8) for _ in range(n))
        e = _enc(data)
        assert 0 not in e
        assert len(e) <= len(data) + 1 + len(data) // 254
        assert _dec(e) == data


def test_cobs_decode_errors():
    assert _dec(b"\x05\x11\x22") is None  # code points past the end
    assert _dec(b"\x03\x11\x00") is None  # zero inside
    assert _dec(b"\x00") is None  # zero code
    assert _dec(b"\x02\x11\x00\x01") is None
    assert _dec(b"") is None  # no code byte


# ---- frame decoder -----------------------------------------------------------------

_PLEN = bytearray(b"\xff" * 256)
_PLEN[D.MSG_CONFIG_SET] = D.MSG_CONFIG_SET_LEN
_PLEN[D.MSG_RSSI_REPORT] = D.MSG_RSSI_REPORT_LEN
_EXTRA = bytearray(256)
_EXTRA[D.MSG_CONFIG_SET] = D.MSG_CONFIG_SET_CRC_EXTRA
_EXTRA[D.MSG_RSSI_REPORT] = D.MSG_RSSI_REPORT_CRC_EXTRA
_TO_HOST = bytearray(256)
_TO_HOST[D.MSG_RSSI_REPORT] = 1


class _Sink:
    def __init__(self):
        self.frames = []
        self.errors = []
        self.dec = W.FrameDecoder(_PLEN, _EXTRA, _TO_HOST, self.frame, self.errors.append)

    def frame(self, t, aid, payload, n):
        self.frames.append((t, aid, bytes(payload[:n])))


def _frame(t, aid, payload, ver=2, extra=None, crc_delta=0):
    """A version-2 frame (SPEC 2.1, by hand): COBS body, CRC trailer over it, delimiter."""
    e = _enc(bytes((ver, t, aid)) + payload)
    c = W.crc16_byte(W.crc16(e), _EXTRA[t] if extra is None else extra) ^ crc_delta
    m, b, k = D.TRAILER_MARKER, D.TRAILER_VALUE_MASK, D.TRAILER_BITS
    return e + bytes((m | (c & b), m | ((c >> k) & b), m | (c >> (2 * k)))) + b"\x00"


def _v1_frame(t, aid, payload):
    """A version-1 frame (SPEC 8.2): the CRC inside the COBS block."""
    r = bytes((1, t, aid)) + payload
    c = W.crc16_byte(W.crc16(r), _EXTRA[t])
    return _enc(r + bytes((c & 0xFF, c >> 8))) + b"\x00"


_CFG = bytes((9, 0, 0, 64, 0, 12, 0, 1))


def test_encoder_produces_decodable_frame():
    e = W.FrameEncoder(_EXTRA)
    e.payload[:8] = _CFG
    f = bytes(e.finish(D.MSG_CONFIG_SET, 5, 8))
    assert f == _frame(D.MSG_CONFIG_SET, 5, _CFG)
    s = _Sink()
    s.dec.feed(f)
    assert s.frames == [(D.MSG_CONFIG_SET, 5, _CFG)] and s.errors == []


def test_decoder_each_error_in_order():
    cs = D.MSG_CONFIG_SET
    cases = (
        (b"\x01" * 66 + b"\x00", D.ERR_OVERLONG),
        (_v1_frame(cs, 5, _CFG), D.ERR_BAD_VERSION),  # a version-1 frame, routed first
        (b"\x81\x81\x81\x00", D.ERR_TRUNCATED),
        (b"\x05\x02\x01\x81\x81\x81\x00", D.ERR_BAD_COBS),
        (_enc(b"\x02\x03") + b"\x81\x81\x81\x00", D.ERR_TRUNCATED),
        (_frame(cs, 5, _CFG, ver=3), D.ERR_BAD_VERSION),
        (_frame(0x55, 5, _CFG), D.ERR_UNKNOWN_TYPE),
        (_frame(cs, 5, _CFG[:7]), D.ERR_TRUNCATED),
        (_frame(cs, 5, _CFG + b"\x01"), D.ERR_BAD_LENGTH),
        (_frame(cs, 5, _CFG, crc_delta=0x100), D.ERR_BAD_CRC),
        (_frame(cs, 5, _CFG, crc_delta=0x8000), D.ERR_BAD_CRC),
        (_frame(cs, 5, _CFG, extra=0), D.ERR_BAD_CRC),
        (_frame(cs, 5, _CFG)[:-2] + b"\x84\x00", D.ERR_BAD_CRC),  # a spare trailer bit
        (_frame(cs, 128, _CFG), D.ERR_BAD_ANCHOR),
        (_frame(D.MSG_RSSI_REPORT, 127, bytes(D.MSG_RSSI_REPORT_LEN)), D.ERR_BAD_ANCHOR),
        # unknown type beats a wrong length; version beats unknown type
        (_frame(0x55, 5, b""), D.ERR_UNKNOWN_TYPE),
        (_frame(0x55, 5, b"", ver=0), D.ERR_BAD_VERSION),
    )
    good = _frame(cs, 5, _CFG)
    for data, err in cases:
        s = _Sink()
        s.dec.feed(data + good)  # a bad frame never eats the next one
        assert s.errors == [err], (data, s.errors, err)
        assert s.frames == [(cs, 5, _CFG)], data


def test_decoder_broadcast_config_accepted():
    s = _Sink()
    s.dec.feed(_frame(D.MSG_CONFIG_SET, 127, _CFG))
    assert s.frames == [(D.MSG_CONFIG_SET, 127, _CFG)] and s.errors == []


def test_decoder_overlong_counted_once_and_resyncs():
    s = _Sink()
    s.dec.feed(b"\x07" * 500)
    assert s.errors == [D.ERR_OVERLONG]
    s.dec.feed(b"\x07" * 100 + b"\x00" + _frame(D.MSG_CONFIG_SET, 5, _CFG))
    assert s.errors == [D.ERR_OVERLONG] and len(s.frames) == 1


def test_decoder_65_bytes_is_not_overlong_66_is():
    s = _Sink()
    s.dec.feed(b"\x01" * 65 + b"\x00")
    assert s.errors == [D.ERR_BAD_VERSION]  # a 61-zero body: version 0
    s = _Sink()
    s.dec.feed(b"\x01" * 66 + b"\x00")
    assert s.errors == [D.ERR_OVERLONG]


def test_decoder_empty_frames_and_chunking():
    stream = b"\x00\x00" + _frame(D.MSG_CONFIG_SET, 1, _CFG) + b"\x00" + \
        _frame(D.MSG_CONFIG_SET, 2, _CFG, crc_delta=1) + \
        _frame(D.MSG_CONFIG_SET, 3, _CFG)
    whole = _Sink()
    whole.dec.feed(stream)
    assert [f[1] for f in whole.frames] == [1, 3] and whole.errors == [D.ERR_BAD_CRC]
    for step in (1, 2, 3, 7):
        s = _Sink()
        for i in range(0, len(stream), step):
            s.dec.feed(stream[i:i + step])
        assert s.frames == whole.frames and s.errors == whole.errors


def test_decoder_random_garbage_bounded():
    random.seed(3)
    s = _Sink()
    for _ in range(200):
        s.dec.feed(bytes(random.getrandbits(8) for _ in range(random.getrandbits(6))))
    assert s.dec._n <= D.MAX_ENCODED
    s.dec.feed(b"\x00" + _frame(D.MSG_CONFIG_SET, 4, _CFG))
    assert s.frames[-1] == (D.MSG_CONFIG_SET, 4, _CFG)
