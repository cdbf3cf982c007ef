"""pfdoa wire protocol (protocol/SPEC.md), version 2, decoding version 1 too: CRC, COBS,
messages, UART and CAN codecs, beacon filters and what beacons transmit.

The reference anchor model (SPEC 3) is in `pfdoa.protocol.anchor_model`, the event-script
runner in `pfdoa.protocol.script`, the random scripts of the differential checks in
`pfdoa.protocol.scriptgen`.
"""

from . import defs
from .beacons import (
                      adv_pdu,
                      altbeacon_adv_data,
                      eddystone_uid_adv_data,
                      ibeacon_adv_data,
                      mac_frame,
                      pfdoa_802154_frame,
                      pfdoa_adv_data,
)
from .can import GATEWAY_CAN_FILTERS, anchor_can_filters, can_id_for, decode_can, encode_can, is_report_id
from .cobs import CobsError, cobs_decode, cobs_encode
from .config import AnchorConfig
from .crc import crc16, crc16_table, crc_extra
from .defs import DecodeError
from .filters import BeaconFilter, Match, default_table, match_802154, match_ble_adv, match_ble_pdu, table_hash
from .messages import (
                      BY_NAME,
                      BY_TYPE,
                      ConfigAck,
                      ConfigSet,
                      FilterAck,
                      FilterSet,
                      Message,
                      RadioInject,
                      RadioInjectRaw,
                      RssiReport,
                      Status,
                      StatusA,
                      StatusB,
                      StatusC,
)
from .uart import (
                      ALL_TYPES,
                      ANCHOR_TO_HOST,
                      COUNTER_NAMES,
                      HOST_TO_ANCHOR,
                      REPORT_TYPES,
                      Decoded,
                      StreamDecoder,
                      decode_frame,
                      encode_block,
                      encode_raw,
                      encode_uart,
                      frame_type,
                      is_report_type,
                      seal,
)

ERRORS = defs.ERRORS
PROTO_VERSION = defs.PROTO_VERSION
VERSIONS = defs.VERSIONS

__all__ = [
    "defs", "ERRORS", "PROTO_VERSION", "VERSIONS", "DecodeError", "AnchorConfig", "crc16", "crc16_table",
    "crc_extra", "cobs_encode", "cobs_decode", "CobsError", "RssiReport", "Status", "StatusA", "StatusB",
    "StatusC", "ConfigSet", "ConfigAck", "FilterSet", "FilterAck", "RadioInject", "RadioInjectRaw", "Message",
    "BY_NAME", "BY_TYPE", "Decoded", "encode_raw", "encode_block", "encode_uart", "seal", "decode_frame",
    "frame_type", "is_report_type", "StreamDecoder", "COUNTER_NAMES", "ALL_TYPES", "ANCHOR_TO_HOST",
    "HOST_TO_ANCHOR", "REPORT_TYPES", "can_id_for", "encode_can", "decode_can", "is_report_id",
    "GATEWAY_CAN_FILTERS", "anchor_can_filters", "BeaconFilter", "Match", "default_table", "table_hash",
    "match_ble_adv", "match_ble_pdu", "match_802154", "pfdoa_adv_data", "pfdoa_802154_frame", "adv_pdu",
    "ibeacon_adv_data", "eddystone_uid_adv_data", "altbeacon_adv_data", "mac_frame",
]
