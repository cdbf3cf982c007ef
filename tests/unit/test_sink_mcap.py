"""ROS 2 recordings (pfdoa.sinks.mcap): every message decoded with the ecosystem's reader
(mcap.reader + mcap_ros2.decoder.DecoderFactory), checked against what was fed; the
recording's readings reproduce the recorded estimates."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

# The 'ros' extra is part of the test environment (tools/bootstrap.sh installs .[test,ros]).
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pfdoa.errors import InputError, OutputError
from pfdoa.gateway.config import GatewayConfig
from pfdoa.gateway.pipeline import Localizer, make_grouper
from pfdoa.gateway.setup import build_estimator
from pfdoa.sinks import Fanout, ros
from pfdoa.sinks.mcap import McapSink, open_recording

from sink_feed import SITE, scripted_run

SITE_TEXT = "# the scripted site\n[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.0\n"


def decoded(path):
    """{topic: [(schema name, log_time, message), ...]} in file order, by the ecosystem's reader."""
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=False):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    run = scripted_run()
    path = tmp_path_factory.mktemp("mcap") / "run.mcap"
    sink = McapSink(path, SITE, frame_id="pfdoa_site", site_toml=SITE_TEXT, metadata={"method": "scripted"})
    # Interleave as the gateway would: readings, then the records they completed, health.
    events = [(r.t, 0, i, r) for i, r in enumerate(run.readings)] + \
             [(rec.t, 1, i, rec) for i, rec in enumerate(run.records)] + \
             [(s.t, 2, i, s) for i, (s, _) in enumerate(run.snapshots)]
    for _, kind, _, obj in sorted(events, key=lambda e: (e[0], e[1], e[2])):
        (sink.reading, sink.write, sink.health)[kind](obj)
    sink.close()
    return run, path, decoded(path)


def test_every_topic_has_its_type_and_count(recorded):
    run, _, msgs = recorded
    assert {t: {m[0] for m in v} for t, v in msgs.items()} == {
        "/pfdoa/pose": {"geometry_msgs/msg/PoseWithCovarianceStamped"},
        "/pfdoa/readings": {"pfdoa_msgs/msg/AnchorReading"},
        "/diagnostics": {"diagnostic_msgs/msg/DiagnosticArray"},
        "/pfdoa/anchors": {"visualization_msgs/msg/MarkerArray"},
    }
    assert len(msgs["/pfdoa/pose"]) == len(run.records)
    assert len(msgs["/pfdoa/readings"]) == len(run.readings)
    assert len(msgs["/diagnostics"]) == 2
    # Once at the start, then when the levels changed (2 WARN, 3 STALE in the 2nd period).
    assert len(msgs["/pfdoa/anchors"]) == 2


def test_poses_equal_the_records(recorded):
    run, _, msgs = recorded
    for rec, (_, log_time, m) in zip(run.records, msgs["/pfdoa/pose"]):
        assert log_time == ros.time_ns(rec.t)
        assert m.header.frame_id == "pfdoa_site"
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ros.time_ns(rec.t)
        p = m.pose.pose
        assert (p.position.x, p.position.y, p.position.z) == (rec.x, rec.y, 0.0)
        c = np.array(m.pose.covariance).reshape(6, 6)
        assert c[0, 0] == rec.cov[0] and c[0, 1] == rec.cov[1] and c[1, 1] == rec.cov[2]
        assert c[2, 2] == c[3, 3] == c[4, 4] == ros.UNKNOWN_VARIANCE
        q = p.orientation
        if rec.heading is None:
            assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0) and c[5, 5] == ros.UNKNOWN_VARIANCE
        else:
            assert 2.0 * math.atan2(q.z, q.w) == pytest.approx(rec.heading, abs=1e-12)
            assert (q.x, q.y) == (0.0, 0.0) and q.z ** 2 + q.w ** 2 == pytest.approx(1.0)
            assert c[5, 5] == rec.heading_var
        off = c.copy()
        np.fill_diagonal(off, 0.0)
        off[0, 1] = off[1, 0] = 0.0
        assert not off.any()  # nothing correlated but x with y


def test_every_covariance_is_symmetric_positive_definite(recorded):
    _, _, msgs = recorded
    for _, _, m in msgs["/pfdoa/pose"]:
        c = np.array(m.pose.covariance).reshape(6, 6)
        assert np.array_equal(c, c.T)
        assert np.linalg.eigvalsh(c).min() > 0.0
        np.linalg.cholesky(c)


