"""Beacon filters (SPEC 3.1-3.3): which beacons an anchor listens to, and the parsers that
match a received BLE advertisement or IEEE 802.15.4 frame against a filter table.

This is the reference the C core (firmware/core/src/match.c) and the MicroPython anchor
are compared with byte for byte (golden vectors protocol/vectors/beacon.json and the
differential test). :class:`BeaconFilter` is also what a host uses to configure anchors:
``BeaconFilter.ibeacon(uuid, major, minor, period_ms=100).set_message(token, index)``.

Layouts, written from the specifications (constants in messages.json):

* BLE advertising PDU: Bluetooth Core Specification v5.3, Vol 6 Part B 2.3; AD
  structures: Vol 3 Part C 11 and the Core Specification Supplement Part A.
* iBeacon: Apple Proximity Beacon Specification (manufacturer data 4C 00 02 15).
* Eddystone-UID: Google Eddystone protocol specification (service data FEAA, frame 0x00).
* AltBeacon: AltBeacon protocol specification v1.0 (beacon code BE AC).
* IEEE 802.15.4-2015, 7.2 (MAC frame format, Frame Control field, Table 7-2).

Our authenticated beacon (SPEC 9) is recognised here (its 22-byte payload, by
:func:`auth_payload_ble_adv` and friends) but verified by :mod:`pfdoa.protocol.auth`: the
pure matchers never match a ``PFDOA_AUTH`` entry, which holds a secret key. A table's hash
covers an entry's key check value, never the key (:meth:`BeaconFilter.public`).

An ``ANCHORS`` entry (SPEC 3.5) matches the other anchors' own advertisements (SPEC 6.1):
such a match is a :class:`PeerMatch`, which names the anchor heard.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple, Sequence

from . import defs
from .auth import check_key, key_check
from .crc import crc16
from .messages import FilterSet

_ENTRY = struct.Struct(defs.FILTER_ENTRY_FMT)
_USED = {defs.FILTER_NONE: defs.FILTER_NONE_USED, defs.FILTER_PFDOA: defs.FILTER_PFDOA_USED,
         defs.FILTER_IBEACON: defs.FILTER_IBEACON_USED, defs.FILTER_EDDYSTONE_UID: defs.FILTER_EDDYSTONE_UID_USED,
         defs.FILTER_ALTBEACON: defs.FILTER_ALTBEACON_USED, defs.FILTER_MAC48: defs.FILTER_MAC48_USED,
         defs.FILTER_MAC64: defs.FILTER_MAC64_USED, defs.FILTER_PFDOA_AUTH: defs.FILTER_PFDOA_AUTH_USED,
         defs.FILTER_ANCHORS: defs.FILTER_ANCHORS_USED}
KIND_NAMES = {v: k[len("FILTER_"):].lower() for k, v in vars(defs).items()
              if k.startswith("FILTER_") and k[len("FILTER_"):] in
              ("NONE", "PFDOA", "IBEACON", "EDDYSTONE_UID", "ALTBEACON", "MAC48", "MAC64", "PFDOA_AUTH", "ANCHORS")}
WITH_SEQ = frozenset((defs.FILTER_PFDOA, defs.FILTER_PFDOA_AUTH))  # kinds whose beacons carry a sequence number


def _mac(text: str | bytes, n: int) -> bytes:
    """A MAC address as on air (least significant byte first) from "AA:BB:...:FF" (most
    significant first, as printed) or from bytes already in air order."""
    if isinstance(text, (bytes, bytearray)):
        b = bytes(text)
    else:
        b = bytes.fromhex(text.replace(":", "").replace("-", ""))[::-1]
    if len(b) != n:
        raise ValueError(f"a MAC address here is {n} bytes, not {len(b)}")
    return b


@dataclass(frozen=True)
class BeaconFilter:
    """One entry of an anchor's filter table (SPEC 3.1): kind, event period, match bytes."""

    kind: int = defs.FILTER_NONE
    period_ms: int = 0
    match: bytes = b""

    def __post_init__(self) -> None:
        m = bytes(self.match)
        if len(m) > defs.FILTER_MATCH_LEN:
            raise ValueError(f"match is at most {defs.FILTER_MATCH_LEN} bytes")
        object.__setattr__(self, "match", m.ljust(defs.FILTER_MATCH_LEN, b"\x00"))

    def __repr__(self) -> str:
        # A PFDOA_AUTH entry's match bytes are a secret key: never in a repr (logs, tracebacks).
        match = "<key>" if self.kind == defs.FILTER_PFDOA_AUTH else repr(self.match)
        return f"BeaconFilter(kind={self.kind}, period_ms={self.period_ms}, match={match})"

    # -- constructors ------------------------------------------------------------------
    @classmethod
    def none(cls) -> "BeaconFilter":
        return cls()

    @classmethod
    def pfdoa(cls, beacon_id: int = defs.FILTER_DEFAULT_ID) -> "BeaconFilter":
        """Our beacon with this id (SPEC 6); reports carry its sequence numbers."""
        return cls(defs.FILTER_PFDOA, 0, bytes((beacon_id,)))

    @classmethod
    def pfdoa_auth(cls, key: bytes) -> "BeaconFilter":
        """Our authenticated rolling beacon (SPEC 9) with this secret key."""
        return cls(defs.FILTER_PFDOA_AUTH, 0, check_key(key))

    @classmethod
    def ibeacon(cls, uuid: bytes | str, major: int, minor: int, period_ms: int) -> "BeaconFilter":
        u = bytes.fromhex(uuid.replace("-", "")) if isinstance(uuid, str) else bytes(uuid)
        if len(u) != 16:
            raise ValueError("an iBeacon proximity UUID is 16 bytes")
        return cls(defs.FILTER_IBEACON, period_ms, u + struct.pack(">HH", major, minor))

    @classmethod
    def eddystone_uid(cls, namespace: bytes | str, instance: bytes | str, period_ms: int) -> "BeaconFilter":
        ns = bytes.fromhex(namespace) if isinstance(namespace, str) else bytes(namespace)
        inst = bytes.fromhex(instance) if isinstance(instance, str) else bytes(instance)
        if len(ns) != 10 or len(inst) != 6:
            raise ValueError("an Eddystone-UID is a 10-byte namespace and a 6-byte instance")
        return cls(defs.FILTER_EDDYSTONE_UID, period_ms, ns + inst)

    @classmethod
    def altbeacon(cls, beacon_id: bytes | str, period_ms: int) -> "BeaconFilter":
        b = bytes.fromhex(beacon_id) if isinstance(beacon_id, str) else bytes(beacon_id)
        if len(b) != 20:
            raise ValueError("an AltBeacon beacon id is 20 bytes")
        return cls(defs.FILTER_ALTBEACON, period_ms, b)

    @classmethod
    def mac48(cls, address: str | bytes, period_ms: int) -> "BeaconFilter":
        """Any BLE advertiser with this device address ("AA:BB:CC:DD:EE:FF" or air-order bytes)."""
        return cls(defs.FILTER_MAC48, period_ms, _mac(address, 6))

    @classmethod
    def mac64(cls, address: str | bytes, period_ms: int) -> "BeaconFilter":
        """Any IEEE 802.15.4 frame from this extended address (EUI-64)."""
        return cls(defs.FILTER_MAC64, period_ms, _mac(address, 8))

    @classmethod
    def anchors(cls, period_ms: int) -> "BeaconFilter":
        """The other anchors (SPEC 3.5): hear their advertisements as peer readings, and
        send this anchor's own every ``period_ms``."""
        return cls(defs.FILTER_ANCHORS, period_ms)

    # -- wire form ---------------------------------------------------------------------
    @property
    def has_seq(self) -> bool:
        return self.kind in WITH_SEQ

    def is_valid(self) -> bool:
        """SPEC 1.5: a known kind, its period rule, zeros in the match bytes it does not use."""
        used = _USED.get(self.kind)
        if used is None or any(self.match[used:]):
            return False
        if self.kind in WITH_SEQ or self.kind == defs.FILTER_NONE:
            return self.period_ms == 0
        return defs.FILTER_PERIOD_MIN <= self.period_ms <= defs.FILTER_PERIOD_MAX

    def pack(self) -> bytes:
        """The FILTER_ENTRY_LEN-byte stored form."""
        return _ENTRY.pack(self.kind, self.period_ms, self.match)

    def public(self) -> "BeaconFilter":
        """What a table's hash covers (SPEC 9.2): a PFDOA_AUTH entry's key replaced by its
        key check value; other entries as they are."""
        if self.kind != defs.FILTER_PFDOA_AUTH:
            return self
        return BeaconFilter(self.kind, self.period_ms, key_check(self.match[:defs.AUTH_KEY_LEN]))

    @classmethod
    def unpack(cls, data: bytes) -> "BeaconFilter":
        kind, period, match = _ENTRY.unpack(data)
        return cls(kind, period, match)

    def set_message(self, token: int, index: int) -> FilterSet:
        """The FILTER_SET that puts this filter into entry `index`."""
        return FilterSet(token, index, self.kind, self.period_ms, self.match)

    @classmethod
    def of_message(cls, msg: FilterSet) -> "BeaconFilter":
        return cls(msg.kind, msg.period_ms, msg.match)

    def describe(self) -> str:
        name = KIND_NAMES.get(self.kind, f"kind {self.kind}")
        used = _USED.get(self.kind, defs.FILTER_MATCH_LEN)
        if self.kind == defs.FILTER_NONE:
            return name
        if self.kind == defs.FILTER_PFDOA_AUTH:  # the key never; its check value names it
            return f"{name} key check {self.public().match[:4].hex()}"
        text = f"{name} {self.match[:used].hex()}"
        return text + (f" every {self.period_ms} ms" if self.period_ms else "")


