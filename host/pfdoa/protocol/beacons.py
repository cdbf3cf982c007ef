"""What beacons transmit: our beacon (SPEC 6) as the C and MicroPython beacons build it, and
the standard formats an anchor can listen to (iBeacon, Eddystone-UID, AltBeacon), as
advertising data, advertising PDUs and IEEE 802.15.4 MAC frames.

The builders for our beacon are the reference for the golden vectors
(protocol/vectors/beacon.json); the others build test input and simulated tags. Layouts
are cited in :mod:`pfdoa.protocol.filters`, which parses them.
"""

from __future__ import annotations

import struct

from . import auth, defs


def _ad(ad_type: int, data: bytes) -> bytes:
    """One AD structure (Core Spec Vol 3 Part C 11): length, type, data."""
    if len(data) + 1 > 255:
        raise ValueError("AD structure too long")
    return bytes((len(data) + 1, ad_type)) + data


FLAGS_AD = _ad(defs.BLE_AD_FLAGS, bytes((defs.BLE_FLAGS_GENERAL_NO_BREDR,)))


def pfdoa_payload(seq: int, beacon_id: int) -> bytes:
    """Our beacon's payload: 'P' 'F', seq u16 little-endian, beacon id."""
    return bytes((defs.BEACON_MAGIC0, defs.BEACON_MAGIC1)) + (seq & 0xFFFF).to_bytes(2, "little") + bytes((beacon_id,))


def pfdoa_adv_data(seq: int, beacon_id: int) -> bytes:
    """Our beacon's AdvData (SPEC 6): Flags, then manufacturer data with company 0xFFFF."""
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, struct.pack("<H", defs.BEACON_COMPANY_ID)
                          + pfdoa_payload(seq, beacon_id))


def pfdoa_v1_adv_data(seq: int) -> bytes:
    """The version-1 beacon (no id byte), still read by anchors as id 0."""
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, struct.pack("<H", defs.BEACON_COMPANY_ID)
                          + pfdoa_payload(seq, 0)[:defs.BEACON_V1_PAYLOAD_LEN])


def adv_pdu(adv_a: bytes, adv_data: bytes, pdu_type: int = defs.BLE_PDU_ADV_NONCONN_IND,
            random_address: bool = True) -> bytes:
    """A legacy advertising PDU (Core Spec Vol 6 Part B 2.3): header, AdvA, AdvData."""
    if len(adv_a) != defs.BLE_ADV_A_LEN or len(adv_data) > defs.BLE_ADV_DATA_MAX:
        raise ValueError("AdvA is 6 bytes, AdvData at most 31")
    h0 = (pdu_type & defs.BLE_PDU_TYPE_MASK) | (defs.BLE_PDU_TXADD if random_address else 0)
    return bytes((h0, len(adv_a) + len(adv_data))) + bytes(adv_a) + bytes(adv_data)


def ibeacon_adv_data(uuid: bytes, major: int, minor: int, measured_power: int = -59) -> bytes:
    """An iBeacon's AdvData: Flags, manufacturer data 4C 00 02 15 uuid major minor power."""
    body = (struct.pack("<H", defs.IBEACON_COMPANY_ID) + bytes((defs.IBEACON_TYPE, defs.IBEACON_LENGTH))
            + bytes(uuid) + struct.pack(">HHb", major, minor, measured_power))
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, body)


def eddystone_uid_adv_data(namespace: bytes, instance: bytes, tx_power: int = -20, rfu: bool = True) -> bytes:
    """An Eddystone-UID's AdvData: Flags, the 16-bit UUID list (FEAA), the UID service data."""
    uuid = struct.pack("<H", defs.EDDYSTONE_UUID)
    frame = bytes((defs.EDDYSTONE_FRAME_UID,)) + struct.pack("b", tx_power) + bytes(namespace) + bytes(instance)
    return (FLAGS_AD + _ad(defs.BLE_AD_UUID16_COMPLETE, uuid)
            + _ad(defs.BLE_AD_SERVICE_DATA16, uuid + frame + (b"\x00\x00" if rfu else b"")))


def altbeacon_adv_data(beacon_id: bytes, company_id: int = 0x0118, ref_rssi: int = -59, reserved: int = 0) -> bytes:
    """An AltBeacon's AdvData: Flags, manufacturer data mfg id, BE AC, id(20), ref RSSI, reserved."""
    body = (struct.pack("<H", company_id) + bytes((defs.ALTBEACON_CODE0, defs.ALTBEACON_CODE1)) + bytes(beacon_id)
            + struct.pack("bB", ref_rssi, reserved))
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, body)


