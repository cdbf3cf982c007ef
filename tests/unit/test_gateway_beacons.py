"""Several beacons through the gateway (issue 16): the site's [[beacons]], reports routed by
their beacon index, NO_SEQ beacons grouped by time, version-1 anchors unchanged."""

import json
from pathlib import Path

import numpy as np
import pytest

from pfdoa.errors import ConfigError
from pfdoa.gateway.beacons import BeaconsConfig, beacons_config
from pfdoa.gateway.reassembly import SeqReassembler, WindowGrouper
from pfdoa.gateway.setup import build_pipeline, load_settings
from pfdoa.gateway.transports import Chunk, Transport, TransportEOF
from pfdoa.protocol import BeaconFilter, RssiReport, Status, defs, encode_uart, table_hash
from pfdoa.radio import PathLoss, mean_rssi

from gateway_feed import ANCHORS, RADIO, TEST_SITE

UUID = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"
TWO = """
[[beacons]]
name = "robot1"
kind = "pfdoa"

[[beacons]]
name = "tag7"
kind = "ibeacon"
uuid = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"
major = 1
minor = 2
period_ms = 50
window_s = 0.1
"""
POS = {0: (1.0, 1.0), 1: (3.0, 3.0)}  # beacon index -> where it stands


def rssi_at(p):
    return mean_rssi(np.array(p), np.array(list(ANCHORS.values())), PathLoss(*RADIO))


def report_frames(k: int, beacon: int, version: int = defs.PROTO_VERSION) -> bytes:
    """Beacon event k of one beacon at every anchor: ours carries seq k, the other NO_SEQ."""
    out = b""
    for (a, _), r in zip(ANCHORS.items(), rssi_at(POS[beacon])):
        q8 = int(round(float(r) * 256))
        flags = defs.FLAG_NO_SEQ if beacon == 1 else 0
        seq = (k + 7 * a) & 0xFFFF if beacon == 1 else k  # NO_SEQ: each anchor's own count
        tick = 1000 + 100 * k + (50 if beacon == 1 else 0)
        m = RssiReport(seq, tick, q8, int(round(float(r))), 3, 37, flags, beacon=beacon)
        out += encode_uart(m, a, version=version)
    return out


def status_frame(anchor: int, filter_hash: int, version: int = defs.PROTO_VERSION, defs_hash=None) -> bytes:
    if version == defs.V1_PROTO_VERSION:
        m = Status(1, 0, 5, 0, 0, 0, 0, defs.V1_DEFS_HASH if defs_hash is None else defs_hash)
    else:
        m = Status(1, 0, 5, 0, 0, 0, 0, defs.DEFS_HASH if defs_hash is None else defs_hash, filter_hash,
                   defs.BEACON_SLOTS)
    return encode_uart(m, anchor, version=version)


def run(tmp_path, extra: str, chunks, method="trilateration", frames=True):
    """The gateway's pipeline over (t, bytes) chunks on one serial source; (records, counters)."""
    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + extra)
    out = tmp_path / "out.jsonl"
    pipe = build_pipeline(load_settings(str(site), str(out), "jsonl"), method=method, seed=3, frames=frames)
    for t, data in chunks:
        pipe.gateway.feed(Chunk("serial0", t, data))
        pipe.gateway.poll(t)
    pipe.gateway.finish()
    pipe.localizer.finish()
    pipe.close()
    return [json.loads(line) for line in out.read_text().splitlines()], pipe.summary()


def interleaved(n: int, beacons=(0, 1)):
    return [(10.0 + 0.1 * k + 0.05 * b, report_frames(k, b)) for k in range(n) for b in beacons]


def test_two_configured_beacons_are_localized_apart_by_one_gateway(tmp_path):
    recs, summary = run(tmp_path, TWO, interleaved(30))
    by = {name: [r for r in recs if r["beacon"] == name] for name in ("robot1", "tag7")}
    assert len(recs) == len(by["robot1"]) + len(by["tag7"])
    # Ours: one set per sequence number, complete; the iBeacon: one window per event.
    assert [r["seq"] for r in by["robot1"]] == list(range(30))
    assert all(r["missing"] == [] for r in by["robot1"])
    assert all(r["seq"] is None for r in by["tag7"]) and len(by["tag7"]) == 30
    for name, index in (("robot1", 0), ("tag7", 1)):
        err = [np.hypot(r["x"] - POS[index][0], r["y"] - POS[index][1]) for r in by[name]]
        assert max(err) < 0.01, (name, max(err))  # noise-free readings: trilateration is exact
    b = summary["beacons"]
    assert b["beacons"]["robot1"]["grouping"] == "seq" and b["beacons"]["tag7"]["grouping"] == "window"
    assert b["unknown_beacon"] == 0 and b["kind_mismatch"] == 0
    assert summary["readings"] == 2 * 30 * 4 and summary["sets"] == 60  # totals over both beacons
    assert all(summary["anchors"][str(a)]["received"] == 60 for a in ANCHORS)