def default_table() -> tuple[BeaconFilter, ...]:
    """The table at first boot: our beacon id 0 in entry 0, the rest empty."""
    return unpack_table(defs.FILTER_TABLE_DEFAULT)


def pack_table(table: Sequence[BeaconFilter]) -> bytes:
    if len(table) != defs.BEACON_SLOTS:
        raise ValueError(f"a filter table has {defs.BEACON_SLOTS} entries")
    return b"".join(f.pack() for f in table)


def unpack_table(data: bytes) -> tuple[BeaconFilter, ...]:
    if len(data) != defs.FILTER_TABLE_LEN:
        raise ValueError(f"a stored filter table is {defs.FILTER_TABLE_LEN} bytes")
    n = defs.FILTER_ENTRY_LEN
    return tuple(BeaconFilter.unpack(data[i:i + n]) for i in range(0, len(data), n))


def table_hash(table: Sequence[BeaconFilter]) -> int:
    """filter_hash of STATUS and FILTER_ACK: over the table's public form (no key)."""
    return crc16(pack_table([f.public() for f in table]))


# ------------------------------------------------------------------------- parsing


class Match(NamedTuple):
    """A reception that matched entry `index`; `seq` None for beacons without one."""

    # The field shadows tuple.index (mypy flags it); kept: it is the entry's index, and callers
    # compare matches with plain tuples.
    index: int  # type: ignore[assignment]
    seq: int | None


