"""The gateway recovers each event's mean from the anchors' exponential average (EventMeans).

Reports come from the reference anchor model (pfdoa.protocol.anchor_model, the executable
SPEC the C core and the MicroPython anchor match byte for byte), decoded by the gateway's
own decoder, so the rounding of the anchor's EMA is the firmware's.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from pfdoa.gateway.decoding import EventMeans, Gateway
from pfdoa.gateway.reassembly import SeqReassembler
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol import defs
from pfdoa.protocol.anchor_model import AnchorModel
from pfdoa.protocol.config import AnchorConfig
from pfdoa.protocol.messages import RssiReport, Status
from pfdoa.protocol.uart import ANCHOR_TO_HOST, StreamDecoder

pytestmark = pytest.mark.unit

ALPHA = AnchorConfig().alpha_q8 / 256.0


def messages(model: AnchorModel, readings, n_per_event: int = 1, skip=()):
    """Decoded messages of one anchor: a poll at 0 (its first STATUS), then one event per
    entry of ``readings`` (``n_per_event`` readings each, closed by a poll 30 ms later);
    reports of the events in ``skip`` are dropped (lost on the link)."""
    dec = StreamDecoder(types=ANCHOR_TO_HOST)
    out = [d.message for d in dec.feed(b"".join(model.poll(0)))]
    tick = 100
    for k, r in enumerate(readings):
        frames = []
        for j in range(n_per_event):
            frames += model.reading(tick + j, k, int(r[j] if n_per_event > 1 else r), 37, 0, defs.RADIO_BLE)
        frames += model.poll(tick + 30)
        msgs = [d.message for d in dec.feed(b"".join(frames))]
        out += [m for m in msgs if not (isinstance(m, RssiReport) and m.seq in skip)]
        tick += 200
    return out


def values(em: EventMeans, msgs, anchor_id: int = 3):
    got = {}
    for m in msgs:
        if isinstance(m, Status):
            em.status(anchor_id, m.config_hash)
        elif isinstance(m, RssiReport):
            got[m.seq] = (em.value(anchor_id, m), m)
    return got


def test_each_events_reading_is_recovered_from_the_filtered_reports():
    rng = np.random.default_rng(1)
    readings = np.round(-60 + 3 * rng.standard_normal(200)).astype(int)
    got = values(EventMeans(), messages(AnchorModel(3), readings))
    filtered = np.array([m.rssi_dbm for _, m in got.values()])
    recovered = np.array([v for v, _ in got.values()])
    # within the anchor's rounding (0.5/256 dB per update, amplified by 1/alpha)
    assert np.abs(recovered - readings).max() <= 0.5 / 256 / ALPHA + 1e-9
    # the filtered values lag: they are far from the readings, and smoother
    assert np.abs(filtered - readings).mean() > 1.5 and np.std(np.diff(filtered)) < 0.5 * np.std(np.diff(readings))


def test_an_events_mean_of_several_readings_and_the_calibration_offset_are_kept():
    cfg = AnchorConfig(offset_q8=-3 * 256)  # the anchor adds -3 dB to what it reports
    rng = np.random.default_rng(2)
    readings = np.round(-70 + 4 * rng.standard_normal((100, 3))).astype(int)
    em = EventMeans(cfg)
    got = values(em, messages(AnchorModel(3, config=cfg), readings, n_per_event=3))
    mean_q8 = (512 * readings.sum(axis=1) + 3) // 6  # the anchor's own fold, half up to 1/256
    for k, (v, _) in got.items():
        assert v == pytest.approx(mean_q8[k] / 256.0 - 3.0, abs=0.5 / 256 / ALPHA + 1e-9)
    assert em.recovered == len(got) and em.filtered == 0


def test_spikes_gaps_and_unconfirmed_anchors_keep_the_reported_value():
    readings = [-60] * 20 + [-85] + [-60] * 20  # event 20 is a spike (25 dB > spike_db 12)
    msgs = messages(AnchorModel(3), readings, skip={30})  # the report of event 30 is lost
    got = values(EventMeans(), msgs)
    v, m = got[20]
    assert m.flags & defs.FLAG_SPIKE and v == m.rssi_dbm  # the anchor rejected it; so do we
    v, m = got[31]
    assert v == m.rssi_dbm  # after the gap: filtered (the chain is broken) ...
    assert got[32][0] == pytest.approx(-60.0, abs=0.01)  # ... and recovered again after it
    # Without a STATUS confirming the configuration every value is as reported.
    no_status = [m for m in msgs if not isinstance(m, Status)]
    em = EventMeans()
    assert all(v == m.rssi_dbm for v, m in values(em, no_status).values()) and em.recovered == 0


def test_an_anchor_running_another_configuration_is_not_inverted(caplog):
    other = AnchorConfig(alpha_q8=128)
    rng = np.random.default_rng(3)
    readings = np.round(-60 + 3 * rng.standard_normal(50)).astype(int)
    em = EventMeans()  # expects the firmware defaults (alpha 0.25)
    with caplog.at_level(logging.WARNING):
        got = values(em, messages(AnchorModel(3, config=other), readings))
    assert all(v == m.rssi_dbm for v, m in got.values()) and em.recovered == 0
    assert "configuration hash" in caplog.text
    assert EventMeans(other).expected == other  # declared, it would be inverted
    assert EventMeans(AnchorConfig(report_mode=1, decimation=4)).expected is None  # decimated: never


def test_the_gateway_hands_the_reassembler_event_means_and_can_keep_the_filtered_values():
    rng = np.random.default_rng(4)
    readings = np.round(-55 + 3 * rng.standard_normal(40)).astype(int)
    model = AnchorModel(3)
    data = b"".join(model.poll(0))
    tick = 100
    for k, r in enumerate(readings):
        data += b"".join(model.reading(tick, k, int(r), 37, 0, defs.RADIO_BLE) + model.poll(tick + 30))
        tick += 200
    for event_means, expect in ((True, readings), (None, None)):
        sets = []
        gw = Gateway(SeqReassembler((3,)), sets.append, event_means=event_means)
        gw.feed(Chunk("uart", 1.0, data))
        gw.finish()
        got = np.array([s.rssi[3] for s in sets])
        assert len(got) == len(readings)
        if expect is not None:
            assert np.abs(got - expect).max() < 0.01
        else:
            assert np.abs(got - readings).mean() > 1.0  # the lagged EMA, as reported
