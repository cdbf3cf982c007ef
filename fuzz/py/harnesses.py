"""atheris targets for the gateway's untrusted-input paths (one function per target).

Each ``<target>(data: bytes)`` raises (AssertionError or the unexpected exception) when an
invariant of docs/security.md breaks, and returns quietly otherwise. They import no atheris,
so tests/unit/test_fuzz_regressions.py replays the committed corpora and regressions through the
same functions; fuzz/py/run_atheris.py instruments them for coverage-guided fuzzing.
"""

from __future__ import annotations

import os
import struct
import tempfile

from pfdoa.errors import ConfigError, InputError
from pfdoa.gateway.reassembly import Reading, SeqReassembler, WindowGrouper
from pfdoa.protocol import defs
from pfdoa.protocol.can import decode_can, encode_can
from pfdoa.protocol.cobs import cobs_encode
from pfdoa.protocol.crc import crc16
from pfdoa.protocol.messages import LAYOUTS, StatusA, StatusB
from pfdoa.protocol.uart import ANCHOR_TO_HOST, StreamDecoder, decode_frame, encode_uart, seal
from pfdoa.site import load_site
from pfdoa.trace import read_odometry, read_trace

_EXTRA = {spec[0]: spec[3] for spec in defs.MESSAGES.values()}
_LEN = {spec[0]: spec[2] for spec in defs.MESSAGES.values()}
_TO_HOST = sorted(ANCHOR_TO_HOST)


def build_frames(data: bytes) -> bytes:
    """Records -> a UART stream whose frames mostly pass COBS and the CRC (the fuzzer
    cannot forge a CRC-16 by itself), in either protocol version (SPEC 2.1, 8.2). Record:
    ctl byte, then ``ctl & 0x3F`` raw bytes; ``ctl & 0x40`` forces a version (1 when the
    first raw byte is odd, else 2), an anchor-to-host type of it and its exact length; the
    CRC (with the type's CRC_EXTRA) is fixed unless ``ctl & 0x80`` (then the last 2 raw
    bytes are the version-1 CRC, or the last 3 the version-2 trailer); ``ctl == 0xFF``
    inserts one raw stream byte (a stray delimiter, a glued frame)."""
    out = bytearray()
    i = 0
    while i < len(data):
        ctl = data[i]
        i += 1
        if ctl == 0xFF:
            out += data[i:i + 1]
            i += 1
            continue
        n = min(ctl & 0x3F, defs.MAX_RAW + 2)
        raw = bytearray(data[i:i + n].ljust(n, b"\x00"))
        i += n
        if ctl & 0x40 and n >= 2:
            version = defs.V1_PROTO_VERSION if raw[0] & 1 else defs.PROTO_VERSION
            types = [t for t in _TO_HOST if version in LAYOUTS[t].versions]
            t = types[raw[1] % len(types)]
            raw[0], raw[1] = version, t
            n = defs.HEADER_LEN + _LEN[t] + (defs.CRC_LEN if version == defs.V1_PROTO_VERSION else 0)
            raw = raw[:n].ljust(n, b"\x00")
        if n and raw[0] == defs.V1_PROTO_VERSION:
            if not ctl & 0x80 and n >= 2:
                crc = crc16(bytes(raw[:-2]) + bytes((_EXTRA.get(raw[1], 0),)))
                raw[-2:] = crc.to_bytes(2, "little")
            out += cobs_encode(bytes(raw)) + b"\x00"
        elif not ctl & 0x80 and n >= 2:
            out += seal(bytes(raw), _EXTRA.get(raw[1], 0)) + b"\x00"
        else:
            out += cobs_encode(bytes(raw[:-3])) + bytes(raw[-3:]) + b"\x00"
    return bytes(out)


def _reencode(d, piece_len: int) -> bytes:
    """The frame of a decoded message in the version whose encoding has the length the
    received piece had (a frame's encoding is unique per version)."""
    for v in defs.VERSIONS:
        try:
            wire = encode_uart(d.message, d.anchor_id, v)
        except ValueError:
            continue  # not representable in that version
        if len(wire) - 1 == piece_len:
            return wire
    raise AssertionError(f"{d} does not re-encode to a frame of {piece_len} bytes")


