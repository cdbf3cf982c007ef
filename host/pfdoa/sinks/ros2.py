"""Live on the robot's ROS 2 graph over DDS (``pfdoa gateway --ros2``).

Needs the optional extra ``ros2`` (PyPI ``cyclonedds``; no ROS installation). One DDS
participant (:mod:`pfdoa.ros2.dds`) on the ``[ros2]`` table's domain publishes, with ROS 2's
topic and type names, the messages of :mod:`pfdoa.sinks.ros` (the conventions of the MCAP
recording):

* ``pfdoa/pose`` (DDS topic ``rt/pfdoa/pose``): ``geometry_msgs/msg/PoseWithCovarianceStamped``,
  one per estimate; reliable (``pose_reliability``), keep-last ``pose_depth`` (10), volatile:
  ROS 2's default, which reliable and best-effort subscribers (robot_localization's) match;
* ``/diagnostics``: ``diagnostic_msgs/msg/DiagnosticArray``, one per health period; reliable,
  keep-last 1, volatile (as ROS 2's diagnostic_updater);
* ``/tf_static``: ``tf2_msgs/msg/TFMessage``, ``map`` -> the site frame (``--frame-id``),
  once, when the site places its frame in the map (``[site] map_pose``:
  :func:`pfdoa.frames.site_transform`, as the recording has it); reliable, keep-last 1,
  transient-local (as tf2's static broadcaster).

With several beacons each has its own pose topic ``pfdoa/<beacon>/pose`` (a beacon id that
is no ROS name token gets a safe one, :func:`pfdoa.ros2.config.name_token`); the topic of a
beacon the gateway lets go is deleted with it. The odometry subscription
(:mod:`pfdoa.sinks.ros2odom`) shares the participant and registers in :attr:`Ros2Sink.inputs`.

Nothing here waits on a subscriber: a DDS write with keep-last history replaces what a slow
reader has not taken yet and never blocks the pipeline for long (at most
:data:`~pfdoa.ros2.dds.WRITE_BLOCK_S`, then the sample is dropped and counted). Counters in
every health snapshot (``outputs.ros2``): poses ``published`` and ``dropped``,
subscriptions ``matched`` on the pose topics, ``diagnostics`` published, and the odometry
input's. On close the sink waits up to :data:`ACK_WAIT_S` for matched reliable
subscribers to acknowledge what was written, then leaves the graph.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Callable

from pfdoa.frames import site_transform
from pfdoa.gateway.health import HealthSnapshot
from pfdoa.ros2 import dds
from pfdoa.ros2.config import Ros2Settings
from pfdoa.sinks import ros
from pfdoa.sinks.base import Sink

log = logging.getLogger(__name__)

DIAGNOSTICS_TOPIC = "/diagnostics"
TF_STATIC_TOPIC = "/tf_static"
MAX_POSE_TOPICS = 256  # beacons with a topic at once (named beacons come and go; their topics with them)
ACK_WAIT_S = 5.0  # at close, for reliable subscribers to acknowledge the last samples


class Ros2Sink(Sink):
    name = "ros2"

    def __init__(self, settings: Ros2Settings, site=None, frame_id: str = ros.DEFAULT_FRAME, per_beacon: bool = False,
                 default_beacon: str = "b0", clock: Callable[[], float] = time.time) -> None:
        self.settings = settings
        self.frame_id = frame_id
        self.per_beacon = per_beacon
        self.default_beacon = default_beacon
        self.types = dds.Types(ros.LIVE_MSGDEFS)
        self.node = dds.Node(settings.domain_id, self.types)
        self.inputs: list = []  # pfdoa.sinks.ros2odom sources on this participant (their counters)
        self.published = 0
        self.dropped = 0
        self.diagnostics = 0
        self._warned = False
        self._final: dict[str, Any] | None = None  # the counters when closed
        try:
            self._pose_qos = self.node.qos(ros.POSE_TYPE, reliable=settings.pose_reliable, depth=settings.pose_depth)
            self._poses: dict[str | None, Any] = {}  # beacon (None: the one topic) -> writer
            if not per_beacon:  # there before the first estimate, so subscribers match early
                self._pose_writer(None)
            self._diag = self.node.writer(DIAGNOSTICS_TOPIC, ros.DIAGNOSTICS_TYPE,
                                          self.node.qos(ros.DIAGNOSTICS_TYPE, reliable=True, depth=1))
            self._tf = None
            transform = site_transform(site, frame_id, ros.stamp(clock())) if site is not None else None
            if transform is not None:
                self._tf = self.node.writer(TF_STATIC_TOPIC, ros.TF_TYPE,
                                            self.node.qos(ros.TF_TYPE, reliable=True, depth=1, transient_local=True))
                self._write(self._tf, ros.TF_TYPE, ros.tf_message([transform]))
        except BaseException:
            self.node.close()
            raise

    def topic_of(self, beacon: str | None) -> str:
        return self.settings.pose_topic(beacon)

    def _pose_writer(self, beacon: str | None):
        w = self._poses.get(beacon)
        if w is None and len(self._poses) < MAX_POSE_TOPICS:
            w = self._poses[beacon] = self.node.writer(self.topic_of(beacon), ros.POSE_TYPE, self._pose_qos)
        return w

    def _write(self, writer, type_name: str, msg: dict) -> bool:
        try:
            writer.write(self.types.sample(type_name, msg))
            return True
        except dds.DDSException as exc:
            if not self._warned:
                self._warned = True
                log.warning("ros2: a %s sample was not written (%s); counted in 'dropped'", type_name, exc)
            return False

    def write(self, record) -> None:
        beacon = (getattr(record, "beacon", None) or self.default_beacon) if self.per_beacon else None
        w = self._pose_writer(beacon)
        if w is not None and self._write(w, ros.POSE_TYPE, ros.pose_message(record, self.frame_id)):
            self.published += 1
        else:
            self.dropped += 1

    def health(self, snapshot: HealthSnapshot) -> None:
        if self._write(self._diag, ros.DIAGNOSTICS_TYPE, ros.diagnostics_message(snapshot, self.frame_id)):
            self.diagnostics += 1

    def beacon_gone(self, beacon: str, reason: str) -> None:
        w = self._poses.pop(beacon, None) if self.per_beacon else None
        if w is not None:
            self.node.delete(w)

    def matched(self) -> dict[str, int]:
        """Subscriptions matched now, by topic."""
        out = {self.topic_of(b): dds.matched(w) for b, w in self._poses.items()}
        out[DIAGNOSTICS_TOPIC] = dds.matched(self._diag)
        if self._tf is not None:
            out[TF_STATIC_TOPIC] = dds.matched(self._tf)
        return out

    def health_counters(self) -> dict[str, Any]:
        m = self.matched()
        d: dict[str, Any] = {"published": self.published, "dropped": self.dropped,
                             "matched": sum(n for t, n in m.items() if t.endswith("/pose")),
                             "diagnostics": self.diagnostics}
        for inp in self.inputs:
            d.update(inp.counters())
        return d

    def counters(self) -> dict[str, Any]:
        """For the final counters: the health counters, the domain and each topic's matched subscriptions
        (as they were when the sink closed)."""
        if self._final is not None:
            return self._final
        d = self.health_counters()
        d.update(domain_id=self.settings.domain_id, topics=self.matched())
        return d

    def _close(self) -> None:
        self._final = self.counters()
        try:
            deadline = time.monotonic() + ACK_WAIT_S
            for w in [*self._poses.values(), self._diag]:
                left = deadline - time.monotonic()
                if left <= 0 or not w.wait_for_acks(dds.duration(seconds=left)):
                    log.info("ros2: not every subscriber acknowledged the last samples within %.0f s", ACK_WAIT_S)
                    break
        except dds.DDSException as exc:
            log.debug("ros2: waiting for acknowledgements: %s", exc)
        finally:
            self.node.close()
