"""Our authenticated rolling beacon (protocol/SPEC.md 9) in the Python reference: the golden
vectors, published values re-checked by hand, the verifier's window, keys kept out of
reprs, and the privacy claim: captures of one beacon a minute apart share no identifier
or address, and are no more alike than captures of two different beacons."""

from __future__ import annotations

import hashlib
import hmac
import json
import random
from pathlib import Path

import pytest

from pfdoa.protocol import auth, beacons, crc16, defs
from pfdoa.protocol.filters import (
    BeaconFilter,
    auth_payload_802154,
    auth_payload_ble_adv,
    auth_payload_ble_pdu,
    match_ble_pdu,
    pack_table,
    split_ble_pdu,
    table_hash,
)

pytestmark = pytest.mark.unit

VECTORS = json.loads((Path(__file__).resolve().parents[2] / "protocol" / "vectors" / "auth.json").read_text())
RESULTS = {v: k for k, v in auth.RESULT_NAMES.items()}


def test_published_values_by_hand():
    # FIPS 180-4 (NIST example "abc") and RFC 4231 test case 2, typed in from the documents.
    abc = next(v for v in VECTORS["sha256"] if v["name"] == "abc")
    assert abc["digest"] == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    jefe = next(v for v in VECTORS["hmac"] if v["name"] == "rfc4231_2")
    assert jefe["mac"] == "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
    million = next(v for v in VECTORS["sha256"] if v["name"] == "fips_million_a")
    assert million["digest"] == "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0"


@pytest.mark.parametrize("v", VECTORS["hmac"], ids=lambda v: v["name"])
def test_hmac_vectors(v):
    assert auth.hmac_sha256(bytes.fromhex(v["key"]), bytes.fromhex(v["data"])).hex() == v["mac"]


@pytest.mark.parametrize("v", VECTORS["derive"], ids=lambda v: v["name"])
def test_derive_vectors(v):
    ids = auth.derive(bytes.fromhex(v["key"]), v["counter"])
    assert (ids.rid.hex(), ids.adv_a.hex(), ids.ext_addr.hex(), ids.pad) == (v["rid"], v["adv_a"], v["ext_addr"], v["pad"])
    assert auth.key_check(bytes.fromhex(v["key"])).hex() == v["key_check"]
    assert ids.adv_a[5] >> 6 == 0  # non-resolvable private address (Core Spec Vol 6 Part B 1.3.2.2)
    assert ids.ext_addr[7] & 3 == 2  # locally administered unicast EUI-64


@pytest.mark.parametrize("v", VECTORS["builds"], ids=lambda v: v["name"])
def test_build_vectors_and_what_the_parsers_find(v):
    key, c, s = bytes.fromhex(v["key"]), v["counter"], v["seq"]
    payload = auth.payload(key, c, s)
    assert payload.hex() == v["payload"] and auth.tag(key, c, s).hex() == v["tag"]
    adv = beacons.pfdoa_auth_adv_data(key, c, s)
    assert adv.hex() == v["adv_data"] and len(adv) <= defs.BLE_ADV_DATA_MAX  # a legacy advertisement
    pdu = beacons.pfdoa_auth_pdu(key, c, s)
    mpdu = beacons.pfdoa_auth_802154_frame(key, c, s, v["pan_id"])
    assert (pdu.hex(), mpdu.hex()) == (v["pdu"], v["mpdu"])
    assert auth_payload_ble_adv(adv) == payload
    assert auth_payload_ble_pdu(pdu) == (auth.derive(key, c).adv_a, payload)
    assert auth_payload_802154(mpdu) == payload
    assert len(mpdu) + 2 <= 127  # with the FCS, an IEEE 802.15.4 frame (aMaxPhyPacketSize)
    f = auth.parse_payload(payload)
    assert f is not None and f.counter == c and f.eseq == s ^ auth.derive(key, c).pad


def test_verify_vector_steps():
    for v in VECTORS["verify"]:
        ver = auth.Verifier(bytes.fromhex(v["key"]))
        for i, st in enumerate(v["steps"]):
            got = ver.verify(auth.parse_payload(bytes.fromhex(st["payload"])), st["tick"])
            assert got.result == RESULTS[st["result"]], (i, st["comment"])
            if got.result != defs.AUTH_NONE:
                assert (got.seq, got.counter) == (st["seq"], st["counter"]), i
        seen = {st["result"] for st in v["steps"]}
        assert seen == set(auth.RESULT_NAMES.values())  # every verdict is exercised