def test_degenerate_covariances_are_published_positive_definite(tmp_path):
    from sink_feed import CovRecord

    path = tmp_path / "degenerate.mcap"
    recs = [CovRecord(t=1.0, x=1.0, y=2.0, cov=(0.0, 0.0, 0.0)),        # all particles on one point
            CovRecord(t=2.0, x=1.0, y=2.0, cov=(0.04, 0.04, 0.04)),     # rank one
            CovRecord(t=3.0, x=1.0, y=2.0, sigma=float("nan")),         # no uncertainty at all
            CovRecord(t=4.0, x=1.0, y=2.0, sigma=0.3)]                  # sigma only (no cov yet)
    with McapSink(path, SITE) as sink:
        for r in recs:
            sink.write(r)
    covs = [np.array(m.pose.covariance).reshape(6, 6) for _, _, m in decoded(path)["/pfdoa/pose"]]
    for c in covs:
        assert np.array_equal(c, c.T) and np.linalg.eigvalsh(c).min() > 0.0
    assert np.linalg.eigvalsh(covs[0][:2, :2]).min() == pytest.approx(ros.MIN_VARIANCE)
    assert covs[2][0, 0] == covs[2][1, 1] == ros.UNKNOWN_VARIANCE
    assert covs[3][0, 0] == covs[3][1, 1] == pytest.approx(0.3 ** 2 / 2)


def test_diagnostics_carry_the_snapshot(recorded):
    run, _, msgs = recorded
    for (snap, line), (_, log_time, m) in zip(run.snapshots, msgs["/diagnostics"]):
        assert log_time == ros.time_ns(snap.t)
        gw, *anchors = m.status
        assert gw.name == "pfdoa: gateway" and gw.message == line.removeprefix("health: ")
        assert [s.hardware_id for s in anchors] == ["anchor0", "anchor1", "anchor2", "anchor3"]
        for s, h in zip(anchors, snap.anchors.values()):
            kv = {v.key: v.value for v in s.values}
            assert s.level == ros.LEVELS[h.level]
            assert (int(kv["received"]), int(kv["lost"]), int(kv["duplicates"]), int(kv["reboots"])) == \
                (h.received, h.lost, h.duplicates, h.reboots)
            assert kv["stale"] == str(h.stale).lower()
    last = msgs["/diagnostics"][-1][2].status
    assert [s.level for s in last[1:]] == [0, 0, 1, 3]  # OK OK WARN STALE
    assert msgs["/diagnostics"][0][2].status[1].level == 0


def test_anchor_markers_are_the_site_coloured_by_level(recorded):
    _, _, msgs = recorded
    first, second = (m for _, _, m in msgs["/pfdoa/anchors"])
    for arr in (first, second):
        cyl = [mk for mk in arr.markers if mk.ns == ros.ANCHOR_NS]
        assert [(mk.id, mk.pose.position.x, mk.pose.position.y) for mk in cyl] == \
            [(a.id, a.x, a.y) for a in SITE.anchors]
        assert all(mk.type == ros._CYLINDER and mk.header.frame_id == "pfdoa_site" for mk in cyl)
        assert [mk.text for mk in arr.markers if mk.ns == ros.LABEL_NS] == ["a0", "a1", "a2", "a3"]
    grey = ros.LEVEL_COLORS["STALE"]
    cyl2 = {mk.id: mk for mk in second.markers if mk.ns == ros.ANCHOR_NS}
    assert (cyl2[3].color.r, cyl2[3].color.g, cyl2[3].color.b) == pytest.approx(grey[:3])
    assert cyl2[0].color.g == pytest.approx(ros.LEVEL_COLORS["OK"][1])


def test_reader_yields_the_readings_back_exactly(recorded):
    run, path, msgs = recorded
    rec = open_recording(path)
    assert rec.metadata["method"] == "scripted" and rec.site_toml == SITE_TEXT
    assert rec.metadata["frame_id"] == "pfdoa_site"
    assert list(rec.readings()) == run.readings  # dataclass equality: every field, bit-exact floats
    assert rec.anchors() == [(a.id, a.x, a.y) for a in SITE.anchors]
    poses = list(rec.poses())
    assert [(p.x, p.y, p.cov) for p in poses] == [(r.x, r.y, r.cov) for r in run.records]
    # Same readings via the ecosystem's decoder: header stamp = receive time.
    _, log_time, m = msgs["/pfdoa/readings"][5]
    assert m.t == run.readings[5].t and log_time == ros.time_ns(run.readings[5].t)