def mac_frame(payload: bytes, *, seq: int = 0, frame_type: int = defs.IEEE802154_FRAME_DATA,
              version: int = 0, dst_mode: int = defs.IEEE802154_ADDR_SHORT, src_mode: int = defs.IEEE802154_ADDR_EXT,
              pan_id_compression: bool = True, dst_pan: int = defs.IEEE802154_BROADCAST,
              dst_addr: bytes = b"\xff\xff", src_pan: int = defs.IEEE802154_BROADCAST,
              src_addr: bytes = bytes(8), security: bool = False, ie_present: bool = False,
              seq_suppressed: bool = False) -> bytes:
    """An IEEE 802.15.4 MAC frame without FCS (IEEE 802.15.4-2015 7.2), any addressing
    modes; the PAN id fields follow the same rules the anchor parses with (SPEC 3.3).
    Addresses are in on-air order."""
    fcf = (frame_type & defs.IEEE802154_FRAME_TYPE_MASK) | (defs.IEEE802154_FCF_SECURITY if security else 0)
    fcf |= defs.IEEE802154_FCF_PANID_COMP if pan_id_compression else 0
    fcf |= defs.IEEE802154_FCF_SEQ_SUPPRESS if seq_suppressed else 0
    fcf |= defs.IEEE802154_FCF_IE_PRESENT if ie_present else 0
    fcf |= (dst_mode << defs.IEEE802154_FCF_DST_MODE_SHIFT) | (version << defs.IEEE802154_FCF_VERSION_SHIFT)
    fcf |= src_mode << defs.IEEE802154_FCF_SRC_MODE_SHIFT
    out = struct.pack("<H", fcf)
    if not (version == defs.IEEE802154_VERSION_2015 and seq_suppressed):
        out += bytes((seq & 0xFF,))
    comp = pan_id_compression
    if version < defs.IEEE802154_VERSION_2015:
        has_dst_pan, has_src_pan = dst_mode != 0, src_mode != 0 and not (comp and dst_mode != 0)
    elif dst_mode == 0 and src_mode == 0:
        has_dst_pan, has_src_pan = comp, False
    elif src_mode == 0:
        has_dst_pan, has_src_pan = not comp, False
    elif dst_mode == 0:
        has_dst_pan, has_src_pan = False, not comp
    elif dst_mode == src_mode == defs.IEEE802154_ADDR_EXT:
        has_dst_pan, has_src_pan = not comp, False
    else:
        has_dst_pan, has_src_pan = True, not comp
    alen = {defs.IEEE802154_ADDR_NONE: 0, 1: 0, defs.IEEE802154_ADDR_SHORT: 2, defs.IEEE802154_ADDR_EXT: 8}  # 1: reserved
    if has_dst_pan:
        out += struct.pack("<H", dst_pan)
    out += bytes(dst_addr)[:alen[dst_mode]].ljust(alen[dst_mode], b"\x00")
    if has_src_pan:
        out += struct.pack("<H", src_pan)
    out += bytes(src_addr)[:alen[src_mode]].ljust(alen[src_mode], b"\x00")
    return out + bytes(payload)


def pfdoa_802154_frame(seq: int, beacon_id: int, ext_addr: bytes,
                       pan_id: int = defs.BEACON_PAN_ID_DEFAULT) -> bytes:
    """Our beacon as an IEEE 802.15.4 data frame (SPEC 6), without the FCS the radio adds."""
    if len(ext_addr) != 8:
        raise ValueError("the beacon's extended address is 8 bytes")
    return mac_frame(pfdoa_payload(seq, beacon_id), seq=seq, dst_pan=pan_id, src_addr=ext_addr)


def pfdoa_auth_adv_data(key: bytes, counter: int, seq: int) -> bytes:
    """Our authenticated beacon's AdvData (SPEC 9.3): Flags, then manufacturer data
    company 0xFFFF with the 22-byte payload of :func:`pfdoa.protocol.auth.payload`."""
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, struct.pack("<H", defs.BEACON_COMPANY_ID)
                          + auth.payload(key, counter, seq))


def pfdoa_auth_pdu(key: bytes, counter: int, seq: int) -> bytes:
    """Its ADV_NONCONN_IND PDU from the period's private address (SPEC 9.3)."""
    return adv_pdu(auth.derive(key, counter).adv_a, pfdoa_auth_adv_data(key, counter, seq))


def pfdoa_auth_802154_frame(key: bytes, counter: int, seq: int, pan_id: int = defs.BEACON_PAN_ID_DEFAULT) -> bytes:
    """Its IEEE 802.15.4 data frame (SPEC 9.3), without the FCS: from the period's extended
    address, MAC sequence number = the low byte of eseq (never the clear seq)."""
    ids = auth.derive(key, counter)
    p = auth.payload(key, counter, seq, ids)
    return mac_frame(p, seq=p[6], dst_pan=pan_id, src_addr=ids.ext_addr)


__all__ = ["pfdoa_auth_adv_data", "pfdoa_auth_pdu", "pfdoa_auth_802154_frame", "pfdoa_payload", "pfdoa_adv_data",
           "pfdoa_v1_adv_data", "adv_pdu", "ibeacon_adv_data", "eddystone_uid_adv_data", "altbeacon_adv_data",
           "mac_frame", "pfdoa_802154_frame"]
