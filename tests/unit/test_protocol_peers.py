"""Peer readings (SPEC 3.5, 6.1): protocol/vectors/peer.json in Python, and what its
expected outputs mean, re-derived from the SPEC's words rather than from the model that
wrote them (the C core and the MicroPython anchor run the same vectors in their suites)."""

import json
from pathlib import Path

import pytest

from pfdoa.protocol import BeaconFilter, StreamDecoder, decode_can, defs, encode_uart
from pfdoa.protocol.anchor_model import AnchorModel, Transmitted
from pfdoa.protocol.filters import PeerMatch, match_802154, match_ble_pdu, match_reception, unpack_table
from pfdoa.protocol.messages import RadioTx, RssiReport
from pfdoa.protocol.peers import anchor_frame
from pfdoa.protocol.script import run_script

pytestmark = pytest.mark.unit

PEER = json.loads((Path(__file__).resolve().parents[2] / "protocol" / "vectors" / "peer.json").read_text())


def ids(vs):
    return [v["name"] for v in vs]


@pytest.mark.parametrize("v", PEER["builds"], ids=ids(PEER["builds"]))
def test_builds(v):
    frame = anchor_frame(v["radio"], bytes.fromhex(v["address"]), v["anchor_id"], v["seq"])
    assert frame.hex() == v["frame"]
    # an anchor with an ANCHORS entry hears it as that anchor, with that seq
    table = [BeaconFilter(), BeaconFilter.anchors(100), BeaconFilter(), BeaconFilter()]
    m = (match_ble_pdu if v["radio"] == defs.RADIO_BLE else match_802154)(table, frame)
    assert m == PeerMatch(1, v["seq"], v["anchor_id"])


def test_build_by_hand():
    # SPEC 6.1: ADV_NONCONN_IND with TxAdd (0x42), length 6 + 12, AdvA, Flags 02 01 06, then
    # 08 FF FF FF 'P' 'N' seq(LE) id.
    frame = anchor_frame(defs.RADIO_BLE, bytes.fromhex("a00000000005"), 5, 0x0102)
    assert frame == bytes.fromhex("4212" "a00000000005" "020106" "08ffffff" "504e" "0201" "05")
    # IEEE 802.15.4: FCF 41 C8, MAC seq = seq & 0xFF, PAN FFFF, dst FFFF, the extended source
    # address, the same payload.
    frame = anchor_frame(defs.RADIO_IEEE802154, bytes(range(8)), 9, 0x1234)
    assert frame == bytes.fromhex("41c8" "34" "ffff" "ffff" "0001020304050607" "504e" "3412" "09")
    with pytest.raises(ValueError):
        anchor_frame(defs.RADIO_BLE, bytes(6), defs.ANCHOR_BROADCAST, 0)
    with pytest.raises(ValueError):
        anchor_frame(defs.RADIO_IEEE802154, bytes(6), 1, 0)


@pytest.mark.parametrize("v", PEER["matches"], ids=ids(PEER["matches"]))
def test_matches(v):
    m = match_reception(unpack_table(bytes.fromhex(v["filters"])), v["input"], bytes.fromhex(v["data"]),
                        bytes.fromhex(v["adv_a"]))
    got = None if m is None else {"index": m.index, "seq": m.seq,
                                  "peer": m.peer if isinstance(m, PeerMatch) else None}
    assert got == v["match"]


@pytest.mark.parametrize("v", PEER["entries"], ids=ids(PEER["entries"]))
def test_entries(v):
    f = BeaconFilter.unpack(bytes.fromhex(v["entry"]))
    assert f.is_valid() == v["valid"] and f.pack().hex() == v["entry"]


@pytest.mark.parametrize("v", PEER["vectors"], ids=ids(PEER["vectors"]))
def test_scripts(v):
    assert run_script(v["init"], v["script"]) == v["expected"]
    anchor = v["init"]["anchor_id"]
    for line in v["expected"]:
        kind, *rest = line.split()
        if kind == "T":  # what it sent is an advertisement of its own id
            frame = bytes.fromhex(rest[0])
            table = [BeaconFilter.anchors(1)] + [BeaconFilter()] * 3
            m = (match_ble_pdu if v["init"]["peer_radio"] == "ble" else match_802154)(table, frame)
            assert isinstance(m, PeerMatch) and m.peer == anchor
            continue
        if kind == "U":
            out = StreamDecoder().feed(bytes.fromhex(rest[0]))
            assert len(out) == 1 and out[0].anchor_id == anchor
            msg = out[0].message
        else:
            d = decode_can(int(rest[0], 16), bytes.fromhex(rest[1]))
            assert not isinstance(d, str)
            msg = d.message
        if isinstance(msg, RssiReport) and msg.peer is not None:
            # a peer reading: another anchor, one reading, its raw RSSI plus the offset
            assert msg.peer != anchor and 0 <= msg.peer <= defs.ANCHOR_ID_MAX
            assert not msg.flags & (defs.FLAG_NO_SEQ | defs.FLAG_SPIKE | defs.FLAG_RESET)
            if msg.n_readings is not None:
                assert msg.n_readings == 1


def _model(**kw):
    return AnchorModel(5, peer_radio=(defs.RADIO_BLE, bytes(6)), **kw)


def test_peer_report_values_by_hand():
    a = _model()
    a.poll(0)
    a.uart_rx(1, encode_uart(BeaconFilter.anchors(1000).set_message(1, 2), 5))
    out = a.ble_pdu(10, -70, 37, anchor_frame(defs.RADIO_BLE, bytes(6), 3, 7))
    (d,) = StreamDecoder().feed(out[0])
    m = d.message
    assert (m.seq, m.tick_ms, m.rssi_q8, m.raw_dbm, m.n_readings, m.channel, m.flags, m.beacon) == \
        (7, 10, -70 * 256, -70, 1, 37, 0, 128 + 3)
    # no EMA: the next reading is reported as it is
    out = a.ble_pdu(11, -60, 38, anchor_frame(defs.RADIO_BLE, bytes(6), 3, 7))
    assert StreamDecoder().feed(out[0])[0].message.rssi_q8 == -60 * 256


def test_sending_follows_the_first_anchors_entry():
    a = _model(filters=[BeaconFilter.pfdoa(0), BeaconFilter.anchors(300), BeaconFilter.anchors(50),
                        BeaconFilter()])
    sent = [t for t in range(0, 1000, 10) for u in a.poll(t) if isinstance(u, Transmitted)]
    assert sent == [0, 300, 600, 900]
    # without an ANCHORS entry nothing is sent; without a radio neither
    assert not any(isinstance(u, Transmitted) for t in range(0, 3000, 100) for u in AnchorModel(
        5, peer_radio=(defs.RADIO_BLE, bytes(6))).poll(t))
    quiet = AnchorModel(5, filters=[BeaconFilter.anchors(10)] + [BeaconFilter()] * 3)
    assert not any(isinstance(u, Transmitted) for t in range(0, 100, 5) for u in quiet.poll(t))


def test_radio_tx_message():
    frame = anchor_frame(defs.RADIO_BLE, bytes(6), 3, 1)
    msg = RadioTx(123, defs.RADIO_BLE, len(frame), frame)
    (d,) = StreamDecoder(types={defs.MSG_RADIO_TX}).feed(encode_uart(msg, 3))
    assert d.message.sent == frame and d.message.tick_ms == 123
    assert RadioTx(0, 0, 40, b"").sent == b""  # a length past the field: nothing