def test_the_iBeacon_grouper_is_a_time_window_and_ours_a_sequence_reassembler(tmp_path):
    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + TWO)
    pipe = build_pipeline(load_settings(str(site), str(tmp_path / "o.jsonl"), "jsonl"), method="wcl", seed=1)
    routes = {r.name: r for r in pipe.gateway.beacons._routes.values()}
    assert isinstance(routes["robot1"].grouper, SeqReassembler) and pipe.grouper is routes["robot1"].grouper
    assert isinstance(routes["tag7"].grouper, WindowGrouper) and routes["tag7"].grouper.window_s == 0.1
    pipe.close()


def test_reports_of_unconfigured_entries_and_of_the_wrong_kind_are_counted_and_dropped(tmp_path):
    stray = b"".join(encode_uart(RssiReport(k, 1000, -15000, -60, 3, 37, 0, beacon=3), 1) for k in range(5))
    wrong = encode_uart(RssiReport(1, 1000, -15000, -60, 3, 37, 0, beacon=1), 2)  # tag7 has no sequence
    bad_index = encode_uart(RssiReport(1, 1000, -15000, -60, 3, 37, 0, beacon=4), 2)  # no such entry
    peer = encode_uart(RssiReport(1, 1000, -15000, -60, 1, 37, 0, beacon=200), 2)  # anchor 72 heard (SPEC 3.5)
    recs, summary = run(tmp_path, TWO, interleaved(5) + [(20.0, stray + wrong + bad_index + peer)])
    b = summary["beacons"]
    assert b["unknown_beacon"] == 6 and b["kind_mismatch"] == 1
    assert summary["peer_readings_ignored"] == 1 and "peers" not in summary  # no anchors' entry: not kept
    assert {r["beacon"] for r in recs} == {"robot1", "tag7"} and b["tracked"] == 2


def test_without_beacons_every_index_is_its_own_beacon_as_its_reports_say(tmp_path):
    recs, summary = run(tmp_path, "", interleaved(20))
    names = {r["beacon"] for r in recs}
    assert names == {"b0", "b1"}
    b1 = [r for r in recs if r["beacon"] == "b1"]
    # b1's reports are NO_SEQ: grouped by windows of [gateway] window_s (1 s: ten events each).
    assert summary["beacons"]["beacons"]["b1"]["grouping"] == "window" and all(r["seq"] is None for r in b1)
    assert 2 <= len(b1) <= 3
    # Indices beyond the table are never tracked: at most BEACON_SLOTS beacons, whatever arrives.
    flood = b"".join(encode_uart(RssiReport(1, 1000, -15000, -60, 3, 37, 0, beacon=i), 1) for i in range(256))
    _, summary = run(tmp_path, "", [(1.0, flood)])
    assert summary["beacons"]["tracked"] == defs.BEACON_SLOTS
    # 128 + id are peer readings (SPEC 3.5): no beacon's, and not kept without the anchors' entry
    assert summary["beacons"]["unknown_beacon"] == defs.PEER_BEACON_BASE - defs.BEACON_SLOTS
    assert summary["peer_readings_ignored"] == 256 - defs.PEER_BEACON_BASE


def test_one_beacon_gives_the_estimates_of_the_single_beacon_pipeline(tmp_path):
    """The multi-beacon routing leaves a single beacon's numbers as they were (same sets,
    same estimator seed): only the beacon field is new."""
    chunks = [(10.0 + 0.1 * k, report_frames(k, 0)) for k in range(40)]
    routed, _ = run(tmp_path, "", chunks, method="pf-doa")
    plain, _ = run(tmp_path, "", chunks, method="pf-doa", frames=False)
    assert len(routed) == len(plain) == 40
    assert [{**r, "beacon": None} for r in routed] == plain and {r["beacon"] for r in routed} == {"b0"}