class PeerMatch(NamedTuple):
    """A reception of another anchor's own advertisement that matched the ``ANCHORS`` entry
    ``index``: its sequence number and the anchor's id (SPEC 3.5)."""

    index: int  # type: ignore[assignment]  # the entry's index, as in Match
    seq: int
    peer: int


class _Adv(NamedTuple):
    ours: tuple[int, int] | None    # (beacon id, seq)
    ibeacon: bytes | None           # uuid + major + minor (20)
    eddystone: bytes | None         # namespace + instance (16)
    altbeacon: bytes | None         # beacon id (20)
    auth: bytes | None = None       # our authenticated payload ('P' 'A' ..., SPEC 9.3)
    anchor: tuple[int, int] | None = None  # an anchor's own advertisement: (anchor id, seq)


def _anchor_payload(p: bytes) -> tuple[int, int] | None:
    """(anchor id, seq) of an anchor's advertisement payload 'P' 'N' seq id (SPEC 6.1); None
    for anything else, an id above ANCHOR_ID_MAX included (no anchor has it)."""
    if (len(p) == defs.BEACON_PAYLOAD_LEN and p[0] == defs.BEACON_MAGIC0 and p[1] == defs.ANCHOR_MAGIC1
            and p[4] <= defs.ANCHOR_ID_MAX):
        return p[4], p[2] | (p[3] << 8)
    return None


