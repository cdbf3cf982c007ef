"""ROS 2 recordings: MCAP files with CDR-encoded ROS 2 messages (``--record run.mcap``).

Needs the optional extra ``ros`` (PyPI ``mcap`` and ``mcap-ros2-support``); ROS itself is
not needed to write or read them, and ``ros2 bag play run.mcap`` / Foxglove play them.

Topics (message definitions in :mod:`pfdoa.sinks.ros`, embedded in the file):

=====================  ==============================================  =====================
topic                  type                                            when
=====================  ==============================================  =====================
``/pfdoa/pose``        ``geometry_msgs/msg/PoseWithCovarianceStamped``  every output record
``/pfdoa/readings``    ``pfdoa_msgs/msg/AnchorReading``                 every RSSI reading
``/diagnostics``       ``diagnostic_msgs/msg/DiagnosticArray``          every health period
``/pfdoa/anchors``     ``visualization_msgs/msg/MarkerArray``           first message, then
                                                                        when a level changes
=====================  ==============================================  =====================

Log times are the messages' own times (the gateway's clock) in nanoseconds. A metadata
record ``pfdoa`` holds the pfdoa version, the frame id, the site file's text (``site_toml``)
and what the caller adds (method, seed, ...).

:func:`open_recording` reads a recording back: its metadata, its anchors, its poses, and
the readings in the order the gateway received them (file order), as
:class:`~pfdoa.gateway.reassembly.Reading` objects for ``pfdoa replay run.mcap``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from pfdoa.errors import InputError
from pfdoa.gateway.reassembly import Reading
from pfdoa.sinks import ros
from pfdoa.gateway.health import OK, HealthSnapshot
from pfdoa.sinks.base import Sink

POSE_TOPIC = "/pfdoa/pose"
READINGS_TOPIC = "/pfdoa/readings"
DIAGNOSTICS_TOPIC = "/diagnostics"
ANCHORS_TOPIC = "/pfdoa/anchors"
METADATA_NAME = "pfdoa"


class McapSink(Sink):
    """Writes a run to an MCAP file (see the module doc). ``site_toml``: the site file's
    text, kept in the metadata; ``metadata``: more string key/values for it."""

    name = "mcap"

    def __init__(self, path: str | Path, site, frame_id: str = ros.DEFAULT_FRAME, site_toml: str | None = None,
                 metadata: Mapping[str, str] | None = None) -> None:
        from pfdoa import __version__

        self.path = str(path)
        self.site = site
        self.frame_id = frame_id
        try:
            self._fh = open(self.path, "wb")
        except OSError as exc:
            raise InputError(f"--record {self.path}: cannot write: {exc.strerror or exc}") from None
        self._w = Ros2Writer(self._fh)
        self._schemas = {name: self._w.register_msgdef(name, text) for name, text in ros.MSGDEFS.items()}
        meta = {"version": __version__, "frame_id": frame_id, "site_toml": site_toml or ""}
        meta.update({str(k): str(v) for k, v in (metadata or {}).items()})
        self._w.add_metadata(METADATA_NAME, meta)
        self._levels: dict[int, str] | None = None  # as last published on /pfdoa/anchors
        self.counts = {POSE_TOPIC: 0, READINGS_TOPIC: 0, DIAGNOSTICS_TOPIC: 0, ANCHORS_TOPIC: 0}

    def _put(self, topic: str, type_name: str, msg: dict, t: float) -> None:
        self._w.write_message(topic, self._schemas[type_name], msg, log_time=ros.time_ns(t))
        self.counts[topic] += 1

    def _anchors(self, t: float, levels: dict[int, str]) -> None:
        if levels != self._levels:
            self._levels = dict(levels)
            self._put(ANCHORS_TOPIC, ros.MARKERS_TYPE, ros.anchors_message(self.site, t, levels, self.frame_id), t)

    def _first(self, t: float) -> None:
        if self._levels is None:
            self._anchors(t, {a.id: OK for a in self.site.anchors})

    def reading(self, r: Reading) -> None:
        self._first(r.t)
        self._put(READINGS_TOPIC, ros.READING_TYPE, ros.reading_message(r, self.frame_id), r.t)

    def write(self, record) -> None:
        self._first(record.t)
        self._put(POSE_TOPIC, ros.POSE_TYPE, ros.pose_message(record, self.frame_id), record.t)

    def health(self, snapshot: HealthSnapshot) -> None:
        self._first(snapshot.t)
        self._put(DIAGNOSTICS_TOPIC, ros.DIAGNOSTICS_TYPE, ros.diagnostics_message(snapshot, self.frame_id),
                  snapshot.t)
        self._anchors(snapshot.t, {a: h.level for a, h in snapshot.anchors.items()})

    def _close(self) -> None:
        try:
            self._w.finish()
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
    """An MCAP recording opened for reading (see :func:`open_recording`)."""

    path: str
    metadata: dict[str, str] = field(default_factory=dict)

    def _messages(self, topic: str) -> Iterator[Any]:
        try:
            with open(self.path, "rb") as fh:
                reader = make_reader(fh, decoder_factories=[DecoderFactory()])
                for _schema, _channel, _message, decoded in reader.iter_decoded_messages(
                        topics=[topic], log_time_order=False):
                    yield decoded
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        except (McapError, ValueError, KeyError, EOFError, UnicodeDecodeError) as exc:
            raise InputError(f"{self.path}: not a readable MCAP recording: {exc}") from None

    def readings(self) -> Iterator[Reading]:
        """The readings in the order the gateway received them."""
        for m in self._messages(READINGS_TOPIC):
            yield Reading(int(m.anchor_id), float(m.rssi_dbm), float(m.t), int(m.seq) if m.has_seq else None,
                          int(m.tick_ms) if m.has_tick else None, int(m.flags))

    def poses(self) -> Iterator[RecordedPose]:
        for m in self._messages(POSE_TOPIC):
            c = m.pose.covariance
            q = m.pose.pose.orientation
            yaw_known = c[35] < ros.UNKNOWN_VARIANCE
            yield RecordedPose(
                t=m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
                x=m.pose.pose.position.x, y=m.pose.pose.position.y, cov=(c[0], c[1], c[7]),
                yaw=2.0 * math.atan2(q.z, q.w) if yaw_known else None, yaw_var=c[35] if yaw_known else None,
                frame_id=m.header.frame_id,
            )

    def anchors(self) -> list[tuple[int, float, float]]:
        """(id, x, y) of the site's anchors, from the first anchor markers."""
        for m in self._messages(ANCHORS_TOPIC):
            return [(mk.id, mk.pose.position.x, mk.pose.position.y) for mk in m.markers if mk.ns == ros.ANCHOR_NS]
        return []

    @property
    def site_toml(self) -> str:
        return self.metadata.get("site_toml", "")


def open_recording(path: str | Path) -> Recording:
    """Open an MCAP recording written by :class:`McapSink`; an unreadable one is an InputError."""
    p = str(path)
    try:
        with open(p, "rb") as fh:
            reader = make_reader(fh)
            meta = {}
            for m in reader.iter_metadata():
                if m.name == METADATA_NAME:
                    meta = dict(m.metadata)
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except (McapError, ValueError, KeyError, EOFError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a readable MCAP recording: {exc}") from None
    if not meta:
        raise InputError(f"{p}: no '{METADATA_NAME}' metadata: not a pfdoa recording")
    return Recording(p, meta)
