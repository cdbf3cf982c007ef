# Every golden vector of protocol/vectors/*.json (README there) run against the
# MicroPython anchor core: one test case per vector.
import json
import struct

import pfdoa_auth as A
import pfdoa_beacon as B
import pfdoa_defs as D
import pfdoa_match as M
import pfdoa_wire as W
import anchor_script
from pfdoa_anchor import PEER_FRAME_MAX, ema_step_q8, fold_q8, peer_frame

_ERR = {"overlong": D.ERR_OVERLONG, "bad_cobs": D.ERR_BAD_COBS,
        "truncated": D.ERR_TRUNCATED, "bad_version": D.ERR_BAD_VERSION,
        "unknown_type": D.ERR_UNKNOWN_TYPE, "bad_length": D.ERR_BAD_LENGTH,
        "bad_crc": D.ERR_BAD_CRC, "bad_anchor": D.ERR_BAD_ANCHOR}

# name -> (type, payload len, crc_extra, to_host, UART format, CAN encodings): version 2
_MSG = {
    "RSSI_REPORT": (D.MSG_RSSI_REPORT, D.MSG_RSSI_REPORT_LEN, D.MSG_RSSI_REPORT_CRC_EXTRA, 1,
                    D.MSG_RSSI_REPORT_FMT,
                    ((D.CAN_RSSI_REPORT, D.CAN_RSSI_REPORT_FMT, ("seq", "rssi_q8", "raw_dbm", "flags", "beacon")),)),
    "STATUS": (D.MSG_STATUS, D.MSG_STATUS_LEN, D.MSG_STATUS_CRC_EXTRA, 1, D.MSG_STATUS_FMT,
               ((D.CAN_STATUS_A, D.CAN_STATUS_A_FMT,
                 ("fw_major", "fw_minor", "uptime_s", "config_hash")),
                (D.CAN_STATUS_B, D.CAN_STATUS_B_FMT,
                 ("dropped_events", "rx_errors", "spikes", "defs_hash")),
                (D.CAN_STATUS_C, D.CAN_STATUS_C_FMT, ("filter_hash", "filter_slots")))),
    "CONFIG_SET": (D.MSG_CONFIG_SET, D.MSG_CONFIG_SET_LEN, D.MSG_CONFIG_SET_CRC_EXTRA, 0,
                   D.MSG_CONFIG_SET_FMT,
                   ((D.CAN_CONFIG_SET, D.MSG_CONFIG_SET_FMT,
                     ("token", "offset_q8", "alpha_q8", "spike_db", "report_mode",
                      "decimation")),)),
    "CONFIG_ACK": (D.MSG_CONFIG_ACK, D.MSG_CONFIG_ACK_LEN, D.MSG_CONFIG_ACK_CRC_EXTRA, 1,
                   D.MSG_CONFIG_ACK_FMT,
                   ((D.CAN_CONFIG_ACK, D.MSG_CONFIG_ACK_FMT, ("token", "result", "config_hash")),)),
    "FILTER_SET": (D.MSG_FILTER_SET, D.MSG_FILTER_SET_LEN, D.MSG_FILTER_SET_CRC_EXTRA, 0,
                   D.MSG_FILTER_SET_FMT, ()),
    "FILTER_ACK": (D.MSG_FILTER_ACK, D.MSG_FILTER_ACK_LEN, D.MSG_FILTER_ACK_CRC_EXTRA, 1,
                   D.MSG_FILTER_ACK_FMT, ()),
    "RADIO_INJECT": (D.MSG_RADIO_INJECT, D.MSG_RADIO_INJECT_LEN, D.MSG_RADIO_INJECT_CRC_EXTRA,
                     0, D.MSG_RADIO_INJECT_FMT, ()),
    "RADIO_INJECT_RAW": (D.MSG_RADIO_INJECT_RAW, D.MSG_RADIO_INJECT_RAW_LEN,
                         D.MSG_RADIO_INJECT_RAW_CRC_EXTRA, 0, D.MSG_RADIO_INJECT_RAW_FMT, ()),
}
_BYTES = ("match", "frame")  # u8[N] fields: hex in the vectors


def _load(name):
    import run_tests
    with open(run_tests.ROOT + "protocol/vectors/" + name + ".json") as f:
        return json.load(f)


def _field_names():
    import run_tests
    with open(run_tests.ROOT + "protocol/messages.json") as f:
        m = json.load(f)
    return {msg["name"]: [fl["name"] for fl in msg["fields"]] for msg in m["messages"]
            if D.PROTO_VERSION in msg["versions"]}