def replay(readings, sink=None, seed=7):
    """Readings -> the gateway's reassembly and a real pf-doa estimator (as pfdoa replay)."""
    cfg = GatewayConfig()
    grouper = make_grouper(SITE.anchor_ids, cfg, "seq")
    loc = Localizer(SITE, build_estimator(SITE, "pf-doa", seed), sink, tolerate_errors=False)
    loc.records = []
    last_t = None
    for r in readings:
        if sink is not None:
            sink.reading(r)
        if r.t != last_t:
            loc.handle_all(grouper.poll(r.t))
            last_t = r.t
        loc.handle_all(grouper.push(r))
    loc.handle_all(grouper.flush())
    return loc.records


def test_a_recording_reproduces_its_estimates(tmp_path):
    run = scripted_run()
    path = tmp_path / "est.mcap"
    with Fanout([McapSink(path, SITE)]) as sink:
        live = replay(run.readings, sink)
    rec = open_recording(path)
    again = replay(rec.readings())
    assert len(live) == len(again) > 30
    assert [(r.t, r.x, r.y, r.sigma, r.seq, tuple(r.anchors)) for r in again] == \
        [(r.t, r.x, r.y, r.sigma, r.seq, tuple(r.anchors)) for r in live]
    assert [(p.x, p.y) for p in rec.poses()] == [(r.x, r.y) for r in live]


def test_unreadable_recordings_are_input_errors(tmp_path, recorded):
    _, path, _ = recorded
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(InputError, match="bad.mcap: not a readable MCAP recording"):
        open_recording(bad)
    with pytest.raises(InputError, match="cannot read"):
        open_recording(tmp_path / "missing.mcap")
    # Cut short (a gateway killed mid-run): what is complete is readable or it is an InputError.
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    try:
        got = list(open_recording(cut).readings())
    except InputError as exc:
        assert "cut.mcap" in str(exc)
    else:
        assert got == list(open_recording(path).readings())[: len(got)]
    with pytest.raises(OutputError, match="cannot write"):
        McapSink(tmp_path / "no" / "dir" / "x.mcap", SITE)


def test_events_come_back_in_the_order_the_pipeline_had_them(tmp_path):
    """Readings (with their event times), odometry increments and timer marks interleaved:
    the recording gives back that very sequence, every float bit-exact."""
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.gateway.transports import OdomLine, TimeMark

    run = scripted_run()
    events = []
    for k, r in enumerate(run.readings[:60]):
        events.append(replace(r, event_t=r.t - 0.0123456789 if k % 3 else None))
        if k % 4 == 3:
            events.append(OdomLine(r.t + 1e-7, r.t - 0.01, 0.01 * k, -0.001 * k, 0.0003 * k))
        if k % 2:
            events.append(TimeMark(r.t + 2e-6))
    path = tmp_path / "events.mcap"
    with McapSink(path, SITE) as sink:
        for e in events:
            if isinstance(e, Reading):
                sink.reading(e)
            elif isinstance(e, OdomLine):
                sink.odometry(e)
            else:
                sink.timer(e.t)
    rec = open_recording(path)
    assert list(rec.events()) == events
    assert list(rec.odometry()) == [e for e in events if isinstance(e, OdomLine)]
    msgs = decoded(path)
    assert {m[0] for m in msgs["/pfdoa/odometry"]} == {"pfdoa_msgs/msg/OdometryIncrement"}
    assert {m[0] for m in msgs["/pfdoa/timer"]} == {"pfdoa_msgs/msg/TimerMark"}
    odo = [e for e in events if isinstance(e, OdomLine)]
    for inc, (_, log_time, m) in zip(odo, msgs["/pfdoa/odometry"]):
        assert log_time == ros.time_ns(inc.t)  # logged at its arrival, stamped with its own time
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ros.time_ns(inc.t_odom)


