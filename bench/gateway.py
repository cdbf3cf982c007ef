"""Gateway throughput (UART and CAN) and set latency through the real pipeline objects.

* UART: :class:`pfdoa.gateway.pipeline.Gateway` (one protocol ``StreamDecoder`` per port,
  ``SeqReassembler``) fed in-memory chunks from 4 anchor ports (bench.streams), with
  ``Gateway.poll`` after every chunk as :class:`~pfdoa.gateway.pipeline.Runner` does; the
  sets go to a counting sink. Frames/s = report frames / wall time of the feed loop.
* CAN: a python-can ``virtual`` bus sends the frames; the gateway's
  :class:`~pfdoa.gateway.inputs.can.CanTransport` (acceptance filters included) receives
  them on another bus instance of the same channel and feeds the same Gateway. Only the
  receive side is timed (send batches of 256 run between the timed reads).
* Rates are frames / wall time (``median``, ``min``, ``max`` over the repeats) and frames /
  CPU time of the process (``cpu_median``: less sensitive to other jobs on a shared machine).
* Latency: Gateway + Localizer (estimator) + output Writer. For each beacon the first
  three anchors' frames are fed, then the perf_counter stamp, then the last frame's bytes;
  the second stamp is taken when the Writer's ``write`` is called.
"""

from __future__ import annotations

import io
import time
from collections import Counter
from typing import cast

import numpy as np

from bench import streams
from pfdoa.api import CanTransport, Chunk, Gateway, Health, Localizer, SeqReassembler
from pfdoa.output import Writer

ANCHORS = (1, 2, 3, 4)


def make_gateway(anchors=ANCHORS, on_set=None) -> Gateway:
    grouper = SeqReassembler(anchors, set_timeout_s=0.25, max_open_sets=64, stale_after_s=3.0)
    sets: Counter[str] = Counter()

    def count(s) -> None:
        sets[s.reason] += 1

    gw = Gateway(grouper, on_set or count, Health())
    gw.sets = sets  # type: ignore[attr-defined]
    return gw


def feed_all(gw: Gateway, chunks) -> tuple[float, float]:
    """Feed every chunk (poll after each, as the Runner does); (wall, CPU) seconds."""
    feed, poll = gw.feed, gw.poll
    c0 = time.process_time()
    t0 = time.perf_counter()
    for c in chunks:
        feed(c)
        poll(c.t)
    gw.finish()
    return time.perf_counter() - t0, time.process_time() - c0


def uart_rate(chunks: list[Chunk], frames: int, repeats: int) -> dict:
    rates, cpu = [], []
    for _ in range(repeats):
        gw = make_gateway()
        dt, dc = feed_all(gw, chunks)
        assert gw.health.frames == frames, (gw.health.frames, frames, dict(gw.health.errors))
        rates.append(frames / dt)
        cpu.append(frames / max(dc, 1e-9))
    r = np.array(rates)
    return {"median": round(float(np.median(r))), "min": round(float(r.min())), "max": round(float(r.max())),
            "cpu_median": round(float(np.median(cpu))), "frames": frames, "chunks": len(chunks),
            "repeats": repeats}


