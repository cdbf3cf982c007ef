"""Score a gateway's position output against the simulator's ground truth.

Estimates (the gateway's JSON lines: ``t, x, y, seq, stale, ...``) are matched to the
beacon that produced them by sequence number (16-bit, unwrapped in arrival order with
serial-number arithmetic), so the score does not depend on clocks or speed-up.

In virtual time the gateway's ``t`` is simulated time, so its event times are scored too:
a set's true time is the median of its anchors' true report times (when each event closed,
``trace.reports.csv``), the statistic the gateway applies to its mapped times.

With several beacons the estimates name theirs (the output's ``beacon`` field):
:func:`read_estimates` takes one beacon's. A beacon without a sequence number is scored
by time (:func:`score_by_time`): each estimate against the beacon's true position at the
estimate's ``t`` (virtual time: the simulated time of the event it stands for).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pfdoa.errors import InputError
from pfdoa.jsonnum import finite_number

SEQ_MOD = 1 << 16
MAX_LINE = 1 << 16


@dataclass
class Estimates:
    seq: np.ndarray  # unwrapped
    x: np.ndarray
    y: np.ndarray
    stale: list[tuple[int, ...]] = field(default_factory=list)
    missing: list[tuple[int, ...]] = field(default_factory=list)
    skipped_lines: int = 0
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    anchors: list[tuple[int, ...]] = field(default_factory=list)
    r95: np.ndarray = field(default_factory=lambda: np.zeros(0))  # NaN where a line has none
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (xx, xy, yy), NaN where none
    lost: np.ndarray = field(default_factory=lambda: np.zeros(0))  # 1.0 flagged, 0.0 not, NaN where none


def read_report_times(path: str | Path) -> dict[tuple[int, int], float]:
    """``trace.reports.csv`` -> {(beacon index, anchor): true time the report's event closed}."""
    import csv

    out: dict[tuple[int, int], float] = {}
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            out.setdefault((int(row["k"]), int(row["anchor"])), float(row["t"]))
    return out


def unwrap_seq(seq: np.ndarray) -> np.ndarray:
    """Unwrap 16-bit sequence numbers given in (roughly) increasing order."""
    s = np.asarray(seq, dtype=np.int64)
    if s.size == 0:
        return s
    d = np.diff(s) % SEQ_MOD
    d = np.where(d >= SEQ_MOD // 2, d - SEQ_MOD, d)  # backward steps (reordering)
    return np.concatenate([[s[0]], s[0] + np.cumsum(d)])


def read_estimates(path: str | Path, beacon: str | None = None, by_time: bool = False) -> Estimates:
    """Read a file of gateway JSON lines (see :func:`estimates_from_lines`)."""
    p = Path(path)
    try:
        fh = open(p, encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from None
    with fh:
        return estimates_from_lines(fh, beacon, by_time)


def estimates_from_lines(lines: Iterable[str], beacon: str | None = None, by_time: bool = False) -> Estimates:
    """Gateway JSON lines (a file's, or ``json.dumps(pfdoa.output.record_values(r))`` of
    records made in process); lines without finite x, y and an integer seq (``by_time``: a
    finite t) are skipped, and with ``beacon`` the lines about other beacons."""
    seq, xs, ys, stale, missing, ts, anchors = [], [], [], [], [], [], []
    r95s: list[float] = []
    covs: list[tuple[float, float, float]] = []
    lost: list[float] = []
    skipped = 0
    for line in lines:
        if len(line) > MAX_LINE:
            skipped += 1
            continue
        try:
            rec = json.loads(line)
            s, x, y = rec["seq"], _number(rec["x"]), _number(rec["y"])
        except (ValueError, KeyError, TypeError, RecursionError):
            skipped += 1
            continue
        if beacon is not None and rec.get("beacon") != beacon:
            continue
        t = _number(rec.get("t"))
        if by_time:
            s = 0 if math.isfinite(t) else None
        if not isinstance(s, int) or not (math.isfinite(x) and math.isfinite(y)):
            skipped += 1
            continue
        seq.append(s % SEQ_MOD)
        xs.append(x)
        ys.append(y)
        stale.append(_ids(rec.get("stale")))
        missing.append(_ids(rec.get("missing")))
        ts.append(t)
        anchors.append(_ids(rec.get("anchors")))
        r95s.append(_number(rec.get("r95")))
        c = rec.get("cov")
        covs.append((_number(c[0]), _number(c[1]), _number(c[2])) if isinstance(c, list) and len(c) == 3
                    else (math.nan, math.nan, math.nan))
        flag = rec.get("lost")
        lost.append(float(flag) if isinstance(flag, bool) else math.nan)
    return Estimates(unwrap_seq(np.array(seq, dtype=np.int64)), np.array(xs), np.array(ys), stale, missing, skipped,
                     np.array(ts), anchors, np.array(r95s), np.array(covs).reshape(-1, 3), np.array(lost))


def _number(v) -> float:
    f = finite_number(v)
    return math.nan if f is None else f


def _ids(v) -> tuple[int, ...]:
    """An anchor-id list of an estimate line (empty when the line has none, or not a list of ids)."""
    if not isinstance(v, list):
        return ()
    return tuple(a for a in v if isinstance(a, int) and not isinstance(a, bool))


@dataclass
class Score:
    n: int  # matched estimates
    beacons: int  # beacons in the scored span (after skip_s)
    rmse: float
    mean: float
    median: float
    p95: float
    max: float
    errors: np.ndarray
    matched_k: np.ndarray  # beacon index of each matched estimate
    flagged_stale: tuple[int, ...] = ()  # anchors the gateway ever flagged stale
    stale_fraction: dict[int, float] = field(default_factory=dict)  # of the scored estimates
    # |gateway t - true event time| (ms) of the scored estimates, and of those after the
    # clock warm-up; None when the times are not comparable (real time)
    time_errors_ms: np.ndarray | None = None
    time_errors_warm_ms: np.ndarray | None = None
    # share of the scored estimates whose truth lies within their r95 / within the 95 %
    # ellipse of their cov (None: no estimate carried one)
    in_r95: float | None = None
    in_cov: float | None = None
    lost: float | None = None  # share of the scored estimates flagged lost (None: none carried the flag)

    @property
    def coverage(self) -> float:
        return self.n / self.beacons if self.beacons else 0.0

    def timing(self) -> dict | None:
        if self.time_errors_ms is None or self.time_errors_ms.size == 0:
            return None
        out = {}
        for key, e in (("", self.time_errors_ms), ("warm_", self.time_errors_warm_ms)):
            if e is not None and e.size:
                out.update({f"{key}n": int(e.size), f"{key}p50_ms": round(float(np.median(e)), 4),
                            f"{key}p99_ms": round(float(np.percentile(e, 99)), 4), f"{key}max_ms": round(float(e.max()), 4)})
        return out

    def as_dict(self) -> dict:
        d = {
            "n": self.n, "beacons": self.beacons, "coverage": round(self.coverage, 4),
            "rmse_m": round(self.rmse, 4), "mean_m": round(self.mean, 4), "median_m": round(self.median, 4),
            "p95_m": round(self.p95, 4), "max_m": round(self.max, 4), "flagged_stale": list(self.flagged_stale),
        }
        for key in ("in_r95", "in_cov"):
            v = getattr(self, key)
            if v is not None:
                d[key] = round(v, 4)
        timing = self.timing()
        if timing is not None:
            d["event_time"] = timing
        return d


def score(est: Estimates, truth_x: np.ndarray, truth_y: np.ndarray, truth_seq0: int = 0,
          skip_s: float = 0.0, beacon_hz: float = 1.0, report_times: dict[tuple[int, int], float] | None = None,
          clock_warmup_s: float = 0.0) -> Score:
    """Errors of estimates against truth indexed by beacon number k (seq = k mod 2^16).

    The first beacon's seq is ``truth_seq0``; estimates whose unwrapped seq falls outside the
    truth are ignored. ``skip_s`` leaves out the filter's start-up (first seconds).
    ``report_times`` (virtual time): the true event time of each (beacon index, anchor) report; the
    estimates' ``t`` are scored against the median over their anchors, from ``skip_s`` on
    and from ``clock_warmup_s`` on.
    """
    k = est.seq - est.seq[0] + ((int(est.seq[0]) - truth_seq0) % SEQ_MOD) if est.seq.size else est.seq
    skip = int(round(skip_s * beacon_hz))
    scored_beacons = max(len(truth_x) - skip, 0)
    ok = (k >= skip) & (k < len(truth_x))
    k = k[ok]
    e = np.hypot(est.x[ok] - truth_x[k], est.y[ok] - truth_y[k])
    stale = sorted({a for s in est.stale for a in s})
    scored = [est.stale[i] for i in np.flatnonzero(ok)]
    frac = {a: sum(a in s for s in scored) / max(len(scored), 1) for a in stale}
    te = tw = None
    if report_times is not None:
        te_l, tw_l = [], []
        for i, kk in zip(np.flatnonzero(ok), k):
            true = sorted(report_times[(int(kk), a)] for a in est.anchors[i] if (int(kk), a) in report_times)
            if not true or not math.isfinite(est.t[i]):
                continue
            n = len(true)
            med = true[n // 2] if n % 2 else 0.5 * (true[n // 2 - 1] + true[n // 2])
            err = abs(float(est.t[i]) - med) * 1e3
            te_l.append(err)
            if kk >= int(round(clock_warmup_s * beacon_hz)):
                tw_l.append(err)
        te, tw = np.array(te_l), np.array(tw_l)
    if e.size == 0:
        nan = float("nan")
        return Score(0, scored_beacons, nan, nan, nan, nan, nan, e, k, tuple(stale), frac, te, tw)
    in_r95, in_cov = uncertainty_checks(est, ok, est.x[ok] - truth_x[k], est.y[ok] - truth_y[k])
    flags = est.lost[ok] if est.lost.size else est.lost
    flags = flags[np.isfinite(flags)]
    return Score(
        n=int(e.size), beacons=scored_beacons, rmse=float(np.sqrt(np.mean(e**2))), mean=float(e.mean()),
        median=float(np.median(e)), p95=float(np.percentile(e, 95)), max=float(e.max()),
        errors=e, matched_k=k, flagged_stale=tuple(stale), stale_fraction=frac,
        time_errors_ms=te, time_errors_warm_ms=tw, in_r95=in_r95, in_cov=in_cov,
        lost=float(flags.mean()) if flags.size else None,
    )


def uncertainty_checks(est: Estimates, sel: np.ndarray, dx: np.ndarray, dy: np.ndarray
                       ) -> tuple[float | None, float | None]:
    """(share within r95, share within the 95 % ellipse of cov) of the estimates ``sel``
    (a mask or indices) with errors (dx, dy), over those that carry each; None when none does."""
    from pfdoa.estimators.base import CHI2_2DOF_95, mahalanobis2

    if est.r95.size == 0:
        return None, None
    r95, cov = est.r95[sel], est.cov[sel]
    have = np.isfinite(r95)
    in_r95 = float(np.mean(np.hypot(dx[have], dy[have]) <= r95[have])) if have.any() else None
    have = np.all(np.isfinite(cov), axis=1)
    in_cov = None
    if have.any():
        d2 = [mahalanobis2(float(a), float(b), (float(c[0]), float(c[1]), float(c[2])))
              for a, b, c in zip(dx[have], dy[have], cov[have])]
        in_cov = float(np.mean(np.array(d2) <= CHI2_2DOF_95))
    return in_r95, in_cov


def score_by_time(est: Estimates, truth_t: np.ndarray, truth_x: np.ndarray, truth_y: np.ndarray,
                  skip_s: float = 0.0) -> Score:
    """Errors of estimates of a beacon without sequence numbers (read with ``by_time``):
    each against the truth interpolated at its ``t``; estimates outside the truth's span
    or before ``skip_s`` are not scored. ``beacons`` counts the truth's times from ``skip_s``
    (coverage: one estimate per advertisement at most, as windows of one period give)."""
    tt = np.asarray(truth_t, dtype=float)
    t = est.t
    ok = np.isfinite(t) & (t >= skip_s) & (t >= tt[0]) & (t <= tt[-1]) if tt.size else np.zeros(t.size, bool)
    gx = np.interp(t[ok], tt, truth_x) if tt.size else np.zeros(0)
    gy = np.interp(t[ok], tt, truth_y) if tt.size else np.zeros(0)
    e = np.hypot(est.x[ok] - gx, est.y[ok] - gy)
    k = np.searchsorted(tt, t[ok]) if tt.size else np.zeros(0, dtype=int)
    scored_beacons = int((tt >= skip_s).sum())
    stale = sorted({a for st in est.stale for a in st})
    if e.size == 0:
        nan = float("nan")
        return Score(0, scored_beacons, nan, nan, nan, nan, nan, e, k, tuple(stale))
    return Score(n=int(e.size), beacons=scored_beacons, rmse=float(np.sqrt(np.mean(e**2))), mean=float(e.mean()),
                 median=float(np.median(e)), p95=float(np.percentile(e, 95)), max=float(e.max()), errors=e,
                 matched_k=k, flagged_stale=tuple(stale))


def plot(path: str | Path, truth_x: np.ndarray, truth_y: np.ndarray, est: Estimates, sc: Score,
         anchors: np.ndarray, title: str = "") -> None:
    """PNG of the true path, the estimates and the anchors."""
    from pfdoa.plotting import pyplot

    plt = pyplot("--plot")

    fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
    ax.plot(truth_x, truth_y, "-", color="0.3", lw=1.5, label="true path")
    k = sc.matched_k
    if k.size:
        ok = (est.seq - est.seq[0]) >= 0
        ax.plot(est.x[ok], est.y[ok], ".", ms=2.5, color="tab:red", alpha=0.6, label="estimates")
    ax.plot(anchors[:, 0], anchors[:, 1], "s", color="tab:blue", ms=8, label="anchors")
    ax.set_aspect("equal")
    ax.grid(True, lw=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    sub = f"RMSE {sc.rmse:.2f} m, median {sc.median:.2f} m, p95 {sc.p95:.2f} m (n={sc.n})"
    ax.set_title(f"{title}\n{sub}" if title else sub, fontsize=9)
    # Below the axes: inside, the legend hides a corner anchor.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    from pfdoa.outfiles import figure_bytes, write_whole

    write_whole(path, figure_bytes(fig, path), "--plot")  # a device or FIFO written through, a file whole
    plt.close(fig)
