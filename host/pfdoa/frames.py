"""The site frame in the robot's map: the one transform ROS 2 tools get as ``/tf_static``.

Positions are in the **site frame** (the frame the site file's anchors are measured in),
named by ``--frame-id`` (default ``map``: the site frame *is* the map, and there is nothing
to transform). A site measured in its own frame says where that frame lies in the map::

    [site]
    map_pose = [X, Y, YAW]    # the site frame's origin (m) and x axis (rad, counter-clockwise) in map

and the positions then need the site frame's own name (``--frame-id pfdoa_site``): the
transform ``map -> <frame-id>`` is :func:`site_transform`, the one builder of it. The MCAP
recording writes it on ``/tf_static`` (``tf2_msgs/msg/TFMessage``, :mod:`pfdoa.sinks.mcap`),
and a live ROS 2 publisher takes it from here too; it is what ``ros2 run tf2_ros
static_transform_publisher --x X --y Y --yaw YAW --frame-id map --child-frame-id
pfdoa_site`` would publish (docs/robot.md). Without ``map_pose`` there is no transform
(a user who runs that command keeps doing so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pfdoa.errors import ConfigError, InputError

MAP_FRAME = "map"  # REP-105's fixed world frame: the transform's parent
MAX_OFFSET_M = 100_000.0
MAX_YAW_RAD = 2.0 * math.pi  # beyond: degrees written where radians belong


@dataclass(frozen=True)
class SiteFrame:
    """The site frame ``child`` placed in ``parent``: origin (x, y) m, rotated ``yaw`` rad."""

    parent: str
    child: str
    x: float
    y: float
    yaw: float

    @property
    def rotation(self) -> dict[str, float]:
        """The yaw as a quaternion (x, y, z, w)."""
        return {"x": 0.0, "y": 0.0, "z": math.sin(self.yaw / 2.0), "w": math.cos(self.yaw / 2.0)}


def parse_map_pose(source: str, value: Any) -> tuple[float, float, float]:
    """``[site] map_pose`` = [x, y, yaw]: ConfigError naming the key unless three finite
    numbers, the offsets within MAX_OFFSET_M and the yaw in radians within +-2 pi."""
    key = "site.map_pose"
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(source, key, f"must be [x, y, yaw] (m, m, rad), got {str(value)[:60]}")
    out = []
    for v in value:
        f = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 1e300 else math.nan
        if not math.isfinite(f):
            raise ConfigError(source, key, f"must hold finite numbers, got {str(v)[:40]}")
        out.append(f)
    x, y, yaw = out
    if max(abs(x), abs(y)) > MAX_OFFSET_M:
        raise ConfigError(source, key, f"an offset beyond {MAX_OFFSET_M:g} m")
    if abs(yaw) > MAX_YAW_RAD:
        raise ConfigError(source, key, f"yaw {yaw:g} is beyond +-2 pi: it is in radians")
    return x, y, yaw


def site_frame(site, frame_id: str) -> SiteFrame | None:
    """Where the positions' frame ``frame_id`` lies in the map, from the site's ``[site]
    map_pose`` (None without it). ``frame_id`` ``map`` with a ``map_pose`` is an InputError
    naming ``--frame-id``: the positions would claim to be in the frame they are placed in."""
    pose = site.sections.get("site", {}).get("map_pose")
    if pose is None:
        return None
    x, y, yaw = parse_map_pose(site.name or "<site>", pose)
    if frame_id == MAP_FRAME:
        raise InputError(f"--frame-id {frame_id}: the site file's [site] map_pose places the site frame in "
                         f"{MAP_FRAME}; give the site frame its own name (e.g. --frame-id pfdoa_site)")
    return SiteFrame(MAP_FRAME, frame_id, x, y, yaw)


def site_transform(site, frame_id: str, stamp: dict[str, int]) -> dict[str, Any] | None:
    """``geometry_msgs/msg/TransformStamped`` (a plain dict, as :mod:`pfdoa.sinks.ros`'s
    messages) of :func:`site_frame` at ``stamp`` (``builtin_interfaces/Time``: sec,
    nanosec); None when the site has no ``map_pose``. The one builder of the site frame's
    transform: the recording's ``/tf_static`` and a live publisher's use it."""
    f = site_frame(site, frame_id)
    if f is None:
        return None
    return {"header": {"stamp": dict(stamp), "frame_id": f.parent}, "child_frame_id": f.child,
            "transform": {"translation": {"x": f.x, "y": f.y, "z": 0.0}, "rotation": f.rotation}}
