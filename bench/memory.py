"""Gateway peak memory over a long run: ``python -m bench.memory --frames 1000000``.

Runs in its own process (so ``ru_maxrss`` is this run's, not the benchmark driver's):
10^6 report frames from 4 anchor ports (bench.streams: generated lazily, so the input
does not sit in memory) through the whole gateway path: protocol ``StreamDecoder`` per
port -> ``SeqReassembler`` -> ``Localizer`` with the estimator (``--method``, default
pf-doa with its default 200 particles; ``none`` = a sink that only builds each set's RSSI
vector) -> JSON-lines ``Writer`` to /dev/null. Prints one JSON object: peak RSS
(VmHWM, the ``ru_maxrss`` of this process image) after the imports and set-up (baseline)
and after the run, in MiB.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import numpy as np


def _rss_mb() -> float:
    """Peak resident set size of this process, MiB.

    /proc/self/status VmHWM where available: Linux carries ``ru_maxrss`` across exec, so a
    child spawned (vfork + exec) by a large parent would report the parent's peak.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)  # KiB on Linux


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--method", default="pf-doa")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)

    from bench import streams
    from bench.gateway import make_gateway
    from pfdoa.api import Health, Localizer
    from pfdoa.estimators import make_estimator
    from pfdoa.output import Writer
    from pfdoasim.scenario import square_site

    anchors = (1, 2, 3, 4)
    site = square_site(6.0, 6.0, -45.0, 3.0, ids=anchors)
    health = Health()
    sink = open(os.devnull, "w", encoding="utf-8")
    if args.method == "none":
        def on_set(s) -> None:
            s.vector(anchors)
        loc = None
    else:
        est = make_estimator(args.method, site, rng=np.random.default_rng(args.seed))
        loc = Localizer(site, est, Writer(sink), health=health)
        on_set = loc.handle
    gw = make_gateway(anchors, on_set)
    gw.health = health
    baseline = _rss_mb()
    feed, poll = gw.feed, gw.poll
    t0 = time.perf_counter()
    for c in streams.uart_chunks(args.frames, anchors, seed=args.seed):
        feed(c)
        poll(c.t)
    gw.finish()
    elapsed = time.perf_counter() - t0
    sink.close()
    out = {
        "peak_rss_mb": _rss_mb(),
        "ru_maxrss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "baseline_rss_mb": baseline,
        "frames": health.frames,
        "sets": gw.grouper.counters.sets,
        "estimates": health.estimates,
        "method": args.method,
        "seconds": round(elapsed, 1),
        "python": sys.version.split()[0],
    }
    print(json.dumps(out))
    return 0 if health.frames == args.frames else 1


def run(quick: bool = False, method: str = "pf-doa") -> dict:
    """Run the measurement in a subprocess; its JSON result."""
    import subprocess
    from pathlib import Path

    frames = 20_000 if quick else 1_000_000
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run([sys.executable, "-m", "bench.memory", "--frames", str(frames), "--method", method],
                          cwd=root, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"bench.memory failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    raise SystemExit(main())
