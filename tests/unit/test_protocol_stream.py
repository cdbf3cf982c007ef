"""UART/CAN codec properties: round trips, garbage, resync, chunking, exact counters."""

import dataclasses
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from pfdoa.protocol import (
    COUNTER_NAMES,
    ConfigAck,
    ConfigSet,
    FilterAck,
    FilterSet,
    RadioInject,
    RadioInjectRaw,
    RssiReport,
    Status,
    StreamDecoder,
    cobs_decode,
    cobs_encode,
    crc16,
    crc16_table,
    decode_can,
    decode_frame,
    defs,
    encode_can,
    encode_raw,
    encode_uart,
    seal,
)
from pfdoa.protocol.can import GATEWAY_CAN_FILTERS, anchor_can_filters, can_id_for, is_report_id
from pfdoa.protocol.uart import frame_type, is_report_type, trailer, trailer_value

u8, u16, u32 = (st.integers(0, 2**k - 1) for k in (8, 16, 32))
i8, i16 = st.integers(-128, 127), st.integers(-32768, 32767)

reports = st.builds(RssiReport, u16, u32, i16, i8, u8, u8, u8, u8)
v1_reports = st.builds(RssiReport, u16, u32, i16, i8, u8, u8, u8)
statuses = st.builds(Status, u8, u8, u32, u16, u16, u16, u16, u16, u16, u8)
v1_statuses = st.builds(Status, u8, u8, u32, u16, u16, u16, u16, u16)
sets = st.builds(ConfigSet, u8, i16, u16, u8, u8, u8)
acks = st.builds(ConfigAck, u8, u8, u16)
fsets = st.builds(FilterSet, u8, u8, u8, u16, st.binary(min_size=20, max_size=20))
facks = st.builds(FilterAck, u8, u8, u8, u16)
injects = st.builds(RadioInject, u16, u32, i8, u8, u8, u8)
raw_injects = st.builds(RadioInjectRaw, u32, i8, u8, u8, u8, u8, st.binary(min_size=39, max_size=39))
to_host = st.one_of(reports, statuses, acks, facks)
any_msg = st.one_of(reports, statuses, sets, acks, fsets, facks, injects, raw_injects)
any_v1_msg = st.one_of(v1_reports, v1_statuses, sets, acks, injects)


def _anchor_for(msg, a):
    return a if msg.layout().direction == "host_to_anchor" else min(a, 126)


@given(any_msg, st.integers(0, 127))
def test_uart_round_trip(msg, anchor):
    anchor = _anchor_for(msg, anchor)
    frame = encode_uart(msg, anchor)
    assert frame.endswith(b"\x00") and frame.count(0) == 1
    assert len(frame) <= defs.MAX_ENCODED + 1
    d = decode_frame(frame[:-1])
    assert d.anchor_id == anchor and d.message == msg
    assert frame_type(frame[:-1]) == msg.TYPE and is_report_type(msg.TYPE) == isinstance(msg, RssiReport)


@given(any_v1_msg, st.integers(0, 127))
def test_v1_uart_round_trip(msg, anchor):
    anchor = _anchor_for(msg, anchor)
    frame = encode_uart(msg, anchor, version=defs.V1_PROTO_VERSION)
    assert frame.count(0) == 1 and frame[1] == defs.V1_PROTO_VERSION
    d = decode_frame(frame[:-1])
    assert d.anchor_id == anchor and d.message == msg
    assert decode_frame(frame[:-1], versions=(defs.PROTO_VERSION,)) == "bad_version"
    assert is_report_type(frame_type(frame[:-1])) == isinstance(msg, RssiReport)


