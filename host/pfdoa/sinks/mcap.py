"""ROS 2 recordings: MCAP files with CDR-encoded ROS 2 messages (``--record run.mcap``).

Needs the optional extra ``ros`` (PyPI ``mcap`` and ``mcap-ros2-support``); ROS itself is
not needed to write or read them, and ``ros2 bag play run.mcap`` / Foxglove play them.

Topics (message definitions in :mod:`pfdoa.sinks.ros`, embedded in the file):

=====================  ==============================================  =====================
topic                  type                                            when
=====================  ==============================================  =====================
``/pfdoa/pose``        ``geometry_msgs/msg/PoseWithCovarianceStamped``  every output record
``/pfdoa/readings``    ``pfdoa_msgs/msg/AnchorReading``                 every RSSI reading (with
                                                                        the beacon id it names)
``/pfdoa/odometry``    ``pfdoa_msgs/msg/OdometryIncrement``             every odometry increment
``/pfdoa/odom``        ``nav_msgs/msg/Odometry``                        every odometry increment,
                                                                        composed (``odom`` ->
                                                                        ``base_link``)
``/tf_static``         ``tf2_msgs/msg/TFMessage``                       first message, when the
                                                                        site places its frame
                                                                        in the map
                                                                        (:mod:`pfdoa.frames`)
``/pfdoa/timer``       ``pfdoa_msgs/msg/TimerMark``                     every time the timers ran
``/diagnostics``       ``diagnostic_msgs/msg/DiagnosticArray``          every health period
``/pfdoa/anchors``     ``visualization_msgs/msg/MarkerArray``           first message, then
                                                                        when a level changes
=====================  ==============================================  =====================

Log times are the messages' own times (the gateway's clock) in nanoseconds; an odometry
increment is logged at its arrival. A metadata record ``pfdoa`` holds the pfdoa version,
the frame id, the site file's text (``site_toml``) and what the caller adds (the command
adds ``method``, ``seed``, ``mode``, ``window_s``, ``odometry``).

The readings, odometry increments and timer marks are written in the order the pipeline
processed them, and that order is the file's: :meth:`Recording.events` gives them back as
they came, so ``pfdoa replay run.mcap`` runs the reassembly, the timers and the estimator
(same seed) exactly as the gateway did, and gets its estimates. A reading that names its
beacon (``beacon`` not empty: an ESPresense device) comes back as a
:class:`~pfdoa.gateway.beacons.BeaconReading`, for that beacon's own estimator.

**Nothing lost to a kill or a power cut.** The header and the metadata are on disk
(flushed and ``fsync``-ed) before the first message; then the messages go into chunks,
each closed, written, flushed and ``fsync``-ed once it holds :data:`CHUNK_MESSAGES`
messages or :data:`FLUSH_S` seconds have passed since the last one (this host's monotonic
clock). A chunk is closed only just before an input is recorded (a reading, an odometry
increment, a timer mark) or a health period: every estimate those inputs led to is then
in the chunk with them. So a gateway killed at any moment (SIGKILL, a power cut) leaves a
file whose complete chunks hold every estimate made up to the last of them, and the
inputs that made exactly those; the open chunk, at most FLUSH_S of the run, is what is
lost. When the inputs end (:meth:`McapSink.inputs_ended`, before the gateway estimates the
sets still open) a metadata record ``pfdoa_end`` follows the last input's chunk. A file
cut anywhere (no MCAP magic at its end) is read up to its last complete record; without
``pfdoa_end`` in it the run was cut short (:attr:`Recording.cut`), and ``pfdoa replay``
warns and estimates from that prefix exactly what the gateway had (it does not estimate
the sets still open at the cut, as the gateway had not).
"""

from __future__ import annotations

import errno
import io
import json
import math
import os
import struct
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Callable, Iterator, Mapping, TypeVar

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from pfdoa.errors import InputError
from pfdoa.frames import site_transform
from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconReading
from pfdoa.gateway.health import OK, HealthSnapshot
from pfdoa.gateway.transports import OdomLine, TimeMark
from pfdoa.readings.reassembly import Reading
from pfdoa.sinks import ros
from pfdoa.sinks.base import Sink
from pfdoa.trace import RSSI_MAX_DBM, RSSI_MIN_DBM

