"""pfdoa wire protocol v1 (protocol/SPEC.md): CRC, COBS, messages, UART and CAN codecs."""
