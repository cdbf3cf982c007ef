# Beacon filter table and reception parsers for MicroPython (protocol/SPEC.md 3.1-3.3),
# byte-identical in behaviour to the C core (firmware/core/src/match.c) and the Python
# reference (pfdoa.protocol.filters). Layouts from the specifications: BLE advertising PDU
# (Bluetooth Core Spec v5.3 Vol 6 Part B 2.3), AD structures (Vol 3 Part C 11), iBeacon
# (Apple Proximity Beacon Specification), Eddystone-UID (Google Eddystone specification),
# AltBeacon (AltBeacon specification v1.0), IEEE 802.15.4-2015 7.2 (MAC frame).
#
# The table is its stored form, one bytearray of FILTER_TABLE_LEN bytes (entry i at
# i * FILTER_ENTRY_LEN: kind, period_ms u16 LE, match[20]). Matching does not allocate: it
# returns -1 (no entry) or ((peer + 1) << 19) | (index << 17) | (has_seq << 16) | seq, a
# small int (< 2**26), where peer is the anchor an ANCHORS entry heard (SPEC 3.5), else -1.
import pfdoa_defs as D
import pfdoa_wire as W

_E = D.FILTER_ENTRY_LEN
_M = 3  # offset of match inside an entry
_USED = bytes((D.FILTER_NONE_USED, D.FILTER_PFDOA_USED, D.FILTER_IBEACON_USED,
               D.FILTER_EDDYSTONE_UID_USED, D.FILTER_ALTBEACON_USED, D.FILTER_MAC48_USED,
               D.FILTER_MAC64_USED, D.FILTER_PFDOA_AUTH_USED, D.FILTER_ANCHORS_USED))
_ADV_TYPES = (D.BLE_PDU_ADV_IND, D.BLE_PDU_ADV_NONCONN_IND, D.BLE_PDU_ADV_SCAN_IND,
              D.BLE_PDU_SCAN_RSP)


def default_table():
    return bytearray(D.FILTER_TABLE_DEFAULT)


def kind(t, i):
    return t[i * _E]


def period(t, i):
    return t[i * _E + 1] | (t[i * _E + 2] << 8)


def entry_valid(e, at=0):
    """SPEC 1.5 for the entry e[at:at+FILTER_ENTRY_LEN]."""
    k = e[at]
    if k >= len(_USED):
        return False
    for i in range(at + _M + _USED[k], at + _E):
        if e[i]:
            return False
    p = e[at + 1] | (e[at + 2] << 8)
    if k == D.FILTER_NONE or k == D.FILTER_PFDOA or k == D.FILTER_PFDOA_AUTH:
        return p == 0
    return p != 0  # 1..65535


def table_valid(t):
    if len(t) != D.FILTER_TABLE_LEN:
        return False
    for i in range(D.BEACON_SLOTS):
        if not entry_valid(t, i * _E):
            return False
    return True


def table_hash(t):
    """CRC-16 over the table; a PFDOA_AUTH entry's key replaced by its key check value
    (SPEC 9.2), so the hash never depends on a key's bits directly."""
    if not any(t[i * _E] == D.FILTER_PFDOA_AUTH for i in range(D.BEACON_SLOTS)):
        return W.crc16(t)
    import pfdoa_auth  # only anchors with an authenticated beacon need it
    pub = bytearray(t)
    for i in range(D.BEACON_SLOTS):
        e = i * _E
        if pub[e] == D.FILTER_PFDOA_AUTH:
            pub[e + _M:e + _M + D.FILTER_MATCH_LEN] = (pfdoa_auth.key_check(t[e + _M:e + _M + D.AUTH_KEY_LEN])
                                                      + bytes(D.FILTER_MATCH_LEN - D.AUTH_CHECK_LEN))
    return W.crc16(pub)


def _same(a, ai, b, bi, n):
    for k in range(n):
        if a[ai + k] != b[bi + k]:
            return False
    return True


def _found(index, has_seq, seq):
    return (index << 17) | (has_seq << 16) | seq


def _anchor_payload(p, at, n):
    """(anchor id << 16) | seq of an anchor's advertisement payload 'P' 'N' seq id at
    p[at:at+n] (SPEC 6.1), -1 for anything else (an id above ANCHOR_ID_MAX included)."""
    if (n != D.BEACON_PAYLOAD_LEN or p[at] != D.BEACON_MAGIC0 or p[at + 1] != D.ANCHOR_MAGIC1
            or p[at + 4] > D.ANCHOR_ID_MAX):
        return -1
    return (p[at + 4] << 16) | p[at + 2] | (p[at + 3] << 8)


def _found_peer(index, peer):
    return ((peer >> 16) + 1) << 19 | (index << 17) | (1 << 16) | (peer & 0xFFFF)


def index(m):
    """The entry of a match result."""
    return (m >> 17) & 3


def peer(m):
    """The anchor an ANCHORS entry's match heard, -1 for other matches."""
    return (m >> 19) - 1


