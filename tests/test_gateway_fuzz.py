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


def test_decoders_bounded_per_source():
    gw = Gateway(SeqReassembler(IDS), lambda s: None, Health())
    for i in range(MAX_DECODERS + 50):
        gw.feed(Chunk(f"src{i}", 0.0, b"\x01\x02"))
    assert len(gw._decoders) == MAX_DECODERS
    assert gw.health.sources_dropped == 50
