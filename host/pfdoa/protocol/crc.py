"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR), SPEC 2.2."""

from __future__ import annotations

import binascii

CRC_INIT = 0xFFFF
CRC_POLY = 0x1021


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC_POLY) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE: tuple[int, ...] = _make_table()


def crc16_table(data: bytes, crc: int = CRC_INIT) -> int:
    """Table-driven reference (the algorithm the firmware runs); slow in CPython."""
    table = CRC_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ b]
    return crc


def crc16(data: bytes, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE of `data`, continuing from `crc`.

    binascii.crc_hqx is the same polynomial without reflection, computed in C; the
    tests check it against crc16_table on random data.
    """
    return binascii.crc_hqx(data, crc)


def crc_extra(definition: str) -> int:
    """SPEC 1.6: fold the CRC of a message's definition string into one byte."""
    c = crc16(definition.encode("ascii"))
    return (c & 0xFF) ^ (c >> 8)
