"""ROS 2 messages of the gateway's output, as plain dicts (no ROS installation needed).

The message definitions are written out in the concatenated form that MCAP files carry
for ROS 2 (``ros2msg`` schema encoding: the message's own fields, then each sub-message
after a line of ``=`` and ``MSG: pkg/Type``), with the field layouts of ROS 2 Humble and
later (``std_msgs``, ``geometry_msgs``, ``diagnostic_msgs``, ``visualization_msgs``,
``nav_msgs``, ``tf2_msgs``) and our own messages, ``pfdoa_msgs/msg/AnchorReading``, ``OdometryIncrement`` and ``TimerMark``
(what the gateway's estimates are a function of, so that a recording replays).

Conventions (REP-103, REP-105): metres, radians, x/y in the site frame, z up, angles
counter-clockwise. A localization source publishes in a fixed frame: ``frame_id``
defaults to ``map``; see docs/robot.md for placing the site frame in a robot's map.
Covariances are row-major 6 x 6 over (x, y, z, rotation about X, Y, Z); what we do not
estimate (z, roll, pitch, and yaw when there is no heading) gets :data:`UNKNOWN_VARIANCE`.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from pfdoa.gateway.health import ERROR, OK, STALE, WARN, HealthSnapshot
from pfdoa.sinks.base import record_cov, record_heading

UNKNOWN_VARIANCE = 1.0e6  # m^2 or rad^2: "not estimated" (REP-103 practice: large, not zero)
# A covariance the estimator reports as singular (all particles on one point) is floored
# to this variance, so every published matrix is positive definite.
MIN_VARIANCE = 1.0e-6  # m^2
DEFAULT_FRAME = "map"

POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
READING_TYPE = "pfdoa_msgs/msg/AnchorReading"
ODOMETRY_TYPE = "pfdoa_msgs/msg/OdometryIncrement"
TIMER_TYPE = "pfdoa_msgs/msg/TimerMark"
NAV_ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
ODOM_FRAME = "odom"  # REP-105: the odometry's continuous frame ...
BASE_FRAME = "base_link"  # ... and the robot's body

LEVELS = {OK: 0, WARN: 1, ERROR: 2, STALE: 3}  # diagnostic_msgs/DiagnosticStatus

_SEP = "=" * 80


def _concat(own: str, *subs: tuple[str, str]) -> str:
    parts = [own.strip("\n")]
    for name, text in subs:
        parts.append(f"{_SEP}\nMSG: {name}\n{text.strip(chr(10))}")
    return "\n".join(parts) + "\n"


_TIME = ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec")
_DURATION = ("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec")
_HEADER = ("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id")
_POINT = ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z")
_QUATERNION = ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1")
_POSE = ("geometry_msgs/Pose", "Point position\nQuaternion orientation")
_VECTOR3 = ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z")
_COLOR = ("std_msgs/ColorRGBA", "float32 r\nfloat32 g\nfloat32 b\nfloat32 a")

POSE_MSGDEF = _concat(
    "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose",
    _HEADER, _TIME,
    ("geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance"),
    _POSE, _POINT, _QUATERNION,
)

DIAGNOSTICS_MSGDEF = _concat(
    "std_msgs/Header header\nDiagnosticStatus[] status",
    _HEADER, _TIME,
    ("diagnostic_msgs/DiagnosticStatus",
     "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n"
     "byte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values"),
    ("diagnostic_msgs/KeyValue", "string key\nstring value"),
)

MARKERS_MSGDEF = _concat(
    "Marker[] markers",
    ("visualization_msgs/Marker",
     "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n"
     "int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\n"
     "int32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\n"
     "int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
     "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
     "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n"
     "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
     "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\n"
     "string texture_resource\nsensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\n"
     "string text\nstring mesh_resource\nMeshFile mesh_file\nbool mesh_use_embedded_materials"),
    _HEADER, _TIME, _POSE, _POINT, _QUATERNION, _VECTOR3, _COLOR, _DURATION,
    ("sensor_msgs/CompressedImage", "std_msgs/Header header\nstring format\nuint8[] data"),
    ("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v"),
    ("visualization_msgs/MeshFile", "string filename\nuint8[] data"),
)

_TWIST = ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular")

NAV_ODOMETRY_MSGDEF = _concat(
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist",
    _HEADER, _TIME,
    ("geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance"),
    _POSE, _POINT, _QUATERNION,
    ("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance"),
    _TWIST, _VECTOR3,
)

TF_MSGDEF = _concat(
    "geometry_msgs/TransformStamped[] transforms",
    ("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform"),
    _HEADER, _TIME,
    ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation"),
    _VECTOR3, _QUATERNION,
)

# One RSSI report as the gateway handed it to its reassembler. header.stamp is t (for ROS
# tools); t and event_t are the floats the gateway computed with, so a replay of the
# recording is exact. seq, tick_ms, event_t are meaningful only when has_seq / has_tick /
# has_event_t. beacon is the id of the beacon the reading names (an ESPresense device), ""
# for our frames' readings; it is the last field, so recordings made before it existed
# still decode (with their own embedded definition) and read back as unnamed. anchor_id is
# a site's id (an ESPresense room's, a trace's: up to 2**31 - 1); recordings made while it
# was uint8 decode the same way.
READING_MSGDEF = _concat(
    "std_msgs/Header header\nfloat64 t\nbool has_event_t\nfloat64 event_t\nuint32 anchor_id\nfloat64 rssi_dbm\n"
    "bool has_seq\nuint16 seq\nbool has_tick\nuint32 tick_ms\nuint8 flags\nstring beacon",
    _HEADER, _TIME,
)

# One odometry increment as the gateway handed it to its localizer: the robot-frame motion
# (dx forward, dy left, dtheta counter-clockwise) over (previous t, t]; arrival is when it
# reached the gateway. header.stamp is t.
ODOMETRY_MSGDEF = _concat(
    "std_msgs/Header header\nfloat64 arrival\nfloat64 t\nfloat64 dx\nfloat64 dy\nfloat64 dtheta",
    _HEADER, _TIME,
)

# The gateway's timers (set timeouts, staleness, the wait for odometry) ran at t.
TIMER_MSGDEF = _concat("std_msgs/Header header\nfloat64 t", _HEADER, _TIME)

# The live ROS 2 output's messages (pfdoa.sinks.ros2): what it publishes, and the odometry it reads.
LIVE_MSGDEFS = {
    POSE_TYPE: POSE_MSGDEF,
    DIAGNOSTICS_TYPE: DIAGNOSTICS_MSGDEF,
    TF_TYPE: TF_MSGDEF,
    NAV_ODOMETRY_TYPE: NAV_ODOMETRY_MSGDEF,
}

MSGDEFS = {
    POSE_TYPE: POSE_MSGDEF,
    DIAGNOSTICS_TYPE: DIAGNOSTICS_MSGDEF,
    MARKERS_TYPE: MARKERS_MSGDEF,
    READING_TYPE: READING_MSGDEF,
    ODOMETRY_TYPE: ODOMETRY_MSGDEF,
    TIMER_TYPE: TIMER_MSGDEF,
    NAV_ODOMETRY_TYPE: NAV_ODOMETRY_MSGDEF,
    TF_TYPE: TF_MSGDEF,
}


def time_ns(t: float) -> int:
    """Seconds (float) to integer nanoseconds, rounded (whole seconds and the fraction
    apart: ``t * 1e9`` of a Unix time would lose the last ~100 ns to float rounding)."""
    sec = math.floor(float(t))
    return int(sec) * 1_000_000_000 + int(round((float(t) - sec) * 1e9))


def stamp(t: float) -> dict[str, int]:
    """builtin_interfaces/Time of ``t`` seconds (nanosec in [0, 1e9))."""
    sec, nsec = divmod(time_ns(t), 1_000_000_000)
    return {"sec": int(sec), "nanosec": int(nsec)}


def stamp_seconds(sec: int, nanosec: int) -> float:
    """builtin_interfaces/Time back to seconds (the float every reader of our messages uses)."""
    return int(sec) + int(nanosec) * 1e-9


def header(t: float, frame_id: str) -> dict[str, Any]:
    return {"stamp": stamp(t), "frame_id": frame_id}


def _spd(xx: float, xy: float, yy: float) -> tuple[float, float, float]:
    """The 2 x 2 covariance with eigenvalues floored to MIN_VARIANCE (symmetric PD)."""
    m = np.array([[xx, xy], [xy, yy]], dtype=float)
    w, v = np.linalg.eigh(m)
    if w[0] >= MIN_VARIANCE:
        return xx, xy, yy
    w = np.maximum(w, MIN_VARIANCE)
    m = (v * w) @ v.T
    return float(m[0, 0]), float(0.5 * (m[0, 1] + m[1, 0])), float(m[1, 1])


def pose_covariance(record) -> list[float]:
    """The 36 covariance values of a record's pose (row-major x, y, z, rotX, rotY, rotZ)."""
    c = [0.0] * 36
    cov = record_cov(record)
    if cov is None:
        xx, xy, yy = UNKNOWN_VARIANCE, 0.0, UNKNOWN_VARIANCE
    else:
        xx, xy, yy = _spd(*cov)
    c[0], c[1], c[6], c[7] = xx, xy, xy, yy
    c[14] = c[21] = c[28] = UNKNOWN_VARIANCE
    h = record_heading(record)
    c[35] = h[1] if h is not None and math.isfinite(h[1]) and h[1] > 0.0 else UNKNOWN_VARIANCE
    return c


