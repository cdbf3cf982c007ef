"""A spoofing transmitter against our static beacon and against the authenticated rolling one
(issue 52), side by side, in virtual time.

For one seed, four runs of the ``demo`` room and walk through the real firmware core and a
gateway process (:func:`pfdoasim.harness.run_once`): ``demo`` and ``spoof`` (our static
beacon, without and with the spoofer), ``demo-auth`` and ``spoof-auth`` (the authenticated
beacon, protocol/SPEC.md 9, without and with it). The spoofer (:class:`pfdoasim.scenario.
Spoofer`) stands at (1, 5), 10 dB louder than our beacon, and rebroadcasts our beacon's
captured advertisements between ours: after each one, the latest with the next sequence
number written in, one 2 s old and one 30 s old. Its radio noise is its own, so each
spoofed run's own beacon readings are its clean run's: the drag is what the spoofer adds.

The drag: at each estimate of the clean run, the distance to the spoofed run's latest
estimate at that time (both gateways' outputs, the first STARTUP_S skipped). The
rejections: each anchor core's counts by reason (what ``AUTH_STATUS`` reports) against the
spoofer's receptions by action, and the gateway's own second verification.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from pfdoasim.harness import run_once
from pfdoasim.launch import RunOptions
from pfdoasim.scenario import SPOOFER_AT, build
from pfdoasim.score import read_estimates

DURATION_S = 40.0
STARTUP_S = 2.0
# The reason an anchor must give each action of the spoofer (SPEC 9.4).
EXPECTED = {"replay_2s": "replayed", "replay_30s": "stale", "forge": "bad_tag"}


def drag(clean: Path, spoofed: Path) -> np.ndarray:
    """Per estimate of the clean run (after STARTUP_S): the distance (m) to the spoofed run's
    latest estimate at that time (inf where it has none yet)."""
    a, b = read_estimates(clean), read_estimates(spoofed)
    keep = a.t >= STARTUP_S
    order = np.argsort(b.t, kind="stable")
    bt, bx, by = b.t[order], b.x[order], b.y[order]
    j = np.searchsorted(bt, a.t[keep], side="right") - 1
    out = np.full(int(keep.sum()), np.inf)
    ok = j >= 0
    out[ok] = np.hypot(a.x[keep][ok] - bx[j[ok]], a.y[keep][ok] - by[j[ok]])
    return out


def measure(seed: int, duration_s: float = DURATION_S, work: Path | None = None) -> dict:
    """The four runs of one seed, compared (module doc)."""
    opts = RunOptions(gateway=True)
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(work or tmp)
        res = {name: run_once(build(name, seed=seed, duration_s=duration_s), opts, base / f"{name}-{seed}", name)
               for name in ("demo", "spoof", "demo-auth", "spoof-auth")}
        out: dict = {"seed": seed, "duration_s": duration_s, "spoofer_at": list(SPOOFER_AT)}
        for label, clean, spoofed in (("static", "demo", "spoof"), ("auth", "demo-auth", "spoof-auth")):
            d = drag(res[clean].out_dir / "gateway.jsonl", res[spoofed].out_dir / "gateway.jsonl")
            sc, ss = res[clean].score, res[spoofed].score
            out[label] = {"drag_mean_m": float(np.mean(d)), "drag_p95_m": float(np.percentile(d, 95)),
                          "drag_max_m": float(np.max(d)), "estimates": int(d.size),
                          "error_clean_m": sc.mean if sc is not None else None,
                          "error_spoofed_m": ss.mean if ss is not None else None,
                          "spoofer": res[spoofed].summary.get("spoofer")}
        s = res["spoof-auth"]
        anchors = s.summary.get("anchor_auth", {})
        out["auth"]["anchor_rejections"] = {r: sum(a[r] for a in anchors.values())
                                            for r in ("bad_tag", "stale", "replayed")}
        out["auth"]["gateway"] = (s.gateway or {}).get("auth")
    return out


def rows(results: list[dict]) -> list[str]:
    """The markdown table of :func:`measure` results, one row per seed and beacon."""
    lines = ["| seed | beacon | drag mean | drag p95 | drag max | error without / with the spoofer | "
             "rejected by the anchors (bad tag / stale / replayed) |",
             "|---:|---|---:|---:|---:|---|---|"]
    for r in results:
        for label, name in (("static", "static identifier (`spoof`)"), ("auth", "authenticated (`spoof-auth`)")):
            m = r[label]
            rej = m.get("anchor_rejections")
            rec = (m["spoofer"] or {}).get("receptions", {})
            cell = "none (nothing tells them apart)" if rej is None else (
                f"{rej['bad_tag']:,} / {rej['stale']:,} / {rej['replayed']:,} of {rec.get('forge', 0):,} / "
                f"{rec.get('replay_30s', 0):,} / {rec.get('replay_2s', 0):,} receptions")
            lines.append(f"| {r['seed']} | {name} | {m['drag_mean_m']:.2f} m | {m['drag_p95_m']:.2f} m | "
                         f"{m['drag_max_m']:.2f} m | {m['error_clean_m']:.2f} / {m['error_spoofed_m']:.2f} m | {cell} |")
    return lines


__all__ = ["DURATION_S", "EXPECTED", "drag", "measure", "rows"]
