"""`pfdoa anchors` library (issue 16 part 4) against the reference anchor model: listing,
configuration and filters verified by ack and STATUS, retries, anchors that do not answer.

Time is a FakeClock that only the fake line moves (a read "waits" its timeout), so every
timeout and retry here is exact and no test depends on the machine's speed.
"""

import pytest

from pfdoa.anchors import AnchorManager, Timing, describe_config, offset_config
from pfdoa.clock import FakeClock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs.stdin import StdinTransport
from pfdoa.gateway.transports import Chunk, Transport
from pfdoa.protocol import BeaconFilter, default_table, defs, table_hash
from pfdoa.protocol.anchor_model import AnchorModel, Transmitted
from pfdoa.protocol.config import AnchorConfig

UUID = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"
TABLE = (BeaconFilter.pfdoa(0), BeaconFilter.ibeacon(UUID, 1, 2, 50), BeaconFilter.none(), BeaconFilter.none())


class SilentStatus(AnchorModel):
    """An anchor whose STATUS never arrives (its acks do)."""

    def _status(self, tick_ms):
        self.last_status_tick = tick_ms
        return None

    def _emit(self, msg, transport=None):
        return [] if msg is None else super()._emit(msg, transport)


class ModelLine(Transport):
    """A shared line to reference-model anchors. A read lets its timeout pass on the fake
    clock; the anchors hear our beacon every 100 ms and poll every 10 ms. ``lose`` host
    frames are lost on the way (the first ones)."""

    name = "line0"
    bidirectional = True

    def __init__(self, clock: FakeClock, models, lose: int = 0, can: bool = False) -> None:
        super().__init__(clock)
        self.models = models
        self.lose = lose
        self.can = can
        self.sent = 0
        self._out: list = []
        self._ms = 0  # the anchors' time (ms), in step with the clock
        self._seq = 0

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _send(self, data: bytes, can_id=None) -> None:
        self.sent += 1
        if self.lose > 0:
            self.lose -= 1
            return
        for m in self.models:
            self._out += m.can_rx(self._ms, can_id, data) if self.can else m.uart_rx(self._ms, data)

    def _read(self, timeout: float):
        end = self._ms + max(1, int(round(timeout * 1000)))
        while self._ms < end:
            self._ms += 1
            for m in self.models:
                if self._ms % 100 == 0:
                    for ch in (37, 38, 39):
                        self._out += m.reading(self._ms, self._seq & 0xFFFF, -60 - m.anchor_id, ch, 0, 0)
                if self._ms % 10 == 0:
                    self._out += m.poll(self._ms)
            if self._ms % 100 == 0:
                self._seq += 1
        self.clock.set(self.clock.now() - self.clock.monotonic() + self._ms / 1000.0)
        out, self._out = self._out, []
        if self.can:
            return [Chunk(self.name, self.clock.now(), data, cid) for cid, data in out]
        return [Chunk(self.name, self.clock.now(), b"".join(out))] if out else []


class CanModelLine(ModelLine):
    """The same over CAN."""

    name = "can0"
    is_can = True

    def __init__(self, clock, models, lose: int = 0) -> None:
        super().__init__(clock, models, lose, can=True)


DEFAULT_TIMING = Timing()


def manager(models, lose=0, timing=DEFAULT_TIMING, can=False):
    clock = FakeClock()
    line = (CanModelLine if can else ModelLine)(clock, models, lose)
    return AnchorManager([line], clock, timing).open(), line, clock


def test_list_hears_every_anchor_with_its_status():
    models = [AnchorModel(a, fw_minor=a) for a in (1, 2, 3)]
    mgr, _, clock = manager(models)
    heard = mgr.listen(2.5)
    assert sorted(heard) == [1, 2, 3] and clock.monotonic() == pytest.approx(2.5, abs=0.06)
    for a, info in heard.items():
        s = info.status
        assert (s.fw_major, s.fw_minor) == (1, a) and s.config_hash == defs.CONFIG_DEFAULT_HASH
        assert info.schema == "v2" and s.filter_hash == defs.FILTER_TABLE_DEFAULT_HASH
        assert s.filter_slots == defs.BEACON_SLOTS and info.reports >= 20 and info.beacons == {0}
        d = info.as_dict()
        assert d["status"]["uptime_s"] == 2 and d["link"] == "line0"


def test_listen_until_stops_once_the_given_anchors_sent_a_status():
    mgr, _, clock = manager([AnchorModel(1), AnchorModel(2)])
    mgr.listen(10.0, until=[1, 2])
    assert clock.monotonic() < 0.2  # their first poll sends a STATUS at once


def test_configuration_is_set_and_verified_by_ack_status_and_a_report():
    models = [AnchorModel(a) for a in (1, 2, 3)]
    mgr, line, _ = manager(models)
    want = {1: offset_config(1.5), 3: offset_config(-2.25)}
    out = mgr.configure(want)
    assert all(o.ok for o in out.values()), [o.message for o in out.values()]
    for a, o in out.items():
        assert o.acked_hash == o.status_hash == want[a].hash and o.report_checked and o.sends == 1
        assert "confirmed by its STATUS, a report checked" in o.message
    assert models[0].config == want[1] and models[2].config == want[3] and models[1].config == AnchorConfig()
    assert models[0].config.offset_q8 == -384  # the anchor removes the site's +1.5 dB itself
    assert line.sent == 2