def stream(data: bytes) -> None:
    """StreamDecoder: never raises; chunking never changes output or counters; pending is
    bounded; every accepted frame re-encodes to itself; every input byte is accounted for."""
    if not data:
        return
    mode, body = data[0], data[1:]
    s = build_frames(body) if mode & 1 else body
    one = StreamDecoder(types=ANCHOR_TO_HOST)
    ref = one.feed(s)
    chunked = StreamDecoder(types=ANCHOR_TO_HOST)
    out = []
    i = k = 0
    while i < len(s):
        n = body[k % len(body)] % 17 + 1 if body else len(s)
        out += chunked.feed(s[i:i + n])
        assert chunked.pending <= defs.MAX_ENCODED
        i, k = i + n, k + 1
    assert out == ref and chunked.counters == one.counters
    c = one.counters
    assert c["frames_ok"] == len(ref)
    # Frames are independent: each delimited piece checked alone gives the same verdicts.
    pieces = [p for p in s.split(b"\x00")[:-1] if p]
    verdicts = [(p, decode_frame(p, ANCHOR_TO_HOST)) for p in pieces]
    accepted = [(p, v) for p, v in verdicts if not isinstance(v, str)]
    assert [v for _, v in accepted] == ref
    ok_bytes = 0
    for p, d in accepted:
        wire = _reencode(d, len(p))
        assert wire[:-1] == p and decode_frame(wire[:-1], ANCHOR_TO_HOST) == d
        ok_bytes += len(p)
    assert ok_bytes + c["bytes_discarded"] + s.count(0) + one.pending == c["bytes_in"] == len(s)


def _can_or_none(m, anchor: int, version: int):
    try:
        return encode_can(m, anchor, version)
    except ValueError:
        return None  # not representable in that version (e.g. a v2 report in v1)


def can(data: bytes) -> None:
    """decode_can: never raises; an accepted frame re-encodes to the same id and bytes."""
    while len(data) >= 3:
        can_id = int.from_bytes(data[:2], "little") & 0xFFF  # also ids beyond 11 bits
        n = data[2] % 10  # DLC 0..9 (9: more than classic CAN allows)
        frame, data = data[3:3 + n], data[3 + n:]
        d = decode_can(can_id, frame)
        if isinstance(d, str):
            assert d in defs.ERRORS
            continue
        assert can_id <= 0x7FF and 0 <= d.anchor_id <= 127
        m = d.message
        if isinstance(m, (StatusA, StatusB)):
            assert len(frame) == 8
            continue
        # one of the versions gives exactly these bytes back (a report's DLC tells which)
        assert [(can_id, bytes(frame))] in [_can_or_none(m, d.anchor_id, v) for v in defs.VERSIONS]


IDS = (0, 1, 2, 3, 4)
_REC = struct.Struct("<BHbBB")  # anchor, seq, rssi, dt (10 ms), op


def reassembler(data: bytes) -> None:
    """Bytes -> readings -> SeqReassembler or WindowGrouper with small bounds. Every set
    is consistent (its values and its missing list partition the configured anchors),
    open sets and remembered history stay within their bounds, counters add up, and every
    reading that is not a duplicate, late, unknown or seq-less ends up in exactly one set."""
    if not data:
        return
    seq_mode = data[0] & 1
    g = (SeqReassembler(IDS, set_timeout_s=0.05, max_open_sets=4, stale_after_s=0.5, history=8) if seq_mode
         else WindowGrouper(IDS, window_s=0.1, stale_after_s=0.5))
    sets = []
    t = 0.0
    tick = 0
    for off in range(1, len(data) - _REC.size + 1, _REC.size):
        a, seq, rssi, dt, op = _REC.unpack_from(data, off)
        t += dt * 0.01
        tick = (tick + dt * 10 - (60000 if op & 0x10 else 0)) % (1 << 32)  # op bit 4: reboot-like tick
        if op & 0x20:
            sets += g.poll(t)
            continue
        r = Reading(a % 8, float(rssi), t, None if op & 0x40 else seq, tick if op & 0x80 else None)
        sets += g.push(r)
        assert g.open_sets <= (4 if seq_mode else 2)
        if seq_mode:
            assert len(g._closed) <= 8 and len(g._closed_order) <= 8 and len(g._heap) == g.open_sets
    sets += g.flush()
    assert g.open_sets == 0
    ids = set(IDS)
    for s in sets:
        assert set(s.rssi) <= ids and set(s.missing) == ids - set(s.rssi), s
        assert set(s.stale) <= ids and set(s.rebooted) <= ids
    c = g.counters
    assert c.sets == len(sets) == c.complete + c.partial
    assert len(c.unknown_ids) <= 256
    if seq_mode:
        placed = c.readings - c.unknown_anchor - c.no_seq - c.duplicates - c.late
        assert sum(len(s.rssi) for s in sets) == placed
    for st in g.tracker.all_stats().values():
        assert st.lost >= 0 and st.received >= 0


