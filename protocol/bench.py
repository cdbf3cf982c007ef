#!/usr/bin/env python3
"""Throughput of the Python gateway codec (benchmark, not a test: CI timing is noisy).

    python protocol/bench.py [n_frames]
"""

from __future__ import annotations

import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "host"))

from pfdoa.protocol import RssiReport, StreamDecoder, decode_can, encode_can, encode_uart  # noqa: E402


def main() -> int:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    rng = random.Random(1)
    msgs = [RssiReport(rng.randrange(65536), rng.randrange(2**32), rng.randrange(-32768, 32768),
                       rng.randrange(-128, 21), rng.randrange(1, 4), rng.randrange(40),
                       rng.randrange(32)) for _ in range(n)]
    stream = b"".join(encode_uart(m, rng.randrange(127)) for m in msgs)
    for chunk in (4096, 64):
        dec = StreamDecoder()
        t0 = time.perf_counter()
        got = 0
        for i in range(0, len(stream), chunk):
            got += len(dec.feed(stream[i:i + chunk]))
        dt = time.perf_counter() - t0
        assert got == n, dec.counters
        print(f"UART StreamDecoder, {chunk:5d}-byte chunks: {n / dt:10,.0f} frames/s")
    frames = [encode_can(RssiReport(m.seq, None, *[getattr(m, f) for f in m.__slots__[2:]]), 5)[0]
              for m in msgs]
    t0 = time.perf_counter()
    for can_id, data in frames:
        decode_can(can_id, data)
    print(f"CAN decode_can:                     {n / (time.perf_counter() - t0):10,.0f} frames/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