def test_lost_frames_are_sent_again_with_the_same_token():
    models = [AnchorModel(1)]
    mgr, line, clock = manager(models, lose=2, timing=Timing(reply_timeout_s=0.5, retries=3))
    out = mgr.configure({1: offset_config(3.0)})
    assert out[1].ok and out[1].sends == 3 and line.sent == 3
    assert clock.monotonic() >= 1.0  # two reply timeouts passed before the third send


def test_an_anchor_that_does_not_answer_fails_after_its_tries_and_the_others_succeed():
    mgr, _, clock = manager([AnchorModel(1)], timing=Timing(reply_timeout_s=0.5, retries=3))
    out = mgr.configure({1: offset_config(1.0), 9: offset_config(1.0)})
    assert out[1].ok
    assert not out[9].ok and out[9].message == "anchor 9: no CONFIG_ACK after 3 tries (1.5 s)"
    assert out[9].sends == 3 and clock.monotonic() < 2.0


def test_the_total_timeout_bounds_the_operation():
    mgr, _, clock = manager([AnchorModel(1)], timing=Timing(reply_timeout_s=1.0, retries=10, total_timeout_s=2.0))
    out = mgr.configure({9: offset_config(1.0)})
    assert not out[9].ok and "not done within the total timeout (2 s): waiting for its acks" in out[9].message
    assert 2.0 <= clock.monotonic() < 2.1


def test_an_ack_without_a_confirming_status_is_a_failure():
    mgr, _, _ = manager([SilentStatus(1)], timing=Timing(status_timeout_s=2.0))
    out = mgr.configure({1: offset_config(1.0)})
    assert not out[1].ok
    assert out[1].message == "anchor 1: acked, but sent no STATUS within 2 s to confirm the configuration"


def test_an_anchor_that_cannot_store_says_so():
    mgr, _, _ = manager([AnchorModel(1, store_ok=False)])
    out = mgr.configure({1: offset_config(1.0)})
    assert not out[1].ok and "applied but not stored" in out[1].message


def test_an_invalid_configuration_is_refused_before_anything_is_sent():
    mgr, line, _ = manager([AnchorModel(1)])
    with pytest.raises(ValueError, match="anchor 1: invalid configuration"):
        mgr.configure({1: AnchorConfig(alpha_q8=0)})
    assert line.sent == 0


def test_filters_are_set_and_verified():
    models = [AnchorModel(1), AnchorModel(2)]
    mgr, line, _ = manager(models)
    out = mgr.set_filters({1: TABLE, 2: TABLE})
    assert all(o.ok for o in out.values()), [o.message for o in out.values()]
    assert all(o.status_hash == table_hash(TABLE) == o.acked_hash for o in out.values())
    assert models[0].filters == list(TABLE) and line.sent == 2 * defs.BEACON_SLOTS
    # Back to the first-boot table.
    out = mgr.set_filters({1: default_table()})
    assert out[1].ok and models[0].filter_hash == defs.FILTER_TABLE_DEFAULT_HASH


def test_configuration_over_can_with_the_status_parts_joined():
    models = [AnchorModel(a, "can") for a in (1, 2)]
    mgr, _, _ = manager(models, can=True)
    heard = mgr.listen(1.5)
    assert sorted(heard) == [1, 2] and heard[1].status.filter_slots == defs.BEACON_SLOTS
    out = mgr.configure({2: offset_config(-1.0)})
    assert out[2].ok and models[1].config == offset_config(-1.0)
    # FILTER_SET has no CAN mapping.
    out = mgr.set_filters({2: TABLE})
    assert not out[2].ok and "FILTER_SET has no CAN mapping" in out[2].message


def test_standard_input_cannot_send():
    clock = FakeClock()
    mgr = AnchorManager([StdinTransport(fd=0, clock=clock)], clock)
    out = mgr.configure({1: offset_config(1.0)})
    assert not out[1].ok and out[1].message == "anchor 1: no link can reach it"


def test_offsets_follow_the_site_model_sign_and_round_to_q8():
    assert offset_config(0.0) == AnchorConfig()
    assert offset_config(1.0).offset_q8 == -256 and offset_config(-0.5).offset_q8 == 128
    assert offset_config(0.001).offset_q8 == 0 and offset_config(128.0).offset_q8 == -(1 << 15)
    with pytest.raises(InputError, match=r"must be in \[-128, 127.996\] dB, got -1000"):  # never clamped
        offset_config(1000.0)
    base = AnchorConfig(alpha_q8=128, spike_db=6)
    assert offset_config(2.0, base) == AnchorConfig(-512, 128, 6)
    assert describe_config(offset_config(2.0, base)) == "offset -2.00 dB, alpha 0.500, spike 6 dB, reports every event"


def test_list_names_the_anchors_each_one_hears():
    table = [BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter(), BeaconFilter.anchors(200)]
    models = [AnchorModel(a, filters=table, peer_radio=(defs.RADIO_BLE, bytes((a, 0, 0, 0, 0, 0xC5))))
              for a in (1, 2, 3)]
    for m in models:  # what a model sends goes to the line; its advertisements to the others
        poll = m.poll

        def polled(ms, m=m, poll=poll):
            units = poll(ms)
            out = [u for u in units if not isinstance(u, Transmitted)]
            for u in units:
                if isinstance(u, Transmitted):
                    for o in models:
                        if o is not m:
                            out += o.ble_pdu(ms, -70, 37, u.frame)
            return out

        m.poll = polled
    mgr, _, _ = manager(models)
    heard = mgr.listen(2.5)
    for a, info in heard.items():
        assert info.beacons == {0}  # peer reports are not a beacon's
        assert info.peers == {1, 2, 3} - {a} and info.as_dict()["peers"] == sorted({1, 2, 3} - {a})
