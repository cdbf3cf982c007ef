"""Consistent Overhead Byte Stuffing (Cheshire & Baker 1999), SPEC 2.1.

The encoded block has no zero bytes; each code byte c (1..255) is followed by c-1 data
bytes and implies a zero after the group unless c == 255 or the group ends the block.
"""

from __future__ import annotations


class CobsError(ValueError):
    """The input is not a valid COBS block (zero byte inside, or a code past the end)."""


def cobs_encode(data: bytes) -> bytes:
    """Encode `data`; the result has no 0x00 and is at most 1 + len//254 bytes longer."""
    out = bytearray()
    groups = bytes(data).split(b"\x00")
    last = len(groups) - 1
    for i, group in enumerate(groups):
        n = len(group)
        pos = 0
        # Full 254-byte runs carry code 255 (no implied zero).
        while n - pos >= 254:
            out.append(255)
            out += group[pos:pos + 254]
            pos += 254
        if i == last and pos and pos == n:
            break  # block ends right after a 255 group: nothing left to say
        out.append(n - pos + 1)
        out += group[pos:]
    return bytes(out)


def cobs_decode(block: bytes) -> bytes:
    """Decode one COBS block (without its delimiter); raise CobsError if malformed."""
    if b"\x00" in block:
        raise CobsError("zero byte inside a COBS block")
    out = cobs_decode_unchecked(block)
    if out is None:
        raise CobsError("COBS code byte points past the end of the block")
    return out


def cobs_decode_unchecked(block: bytes) -> bytes | None:
    """Decode a block known to hold no 0x00 (e.g. one piece of bytes.split(b"\\0")).

    Returns None when a code byte points past the end. Hot path of the gateway.
    """
    n = len(block)
    if n == 0:
        return None
    c = block[0]
    if c >= n:
        # The common short-frame case: one group, no zero inside the data.
        return block[1:] if c == n else None
    if n < 255:
        # No code 255 can be valid here (its group would end past the block), so every
        # code byte after the first stands for one zero: write the zeros over the codes in
        # a copy (a fraction of the group-by-group copying below). A code that points past
        # the end leaves i > n.
        buf = bytearray(block)
        i = c
        while i < n:
            buf[i] = 0
            i += block[i]
        if i > n:
            return None
        del buf[0]
        return bytes(buf)
    out = bytearray()
    i = 0
    while i < n:
        c = block[i]
        j = i + c
        if j > n:
            return None
        out += block[i + 1:j]
        if c != 255 and j < n:
            out.append(0)
        i = j
    return bytes(out)
