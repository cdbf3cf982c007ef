"""Reference anchor model: agreement with the real-number formula and invariants."""

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pfdoa.protocol import ConfigSet, Status, StreamDecoder, decode_can, defs, encode_uart
from pfdoa.protocol.anchor_model import AnchorConfig, AnchorModel
from pfdoa.protocol.can import can_id_for
from pfdoa.protocol.script import ScriptError, run_script, step


def _reports(units):
    out = []
    for u in units:
        d = StreamDecoder().feed(u)
        out += [x.message for x in d]
    return out


def test_matches_real_number_ema_within_rounding():
    rng = random.Random(3)
    m = AnchorModel(1, config=AnchorConfig(spike_db=0))
    ema = None
    alpha = 64 / 256
    worst = 0.0
    for seq in range(2000):
        readings = [rng.randrange(-90, -40) for _ in range(3)]
        units = []
        for k, r in enumerate(readings):
            units += m.reading(10 * seq + k, seq, r, 37 + k, 0, 0)
        (rep,) = _reports(units)
        mean = sum(readings) / 3
        ema = mean if ema is None else ema + alpha * (mean - ema)
        worst = max(worst, abs(rep.rssi_dbm - ema))
    # Per step: fold error <= 0.5/256 and increment rounding <= 0.5/256; the EMA forgets
    # old errors at rate alpha, so the accumulated error stays below ~ (0.5 + 0.25*0.5)/0.25/256.
    assert worst <= 3 / 256


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("RRRRPU"), st.integers(0, 60), st.integers(0, 3),
                          st.integers(-128, 127), st.integers(0, 45), st.integers(0, 2)),
                max_size=80),
       st.sampled_from(["uart", "can"]))
def test_random_scripts_never_raise_and_emit_valid_frames(ops, transport):
    m = AnchorModel(7, transport)
    tick = 0
    units = []
    for op, dt, seq, rssi, ch, radio in ops:
        tick = (tick + dt) & 0xFFFFFFFF
        if op == "R":
            units += m.reading(tick, seq, rssi, ch, 0, radio)
        elif op == "P":
            units += m.poll(tick)
        else:
            cfg = ConfigSet(seq, rssi * 10, ch * 7, ch // 3, radio, ch // 4)
            data = encode_uart(cfg, 7)
            units += (m.uart_rx(tick, data) if transport == "uart"
                      else m.can_rx(tick, can_id_for(defs.CAN_CONFIG_SET, 7), cfg.pack()))
    for u in units:
        if transport == "uart":
            d = StreamDecoder().feed(u)
            assert len(d) == 1 and d[0].anchor_id == 7
        else:
            assert not isinstance(decode_can(*u), str)
    assert 0 <= m.dropped_events <= 0xFFFF and 0 <= m.spikes <= 0xFFFF


def test_counters_saturate():
    m = AnchorModel(1)
    for k in range(70000):
        m.reading(k, 1, 127, 37, 0, 0)
    assert m.dropped_events == 0xFFFF
    (st_msg,) = _reports(m.poll(0))
    assert isinstance(st_msg, Status) and st_msg.dropped_events == 0xFFFF


def test_spike_count_matches_flagged_reports():
    rng = random.Random(11)
    m = AnchorModel(2)
    units = []
    for seq in range(500):
        level = -60 if rng.random() < 0.8 else rng.choice((-90, -30))
        units += m.reading(seq * 30, seq, level, 15, 0, 1)
    reports = _reports(units)
    assert sum(1 for r in reports if r.flags & defs.FLAG_SPIKE) == m.spikes > 0
    assert all(r.flags & defs.FLAG_ZIGBEE for r in reports)


def test_rx_errors_and_config_over_uart():
    m = AnchorModel(3)
    good = encode_uart(ConfigSet(9, offset_q8=256), 3)
    out = m.uart_rx(0, b"\x01\x02\x00" + good[:4])
    assert out == [] and m.rx_errors == 1
    (ack,) = _reports(m.uart_rx(1, good[4:]))
    assert ack.token == 9 and ack.result == defs.ACK_OK and m.config.offset_q8 == 256
    assert ack.config_hash == AnchorConfig(offset_q8=256).hash


def test_invalid_init_rejected():
    with pytest.raises(ValueError):
        AnchorModel(127)
    with pytest.raises(ValueError):
        AnchorModel(1, "spi")
    with pytest.raises(ValueError):
        AnchorModel(1, config=AnchorConfig(alpha_q8=0))


def test_script_errors_name_the_line():
    with pytest.raises(ScriptError, match="line 2"):
        run_script({"anchor_id": 1}, ["P 0", "R 1 2 3"])
    with pytest.raises(ScriptError):
        run_script({"anchor_id": 1}, ["X 0"])
    with pytest.raises(ScriptError):
        run_script({"anchor_id": 1}, ["R 0 1 200 37 0 0"])  # rssi not an i8
    assert run_script({"anchor_id": 1}, ["", "# comment", "P 5  # poll"]) != []
    assert step(AnchorModel(1), "   ") == []