def test_a_version_1_anchor_stream_still_works(tmp_path):
    """v1 frames (reports about entry 0, a v1 STATUS with version 1's defs_hash): positions,
    and no schema mismatch; an unknown schema is still flagged."""
    chunks = [(10.0, b"".join(status_frame(a, 0, defs.V1_PROTO_VERSION) for a in ANCHORS))]
    chunks += [(10.0 + 0.1 * k, report_frames(k, 0, defs.V1_PROTO_VERSION)) for k in range(20)]
    chunks += [(13.0, status_frame(2, 0, defs.V1_PROTO_VERSION, defs_hash=0x1234))]
    recs, summary = run(tmp_path, "", chunks)
    assert [r["seq"] for r in recs] == list(range(20)) and {r["beacon"] for r in recs} == {"b0"}
    assert max(np.hypot(r["x"] - POS[0][0], r["y"] - POS[0][1]) for r in recs) < 0.01
    assert summary["errors"] == {} and summary["status"] == 5
    assert summary["schema_mismatch"] == [2]


def test_the_v1_golden_vectors_decode_in_the_gateway_without_errors(tmp_path):
    vectors = json.loads((Path(__file__).resolve().parents[2] / "protocol" / "vectors" / "uart.json").read_text())["vectors"]
    v1 = [v for v in vectors
          if int(v["version"]) == defs.V1_PROTO_VERSION and v["message"] in ("RSSI_REPORT", "STATUS", "CONFIG_ACK")]
    assert len(v1) >= 4
    _, summary = run(tmp_path, "", [(1.0, b"".join(bytes.fromhex(v["frame"]) for v in v1))])
    assert summary["errors"] == {} and summary["frames"] == len(v1)
    # v1_status_boot (anchor 5) carries version 1's defs_hash: not a mismatch. The STATUS of
    # issue 14's example (anchor 62) carries 0x1f00, which is neither version's.
    assert summary["schema_mismatch"] == [62]


def test_anchors_whose_filter_table_is_not_the_sites_are_named(tmp_path):
    good = table_hash((BeaconFilter.pfdoa(0), BeaconFilter.ibeacon(UUID, 1, 2, 50), BeaconFilter.none(),
                       BeaconFilter.none()))
    assert good == beacons_config({"beacons": [{"kind": "pfdoa"}, {"kind": "ibeacon", "uuid": UUID, "major": 1,
                                                                  "minor": 2, "period_ms": 50}]}).filter_hash
    chunks = [(10.0, status_frame(0, good) + status_frame(1, defs.FILTER_TABLE_DEFAULT_HASH)
               + status_frame(2, good) + status_frame(3, 0x4242))] + interleaved(3)
    _, summary = run(tmp_path, TWO, chunks)
    assert summary["beacons"]["filter_mismatch"] == [1, 3] and summary["beacons"]["filter_hash"] == good
    # It is set right later: no longer named.
    _, summary = run(tmp_path, TWO, chunks + [(12.0, status_frame(1, good))])
    assert summary["beacons"]["filter_mismatch"] == [3]


def test_beacons_array_parsed_with_its_table():
    cfg = beacons_config({"beacons": [
        {"name": "r", "kind": "pfdoa", "id": 4},
        {"kind": "ibeacon", "uuid": UUID, "major": 1, "minor": 2, "odometry": True},
        {"kind": "eddystone_uid", "namespace": "00112233445566778899", "instance": "aabbccddeeff", "index": 3},
        {"kind": "mac48", "address": "C0:FF:EE:00:00:01", "period_ms": 250, "index": 2},
    ]})
    assert [(e.name, e.index) for e in cfg.entries] == [("r", 0), ("b1", 1), ("b3", 3), ("b2", 2)]
    t = cfg.table()
    assert t[0] == BeaconFilter.pfdoa(4) and t[1] == BeaconFilter.ibeacon(UUID, 1, 2, 100)
    assert t[2] == BeaconFilter.mac48("C0:FF:EE:00:00:01", 250) and t[3].kind == defs.FILTER_EDDYSTONE_UID
    assert cfg.entries[1].window_s == 0.1 and cfg.entries[3].window_s == 0.25 and cfg.entries[0].window_s is None
    assert cfg.primary().name == "b1"  # the one with the odometry
    assert BeaconsConfig().table() is None and BeaconsConfig().filter_hash is None
    # The limits table (ESPresense input) is still a table.
    assert beacons_config({"beacons": {"max_beacons": 5}}).max_beacons == 5