def test_a_forger_without_the_key_never_gets_past_the_tag():
    """Any change of a captured payload's counter, eseq or tag is a bad tag or not this
    beacon's (the rid binds the counter): 2,000 random forgeries, none accepted."""
    key = bytes(range(16))
    rng = random.Random(7)
    good = bytearray(auth.payload(key, 1000, 5))
    ver = auth.Verifier(key)
    for _ in range(2000):
        p = bytearray(good)
        for _ in range(rng.randrange(1, 4)):
            i = rng.randrange(2, len(p))
            p[i] ^= 1 << rng.randrange(8)
        if p == good:
            continue
        res = ver.verify(auth.parse_payload(bytes(p)), 0).result
        assert res in (defs.AUTH_NONE, defs.AUTH_BAD_TAG)


def test_window_and_counter_clock():
    w = auth.Window()
    assert w.check(10, 1, 0) == defs.AUTH_ACCEPT
    assert w.check(10, 1, defs.EVENT_TIMEOUT_MS - 1) == defs.AUTH_ACCEPT  # the same advertising event
    assert w.check(10, 1, defs.EVENT_TIMEOUT_MS) == defs.AUTH_REPLAYED
    assert w.check(10, 1, 100, same_event_ms=None) == defs.AUTH_REPLAYED
    assert w.check(11, 0, 4096 * 5) == defs.AUTH_STALE  # 5 periods on the beacon is at 15: 11 + 2 < 15
    assert w.check(15, 0, 4096 * 5) == defs.AUTH_ACCEPT
    assert w.expected(4096 * 8) == 18
    assert w.check(15, 1, 4096 * 8) == defs.AUTH_STALE  # 15 + 2 < 18
    assert w.check(16, 1, 4096 * 8) == defs.AUTH_ACCEPT  # the oldest counter in the window, and newer
    assert w.check(16, 0, 4096 * 8 + 30) == defs.AUTH_REPLAYED  # in the window, older than the last
    assert w.check(99, 0, 4096 * 8 + 31) == defs.AUTH_ACCEPT  # any later counter: only the key makes one
    assert auth.counter_at(1_700_000_000_000) == 1_700_000_000_000 // 4096
    assert auth.seq_newer(0, 0xFFFF) and not auth.seq_newer(0xFFFF, 0) and not auth.seq_newer(5, 5)


def test_keys_never_in_a_repr_or_description():
    key = bytes.fromhex("00112233445566778899aabbccddeeff")
    f = BeaconFilter.pfdoa_auth(key)
    text = repr(f) + f.describe() + repr([f]) + str(f)
    for piece in (key.hex(), key.hex()[:8], repr(key)[2:12]):
        assert piece not in text
    assert f.describe().startswith("pfdoa_auth key check ")
    assert repr(BeaconFilter.pfdoa(3)).endswith("match=b'\\x03" + "\\x00" * 19 + "')")  # others unchanged
    # The table's hash covers the key check value: it changes with the key, and equals the
    # hash of the public form.
    other = BeaconFilter.pfdoa_auth(bytes(16))
    t = [f, BeaconFilter(), BeaconFilter(), BeaconFilter()]
    assert table_hash(t) == crc16(pack_table([f.public()] + t[1:])) != table_hash([other] + t[1:])
    assert f.public().match[:16] == auth.key_check(key) and f.public().match[16:] == bytes(4)
    with pytest.raises(ValueError):
        BeaconFilter.pfdoa_auth(bytes(15))


def test_the_pure_matchers_never_match_a_key_entry():
    key = bytes(range(16))
    pdu = beacons.pfdoa_auth_pdu(key, 5, 6)
    assert match_ble_pdu([BeaconFilter.pfdoa_auth(key), BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter()],
                         pdu) is None
    parts = split_ble_pdu(pdu)
    assert parts is not None and parts[0] == auth.derive(key, 5).adv_a


# ------------------------------------------------------------------------- privacy

