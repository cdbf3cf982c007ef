"""Every golden vector in protocol/vectors/ passes in Python, and the files are current."""

import importlib.util
import json
from pathlib import Path

import pytest

from pfdoa.protocol import (
    BY_NAME,
    BeaconFilter,
    CobsError,
    Match,
    StreamDecoder,
    beacons,
    cobs_decode,
    cobs_encode,
    crc16,
    decode_can,
    decode_frame,
    default_table,
    defs,
    encode_can,
    encode_raw,
    encode_uart,
    match_802154,
    match_ble_pdu,
)
from pfdoa.protocol.anchor_model import ema_step_q8, fold_q8
from pfdoa.protocol.filters import match_reception, unpack_table
from pfdoa.protocol.script import run_script
from pfdoa.protocol.uart import HOST_TO_ANCHOR

ROOT = Path(__file__).resolve().parents[2]
VEC = ROOT / "protocol" / "vectors"
ANCHOR_TYPES = HOST_TO_ANCHOR - defs.TEST_ONLY
BYTE_FIELDS = ("match", "frame")


def load(name):
    return json.loads((VEC / name).read_text())


def ids(vs):
    return [v["name"] for v in vs]


def test_vectors_are_current_and_plentiful():
    spec = importlib.util.spec_from_file_location("gen_vectors", ROOT / "protocol" / "gen_vectors.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    built = gen.build()
    total = 0
    for fname, doc in built.items():
        assert (VEC / fname).read_text() == gen.render(doc), f"{fname} stale: run gen_vectors.py"
        for value in doc.values():
            if isinstance(value, list):
                total += len(value)
                assert len({v.get("name", json.dumps(v)) for v in value}) == len(value)
    assert total >= 30


@pytest.mark.parametrize("v", load("crc.json")["vectors"], ids=ids(load("crc.json")["vectors"]))
def test_crc(v):
    assert crc16(bytes.fromhex(v["data"])) == v["crc"]
    if "crc_extra" in v:
        assert (v["crc"] & 0xFF) ^ (v["crc"] >> 8) == v["crc_extra"]


@pytest.mark.parametrize("v", load("cobs.json")["vectors"], ids=ids(load("cobs.json")["vectors"]))
def test_cobs(v):
    d, e = bytes.fromhex(v["decoded"]), bytes.fromhex(v["encoded"])
    assert cobs_encode(d) == e
    assert cobs_decode(e) == d


@pytest.mark.parametrize("v", load("cobs.json")["errors"], ids=ids(load("cobs.json")["errors"]))
def test_cobs_errors(v):
    with pytest.raises(CobsError):
        cobs_decode(bytes.fromhex(v["encoded"]))


def _fields(msg):
    return {f: (getattr(msg, f).hex() if f in BYTE_FIELDS else getattr(msg, f))
            for f in msg.__slots__ if getattr(msg, f) is not None}


def _message(name, fields):
    return BY_NAME[name](**{k: (bytes.fromhex(v) if k in BYTE_FIELDS else v) for k, v in fields.items()})


@pytest.mark.parametrize("v", load("uart.json")["vectors"], ids=ids(load("uart.json")["vectors"]))
def test_uart(v):
    msg = _message(v["message"], v["fields"])
    assert msg.layout(v["version"]).type == v["type"]
    assert encode_raw(msg, v["anchor_id"], v["version"]).hex() == v["raw"]
    frame = bytes.fromhex(v["frame"])
    assert encode_uart(msg, v["anchor_id"], v["version"]) == frame
    out = StreamDecoder().feed(frame)
    assert len(out) == 1
    assert out[0].anchor_id == v["anchor_id"]
    assert out[0].message.NAME == v["message"] and _fields(out[0].message) == v["fields"]
    # A version-2 anchor decodes only version 2 (SPEC 8.1).
    anchor_view = decode_frame(frame[:-1], versions=(defs.PROTO_VERSION,))
    assert (anchor_view == "bad_version") == (v["version"] == defs.V1_PROTO_VERSION)


@pytest.mark.parametrize("v", load("can.json")["vectors"], ids=ids(load("can.json")["vectors"]))
def test_can(v):
    fields = dict(v["fields"])
    if v["message"] == "RSSI_REPORT":
        fields.setdefault("tick_ms", None)
        fields.setdefault("n_readings", None)
        fields.setdefault("channel", None)
    msg = BY_NAME[v["message"]](**fields)
    frames = [(int(f["id"], 16), bytes.fromhex(f["data"])) for f in v["frames"]]
    assert encode_can(msg, v["anchor_id"], v["version"]) == frames
    decoded = [decode_can(i, d) for i, d in frames]
    assert all(d.anchor_id == v["anchor_id"] for d in decoded)
    merged = {}
    for d in decoded:
        merged.update(_fields(d.message))
    assert merged == v["fields"]


INVALID = load("uart_invalid.json")


@pytest.mark.parametrize("v", INVALID["vectors"], ids=ids(INVALID["vectors"]))
def test_uart_invalid(v):
    types = ANCHOR_TYPES if v["receiver"] == "anchor" else None
    versions = (defs.PROTO_VERSION,) if v["receiver"] == "anchor" else None
    frame = bytes.fromhex(v["frame"])
    assert decode_frame(frame, types, versions) == v["error"]
    if 0 in frame:
        return  # on a stream the zero is a delimiter: that is two frames, not this one
    dec = StreamDecoder(types, versions)
    assert dec.feed(frame + b"\x00") == []
    assert dec.counters[v["error"]] == 1
    assert sum(dec.counters[e] for e in defs.ERRORS) == 1


@pytest.mark.parametrize("v", INVALID["streams"], ids=ids(INVALID["streams"]))
def test_uart_streams(v):
    stream = bytes.fromhex(v["stream"])
    for chunk in (len(stream), 1, 7):
        dec = StreamDecoder()
        out = []
        for i in range(0, len(stream), chunk):
            out += dec.feed(stream[i:i + chunk])
        assert [{"anchor_id": d.anchor_id, "message": d.message.NAME, "fields": _fields(d.message)}
                for d in out] == v["decoded"]
        assert dec.counters == v["counters"]


CAN_INVALID = load("can_invalid.json")["vectors"]


@pytest.mark.parametrize("v", CAN_INVALID, ids=ids(CAN_INVALID))
def test_can_invalid(v):
    assert decode_can(int(v["id"], 16), bytes.fromhex(v["data"])) == v["error"]
    assert decode_can(int(v["id"], 16), bytes.fromhex(v["data"]), versions=(defs.PROTO_VERSION,)) == v["error_v2"]


def test_qformat():
    q = load("qformat.json")
    for v in q["fold"]:
        assert fold_q8(sum(v["readings"]), len(v["readings"])) == v["mean_q8"]
        # round half up of the exact mean, by exact rational arithmetic
        from fractions import Fraction
        exact = Fraction(256 * sum(v["readings"]), len(v["readings"]))
        assert v["mean_q8"] == (exact + Fraction(1, 2)).__floor__()
    for v in q["ema"]:
        assert ema_step_q8(v["ema_q8"], v["mean_q8"], v["alpha_q8"]) == v["result"]
        inc = Fraction(v["alpha_q8"] * (v["mean_q8"] - v["ema_q8"]), 256)
        assert v["result"] == v["ema_q8"] + (inc + Fraction(1, 2)).__floor__()


BEACON = load("beacon.json")


@pytest.mark.parametrize("v", BEACON["builds"], ids=ids(BEACON["builds"]))
def test_beacon_builds(v):
    adv = beacons.pfdoa_adv_data(v["seq"], v["beacon_id"])
    assert adv.hex() == v["adv_data"]
    assert beacons.adv_pdu(bytes.fromhex(v["adv_a"]), adv).hex() == v["pdu"]
    assert beacons.pfdoa_802154_frame(v["seq"], v["beacon_id"], bytes.fromhex(v["ext_addr"]),
                                      v["pan_id"]).hex() == v["mpdu"]
    # and an anchor with the default table reads them back (id 0) or not (another id)
    want = Match(0, v["seq"]) if v["beacon_id"] == 0 else None
    assert match_ble_pdu(default_table(), bytes.fromhex(v["pdu"])) == want
    assert match_802154(default_table(), bytes.fromhex(v["mpdu"])) == want


@pytest.mark.parametrize("v", BEACON["matches"], ids=ids(BEACON["matches"]))
def test_beacon_matches(v):
    m = match_reception(unpack_table(bytes.fromhex(v["filters"])), v["input"], bytes.fromhex(v["data"]),
                        bytes.fromhex(v["adv_a"]))
    assert (None if m is None else {"index": m.index, "seq": m.seq}) == v["match"]


@pytest.mark.parametrize("v", BEACON["entries"], ids=ids(BEACON["entries"]))
def test_beacon_filter_entries(v):
    f = BeaconFilter.unpack(bytes.fromhex(v["entry"]))
    assert f.is_valid() == v["valid"] and f.pack().hex() == v["entry"]


ANCHOR = load("anchor.json")["vectors"]


@pytest.mark.parametrize("v", ANCHOR, ids=ids(ANCHOR))
def test_anchor(v):
    assert run_script(v["init"], v["script"]) == v["expected"]
    # Every emitted UART/CAN frame is valid for a gateway.
    for line in v["expected"]:
        kind, *rest = line.split()
        if kind == "U":
            out = StreamDecoder().feed(bytes.fromhex(rest[0]))
            assert len(out) == 1 and out[0].anchor_id == v["init"]["anchor_id"]
        else:
            d = decode_can(int(rest[0], 16), bytes.fromhex(rest[1]))
            assert not isinstance(d, str) and d.anchor_id == v["init"]["anchor_id"]
