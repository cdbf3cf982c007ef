"""Our authenticated rolling beacon (protocol/SPEC.md section 9): what is derived from a
beacon's secret key and the time counter, the payload it advertises, and the counter
window a verifier (an anchor, the gateway) keeps per beacon.

The reference the C module (firmware/core/src/auth.c) and the MicroPython one
(firmware/micropython/pfdoa_auth.py) are compared with, byte for byte (golden vectors
protocol/vectors/auth.json and the differential test over random keys and counters).
HMAC-SHA-256 here is the standard library's (RFC 2104, FIPS 180-4).

    ids = derive(key, counter)                 # the period's identifiers
    payload = payload(key, counter, seq)       # 'P' 'A' counter eseq rid tag (22 bytes)
    window = Window(); window.check(...)       # accept / stale / replayed
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from dataclasses import dataclass
from typing import NamedTuple

from . import defs

U32 = 0xFFFFFFFF

RESULT_NAMES = {defs.AUTH_NONE: "none", defs.AUTH_ACCEPT: "accept", defs.AUTH_BAD_TAG: "bad_tag",
                defs.AUTH_STALE: "stale", defs.AUTH_REPLAYED: "replayed"}
REJECTIONS = ("bad_tag", "stale", "replayed")  # the verdicts that reject, in SPEC order


def hmac_sha256(key: bytes, msg: bytes) -> bytes:
    return hmac.new(bytes(key), bytes(msg), hashlib.sha256).digest()


def check_key(key: bytes) -> bytes:
    """A key as bytes of the right length (ValueError otherwise)."""
    k = bytes(key)
    if len(k) != defs.AUTH_KEY_LEN:
        raise ValueError(f"a beacon key is {defs.AUTH_KEY_LEN} bytes, not {len(k)}")
    return k


def key_check(key: bytes) -> bytes:
    """The key check value (SPEC 9.2): what a filter table's hash covers in place of the key."""
    return hmac_sha256(check_key(key), bytes((defs.AUTH_DOMAIN_CHECK,)))[:defs.AUTH_CHECK_LEN]


class Ids(NamedTuple):
    """What one period shows of a beacon (SPEC 9.2): its rolling identifier, its BLE
    device address and IEEE 802.15.4 extended address (on-air order), and the pad that
    hides the sequence number."""

    rid: bytes
    adv_a: bytes
    ext_addr: bytes
    pad: int


def _private_address(b: bytes) -> bytes:
    """A non-resolvable private address (Core Spec Vol 6 Part B 1.3.2.2): the two most
    significant bits 0b00, the other 46 bits neither all 0 nor all 1."""
    a = bytearray(b)
    a[5] &= 0x3F
    if (a[5] == 0 and not any(a[:5])) or (a[5] == 0x3F and all(x == 0xFF for x in a[:5])):
        a[0] ^= 0x01
    return bytes(a)


def _local_eui64(b: bytes) -> bytes:
    """A locally administered unicast EUI-64, on-air order (the most significant octet
    last): U/L bit set, I/G bit clear."""
    a = bytearray(b)
    a[7] = (a[7] | 0x02) & 0xFE
    return bytes(a)


def derive(key: bytes, counter: int) -> Ids:
    """The identifiers of period `counter`: HMAC(K, 0x01 || counter LE32) split up."""
    b = hmac_sha256(check_key(key), bytes((defs.AUTH_DOMAIN_IDS,)) + struct.pack("<I", counter & U32))
    r = defs.AUTH_RID_LEN
    return Ids(b[:r], _private_address(b[r:r + 6]), _local_eui64(b[r + 6:r + 14]),
               b[r + 14] | (b[r + 15] << 8))


def tag(key: bytes, counter: int, seq: int) -> bytes:
    """An advertisement's tag: HMAC(K, 0x02 || counter LE32 || seq LE16), truncated."""
    msg = bytes((defs.AUTH_DOMAIN_TAG,)) + struct.pack("<IH", counter & U32, seq & 0xFFFF)
    return hmac_sha256(check_key(key), msg)[:defs.AUTH_TAG_LEN]


def payload(key: bytes, counter: int, seq: int, ids: Ids | None = None) -> bytes:
    """The 22 bytes our authenticated beacon advertises (SPEC 9.3):
    'P' 'A' counter(u32 LE) eseq(u16 LE) rid tag; eseq = seq XOR pad."""
    ids = ids or derive(key, counter)
    return (bytes((defs.BEACON_MAGIC0, defs.AUTH_MAGIC1)) + struct.pack("<IH", counter & U32, (seq ^ ids.pad) & 0xFFFF)
            + ids.rid + tag(key, counter, seq))