def test_named_beacon_readings_carry_their_id_and_old_recordings_still_read(tmp_path):
    """A named beacon's reading is written with its id (decoded by mcap-ros2-support's
    reader) and read back as a BeaconReading; a recording whose AnchorReading definition
    predates the field (written here with that older definition) reads back unnamed."""
    from pfdoa.gateway.beacons import BeaconReading
    from pfdoa.gateway.reassembly import Reading

    path = tmp_path / "named.mcap"
    readings = [(Reading(1, -60.5, 1.0), "iBeacon:e2c5-1-2"), (Reading(2, -61.0, 1.1), None),
                (Reading(1, -62.0, 1.2), "phone")]
    with McapSink(path, SITE, site_toml=SITE_TEXT) as sink:
        for r, b in readings:
            sink.reading(r, b)
    assert [m[2].beacon for m in decoded(path)["/pfdoa/readings"]] == ["iBeacon:e2c5-1-2", "", "phone"]
    assert list(open_recording(path).events()) == [BeaconReading(b, r) if b else r for r, b in readings]

    old = tmp_path / "old.mcap"
    old_def = ros.READING_MSGDEF.replace("uint8 flags\nstring beacon\n", "uint8 flags\n", 1)
    assert old_def != ros.READING_MSGDEF
    msg = ros.reading_message(readings[0][0])
    del msg["beacon"]
    _record_one_reading(old, old_def, msg)
    assert list(open_recording(old).events()) == [readings[0][0]]


def _record_one_reading(path, msgdef: str, msg: dict) -> None:
    """A recording of one reading written with ``msgdef`` (an older AnchorReading) by
    mcap-ros2-support's writer."""
    from mcap_ros2.writer import Writer as Ros2Writer

    with open(path, "wb") as fh:
        w = Ros2Writer(fh)
        w.add_metadata("pfdoa", {"site_toml": SITE_TEXT})
        schema = w.register_msgdef(ros.READING_TYPE, msgdef)
        w.write_message("/pfdoa/readings", schema, msg, log_time=ros.time_ns(1.0))
        w.finish()


def test_a_site_s_own_anchor_ids_are_recorded_and_uint8_recordings_still_read(tmp_path):
    """A recorded dataset's anchor ids (6501, up to 2**31 - 1) go into the recording as they
    are (read back by mcap-ros2-support and by open_recording); a recording from when
    AnchorReading's anchor_id was uint8 still reads."""
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.site import SITE_ANCHOR_ID_MAX, parse_site

    ids = [6501, 300, SITE_ANCHOR_ID_MAX]
    site = parse_site({"radio": {"rssi_at_1m_dbm": -45.0, "path_loss_exponent": 2.0},
                       "anchors": [{"id": a, "x": x, "y": y} for a, (x, y) in zip(ids, [(0, 0), (5, 0), (0, 5)])]})
    readings = [Reading(a, -60.0 - i, 1.0 + 0.1 * i) for i, a in enumerate(ids)]
    path = tmp_path / "ids.mcap"
    with McapSink(path, site, site_toml=SITE_TEXT) as sink:
        for r in readings:
            sink.reading(r)
    msgs = decoded(path)
    assert [m[2].anchor_id for m in msgs["/pfdoa/readings"]] == ids
    cyl = [mk for mk in msgs["/pfdoa/anchors"][0][2].markers if mk.ns == ros.ANCHOR_NS]
    assert [mk.id for mk in cyl] == ids
    assert list(open_recording(path).readings()) == readings

    old = tmp_path / "old.mcap"
    old_def = ros.READING_MSGDEF.replace("uint32 anchor_id", "uint8 anchor_id", 1)
    assert old_def != ros.READING_MSGDEF
    _record_one_reading(old, old_def, ros.reading_message(Reading(126, -61.0, 1.0)))
    assert list(open_recording(old).readings()) == [Reading(126, -61.0, 1.0)]


def _read_all(path):
    rec = open_recording(path)
    return rec.metadata, list(rec.events()), list(rec.poses()), rec.anchors()


def test_a_damaged_recording_reads_back_the_same_or_is_an_input_error(tmp_path, recorded):
    """Single bit flips anywhere in a recording: every one reads back exactly what was
    written or is refused with one InputError line naming the file; never another
    exception and never other values. Chunks carry MCAP's CRC (checked); the metadata
    (the site file the replay runs on) carries ours."""
    import random

    _, path, _ = recorded
    data = path.read_bytes()
    want = _read_all(path)
    rng = random.Random(0)
    bad = tmp_path / "flip.mcap"
    refused = 0
    for _ in range(300):
        b = bytearray(data)
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
        bad.write_bytes(bytes(b))
        try:
            got = _read_all(bad)
        except InputError as exc:
            msg = str(exc)
            assert msg.startswith(f"{bad}: ") and "\n" not in msg, msg
            refused += 1
        else:
            assert got == want, f"bit flip at byte {i} changed what was read back"
    assert 50 <= refused < 300  # both outcomes occur: the flips reach the checked parts


