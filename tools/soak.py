#!/usr/bin/env python3
"""Soak: 10^7 report frames with faults through the gateway's decode + reassembly path.

The stream is generated on the fly (an in-memory byte stream cut into serial-sized chunks)
and fed to :class:`pfdoa.gateway.pipeline.Gateway` (one ``StreamDecoder`` and a
``SeqReassembler``), with every fault the gateway must survive at once:

* frame loss, duplicates (re-sent 1..8 frames later), adjacent reordering;
* garbage blocks between frames and random bit errors on the wire (``--ber``);
* an anchor silent for a while (every ``SILENCE_EVERY`` beacons, in turn);
* an anchor reboot (its tick and uptime restart from 0) and a beacon reboot (silent for
  1 s, then its sequence restarts from 0), each periodically; the gateway must count each
  exactly once;
* reports from an anchor id the site does not know, and STATUS frames.

Memory is sampled every ``--sample`` frames: the process's current RSS (/proc/self/statm),
and, in a window of ``--window`` frames after each sample, tracemalloc (net growth of live
Python memory over the window, and its peak), plus the gateway's own state sizes (open
sets, closed-set history, pending decoder bytes). The bounds checked at the end (exit 1
if broken) are stated in docs/reliability.md. ``--plot`` writes the memory curve.

    .venv/bin/python tools/soak.py --frames 10000000 --json build/soak.json --plot docs/img/soak_memory.png
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
import tracemalloc
from dataclasses import asdict, dataclass

import numpy as np

from pfdoa.api import Chunk, Gateway, Health, SeqReassembler
from pfdoa.protocol import defs
from pfdoa.protocol.messages import RssiReport, Status
from pfdoa.protocol.uart import encode_uart

ANCHORS = (1, 2, 3, 4)
UNKNOWN_ANCHOR = 99
BEACON_PERIOD_S = 0.02
SILENCE_EVERY, SILENCE_LEN = 40_000, 300  # beacons (6 s silent, long past stale_after_s)
ANCHOR_REBOOT_EVERY = 90_000
BEACON_REBOOT_EVERY = 210_000
STATUS_EVERY = 50
BEACON_BOOT_BEACONS = 50  # a rebooting beacon is silent for 1 s
BLOCK = 4096

# Bounds (docs/reliability.md): RSS growth after warm-up, per-window tracemalloc.
RSS_GROWTH_LIMIT = 8 << 20
TRACE_PEAK_LIMIT = 2 << 20
TRACE_NET_LIMIT = 512 << 10
WARMUP_FRAMES = 1_000_000
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * PAGE


@dataclass
class Injected:
    """What :func:`generate` injected so far (the result's ``injected``, in this order)."""

    reports: int = 0
    frames: int = 0
    lost: int = 0
    duplicates: int = 0
    swaps: int = 0
    junk_blocks: int = 0
    bit_flips: int = 0
    silenced: int = 0
    anchor_reboots: int = 0
    beacon_reboots: int = 0
    unknown: int = 0
    status: int = 0


def generate(n_frames: int, seed: int, loss: float, dup: float, reorder: float, garbage: float, ber: float,
             counts: Injected | None = None):
    """Yield (t, bytes) per beacon; the counts of what was injected go in ``counts``."""
    rng = np.random.default_rng(seed)
    counts = counts if counts is not None else Injected()
    n_beacons = n_frames // len(ANCHORS)
    boot_tick = {a: int(rng.integers(0, 2**32)) for a in ANCHORS}  # tick at boot: anywhere
    boot_t = dict.fromkeys(ANCHORS, 0.0)
    seq0 = 0
    off_until = 0
    pending: list[tuple[int, bytes]] = []
    idx = 0
    prev = None
    for b0 in range(0, n_beacons, BLOCK):
        nb = min(BLOCK, n_beacons - b0)
        r_loss = rng.random((nb, len(ANCHORS))) < loss
        r_dup = rng.random((nb, len(ANCHORS))) < dup
        r_reo = rng.random((nb, len(ANCHORS))) < reorder
        rssi = rng.integers(-9000, -4000, size=(nb, len(ANCHORS)))
        junk_at = rng.random(nb) < garbage
        unk_at = rng.random(nb) < 0.001
        for j in range(nb):
            s = b0 + j
            t = s * BEACON_PERIOD_S
            if s and s % BEACON_REBOOT_EVERY == 0:
                # The beacon reboots: what the link still held arrives first, then nothing
                # for the boot time, then its numbering restarts from 0.
                tail = (prev or b"") + b"".join(f for _, f in pending)
                prev, pending = None, []
                off_until = s + BEACON_BOOT_BEACONS
                seq0 = off_until
                counts.beacon_reboots += 1
                if tail:
                    yield t, tail
            if s < off_until:
                continue
            if s and s % ANCHOR_REBOOT_EVERY == 0:
                a = ANCHORS[(s // ANCHOR_REBOOT_EVERY) % len(ANCHORS)]
                boot_tick[a], boot_t[a] = 0, t  # its tick restarts from 0
                counts.anchor_reboots += 1
            silent = ANCHORS[(s // SILENCE_EVERY) % len(ANCHORS)] if s % SILENCE_EVERY < SILENCE_LEN else None
            seq = (s - seq0) & 0xFFFF
            buf = bytearray()
            for i, a in enumerate(ANCHORS):
                up_ms = int((t - boot_t[a]) * 1000)
                tick = (boot_tick[a] + up_ms) & 0xFFFFFFFF
                if a == silent:
                    counts.silenced += 1
                    continue
                counts.reports += 1
                if r_loss[j, i]:
                    counts.lost += 1
                    continue
                frame = encode_uart(RssiReport(seq, tick, int(rssi[j, i]), -60, 3, 37, 8), a)
                if s % STATUS_EVERY == 0:
                    frame += encode_uart(Status(1, 0, up_ms // 1000, 0, 0, 0, 0, defs.DEFS_HASH), a)
                    counts.status += 1
                idx += 1
                if r_dup[j, i]:
                    counts.duplicates += 1
                    pending.append((idx + 1 + (s % 8), frame))
                if prev is not None and r_reo[j, i]:
                    counts.swaps += 1
                    buf += frame + prev
                    prev = None
                else:
                    if prev is not None:
                        buf += prev
                    prev = frame
                while pending and pending[0][0] <= idx:
                    buf += pending.pop(0)[1]
            if unk_at[j]:
                buf += encode_uart(RssiReport(seq, 0, -7000, -70, 1, 37, 0), UNKNOWN_ANCHOR)
                counts.unknown += 1
            if junk_at[j]:
                buf += rng.bytes(int(rng.integers(1, 80))) + b"\x00"
                counts.junk_blocks += 1
            if ber and buf:
                nflip = rng.poisson(ber * 8 * len(buf))
                for bit in rng.integers(0, 8 * len(buf), size=nflip):
                    buf[bit >> 3] ^= 1 << (bit & 7)
                counts.bit_flips += nflip
            counts.frames = idx
            yield t, bytes(buf)
    if prev is not None:
        yield n_beacons * BEACON_PERIOD_S, prev


def gateway_state(gw: Gateway) -> dict:
    g = gw.grouper
    if not isinstance(g, SeqReassembler):  # the closed-set history and heap are SeqReassembler's
        raise TypeError(f"the soak runs a SeqReassembler, not {type(g).__name__}")
    return {"open_sets": g.open_sets, "closed_history": len(g._closed), "heap": len(g._heap),
            "pending_bytes": sum(d.pending for d in gw._decoders.values()),
            "unknown_ids": len(g.counters.unknown_ids)}


def run(n_frames: int, seed: int = 1, sample: int = 250_000, window: int = 5_000, loss: float = 0.05,
        dup: float = 0.01, reorder: float = 0.01, garbage: float = 0.02, ber: float = 1e-5,
        progress=None) -> dict:
    grouper = SeqReassembler(ANCHORS, set_timeout_s=0.25, max_open_sets=64, stale_after_s=3.0)
    health = Health()
    n_sets = 0

    def on_set(s) -> None:
        nonlocal n_sets
        n_sets += 1

    gw = Gateway(grouper, on_set, health)
    chunk_rng = np.random.default_rng(seed + 1)
    cuts = chunk_rng.integers(1, 257, size=1 << 16)
    k = 0
    samples = []
    next_sample = 0
    tracing_until = None
    t0 = time.perf_counter()
    traced_time = 0.0
    t_trace = 0.0
    t = 0.0
    injected = Injected()
    for t, data in generate(n_frames, seed, loss, dup, reorder, garbage, ber, injected):
        i = 0
        while i < len(data):
            n = int(cuts[k & 0xFFFF])
            k += 1
            gw.feed(Chunk("serial0", t, data[i:i + n]))
            i += n
        gw.poll(t)
        frames = injected.frames
        if tracing_until is not None and frames >= tracing_until:
            cur, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            traced_time += time.perf_counter() - t_trace
            samples[-1].update(trace_net=cur, trace_peak=peak)
            tracing_until = None
        if frames >= next_sample and tracing_until is None:
            elapsed = time.perf_counter() - t0
            samples.append({"frames": frames, "seconds": round(elapsed, 2), "rss": rss_bytes(),
                            **gateway_state(gw)})
            if progress:
                progress(samples[-1])
            next_sample += sample
            tracemalloc.start()
            t_trace = time.perf_counter()
            tracing_until = frames + window
    if tracing_until is not None:
        tracemalloc.stop()
    gw.poll(t + 1.0)
    gw.finish()
    elapsed = time.perf_counter() - t0
    samples.append({"frames": injected.frames, "seconds": round(elapsed, 2), "rss": rss_bytes(),
                    **gateway_state(gw)})
    summary = health.summary(grouper)
    return {"frames": injected.frames, "seconds": round(elapsed, 1),
            "frames_per_s": round(injected.frames / max(elapsed - traced_time, 1e-9)),
            "traced_seconds": round(traced_time, 1),
            "injected": asdict(injected), "sets": n_sets,
            "gateway": {k: summary[k] for k in ("frames", "reports", "status", "errors", "duplicates", "late",
                                                 "unknown_anchor", "sets", "complete", "partial", "evicted",
                                                 "seq_restarts", "timeouts")},
            "anchors": summary["anchors"], "samples": samples}


def check(r: dict) -> list[str]:
    """The stated bounds, and that every periodic fault was seen by the gateway."""
    s = r["samples"]
    warm = min(WARMUP_FRAMES, r["frames"] // 10)
    after = [x["rss"] for x in s if x["frames"] >= warm]
    bad = []
    growth = max(after) - after[0]
    if growth > RSS_GROWTH_LIMIT:
        bad.append(f"RSS grew {growth / 2**20:.1f} MiB after 10^6 frames (limit {RSS_GROWTH_LIMIT / 2**20:.0f})")
    for x in s:
        if x.get("trace_peak", 0) > TRACE_PEAK_LIMIT or x.get("trace_net", 0) > TRACE_NET_LIMIT:
            bad.append(f"tracemalloc window at {x['frames']}: net {x['trace_net']} peak {x['trace_peak']} bytes")
        if x["open_sets"] > 64 or x["closed_history"] > 1024 or x["pending_bytes"] > 65:
            bad.append(f"gateway state out of bounds at {x['frames']}: {x}")
    if r["gateway"]["reports"] == 0 or r["sets"] == 0:
        bad.append("nothing got through")
    inj, g = r["injected"], r["gateway"]
    if g["seq_restarts"] != inj["beacon_reboots"]:
        bad.append(f"beacon reboots {inj['beacon_reboots']}, gateway seq_restarts {g['seq_restarts']}")
    seen = sum(a["reboots"] for a in r["anchors"].values())
    if seen != inj["anchor_reboots"]:
        bad.append(f"anchor reboots {inj['anchor_reboots']}, gateway counted {seen}")
    if g["unknown_anchor"] < inj["unknown"] * 0.9:
        bad.append("unknown-anchor reports not counted")
    return bad


def plot(r: dict, path: str) -> None:
    from pfdoa.plotting import pyplot

    plt = pyplot("--plot")

    s = r["samples"]
    f = np.array([x["frames"] for x in s]) / 1e6
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(f, [x["rss"] / 2**20 for x in s], "o-", ms=3, label="process RSS (MiB)")
    tw = [(x["frames"] / 1e6, x["trace_peak"] / 2**20, x["trace_net"] / 2**20) for x in s if "trace_peak" in x]
    if tw:
        ax.plot([a for a, _, _ in tw], [b for _, b, _ in tw], "s-", ms=3,
                label="tracemalloc peak in a 5k-frame window (MiB)")
        ax.plot([a for a, _, _ in tw], [c for _, _, c in tw], "^-", ms=3,
                label="tracemalloc net growth over the window (MiB)")
    ax.set_xlabel("report frames sent (millions)")
    ax.set_ylabel("MiB")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"gateway soak: {r['frames']:,} report frames sent, {r['gateway']['frames']:,} decoded, with faults")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sample", type=int, default=250_000)
    ap.add_argument("--json", help="write the result here")
    ap.add_argument("--plot", help="write the memory curve (PNG) here")
    a = ap.parse_args()
    if a.plot:
        from pfdoa.plotting import require

        require("--plot")  # before the run, not after it
    logging.basicConfig(level=logging.ERROR)  # stale/reboot warnings by the thousand: counted instead
    r = run(a.frames, a.seed, a.sample,
            progress=lambda x: print(f"{x['frames']:>10} frames {x['seconds']:7.1f} s rss {x['rss'] / 2**20:6.1f} MiB",
                                     file=sys.stderr, flush=True))
    bad = check(r)
    r["ok"] = not bad
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(r, fh, indent=1)
    if a.plot:
        plot(r, a.plot)
    print(json.dumps({k: v for k, v in r.items() if k != "samples"}, indent=1))
    for b in bad:
        print("BOUND BROKEN:", b, file=sys.stderr)
    return 0 if not bad else 1


if __name__ == "__main__":
    sys.exit(main())