def _tables(receiver):
    plen = bytearray(b"\xff" * 256)
    extra = bytearray(256)
    to_host = bytearray(256)
    for name, (t, n, x, th, fmt, can) in _MSG.items():
        extra[t] = x
        to_host[t] = th
        if receiver == "host" or name in ("CONFIG_SET", "FILTER_SET"):  # "host": every type
            plen[t] = n
    return plen, extra, to_host


class _Rx:
    def __init__(self, receiver, keep_errors=True):
        plen, extra, to_host = _tables(receiver)
        self.frames = []
        self.errors = []
        self.error_count = 0
        self._keep = keep_errors  # off: only counted (the exhaustive searches make 10^4-10^5)
        self.dec = W.FrameDecoder(plen, extra, to_host, self._frame, self._error)

    def _error(self, code):
        self.error_count += 1
        if self._keep:
            self.errors.append(code)

    def _frame(self, t, aid, payload, n):
        self.frames.append((t, aid, bytes(payload[:n])))


def _unhex(s):
    return bytes.fromhex(s)


def _case(fn, v):
    return lambda: fn(v)


# ---- checks, one per vector kind ----------------------------------------------------

def _crc(v):
    assert W.crc16(_unhex(v["data"])) == v["crc"], v["name"]
    if "crc_extra" in v:
        assert W.crc_extra(_unhex(v["data"]).decode()) == v["crc_extra"]


