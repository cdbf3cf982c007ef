"""Peer calibration (pfdoa.peercal, pfdoa.gateway.peers): what the anchors' readings of each
other identify, the fit's gauge and conditioning, the bounded store, the live refit's rule,
the site file's anchors' entry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pfdoa.errors import ConfigError, InputError
from pfdoa.gateway.beacons import PeersConfig, beacons_config
from pfdoa.gateway.peers import APPLY_CHANGE_DB, LivePeers
from pfdoa.peercal import (
    PeerReadings,
    anchor_distances,
    fit_peers,
    peer_mean_rssi,
    prior_readings,
)
from pfdoa.protocol import defs
from pfdoa.radio import PathLoss
from pfdoa.site import Anchor, Site

pytestmark = pytest.mark.unit

SPOTS = [(0.0, 0.0, 2.4), (0.0, 6.0, 1.2), (5.0, 6.0, 2.4), (10.0, 6.0, 1.2), (10.0, 0.0, 2.4), (5.0, 0.0, 1.2)]
SITE = Site(radio=PathLoss(-50.0, 2.0), anchors=tuple(Anchor(id=10 + i, x=x, y=y, z=z) for i, (x, y, z) in
                                                   enumerate(SPOTS)))
TRUTH = PathLoss(-57.0, 2.6)
RX = np.array([2.0, -3.0, 0.5, 1.0, -1.5, 4.0])
TX = np.array([-1.0, 0.5, 1.5, -2.0, 0.0, 2.5])


def readings_of(mu: np.ndarray, rng=None, noise=0.0, k=10) -> PeerReadings:
    pr = PeerReadings(SITE.anchor_ids)
    for _ in range(k):
        for i, a in enumerate(SITE.anchor_ids):
            for j, b in enumerate(SITE.anchor_ids):
                if i != j:
                    pr.add(a, b, float(mu[i, j] + (rng.normal(0.0, noise) if rng is not None else 0.0)))
    return pr


def test_distances_are_3d_with_the_anchors_own_heights():
    d = anchor_distances(SITE)
    assert d[0, 1] == pytest.approx(math.sqrt(36 + 1.2**2)) and d[0, 2] == pytest.approx(math.sqrt(25 + 36))
    assert np.allclose(d, d.T) and np.all(np.diag(d) == 0)


def test_noise_free_links_give_the_truth_up_to_the_gauge():
    fit = fit_peers(SITE, readings_of(peer_mean_rssi(SITE, TRUTH, RX, TX)))
    # identified: n; A plus the offsets' means; the offsets less their means (the weak priors
    # move them by a little: n N(2, 1), every offset N(0, 6 dB), against 1 dB per link)
    assert fit.path_loss_exponent == pytest.approx(2.6, abs=0.02)
    assert fit.rssi_at_1m_dbm == pytest.approx(-57.0 + RX.mean() + TX.mean(), abs=0.3)
    assert np.allclose(fit.rx_offsets, RX - RX.mean(), atol=0.1)
    assert np.allclose(fit.tx_offsets, TX - TX.mean(), atol=0.1)
    assert abs(fit.rx_offsets.sum()) < 1e-6 and abs(fit.tx_offsets.sum()) < 1e-6  # the gauge
    assert fit.conditioned and fit.reason == ""
    # The fitted model predicts every link as the truth does (the gauge changes nothing seen).
    mu_fit = peer_mean_rssi(SITE, PathLoss(fit.rssi_at_1m_dbm, fit.path_loss_exponent), fit.rx_offsets,
                            fit.tx_offsets)
    assert np.nanmax(np.abs(mu_fit - peer_mean_rssi(SITE, TRUTH, RX, TX))) < 0.2


def test_2d_distances_would_fit_another_exponent():
    # The heights matter: the same links fitted as if every anchor were at one height.
    flat = Site(radio=SITE.radio, anchors=tuple(Anchor(a.id, a.x, a.y) for a in SITE.anchors))
    mu = peer_mean_rssi(SITE, TRUTH, RX, TX)
    f3, f2 = fit_peers(SITE, readings_of(mu)), fit_peers(flat, readings_of(mu))
    assert abs(f3.path_loss_exponent - 2.6) < 0.02 and abs(f2.path_loss_exponent - 2.6) > 0.05


def test_a_wall_on_one_link_is_weighed_down():
    mu = peer_mean_rssi(SITE, TRUTH, RX, TX)
    mu[0, 3] -= 15.0  # NLOS both ways
    mu[3, 0] -= 15.0
    rng = np.random.default_rng(3)
    robust = fit_peers(SITE, readings_of(mu, rng, 1.0, 20))
    plain = fit_peers(SITE, readings_of(mu, np.random.default_rng(3), 1.0, 20), robust=False)
    assert abs(robust.path_loss_exponent - 2.6) < abs(plain.path_loss_exponent - 2.6)
    assert abs(robust.path_loss_exponent - 2.6) < 0.15


def test_noisy_links_recover_the_truth_within_their_standard_errors():
    rng = np.random.default_rng(7)
    shadow = rng.normal(0.0, 1.0, (6, 6))
    mu = peer_mean_rssi(SITE, TRUTH, RX, TX) + (shadow + shadow.T) / math.sqrt(2)
    fit = fit_peers(SITE, readings_of(mu, rng, 2.0, 40))
    assert abs(fit.path_loss_exponent - 2.6) < 3 * fit.se_exponent
    assert np.all(np.abs(fit.rx_offsets - (RX - RX.mean())) < 3 * fit.se_rx_db + 0.3)
    assert 0.0 < fit.se_exponent < 0.4


def test_too_few_anchors_or_links():
    pr = PeerReadings(SITE.anchor_ids)
    for _ in range(5):
        pr.add(10, 11, -60.0)
        pr.add(11, 10, -61.0)
    with pytest.raises(InputError, match="at least 3 anchors"):
        fit_peers(SITE, pr)
    # three anchors, each hearing one other only: a fit, but not well-conditioned
    for _ in range(5):
        pr.add(12, 10, -65.0)
    fit = fit_peers(SITE, pr)
    assert not fit.conditioned and "fewer than 2 others" in fit.reason
    with pytest.raises(ValueError, match="another site"):
        fit_peers(SITE, PeerReadings((1, 2, 3)))


def test_readings_are_bounded_and_checked():
    pr = PeerReadings(SITE.anchor_ids, max_per_link=4)
    for v in (-60.0, -61.0, -62.0, -63.0, -90.0, -90.0):
        pr.add(10, 11, v)
    assert pr._values.shape == (6, 6, 4)  # the most recent 4 of link 11 -> 10
    _, _, med, kept = pr.links(min_readings=1)
    assert kept.tolist() == [4] and med[0] == pytest.approx(-76.5)  # -62, -63, -90, -90
    assert not pr.add(99, 11, -60.0) and not pr.add(10, 10, -60.0) and not pr.add(10, 11, float("nan"))
    assert (pr.unknown_anchor, pr.itself, pr.readings) == (1, 1, 6)


def test_apply_writes_the_receive_offsets_and_the_beacons_a():
    fit = fit_peers(SITE, readings_of(peer_mean_rssi(SITE, TRUTH, RX, TX)))
    site = fit.apply(SITE, beacon_tx_db=3.0)
    assert site.radio.rssi_at_1m_dbm == pytest.approx(fit.rssi_at_1m_dbm + 3.0, abs=1e-3)
    assert np.allclose(site.offsets, fit.rx_offsets, atol=1e-3)
    assert [(a.x, a.y, a.z) for a in site.anchors] == SPOTS


def test_prior_readings_are_what_the_fit_predicts_inside_the_site():
    fit = fit_peers(SITE, readings_of(peer_mean_rssi(SITE, TRUTH, RX, TX)))
    pts, idx, val = prior_readings(fit, SITE, per_anchor=16)
    assert len(pts) == 16 * 6 and set(idx.tolist()) == set(range(6))
    lo, hi = SITE.positions.min(axis=0) - 3.0, SITE.positions.max(axis=0) + 3.0
    assert np.all(pts >= lo) and np.all(pts <= hi)
    from pfdoa.calibrate import fit_path_loss

    back = fit_path_loss(pts, idx, val, SITE)  # a fit of the prior alone is the peer fit (for the beacon)
    assert back.path_loss_exponent == pytest.approx(fit.path_loss_exponent, abs=1e-3)


def test_the_anchors_entry_of_the_site_file():
    b = beacons_config({"beacons": [{"kind": "anchors", "period_ms": 500, "refit_s": 30.0, "apply": False}]})
    assert b.entries == () and b.peers == PeersConfig(defs.BEACON_SLOTS - 1, 500, 30.0, False)
    table = b.table()
    assert table is not None and table[0].kind == defs.FILTER_PFDOA and table[3].kind == defs.FILTER_ANCHORS
    assert table[3].period_ms == 500
    b = beacons_config({"beacons": [{"kind": "anchors"}, {"kind": "pfdoa", "name": "r"}]})
    assert b.entries[0].index == 0 and b.peers is not None and b.peers.period_ms == 1000
    for bad, key in (({"kind": "anchors", "period_ms": 0}, "period_ms"), ({"kind": "anchors", "apply": 1}, "apply"),
                     ({"kind": "anchors", "refit_s": 0.5}, "refit_s"), ({"kind": "anchors", "odometry": True}, "odometry"),
                     ({"kind": "anchors", "index": 0}, "beacons")):
        with pytest.raises(ConfigError, match=key):
            beacons_config({"beacons": [bad]})
    with pytest.raises(ConfigError, match="only one"):
        beacons_config({"beacons": [{"kind": "anchors"}, {"kind": "anchors", "index": 2}]})
    with pytest.raises(ConfigError, match="share"):
        beacons_config({"beacons": [{"kind": "pfdoa", "index": 3}, {"kind": "anchors"}]})


def test_live_refits_on_timer_time_and_uses_a_well_conditioned_fit_once():
    used = []
    live = LivePeers(SITE, PeersConfig(3, refit_s=10.0), on_model=used.append)
    mu = peer_mean_rssi(SITE, TRUTH, RX, TX)
    for t in np.arange(0.0, 9.0, 1.0):
        for i, a in enumerate(SITE.anchor_ids):
            for j, b in enumerate(SITE.anchor_ids):
                if i != j:
                    live.add(a, b, float(mu[i, j]), t)
        live.poll(float(t))
    assert live.fits == 0  # not before refit_s after the first reading
    live.poll(10.0)
    assert live.fits == 1 and live.applied == 1 and len(used) == 1
    assert used[0].radio.path_loss_exponent == pytest.approx(2.6, abs=0.02)
    assert live.change_db is not None and live.change_db >= APPLY_CHANGE_DB
    live.poll(25.0)  # no new readings: no refit
    assert live.fits == 1
    live.add(10, 11, float(mu[0, 1]), 26.0)
    live.poll(30.0)  # the same model again: not used again (the estimators would restart for nothing)
    assert live.fits == 2 and live.applied == 1 and live.change_db < APPLY_CHANGE_DB
    js = live.to_json()
    assert js["fit"]["conditioned"] and js["applied"] == 1 and js["in_use"]["path_loss_exponent"] == pytest.approx(
        used[0].radio.path_loss_exponent)


def test_live_with_apply_false_only_reports():
    used = []
    live = LivePeers(SITE, PeersConfig(3, refit_s=1.0, apply=False), on_model=used.append)
    mu = peer_mean_rssi(SITE, TRUTH, RX, TX)
    for i, a in enumerate(SITE.anchor_ids):
        for j, b in enumerate(SITE.anchor_ids):
            if i != j:
                for _ in range(3):
                    live.add(a, b, float(mu[i, j]), 0.0)
    live.poll(2.0)
    assert live.fits == 1 and live.applied == 0 and used == [] and live.fit is not None and live.fit.conditioned
    assert "well-conditioned" in live.line()