def parse_adv_data(data: bytes) -> _Adv:
    """The beacon identities in AdvData: the first AD structure of each format (SPEC 3.2)."""
    ours = ib = ed = alt = auth = anchor = None
    i, n = 0, len(data)
    while i < n:
        length = data[i]
        if length == 0 or i + 1 + length > n:
            break  # the end of the significant part, or a structure that does not fit
        ad_type, c = data[i + 1], data[i + 2:i + 1 + length]  # c: the AD data after the type
        if ad_type == defs.BLE_AD_MANUFACTURER and len(c) >= 4:
            company = c[0] | (c[1] << 8)
            if (ours is None and company == defs.BEACON_COMPANY_ID and c[2] == defs.BEACON_MAGIC0
                    and c[3] == defs.BEACON_MAGIC1
                    and len(c) in (2 + defs.BEACON_PAYLOAD_LEN, 2 + defs.BEACON_V1_PAYLOAD_LEN)):
                ours = (c[6] if len(c) == 2 + defs.BEACON_PAYLOAD_LEN else 0, c[4] | (c[5] << 8))
            elif (auth is None and company == defs.BEACON_COMPANY_ID and c[2] == defs.BEACON_MAGIC0
                  and c[3] == defs.AUTH_MAGIC1 and len(c) == 2 + defs.AUTH_PAYLOAD_LEN):
                auth = bytes(c[2:])
            elif anchor is None and company == defs.BEACON_COMPANY_ID and _anchor_payload(c[2:]) is not None:
                anchor = _anchor_payload(c[2:])
            elif (ib is None and company == defs.IBEACON_COMPANY_ID and c[2] == defs.IBEACON_TYPE
                  and c[3] == defs.IBEACON_LENGTH and len(c) == 4 + defs.IBEACON_LENGTH):
                ib = bytes(c[4:24])
            elif (alt is None and c[2] == defs.ALTBEACON_CODE0 and c[3] == defs.ALTBEACON_CODE1
                  and len(c) == 2 + defs.ALTBEACON_LEN):
                alt = bytes(c[4:24])
        elif (ad_type == defs.BLE_AD_SERVICE_DATA16 and ed is None and len(c) >= 3
              and c[0] | (c[1] << 8) == defs.EDDYSTONE_UUID and c[2] == defs.EDDYSTONE_FRAME_UID
              and len(c) in (2 + defs.EDDYSTONE_UID_MIN_LEN, 2 + defs.EDDYSTONE_UID_MIN_LEN + 2)):
            ed = bytes(c[4:20])
        i += 1 + length
    return _Adv(ours, ib, ed, alt, auth, anchor)


def match_ble_adv(table: Sequence[BeaconFilter], adv_a: bytes, adv_data: bytes) -> Match | PeerMatch | None:
    """Match AdvA + AdvData (as a BLE stack reports an advertisement) against the table."""
    if len(adv_a) != defs.BLE_ADV_A_LEN:
        return None
    adv = parse_adv_data(adv_data)
    for i, f in enumerate(table):
        k, m = f.kind, f.match
        if k == defs.FILTER_PFDOA and adv.ours is not None and adv.ours[0] == m[0]:
            return Match(i, adv.ours[1])
        if k == defs.FILTER_ANCHORS and adv.anchor is not None:
            return PeerMatch(i, adv.anchor[1], adv.anchor[0])
        if ((k == defs.FILTER_IBEACON and adv.ibeacon == m[:20])
                or (k == defs.FILTER_EDDYSTONE_UID and adv.eddystone == m[:16])
                or (k == defs.FILTER_ALTBEACON and adv.altbeacon == m[:20])
                or (k == defs.FILTER_MAC48 and bytes(adv_a) == m[:6])):
            return Match(i, None)
    return None


