"""The protocol package as the gateway side uses it for several beacons (issue 16): filter
types and their FILTER_SET, the reference anchor's FILTER_ACK, reports carrying the beacon
index from both protocol versions, and STATUS with the table hash."""

import pytest

from pfdoa.protocol import (
    BeaconFilter,
    Decoded,
    FilterAck,
    FilterSet,
    RssiReport,
    Status,
    StreamDecoder,
    beacons,
    decode_can,
    decode_frame,
    default_table,
    defs,
    encode_can,
    encode_uart,
    table_hash,
)
from pfdoa.protocol.anchor_model import AnchorModel
from pfdoa.protocol.filters import match_ble_adv, pack_table, unpack_table

UUID = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"


def test_constructors_lay_out_the_match_bytes():
    ib = BeaconFilter.ibeacon(UUID, 1, 0x0203, period_ms=100)
    assert ib.kind == defs.FILTER_IBEACON and ib.is_valid() and not ib.has_seq
    assert ib.match[:16] == bytes.fromhex(UUID.replace("-", "")) and ib.match[16:20] == b"\x00\x01\x02\x03"
    assert BeaconFilter.ibeacon(bytes.fromhex(UUID.replace("-", "")), 1, 0x0203, 100) == ib
    ed = BeaconFilter.eddystone_uid("00112233445566778899", "aabbccddeeff", 250)
    assert ed.match[:16].hex() == "00112233445566778899aabbccddeeff" and ed.is_valid()
    assert BeaconFilter.altbeacon(bytes(range(20)), 50).match == bytes(range(20))
    # MAC addresses as printed (most significant first) are stored in air order.
    assert BeaconFilter.mac48("C0:FF:EE:00:00:01", 30).match[:6] == bytes.fromhex("010000eeffc0")
    assert BeaconFilter.mac64("01-02-03-04-05-06-07-08", 30).match[:8] == bytes.fromhex("0807060504030201")
    ours = BeaconFilter.pfdoa(3)
    assert ours.has_seq and ours.period_ms == 0 and ours.match[0] == 3 and ours.is_valid()
    assert ours.describe() == "pfdoa 03" and ib.describe().endswith("every 100 ms")
    for bad in (lambda: BeaconFilter.ibeacon("00", 1, 2, 100), lambda: BeaconFilter.mac48("01:02", 30),
                lambda: BeaconFilter.eddystone_uid("00" * 10, "00" * 5, 30),
                lambda: BeaconFilter.altbeacon(bytes(19), 30), lambda: BeaconFilter(1, 0, bytes(21))):
        with pytest.raises(ValueError):
            bad()


def test_validity_rules():
    assert not BeaconFilter.ibeacon(UUID, 1, 2, period_ms=0).is_valid()  # no sequence: needs a period
    assert not BeaconFilter(defs.FILTER_PFDOA, 10, b"\x01").is_valid()  # ours: no period
    assert not BeaconFilter(defs.FILTER_MAC48, 10, bytes(6) + b"\x01").is_valid()  # unused bytes non-zero
    assert not BeaconFilter(defs.FILTER_ANCHORS + 1, 10).is_valid()  # no such kind
    assert BeaconFilter.none().is_valid() and not BeaconFilter(defs.FILTER_NONE, 5).is_valid()


def test_table_pack_hash_and_default():
    t = default_table()
    assert len(t) == defs.BEACON_SLOTS and t[0] == BeaconFilter.pfdoa(defs.FILTER_DEFAULT_ID)
    assert all(f == BeaconFilter.none() for f in t[1:])
    assert pack_table(t) == defs.FILTER_TABLE_DEFAULT
    assert table_hash(t) == defs.FILTER_TABLE_DEFAULT_HASH
    t2 = (t[0], BeaconFilter.ibeacon(UUID, 1, 2, 100), t[2], t[3])
    assert unpack_table(pack_table(t2)) == t2 and table_hash(t2) != table_hash(t)
    with pytest.raises(ValueError):
        pack_table(t[:3])