@pytest.mark.parametrize("entries, key, problem", [
    ([], "beacons", "empty"),
    ([{"kind": "pfdoa"}] * 5, "beacons", "at most 4"),
    (["x"], "beacons[0]", "must be a table"),
    ([{"name": "a"}], "beacons[0].kind", "missing"),
    ([{"kind": "eddystone"}], "beacons[0].kind", "must be one of"),
    ([{"kind": "pfdoa", "uuid": UUID}], "beacons[0].uuid", "unknown key"),
    ([{"kind": "pfdoa", "period_ms": 100}], "beacons[0].period_ms", "unknown key"),
    ([{"kind": "pfdoa", "id": 256}], "beacons[0].id", "0..255"),
    ([{"kind": "pfdoa", "index": 4}], "beacons[0].index", "0..3"),
    ([{"kind": "pfdoa", "name": ""}], "beacons[0].name", "printable"),
    ([{"kind": "pfdoa", "odometry": 1}], "beacons[0].odometry", "true or false"),
    ([{"kind": "ibeacon", "uuid": UUID, "major": 1}], "beacons[0].minor", "missing"),
    ([{"kind": "ibeacon", "uuid": "f782", "major": 1, "minor": 2}], "beacons[0].uuid", "16 bytes"),
    ([{"kind": "ibeacon", "uuid": UUID, "major": 70000, "minor": 2}], "beacons[0].major", "0..65535"),
    ([{"kind": "ibeacon", "uuid": UUID, "major": 1, "minor": 2, "period_ms": 0}], "beacons[0].period_ms", "1..65535"),
    ([{"kind": "ibeacon", "uuid": UUID, "major": 1, "minor": 2, "window_s": 0}], "beacons[0].window_s", "number"),
    ([{"kind": "mac48", "address": "zz"}], "beacons[0].address", "hex"),
    ([{"kind": "pfdoa"}, {"kind": "pfdoa", "id": 1, "index": 0}], "beacons[1].index", "also"),
    ([{"kind": "pfdoa", "name": "a"}, {"kind": "pfdoa", "id": 1, "name": "a"}], "beacons[1].name", "duplicate"),
    ([{"kind": "pfdoa"}, {"kind": "pfdoa"}], "beacons[1]", "the same beacon"),
    ([{"kind": "pfdoa", "odometry": True}, {"kind": "pfdoa", "id": 1, "odometry": True}], "beacons[1].odometry",
     "only one"),
])
def test_bad_beacons_entries_name_the_key(entries, key, problem):
    with pytest.raises(ConfigError) as e:
        beacons_config({"beacons": entries}, "s.toml")
    assert e.value.key == key and problem in e.value.problem, (e.value.key, e.value.problem)