@given(u16)
def test_trailer_carries_every_crc(crc):
    t = trailer(crc)
    assert len(t) == defs.TRAILER_LEN and all(b & defs.TRAILER_MARKER for b in t)
    assert trailer_value(t) == crc
    for bit in range(24):  # every single-bit change is another CRC or an invalid trailer
        bad = bytes(b ^ ((1 << (bit % 8)) if k == bit // 8 else 0) for k, b in enumerate(t))
        assert trailer_value(bad) != crc


@given(st.one_of(reports, statuses, sets, acks), st.integers(0, 127))
def test_can_round_trip(msg, anchor):
    anchor = _anchor_for(msg, anchor)
    if isinstance(msg, RssiReport):  # version 2 on CAN: no tick, reading count or channel
        msg = RssiReport(msg.seq, None, msg.rssi_q8, msg.raw_dbm, None, None, msg.flags, msg.beacon)
    frames = encode_can(msg, anchor)
    decoded = [decode_can(i, d) for i, d in frames]
    assert all(d.anchor_id == anchor for d in decoded)
    if isinstance(msg, Status):
        assert len(frames) == 3
        assert Status.from_halves(*[d.message for d in decoded]) == msg
    else:
        assert decoded[0].message == msg
    assert all(is_report_id(i) == isinstance(msg, RssiReport) for i, _ in frames)
    for can_id, data in frames:
        assert can_id <= 0x7FF and len(data) <= 8
        assert any(can_id & f["can_mask"] == f["can_id"] for f in GATEWAY_CAN_FILTERS) \
            != isinstance(msg, ConfigSet)


@given(st.one_of(v1_reports, v1_statuses), st.integers(0, 126))
def test_v1_can_round_trip(msg, anchor):
    if isinstance(msg, RssiReport):
        msg = RssiReport(msg.seq, None, msg.rssi_q8, msg.raw_dbm, msg.n_readings, msg.channel, msg.flags)
    frames = encode_can(msg, anchor, version=defs.V1_PROTO_VERSION)
    decoded = [decode_can(i, d).message for i, d in frames]
    if isinstance(msg, Status):
        assert len(frames) == 2 and Status.from_halves(*decoded) == msg
    else:
        assert len(frames[0][1]) == defs.CAN_V1_RSSI_REPORT_DLC and decoded[0] == msg


def test_version_1_carries_only_what_it_has():
    import pytest
    with pytest.raises(ValueError):
        encode_uart(RssiReport(1, 1, 1, 1, 1, 1, 1, beacon=1), 1, version=defs.V1_PROTO_VERSION)
    with pytest.raises(ValueError):
        encode_can(RssiReport(1, None, 1, 1, 1, 1, 1, beacon=2), 1, version=defs.V1_PROTO_VERSION)
    with pytest.raises(ValueError):
        encode_uart(FilterSet(1, 0, 0, 0), 1, version=defs.V1_PROTO_VERSION)
    # a version-1 STATUS drops the filter fields; decoding gives 0 for them and version 1
    st1 = Status(1, 0, 2, 3, 4, 5, 6, defs.V1_DEFS_HASH, 0xAAAA, 4)
    got = decode_frame(encode_uart(st1, 2, version=defs.V1_PROTO_VERSION)[:-1]).message
    assert got.filter_hash == got.filter_slots == 0 and got.version == defs.V1_PROTO_VERSION
    assert Status(1, 0, 2, 3, 4, 5, 6, defs.DEFS_HASH).version == defs.PROTO_VERSION


def test_anchor_filters_accept_own_and_broadcast_only():
    flt = anchor_can_filters(9)
    accepted = {i for i in range(0x800) if any(i & f["can_mask"] == f["can_id"] for f in flt)}
    assert accepted == {can_id_for(defs.CAN_CONFIG_SET, 9), can_id_for(defs.CAN_CONFIG_SET, 127)}


@given(st.binary(max_size=700))
def test_cobs_round_trip_and_overhead(data):
    enc = cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + 1 + len(data) // 254
    assert cobs_decode(enc) == data


@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_fast_crc_matches_table_crc(data, init):
    assert crc16(data, init) == crc16_table(data, init)


@settings(max_examples=300)
@given(st.binary(max_size=400))
def test_decode_frame_never_raises(data):
    r = decode_frame(data)
    assert isinstance(r, str) or encode_raw(r.message, r.anchor_id)  # valid => re-encodable


def _valid_if_accepted(out):
    for d in out:  # an accepted frame is a genuinely valid frame (a CRC accident at worst)
        assert decode_frame(encode_uart(d.message, d.anchor_id)[:-1]) == d


def test_random_garbage_never_raises_and_yields_only_crc_accidents():
    rng = random.Random(1234)
    dec = StreamDecoder()
    accepted = []
    total_frames = 0
    for _ in range(400):
        # Garbage with plenty of zeros, so many short "frames" reach the later checks.
        chunk = bytes(rng.choice((0, rng.randrange(256), 1, 5)) for _ in range(rng.randrange(1, 600)))
        total_frames += chunk.count(0)
        out = dec.feed(chunk)
        _valid_if_accepted(out)
        accepted += out
        assert dec.pending <= defs.MAX_ENCODED
    c = dec.counters
    assert c["frames_ok"] == len(accepted)
    # Only frames that pass ver/type/length can pass by accident: 1 in 65536 of those.
    candidates = total_frames
    assert len(accepted) <= 2 + candidates // 10000
    assert sum(c[e] for e in defs.ERRORS) + c["frames_ok"] > 1000


def test_random_garbage_with_valid_header_counts_crc_accidents():
    # Frames with a correct header and length but random payload + CRC: accepted only when
    # the CRC matches by accident, about 1/65536 of them, in either framing.
    rng = random.Random(99)
    n = 60000
    for version in defs.VERSIONS:
        dec = StreamDecoder()
        stream = bytearray()
        for _ in range(n):
            body = bytes((version, defs.MSG_CONFIG_ACK, rng.randrange(127))) + rng.randbytes(4)
            if version == defs.V1_PROTO_VERSION:
                stream += cobs_encode(body + rng.randbytes(2)) + b"\x00"
            else:
                stream += cobs_encode(body) + trailer(rng.randrange(65536)) + b"\x00"
        out = dec.feed(bytes(stream))
        _valid_if_accepted(out)
        assert dec.counters["bad_crc"] + dec.counters["frames_ok"] == n
        assert dec.counters["frames_ok"] == len(out) <= 6  # expectation ~0.9


def _stream():
    rng = random.Random(7)
    parts = []
    for k in range(40):
        m = RssiReport(k, 1000 * k, -15000 - k, -60, 3, 37, 0)
        frame = encode_uart(m, k % defs.ANCHOR_BROADCAST)
        r = rng.random()
        if r < 0.15:
            frame = frame[:3] + bytes([frame[3] ^ 0x10 or 1]) + frame[4:]  # corrupt (bad_crc)
        elif r < 0.2:
            frame = frame[:-1]  # lost delimiter: merges with the next frame
        elif r < 0.25:
            frame = b"\x55" * 80 + b"\x00"  # overlong
        elif r < 0.3:
            frame = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))  # garbage
        parts.append(frame)
    return b"".join(parts)


