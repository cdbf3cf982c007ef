# Our authenticated rolling beacon for MicroPython (protocol/SPEC.md section 9): HMAC-SHA-256
# (RFC 2104, written here over the port's hashlib.sha256), what a beacon's key derives for
# a period, an advertisement's tag and payload, and the counter window a verifier keeps.
# Byte-identical to the C module (firmware/core/src/auth.c) and the Python reference
# (pfdoa.protocol.auth): golden vectors protocol/vectors/auth.json and the differential
# test over 10,000 random keys and counters. Needs a port with hashlib.sha256 (unix, ESP32,
# rp2, stm32 with it enabled).
from micropython import const
import hashlib
import pfdoa_defs as D

_M32 = const(0xFFFFFFFF)
_BLOCK = const(64)
_TAG_AT = const(8 + 6)  # payload: magic(2) counter(4) eseq(2) rid(6) tag(8)


class Key:
    """An HMAC-SHA-256 key: the key padded to a block, xored with ipad and opad (RFC 2104).
    hashlib has no copy() here, so each HMAC hashes the two pad blocks again."""

    def __init__(self, key):
        k = bytes(key)
        if len(k) > _BLOCK:
            k = hashlib.sha256(k).digest()
        k = k + bytes(_BLOCK - len(k))
        self._ipad = bytes(b ^ 0x36 for b in k)
        self._opad = bytes(b ^ 0x5C for b in k)

    def hmac(self, msg):
        h = hashlib.sha256(self._ipad)
        h.update(msg)
        o = hashlib.sha256(self._opad)
        o.update(h.digest())
        return o.digest()


def _u32le(v):
    return bytes((v & 0xFF, (v >> 8) & 0xFF, (v >> 16) & 0xFF, (v >> 24) & 0xFF))


def key_check(key):
    """The key check value (SPEC 9.2): hashed into filter_hash in place of the key."""
    return Key(key).hmac(bytes((D.AUTH_DOMAIN_CHECK,)))[:D.AUTH_CHECK_LEN]


def derive(k, counter):
    """(rid, adv_a, ext_addr, pad) of period `counter` for Key k (SPEC 9.2), addresses in
    on-air order."""
    b = k.hmac(bytes((D.AUTH_DOMAIN_IDS,)) + _u32le(counter))
    r = D.AUTH_RID_LEN
    a = bytearray(b[r:r + 6])
    a[5] &= 0x3F  # non-resolvable private address: the two most significant bits 0b00
    rest = a[:5]
    if (a[5] == 0 and rest == bytes(5)) or (a[5] == 0x3F and rest == b"\xff" * 5):
        a[0] ^= 0x01  # 46 random bits neither all 0 nor all 1
    e = bytearray(b[r + 6:r + 14])
    e[7] = (e[7] | 0x02) & 0xFE  # locally administered unicast EUI-64
    return bytes(b[:r]), bytes(a), bytes(e), b[r + 14] | (b[r + 15] << 8)


def tag(k, counter, seq):
    msg = bytes((D.AUTH_DOMAIN_TAG,)) + _u32le(counter) + bytes((seq & 0xFF, (seq >> 8) & 0xFF))
    return k.hmac(msg)[:D.AUTH_TAG_LEN]


def payload(k, counter, seq, ids=None, out=None):
    """The 22 bytes advertised (SPEC 9.3): 'P' 'A' counter(LE32) eseq(LE16) rid tag, into
    out when given. ids: derive(k, counter), which changes once a period."""
    rid, _, _, pad = ids if ids is not None else derive(k, counter)
    b = out if out is not None else bytearray(D.AUTH_PAYLOAD_LEN)
    b[0] = D.BEACON_MAGIC0
    b[1] = D.AUTH_MAGIC1
    b[2:6] = _u32le(counter)
    e = (seq ^ pad) & 0xFFFF
    b[6] = e & 0xFF
    b[7] = e >> 8
    b[8:_TAG_AT] = rid
    b[_TAG_AT:_TAG_AT + D.AUTH_TAG_LEN] = tag(k, counter, seq)
    return b


def equal(a, ai, b, n):
    """a[ai:ai+n] == b[:n], in time that depends on n only (tags)."""
    d = 0
    for i in range(n):
        d |= a[ai + i] ^ b[i]
    return d == 0


def seq_newer(seq, last):
    d = (seq - last) & 0xFFFF
    return 0 < d < 0x8000


class Window:
    """A verifier's state for one beacon (SPEC 9.4): the last accepted counter and seq,
    and the tick of their first acceptance."""

    def __init__(self):
        self.have = False
        self.counter = 0
        self.seq = 0
        self.tick = 0

    def check(self, counter, seq, tick):
        if self.have:
            elapsed = (tick - self.tick) & _M32
            if counter + D.AUTH_WINDOW < self.counter + (elapsed >> D.AUTH_PERIOD_SHIFT):
                return D.AUTH_STALE
            if counter == self.counter and seq == self.seq:
                return D.AUTH_ACCEPT if elapsed < D.EVENT_TIMEOUT_MS else D.AUTH_REPLAYED
            if counter < self.counter or (counter == self.counter and not seq_newer(seq, self.seq)):
                return D.AUTH_REPLAYED
        self.have = True
        self.counter = counter
        self.seq = seq
        self.tick = tick & _M32
        return D.AUTH_ACCEPT


class Verifier:
    """One PFDOA_AUTH entry: its key, window, and the last period's rid and pad. After a
    verify() that got past the rolling identifier, .counter, .seq and .tag hold what the
    payload said."""

    def __init__(self, key):
        self._k = Key(key)
        self.window = Window()
        self._cc = -1  # the counter whose rid and pad are cached
        self._rid = b""
        self._pad = 0
        self.counter = 0
        self.seq = 0
        self.tag = b""

    def verify(self, p, at, tick):
        """The payload p[at:at+22] (magic already checked) at tick: AUTH_NONE, _BAD_TAG,
        or the window's verdict."""
        c = p[at + 2] | (p[at + 3] << 8) | (p[at + 4] << 16) | (p[at + 5] << 24)
        if c != self._cc:
            self._rid, _, _, self._pad = derive(self._k, c)
            self._cc = c
        if not equal(p, at + 8, self._rid, D.AUTH_RID_LEN):
            return D.AUTH_NONE
        seq = (p[at + 6] | (p[at + 7] << 8)) ^ self._pad
        self.counter = c
        self.seq = seq
        self.tag = bytes(p[at + _TAG_AT:at + _TAG_AT + D.AUTH_TAG_LEN])
        if not equal(p, at + _TAG_AT, tag(self._k, c, seq), D.AUTH_TAG_LEN):
            return D.AUTH_BAD_TAG
        return self.window.check(c, seq, tick)