def test_filter_set_to_the_reference_anchor_and_its_ack():
    # What `pfdoa anchors` will do: send FILTER_SET, read FILTER_ACK, compare the hash.
    ib = BeaconFilter.ibeacon(UUID, 1, 2, 100)
    msg = ib.set_message(token=9, index=2)
    assert isinstance(msg, FilterSet) and BeaconFilter.of_message(msg) == ib
    wire = encode_uart(msg, 5)
    d = decode_frame(wire[:-1])
    assert isinstance(d, Decoded) and d.anchor_id == 5 and d.message == msg
    m = AnchorModel(5)
    out = m.uart_rx(0, wire)
    dec = StreamDecoder()
    acks = [x.message for x in dec.feed(b"".join(out)) if isinstance(x.message, FilterAck)]
    want = table_hash((default_table()[0], default_table()[1], ib, default_table()[3]))
    assert acks == [FilterAck(9, defs.ACK_OK, 2, want)]
    # STATUS then carries the same hash and the table size.
    status = [x.message for x in dec.feed(b"".join(m.poll(0))) if isinstance(x.message, Status)]
    assert status[0].filter_hash == want and status[0].filter_slots == defs.BEACON_SLOTS
    assert status[0].version == defs.PROTO_VERSION
    # An invalid entry is refused with the hash unchanged.
    bad = BeaconFilter(defs.FILTER_IBEACON, 0, ib.match).set_message(10, 1)
    acks = [x.message for x in dec.feed(b"".join(m.uart_rx(1, encode_uart(bad, 5))))]
    assert acks == [FilterAck(10, defs.ACK_INVALID, 1, want)]
    # FILTER_SET has no CAN mapping (SPEC 4).
    with pytest.raises(ValueError):
        encode_can(msg, 5)


def test_reports_say_which_beacon_in_both_versions():
    v2 = RssiReport(7, 1000, -16000, -62, 2, 38, defs.FLAG_NO_SEQ, beacon=2)
    assert not v2.has_seq
    d = decode_frame(encode_uart(v2, 4)[:-1])
    assert d.message.beacon == 2 and d.message.flags & defs.FLAG_NO_SEQ
    # A version-1 anchor's report: beacon entry 0, with a sequence number.
    v1 = RssiReport(7, 1000, -16000, -62, 2, 38, defs.FLAG_RESET)
    d1 = decode_frame(encode_uart(v1, 4, version=defs.V1_PROTO_VERSION)[:-1])
    assert d1.message.beacon == 0 and d1.message.has_seq and d1.message == v1
    # CAN: the DLC tells the versions apart.
    (cid, data), = encode_can(v2, 4)
    assert len(data) == defs.CAN_RSSI_REPORT_DLC and decode_can(cid, data).message.beacon == 2
    (cid1, data1), = encode_can(v1, 4, version=defs.V1_PROTO_VERSION)
    assert decode_can(cid1, data1).message.beacon == 0
    # A version-1 STATUS is recognisable as such (its defs_hash is version 1's).
    s1 = decode_frame(encode_uart(Status(1, 0, 5, 1, 0, 0, 0, defs.V1_DEFS_HASH), 4,
                                  version=defs.V1_PROTO_VERSION)[:-1]).message
    assert s1.version == defs.V1_PROTO_VERSION and s1.defs_hash == defs.V1_DEFS_HASH


def test_the_model_matches_standard_beacons_by_table():
    ib = BeaconFilter.ibeacon(UUID, 1, 2, 100)
    table = (BeaconFilter.pfdoa(0), BeaconFilter.pfdoa(1), ib, BeaconFilter.none())
    adv_a = bytes(range(6))
    assert match_ble_adv(table, adv_a, beacons.pfdoa_adv_data(44, 1)) == (1, 44)
    m = match_ble_adv(table, adv_a, beacons.ibeacon_adv_data(bytes.fromhex(UUID.replace("-", "")), 1, 2))
    assert m is not None and m.index == 2 and m.seq is None
    assert match_ble_adv(table, adv_a, beacons.pfdoa_adv_data(44, 2)) is None