def test_the_metadata_checksum_catches_a_changed_site_file(tmp_path, recorded):
    _, path, _ = recorded
    data = path.read_bytes()
    assert data.count(b"rssi_at_1m_dbm = -45.0") == 1
    bad = tmp_path / "site.mcap"
    bad.write_bytes(data.replace(b"rssi_at_1m_dbm = -45.0", b"rssi_at_1m_dbm = -46.0"))
    with pytest.raises(InputError, match="site.mcap: .*does not match its checksum"):
        open_recording(bad)


@pytest.mark.parametrize("what, event", [
    ("reading rssi_dbm 500.0 is outside", "rssi"),
    ("odometry dx nan is not finite", "odom"),
])
def test_values_no_gateway_writes_are_refused(tmp_path, what, event):
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.gateway.transports import OdomLine

    path = tmp_path / "forged.mcap"
    with McapSink(path, SITE) as sink:
        sink.reading(Reading(1, -60.0, 1.0, 3))
        if event == "rssi":
            sink.reading(Reading(2, 500.0, 1.1, 3))
        else:
            sink.odometry(OdomLine(1.2, 1.1, math.nan, 0.0, 0.0))
    rec = open_recording(path)
    with pytest.raises(InputError, match=f"forged.mcap: not a readable MCAP recording: DamagedRecording: {what}"):
        list(rec.events())


def _rechunked(src, dst, make_chunk):
    """``src`` rewritten record by record (mcap's own record writers) with each chunk replaced
    by ``make_chunk(its uncompressed bytes, the chunk)``; no summary section, as a writer
    killed before its end or a forger would leave it."""
    import zlib

    import mcap.records as records
    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.stream_reader import StreamReader

    magic = b"\x89MCAP0\r\n"
    out = RecordBuilder()
    with open(src, "rb") as fh:
        for rec in StreamReader(fh, emit_chunks=True).records:
            if isinstance(rec, records.Chunk):
                raw = zstandard.ZstdDecompressor().decompress(rec.data, max_output_size=rec.uncompressed_size)
                assert zlib.crc32(raw) == rec.uncompressed_crc
                make_chunk(raw, rec).write(out)
            elif isinstance(rec, (records.Header, records.Metadata, records.DataEnd)):
                rec.write(out)
            elif isinstance(rec, records.Footer):
                records.Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(out)
    dst.write_bytes(magic + out.end() + magic)


def test_a_chunk_is_never_decompressed_beyond_what_it_declares(tmp_path, recorded):
    """A decompression bomb: a few kilobytes whose chunk inflates to gigabytes. A chunk that
    declares more than MAX_CHUNK_BYTES is refused before anything is decompressed; one that
    declares less than it holds is read to its declared size and refused. A forged 39 kB
    file used to take 1 GB of memory and two minutes before failing (docs/security.md)."""
    import zlib

    import mcap.records as records
    import zstandard

    from pfdoa.sinks.mcap import MAX_CHUNK_BYTES

    _, path, _ = recorded
    same = tmp_path / "same.mcap"
    _rechunked(path, same, lambda raw, c: c)  # the rewriting alone keeps the recording
    assert _read_all(same) == _read_all(path)

    def chunk(raw, c, *, declared, data):
        return records.Chunk(compression="zstd", data=data, message_start_time=c.message_start_time,
                             message_end_time=c.message_end_time, uncompressed_crc=0, uncompressed_size=declared)

    big = tmp_path / "declares-too-much.mcap"
    _rechunked(path, big, lambda raw, c: chunk(raw, c, declared=MAX_CHUNK_BYTES + 1, data=c.data))
    with pytest.raises(InputError, match=r"declares-too-much.mcap: .*a chunk declares 67108865 bytes \(at most"):
        list(open_recording(big).readings())

    zeros = zstandard.ZstdCompressor().compressobj()
    inflating = zeros.compress(b"") + b"".join(zeros.compress(bytes(1 << 20)) for _ in range(8)) + zeros.flush()
    assert len(inflating) < 4096  # 8 MiB of zeros, no content size in the frame header
    bomb = tmp_path / "inflates.mcap"
    _rechunked(path, bomb, lambda raw, c: chunk(raw, c, declared=len(raw), data=inflating))
    with pytest.raises(InputError, match=r"inflates.mcap: .*decompresses to more than the \d+ bytes it declares"):
        list(open_recording(bomb).readings())

    short = tmp_path / "short.mcap"
    _rechunked(path, short, lambda raw, c: chunk(raw, c, declared=len(raw) + 10, data=zstandard.compress(raw)))
    with pytest.raises(InputError, match=r"short.mcap: .*decompresses to \d+ bytes, not the \d+ it declares"):
        list(open_recording(short).readings())

    crc = tmp_path / "crc.mcap"
    _rechunked(path, crc, lambda raw, c: records.Chunk(
        compression="", data=raw[:-1] + bytes([raw[-1] ^ 1]), message_start_time=c.message_start_time,
        message_end_time=c.message_end_time, uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw)))
    with pytest.raises(InputError, match="crc.mcap: .*does not match its CRC"):
        list(open_recording(crc).readings())