POSE_TOPIC = "/pfdoa/pose"
READINGS_TOPIC = "/pfdoa/readings"
ODOMETRY_TOPIC = "/pfdoa/odometry"
NAV_ODOMETRY_TOPIC = "/pfdoa/odom"
TF_STATIC_TOPIC = "/tf_static"
TIMER_TOPIC = "/pfdoa/timer"
DIAGNOSTICS_TOPIC = "/diagnostics"
ANCHORS_TOPIC = "/pfdoa/anchors"
METADATA_NAME = "pfdoa"
# A second metadata record, written when the gateway's inputs ended (before it estimated the
# sets still open): a recording that holds it ran to its end even if its last bytes are missing.
END_METADATA_NAME = "pfdoa_end"

METADATA_CRC = "crc32"  # of the other metadata entries: MCAP's own CRCs cover chunks, not metadata

# When a chunk is closed and made durable (see the module doc): at most this many messages
# (~100 s of a 10 Hz beacon's readings and poses; a few hundred kilobytes) or this much time.
CHUNK_MESSAGES = 2000
FLUSH_S = 1.0
# The mcap writer's own size limit, a backstop far above what CHUNK_MESSAGES gives: it closes
# a chunk wherever it is reached, which our readers then read as well but a cut there could
# hold an input without the estimate it led to.
WRITER_CHUNK_BYTES = 16 << 20
MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_OPCODES = frozenset(int(o) for o in Opcode)

T = TypeVar("T")


def _metadata_crc(meta: Mapping[str, str]) -> str:
    text = json.dumps(sorted((k, v) for k, v in meta.items() if k != METADATA_CRC))  # ASCII, unambiguous
    return f"{zlib.crc32(text.encode('ascii')):08x}"


class DamagedRecording(ValueError):
    """A record whose values no gateway writes (a damaged or forged file)."""


# A chunk's records, decompressed: McapSink's chunks hold ~1 MiB (the writer's chunk size); a
# chunk that says it holds more than this is refused before anything is decompressed, so a
# few kilobytes of a forged or damaged file cannot make the reader allocate gigabytes (a
# zstd frame of zeros grows ~30,000-fold).
MAX_CHUNK_BYTES = 64 << 20


@dataclass(frozen=True)
class Extent:
    """How much of a recording can be read: ``size`` bytes in the file, the first
    ``complete`` of them whole records. ``truncated``: the file does not end as a finished
    one does (with the MCAP magic)."""

    size: int
    complete: int
    truncated: bool


def _extent(fh: IO[bytes]) -> Extent:
    """Where a recording's whole records end. A finished file: all of it. A truncated one:
    the top level records are walked by their lengths (nothing else is read) up to the
    last that ends within the file."""
    size = os.fstat(fh.fileno()).st_size
    if not MAGIC.startswith(fh.read(len(MAGIC))[:len(MAGIC)]):  # not an MCAP file at all: the reader says so
        fh.seek(0)
        return Extent(size, size, False)
    fh.seek(max(0, size - len(MAGIC)))
    truncated = size < 2 * len(MAGIC) or fh.read(len(MAGIC)) != MAGIC
    pos = size
    if truncated:
        pos = len(MAGIC) if size >= len(MAGIC) else 0
        while pos + _RECORD_HEAD.size <= size:
            fh.seek(pos)
            opcode, length = _RECORD_HEAD.unpack(fh.read(_RECORD_HEAD.size))
            if opcode not in _OPCODES or (pos == len(MAGIC) and opcode != Opcode.HEADER):
                fh.seek(0)  # not what a writer writes: damaged, not cut (the reader says so)
                return Extent(size, size, False)
            end = pos + _RECORD_HEAD.size + length
            if end > size:
                break
            pos = end
    fh.seek(0)
    return Extent(size, pos, truncated)


class _Prefix(io.RawIOBase):
    """The first ``n`` bytes of a file (a cut recording's whole records)."""

    def __init__(self, fh: IO[bytes], n: int) -> None:
        self._fh, self._left = fh, n

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:  # what BufferedReader (around a raw stream) calls
        data = self._fh.read(min(len(buf), self._left))
        buf[:len(data)] = data
        self._left -= len(data)
        return len(data)