def test_a_bad_beacons_entry_in_a_site_file_is_one_line_and_exit_2(tmp_path, capsys):
    from pfdoa.cli import main

    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + '[[beacons]]\nkind = "ibeacon"\nuuid = "00"\nmajor = 1\nminor = 2\n')
    assert main(["gateway", "--config", str(site), "--replay-capture", str(tmp_path / "none.cap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"pfdoa: error: {site}: beacons[0].uuid: an iBeacon proximity UUID is 16 bytes"]


# -- beacons that their readings name (ESPresense input: pfdoa gateway --mqtt-input espresense) --

ESP_SITE = """
[gateway]
window_s = 0.1
[beacons]
max_beacons = 2
[espresense]
rooms = { r0 = 0, r1 = 1, r2 = 2, r3 = 3 }
normalize_1m = false
time_field = "t"
"""


def named_readings(device: str, pos, k0: int, n: int, offset: float = 0.0):
    """n events of one device, 0.1 s apart from event k0 on: every anchor's noise-free reading."""
    from pfdoa.gateway.beacons import BeaconReading
    from pfdoa.gateway.reassembly import Reading

    return [BeaconReading(device, Reading(a, float(r), 10.0 + 0.1 * k + offset + 0.001 * a))
            for k in range(k0, k0 + n) for a, r in zip(ANCHORS, rssi_at(pos))]


class _Gone:
    """A sink that keeps what the named-beacons path tells the sinks."""

    def __init__(self) -> None:
        from pfdoa.sinks.base import Fanout, Sink

        outer = self
        self.written: list[str] = []
        self.gone: list[tuple[str, str]] = []

        class S(Sink):
            name = "probe"

            def write(self, record) -> None:
                outer.written.append(record.beacon)

            def beacon_gone(self, beacon: str, reason: str) -> None:
                outer.gone.append((beacon, reason))

        self.fan = Fanout([S()])


def test_devices_named_by_their_readings_get_their_own_estimator_within_max_beacons(tmp_path):
    from pfdoa.gateway.beacons import BeaconBatch

    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + ESP_SITE)
    st = load_settings(str(site), str(tmp_path / "out.jsonl"), "jsonl")
    assert st.espresense.rooms == {"r0": 0, "r1": 1, "r2": 2, "r3": 3} and st.beacons.max_beacons == 2
    probe = _Gone()
    pipe = build_pipeline(st, method="trilateration", seed=1, named_beacons=True, sinks=probe.fan)
    both = sorted(named_readings("phone-a", POS[0], 0, 10) + named_readings("tag-b", POS[1], 0, 10, 0.05),
                  key=lambda br: br.t)
    pipe.gateway.push_beacon(BeaconBatch(both))
    # A third device while two are tracked: the least recently heard (phone-a) is let go,
    # its open window estimated first, and the sinks told.
    pipe.gateway.push_beacon(named_readings("tag-c", POS[0], 10, 3)[0])
    pipe.gateway.finish()
    pipe.close()
    recs = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    by = {d: [r for r in recs if r["beacon"] == d] for d in ("phone-a", "tag-b", "tag-c")}
    assert len(by["phone-a"]) == 10 and len(by["tag-b"]) == 10 and len(by["tag-c"]) == 1
    for d, p in (("phone-a", POS[0]), ("tag-b", POS[1])):
        assert max(np.hypot(r["x"] - p[0], r["y"] - p[1]) for r in by[d]) < 0.01, d  # noise-free
    assert probe.written == [r["beacon"] for r in recs]  # every record reached the sinks, named
    assert probe.gone == [("phone-a", "evicted")]
    named = pipe.summary()["named_beacons"]
    assert (named["created"], named["evicted"], named["tracked"], named["records"]) == (3, 1, 2, 21)
    assert set(named["beacons"]) == {"tag-b", "tag-c"}
    # Without a tracker for them (a pipeline built without named_beacons) they are counted.
    plain = build_pipeline(st, method="trilateration", seed=1)
    plain.gateway.push_beacon(BeaconBatch(both[:5]))
    plain.close()
    assert plain.summary()["unnamed_dropped"] == 5 and "named_beacons" not in plain.summary()


class _Batches(Transport):
    """A finite input of prepared beacon-reading batches (message time when asked)."""

    finite = True

    def __init__(self, batches, message_time: bool, clock) -> None:
        super().__init__(clock)
        self.name = "batches"
        self.batches = list(batches)
        self.message_time = message_time

    def _open(self) -> None:
        pass

    def _read(self, timeout: float):
        if not self.batches:
            raise TransportEOF(self.name)
        return [self.batches.pop(0)]

    def _close(self) -> None:
        pass


def _run_named(tmp_path, name: str, batches, message_time: bool):
    from pfdoa.clock import FakeClock
    from pfdoa.gateway.runner import Runner

    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + ESP_SITE.replace("max_beacons = 2", "max_beacons = 8"))
    st = load_settings(str(site), str(tmp_path / f"{name}.jsonl"), "jsonl")
    pipe = build_pipeline(st, method="trilateration", seed=1, named_beacons=True)
    clock = FakeClock()
    runner = Runner([_Batches(batches, message_time, clock)], pipe.gateway, st.gateway, localizer=pipe.localizer,
                    clock=clock)
    runner.run()
    pipe.close()
    recs = [json.loads(line) for line in (tmp_path / f"{name}.jsonl").read_text().splitlines()]
    timeouts = sum(pipe.gateway.named.grouper(b).counters.timeouts for b in pipe.gateway.named.beacons)
    return recs, runner, timeouts


def test_on_message_time_the_timers_follow_each_reading_however_the_reads_were_batched(tmp_path):
    from pfdoa.gateway.beacons import BeaconBatch

    # tag-b goes on 0.2 s longer than phone-a: phone-a's last window can only close on time.
    both = sorted(named_readings("phone-a", POS[0], 0, 10) + named_readings("tag-b", POS[1], 0, 12, 0.05),
                  key=lambda br: br.t)
    one, runner1, timeouts1 = _run_named(tmp_path, "one", [BeaconBatch(both)], message_time=True)
    many, runner2, _ = _run_named(tmp_path, "many", [BeaconBatch(both[i:i + 3]) for i in range(0, len(both), 3)],
                                  message_time=True)
    assert one == many and len(one) == 22
    # The timers ran at every reading's own time (not the host clock, which never moved):
    # phone-a's last window closed on tag-b's later readings, not at the end of input.
    assert runner1.timer_polls == runner2.timer_polls == len(both) and runner1.timer == both[-1].t
    assert timeouts1 == 1
    last_a = [r for r in one if r["beacon"] == "phone-a"][-1]
    assert one.index(last_a) < len(one) - 1  # it left before the end of input
    # Receive time (no message time) and an input that never says it caught up: no timer ran.
    recv, runner3, timeouts3 = _run_named(tmp_path, "recv", [BeaconBatch(both)], message_time=False)
    assert runner3.timer_polls == 0 and timeouts3 == 0
    assert len(recv) == 22 and recv[-2:] != one[-2:]  # the same sets, phone-a's last only at the flush
