"""Calibrate the radio model from anchors that hear each other (peer readings, SPEC 3.5).

Each anchor with an ``ANCHORS`` filter entry sends its own advertisement every period and
reports every other anchor's it hears. For the link from anchor ``j`` to anchor ``i`` the
model is :mod:`pfdoa.radio`'s log-distance law at the anchors' own 3-D distance (their
``x``, ``y`` and ``z``: heights count where the site declares them)::

    rssi_ij = A - 10 n log10(d_ij) + rx_i + tx_j + e_ij

``rx_i`` is anchor i's receive offset: the same receiver hears the beacon, so it is the
site file's ``rssi_offset_db`` (docs/anchors.md). ``tx_j`` is anchor j's transmit offset
(its transmitter and antenna towards the others); no beacon reading depends on it.

**What the readings identify.** Only sums ``rx_i + tx_j`` over links between two different
anchors are seen. Adding ``c`` to every ``rx`` and ``c'`` to every ``tx`` while taking
``c + c'`` from ``A`` changes nothing: the offsets are fixed by a gauge, zero mean over the
anchors fitted (``sum rx = 0``, ``sum tx = 0``), and ``A`` is the RSSI at 1 m of an average
anchor's transmitter heard by an average anchor's receiver. The differences ``rx_i - tx_i``
come from the asymmetry of the two directions of a link, the sums ``rx_i + tx_i`` from the
links' levels against their distances, and ``n`` from the part of the distances that no
sum of per-anchor terms explains (three anchors or more, not all at one distance from each
other). The beacon's ``A`` differs from the anchors' by its transmit power against theirs,
which peer readings cannot see: :meth:`PeerFit.apply` takes it (``beacon_tx_db``, default
0: the beacon transmits like an average anchor, the same radio at the same power), and a
walk with ground truth measures it (``pfdoa calibrate TRACE --from-anchors``).

**Fitting.** Per directed link, the median of its readings (a burst or a moment's blockage
does not move it), then Huber-weighted least squares over the links (a link through a wall,
NLOS, weighs less), with weak priors: every offset ``N(0, 6 dB)`` (receivers of one kind
differ by a few dB: only an offset the links cannot fix is held near 0) and ``n``
``N(n_site, 1)`` around the site file's exponent (only a geometry that cannot tell ``n`` is
held near it). The standard errors come from the links' residual scale and these priors.

**Well-conditioned** (:attr:`PeerFit.conditioned`, what the gateway needs before it uses a
fit): at least three anchors, each heard by two others and hearing two others (every link at
least ``MIN_LINK_READINGS`` readings); the standard error of ``n`` at most
``MAX_SE_EXPONENT`` and of every receive offset at most ``MAX_SE_OFFSET_DB``; ``n`` within
what a site file takes. :attr:`PeerFit.reason` says which failed.

Memory: :class:`PeerReadings` keeps at most ``MAX_PER_LINK`` readings per directed link of
the site's anchors (the most recent), readings of other anchors are counted, not kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from pfdoa.errors import InputError
from pfdoa.radio import PathLoss, rssi_at_distance
from pfdoa.site import MAX_PATH_LOSS_EXPONENT, MIN_PATH_LOSS_EXPONENT, Site

MAX_PER_LINK = 128  # readings kept per directed link (the most recent)
MIN_LINK_READINGS = 3  # a link with fewer is not fitted
MIN_ANCHORS = 3
MIN_LINKS_PER_ANCHOR = 2  # as receiver and as transmitter, for a well-conditioned fit
PRIOR_OFFSET_DB = 6.0  # sd of the prior on every rx and tx offset (around 0)
PRIOR_EXPONENT = 1.0  # sd of the prior on n (around the site file's)
MAX_SE_EXPONENT = 0.4
MAX_SE_OFFSET_DB = 2.0
MIN_SCALE_DB = 1.0  # the links' scale is at least this: walls shadow every link by a dB or more, which a geometry with few links cannot show itself
HUBER_K = 1.345
MAX_IRLS_ITERATIONS = 50
GAUGE_WEIGHT = 1e3  # the gauge rows: sum rx = 0, sum tx = 0 (all but exact)


def anchor_distances(site: Site) -> np.ndarray:
    """The anchors' 3-D distances to each other (m), (n, n) in site order: x, y and their own z."""
    p = np.array([[a.x, a.y, a.z] for a in site.anchors], dtype=float)
    return np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=-1))