ADV_PDU_TYPES = frozenset((defs.BLE_PDU_ADV_IND, defs.BLE_PDU_ADV_NONCONN_IND, defs.BLE_PDU_ADV_SCAN_IND,
                           defs.BLE_PDU_SCAN_RSP))


def split_ble_pdu(pdu: bytes) -> tuple[bytes, bytes] | None:
    """(AdvA, AdvData) of an advertising PDU that carries them (SPEC 3.2), else None."""
    if len(pdu) < defs.BLE_PDU_HEADER_LEN or pdu[0] & defs.BLE_PDU_TYPE_MASK not in ADV_PDU_TYPES:
        return None
    length = pdu[1]
    if not defs.BLE_ADV_A_LEN <= length <= defs.BLE_ADV_A_LEN + defs.BLE_ADV_DATA_MAX or 2 + length > len(pdu):
        return None
    a = defs.BLE_PDU_HEADER_LEN
    return bytes(pdu[a:a + defs.BLE_ADV_A_LEN]), bytes(pdu[a + defs.BLE_ADV_A_LEN:a + length])


def match_ble_pdu(table: Sequence[BeaconFilter], pdu: bytes) -> Match | PeerMatch | None:
    """Match a raw BLE advertising PDU (header + payload) against the table."""
    parts = split_ble_pdu(pdu)
    return None if parts is None else match_ble_adv(table, *parts)


class MacFrame(NamedTuple):
    """The parts of an IEEE 802.15.4 MAC frame the anchor looks at."""

    frame_type: int
    src_ext: bytes | None     # the 64-bit source address, on-air order
    payload: bytes | None     # None: security or IEs make it unreadable


_ADDR_LEN = {defs.IEEE802154_ADDR_NONE: 0, defs.IEEE802154_ADDR_SHORT: 2, defs.IEEE802154_ADDR_EXT: 8}


def parse_802154(mpdu: bytes) -> MacFrame | None:
    """Parse a MAC frame without FCS (SPEC 3.3), or None when it is malformed."""
    n = len(mpdu)
    if n < defs.IEEE802154_FCF_LEN:
        return None
    fcf = mpdu[0] | (mpdu[1] << 8)
    version = (fcf >> defs.IEEE802154_FCF_VERSION_SHIFT) & 3
    dst = (fcf >> defs.IEEE802154_FCF_DST_MODE_SHIFT) & 3
    src = (fcf >> defs.IEEE802154_FCF_SRC_MODE_SHIFT) & 3
    if version > defs.IEEE802154_VERSION_2015 or dst not in _ADDR_LEN or src not in _ADDR_LEN:
        return None
    comp = bool(fcf & defs.IEEE802154_FCF_PANID_COMP)
    v2 = version == defs.IEEE802154_VERSION_2015
    pos = defs.IEEE802154_FCF_LEN
    if not (v2 and fcf & defs.IEEE802154_FCF_SEQ_SUPPRESS):
        pos += 1
    if not v2:
        dst_pan = dst != 0
        src_pan = src != 0 and not (comp and dst != 0)
    elif dst == 0 and src == 0:
        dst_pan, src_pan = comp, False
    elif src == 0:
        dst_pan, src_pan = not comp, False
    elif dst == 0:
        dst_pan, src_pan = False, not comp
    elif dst == defs.IEEE802154_ADDR_EXT and src == defs.IEEE802154_ADDR_EXT:
        dst_pan, src_pan = not comp, False
    else:
        dst_pan, src_pan = True, not comp
    pos += 2 * dst_pan + _ADDR_LEN[dst] + 2 * src_pan
    src_at = pos
    pos += _ADDR_LEN[src]
    if pos > n:
        return None
    src_ext = bytes(mpdu[src_at:pos]) if src == defs.IEEE802154_ADDR_EXT else None
    unreadable = fcf & defs.IEEE802154_FCF_SECURITY or (v2 and fcf & defs.IEEE802154_FCF_IE_PRESENT)
    return MacFrame(fcf & defs.IEEE802154_FRAME_TYPE_MASK, src_ext, None if unreadable else bytes(mpdu[pos:]))