_ESP_ROOMS = {"kitchen": 1, "hall": 2, "office": 3}
_ESP_REJECTIONS = {"oversized", "bad_topic", "bad_json", "bad_rssi", "bad_rssi_1m", "bad_time", "bad_device",
                   "unknown_room", "ignored_device"}


def espresense(data: bytes) -> None:
    """ESPresense MQTT messages (records split at 0x00; in each, the topic up to the first
    newline, the payload after it) through ``EspresenseInput``'s message handler, as paho's
    thread calls it, with two configurations (receive time; a time field, device patterns,
    no 1 m normalisation): the handler never raises, every message is accepted, dropped
    from the full queue or rejected under a documented name, and every queued reading has
    a configured anchor, a finite RSSI and time and a bounded device id."""
    import math

    from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconReading
    from pfdoa.mqtt.espresense import MAX_TIME, MAX_UNKNOWN_ROOMS, EspresenseInput, espresense_config

    configs = ({"rooms": _ESP_ROOMS},
               {"rooms": _ESP_ROOMS, "time_field": "t", "devices": ["tag*", "iBeacon:*-?"], "normalize_1m": False})
    for k, table in enumerate(configs):
        cfg = espresense_config({"espresense": table}, "fuzz", (1, 2, 3), -59.0)
        inp = EspresenseInput(None, cfg, max_queue=8)  # never started: no broker, messages handed in below
        for i, record in enumerate(data.split(b"\x00")[:64]):
            topic, _, payload = record.partition(b"\n")
            inp._on_message(topic.decode("utf-8", "replace"), payload, 100.0 + i)
        assert inp.messages == inp.accepted + inp.queue_drops + sum(inp.rejected.values())
        assert set(inp.rejected) <= _ESP_REJECTIONS, inp.rejected
        assert len(inp._q) <= 8 and len(inp.parser.unknown_rooms) <= MAX_UNKNOWN_ROOMS
        for item in inp._q:
            assert isinstance(item, BeaconReading) and 0 < len(item.beacon) <= MAX_ID_LEN
            r = item.reading
            assert r.anchor_id in _ESP_ROOMS.values() and math.isfinite(r.rssi_dbm)
            assert (0.0 <= r.t <= MAX_TIME) if k else 100.0 <= r.t < 164.0


def _in_file(data: bytes, suffix: str) -> str:
    fd, path = tempfile.mkstemp(suffix=suffix)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    return path


def trace(data: bytes) -> None:
    """read_trace / read_odometry: a Trace with consistent columns, or InputError."""
    path = _in_file(data, ".csv")
    try:
        try:
            tr = read_trace(path)
        except InputError:
            pass
        else:
            n = len(tr.t)
            assert n > 0 and len(tr.anchor) == len(tr.rssi_dbm) == n
            assert tr.seq is None or len(tr.seq) == n
            assert (tr.gt_x is None) == (tr.gt_y is None)
        try:
            od = read_odometry(path)
        except InputError:
            pass
        else:
            assert len(od.t) == len(od.dx) == len(od.dy) == len(od.dtheta)
    finally:
        os.unlink(path)


def site(data: bytes) -> None:
    """load_site: a Site with finite values and distinct ids in 0..126, or ConfigError."""
    import math

    path = _in_file(data, ".toml")
    try:
        try:
            s = load_site(path)
        except ConfigError:
            return
        ids = s.anchor_ids
        assert len(set(ids)) == len(ids) >= 3 and all(0 <= a <= 126 for a in ids)
        assert all(math.isfinite(v) for v in (s.radio.rssi_at_1m_dbm, s.radio.path_loss_exponent))
        assert all(math.isfinite(v) for a in s.anchors for v in (a.x, a.y, a.rssi_offset_db))
    finally:
        os.unlink(path)