def can_rate(frames: list[tuple[int, bytes]], repeats: int, batch: int = 256) -> dict:
    import can

    msgs = [can.Message(arbitration_id=i, data=d, is_extended_id=False) for i, d in frames]
    rates, cpus = [], []
    for rep in range(repeats):
        channel = f"pfdoa-bench-{rep}"
        sender = can.Bus(interface="virtual", channel=channel)
        rx = CanTransport(f"virtual:{channel}")
        rx.open()
        gw = make_gateway()
        busy = 0.0
        cpu = 0.0
        try:
            for k in range(0, len(msgs), batch):
                for m in msgs[k:k + batch]:
                    sender.send(m)
                want = min(batch, len(msgs) - k)
                got = 0
                c0 = time.process_time()
                t0 = time.perf_counter()
                while got < want:
                    for c in cast("list[Chunk]", rx.read(0.5)):  # a CAN transport reads frames only
                        gw.feed(c)
                        got += 1
                    gw.poll(time.time())
                busy += time.perf_counter() - t0
                cpu += time.process_time() - c0
            t0 = time.perf_counter()
            gw.finish()
            busy += time.perf_counter() - t0
        finally:
            rx.close()
            sender.shutdown()
        assert gw.health.frames == len(msgs), (gw.health.frames, len(msgs))
        rates.append(len(msgs) / busy)
        cpus.append(len(msgs) / max(cpu, 1e-9))
    r = np.array(rates)
    return {"median": round(float(np.median(r))), "min": round(float(r.min())), "max": round(float(r.max())),
            "cpu_median": round(float(np.median(cpus))), "frames": len(msgs), "repeats": repeats}


class _StampingWriter(Writer):
    def __init__(self) -> None:
        super().__init__(io.StringIO())
        self.stamps: list[float] = []

    def write(self, r) -> None:
        self.stamps.append(time.perf_counter())
        super().write(r)


def latency(sets: int, warmup: int, method: str = "pf-doa", seed: int = 1) -> dict:
    from bench.estimators import observations
    from pfdoa.estimators import make_estimator
    from pfdoa.protocol.uart import encode_uart

    site, obs = observations(warmup + sets, seed=seed)
    ids = site.anchor_ids
    est = make_estimator(method, site, rng=np.random.default_rng(seed))
    writer = _StampingWriter()
    health = Health()
    loc = Localizer(site, est, writer, health=health)
    gw = make_gateway(ids, loc.handle)
    gw.health = health
    lat = []
    for k, o in enumerate(obs):
        t = k * streams.PERIOD_S
        frames = [encode_uart(streams.report(k, i, int(round(v * 256))), a)
                  for i, (a, v) in enumerate(zip(ids, np.nan_to_num(o.rssi, nan=-100.0)))]
        for i, f in enumerate(frames[:-1]):
            gw.feed(Chunk(f"serial{i}", t, f))
        before = len(writer.stamps)
        t0 = time.perf_counter()
        gw.feed(Chunk(f"serial{len(frames) - 1}", t, frames[-1]))
        assert len(writer.stamps) == before + 1, "the last frame must complete its set"
        if k >= warmup:
            lat.append(writer.stamps[-1] - t0)
    v = np.array(lat) * 1e3
    return {"p50": round(float(np.percentile(v, 50)), 4), "p90": round(float(np.percentile(v, 90)), 4),
            "p99": round(float(np.percentile(v, 99)), 4), "max": round(float(v.max()), 4), "n": int(v.size),
            "method": method}


def run(quick: bool = False) -> dict:
    n_uart = 4000 if quick else 200_000
    n_can = 1000 if quick else 50_000
    repeats = 1 if quick else 3
    # Warm-up (imports, caches): a short run whose result is discarded.
    feed_all(make_gateway(), list(streams.uart_chunks(2000, ANCHORS, seed=2)))
    chunks = list(streams.uart_chunks(n_uart, ANCHORS))
    bulk = streams.uart_bulk(n_uart, ANCHORS)
    out = {
        "uart": uart_rate(chunks, n_uart, repeats),
        "uart_bulk_4096": uart_rate(bulk, n_uart, repeats),
        "can": can_rate(streams.can_frames(n_can, ANCHORS), repeats),
    }
    lat_sets, lat_warm = (20, 5) if quick else (1000, 50)
    lat = latency(lat_sets, lat_warm, "pf-doa")
    lat["wcl"] = {k: v for k, v in latency(lat_sets, lat_warm, "wcl").items() if k in ("p50", "p99")}
    return {"gateway_frames_per_s": {k: v["median"] for k, v in out.items()},
            "gateway_frames_per_s_detail": out, "latency_ms": lat}