def match_802154(table: Sequence[BeaconFilter], mpdu: bytes) -> Match | PeerMatch | None:
    """Match a raw IEEE 802.15.4 MAC frame (no FCS) against the table."""
    f = parse_802154(mpdu)
    if f is None:
        return None
    ours = anchor = None
    p = f.payload
    if f.frame_type == defs.IEEE802154_FRAME_DATA and p is not None:
        if len(p) == defs.BEACON_PAYLOAD_LEN and p[0] == defs.BEACON_MAGIC0 and p[1] == defs.BEACON_MAGIC1:
            ours = (p[4], p[2] | (p[3] << 8))
        anchor = _anchor_payload(p)
    for i, flt in enumerate(table):
        if flt.kind == defs.FILTER_PFDOA and ours is not None and ours[0] == flt.match[0]:
            return Match(i, ours[1])
        if flt.kind == defs.FILTER_ANCHORS and anchor is not None:
            return PeerMatch(i, anchor[1], anchor[0])
        if flt.kind == defs.FILTER_MAC64 and f.src_ext is not None and f.src_ext == flt.match[:8]:
            return Match(i, None)
    return None


def match_reception(table: Sequence[BeaconFilter], kind: str, data: bytes,
                    adv_a: bytes | None = None) -> Match | PeerMatch | None:
    """Match one reception given as the golden vectors give it (protocol/vectors/README.md):
    ``kind`` "adv" (``adv_a`` + ``data`` as AdvData), "pdu" (an advertising PDU) or "802154"."""
    if kind == "adv":
        return match_ble_adv(table, adv_a or b"", data)
    if kind == "pdu":
        return match_ble_pdu(table, data)
    if kind == "802154":
        return match_802154(table, data)
    raise ValueError(f"unknown reception kind {kind!r}")


# ------------------------------------------------------------------------- our authenticated beacon


def auth_payload_ble_adv(adv_data: bytes) -> bytes | None:
    """Our authenticated beacon's 22-byte payload in AdvData (SPEC 9.3), else None."""
    return parse_adv_data(adv_data).auth


def auth_payload_ble_pdu(pdu: bytes) -> tuple[bytes, bytes] | None:
    """(AdvA, payload) of an advertising PDU carrying our authenticated beacon, else None."""
    parts = split_ble_pdu(pdu)
    if parts is None:
        return None
    p = auth_payload_ble_adv(parts[1])
    return None if p is None else (parts[0], p)


def auth_payload_802154(mpdu: bytes) -> bytes | None:
    """Our authenticated beacon's payload in an IEEE 802.15.4 data frame (SPEC 9.3), else None."""
    f = parse_802154(mpdu)
    if f is None or f.frame_type != defs.IEEE802154_FRAME_DATA or f.payload is None:
        return None
    p = f.payload
    if len(p) != defs.AUTH_PAYLOAD_LEN or p[0] != defs.BEACON_MAGIC0 or p[1] != defs.AUTH_MAGIC1:
        return None
    return p


__all__ = ["BeaconFilter", "Match", "PeerMatch", "MacFrame", "match_reception", "default_table", "pack_table", "unpack_table", "table_hash",
           "parse_adv_data", "match_ble_adv", "split_ble_pdu", "match_ble_pdu", "parse_802154",
           "match_802154", "KIND_NAMES", "WITH_SEQ", "auth_payload_ble_adv", "auth_payload_ble_pdu",
           "auth_payload_802154"]
