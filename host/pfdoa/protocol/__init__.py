"""pfdoa wire protocol v1 (protocol/SPEC.md): CRC, COBS, messages, UART and CAN codecs.

The reference anchor model (SPEC 3) is in `pfdoa.protocol.anchor_model`, the event-script
runner in `pfdoa.protocol.script`.
"""

from . import defs
from .can import GATEWAY_CAN_FILTERS, anchor_can_filters, can_id_for, decode_can, encode_can
from .cobs import CobsError, cobs_decode, cobs_encode
from .config import AnchorConfig
from .crc import crc16, crc16_table, crc_extra
from .defs import DecodeError
from .messages import (BY_NAME, BY_TYPE, ConfigAck, ConfigSet, Message, RadioInject,
                       RssiReport, Status, StatusA, StatusB)
from .uart import (ALL_TYPES, ANCHOR_TO_HOST, COUNTER_NAMES, HOST_TO_ANCHOR, Decoded,
                   StreamDecoder, decode_frame, encode_raw, encode_uart)

ERRORS = defs.ERRORS

__all__ = [
    "defs", "ERRORS", "DecodeError", "AnchorConfig", "crc16", "crc16_table", "crc_extra", "cobs_encode", "cobs_decode",
    "CobsError", "RssiReport", "Status", "StatusA", "StatusB", "ConfigSet", "ConfigAck",
    "RadioInject", "Message", "BY_NAME", "BY_TYPE", "Decoded", "encode_raw", "encode_uart",
    "decode_frame", "StreamDecoder", "COUNTER_NAMES", "ALL_TYPES", "ANCHOR_TO_HOST",
    "HOST_TO_ANCHOR", "can_id_for", "encode_can", "decode_can", "GATEWAY_CAN_FILTERS",
    "anchor_can_filters",
]