def _cobs(v):
    dec = _unhex(v["decoded"])
    enc = _unhex(v["encoded"])
    buf = bytearray(len(dec) + 2 + len(dec) // 254)
    n = W.cobs_encode(dec, len(dec), buf)
    assert bytes(buf[:n]) == enc, v["name"]
    out = bytearray(max(len(enc), 1))
    m = W.cobs_decode(enc, len(enc), out)
    assert m >= 0 and bytes(out[:m]) == dec, v["name"]


def _cobs_error(v):
    enc = _unhex(v["encoded"])
    assert W.cobs_decode(enc, len(enc), bytearray(len(enc) + 1)) < 0, v["name"]


_NAMES = None


def _values(msg, fields):
    global _NAMES
    if _NAMES is None:
        _NAMES = _field_names()
    return [_unhex(fields[k]) if k in _BYTES else fields[k] for k in _NAMES[msg]]


def _uart(v):
    if v["version"] != D.PROTO_VERSION:
        # A version-1 frame (a v1 anchor's): this version-2 receiver refuses it.
        rx = _Rx("host")
        rx.dec.feed(_unhex(v["frame"]))
        assert rx.errors == [D.ERR_BAD_VERSION] and rx.frames == [], v["name"]
        return
    t, n, x, th, fmt, can = _MSG[v["message"]]
    extra = bytearray(256)
    extra[t] = x
    enc = W.FrameEncoder(extra)
    struct.pack_into(fmt, enc.payload, 0, *_values(v["message"], v["fields"]))
    assert bytes(enc.finish(t, v["anchor_id"], n)) == _unhex(v["frame"]), v["name"]
    rx = _Rx("host")
    rx.dec.feed(_unhex(v["frame"]))
    assert rx.errors == [] and len(rx.frames) == 1, v["name"]
    ft, aid, payload = rx.frames[0]
    assert ft == t and aid == v["anchor_id"]
    assert list(struct.unpack(fmt, payload)) == _values(v["message"], v["fields"])
    raw = _unhex(v["raw"])  # the body
    assert raw[3:] == payload


def _can(v):
    if v["version"] != D.PROTO_VERSION:
        return  # a version-1 anchor's CAN frames: the gateway's business
    t, n, x, th, fmt, can = _MSG[v["message"]]
    got = []
    for can_type, cfmt, names in can:
        data = struct.pack(cfmt, *[v["fields"][k] for k in names])
        got.append({"id": "%03x" % W.can_id(can_type, v["anchor_id"]), "data": data.hex()})
    assert got == v["frames"], (v["name"], got)


def _uart_invalid(v):
    rx = _Rx(v["receiver"])
    rx.dec.check(_unhex(v["frame"]))
    # A frame the gateway checks as version 1 is refused by this version-2 receiver.
    want = D.ERR_BAD_VERSION if v["v1_frame"] else _ERR[v["error"]]
    assert rx.errors == [want] and rx.frames == [], (v["name"], rx.errors)
    if v["receiver"] == "anchor":  # and the anchor itself counts it, emitting nothing
        r = anchor_script.Runner({"anchor_id": 5}, [])
        r.anchor._dec.check(_unhex(v["frame"]))
        a = r.anchor
        assert r.out == [] and a.rx_errors == 1, v["name"]
        assert a.rx_error_kinds[-1 - want] == 1, v["name"]


def _stream(v):
    if v["v1_frames"]:
        return  # the gateway's two-version streams
    rx = _Rx(v["receiver"])
    rx.dec.feed(_unhex(v["stream"]))
    names = {m[0]: k for k, m in _MSG.items()}
    got = [{"anchor_id": aid, "message": names[t],
            "fields": dict(zip(_field_names()[names[t]], [x.hex() if isinstance(x, bytes) else x
                                                         for x in struct.unpack(_MSG[names[t]][4], p)]))}
           for t, aid, p in rx.frames]
    assert got == v["decoded"], v["name"]
    c = v["counters"]
    for name, code in _ERR.items():
        assert rx.errors.count(code) == c[name], (v["name"], name)
    assert len(rx.frames) == c["frames_ok"]


def _can_invalid(v):
    # The anchor's side: only CONFIG_SET ids it accepts reach it; a wrong DLC counts.
    aid = int(v["id"], 16) & D.CAN_ANCHOR_MASK
    if aid == D.ANCHOR_BROADCAST:
        aid = 5
    r = anchor_script.Runner({"anchor_id": aid, "transport": "can"}, [])
    data = _unhex(v["data"])
    r.anchor.can_rx(int(v["id"], 16), data)
    accepted = (int(v["id"], 16) >> D.CAN_ANCHOR_BITS) == D.CAN_CONFIG_SET
    assert r.anchor.rx_errors == (1 if accepted and v["error_v2"] == "bad_length" else 0), v["name"]
    assert r.out == []


def _fold(v):
    rs = v["readings"]
    assert fold_q8(sum(rs), len(rs)) == v["mean_q8"], rs


def _ema(v):
    assert ema_step_q8(v["ema_q8"], v["mean_q8"], v["alpha_q8"]) == v["result"], v


def _anchor(v):
    out = anchor_script.run(v["init"], v["script"])
    assert out == v["expected"], (v["name"], out, v["expected"])


def _beacon_build(v):
    adv = B.adv_data(v["seq"], v["beacon_id"])
    assert bytes(adv) == _unhex(v["adv_data"]), v["name"]
    assert bytes(B.adv_pdu(_unhex(v["adv_a"]), adv)) == _unhex(v["pdu"]), v["name"]
    assert bytes(B.mpdu(v["seq"], v["beacon_id"], _unhex(v["ext_addr"]), v["pan_id"])) == _unhex(v["mpdu"])


def _beacon_match(v):
    t = bytearray(_unhex(v["filters"]))
    data = _unhex(v["data"])
    if v["input"] == "adv":
        m = M.match_adv(t, _unhex(v["adv_a"]), 0, data, 0, len(data))
    elif v["input"] == "pdu":
        m = M.match_pdu(t, data, len(data))
    else:
        m = M.match_802154(t, data, len(data))
    got = None if m < 0 else {"index": M.index(m), "seq": (m & 0xFFFF) if (m >> 16) & 1 else None}
    if got is not None and "peer" in v["match"]:  # peer.json: the anchor an ANCHORS entry heard
        got["peer"] = None if M.peer(m) < 0 else M.peer(m)
    assert got == v["match"], (v["name"], got)


def _beacon_entry(v):
    assert M.entry_valid(_unhex(v["entry"])) == v["valid"], v["name"]


def _sha256(v):
    # The port's hashlib.sha256 (which pfdoa_auth's HMAC stands on) against FIPS 180-4.
    import hashlib
    h = hashlib.sha256()
    data = _unhex(v["data"])
    for _ in range(v["repeat"]):
        h.update(data)
    assert h.digest() == _unhex(v["digest"]), v["name"]


def _hmac(v):
    assert A.Key(_unhex(v["key"])).hmac(_unhex(v["data"])) == _unhex(v["mac"]), v["name"]


def _auth_derive(v):
    key = _unhex(v["key"])
    rid, adv_a, ext, pad = A.derive(A.Key(key), v["counter"])
    assert (rid, adv_a, ext, pad) == (_unhex(v["rid"]), _unhex(v["adv_a"]), _unhex(v["ext_addr"]), v["pad"]), v["name"]
    assert A.key_check(key) == _unhex(v["key_check"]), v["name"]


def _auth_build(v):
    k = A.Key(_unhex(v["key"]))
    ids = A.derive(k, v["counter"])
    assert A.tag(k, v["counter"], v["seq"]) == _unhex(v["tag"]), v["name"]
    assert bytes(A.payload(k, v["counter"], v["seq"], ids)) == _unhex(v["payload"]), v["name"]
    adv = B.auth_adv_data(k, ids, v["counter"], v["seq"])
    assert bytes(adv) == _unhex(v["adv_data"]), v["name"]
    assert bytes(B.adv_pdu(ids[1], adv)) == _unhex(v["pdu"]), v["name"]
    assert bytes(B.auth_mpdu(k, ids, v["counter"], v["seq"], v["pan_id"])) == _unhex(v["mpdu"]), v["name"]


_RESULTS = {"none": D.AUTH_NONE, "accept": D.AUTH_ACCEPT, "bad_tag": D.AUTH_BAD_TAG,
            "stale": D.AUTH_STALE, "replayed": D.AUTH_REPLAYED}


def _auth_verify(v):
    ver = A.Verifier(_unhex(v["key"]))
    for i, st in enumerate(v["steps"]):
        res = ver.verify(_unhex(st["payload"]), 0, st["tick"])
        assert res == _RESULTS[st["result"]], (v["name"], i, res)
        if res != D.AUTH_NONE:
            assert (ver.seq, ver.counter) == (st["seq"], st["counter"]), (v["name"], i)


def _peer_build(v):
    out = bytearray(PEER_FRAME_MAX)
    n = peer_frame(v["radio"], _unhex(v["address"]), v["anchor_id"], v["seq"], out)
    assert bytes(out[:n]) == _unhex(v["frame"]), v["name"]


_PLAN = (
    ("auth", "sha256", _sha256),
    ("auth", "hmac", _hmac),
    ("auth", "derive", _auth_derive),
    ("auth", "builds", _auth_build),
    ("auth", "verify", _auth_verify),
    ("crc", "vectors", _crc),
    ("cobs", "vectors", _cobs),
    ("cobs", "errors", _cobs_error),
    ("qformat", "fold", _fold),
    ("qformat", "ema", _ema),
    ("uart", "vectors", _uart),
    ("uart_invalid", "vectors", _uart_invalid),
    ("uart_invalid", "streams", _stream),
    ("can", "vectors", _can),
    ("can_invalid", "vectors", _can_invalid),
    ("anchor", "vectors", _anchor),
    ("beacon", "builds", _beacon_build),
    ("beacon", "matches", _beacon_match),
    ("beacon", "entries", _beacon_entry),
    ("peer", "builds", _peer_build),
    ("peer", "matches", _beacon_match),
    ("peer", "entries", _beacon_entry),
    ("peer", "vectors", _anchor),
)


def _flip(b, bit):
    b[bit >> 3] ^= 0x80 >> (bit & 7)


def _exhaustive(v):
    # SPEC 2.4: every 1- and 2-bit error of the frame, delimiter included, with a delimiter
    # before and after; a receiver that knows every type must accept none of them.
    rx = _Rx("host", keep_errors=False)
    wire = bytearray(_unhex(v["frame"]))
    rx.dec.feed(b"\x00" + wire + b"\x00")
    assert len(rx.frames) == (1 if v["version"] == D.PROTO_VERSION else 0), v["name"]
    rx.frames.clear()
    nbits = 8 * len(wire)
    patterns = 0
    zero = b"\x00"
    feed = rx.dec.feed
    for i in range(nbits):
        _flip(wire, i)
        feed(zero)
        feed(wire)
        feed(zero)
        patterns += 1
        for j in range(i + 1, nbits):
            _flip(wire, j)
            feed(wire)
            feed(zero)
            patterns += 1
            _flip(wire, j)
        _flip(wire, i)
    assert patterns == nbits * (nbits + 1) // 2
    assert rx.frames == [], (v["name"], rx.frames[:3])
    assert rx.error_count >= patterns


def cases():
    out = []
    for fname, key, fn in _PLAN:
        vs = _load(fname)[key]
        assert vs, fname + "." + key + " is empty"
        for i, v in enumerate(vs):
            out.append(("%s.%s[%s]" % (fname, key, v.get("name", i)), _case(fn, v)))
    for v in _load("uart")["vectors"]:
        out.append(("uart.json.exhaustive_1_2_bits[%s]" % v["name"], _case(_exhaustive, v)))
    return out