def yaw_quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The rotation about z (rad) of a unit quaternion, roll and pitch aside (Z-Y-X angles)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def pose_message(record, frame_id: str = DEFAULT_FRAME) -> dict[str, Any]:
    """geometry_msgs/msg/PoseWithCovarianceStamped of an output record.

    position (x, y, 0); orientation the yaw of ``record.heading`` when the record has
    one (its variance ``heading_var`` at covariance[35]), else the identity with an
    unknown yaw; covariance from ``record.cov`` (``[xx, xy, yy]``; from ``sigma`` before
    records carry it). Stamp: ``record.t``.
    """
    h = record_heading(record)
    return {
        "header": header(record.t, frame_id),
        "pose": {
            "pose": {
                "position": {"x": float(record.x), "y": float(record.y), "z": 0.0},
                "orientation": yaw_quaternion(h[0]) if h is not None else yaw_quaternion(0.0),
            },
            "covariance": pose_covariance(record),
        },
    }


def _kv(key: str, value) -> dict[str, str]:
    return {"key": key, "value": "" if value is None else str(value)}


def diagnostics_message(snap: HealthSnapshot, frame_id: str = DEFAULT_FRAME,
                        hardware: Mapping[int, str] | None = None) -> dict[str, Any]:
    """diagnostic_msgs/msg/DiagnosticArray: one status for the gateway, one per anchor."""
    worst = max((LEVELS[h.level] for h in snap.anchors.values()), default=0)
    gw_level = 1 if (worst or snap.errors) else 0
    status = [{
        "level": gw_level,
        "name": "pfdoa: gateway",
        "message": snap.line().removeprefix("health: "),
        "hardware_id": "pfdoa-gateway",
        "values": [
            _kv("frames_per_s", f"{snap.frames_per_s:.3f}"), _kv("sets_per_s", f"{snap.sets_per_s:.3f}"),
            _kv("estimates_per_s", f"{snap.estimates_per_s:.3f}"), _kv("open_sets", snap.open_sets),
            _kv("frames", snap.frames), _kv("sets", snap.sets), _kv("estimates", snap.estimates),
            _kv("estimator_errors", snap.estimator_errors),
        ] + [_kv(f"error.{k}", v) for k, v in sorted(snap.errors.items())]
          + [_kv(f"reconnects.{k}", v) for k, v in sorted(snap.reconnects.items())]
          + [_kv(f"odometry.{k}", v) for k, v in snap.odometry.items()]
          + [_kv(f"{name}.{k}", v) for name, c in snap.outputs.items() for k, v in c.items() if isinstance(v, int)],
    }]
    for a, h in snap.anchors.items():
        loss = "-" if h.loss is None else f"{100.0 * h.loss:.1f}%"
        why = {STALE: "stale (silent)", ERROR: "message definitions differ", WARN: "lossy or rebooted",
               OK: "ok"}[h.level]
        status.append({
            "level": LEVELS[h.level],
            "name": f"pfdoa: anchor {a}",
            "message": f"{why}; loss {loss}",
            "hardware_id": (hardware or {}).get(a, f"anchor{a}"),
            "values": [
                _kv("received", h.received), _kv("lost", h.lost),
                _kv("loss_pct", "" if h.loss is None else f"{100.0 * h.loss:.3f}"),
                _kv("duplicates", h.duplicates), _kv("late", h.late), _kv("stale", str(h.stale).lower()),
                _kv("reboots", h.reboots), _kv("period_received", h.period_received),
                _kv("period_lost", h.period_lost), _kv("period_reboots", h.period_reboots),
            ],
        })
    return {"header": header(snap.t, frame_id), "status": status}


