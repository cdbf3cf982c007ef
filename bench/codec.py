"""Protocol codec alone (formerly protocol/bench.py): frames/s of the gateway's decoders
without reassembly, to separate decoding from the rest of the gateway path.

* ``uart_4096`` / ``uart_64``: one ``StreamDecoder`` fed a stream of random RSSI_REPORT frames
  (random anchors, fields over their whole ranges) in 4096- and 64-byte chunks;
* ``can``: ``decode_can`` per frame.

Median of ``repeats`` (after one warm-up pass), fixed seed.
"""

from __future__ import annotations

import random
import time

import numpy as np

from pfdoa.protocol import RssiReport, StreamDecoder, decode_can, encode_can, encode_uart


def _messages(n: int, seed: int = 1) -> list[RssiReport]:
    rng = random.Random(seed)
    return [RssiReport(rng.randrange(65536), rng.randrange(2**32), rng.randrange(-32768, 32768),
                       rng.randrange(-128, 21), rng.randrange(1, 4), rng.randrange(40), rng.randrange(32))
            for _ in range(n)]


def _rate(fn, n: int, repeats: int) -> int:
    fn()  # warm-up
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        rates.append(n / (time.perf_counter() - t0))
    return round(float(np.median(rates)))


def run(quick: bool = False) -> dict:
    n = 5_000 if quick else 200_000
    repeats = 1 if quick else 3
    rng = random.Random(2)
    msgs = _messages(n)
    stream = b"".join(encode_uart(m, rng.randrange(127)) for m in msgs)
    out: dict = {"frames": n}
    for chunk in (4096, 64):
        def uart(chunk: int = chunk) -> None:
            dec = StreamDecoder()
            got = 0
            for i in range(0, len(stream), chunk):
                got += len(dec.feed(stream[i:i + chunk]))
            assert got == n, dec.counters
        out[f"uart_{chunk}"] = _rate(uart, n, repeats)
    frames = [encode_can(RssiReport(m.seq, None, m.rssi_q8, m.raw_dbm, m.n_readings, m.channel, m.flags),
                         rng.randrange(127))[0] for m in msgs]

    def can() -> None:
        for can_id, data in frames:
            decode_can(can_id, data)
    out["can"] = _rate(can, n, repeats)
    return out