def match_adv(t, adv_a, ai, data, di, n):
    """AdvA adv_a[ai:ai+6] and AdvData data[di:di+n] against table t."""
    ours = -1  # (id << 16) | seq of our beacon
    anchor = -1  # (anchor id << 16) | seq of an anchor's advertisement
    ib = ed = alt = -1  # offsets into data of the identities
    i = di
    end = di + n
    while i < end:
        length = data[i]
        if length == 0 or length > end - i - 1:
            break  # the end of the significant part, or a structure that does not fit
        ad_type = data[i + 1]
        c = i + 2  # the AD data after its type
        m = length - 1
        if ad_type == D.BLE_AD_MANUFACTURER and m >= 4:
            company = data[c] | (data[c + 1] << 8)
            if (ours < 0 and company == D.BEACON_COMPANY_ID and data[c + 2] == D.BEACON_MAGIC0
                    and data[c + 3] == D.BEACON_MAGIC1
                    and (m == 2 + D.BEACON_PAYLOAD_LEN or m == 2 + D.BEACON_V1_PAYLOAD_LEN)):
                bid = data[c + 6] if m == 2 + D.BEACON_PAYLOAD_LEN else 0  # the v1 beacon is id 0
                ours = (bid << 16) | data[c + 4] | (data[c + 5] << 8)
            elif anchor < 0 and company == D.BEACON_COMPANY_ID and _anchor_payload(data, c + 2, m - 2) >= 0:
                anchor = _anchor_payload(data, c + 2, m - 2)
            elif (ib < 0 and company == D.IBEACON_COMPANY_ID and data[c + 2] == D.IBEACON_TYPE
                  and data[c + 3] == D.IBEACON_LENGTH and m == 4 + D.IBEACON_LENGTH):
                ib = c + 4
            elif (alt < 0 and data[c + 2] == D.ALTBEACON_CODE0 and data[c + 3] == D.ALTBEACON_CODE1
                  and m == 2 + D.ALTBEACON_LEN):
                alt = c + 4
        elif (ad_type == D.BLE_AD_SERVICE_DATA16 and ed < 0 and m >= 3
              and (data[c] | (data[c + 1] << 8)) == D.EDDYSTONE_UUID and data[c + 2] == D.EDDYSTONE_FRAME_UID
              and (m == 2 + D.EDDYSTONE_UID_MIN_LEN or m == 4 + D.EDDYSTONE_UID_MIN_LEN)):
            ed = c + 4
        i += 1 + length
    for x in range(D.BEACON_SLOTS):
        e = x * _E
        k = t[e]
        mm = e + _M
        if k == D.FILTER_PFDOA:
            if ours >= 0 and (ours >> 16) == t[mm]:
                return _found(x, 1, ours & 0xFFFF)
        elif k == D.FILTER_IBEACON:
            if ib >= 0 and _same(data, ib, t, mm, D.FILTER_IBEACON_USED):
                return _found(x, 0, 0)
        elif k == D.FILTER_EDDYSTONE_UID:
            if ed >= 0 and _same(data, ed, t, mm, D.FILTER_EDDYSTONE_UID_USED):
                return _found(x, 0, 0)
        elif k == D.FILTER_ALTBEACON:
            if alt >= 0 and _same(data, alt, t, mm, D.FILTER_ALTBEACON_USED):
                return _found(x, 0, 0)
        elif k == D.FILTER_MAC48:
            if _same(adv_a, ai, t, mm, D.FILTER_MAC48_USED):
                return _found(x, 0, 0)
        elif k == D.FILTER_ANCHORS:
            if anchor >= 0:
                return _found_peer(x, anchor)
    return -1


def _pdu_len(pdu, n):
    """The Length of pdu[0:n] when it is an advertising PDU whose AdvA and AdvData fit
    (SPEC 3.2), else -1."""
    if n < D.BLE_PDU_HEADER_LEN:
        return -1
    plen = pdu[1]
    if ((pdu[0] & D.BLE_PDU_TYPE_MASK) not in _ADV_TYPES or plen < D.BLE_ADV_A_LEN
            or plen > D.BLE_ADV_A_LEN + D.BLE_ADV_DATA_MAX or plen > n - D.BLE_PDU_HEADER_LEN):
        return -1
    return plen


def match_pdu(t, pdu, n):
    """A raw advertising PDU pdu[0:n] (header, AdvA, AdvData) against table t."""
    plen = _pdu_len(pdu, n)
    if plen < 0:
        return -1
    a = D.BLE_PDU_HEADER_LEN
    return match_adv(t, pdu, a, pdu, a + D.BLE_ADV_A_LEN, plen - D.BLE_ADV_A_LEN)


def _addr_len(mode):
    if mode == D.IEEE802154_ADDR_EXT:
        return 8
    return 2 if mode == D.IEEE802154_ADDR_SHORT else 0