# Anchor colours by level (RGBA, 0..1).
LEVEL_COLORS = {OK: (0.10, 0.60, 0.20, 1.0), WARN: (0.95, 0.65, 0.05, 1.0), ERROR: (0.85, 0.10, 0.10, 1.0),
                STALE: (0.55, 0.55, 0.55, 1.0)}
ANCHOR_NS = "pfdoa_anchors"
LABEL_NS = "pfdoa_anchor_labels"
_CYLINDER, _TEXT = 3, 9


def _marker(ns: str, mid: int, mtype: int, t: float, frame_id: str, x: float, y: float, z: float,
            scale: tuple[float, float, float], color: tuple[float, float, float, float], text: str = "") -> dict:
    return {
        "header": header(t, frame_id), "ns": ns, "id": int(mid), "type": mtype, "action": 0,
        "pose": {"position": {"x": float(x), "y": float(y), "z": float(z)}, "orientation": yaw_quaternion(0.0)},
        "scale": {"x": scale[0], "y": scale[1], "z": scale[2]},
        "color": dict(zip("rgba", color)),
        "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False, "points": [], "colors": [],
        "texture_resource": "", "texture": {"header": header(0.0, ""), "format": "", "data": b""},
        "uv_coordinates": [], "text": text, "mesh_resource": "",
        "mesh_file": {"filename": "", "data": b""}, "mesh_use_embedded_materials": False,
    }