def _run(chunks):
    dec = StreamDecoder()
    out = []
    for c in chunks:
        out += dec.feed(c)
    return out, dec.counters


def test_split_at_every_byte_boundary_gives_identical_output():
    s = _stream()
    ref_out, ref_counters = _run([s])
    assert len(ref_out) > 20 and sum(ref_counters[e] for e in defs.ERRORS) > 3
    for i in range(len(s) + 1):
        assert _run([s[:i], s[i:]]) == (ref_out, ref_counters)


@given(st.lists(st.integers(0, 2000), max_size=20))
def test_random_chunking_gives_identical_output(cuts):
    s = _stream()
    points = sorted({c % (len(s) + 1) for c in cuts})
    chunks = [s[a:b] for a, b in zip([0] + points, points + [len(s)])]
    assert _run(chunks) == _run([s])


def test_one_byte_at_a_time():
    s = _stream()
    assert _run([s[i:i + 1] for i in range(len(s))]) == _run([s])


def test_bad_crc_frame_never_swallows_the_next_good_frame():
    good = encode_uart(RssiReport(2, 20, -1, -1, 1, 37, 0), 3)
    template = encode_uart(RssiReport(1, 10, -1, -1, 1, 37, 0), 3)
    # A bad-CRC frame whose last bytes look like the start of a frame (a code byte and a
    # header): pymavlink#881's failure mode for COBS. It must end at its delimiter.
    body = bytearray(template[:-1])
    body[-3:] = bytes((0x04, 0x01, 0x01))
    for bad in (bytes(body) + b"\x00",
                template[:5] + b"\x00" + template[6:],   # corrupted into a premature delimiter
                template[:-1] + template[:-1] + b"\x00"):  # a lost delimiter: two merged frames
        dec = StreamDecoder()
        out = dec.feed(bad + good)
        assert [d.message for d in out] == [decode_frame(good[:-1]).message]
        assert dec.counters["frames_ok"] == 1
        assert sum(dec.counters[e] for e in defs.ERRORS) >= 1