def _records(fh: IO[bytes], *, chunks: bool = True) -> Iterator[McapRecord]:
    """The file's records in order, each chunk's records in its place (``chunks=False``:
    the chunks left closed). Read front to back, as written: the summary section, which
    could point anywhere, is not used. No record longer than the file is read (the mcap
    reader's default limit, 4 GiB, would let one damaged length field allocate that much),
    and no chunk is decompressed beyond the size it declares (:func:`_chunk_records`). A
    cut file (:func:`_extent`) is read up to its last whole record: what the writer had
    made durable."""
    ext = _extent(fh)
    src: IO[bytes] = _Prefix(fh, ext.complete) if ext.truncated else fh  # type: ignore[assignment]
    reader = StreamReader(src, emit_chunks=True, validate_crcs=True, record_size_limit=max(ext.size, 1))
    it = iter(reader.records)
    while True:
        try:
            rec = next(it)
        except StopIteration:
            return
        except EndOfFile:
            if ext.truncated:  # the end of the whole records: the rest was never written
                return
            raise
        if isinstance(rec, Chunk):
            if chunks:
                yield from _chunk_records(rec)
        else:
            yield rec


def _chunk_records(chunk: Chunk) -> Iterator[McapRecord]:
    """A chunk's records, decompressed into at most its declared size, which must be at most
    MAX_CHUNK_BYTES and exact, and checked against its CRC."""
    want = chunk.uncompressed_size
    if want > MAX_CHUNK_BYTES:
        raise DamagedRecording(f"a chunk declares {want} bytes (at most {MAX_CHUNK_BYTES} are read)")
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.ZstdDecompressor().stream_reader(chunk.data).read(want + 1)
    elif chunk.compression == "lz4":
        import lz4.frame  # type: ignore[import-untyped]  # lz4 ships no type information

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=want + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise DamagedRecording(f"unknown chunk compression {chunk.compression[:40]!r}")
    if len(data) > want:
        raise DamagedRecording(f"a chunk decompresses to more than the {want} bytes it declares")
    if len(data) < want:
        raise DamagedRecording(f"a chunk decompresses to {len(data)} bytes, not the {want} it declares")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise DamagedRecording("a chunk does not match its CRC")
    stream = ReadDataStream(io.BytesIO(data))
    while stream.count < want:
        opcode, length = stream.read1(), stream.read8()
        start = stream.count
        if length > want - start:
            raise DamagedRecording("a record runs past the end of its chunk")
        if opcode == Opcode.SCHEMA:
            yield Schema.read(stream)
        elif opcode == Opcode.CHANNEL:
            yield Channel.read(stream)
        elif opcode == Opcode.MESSAGE:
            yield Message.read(stream, length)
        rest = length - (stream.count - start)  # a record's own padding, or one of another kind
        if rest < 0:
            raise DamagedRecording("a record is longer than its length says")
        stream.read(rest)


def _decoded(fh: IO[bytes], topics: Mapping[str, Any]) -> Iterator[tuple[str, Any]]:
    """(topic, decoded ROS 2 message) of every message on ``topics``, in file order."""
    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}  # ids are u16: each table holds at most 65,536 entries
    channels: dict[int, Channel] = {}
    decoders: dict[int, Callable[[bytes], Any]] = {}
    for rec in _records(fh):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message):
            channel = channels.get(rec.channel_id)
            if channel is None:
                raise DamagedRecording(f"a message on channel {rec.channel_id}, which no record declares")
            if channel.topic not in topics:
                continue
            decode = decoders.get(rec.channel_id)
            if decode is None:
                decode = factory.decoder_for(channel.message_encoding, schemas.get(channel.schema_id))
                if decode is None:
                    raise DamagedRecording(f"no ROS 2 schema for the messages on {channel.topic}")
                decoders[rec.channel_id] = decode
            yield channel.topic, decode(rec.data)


def _unreadable(path: str, exc: BaseException) -> InputError:
    # The mcap reader and the ROS 2 decoders (which parse the message definitions the file
    # itself carries) raise many exception types on damaged input, none of them ours: at
    # this boundary each one means "not a readable recording", said in one line.
    why = (str(exc).strip().splitlines() or [""])[0][:200]
    return InputError(f"{path}: not a readable MCAP recording: {type(exc).__name__}{': ' + why if why else ''}")