def anchors_message(site, t: float, levels: Mapping[int, str] | None = None,
                    frame_id: str = DEFAULT_FRAME) -> dict[str, Any]:
    """visualization_msgs/msg/MarkerArray: a cylinder per anchor coloured by its level
    (namespace ``pfdoa_anchors``, marker id = anchor id, at the anchor's x, y) and a text
    label above it (``pfdoa_anchor_labels``)."""
    levels = levels or {}
    markers = []
    for a in site.anchors:
        color = LEVEL_COLORS[levels.get(a.id, OK)]
        markers.append(_marker(ANCHOR_NS, a.id, _CYLINDER, t, frame_id, a.x, a.y, 0.25, (0.15, 0.15, 0.5), color))
        markers.append(_marker(LABEL_NS, a.id, _TEXT, t, frame_id, a.x, a.y, 0.7, (0.0, 0.0, 0.25),
                               (1.0, 1.0, 1.0, 1.0), text=f"a{a.id}"))
    return {"markers": markers}


def reading_message(r, frame_id: str = DEFAULT_FRAME, beacon: str | None = None) -> dict[str, Any]:
    """pfdoa_msgs/msg/AnchorReading of a :class:`~pfdoa.readings.reassembly.Reading` (and the
    beacon id it names, if any)."""
    event_t = getattr(r, "event_t", None)
    return {
        "header": header(r.t, frame_id), "t": float(r.t),
        "has_event_t": event_t is not None, "event_t": float(event_t) if event_t is not None else 0.0,
        "anchor_id": int(r.anchor_id), "rssi_dbm": float(r.rssi_dbm),
        "has_seq": r.seq is not None, "seq": int(r.seq) & 0xFFFF if r.seq is not None else 0,
        "has_tick": r.tick_ms is not None, "tick_ms": int(r.tick_ms) & 0xFFFFFFFF if r.tick_ms is not None else 0,
        "flags": int(r.flags) & 0xFF, "beacon": beacon or "",
    }