def test_counters_exact_for_injected_errors():
    good = [encode_uart(RssiReport(k, k, 0, 0, 1, 37, 0, k % 4), 1) for k in range(10)]
    good.append(encode_uart(RssiReport(3, 3, 0, 0, 1, 37, 0), 2, version=defs.V1_PROTO_VERSION))
    rp = RssiReport(1, 1, 1, 1, 1, 1, 1, 1).pack()
    t, x = defs.MSG_RSSI_REPORT, defs.MSG_RSSI_REPORT_CRC_EXTRA
    ok = seal(bytes((2, t, 1)) + rp, x)

    def v1(ver, typ, aid, payload, extra, xor=0):
        b = bytes((ver, typ, aid)) + payload
        return cobs_encode(b + (crc16(b + bytes((extra,))) ^ xor).to_bytes(2, "little"))

    bad = {
        "bad_crc": ok[:-3] + trailer(trailer_value(ok[-3:]) ^ 1),
        "truncated": seal(bytes((2, t, 1)) + rp[:5], x),
        "overlong": b"\x01" * 66,
        "bad_cobs": b"\x09\x01\x01\x81\x81\x81",
        "unknown_type": seal(bytes((2, 9, 1)) + rp, 0),
        "bad_version": seal(bytes((3, t, 1)) + rp, x),
        "bad_length": seal(bytes((2, t, 1)) + rp + b"\x07", x),
        "bad_anchor": seal(bytes((2, t, 127)) + rp, x),
    }
    v1_bad = {"bad_crc": v1(1, defs.MSG_V1_RSSI_REPORT, 1, rp[:-1], defs.MSG_V1_RSSI_REPORT_CRC_EXTRA, 1),
              "unknown_type": v1(1, t, 1, rp, x)}
    rng = random.Random(5)
    frames = []
    expected = dict.fromkeys(COUNTER_NAMES, 0)
    for i, (kind, frame) in enumerate(list(bad.items()) + list(v1_bad.items())):
        for _ in range(i + 1):
            frames.append(frame + b"\x00")
            expected[kind] += 1
            expected["bytes_discarded"] += len(frame)
    frames += good
    expected["frames_ok"] = len(good)
    rng.shuffle(frames)
    stream = b"\x00" + b"".join(frames) + b"\x00\x00"
    expected["bytes_in"] = len(stream)
    dec = StreamDecoder()
    out = dec.feed(stream)
    assert len(out) == len(good)
    assert dec.counters == expected


def test_overlong_counted_once_and_memory_bounded():
    dec = StreamDecoder()
    for _ in range(1000):
        assert dec.feed(b"\x55" * 1000) == []
        assert dec.pending <= defs.MAX_ENCODED
    good = encode_uart(ConfigAck(1, 0, 2), 4)
    assert dec.feed(b"\x00" + good)[0].message == ConfigAck(1, 0, 2)
    assert dec.counters["overlong"] == 1
    assert dec.counters["bytes_discarded"] == 1_000_000