def test_lz4_and_uncompressed_chunks_read_back_and_are_bounded_too(tmp_path, recorded):
    """MCAP allows lz4 and uncompressed chunks (`mcap compress` and other writers make
    them): read back the same, and an lz4 chunk is bounded as a zstd one is."""
    import zlib

    import lz4.frame
    import mcap.records as records

    _, path, _ = recorded
    want = _read_all(path)
    for kind, pack in (("lz4", lz4.frame.compress), ("", bytes)):
        out = tmp_path / f"chunks-{kind or 'plain'}.mcap"
        _rechunked(path, out, lambda raw, c, kind=kind, pack=pack: records.Chunk(
            compression=kind, data=pack(raw), message_start_time=c.message_start_time,
            message_end_time=c.message_end_time, uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw)))
        assert _read_all(out) == want
    bomb = tmp_path / "lz4-inflates.mcap"
    _rechunked(path, bomb, lambda raw, c: records.Chunk(
        compression="lz4", data=lz4.frame.compress(raw + bytes(8 << 20)), message_start_time=c.message_start_time,
        message_end_time=c.message_end_time, uncompressed_crc=0, uncompressed_size=len(raw)))
    assert bomb.stat().st_size < 200_000
    with pytest.raises(InputError, match=r"lz4-inflates.mcap: .*decompresses to more than the \d+ bytes it declares"):
        list(open_recording(bomb).readings())


def test_ros2_tools_see_the_odometry_as_nav_msgs_and_the_site_frame_on_tf_static(tmp_path):
    """`pfdoa replay` of the example robot run with its odometry and a site placed in the map
    ([site] map_pose): mcap-ros2-support's reader finds nav_msgs/msg/Odometry (the increments
    composed in odom -> base_link) and one tf2_msgs/msg/TFMessage on /tf_static (map ->
    pfdoa_site, what static_transform_publisher would send), and the poses in pfdoa_site."""
    from pathlib import Path

    from pfdoa.cli import main
    from pfdoa.trace import read_odometry

    ex = Path(__file__).resolve().parents[2] / "examples"
    site = tmp_path / "site.toml"
    site.write_text("[site]\nmap_pose = [12.5, -3.0, 1.2]\n" + (ex / "site.toml").read_text())
    path = tmp_path / "run.mcap"
    assert main(["-q", "replay", str(ex / "run.csv"), "--config", str(site), "--odom", str(ex / "run.odom.csv"),
                 "--seed", "1", "--frame-id", "pfdoa_site", "--record", str(path), "--out", str(tmp_path / "o.jsonl")]) == 0
    msgs = decoded(path)
    assert {m[0] for m in msgs["/pfdoa/odom"]} == {"nav_msgs/msg/Odometry"}
    ((schema, log_time, tf),) = msgs["/tf_static"]
    assert schema == "tf2_msgs/msg/TFMessage" and log_time == min(m[1] for v in msgs.values() for m in v)
    (t,) = tf.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("map", "pfdoa_site")
    assert (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z) == (12.5, -3.0, 0.0)
    q = t.transform.rotation
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 0.0, math.sin(0.6), math.cos(0.6)))
    assert {m[2].header.frame_id for m in msgs["/pfdoa/pose"]} == {"pfdoa_site"}
    # The odometry: every increment, composed from the origin, each with its own time.
    od = read_odometry(ex / "run.odom.csv")
    odom = [m[2] for m in msgs["/pfdoa/odom"]]
    assert len(odom) == len(od.t) == len(msgs["/pfdoa/odometry"])
    x = y = yaw = 0.0
    for k, m in enumerate(odom):
        x, y = x + math.cos(yaw) * od.dx[k] - math.sin(yaw) * od.dy[k], y + math.sin(yaw) * od.dx[k] + math.cos(yaw) * od.dy[k]
        yaw += od.dtheta[k]
        assert (m.header.frame_id, m.child_frame_id) == ("odom", "base_link")
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ros.time_ns(od.t[k])
        p = m.pose.pose
        assert (p.position.x, p.position.y) == pytest.approx((x, y), abs=1e-9)
        assert 2.0 * math.atan2(p.orientation.z, p.orientation.w) == pytest.approx(math.remainder(yaw, 2 * math.pi))
        if k:
            dt = od.t[k] - od.t[k - 1]
            assert m.twist.twist.linear.x == pytest.approx(od.dx[k] / dt)
            assert m.twist.twist.angular.z == pytest.approx(od.dtheta[k] / dt)
        assert m.pose.covariance[0] == m.twist.covariance[35] == ros.UNKNOWN_VARIANCE
    assert math.hypot(x, y) > 0.5  # the robot drove, not a standstill
    # Without map_pose the site frame is the map: no /tf_static.
    assert "/tf_static" not in decoded(recorded_without_map_pose(tmp_path, ex))


