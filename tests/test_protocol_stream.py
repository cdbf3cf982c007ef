"""UART/CAN codec properties: round trips, garbage, resync, chunking, exact counters."""

import random

from hypothesis import given, settings, strategies as st

from pfdoa.protocol import (COUNTER_NAMES, ConfigAck, ConfigSet, RadioInject, RssiReport, Status,
                            StreamDecoder, cobs_decode, cobs_encode, crc16, crc16_table,
                            decode_can, decode_frame, defs, encode_can, encode_raw, encode_uart)
from pfdoa.protocol.can import GATEWAY_CAN_FILTERS, anchor_can_filters, can_id_for

u8, u16, u32 = (st.integers(0, 2**k - 1) for k in (8, 16, 32))
i8, i16 = st.integers(-128, 127), st.integers(-32768, 32767)

reports = st.builds(RssiReport, u16, u32, i16, i8, u8, u8, u8)
statuses = st.builds(Status, u8, u8, u32, u16, u16, u16, u16, u16)
sets = st.builds(ConfigSet, u8, i16, u16, u8, u8, u8)
acks = st.builds(ConfigAck, u8, u8, u16)
injects = st.builds(RadioInject, u16, u32, i8, u8, u8, u8)
to_host = st.one_of(reports, statuses, acks)
any_msg = st.one_of(reports, statuses, sets, acks, injects)


def _anchor_for(msg, a):
    return a if msg.TYPE in (defs.MSG_CONFIG_SET, defs.MSG_RADIO_INJECT) else min(a, 126)


@given(any_msg, st.integers(0, 127))
def test_uart_round_trip(msg, anchor):
    anchor = _anchor_for(msg, anchor)
    frame = encode_uart(msg, anchor)
    assert frame.endswith(b"\x00") and frame.count(0) == 1
    assert len(frame) <= defs.MAX_ENCODED + 1
    d = decode_frame(frame[:-1])
    assert d.anchor_id == anchor and d.message == msg


@given(st.one_of(reports, statuses, sets, acks), st.integers(0, 127))
def test_can_round_trip(msg, anchor):
    anchor = _anchor_for(msg, anchor)
    if isinstance(msg, RssiReport):
        msg = RssiReport(msg.seq, None, *[getattr(msg, f) for f in msg.__slots__[2:]])
    frames = encode_can(msg, anchor)
    decoded = [decode_can(i, d) for i, d in frames]
    assert all(d.anchor_id == anchor for d in decoded)
    if isinstance(msg, Status):
        assert len(frames) == 2
        assert Status.from_halves(decoded[0].message, decoded[1].message) == msg
    else:
        assert decoded[0].message == msg
    for can_id, data in frames:
        assert can_id <= 0x7FF and len(data) <= 8
        assert any(can_id & f["can_mask"] == f["can_id"] for f in GATEWAY_CAN_FILTERS) \
            != isinstance(msg, ConfigSet)


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
    # Frames with a correct header and length but random payload+CRC: accepted only when the
    # CRC matches by accident. Count them, and check the rate is about 1/65536.
    rng = random.Random(99)
    dec = StreamDecoder()
    n = 60000
    stream = bytearray()
    for _ in range(n):
        raw = bytes((1, 4, rng.randrange(127))) + rng.randbytes(6)
        stream += cobs_encode(raw) + b"\x00"
    out = dec.feed(bytes(stream))
    _valid_if_accepted(out)
    assert dec.counters["bad_crc"] + dec.counters["frames_ok"] == n
    assert dec.counters["frames_ok"] == len(out) <= 6  # expectation ~0.9


def _stream():
    rng = random.Random(7)
    parts = []
    for k in range(40):
        m = RssiReport(k, 1000 * k, -15000 - k, -60, 3, 37, 0)
        frame = encode_uart(m, k % 127)
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
    good = [encode_uart(RssiReport(k, k, 0, 0, 1, 37, 0), 1) for k in range(10)]
    rp = RssiReport(1, 1, 1, 1, 1, 1, 1).pack()

    def raw(ver, typ, aid, payload, extra, xor=0):
        b = bytes((ver, typ, aid)) + payload
        return b + (crc16(b + bytes((extra,))) ^ xor).to_bytes(2, "little")

    bad = {
        "bad_crc": cobs_encode(raw(1, 1, 1, rp, 145, 1)),
        "truncated": cobs_encode(raw(1, 1, 1, rp[:5], 145)),
        "overlong": b"\x01" * 66,
        "bad_cobs": b"\x09\x01\x01",
        "unknown_type": cobs_encode(raw(1, 9, 1, rp, 0)),
        "bad_version": cobs_encode(raw(3, 1, 1, rp, 145)),
        "bad_length": cobs_encode(raw(1, 1, 1, rp + b"\x07", 145)),
        "bad_anchor": cobs_encode(raw(1, 1, 127, rp, 145)),
    }
    rng = random.Random(5)
    frames = []
    expected = dict.fromkeys(COUNTER_NAMES, 0)
    for i, (kind, frame) in enumerate(bad.items()):
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


def test_mutation_fuzz_accounting_is_exact():
    """Bit flips, insertions and deletions on valid streams: never raises, and every byte
    is accounted for (ok frame bytes + discarded bytes + delimiters == bytes_in)."""
    rng = random.Random(2024)
    base = b"".join(encode_uart(RssiReport(k, k * 7, -k, -50, 2, 38, 8), k % 127) for k in range(30))
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
    from pfdoa.protocol.messages import BY_NAME, StatusA, StatusB
    for name, spec in defs.MESSAGES.items():
        assert BY_NAME[name].__slots__ == tuple(f for f, _ in spec[4])
        assert BY_NAME[name].TYPE == spec[0]
    assert StatusA.__slots__ == defs.CAN_TYPES["STATUS_A"][2]
    assert StatusB.__slots__ == defs.CAN_TYPES["STATUS_B"][2]