def test_max_encoded_frame_is_checked_normally():
    dec = StreamDecoder()
    dec.feed(b"\x42" * defs.MAX_ENCODED + b"\x00")
    assert dec.counters["overlong"] == 0 and dec.counters["bad_cobs"] == 1
    dec.feed(b"\x42" * (defs.MAX_ENCODED + 1) + b"\x00")
    assert dec.counters["overlong"] == 1


def test_receiver_type_set_restricts_known_types():
    frame = encode_uart(RssiReport(1, 1, 1, 1, 1, 1, 1), 1)
    anchor_rx = StreamDecoder({defs.MSG_CONFIG_SET})
    assert anchor_rx.feed(frame) == [] and anchor_rx.counters["unknown_type"] == 1
    assert decode_frame(encode_uart(ConfigSet(1), 127)[:-1]).anchor_id == 127


def test_encoders_reject_out_of_range_values():
    import pytest
    with pytest.raises(ValueError):
        encode_uart(RssiReport(65536, 0, 0, 0, 0, 0, 0), 1)
    with pytest.raises(ValueError):
        encode_uart(ConfigAck(0, 0, 0), 128)
    with pytest.raises(ValueError):
        encode_can(RssiReport(1, None, 0, 0, 0, 0, 0), 127)
    with pytest.raises(ValueError):
        encode_can(RadioInject(1, 1, 1, 1, 1, 1), 1)
    with pytest.raises(ValueError):
        encode_can(FilterSet(1, 0, 0, 0), 1)
    with pytest.raises(ValueError):
        FilterSet(1, 0, 0, 0, bytes(21))


def test_mutation_fuzz_accounting_is_exact():
    """Bit flips, insertions and deletions on valid streams: never raises, and every byte
    is accounted for (ok frame bytes + discarded bytes + delimiters == bytes_in)."""
    rng = random.Random(2024)
    base = b"".join(encode_uart(RssiReport(k, k * 7, -k, -50, 2, 38, 8), k % defs.ANCHOR_BROADCAST) for k in range(30))
    base += b"".join(encode_uart(ConfigSet(k, -k, 64 + k, 3, 1, 2), 127) for k in range(10))
    for _ in range(300):
        s = bytearray(base)
        for _ in range(rng.randrange(1, 12)):
            op, i = rng.random(), rng.randrange(len(s))
            if op < 0.5:
                s[i] ^= 1 << rng.randrange(8)
            elif op < 0.75:
                s[i:i] = rng.randbytes(rng.randrange(1, 90))
            else:
                del s[i:i + rng.randrange(1, 40)]
        s += b"\x00"
        dec = StreamDecoder()
        out = []
        i = 0
        while i < len(s):
            n = rng.randrange(1, 100)
            out += dec.feed(bytes(s[i:i + n]))
            i += n
            assert dec.pending <= defs.MAX_ENCODED
        c = dec.counters
        ok_bytes = sum(len(encode_uart(d.message, d.anchor_id)) - 1 for d in out)
        assert c["frames_ok"] == len(out)
        assert ok_bytes + c["bytes_discarded"] + s.count(0) == c["bytes_in"] == len(s)


def test_dataclass_fields_match_messages_json():
    from pfdoa.protocol.messages import BY_TYPE, StatusA, StatusB, StatusC
    for key, spec in defs.MESSAGES.items():
        cls = BY_TYPE[spec[0]]
        fields = tuple(f for f, _ in spec[4])
        if defs.PROTO_VERSION in spec[6]:  # the current layout is the class, field for field
            # dataclasses.fields: a subclass (AUTH_REPORT extends RSSI_REPORT) holds its parent's too
            assert tuple(f.name for f in dataclasses.fields(cls)) == fields and cls.TYPE == spec[0] and cls.NAME == key
        else:  # an older layout is a prefix of it
            assert cls.__slots__[:len(fields)] == fields and key == "V1_" + cls.NAME
    assert StatusA.__slots__ == defs.CAN_TYPES["STATUS_A"][2]
    assert StatusB.__slots__ == defs.CAN_TYPES["STATUS_B"][2]
    assert StatusC.__slots__ == defs.CAN_TYPES["STATUS_C"][2]
