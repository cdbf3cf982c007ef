#!/usr/bin/env python3
"""Gateway stress: N report frames with garbage, loss, duplicates and reordering.

The stream is generated lazily (so the input itself does not dominate memory), cut into
random chunks, and fed through the real gateway path (one protocol ``StreamDecoder`` +
``SeqReassembler`` inside :class:`pfdoa.gateway.pipeline.Gateway`). Every injected fault is
counted by the generator and compared with the gateway's counters:

* garbage: random junk blocks (about ``--garbage`` of all bytes) each ending with a 0x00,
  so every non-empty junk piece between delimiters is exactly one decode error;
* loss: a report is not sent (never in the first or last beacon, so every loss is visible
  as a sequence gap);
* duplicates: a report is sent again 1..8 frames later;
* reordering: adjacent frames swapped.

Memory: tracemalloc's peak while the gateway runs (after a warm-up), and the process's
max RSS. Usage::

    .venv/bin/python tools/gateway_stress.py --frames 1000000
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
import tracemalloc
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from pfdoa.api import Chunk, Gateway, Health, SeqReassembler
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart

BEACON_PERIOD_S = 0.02


@dataclass
class Injected:
    frames_sent: int = 0  # report frames on the wire (originals + duplicate copies)
    lost: Counter = field(default_factory=Counter)  # per anchor
    duplicates: int = 0
    swaps: int = 0
    garbage_bytes: int = 0
    garbage_pieces: int = 0  # non-empty junk pieces between delimiters = decode errors
    total_bytes: int = 0
    beacons: int = 0
    beacons_with_any: int = 0
    beacons_complete: int = 0
    missing_in_sets: int = 0


def stream(n_frames: int, anchors: tuple[int, ...], rng: np.random.Generator, garbage: float = 0.10,
           loss: float = 0.05, dup: float = 0.01, reorder: float = 0.01, inj: Injected | None = None):
    """Yield (t, bytes) pieces of the wire stream; fill ``inj`` with what was injected."""
    inj = inj if inj is not None else Injected()
    n_beacons = max(3, n_frames // len(anchors))
    inj.beacons = n_beacons
    pending: list[tuple[int, bytes]] = []  # (release index, frame) duplicate copies
    idx = 0
    prev: bytes | None = None
    # Junk share: a junk block of mean length L after a frame with probability p gives
    # garbage/(1-garbage) bytes of junk per frame byte.
    frame_len = 19
    mean_junk = 40
    p_junk = min(1.0, garbage / (1.0 - garbage) * frame_len / mean_junk)

    def junk() -> bytes:
        n = int(rng.integers(1, 2 * mean_junk))
        b = rng.integers(0, 256, size=n, dtype=np.uint8).tobytes() + b"\x00"
        inj.garbage_bytes += len(b)
        inj.garbage_pieces += sum(1 for piece in b.split(b"\x00") if piece)
        return b

    def emit(frame: bytes) -> bytes:
        nonlocal idx
        out = frame
        idx += 1
        while pending and pending[0][0] <= idx:
            out += pending.pop(0)[1]
            inj.frames_sent += 1
        if rng.random() < p_junk:
            out += junk()
        return out

    for s in range(n_beacons):
        t = s * BEACON_PERIOD_S
        delivered = 0
        buf = b""
        for a in anchors:
            if 0 < s < n_beacons - 1 and rng.random() < loss:
                inj.lost[a] += 1
                continue
            delivered += 1
            rep = RssiReport(s & 0xFFFF, (1000 + 20 * s) & 0xFFFFFFFF, int(-6000 - 100 * a), -60, 1, 37, 0)
            frame = encode_uart(rep, a)
            inj.frames_sent += 1
            if rng.random() < dup:
                inj.duplicates += 1
                pending.append((idx + int(rng.integers(1, 9)), frame))
                pending.sort(key=lambda p: p[0])
            if prev is not None and rng.random() < reorder:
                inj.swaps += 1
                buf += emit(frame) + emit(prev)
                prev = None
                continue
            if prev is not None:
                buf += emit(prev)
            prev = frame
        if delivered:
            inj.beacons_with_any += 1
            inj.missing_in_sets += len(anchors) - delivered
        if delivered == len(anchors):
            inj.beacons_complete += 1
        if buf:
            inj.total_bytes += len(buf)
            yield t, buf
    tail = (prev or b"") + b"".join(f for _, f in pending)
    inj.frames_sent += len(pending)
    inj.total_bytes += len(tail)
    yield n_beacons * BEACON_PERIOD_S, tail


def run(n_frames: int, seed: int = 1, anchors: tuple[int, ...] = (0, 1, 2, 3), trace_memory: bool = True,
        warmup_frames: int = 20000) -> dict:
    rng = np.random.default_rng(seed)
    inj = Injected()
    grouper = SeqReassembler(anchors, set_timeout_s=0.25, max_open_sets=64, stale_after_s=3.0)
    health = Health()
    sets: Counter[str] = Counter()  # sets emitted, per reason
    missing = 0

    def on_set(s) -> None:
        nonlocal missing
        sets[s.reason] += 1
        missing += len(s.missing)

    gw = Gateway(grouper, on_set, health)
    chunk_rng = np.random.default_rng(seed + 1)
    carry = b""
    warm_bytes = warmup_frames * 19
    traced = False
    peak = 0
    t0 = time.perf_counter()
    fed = 0
    for t, data in stream(n_frames, anchors, rng, inj=inj):
        carry += data
        # Cut into chunks of random size, like reads from a serial port; what is left (a
        # partial frame) waits for the next beacon's bytes.
        while carry:
            k = int(chunk_rng.integers(1, 257))
            if k > len(carry):
                break
            gw.feed(Chunk("serial0", t, carry[:k]))
            carry = carry[k:]
            fed += k
        gw.poll(t)
        if trace_memory and not traced and fed >= warm_bytes:
            tracemalloc.start()
            traced = True
    gw.feed(Chunk("serial0", t, carry))
    gw.poll(t + 1.0)  # past every set timeout, before any anchor would turn stale
    gw.finish()
    elapsed = time.perf_counter() - t0
    if traced:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    summary = health.summary(grouper)
    return {
        "frames": n_frames,
        "seconds": round(elapsed, 2),
        "frames_per_s": round(inj.frames_sent / elapsed),
        "injected": {
            "frames_sent": inj.frames_sent,
            "lost": {str(a): inj.lost[a] for a in anchors},
            "duplicates": inj.duplicates,
            "swaps": inj.swaps,
            "garbage_bytes": inj.garbage_bytes,
            "garbage_share": round(inj.garbage_bytes / max(1, inj.total_bytes), 4),
            "garbage_pieces": inj.garbage_pieces,
            "beacons_with_any": inj.beacons_with_any,
            "beacons_complete": inj.beacons_complete,
            "missing_in_sets": inj.missing_in_sets,
        },
        "gateway": {
            "frames": summary["frames"],
            "errors": summary["errors"],
            "errors_total": sum(summary["errors"].values()),
            "lost": {a: s["lost"] for a, s in summary["anchors"].items()},
            "duplicates": summary["duplicates"],
            "late": summary["late"],
            "reordered": sum(s["reordered"] for s in summary["anchors"].values()),
            "sets": summary["sets"],
            "complete": summary["complete"],
            "missing_in_sets": missing,
            "evicted": summary["evicted"],
            "set_reasons": dict(sets),
        },
        "memory": {
            "tracemalloc_peak_bytes_after_warmup": peak,
            "max_rss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
        },
    }


def check(r: dict) -> list[str]:
    """Mismatches between what was injected and what the gateway counted."""
    i, g = r["injected"], r["gateway"]
    bad = []
    for name, want, got in [
        ("frames", i["frames_sent"], g["frames"]),
        ("decode errors", i["garbage_pieces"], g["errors_total"]),
        ("lost per anchor", i["lost"], g["lost"]),
        ("duplicates", i["duplicates"], g["duplicates"]),
        ("late", 0, g["late"]),
        ("sets", i["beacons_with_any"], g["sets"]),
        ("complete sets", i["beacons_complete"], g["complete"]),
        ("missing anchors in sets", i["missing_in_sets"], g["missing_in_sets"]),
        ("evicted", 0, g["evicted"]),
    ]:
        if want != got:
            bad.append(f"{name}: injected {want}, gateway {got}")
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-tracemalloc", action="store_true", help="faster; RSS only")
    args = ap.parse_args()
    r = run(args.frames, args.seed, trace_memory=not args.no_tracemalloc)
    bad = check(r)
    r["ok"] = not bad
    print(json.dumps(r, indent=1))
    for b in bad:
        print("MISMATCH:", b, file=sys.stderr)
    return 0 if not bad else 1


if __name__ == "__main__":
    raise SystemExit(main())
