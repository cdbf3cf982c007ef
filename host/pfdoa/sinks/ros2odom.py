"""The robot's odometry from its ROS 2 graph (``nav_msgs/msg/Odometry``) as increments, in message time.

``pfdoa gateway --ros2`` subscribes to ``[ros2] odom_topic`` (default ``/odom``) on the
participant of the ROS 2 sink (:mod:`pfdoa.sinks.ros2`) and uses it as ``--odom`` uses a
stream of ``t,dx,dy,dtheta`` lines: every message becomes an
:class:`~pfdoa.gateway.transports.OdomLine` stamped with its arrival, for the localizer's
odometry buffer, where the increments count by their own time ``t``, the message's
``header.stamp`` (on the robot's clock, which must be the gateway's: the same host, or
synchronised).

:class:`OdometryPoses` makes the increments from the poses (``pose.pose``: x, y and the yaw
of the orientation) exactly as an odometry file is made from a track
(:func:`pfdoa.odometry.increments`: the motion from the previous pose, in the robot frame
of the previous pose; the first pose of a stream is no motion), so a file of the same poses
gives the same estimates (``tests/io/test_ros2.py``). The twist is not used: the difference of
two poses is the motion between them whatever was lost in between.

Untrusted input: a message with a non-finite pose or a stamp out of range is counted
(``bad``) and skipped; one not after the previous one from the same publisher
(``out_of_order``) too. A new publisher (another writer on the topic, or the same one
restarted) starts a new stream (``restarts``): poses of different odometry sources are never
subtracted. The reader holds at most :data:`DEPTH` messages; at most :data:`MAX_TAKE` are
taken per read.
"""

from __future__ import annotations

import math

import numpy as np

from pfdoa.clock import Clock
from pfdoa.gateway.transports import Item, OdomLine, Transport, TransportError
from pfdoa.odometry import increments
from pfdoa.ros2 import dds
from pfdoa.sinks import ros

# The DDS reader keeps every message (keep-all) up to this many not yet taken (two seconds
# of 100 Hz odometry; the reader takes what came every 50 ms): a reliable publisher is then
# held back (its samples acknowledged only as room frees) rather than losing any; a
# best-effort one loses what comes beyond (counted, odom_lost).
DEPTH = 200
MAX_TAKE = 256
SEC_MAX = 2**31 - 1


class OdometryPoses:
    """Poses (t, x, y, yaw) of one or more publishers -> increments (t, dx, dy, dtheta)."""

    def __init__(self) -> None:
        self._prev: tuple[float, float, float, float] | None = None
        self._source: object = None
        self.bad = 0
        self.out_of_order = 0
        self.restarts = 0

    def add(self, t: float, x: float, y: float, yaw: float,
            source: object = None) -> tuple[float, float, float, float] | None:
        """The increment this pose ends (None: skipped, counted)."""
        pose = (float(t), float(x), float(y), float(yaw))
        if not all(math.isfinite(v) for v in pose):
            self.bad += 1
            return None
        prev = self._prev
        if prev is not None and source == self._source:
            if not pose[0] > prev[0]:
                self.out_of_order += 1
                return None
            row = increments(np.array([prev, pose]))[1]
        else:
            if prev is not None:
                self.restarts += 1
            row = increments(np.array([pose]))[0]  # no motion at the first pose
        self._prev, self._source = pose, source
        return float(row[0]), float(row[1]), float(row[2]), float(row[3])


def pose_of(msg) -> tuple[float, float, float, float] | None:
    """(t, x, y, yaw) of a ``nav_msgs/msg/Odometry`` sample; None when its stamp is out of range."""
    st = msg.header.stamp
    if not (0 <= st.sec <= SEC_MAX and 0 <= st.nanosec < 1_000_000_000):
        return None
    p = msg.pose.pose
    q = p.orientation
    return ros.stamp_seconds(st.sec, st.nanosec), p.position.x, p.position.y, ros.quaternion_yaw(q.x, q.y, q.z, q.w)


class Ros2OdometrySource(Transport):
    """``nav_msgs/msg/Odometry`` on ``topic`` -> :class:`OdomLine` items (see the module doc).
    ``node``: the ROS 2 sink's :class:`pfdoa.ros2.dds.Node`."""

    finite = False
    # Its inbox is the DDS reader's bounded history (DEPTH), its losses counted there
    # (odom_lost): the runner's reader waits for the loop rather than drop increments.
    buffered = True

    def __init__(self, node, topic: str, reliable: bool = False, clock: Clock | None = None) -> None:
        super().__init__(clock)
        self.node = node
        self.topic = topic
        self.reliable = reliable
        self.name = f"ros2:{topic}"
        self.poses = OdometryPoses()
        self.messages = 0
        self.increments = 0
        self._reader: dds.DataReader | None = None
        self._waiter: dds.Waiter | None = None

    def _open(self) -> None:
        try:
            reader = self._reader = self.node.reader(
                self.topic, ros.NAV_ODOMETRY_TYPE,
                self.node.qos(ros.NAV_ODOMETRY_TYPE, reliable=self.reliable, depth=DEPTH, keep_all=True))
            self._waiter = dds.Waiter(self.node, [reader])
        except dds.DDSException as exc:
            raise TransportError(f"{self.name}: {exc}") from None

    def _read(self, timeout: float) -> list[Item]:
        reader, waiter = self._reader, self._waiter
        if reader is None or waiter is None:
            raise TransportError(f"{self.name}: not open")
        try:
            if not waiter.wait(timeout):
                return []
            samples = reader.take(N=MAX_TAKE)
        except dds.DDSException as exc:
            raise TransportError(f"{self.name}: {exc}") from None
        out: list[Item] = []
        for s in samples:
            info = getattr(s, "sample_info", None)
            if info is None or not info.valid_data:
                continue  # a publisher went away (no data in it)
            self.messages += 1
            pose = pose_of(s)
            if pose is None:
                self.poses.bad += 1
                continue
            inc = self.poses.add(*pose, source=info.publication_handle)
            if inc is not None:
                self.increments += 1
                out.append(OdomLine(self.clock.now(), *inc))
        return out

    def counters(self) -> dict[str, int]:
        d = {"odom_messages": self.messages, "odom_increments": self.increments, "odom_bad": self.poses.bad,
             "odom_out_of_order": self.poses.out_of_order, "odom_restarts": self.poses.restarts}
        reader = self._reader
        if reader is not None:
            try:
                d["odom_publishers"] = int(reader.get_subscription_matched_status().current_count)
                d["odom_lost"] = int(reader.get_sample_lost_status().total_count)
            except dds.DDSException:  # the reader is being deleted (the source closing): counters without it
                pass
        return d

    def _close(self) -> None:
        waiter, reader, self._waiter, self._reader = self._waiter, self._reader, None, None
        if waiter is not None:
            waiter.close()
        if reader is not None:
            self.node.delete(reader)