def _mac_parse(f, n):
    """An IEEE 802.15.4 MAC frame f[0:n] without FCS (SPEC 3.3), as one small int (no
    allocation): payload offset | source address offset << 8 | source mode << 16 |
    readable data frame << 18; -1 when it is malformed."""
    if n < D.IEEE802154_FCF_LEN:
        return -1
    fcf = f[0] | (f[1] << 8)
    version = (fcf >> D.IEEE802154_FCF_VERSION_SHIFT) & 3
    dst = (fcf >> D.IEEE802154_FCF_DST_MODE_SHIFT) & 3
    src = (fcf >> D.IEEE802154_FCF_SRC_MODE_SHIFT) & 3
    if version > D.IEEE802154_VERSION_2015 or dst == 1 or src == 1:
        return -1  # reserved frame version or addressing mode
    comp = (fcf & D.IEEE802154_FCF_PANID_COMP) != 0
    v2015 = version == D.IEEE802154_VERSION_2015
    pos = D.IEEE802154_FCF_LEN
    if not (v2015 and (fcf & D.IEEE802154_FCF_SEQ_SUPPRESS)):
        pos += 1
    # Which PAN ids are present: 7.2.2.6 for frame versions 0 and 1, Table 7-2 for 2.
    if not v2015:
        dst_pan = dst != 0
        src_pan = src != 0 and not (comp and dst != 0)
    elif dst == 0 and src == 0:
        dst_pan, src_pan = comp, False
    elif src == 0:
        dst_pan, src_pan = not comp, False
    elif dst == 0:
        dst_pan, src_pan = False, not comp
    elif dst == D.IEEE802154_ADDR_EXT and src == D.IEEE802154_ADDR_EXT:
        dst_pan, src_pan = not comp, False
    else:
        dst_pan, src_pan = True, not comp
    pos += (2 if dst_pan else 0) + _addr_len(dst) + (2 if src_pan else 0)
    src_at = pos
    pos += _addr_len(src)
    if pos > n:
        return -1
    unreadable = (fcf & D.IEEE802154_FCF_SECURITY) or (v2015 and (fcf & D.IEEE802154_FCF_IE_PRESENT))
    data = not unreadable and (fcf & D.IEEE802154_FRAME_TYPE_MASK) == D.IEEE802154_FRAME_DATA
    return pos | (src_at << 8) | (src << 16) | ((1 if data else 0) << 18)


def _mac_payload(f, n):
    """Payload offset of a readable data frame, else -1."""
    m = _mac_parse(f, n)
    return m & 0xFF if m >= 0 and m >> 18 else -1


def match_802154(t, f, n):
    """An IEEE 802.15.4 MAC frame f[0:n] without FCS against table t."""
    m = _mac_parse(f, n)
    if m < 0:
        return -1
    pos = m & 0xFF
    src_at = (m >> 8) & 0xFF
    src = (m >> 16) & 3
    ours = (m >> 18 and n - pos == D.BEACON_PAYLOAD_LEN and f[pos] == D.BEACON_MAGIC0
            and f[pos + 1] == D.BEACON_MAGIC1)
    anchor = _anchor_payload(f, pos, n - pos) if m >> 18 else -1
    for x in range(D.BEACON_SLOTS):
        e = x * _E
        k = t[e]
        if k == D.FILTER_PFDOA and ours and f[pos + 4] == t[e + _M]:
            return _found(x, 1, f[pos + 2] | (f[pos + 3] << 8))
        if k == D.FILTER_ANCHORS and anchor >= 0:
            return _found_peer(x, anchor)
        if (k == D.FILTER_MAC64 and src == D.IEEE802154_ADDR_EXT
                and _same(f, src_at, t, e + _M, D.FILTER_MAC64_USED)):
            return _found(x, 0, 0)
    return -1


def auth_adv(data, di, n):
    """Offset in data of our authenticated beacon's payload in AdvData data[di:di+n]
    (SPEC 9.3: the first manufacturer AD of company 0xFFFF with 'P' 'A' and 22 bytes), or -1."""
    i = di
    end = di + n
    while i < end:
        length = data[i]
        if length == 0 or length > end - i - 1:
            return -1
        c = i + 2
        if (data[i + 1] == D.BLE_AD_MANUFACTURER and length - 1 == 2 + D.AUTH_PAYLOAD_LEN
                and (data[c] | (data[c + 1] << 8)) == D.BEACON_COMPANY_ID
                and data[c + 2] == D.BEACON_MAGIC0 and data[c + 3] == D.AUTH_MAGIC1):
            return c + 2
        i += 1 + length
    return -1


def auth_pdu(pdu, n):
    """The same in a raw advertising PDU pdu[0:n], or -1."""
    plen = _pdu_len(pdu, n)
    if plen < 0:
        return -1
    a = D.BLE_PDU_HEADER_LEN + D.BLE_ADV_A_LEN
    return auth_adv(pdu, a, plen - D.BLE_ADV_A_LEN)


def auth_802154(f, n):
    """Offset of the payload in an IEEE 802.15.4 data frame f[0:n] carrying our
    authenticated beacon (SPEC 9.3), or -1."""
    pos = _mac_payload(f, n)
    if pos < 0 or n - pos != D.AUTH_PAYLOAD_LEN or f[pos] != D.BEACON_MAGIC0 or f[pos + 1] != D.AUTH_MAGIC1:
        return -1
    return pos