def odometry_message(inc, frame_id: str = DEFAULT_FRAME) -> dict[str, Any]:
    """pfdoa_msgs/msg/OdometryIncrement of an :class:`~pfdoa.gateway.transports.OdomLine`."""
    return {"header": header(inc.t_odom, frame_id), "arrival": float(inc.t), "t": float(inc.t_odom),
            "dx": float(inc.dx), "dy": float(inc.dy), "dtheta": float(inc.dtheta)}


def timer_message(t: float, frame_id: str = DEFAULT_FRAME) -> dict[str, Any]:
    """pfdoa_msgs/msg/TimerMark: the gateway's timers ran at ``t``."""
    return {"header": header(t, frame_id), "t": float(t)}


def _unknown_covariance() -> list[float]:
    c = [0.0] * 36
    for i in range(6):
        c[7 * i] = UNKNOWN_VARIANCE
    return c


class OdometryPose:
    """The odometry increments composed into ``nav_msgs/msg/Odometry``: the pose in
    :data:`ODOM_FRAME` (starting at the origin, heading 0) of :data:`BASE_FRAME`, and the
    twist of each increment over its interval (zero for the first). The increments carry
    no uncertainty, so every variance is :data:`UNKNOWN_VARIANCE`."""

    def __init__(self) -> None:
        self.x = self.y = self.yaw = 0.0
        self._t: float | None = None

    def message(self, inc) -> dict[str, Any]:
        """Add one :class:`~pfdoa.gateway.transports.OdomLine` (robot-frame dx forward, dy
        left, dtheta counter-clockwise over (previous t, t]) and return the message at its t."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        self.x += c * inc.dx - s * inc.dy
        self.y += s * inc.dx + c * inc.dy
        self.yaw = math.remainder(self.yaw + inc.dtheta, 2.0 * math.pi)
        dt = float(inc.t_odom) - self._t if self._t is not None else 0.0
        self._t = float(inc.t_odom)
        rate = 1.0 / dt if dt > 0.0 else 0.0
        return {
            "header": header(inc.t_odom, ODOM_FRAME), "child_frame_id": BASE_FRAME,
            "pose": {"pose": {"position": {"x": self.x, "y": self.y, "z": 0.0}, "orientation": yaw_quaternion(self.yaw)},
                     "covariance": _unknown_covariance()},
            "twist": {"twist": {"linear": {"x": inc.dx * rate, "y": inc.dy * rate, "z": 0.0},
                                "angular": {"x": 0.0, "y": 0.0, "z": inc.dtheta * rate}},
                      "covariance": _unknown_covariance()},
        }


def tf_message(transforms: list[dict[str, Any]]) -> dict[str, Any]:
    """``tf2_msgs/msg/TFMessage`` of ``geometry_msgs/msg/TransformStamped`` dicts
    (:func:`pfdoa.frames.site_transform`)."""
    return {"transforms": list(transforms)}
