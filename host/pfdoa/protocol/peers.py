"""An anchor's own advertisement (SPEC 6.1): what an anchor with an ``ANCHORS`` filter entry
transmits every ``period_ms`` so that the other anchors can report hearing it (peer
readings, SPEC 3.5), as the C core and the MicroPython anchor build it.

The reference for the golden vectors (protocol/vectors/peer.json "builds"); parsed by
:mod:`pfdoa.protocol.filters`. The layout is our beacon's (SPEC 6) with the magic 'P' 'N'
and the anchor's id in place of the beacon id.
"""

from __future__ import annotations

import struct

from . import defs
from .beacons import FLAGS_AD, _ad, adv_pdu, mac_frame

ADDRESS_LEN = {defs.RADIO_BLE: defs.BLE_ADV_A_LEN, defs.RADIO_IEEE802154: defs.IEEE802154_EXT_ADDR_LEN}


def anchor_payload(seq: int, anchor_id: int) -> bytes:
    """'P' 'N', seq u16 little-endian, anchor id."""
    if not 0 <= anchor_id <= defs.ANCHOR_ID_MAX:
        raise ValueError(f"anchor id {anchor_id} out of range 0..{defs.ANCHOR_ID_MAX}")
    return bytes((defs.BEACON_MAGIC0, defs.ANCHOR_MAGIC1)) + (seq & 0xFFFF).to_bytes(2, "little") + bytes((anchor_id,))


def anchor_adv_data(seq: int, anchor_id: int) -> bytes:
    """The AdvData: Flags, then manufacturer data with company 0xFFFF (12 bytes)."""
    return FLAGS_AD + _ad(defs.BLE_AD_MANUFACTURER, struct.pack("<H", defs.BEACON_COMPANY_ID)
                          + anchor_payload(seq, anchor_id))


def anchor_frame(radio: int, address: bytes, anchor_id: int, seq: int) -> bytes:
    """What the radio sends: over BLE an ``ADV_NONCONN_IND`` PDU from AdvA ``address`` (6
    bytes, on-air order); over IEEE 802.15.4 a data frame to the broadcast address of the
    broadcast PAN from the extended address ``address`` (8 bytes, on-air order), MAC
    sequence number ``seq & 0xFF``, without the FCS the radio adds."""
    if radio not in ADDRESS_LEN:
        raise ValueError(f"unknown radio {radio}")
    if len(address) != ADDRESS_LEN[radio]:
        raise ValueError(f"this radio's address is {ADDRESS_LEN[radio]} bytes, not {len(address)}")
    if radio == defs.RADIO_BLE:
        return adv_pdu(bytes(address), anchor_adv_data(seq, anchor_id))
    return mac_frame(anchor_payload(seq, anchor_id), seq=seq, dst_pan=defs.IEEE802154_BROADCAST,
                     src_addr=bytes(address))


__all__ = ["ADDRESS_LEN", "anchor_payload", "anchor_adv_data", "anchor_frame"]