def capture(data: bytes) -> None:
    """CaptureReader: a whole file (through the reader, as `pfdoa replay` reads it) gives
    chunks with a finite time, bounded data and a valid CAN id, or counted bad lines."""
    import math

    from pfdoa.gateway.inputs.capture import CAPTURE_MAX_LINE, CaptureReader
    from pfdoa.gateway.transports import Chunk, OdomLine, TransportEOF

    path = _in_file(data, ".cap")
    try:
        r = CaptureReader(path)
        r.open()
        chunks = []
        try:
            while True:
                chunks += r.read(0.0)
        except TransportEOF:
            pass
        r.close()
        for c in chunks:
            assert math.isfinite(c.t), c
            if isinstance(c, OdomLine):
                assert all(math.isfinite(v) for v in (c.t_odom, c.dx, c.dy, c.dtheta)), c
            elif isinstance(c, Chunk):
                assert isinstance(c.data, bytes) and len(c.data) <= CAPTURE_MAX_LINE // 2
                assert c.can_id is None or (0 <= c.can_id <= 0x7FF and len(c.data) <= 8)
        assert r.bad_lines >= 0
    finally:
        os.unlink(path)


def recording(data: bytes) -> None:
    """open_recording and every reader of a Recording: what a gateway wrote (finite times,
    RSSI in range, bounded beacon ids), or one InputError line naming the file; memory
    bounded by the file and MAX_CHUNK_BYTES (the fuzzer's -rss_limit_mb catches the rest).
    The same file cut short reads as a prefix of it (or one InputError line)."""
    import math

    from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconReading
    from pfdoa.gateway.transports import OdomLine, TimeMark
    from pfdoa.sinks.mcap import open_recording
    from pfdoa.trace import RSSI_MAX_DBM, RSSI_MIN_DBM

    path = _in_file(data, ".mcap")
    try:
        try:
            rec = open_recording(path)
            events = list(rec.events())
            poses = list(rec.poses())
            rec.anchors()
        except InputError as exc:
            msg = str(exc)
            assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
            return
        assert isinstance(rec.metadata, dict) and isinstance(rec.site_toml, str)
        for e in events:
            if isinstance(e, BeaconReading):
                assert 0 < len(e.beacon) <= MAX_ID_LEN
                e = e.reading
            if isinstance(e, OdomLine):
                assert all(math.isfinite(v) for v in (e.t, e.t_odom, e.dx, e.dy, e.dtheta)), e
            elif isinstance(e, TimeMark):
                assert math.isfinite(e.t), e
            else:
                assert math.isfinite(e.t) and RSSI_MIN_DBM <= e.rssi_dbm <= RSSI_MAX_DBM, e
        assert all(len(p.cov) == 3 for p in poses)
        # Cut short at a point the input picks (a gateway killed while recording): read up
        # to its last whole record, a prefix of what the whole file gives, or one InputError.
        with open(path, "r+b") as fh:
            fh.truncate(len(data) * data[-1] // 256)
        try:
            cut = open_recording(path)
            assert list(cut.events()) == events[:len(list(cut.events()))]
            assert list(cut.poses()) == poses[:len(list(cut.poses()))]
        except InputError as exc:
            msg = str(exc)
            assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    finally:
        os.unlink(path)


# -- the command line's file inputs, end to end -------------------------------------------
# Each target below hands the bytes as one file to a real `pfdoa` command, in process
# (pfdoa.cli.main: the same loading code, checks and error handling the command runs),
# beside fixed good files for its other inputs. The command must exit 0 with output that
# matches its counters, or 2 with exactly one error line that names the file or the
# option; anything else (another exit status, an exception) is a crash.

_SITE = ("[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.5\n" + "".join(
    f"\n[[anchors]]\nid = {i + 1}\nx = {x}\ny = {y}\n" for i, (x, y) in enumerate(((0, 0), (0, 6), (6, 6), (6, 0))))
    + "\n[gateway]\nset_timeout_s = 0.3\nstale_after_s = 2.0\n")
_TRACE = "t,anchor,rssi_dbm,gt_x,gt_y,seq\n" + "".join(
    f"{k * 0.1:.1f},{a},{-55 - 3 * a - k % 3},3.0,{1.0 + 0.1 * k:.1f},{k}\n" for k in range(20) for a in (1, 2, 3, 4))
_ODOM = "t,dx,dy,dtheta\n" + "".join(f"{k * 0.1:.1f},0.01,0.0,0.001\n" for k in range(20))
_FIXED: dict[str, str] = {}


def _fixed(name: str) -> str:
    """Path of a fixed good input (written once per process)."""
    if not _FIXED:
        d = tempfile.mkdtemp(prefix="pfdoa-fuzz-")
        for key, text in (("site", _SITE), ("trace", _TRACE), ("odom", _ODOM)):
            path = os.path.join(d, {"site": "site.toml", "trace": "trace.csv", "odom": "odom.csv"}[key])
            with open(path, "w") as fh:
                fh.write(text)
            _FIXED[key] = path
        _FIXED["dir"] = d
        import logging

        # The commands' warnings go to a handler of ours (cli.main then adds none: no log
        # line per input, no handler bound to a replaced stderr).
        logging.getLogger().addHandler(logging.NullHandler())
    return _FIXED[name]


def _run_cli(args: list[str], named: str) -> tuple[int, list[str]]:
    """pfdoa.cli.main(args) with standard error captured: (exit status, error lines).
    Checks the exit-status contract (0, or 2 with one line naming ``named`` or an option)."""
    import contextlib
    import io

    from pfdoa.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(args)
    errors = [ln for ln in err.getvalue().splitlines() if ln.startswith("pfdoa: error: ")]
    assert rc in (0, 2), (rc, err.getvalue()[-2000:])
    if rc == 2:
        assert len(errors) == 1, err.getvalue()[-2000:]
        assert named in errors[0] or " --" in errors[0] or errors[0].startswith("pfdoa: error: --"), errors[0]
    else:
        assert not errors, errors
    return rc, errors


def _json_lines(path: str) -> list:
    import json

    with open(path) as fh:
        return [json.loads(ln) for ln in fh]


def _stats(path: str) -> dict:
    import json

    with open(path) as fh:
        return json.load(fh)


def cli_site(data: bytes) -> None:
    """A site file through `pfdoa replay --config` (its [gateway], [output] and [estimator]
    tables included); a site that loads also survives the one writer: written, loaded and
    written again it is the same text, with the same anchors, radio and name."""
    from pfdoa import _toml as toml
    from pfdoa.site import parse_site, site_to_toml

    path = _in_file(data, ".toml")
    out, stats = path + ".jsonl", path + ".json"
    try:
        try:
            s = load_site(path)
        except ConfigError:
            s = None
        if s is not None:
            text = site_to_toml(s)
            again = parse_site(toml.loads(text), path)
            assert site_to_toml(again) == text, text
            assert again.anchors == s.anchors and again.radio == s.radio and again.name == s.name
        rc, _ = _run_cli(["-q", "replay", _fixed("trace"), "--config", path, "--method", "wcl", "--format", "jsonl",
                          "--out", out, "--stats", stats], path)
        if rc == 0:
            assert len(_json_lines(out)) == _stats(stats)["estimates"]
    finally:
        for f in (path, out, stats):
            if os.path.exists(f):
                os.unlink(f)


def cli_trace(data: bytes) -> None:
    """A trace through `pfdoa replay`: exit 0 with one output record per counted estimate,
    or exit 2 with one line naming the file."""
    path = _in_file(data, ".csv")
    out, stats = path + ".jsonl", path + ".json"
    try:
        rc, _ = _run_cli(["-q", "replay", path, "--config", _fixed("site"), "--method", "wcl", "--out", out,
                          "--stats", stats], path)
        if rc == 0:
            recs, st = _json_lines(out), _stats(stats)
            assert len(recs) == st["estimates"] <= st["sets"]
            assert st["readings"] >= st["unknown_anchor"] + st["duplicates"]
    finally:
        for f in (path, out, stats):
            if os.path.exists(f):
                os.unlink(f)


def cli_odometry(data: bytes) -> None:
    """An odometry file through `pfdoa replay --odom`, and the same bytes as a live stream
    (OdometryReader on a pipe): every increment finite, no unfinished line held beyond
    MAX_LINE, each overlong line counted once."""
    import math

    from pfdoa.gateway.odomsource import MAX_LINE, OdometryReader
    from pfdoa.gateway.transports import TransportError

    path = _in_file(data, ".csv")
    out, stats = path + ".jsonl", path + ".json"
    try:
        rc, _ = _run_cli(["-q", "replay", _fixed("trace"), "--config", _fixed("site"), "--odom", path,
                          "--method", "wcl", "--out", out, "--stats", stats], path)
        if rc == 0:
            assert len(_json_lines(out)) == _stats(stats)["estimates"]
    finally:
        for f in (path, out, stats):
            if os.path.exists(f):
                os.unlink(f)
    r, w = os.pipe()
    try:
        os.write(w, data[:60000])  # within a pipe's buffer: no writer thread needed
        os.close(w)
        w = -1
        reader = OdometryReader(f"/dev/fd/{r}")
        reader.open()
        items = []
        try:
            while True:
                items += reader.read(0.0)
                assert len(reader._buf) <= MAX_LINE
        except TransportError:
            pass
        reader.close()
        for it in items:
            assert all(math.isfinite(v) for v in (it.t_odom, it.dx, it.dy, it.dtheta)), it
        n_lines = data[:60000].count(b"\n") + 1
        assert reader.lines == len(items) and reader.lines + reader.bad_lines <= n_lines
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


def cli_capture(data: bytes) -> None:
    """A capture file through `pfdoa gateway --replay-capture`: exit 0 with one record per
    counted estimate and the file's own counters in the final ones, or exit 2 naming it."""
    path = _in_file(data, ".cap")
    out, stats = path + ".jsonl", path + ".json"
    try:
        rc, _ = _run_cli(["-q", "gateway", "--config", _fixed("site"), "--replay-capture", path, "--method", "wcl",
                          "--out", out, "--stats", stats], path)
        if rc == 0:
            st = _stats(stats)
            assert len(_json_lines(out)) == st["estimates"] <= st["sets"]
            mine = st["inputs"][path]
            assert mine["bad_lines"] >= 0 and mine["time_jumps"] >= 0
            # Sources beyond the decoder table, counted by the gateway: a new source's chunk is dropped or makes room.
            assert st["sources_dropped"] + st["sources_evicted"] <= st["chunks"]  # a chunk is dropped or makes room
    finally:
        for f in (path, out, stats):
            if os.path.exists(f):
                os.unlink(f)


def auth_py(data: bytes) -> None:
    """Our authenticated beacon's Python parsers and verifiers (SPEC 9): the payload finders
    on any AdvData, PDU or 802.15.4 frame; the reference Verifier and the gateway's
    AuthGuard on every payload found and on AUTH_REPORTs whose fields come from the input.
    Never raises; a verifier accepts only the key's tag for the decrypted seq; a guard
    accepts an AUTH_REPORT only with the key's tag, and counts every report exactly once."""
    from pfdoa.gateway.auth import AuthCounters, AuthGuard
    from pfdoa.protocol import auth
    from pfdoa.protocol.filters import auth_payload_802154, auth_payload_ble_adv, auth_payload_ble_pdu
    from pfdoa.protocol.messages import AuthReport

    if len(data) < 17:
        return
    key, which, rest = data[:16], data[16] % 3, data[17:]
    ver = auth.Verifier(key)
    counters = AuthCounters()
    guard = AuthGuard(key, counters)
    t = 0.0
    done = 0
    for piece in rest.split(b"\xfe")[:64]:
        if which == 0:
            p = auth_payload_ble_adv(piece)
        elif which == 1:
            found = auth_payload_ble_pdu(piece)
            p = None if found is None else found[1]
        else:
            p = auth_payload_802154(piece)
        if p is not None:
            assert len(p) == defs.AUTH_PAYLOAD_LEN and p[:2] == b"PA" and p in piece
            f = auth.parse_payload(p)
            assert f is not None
            v = ver.verify(f, int(t * 1000))
            assert v.result in auth.RESULT_NAMES
            if v.result == defs.AUTH_ACCEPT:
                assert auth.tag(key, v.counter, v.seq) == f.tag
        if len(piece) >= 16:
            counter = int.from_bytes(piece[:4], "little")
            seq = int.from_bytes(piece[4:6], "little")
            tag = piece[6:14] if piece[14] & 1 else auth.tag(key, counter, seq)
            rep = AuthReport(seq, int.from_bytes(piece[8:12], "little"), 0, 0, 1, 37, 0, 0, counter, tag)
            before = (counters.accepted, counters.bad_tag, counters.stale, counters.replayed)
            ok = guard.accept(piece[15] % 4, rep, t)
            after = (counters.accepted, counters.bad_tag, counters.stale, counters.replayed)
            assert sum(after) - sum(before) in (0, 1)  # once, or a link duplicate (0)
            assert not ok or tag == auth.tag(key, counter, seq)
            done += 1
        t += (piece[0] if piece else 1) / 10.0


TARGETS = {"auth_py": auth_py, "stream": stream, "can": can, "reassembler": reassembler, "trace": trace, "site": site,
           "espresense": espresense, "recording": recording,
           "capture": capture, "cli_site": cli_site, "cli_trace": cli_trace, "cli_odometry": cli_odometry,
           "cli_capture": cli_capture}
