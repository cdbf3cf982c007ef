"""Untrusted input never raises in the gateway path and never grows its state (hypothesis)."""

from hypothesis import given, settings
from hypothesis import strategies as st

from pfdoa.gateway.health import Health
from pfdoa.gateway.pipeline import MAX_DECODERS, Gateway
from pfdoa.gateway.reassembly import SeqReassembler, WindowGrouper
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol.messages import RssiReport, Status
from pfdoa.protocol.uart import encode_uart

IDS = (0, 1, 2, 3)

valid = st.builds(
    lambda seq, a, q8, tick: encode_uart(RssiReport(seq, tick, q8, -60, 1, 37, 0), a),
    st.integers(0, 65535), st.integers(0, 6), st.integers(-32768, 32767), st.integers(0, 2**32 - 1),
)
status = st.builds(lambda a, up: encode_uart(Status(1, 0, up, 0, 0, 0, 0, 0), a), st.integers(0, 6),
                   st.integers(0, 2**32 - 1))
pieces = st.lists(st.one_of(valid, status, st.binary(max_size=80)), max_size=60)
can_frames = st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=30)


@settings(max_examples=150, deadline=None)
@given(pieces, can_frames, st.sampled_from(["seq", "window"]), st.lists(st.floats(0, 100), min_size=1, max_size=5))
def test_any_bytes_and_frames_never_raise(stream_pieces, frames, mode, times):
    grouper = (SeqReassembler(IDS, max_open_sets=4, set_timeout_s=0.1, history=8) if mode == "seq"
               else WindowGrouper(IDS, window_s=0.5))
    sets = []
    gw = Gateway(grouper, sets.append, Health())
    data = b"".join(stream_pieces)
    t = 0.0
    for i, k in enumerate(range(0, len(data), 37)):
        t = times[i % len(times)]
        gw.feed(Chunk(f"s{i % 3}", t, data[k:k + 37]))
        gw.poll(t)
    for cid, payload in frames:
        gw.feed(Chunk("can0", t, payload, cid))
    gw.finish()
    assert grouper.open_sets == 0
    if mode == "seq":
        assert len(grouper._closed) <= 8 and len(grouper._closed_order) <= 8
    for s in sets:
        assert set(s.rssi) <= set(IDS) and set(s.missing) == set(IDS) - set(s.rssi)
    assert all(d.pending <= 65 for d in gw._decoders.values())


def test_decoders_bounded_per_source_and_noise_never_holds_a_place(caplog):
    """At most MAX_DECODERS decoders. A new source takes the place of the least recently fed
    one that never decoded a valid frame (64 one-off junk sources cannot lock real anchors
    out), or of one idle for DECODER_IDLE_S of chunk time; with every place held by a
    source that decodes and is not idle, the new source's chunks are dropped. Each is
    counted and said."""
    from pfdoa.gateway.transports import DECODER_IDLE_S
    from pfdoa.protocol.messages import RssiReport
    from pfdoa.protocol.uart import encode_uart

    def good(seq: int, anchor: int) -> bytes:
        return encode_uart(RssiReport(seq, 1000 + seq, -60 * 256, -60, 1, 37, 0), anchor)

    gw = Gateway(SeqReassembler(IDS), lambda s: None, Health())
    for i in range(MAX_DECODERS + 50):  # junk on ever new sources: they make room for each other
        gw.feed(Chunk(f"junk{i}", 0.0, b"\x01\x02"))
    assert len(gw._decoders) == MAX_DECODERS and gw.health.sources_evicted == 50
    assert gw.health.sources_dropped == 0
    for a in IDS:  # real anchors after the junk: each takes a junk source's place and decodes
        gw.feed(Chunk(f"port{a}", 1.0, good(1, a)))
    assert {f"port{a}" for a in IDS} <= set(gw._decoders) and gw.health.reports == len(IDS)
    assert gw.health.sources_evicted == 50 + len(IDS)
    for i in range(MAX_DECODERS - len(IDS)):  # every place held by sources that decode: the next one is dropped
        gw.feed(Chunk(f"valid{i}", 2.0, good(2, IDS[i % len(IDS)])))
    for a in IDS:  # (the real anchors keep theirs: they are fed more recently than the oldest)
        gw.feed(Chunk(f"port{a}", 2.0, good(3, a)))
    assert all(d.counters["frames_ok"] for d in gw._decoders.values())
    gw.feed(Chunk("late", 3.0, good(4, IDS[0])))
    assert gw.health.sources_dropped == 1 and "late" not in gw._decoders
    assert "not decoded" in caplog.text and "never sent a valid frame" in caplog.text
    # Chunk time passes: the least recently fed decoder, idle that long, makes room.
    oldest = next(iter(gw._decoders))
    gw.feed(Chunk("late", 2.0 + DECODER_IDLE_S + 1.0, good(5, IDS[0])))
    assert "late" in gw._decoders and oldest not in gw._decoders and "idle for" in caplog.text
    assert len(gw._decoders) == MAX_DECODERS
