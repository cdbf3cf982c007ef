"""Summary statistics and machine facts shared by the benchmarks."""

from __future__ import annotations

import os
import platform
import sys

import numpy as np


def summary(values_s, scale: float = 1e3, digits: int = 4) -> dict:
    """Median and spread of timings in seconds, scaled (default: to ms)."""
    v = np.asarray(values_s, dtype=float) * scale
    if v.size == 0:
        return {"median": None, "p10": None, "p90": None, "n": 0}
    p10, p50, p90 = np.percentile(v, [10, 50, 90])
    return {"median": round(float(p50), digits), "p10": round(float(p10), digits),
            "p90": round(float(p90), digits), "n": int(v.size)}


def machine() -> dict:
    import numpy

    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {
        "cpu_count": os.cpu_count(),
        "cpu": cpu,
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "numpy": numpy.__version__,
        "load_avg_1_5_15": load,
        "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
    }
