"""Synthetic anchor traffic for the gateway benchmarks (fixed seeds, generated lazily).

One beacon every ``period_s`` (BLE advertising at 20 ms: the fastest an anchor set can
update); every anchor reports it once. UART: each anchor has its own serial port, and
its byte stream reaches the gateway in reads of 1..64 bytes (a full-speed USB-serial
adapter delivers at most 64 bytes per packet), so a frame is often split across reads and
reads of different ports interleave. CAN: one frame per report.
"""

from __future__ import annotations

from typing import Iterator, Sequence

import numpy as np

from pfdoa.api import Chunk
from pfdoa.protocol.can import encode_can
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart

PERIOD_S = 0.02
MAX_READ = 64


def rssi_table(anchors: int, count: int = 512, seed: int = 1) -> np.ndarray:
    """(count, anchors) rssi_q8 values around -60 dBm (only their range matters here)."""
    rng = np.random.default_rng(seed)
    return np.round((-60.0 + 8.0 * rng.standard_normal((count, anchors))) * 256).astype(int)


def report(seq: int, anchor_index: int, rssi_q8: int, tick: bool = True) -> RssiReport:
    raw = max(-128, min(20, int(round(rssi_q8 / 256))))
    return RssiReport(seq & 0xFFFF, (1000 + 20 * seq) & 0xFFFFFFFF if tick else None, int(rssi_q8), raw, 3, 37, 0)


def uart_chunks(n_frames: int, anchor_ids: Sequence[int], seed: int = 1,
                max_read: int = MAX_READ) -> Iterator[Chunk]:
    """Chunks of ``n_frames`` report frames from one serial port per anchor."""
    rng = np.random.default_rng(seed)
    table = rssi_table(len(anchor_ids), seed=seed)
    names = [f"serial{i}" for i in range(len(anchor_ids))]
    pending = [b""] * len(anchor_ids)
    n_beacons = -(-n_frames // len(anchor_ids))
    sent = 0
    for s in range(n_beacons):
        t = s * PERIOD_S
        row = table[s % len(table)]
        for i in rng.permutation(len(anchor_ids)):
            if sent == n_frames:
                break
            sent += 1
            buf = pending[i] + encode_uart(report(s, i, row[i]), anchor_ids[i])
            # Reads of random size; what is left waits for the port's next bytes.
            sizes = rng.integers(1, max_read + 1, size=8)
            k = 0
            pos = 0
            while len(buf) - pos >= sizes[k % 8]:
                yield Chunk(names[i], t, buf[pos:pos + sizes[k % 8]])
                pos += sizes[k % 8]
                k += 1
            pending[i] = buf[pos:]
    for i, rest in enumerate(pending):
        if rest:
            yield Chunk(names[i], n_beacons * PERIOD_S, rest)


def uart_bulk(n_frames: int, anchor_ids: Sequence[int], seed: int = 1, read: int = 4096) -> list[Chunk]:
    """All anchors multiplexed on one byte stream, read ``read`` bytes at a time (replay-like)."""
    table = rssi_table(len(anchor_ids), seed=seed)
    n = len(anchor_ids)
    stream = b"".join(encode_uart(report(k // n, k % n, table[(k // n) % len(table)][k % n]), anchor_ids[k % n])
                      for k in range(n_frames))
    return [Chunk("serial0", (i // 19) * PERIOD_S / n, stream[i:i + read]) for i in range(0, len(stream), read)]


def can_frames(n_frames: int, anchor_ids: Sequence[int], seed: int = 1) -> list[tuple[int, bytes]]:
    table = rssi_table(len(anchor_ids), seed=seed)
    n = len(anchor_ids)
    return [encode_can(report(k // n, k % n, table[(k // n) % len(table)][k % n], tick=False),
                       anchor_ids[k % n])[0] for k in range(n_frames)]
