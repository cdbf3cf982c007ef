#!/usr/bin/env python3
"""Corruption detection measured: corrupt valid UART frames and count what gets through.

Each of ``--frames`` valid anchor-to-host frames (random RSSI_REPORT / STATUS / CONFIG_ACK /
FILTER_ACK from random anchors, protocol ``--version`` 2 unless told) is damaged on the
wire (the bytes between the delimiters) by one channel model, then checked by the
gateway's receiver (``decode_frame`` on every piece between delimiters, exactly what
``StreamDecoder`` does). Outcomes per model:

* ``rejected``: every piece failed a check of SPEC 2.3 (counted by the decoder);
* ``intact``: a piece decoded to the original frame (the damage missed it, e.g. an inserted
  delimiter in front of it) - not an error;
* ``wrong``: a piece was accepted with content other than the original - an UNDETECTED
  error. This is the figure that matters.

Channel models: ``flip1``/``flip2``/``flip3`` (that many distinct random bit flips),
``burst16`` (a burst of 2..16 bits: first and last bit flipped, the inside random),
``burst64`` (17..64 bits), ``multi`` (4..32 random bit flips), ``truncate`` (the frame ends
early), ``insert`` (1..8 random bytes inserted), ``delete`` (1..8 bytes removed).

Version 2 puts the CRC-16/CCITT-FALSE over the encoded bytes (SPEC 2.1, 2.4), so an error
that leaves the delimiters where they were is an error of the same weight in the CRC's
codeword: every 1-, 2- and 3-bit error and every burst of <= 16 bits is detected (Hamming
distance 4 up to 32,751 bits; ours are <= 512), other errors pass with probability about
2^-16. Version 1 (CRC over the decoded bytes) does not have that guarantee: a flipped COBS
code byte moves the decoded zeros.

``--crc-frames`` runs the CRC-only experiment that shows the 2^-16, through the real
decoder: a random error pattern on the payload of a valid frame's body and on the CRC bits
of its trailer, the damaged body COBS-encoded again (so COBS, version, type and length all
pass) and the frame handed to ``decode_frame``; only the CRC comparison can reject it.

``--exhaustive`` flips every single bit and every pair of bits (delimiter included) of
every golden frame in protocol/vectors/uart.json and counts what the decoder accepts.

    .venv/bin/python tools/corruption.py --frames 1000000 --crc-frames 1000000 --exhaustive --seed 1
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from itertools import combinations
from pathlib import Path
from typing import Literal, TypedDict

import numpy as np

from pfdoa.protocol import defs
from pfdoa.protocol.cobs import cobs_encode
from pfdoa.protocol.messages import ConfigAck, FilterAck, Message, RssiReport, Status
from pfdoa.protocol.uart import (
    ALL_TYPES,
    ANCHOR_TO_HOST,
    Decoded,
    decode_frame,
    encode_block,
    encode_raw,
    trailer,
    trailer_value,
)

MODELS = ("flip1", "flip2", "flip3", "burst16", "burst64", "multi", "truncate", "insert", "delete")
GUARANTEED = ("flip1", "flip2", "flip3", "burst16")
CRC_UNDETECTED = 2.0 ** -16
VECTORS = Path(__file__).resolve().parent.parent / "protocol" / "vectors" / "uart.json"

Verdict = Literal["rejected", "intact", "wrong"]


class ModelCounts(TypedDict):
    """Outcome counts of one channel model in :func:`run` (a plain dict at run time)."""

    frames: int
    rejected: int
    intact: int
    wrong: int
    crc_checked: int
    examples: list[dict[str, str]]


def _frame(rng: np.random.Generator, version: int = defs.PROTO_VERSION) -> tuple[Message, int]:
    """A random valid anchor-to-host message (fields of `version`) and its anchor id."""
    k = rng.random()
    a = int(rng.integers(0, defs.ANCHOR_ID_MAX + 1))
    u = lambda bits: int(rng.integers(0, 1 << bits))  # noqa: E731
    v2 = version == defs.PROTO_VERSION
    m: Message
    if k < 0.8:
        m = RssiReport(u(16), u(32), u(16) - 32768, u(8) - 128, u(8), u(8), u(8),
                       int(rng.integers(0, defs.BEACON_SLOTS)) if v2 else 0)
    elif k < 0.95:
        m = Status(u(8), u(8), u(32), u(16), u(16), u(16), u(16), u(16), u(16) if v2 else 0, u(8) if v2 else 0)
    elif k < 0.975 or not v2:
        m = ConfigAck(u(8), u(8), u(16))
    else:
        m = FilterAck(u(8), u(8), u(8), u(16))
    return m, a


def _flip_bits(b: bytearray, bits) -> None:
    for i in bits:
        b[i >> 3] ^= 0x80 >> (i & 7)


def corrupt(wire: bytes, model: str, rng: np.random.Generator) -> bytes:
    """One channel model applied to the frame block ``wire`` (no delimiter)."""
    b = bytearray(wire)
    nbits = 8 * len(b)
    if model in ("flip1", "flip2", "flip3", "multi"):
        k = {"flip1": 1, "flip2": 2, "flip3": 3}.get(model) or int(rng.integers(4, 33))
        _flip_bits(b, rng.choice(nbits, size=min(k, nbits), replace=False))
    elif model in ("burst16", "burst64"):
        lo, hi = (2, 16) if model == "burst16" else (17, 64)
        n = min(int(rng.integers(lo, hi + 1)), nbits)
        start = int(rng.integers(0, nbits - n + 1))
        inside = [start + 1 + i for i in np.flatnonzero(rng.random(max(n - 2, 0)) < 0.5)]
        _flip_bits(b, [start, start + n - 1, *inside])
    elif model == "truncate":
        del b[int(rng.integers(1, len(b))):]
    elif model == "insert":
        at = int(rng.integers(0, len(b) + 1))
        b[at:at] = rng.bytes(int(rng.integers(1, 9)))
    elif model == "delete":
        at = int(rng.integers(0, len(b)))
        del b[at:at + int(rng.integers(1, 9))]
    else:
        raise ValueError(f"unknown model {model!r}")
    return bytes(b)


def run(n_frames: int, seed: int = 1, models: tuple[str, ...] = MODELS,
        version: int = defs.PROTO_VERSION) -> dict[str, ModelCounts]:
    """Corrupt ``n_frames`` frames of `version` (models in turn); per-model outcome counts."""
    rng = np.random.default_rng(seed)
    out: dict[str, ModelCounts] = {m: {"frames": 0, "rejected": 0, "intact": 0, "wrong": 0, "crc_checked": 0, "examples": []}
           for m in models}
    for i in range(n_frames):
        model = models[i % len(models)]
        msg, a = _frame(rng, version)
        wire = encode_block(msg, a, version)
        bad = corrupt(wire, model, rng)
        r = out[model]
        r["frames"] += 1
        verdict: Verdict = "rejected"
        reached_crc = False  # some piece passed COBS, version, type and length
        for piece in bad.split(b"\x00"):
            if not piece:
                continue
            d = decode_frame(piece, ANCHOR_TO_HOST)
            reached_crc |= d == "bad_crc" or (isinstance(d, Decoded) and d.message != msg)
            if isinstance(d, Decoded):
                if d.anchor_id == a and d.message == msg:
                    verdict = "intact" if verdict == "rejected" else verdict
                else:
                    verdict = "wrong"
                    if len(r["examples"]) < 3:
                        r["examples"].append({"sent": wire.hex(), "received": bad.hex()})
        r[verdict] += 1
        r["crc_checked"] += reached_crc
    return out


def run_crc_only(n_frames: int, seed: int = 2) -> dict:
    """Random error patterns that only the CRC can see, through ``decode_frame``.

    A valid version-2 frame's body payload and trailer CRC bits get a random non-zero error
    pattern; the damaged body is COBS-encoded again so that COBS, version, type and length
    pass. Returns how many the decoder accepted (``passed``) and how it rejected the rest
    (``bad_crc`` must be all of them)."""
    rng = np.random.default_rng(seed)
    passed = bad_crc = other = 0
    for _ in range(n_frames):
        msg, a = _frame(rng)
        wire = encode_block(msg, a)
        body = encode_raw(msg, a)
        crc = trailer_value(wire[-defs.TRAILER_LEN:])
        if crc is None:  # encode_block always writes a valid trailer
            raise RuntimeError(f"encode_block wrote a bad trailer: {wire.hex()}")
        e = rng.integers(0, 256, size=len(body) - defs.HEADER_LEN, dtype=np.uint8).tobytes()
        e_crc = int(rng.integers(0, 1 << 16))
        if not any(e) and not e_crc:
            e_crc = 1  # an error pattern is non-zero
        bad_body = body[:defs.HEADER_LEN] + bytes(x ^ y for x, y in zip(body[defs.HEADER_LEN:], e))
        d = decode_frame(cobs_encode(bad_body) + trailer(crc ^ e_crc), ALL_TYPES)
        if isinstance(d, Decoded):
            passed += 1
        elif d == "bad_crc":
            bad_crc += 1
        else:
            other += 1
    return {"frames": n_frames, "passed": passed, "bad_crc": bad_crc, "other": other,
            "rate": passed / n_frames, "theory": CRC_UNDETECTED, "expected": n_frames * CRC_UNDETECTED}


def golden_frames(version: int = defs.PROTO_VERSION) -> list[bytes]:
    """The wire bytes (delimiter included) of every golden frame of `version`."""
    vectors = json.loads(VECTORS.read_text())["vectors"]
    return [bytes.fromhex(v["frame"]) for v in vectors if v["version"] == version]


def code_byte_positions(block: bytes) -> frozenset[int]:
    """Where the COBS code bytes of a valid block (no delimiter) are."""
    out, i = set(), 0
    while i < len(block):
        out.add(i)
        i += block[i]
    return frozenset(out)


def exhaustive(frames: list[bytes], max_flips: int = 2, types=ALL_TYPES, versions=None) -> dict:
    """Flip every combination of 1..max_flips bits of each frame (wire bytes with the
    delimiter) and decode every piece between delimiters (a delimiter is assumed before
    the frame and added after it, so a destroyed delimiter joins it to that empty end).

    Returns per flip count the patterns tried and accepted, and the accepted examples
    (frame, flipped bit positions) with whether a COBS code byte was among the flipped."""
    out = {k: {"frames": len(frames), "patterns": 0, "accepted": 0} for k in range(1, max_flips + 1)}
    accepted = []
    for wire in frames:
        codes = code_byte_positions(wire[:-1])
        nbits = 8 * len(wire)
        for k in range(1, max_flips + 1):
            r = out[k]
            for bits in combinations(range(nbits), k):
                b = bytearray(wire)
                _flip_bits(b, bits)
                r["patterns"] += 1
                for piece in bytes(b).split(b"\x00"):
                    if piece and isinstance(decode_frame(piece, types, versions), Decoded):
                        r["accepted"] += 1
                        accepted.append({"frame": wire.hex(), "bits": bits,
                                         "code_byte": any((i >> 3) in codes for i in bits)})
                        break
    return {"by_flips": out, "accepted": accepted}


def upper95(k: int, n: int) -> float:
    """One-sided 95 % upper bound on a rate with k events in n trials (exact for k = 0:
    1 - 0.05^(1/n), about 3/n; normal approximation on the Poisson count otherwise)."""
    if n == 0:
        return math.nan
    if k == 0:
        return 1.0 - 0.05 ** (1.0 / n)
    return (k + 1.645 * math.sqrt(k) + 1.0) / n


def table(res: dict, crc: dict | None) -> str:
    lines = ["| model | frames | rejected | intact | reached the CRC | accepted wrong | rate | "
             "95 % upper bound | 2^-16 x reached |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    tot = {"frames": 0, "rejected": 0, "intact": 0, "crc_checked": 0, "wrong": 0}
    for m, r in list(res.items()) + [("**all**", tot)]:
        if r is not tot:
            for k in tot:
                tot[k] += r[k]
        lines.append(f"| {m} | {r['frames']} | {r['rejected']} | {r['intact']} | {r['crc_checked']} | {r['wrong']} | "
                     f"{r['wrong'] / max(r['frames'], 1):.2e} | {upper95(r['wrong'], r['frames']):.2e} | "
                     f"{r['crc_checked'] * CRC_UNDETECTED:.2f} |")
    if crc:
        lines += ["", f"CRC only (random error patterns on payload and trailer CRC, framing kept, through "
                      f"decode_frame): {crc['passed']} of {crc['frames']} passed = {crc['rate']:.2e} (theory "
                      f"2^-16 = {crc['theory']:.2e}, expected {crc['expected']:.1f}); rejected bad_crc "
                      f"{crc['bad_crc']}, otherwise {crc['other']}"]
    return "\n".join(lines)


def exhaustive_table(ex: dict[int, dict]) -> str:
    lines = ["| frames | version | flips | patterns | accepted | of which a COBS code byte was flipped |",
             "|---|---:|---:|---:|---:|---:|"]
    for version, e in ex.items():
        for k, r in e["by_flips"].items():
            acc = [x for x in e["accepted"] if len(x["bits"]) == k]
            lines.append(f"| golden (uart.json) | {version} | {k} | {r['patterns']} | {r['accepted']} | "
                         f"{sum(x['code_byte'] for x in acc)} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--crc-frames", type=int, default=1_000_000)
    ap.add_argument("--version", type=int, choices=defs.VERSIONS, default=defs.PROTO_VERSION,
                    help="protocol version of the random frames (default %(default)s)")
    ap.add_argument("--exhaustive", action="store_true",
                    help="also flip every 1 and 2 bits of every golden frame of both versions")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    t0 = time.monotonic()
    res = run(a.frames, a.seed, version=a.version)
    crc = run_crc_only(a.crc_frames, a.seed + 1) if a.crc_frames else None
    ex = {v: exhaustive(golden_frames(v)) for v in sorted(defs.VERSIONS, reverse=True)} if a.exhaustive else None
    if a.json:
        print(json.dumps({"models": res, "crc_only": crc, "exhaustive": ex, "seconds": time.monotonic() - t0},
                         indent=1, default=list))
    else:
        print(table(res, crc))
        if ex:
            print()
            print(exhaustive_table(ex))
        print(f"\n({time.monotonic() - t0:.0f} s, seed {a.seed}, version {a.version})")
    failed = a.version == defs.PROTO_VERSION and any(res[m]["wrong"] for m in GUARANTEED if m in res)
    failed |= bool(ex and ex[defs.PROTO_VERSION]["accepted"])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
