#!/usr/bin/env python3
"""Corruption detection measured: corrupt valid UART frames and count what gets through.

Each of ``--frames`` valid anchor-to-host frames (random RSSI_REPORT / STATUS / CONFIG_ACK
from random anchors) is damaged on the wire (the COBS bytes, before the delimiter) by one
channel model, then checked by the gateway's receiver (``decode_frame`` on every piece
between delimiters, exactly what ``StreamDecoder`` does). Outcomes per model:

* ``rejected``: every piece failed a check of SPEC 2.3 (counted by the decoder);
* ``intact``: a piece decoded to the original frame (the damage missed it, e.g. an inserted
  delimiter in front of it) - not an error;
* ``wrong``: a piece was accepted with content other than the original - an UNDETECTED
  error. This is the figure that matters.

Channel models: ``flip1``/``flip2``/``flip3`` (that many distinct random bit flips),
``burst16`` (a burst of 2..16 bits: first and last bit flipped, the inside random),
``burst64`` (17..64 bits), ``multi`` (4..32 random bit flips), ``truncate`` (the frame ends
early), ``insert`` (1..8 random bytes inserted), ``delete`` (1..8 bytes removed).

The CRC-16/CCITT-FALSE (poly 0x1021, which has the factor x+1) detects every error of 1, 2
or 3 bits and every odd number of bit errors in frames up to 32,751 bits (Hamming distance
4; ours are <= 512 bits) and every burst of <= 16 bits; other errors pass with probability
about 2^-16. COBS and the fixed per-type length reject most damage before the CRC is even
looked at. ``--crc-frames`` runs the CRC-only experiment that shows the 2^-16: random
error patterns XORed into the payload and CRC of a raw frame whose header and length are
kept, so only the CRC decides.

    .venv/bin/python tools/corruption.py --frames 1000000 --crc-frames 1000000 --seed 1
"""

from __future__ import annotations

import argparse
import binascii
import json
import math
import sys
import time

import numpy as np

from pfdoa.protocol import defs
from pfdoa.protocol.cobs import cobs_encode
from pfdoa.protocol.messages import ConfigAck, RssiReport, Status
from pfdoa.protocol.uart import ANCHOR_TO_HOST, Decoded, decode_frame, encode_raw

MODELS = ("flip1", "flip2", "flip3", "burst16", "burst64", "multi", "truncate", "insert", "delete")
CRC_UNDETECTED = 2.0 ** -16


def _frame(rng: np.random.Generator):
    """A random valid anchor-to-host message and its anchor id."""
    k = rng.random()
    a = int(rng.integers(0, 127))
    u = lambda bits: int(rng.integers(0, 1 << bits))  # noqa: E731
    if k < 0.8:
        m = RssiReport(u(16), u(32), u(16) - 32768, u(8) - 128, u(8), u(8), u(8))
    elif k < 0.95:
        m = Status(u(8), u(8), u(32), u(16), u(16), u(16), u(16), u(16))
    else:
        m = ConfigAck(u(8), u(8), u(16))
    return m, a


def _flip_bits(b: bytearray, bits) -> None:
    for i in bits:
        b[i >> 3] ^= 0x80 >> (i & 7)


def corrupt(wire: bytes, model: str, rng: np.random.Generator) -> bytes:
    """One channel model applied to the COBS block ``wire`` (no delimiter)."""
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


def run(n_frames: int, seed: int = 1, models: tuple[str, ...] = MODELS) -> dict:
    """Corrupt ``n_frames`` frames (models in turn); per-model outcome counts."""
    rng = np.random.default_rng(seed)
    out = {m: {"frames": 0, "rejected": 0, "intact": 0, "wrong": 0, "crc_checked": 0, "examples": []}
           for m in models}
    for i in range(n_frames):
        model = models[i % len(models)]
        msg, a = _frame(rng)
        wire = cobs_encode(encode_raw(msg, a))
        bad = corrupt(wire, model, rng)
        r = out[model]
        r["frames"] += 1
        verdict = "rejected"
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
    """Random error patterns on payload+CRC of RSSI_REPORT raw frames (header and length
    kept): the fraction that passes is the CRC's own undetected-error rate."""
    rng = np.random.default_rng(seed)
    extra = bytes((defs.MESSAGES["RSSI_REPORT"][3],))
    n_raw = defs.HEADER_LEN + defs.MESSAGES["RSSI_REPORT"][2] + defs.CRC_LEN
    passed = 0
    hqx = binascii.crc_hqx
    frames = rng.integers(0, 256, size=(n_frames, n_raw), dtype=np.uint8)
    errors = rng.integers(0, 256, size=(n_frames, n_raw - defs.HEADER_LEN), dtype=np.uint8)
    for i in range(n_frames):
        raw = bytearray(frames[i].tobytes())
        raw[0], raw[1] = 1, defs.MSG_RSSI_REPORT
        crc = hqx(extra, hqx(bytes(raw[:-2]), 0xFFFF))
        raw[-2:] = crc.to_bytes(2, "little")
        e = errors[i].tobytes()
        if not any(e):
            e = b"\x01" + e[1:]  # an error pattern is non-zero
        bad = raw[:3] + bytes(x ^ y for x, y in zip(raw[3:], e))
        if hqx(extra, hqx(bytes(bad[:-2]), 0xFFFF)) == bad[-2] | (bad[-1] << 8):
            passed += 1
    return {"frames": n_frames, "passed": passed, "rate": passed / n_frames, "theory": CRC_UNDETECTED,
            "expected": n_frames * CRC_UNDETECTED}


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
        lines += ["", f"CRC only (random error patterns, header and length kept): {crc['passed']} of "
                      f"{crc['frames']} passed = {crc['rate']:.2e} (theory 2^-16 = {crc['theory']:.2e}, "
                      f"expected {crc['expected']:.1f})"]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--crc-frames", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    t0 = time.monotonic()
    res = run(a.frames, a.seed)
    crc = run_crc_only(a.crc_frames, a.seed + 1) if a.crc_frames else None
    if a.json:
        print(json.dumps({"models": res, "crc_only": crc, "seconds": time.monotonic() - t0}, indent=1))
    else:
        print(table(res, crc))
        print(f"\n({time.monotonic() - t0:.0f} s, seed {a.seed})")
    guaranteed = ("flip1", "flip2", "flip3", "burst16")
    return 1 if any(res[m]["wrong"] for m in guaranteed if m in res) else 0


if __name__ == "__main__":
    sys.exit(main())