def recorded_without_map_pose(tmp_path, ex):
    from pfdoa.cli import main

    path = tmp_path / "plain.mcap"
    assert main(["-q", "replay", str(ex / "run.csv"), "--config", str(ex / "site.toml"), "--odom",
                 str(ex / "run.odom.csv"), "--record", str(path), "--out", str(tmp_path / "p.jsonl")]) == 0
    return path


def test_a_site_placed_in_the_map_needs_its_own_frame_name(tmp_path, capsys):
    from pathlib import Path

    from pfdoa.cli import main

    ex = Path(__file__).resolve().parents[2] / "examples"
    site = tmp_path / "site.toml"
    site.write_text("[site]\nmap_pose = [1.0, 2.0, 0.5]\n" + (ex / "site.toml").read_text())
    assert main(["replay", str(ex / "run.csv"), "--config", str(site), "--out", str(tmp_path / "o.jsonl")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--frame-id map" in err[0] and "map_pose" in err[0], err
    site.write_text("[site]\nmap_pose = [1.0, 2.0, 90]\n" + (ex / "site.toml").read_text())
    assert main(["replay", str(ex / "run.csv"), "--config", str(site), "--frame-id", "pfdoa_site"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "site.map_pose" in err[0] and "radians" in err[0], err


def _stream_records(path):
    """The records the mcap package's own linear reader gets from a file, stopping where a
    cut file ends (it raises there: the record it was reading is incomplete)."""
    from mcap.stream_reader import StreamReader

    out = []
    with open(path, "rb") as fh:
        try:
            for rec in StreamReader(fh, emit_chunks=False, validate_crcs=True).records:
                out.append(rec)
        except Exception as exc:  # the cut: whatever the partial record made the reader raise
            out.append(exc)
    return out


def test_chunks_are_closed_and_made_durable_by_count_and_by_time(tmp_path, monkeypatch):
    """While the sink is open (a gateway still running, or killed now) the file on disk
    already holds the header and metadata, then every closed chunk: one is closed after
    CHUNK_MESSAGES messages, or FLUSH_S after the last on the (injected) monotonic clock, at
    the next input; the open one is all a kill would lose."""
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.sinks import mcap as mcap_sink

    monkeypatch.setattr(mcap_sink, "CHUNK_MESSAGES", 10)
    now = [0.0]
    path = tmp_path / "live.mcap"
    sink = McapSink(path, SITE, site_toml=SITE_TEXT, monotonic=lambda: now[0])
    rec = open_recording(path)  # not finished: cut, but it says what it is
    assert rec.cut and rec.metadata["site_toml"] == SITE_TEXT and list(rec.readings()) == []
    readings = [Reading(a, -60.0 - a, 0.01 * k) for k in range(25) for a in (0, 1)]
    for r in readings[:12]:
        sink.reading(r)
    # 10 messages (the anchor markers and 9 readings) were in the chunk before the 11th reading.
    assert sink.chunks == 1 and list(open_recording(path).readings()) == readings[:9]
    for r in readings[12:15]:
        sink.reading(r)
    assert sink.chunks == 1  # 6 in the open chunk: neither full nor old
    now[0] = mcap_sink.FLUSH_S
    sink.reading(readings[15])  # FLUSH_S later: the open chunk is closed before this one goes in
    assert sink.chunks == 2 and list(open_recording(path).readings()) == readings[:15]
    # The mcap package's own linear reader reads the same cut file up to where it ends.
    got = _stream_records(path)
    assert isinstance(got[-1], Exception) and sum(type(r).__name__ == "Message" for r in got) == 16
    sink.close()
    rec = open_recording(path)
    assert not rec.cut and list(rec.readings()) == readings[:16]


def test_a_recording_cut_at_any_byte_replays_to_a_prefix_of_the_gateways_estimates(tmp_path, monkeypatch, capsys,
                                                                                   caplog):
    """A gateway's recording (small chunks) cut at 40 seeded random offsets and at every
    chunk's end and one byte either side: it is never an error but before its metadata (one
    InputError line); every reader gives a prefix of the whole file's; and ``pfdoa replay``
    of the cut file (exit 0, a warning that it was cut) writes exactly the gateway's first
    estimates, as many as the cut file holds poses (cut after the inputs' end, which the
    recording marks: every estimate, and no warning)."""
    import random

    from pfdoa.cli import main
    from pfdoa.gateway.inputs.capture import CAPTURE_V2, capture_line
    from pfdoa.gateway.transports import Chunk, TimeMark
    from pfdoa.protocol.uart import encode_uart
    from pfdoa.sinks import mcap as mcap_sink

    import gateway_feed as feed

    monkeypatch.setattr(mcap_sink, "CHUNK_MESSAGES", 80)
    site = tmp_path / "site.toml"
    site.write_text(feed.TEST_SITE + "[gateway]\nhealth_interval_s = 0\n")
    cap = tmp_path / "run.cap"
    t0 = 1_700_000_000.0
    lines = [CAPTURE_V2 + "\n"]
    for seq in range(120):
        for a, m in feed.reports(seq):
            if (seq + a) % 11:  # some reports lost: sets that time out, timer marks that matter
                lines.append(capture_line(Chunk("serial0", t0 + 0.02 * seq + 0.001 * a, encode_uart(m, a))))
        lines.append(capture_line(TimeMark(t0 + 0.02 * seq + 0.015)))
    cap.write_text("".join(lines))
    full, live = tmp_path / "full.mcap", tmp_path / "live.jsonl"
    assert main(["-q", "gateway", "--config", str(site), "--replay-capture", str(cap), "--method", "wcl",
                 "--seed", "1", "--record", str(full), "--out", str(live)]) == 0
    live_lines = live.read_text().splitlines()
    whole = open_recording(full)
    events, poses = list(whole.events()), list(whole.poses())
    assert not whole.cut and len(poses) == len(live_lines) > 60
    data = full.read_bytes()
    chunk_ends = []
    with open(full, "rb") as fh:
        from mcap.records import Chunk as McapChunk
        from mcap.stream_reader import StreamReader

        reader = StreamReader(fh, emit_chunks=True)
        for rec in reader.records:
            if isinstance(rec, McapChunk):
                chunk_ends.append(fh.tell())
    assert len(chunk_ends) >= 5
    rng = random.Random(48)
    offsets = sorted({rng.randrange(len(data)) for _ in range(40)} | {e + d for e in chunk_ends for d in (-1, 0, 1)})
    cut = tmp_path / "cut.mcap"
    replayed = 0
    for i, off in enumerate(offsets):
        cut.write_bytes(data[:off])
        try:
            rec = open_recording(cut)
        except InputError as exc:
            assert off < chunk_ends[0] and "\n" not in str(exc), (off, exc)
            continue
        got_events, got_poses = list(rec.events()), list(rec.poses())
        assert rec.extent.truncated and got_events == events[:len(got_events)], off
        assert got_poses == poses[:len(got_poses)], off
        assert rec.cut or got_events == events, off  # past the inputs' end the run was whole
        if i % 4 and off not in chunk_ends:
            continue  # the command on a quarter of them and on every chunk's end
        out = tmp_path / f"r{off}.jsonl"
        capsys.readouterr()
        caplog.clear()
        rc = main(["replay", str(cut), "--out", str(out)])
        err = capsys.readouterr().err + caplog.text
        if not got_events:
            assert rc == 2 and "no readings recorded" in err, (off, err)
            continue
        assert rc == 0 and ("the recording was cut" in err) == rec.cut, (off, err[-500:])
        # Cut: exactly the estimates the gateway had made by then. Its inputs whole: all of them.
        assert out.read_text().splitlines() == (live_lines[:len(got_poses)] if rec.cut else live_lines), off
        replayed += 1
    assert replayed >= 10