def peer_mean_rssi(site: Site, model: PathLoss, rx: np.ndarray | None = None,
                   tx: np.ndarray | None = None) -> np.ndarray:
    """Noise-free RSSI (dBm) of every link, (receiver i, transmitter j) in site order; the
    diagonal (an anchor hearing itself) is NaN. The simulator's anchor-to-anchor links and the
    fit's model are this one function."""
    out = rssi_at_distance(anchor_distances(site), model)
    if rx is not None:
        out = out + np.asarray(rx, dtype=float)[:, None]
    if tx is not None:
        out = out + np.asarray(tx, dtype=float)[None, :]
    np.fill_diagonal(out, np.nan)
    return out


class PeerReadings:
    """Peer readings of a site's anchors, per directed link (receiver, transmitter): the
    most recent ``max_per_link`` of each (see the module doc)."""

    def __init__(self, anchor_ids: Sequence[int], max_per_link: int = MAX_PER_LINK) -> None:
        self.anchor_ids = tuple(anchor_ids)
        self._index = {a: i for i, a in enumerate(self.anchor_ids)}
        n = len(self.anchor_ids)
        self.max_per_link = int(max_per_link)
        self._values = np.full((n, n, self.max_per_link), np.nan, dtype=np.float32)
        self._count = np.zeros((n, n), dtype=np.int64)  # readings ever added per link
        self.readings = 0  # kept (added to a link)
        self.unknown_anchor = 0  # a receiver or transmitter not in the site
        self.itself = 0  # an anchor reporting its own id (two anchors with one id)

    def add(self, receiver: int, transmitter: int, rssi_dbm: float) -> bool:
        """One peer reading; False (counted) when it names an anchor the site does not have."""
        i, j = self._index.get(receiver), self._index.get(transmitter)
        if i is None or j is None:
            self.unknown_anchor += 1
            return False
        if i == j:
            self.itself += 1
            return False
        if not math.isfinite(rssi_dbm):
            return False
        self._values[i, j, self._count[i, j] % self.max_per_link] = rssi_dbm
        self._count[i, j] += 1
        self.readings += 1
        return True

    def extend(self, readings: Iterable[tuple[int, int, float]]) -> None:
        for receiver, transmitter, rssi in readings:
            self.add(receiver, transmitter, rssi)

    def links(self, min_readings: int = MIN_LINK_READINGS) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(receiver index, transmitter index, median dBm, readings kept) of every link with at
        least ``min_readings`` readings, in site order."""
        kept = np.minimum(self._count, self.max_per_link)
        i, j = np.nonzero(kept >= max(min_readings, 1))
        med = np.array([float(np.nanmedian(self._values[a, b, :kept[a, b]])) for a, b in zip(i, j)])
        return i, j, med, kept[i, j]


@dataclass(frozen=True)
class PeerFit:
    """The fitted model (see the module doc); offsets in site order, NaN for an anchor the
    links did not reach."""

    anchor_ids: tuple[int, ...]
    rssi_at_1m_dbm: float
    path_loss_exponent: float
    rx_offsets: np.ndarray
    tx_offsets: np.ndarray
    links: int
    readings: int
    rms_db: float  # the links' residual RMS (medians against the fit)
    scale_db: float  # their scale over the degrees of freedom left, behind the standard errors
    se_exponent: float
    se_rx_db: np.ndarray  # standard error of every receive offset (NaN: not fitted)
    conditioned: bool
    reason: str  # why not (empty when conditioned)

    def apply(self, site: Site, beacon_tx_db: float = 0.0) -> Site:
        """``site`` with this model for the beacon: ``rssi_at_1m_dbm`` is the anchors' ``A``
        plus ``beacon_tx_db`` (how much stronger the beacon transmits than an average
        anchor), ``path_loss_exponent`` the fitted one, each anchor's ``rssi_offset_db`` its
        receive offset (0 where the links did not reach it). Positions and tables are kept;
        a ``[radio_map]`` of the old model is dropped (calibrate's one way of applying a fit)."""
        from pfdoa.calibrate import AnchorFit, CalibrationResult

        fits = tuple(AnchorFit(a, 0, float(o) if math.isfinite(o) else 0.0, math.nan, math.nan)
                     for a, o in zip(self.anchor_ids, self.rx_offsets))
        result = CalibrationResult(self.rssi_at_1m_dbm + float(beacon_tx_db), self.path_loss_exponent, fits,
                                   self.rms_db, self.readings, True, "sum-zero")
        return result.apply(site)

    def report(self) -> str:
        lines = [f"peer fit: {self.links} links, {self.readings} readings, link residual RMS {self.rms_db:.2f} dB "
                 f"(scale {self.scale_db:.2f} dB over the degrees of freedom left)",
                 f"rssi_at_1m_dbm     = {self.rssi_at_1m_dbm:.2f} dBm (an average anchor heard by an average anchor)",
                 f"path_loss_exponent = {self.path_loss_exponent:.3f} (standard error {self.se_exponent:.3f})"]
        w = max([6] + [len(str(a)) for a in self.anchor_ids])
        lines.append(f"{'anchor':>{w}}  rx_offset_dB  se_dB  tx_offset_dB")
        for a, r, s, t in zip(self.anchor_ids, self.rx_offsets, self.se_rx_db, self.tx_offsets):
            lines.append(f"{a:>{w}}  {r:>12.2f}  {s:>5.2f}  {t:>12.2f}")
        lines.append("well-conditioned" if self.conditioned else f"not well-conditioned: {self.reason}")
        return "\n".join(lines)

    def to_json(self) -> dict:
        """The fit as the gateway's health reports it (NaN as null)."""
        def num(v: float, nd: int = 3) -> float | None:
            return round(float(v), nd) if math.isfinite(v) else None

        return {"rssi_at_1m_dbm": num(self.rssi_at_1m_dbm), "path_loss_exponent": num(self.path_loss_exponent),
                "se_exponent": num(self.se_exponent),
                "rx_offsets_db": {str(a): num(v) for a, v in zip(self.anchor_ids, self.rx_offsets)},
                "tx_offsets_db": {str(a): num(v) for a, v in zip(self.anchor_ids, self.tx_offsets)},
                "se_rx_db": {str(a): num(v) for a, v in zip(self.anchor_ids, self.se_rx_db)},
                "links": self.links, "readings": self.readings, "rms_db": num(self.rms_db),
                "conditioned": self.conditioned, "reason": self.reason}


def fit_peers(site: Site, readings: PeerReadings, *, robust: bool = True,
              min_readings: int = MIN_LINK_READINGS) -> PeerFit:
    """Fit ``A``, ``n`` and every anchor's receive and transmit offsets to the peer readings
    of ``site``'s anchors (module doc). InputError when no three anchors are linked."""
    if readings.anchor_ids != site.anchor_ids:
        raise ValueError("the peer readings are of another site's anchors")
    i, j, y, counts = readings.links(min_readings)
    present = np.union1d(i, j)
    if present.size < MIN_ANCHORS or y.size < 3:
        raise InputError(f"peer calibration needs links between at least {MIN_ANCHORS} anchors with "
                         f"{min_readings} readings or more each; got {y.size} links between {present.size} anchors")
    n_a = len(site.anchors)
    d = anchor_distances(site)[i, j]
    # Parameters: A, n, rx of every anchor, tx of every anchor (absent ones held at 0 by the prior).
    m, k = y.size, 2 + 2 * n_a
    X = np.zeros((m, k))
    X[:, 0] = 1.0
    X[:, 1] = -10.0 * np.log10(np.maximum(d, site.radio.min_distance_m))
    X[np.arange(m), 2 + i] = 1.0
    X[np.arange(m), 2 + n_a + j] = 1.0
    rx_present = np.isin(np.arange(n_a), i)
    tx_present = np.isin(np.arange(n_a), j)
    n_site = site.radio.path_loss_exponent

    def prior_rows(scale: float) -> tuple[np.ndarray, np.ndarray]:
        rows, target = [], []
        for present_mask, base in ((rx_present, 2), (tx_present, 2 + n_a)):
            g = np.zeros(k)
            g[base:base + n_a] = present_mask * GAUGE_WEIGHT  # the gauge: zero mean over the fitted
            rows.append(g)
            target.append(0.0)
            for a in range(n_a):
                r = np.zeros(k)
                r[base + a] = scale / PRIOR_OFFSET_DB
                rows.append(r)
                target.append(0.0)
        r = np.zeros(k)
        r[1] = scale / PRIOR_EXPONENT
        rows.append(r)
        target.append(n_site * scale / PRIOR_EXPONENT)
        return np.array(rows), np.array(target)

    w = np.ones(m)
    scale = 2.0  # the first pass's guess at the links' scale; then measured
    beta = np.zeros(k)
    for _ in range(MAX_IRLS_ITERATIONS if robust else 2):
        P, t = prior_rows(scale)
        sw = np.sqrt(w)
        new, *_ = np.linalg.lstsq(np.vstack([X * sw[:, None], P]), np.concatenate([y * sw, t]), rcond=None)
        resid = y - X @ new
        scale = max(1.4826 * float(np.median(np.abs(resid - np.median(resid)))), MIN_SCALE_DB)
        converged = np.allclose(new, beta, atol=1e-6)
        beta = new
        if robust:
            a = np.abs(resid) / (HUBER_K * scale)
            w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
            if converged:
                break
    resid = y - X @ beta
    # The standard errors: the links' scale from their weighted residuals over the degrees of
    # freedom the fit leaves (few links fit nearly as many parameters: their spread alone
    # would say far too little), with the priors.
    P, _t = prior_rows(scale)
    Xw = X * np.sqrt(w)[:, None]
    inv = np.linalg.pinv(np.vstack([Xw, P]).T @ np.vstack([Xw, P]))
    dof = m - float(np.trace(Xw @ inv @ Xw.T))
    se_scale = max(math.sqrt(float(np.sum(w * resid ** 2)) / max(dof, 1.0)), MIN_SCALE_DB)
    P, _t = prior_rows(se_scale)
    A_ = np.vstack([Xw, P])
    cov = se_scale ** 2 * np.linalg.pinv(A_.T @ A_)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rx = np.where(rx_present, beta[2:2 + n_a], np.nan)
    tx = np.where(tx_present, beta[2 + n_a:], np.nan)
    se_rx = np.where(rx_present, se[2:2 + n_a], np.nan)
    n_fit = float(beta[1])
    reasons = []
    heard = np.bincount(j, minlength=n_a)  # links on which each anchor was heard
    hears = np.bincount(i, minlength=n_a)
    short = [site.anchor_ids[a] for a in present if heard[a] < MIN_LINKS_PER_ANCHOR or hears[a] < MIN_LINKS_PER_ANCHOR]
    if short:
        reasons.append(f"anchors {', '.join(map(str, short))} are heard by or hear fewer than "
                       f"{MIN_LINKS_PER_ANCHOR} others")
    if se[1] > MAX_SE_EXPONENT:
        reasons.append(f"path_loss_exponent standard error {se[1]:.2f} > {MAX_SE_EXPONENT}")
    worst = float(np.nanmax(se_rx)) if np.any(rx_present) else math.inf
    if worst > MAX_SE_OFFSET_DB:
        reasons.append(f"a receive offset's standard error {worst:.2f} dB > {MAX_SE_OFFSET_DB} dB")
    if not MIN_PATH_LOSS_EXPONENT <= n_fit <= MAX_PATH_LOSS_EXPONENT:
        reasons.append(f"path_loss_exponent {n_fit:.2f} outside [{MIN_PATH_LOSS_EXPONENT:g}, "
                       f"{MAX_PATH_LOSS_EXPONENT:g}]")
    return PeerFit(site.anchor_ids, float(beta[0]), n_fit, rx, tx, int(m), int(counts.sum()),
                   float(np.sqrt(np.mean(resid ** 2))), se_scale, float(se[1]), se_rx, not reasons, "; ".join(reasons))


def prior_readings(fit: PeerFit, site: Site, per_anchor: int = 20, beacon_tx_db: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pseudo-readings that hold a walk's fit near the peer fit (``pfdoa calibrate TRACE
    --from-anchors``): for every anchor the links reached, what the peer fit (applied for the
    beacon) predicts at ``per_anchor`` points of a grid over the estimators' search box, as
    (points, anchor index, rssi) for :func:`pfdoa.calibrate.calibrate_traces`'s ``prior``. A
    walk of a few hundred readings per anchor outweighs them; a walk that does not separate a
    parameter (one distance, a static beacon) leaves it near the peer fit's."""
    from pfdoa.estimators.common import default_margin, search_box
    from pfdoa.radio import mean_rssi

    fitted = fit.apply(site, beacon_tx_db)
    lo, hi = search_box(site, default_margin(site.positions))
    k = max(int(math.ceil(math.sqrt(per_anchor))), 2)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], k), np.linspace(lo[1], hi[1], k))
    grid = np.column_stack([gx.ravel(), gy.ravel()])[:per_anchor]
    rssi = mean_rssi(grid, fitted.positions, PathLoss.from_site(fitted), fitted.offsets, fitted.heights)
    reached = [a for a in range(len(site.anchors)) if math.isfinite(fit.rx_offsets[a])]
    pts = np.concatenate([grid for _ in reached])
    idx = np.concatenate([np.full(len(grid), a) for a in reached])
    val = np.concatenate([rssi[:, a] for a in reached])
    return pts, idx, val