class Fields(NamedTuple):
    """A parsed authenticated payload (nothing verified yet)."""

    counter: int
    eseq: int
    rid: bytes
    tag: bytes


def parse_payload(p: bytes) -> Fields | None:
    """The fields of a 22-byte payload starting 'P' 'A', else None."""
    if len(p) != defs.AUTH_PAYLOAD_LEN or p[0] != defs.BEACON_MAGIC0 or p[1] != defs.AUTH_MAGIC1:
        return None
    counter, eseq = struct.unpack_from("<IH", p, 2)
    r = 8 + defs.AUTH_RID_LEN
    return Fields(counter, eseq, bytes(p[8:r]), bytes(p[r:r + defs.AUTH_TAG_LEN]))


def counter_at(unix_ms: int) -> int:
    """The counter at a Unix time in milliseconds (SPEC 9.1)."""
    return (int(unix_ms) >> defs.AUTH_PERIOD_SHIFT) & U32


def seq_newer(seq: int, last: int) -> bool:
    """Serial-number arithmetic on u16 (SPEC 4 Loss detection): seq after last."""
    return 0 < ((seq - last) & 0xFFFF) < 0x8000


@dataclass
class Window:
    """One verifier's state for one beacon (SPEC 9.4): the last accepted counter and
    sequence number and when (in the verifier's own milliseconds, wrapping u32)."""

    have: bool = False
    counter: int = 0
    seq: int = 0
    tick: int = 0

    def expected(self, tick_ms: int) -> int:
        """The counter the beacon should be at by now (valid when have)."""
        return self.counter + (((tick_ms - self.tick) & U32) >> defs.AUTH_PERIOD_SHIFT)

    def check(self, counter: int, seq: int, tick_ms: int, same_event_ms: int | None = defs.EVENT_TIMEOUT_MS) -> int:
        """The verdict for an advertisement whose tag verified: AUTH_ACCEPT (the state moves
        on when it is newer), AUTH_STALE or AUTH_REPLAYED. `same_event_ms`: the last accepted
        (counter, seq) is accepted again within that many ms of its acceptance (the same
        advertising event heard on another channel); None: never."""
        tick_ms &= U32
        if self.have:
            if counter + defs.AUTH_WINDOW < self.expected(tick_ms):
                return defs.AUTH_STALE
            if counter == self.counter and seq == self.seq:
                if same_event_ms is not None and ((tick_ms - self.tick) & U32) < same_event_ms:
                    return defs.AUTH_ACCEPT
                return defs.AUTH_REPLAYED
            if counter < self.counter or (counter == self.counter and not seq_newer(seq, self.seq)):
                return defs.AUTH_REPLAYED
        self.have, self.counter, self.seq, self.tick = True, counter, seq, tick_ms
        return defs.AUTH_ACCEPT


class Verdict(NamedTuple):
    result: int          # AUTH_* (AUTH_NONE: not this beacon)
    seq: int = 0         # the sequence number (when the tag verified)
    counter: int = 0
    tag: bytes = b""


class Verifier:
    """One beacon's key and counter window: an anchor's PFDOA_AUTH entry (SPEC 9.4)."""

    def __init__(self, key: bytes) -> None:
        self.key = check_key(key)
        self.window = Window()

    def verify(self, fields: Fields, tick_ms: int) -> Verdict:
        ids = derive(self.key, fields.counter)
        if not hmac.compare_digest(ids.rid, fields.rid):
            return Verdict(defs.AUTH_NONE)
        seq = fields.eseq ^ ids.pad
        if not hmac.compare_digest(tag(self.key, fields.counter, seq), fields.tag):
            return Verdict(defs.AUTH_BAD_TAG, seq, fields.counter, fields.tag)
        return Verdict(self.window.check(fields.counter, seq, tick_ms), seq, fields.counter, fields.tag)


__all__ = ["hmac_sha256", "check_key", "key_check", "Ids", "derive", "tag", "payload", "Fields",
           "parse_payload", "counter_at", "seq_newer", "Window", "Verdict", "Verifier", "RESULT_NAMES",
           "REJECTIONS"]