class McapSink(Sink):
    """Writes a run to an MCAP file (see the module doc). ``site_toml``: the site file's
    text, kept in the metadata; ``metadata``: more string key/values for it."""

    name = "mcap"

    def __init__(self, path: str | Path, site, frame_id: str = ros.DEFAULT_FRAME, site_toml: str | None = None,
                 metadata: Mapping[str, str] | None = None, existing: str = "replace",
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        """``monotonic``: the clock of FLUSH_S (injected in tests)."""
        from pfdoa import __version__
        from pfdoa.outfiles import open_stream

        self.path = str(path)
        self.site = site
        self.frame_id = frame_id
        self.monotonic = monotonic
        # pfdoa.outfiles: a device or FIFO written through; "keep": an earlier recording moved aside
        self._fh = open_stream(self.path, "--record", existing=existing, binary=True)[0]
        self._w = Ros2Writer(self._fh, chunk_size=WRITER_CHUNK_BYTES)
        self._schemas = {name: self._w.register_msgdef(name, text) for name, text in ros.MSGDEFS.items()}
        meta = {"version": __version__, "frame_id": frame_id, "site_toml": site_toml or ""}
        meta.update({str(k): str(v) for k, v in (metadata or {}).items()})
        meta[METADATA_CRC] = _metadata_crc(meta)
        self._w.add_metadata(METADATA_NAME, meta)
        # A gateway killed before its first chunk leaves a recording that says what it was. An
        # output that fails already (a full disk) fails at the first message, as it would
        # have without this: the fan-out then says so, drops it and the run goes on.
        self._error: OSError | None = None
        try:
            self._durable()
        except OSError as exc:
            self._error = exc
        self._levels: dict[int, str] | None = None  # as last published on /pfdoa/anchors
        self._odom = ros.OdometryPose()
        self.counts = {topic: 0 for topic in (POSE_TOPIC, READINGS_TOPIC, ODOMETRY_TOPIC, NAV_ODOMETRY_TOPIC,
                                              TIMER_TOPIC, DIAGNOSTICS_TOPIC, ANCHORS_TOPIC, TF_STATIC_TOPIC)}
        self.chunks = 0  # chunks closed and made durable
        self._in_chunk = 0  # messages in the open chunk
        self._flushed_at = monotonic()

    def _put(self, topic: str, type_name: str, msg: dict, t: float) -> None:
        if self._error is not None:
            raise self._error
        self._w.write_message(topic, self._schemas[type_name], msg, log_time=ros.time_ns(t))
        self.counts[topic] += 1
        self._in_chunk += 1

    def _boundary(self) -> None:
        """Before an input or a health period is recorded (see the module doc): close the
        open chunk and make it durable when it is full or FLUSH_S old."""
        if not self._in_chunk:
            return
        now = self.monotonic()
        if self._in_chunk >= CHUNK_MESSAGES or now - self._flushed_at >= FLUSH_S:
            # mcap >= 1.6's Writer.flush closes the open chunk and flushes the stream;
            # mcap-ros2-support's writer keeps that writer as `_writer` (no flush of its own).
            self._w._writer.flush()
            self._durable()
            self.chunks += 1
            self._in_chunk = 0
            self._flushed_at = now

    def _durable(self) -> None:
        self._fh.flush()
        try:
            os.fsync(self._fh.fileno())
        except OSError as exc:  # a FIFO or a device written through: nothing to make durable there
            if exc.errno not in (errno.EINVAL, errno.EROFS, errno.ENOTSUP):
                raise

    def _anchors(self, t: float, levels: dict[int, str]) -> None:
        if levels != self._levels:
            self._levels = dict(levels)
            self._put(ANCHORS_TOPIC, ros.MARKERS_TYPE, ros.anchors_message(self.site, t, levels, self.frame_id), t)

    def _first(self, t: float) -> None:
        if self._levels is None:
            self._anchors(t, {a.id: OK for a in self.site.anchors})
            tf = site_transform(self.site, self.frame_id, ros.stamp(t)) if hasattr(self.site, "sections") else None
            if tf is not None:
                self._put(TF_STATIC_TOPIC, ros.TF_TYPE, ros.tf_message([tf]), t)

    def reading(self, r: Reading, beacon: str | None = None) -> None:
        self._boundary()
        self._first(r.t)
        self._put(READINGS_TOPIC, ros.READING_TYPE, ros.reading_message(r, self.frame_id, beacon), r.t)

    def odometry(self, inc: OdomLine) -> None:
        self._boundary()
        self._first(inc.t)
        self._put(ODOMETRY_TOPIC, ros.ODOMETRY_TYPE, ros.odometry_message(inc, self.frame_id), inc.t)
        self._put(NAV_ODOMETRY_TOPIC, ros.NAV_ODOMETRY_TYPE, self._odom.message(inc), inc.t)

    def timer(self, t: float) -> None:
        self._boundary()
        self._first(t)
        self._put(TIMER_TOPIC, ros.TIMER_TYPE, ros.timer_message(t, self.frame_id), t)

    def write(self, record) -> None:
        self._first(record.t)
        self._put(POSE_TOPIC, ros.POSE_TYPE, ros.pose_message(record, self.frame_id), record.t)

    def health(self, snapshot: HealthSnapshot) -> None:
        self._boundary()
        self._first(snapshot.t)
        self._put(DIAGNOSTICS_TOPIC, ros.DIAGNOSTICS_TYPE, ros.diagnostics_message(snapshot, self.frame_id),
                  snapshot.t)
        self._anchors(snapshot.t, {a: h.level for a, h in snapshot.anchors.items()})

    def inputs_ended(self) -> None:
        """The run's inputs ended: what was recorded is made durable and marked so (the
        estimates of the sets still open come next, in a chunk of their own)."""
        if self._in_chunk:
            self._w._writer.flush()
            self.chunks += 1
            self._in_chunk = 0
        self._w.add_metadata(END_METADATA_NAME, {"inputs": "ended"})
        self._durable()

    def _close(self) -> None:
        try:
            self._w.finish()
            self._durable()
        finally:
            self._fh.close()


@dataclass(frozen=True)
class RecordedPose:
    """A pose read back: time, position, 2 x 2 covariance ``(xx, xy, yy)``, yaw (None if unknown)."""

    t: float
    x: float
    y: float
    cov: tuple[float, float, float]
    yaw: float | None
    yaw_var: float | None
    frame_id: str


@dataclass
class Recording:
    """An MCAP recording opened for reading (see :func:`open_recording`); ``extent``: how
    much of the file is whole records; ``cut``: the run it recorded never reached the end
    of its inputs in the file (the gateway was killed, or the power cut, while recording)."""

    path: str
    metadata: dict[str, str] = field(default_factory=dict)
    extent: Extent | None = None
    cut: bool = False

    def _messages(self, convert: Mapping[str, Callable[[Any], T]]) -> Iterator[T]:
        """The messages on ``convert``'s topics in file order, each through its topic's
        converter; a damaged file or value is an InputError (one line)."""
        try:
            fh = open(self.path, "rb")
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        try:
            with fh:
                for topic, decoded in _decoded(fh, convert):
                    yield convert[topic](decoded)
        except Exception as exc:  # see _unreadable
            raise _unreadable(self.path, exc) from None

    def readings(self) -> Iterator[Reading | BeaconReading]:
        """The readings in the order the gateway handed them to its reassembler (a named
        beacon's as a BeaconReading)."""
        return self._messages({READINGS_TOPIC: _reading})

    def odometry(self) -> Iterator[OdomLine]:
        """The odometry increments in the order the gateway received them."""
        return self._messages({ODOMETRY_TOPIC: _odometry})

    def events(self) -> Iterator[Reading | BeaconReading | OdomLine | TimeMark]:
        """Readings, odometry increments and timer marks, in the order the pipeline had them."""
        convert: dict[str, Callable[[Any], Reading | BeaconReading | OdomLine | TimeMark]] = {
            READINGS_TOPIC: _reading, ODOMETRY_TOPIC: _odometry, TIMER_TOPIC: _timer}
        return self._messages(convert)

    def poses(self) -> Iterator[RecordedPose]:
        return self._messages({POSE_TOPIC: _pose})

    def anchors(self) -> list[tuple[int, float, float]]:
        """(id, x, y) of the site's anchors, from the first anchor markers."""
        for markers in self._messages({ANCHORS_TOPIC: _anchor_markers}):
            return markers
        return []

    @property
    def site_toml(self) -> str:
        return self.metadata.get("site_toml", "")


# What the gateway can have written: a recording with other values is damaged or forged,
# and one infinite time would stall every replay timer (as a capture line once did).
def _finite(v: Any, what: str) -> float:
    f = float(v)
    if not math.isfinite(f):
        raise DamagedRecording(f"{what} {f} is not finite")
    return f


def _reading(m) -> Reading | BeaconReading:
    rssi = float(m.rssi_dbm)
    if not RSSI_MIN_DBM <= rssi <= RSSI_MAX_DBM:
        raise DamagedRecording(f"reading rssi_dbm {rssi} is outside [{RSSI_MIN_DBM:g}, {RSSI_MAX_DBM:g}]")
    r = Reading(int(m.anchor_id), rssi, _finite(m.t, "reading t"), int(m.seq) if m.has_seq else None,
                int(m.tick_ms) if m.has_tick else None, int(m.flags),
                event_t=_finite(m.event_t, "reading event_t") if m.has_event_t else None)
    beacon = getattr(m, "beacon", "")  # absent in recordings made before the field existed
    if not isinstance(beacon, str) or len(beacon) > MAX_ID_LEN:
        raise DamagedRecording(f"reading beacon id is not a string of at most {MAX_ID_LEN} characters")
    return BeaconReading(beacon, r) if beacon else r


def _odometry(m) -> OdomLine:
    return OdomLine(_finite(m.arrival, "odometry arrival"), _finite(m.t, "odometry t"), _finite(m.dx, "odometry dx"),
                    _finite(m.dy, "odometry dy"), _finite(m.dtheta, "odometry dtheta"))


def _timer(m) -> TimeMark:
    return TimeMark(_finite(m.t, "timer t"))


def _pose(m) -> RecordedPose:
    c = m.pose.covariance
    q = m.pose.pose.orientation
    yaw_known = c[35] < ros.UNKNOWN_VARIANCE
    return RecordedPose(
        t=ros.stamp_seconds(m.header.stamp.sec, m.header.stamp.nanosec),
        x=m.pose.pose.position.x, y=m.pose.pose.position.y, cov=(c[0], c[1], c[7]),
        yaw=2.0 * math.atan2(q.z, q.w) if yaw_known else None, yaw_var=c[35] if yaw_known else None,
        frame_id=m.header.frame_id,
    )


def _anchor_markers(m) -> list[tuple[int, float, float]]:
    return [(mk.id, mk.pose.position.x, mk.pose.position.y) for mk in m.markers if mk.ns == ros.ANCHOR_NS]


def open_recording(path: str | Path) -> Recording:
    """Open an MCAP recording written by :class:`McapSink`; an unreadable one is an InputError."""
    p = str(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from None
    try:
        with fh:
            extent = _extent(fh)
            meta = {}
            ended = not extent.truncated
            for m in _records(fh, chunks=False):
                if isinstance(m, Metadata) and m.name == METADATA_NAME:
                    meta = dict(m.metadata)
                ended |= isinstance(m, DataEnd) or (isinstance(m, Metadata) and m.name == END_METADATA_NAME)
    except Exception as exc:  # see _unreadable (also OSError from the file itself)
        raise _unreadable(p, exc) from None
    if not meta:
        if extent.truncated:
            raise InputError(f"{p}: cut after {extent.size} bytes, before its '{METADATA_NAME}' metadata: "
                             "nothing was recorded")
        raise InputError(f"{p}: no '{METADATA_NAME}' metadata: not a pfdoa recording")
    # Recordings written before the checksum existed have none and are read as they are.
    if METADATA_CRC in meta and meta[METADATA_CRC] != _metadata_crc(meta):
        raise InputError(f"{p}: not a readable MCAP recording: its '{METADATA_NAME}' metadata (site file, "
                         "options) does not match its checksum: the file is damaged")
    return Recording(p, meta, extent, cut=not ended)