class _Sink:
    """The gateway's peers hook for reading recordings: every peer reading into PeerReadings."""

    def __init__(self, readings: PeerReadings) -> None:
        self.readings = readings

    def add(self, receiver: int, transmitter: int, rssi_dbm: float, t: float) -> None:
        self.readings.add(receiver, transmitter, rssi_dbm)

    def poll(self, now: float) -> None:
        pass


def read_captures(paths: Sequence[str], site: Site) -> tuple[PeerReadings, dict]:
    """The peer readings in capture files (``pfdoa gateway --capture``, ``pfdoa sim
    --transport timed``): their frames decoded as the gateway decodes them (UART streams per
    source, CAN frames). Returns the readings of ``site``'s anchors and what the files held
    (``chunks``, ``reports``, ``peer_readings``, ``bad_lines``, decode ``errors``). InputError
    when a file cannot be read."""
    from pfdoa.gateway.config import gateway_config
    from pfdoa.gateway.decoding import Gateway, make_grouper

    readings = PeerReadings(site.anchor_ids)
    gw = Gateway(make_grouper(site.anchor_ids, gateway_config({})), lambda s: None, event_means=False,
                 peers=_Sink(readings))
    bad = [0]
    for path in paths:
        for chunk in capture_chunks(path, bad):
            gw.feed(chunk)
    h = gw.health
    return readings, {"chunks": h.chunks, "reports": h.reports, "peer_readings": gw.peer_readings,
                      "bad_lines": bad[0], "errors": dict(h.errors)}


def capture_chunks(path: str, bad_lines: list[int] | None = None):
    """The chunks of a capture file, in order (its odometry and timer lines left out);
    ``bad_lines[0]`` gets the malformed lines added. InputError when it cannot be read."""
    from pfdoa.gateway.inputs.capture import CaptureReader
    from pfdoa.gateway.transports import Chunk, TransportEOF

    reader = CaptureReader(path)
    reader.open()
    try:
        while True:
            try:
                items = reader.read(0.0)
            except TransportEOF:
                return
            for item in items:
                if isinstance(item, Chunk):
                    yield item
    finally:
        reader.close()
        if bad_lines is not None:
            bad_lines[0] += reader.bad_lines