FIELDS = ("rid", "adv_a", "ext_addr", "eseq", "tag")


def capture(key: bytes, unix_ms: int, seq: int) -> dict[str, bytes]:
    """What a listener records of one advertisement: every field that could name the beacon
    (the counter is the site's time, the same for every beacon)."""
    c = auth.counter_at(unix_ms)
    pdu = beacons.pfdoa_auth_pdu(key, c, seq)
    parts = split_ble_pdu(pdu)
    assert parts is not None
    p = auth.parse_payload(auth_payload_ble_adv(parts[1]) or b"")
    z = beacons.pfdoa_auth_802154_frame(key, c, seq)
    assert p is not None
    return {"rid": p.rid, "adv_a": parts[0], "ext_addr": z[7:15], "eseq": p.eseq.to_bytes(2, "little"),
            "tag": p.tag, "mac_seq": z[2:3]}


def test_two_captures_a_minute_apart_share_no_identifier_or_address():
    """2,000 beacons (random keys), each captured twice 60 s apart at a random time of day,
    its sequence number 600 advertisements on (100 ms interval): no identifier, address or
    sequence field repeats; per byte, the two captures agree no more often than chance."""
    rng = random.Random(52)
    equal_bytes = {f: 0 for f in FIELDS}
    total = {f: 0 for f in FIELDS}
    n = 2000
    for _ in range(n):
        key = rng.randbytes(16)
        t0 = rng.randrange(1_700_000_000_000, 1_800_000_000_000)
        seq = rng.randrange(65536)
        a, b = capture(key, t0, seq), capture(key, t0 + 60_000, (seq + 600) & 0xFFFF)
        for f in ("rid", "adv_a", "ext_addr", "tag"):
            assert a[f] != b[f], f
        for f in FIELDS:
            equal_bytes[f] += sum(x == y for x, y in zip(a[f], b[f]))
            total[f] += len(a[f])
    for f in FIELDS:
        rate = equal_bytes[f] / total[f]
        # Random bytes agree with probability 1/256 (the fixed bits of the address: 2 of its
        # 48 bits, and of the EUI-64: 2 of 64, push those up a little).
        assert rate < 0.008, (f, rate)


def test_a_listener_cannot_tell_the_same_beacon_from_another_one():
    """The best simple distinguisher - how many bytes of the identifying fields two captures
    share - scores pairs of one beacon (a minute apart) as it scores pairs of two beacons:
    the means differ by less than what 2 x 3,000 pairs can resolve."""
    rng = random.Random(9)

    def score(a: dict, b: dict) -> int:
        return sum(x == y for f in FIELDS for x, y in zip(a[f], b[f]))

    same, other = [], []
    for _ in range(3000):
        k1, k2 = rng.randbytes(16), rng.randbytes(16)
        t0 = rng.randrange(1_700_000_000_000, 1_800_000_000_000)
        s = rng.randrange(65536)
        first = capture(k1, t0, s)
        same.append(score(first, capture(k1, t0 + 60_000, (s + 600) & 0xFFFF)))
        other.append(score(first, capture(k2, t0 + 60_000, rng.randrange(65536))))
    mean_same, mean_other = sum(same) / len(same), sum(other) / len(other)
    # 28 bytes compared, ~0.11 equal by chance; the standard error of each mean is ~0.006.
    assert abs(mean_same - mean_other) < 0.03, (mean_same, mean_other)
    assert 0.05 < mean_same < 0.2


def test_within_one_period_the_identifiers_stay_and_the_seq_stays_hidden():
    key = bytes(range(16))
    c = auth.counter_at(1_750_000_000_000)
    a, b = auth.payload(key, c, 100), auth.payload(key, c, 101)
    fa, fb = auth.parse_payload(a), auth.parse_payload(b)
    assert fa is not None and fb is not None
    assert fa.rid == fb.rid  # one period: one identifier (a verifier's cache)
    assert fa.eseq ^ fb.eseq == 100 ^ 101  # the pad is the period's: differences show, values do not
    assert fa.eseq != 100


def test_the_reference_hmac_is_the_standard_librarys():
    key, msg = b"k" * 16, b"\x02abcdef"
    assert auth.hmac_sha256(key, msg) == hmac.new(key, msg, hashlib.sha256).digest()
