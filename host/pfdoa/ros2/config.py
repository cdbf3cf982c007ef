"""The site file's optional ``[ros2]`` table: where ``pfdoa gateway --ros2`` joins the ROS 2 graph.

Every key has a default (shown)::

    [ros2]
    domain_id = 0                 # ROS_DOMAIN_ID; when the key is absent, $ROS_DOMAIN_ID, else 0
    namespace = ""                # prefix of the relative topics below ("/robot1": /robot1/pfdoa/pose)
    odom_topic = "odom"           # nav_msgs/msg/Odometry to subscribe to ("" = none)
    odom_reliability = "best_effort"  # or "reliable" (then only reliable publishers match)
    pose_reliability = "reliable"     # /pfdoa/pose; "best_effort" for subscribers that ask for no more
    pose_depth = 10               # keep-last depth of /pfdoa/pose

Topics: ``pfdoa/pose`` (one per beacon, ``pfdoa/<beacon>/pose``, when the gateway tracks
several) and ``odom_topic`` are relative to ``namespace``; ``/diagnostics`` and
``/tf_static`` are absolute, as ROS 2's own publishers of them have them. The frames are the
recording's: ``--frame-id`` names the positions' frame and ``[site] map_pose`` places it in
``map`` (:mod:`pfdoa.frames`). Unknown keys, wrong types and out-of-range values are one
:class:`~pfdoa.errors.ConfigError` line naming the key (exit status 2).
"""

from __future__ import annotations

import os
import re
import zlib
from dataclasses import dataclass
from typing import Any, Mapping

from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.mqtt.config import check_table  # the one validator of our optional tables

# the highest id RTPS's port mapping (7400 + 250 * id + ...) leaves in range
DOMAIN_ID_MAX = int(schema.row("ros2", "domain_id").max or 0)
RELIABILITIES = schema.row("ros2", "odom_reliability").choices
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Ros2Table:
    domain_id: int = 0
    namespace: str = ""
    odom_topic: str = "odom"
    odom_reliability: str = "best_effort"
    pose_reliability: str = "reliable"
    pose_depth: int = 10


@dataclass(frozen=True)
class Ros2Settings:
    """The table checked and resolved: fully qualified topic names, the domain id."""

    domain_id: int = 0
    namespace: str = ""
    odom_topic: str = "/odom"  # "" = no subscription
    odom_reliable: bool = False
    pose_reliable: bool = True
    pose_depth: int = 10

    def topic(self, name: str) -> str:
        """``name`` resolved against the namespace (absolute names stay)."""
        return resolve(name, self.namespace)

    def pose_topic(self, beacon: str | None = None) -> str:
        return self.topic("pfdoa/pose" if beacon is None else f"pfdoa/{name_token(beacon)}/pose")


def check_name(name: str, *, absolute_ok: bool = True) -> str:
    """A ROS 2 name: tokens of letters, digits and '_' (not starting with a digit, no '__')
    joined by '/'; ValueError otherwise."""
    body = name[1:] if name.startswith("/") and absolute_ok else name
    tokens = body.split("/")
    if not body or any(not _TOKEN.match(t) or "__" in t for t in tokens):
        raise ValueError(f"{name!r} is not a ROS 2 name (tokens of letters, digits and '_', not starting with a "
                         "digit, joined by '/')")
    return name


def resolve(name: str, namespace: str) -> str:
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


def name_token(text: str) -> str:
    """One ROS 2 name token for ``text`` (a beacon id): itself when it is one, else its
    other characters as '_' and a CRC of the original, so two ids never share a token."""
    return text if _TOKEN.match(text) and "__" not in text else _safe(text)


def _safe(text: str) -> str:
    safe = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", text))[:64].strip("_") or "b"
    if safe[0].isdigit():
        safe = "b" + safe
    return f"{safe}_{zlib.crc32(text.encode('utf-8')):08x}"


def _name(source: str, absolute_ok: bool = True, empty_ok: bool = False):
    def conv(where: str, v: Any) -> str:
        if not isinstance(v, str):
            raise ConfigError(source, where, f"must be a string, got {v!r}")
        if v == "" and empty_ok:
            return v
        try:
            return check_name(v, absolute_ok=absolute_ok)
        except ValueError as exc:
            raise ConfigError(source, where, str(exc)) from None
    return conv


def ros2_settings(sections: Mapping[str, Any], source: str = "<site>",
                  environ: Mapping[str, str] | None = None) -> Ros2Settings:
    """The ``[ros2]`` table (missing -> defaults); ``domain_id`` from ``$ROS_DOMAIN_ID`` when
    the table does not give it."""
    table = sections.get("ros2")
    t = check_table(Ros2Table, table, source, "ros2", {
        "namespace": _name(source, empty_ok=True), "odom_topic": _name(source, empty_ok=True)})
    if t.namespace and not t.namespace.startswith("/"):
        raise ConfigError(source, "ros2.namespace", f"must start with '/' (or be empty), got {t.namespace!r}")
    domain_id = t.domain_id
    if not isinstance(table, dict) or "domain_id" not in table:
        env = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
        if env:
            if not env.isdigit() or not 0 <= int(env) <= DOMAIN_ID_MAX:
                raise ConfigError("$ROS_DOMAIN_ID", "value", f"must be an integer in 0..{DOMAIN_ID_MAX}, got {env!r}")
            domain_id = int(env)
    return Ros2Settings(
        domain_id=domain_id, namespace=t.namespace, odom_topic=resolve(t.odom_topic, t.namespace) if t.odom_topic else "",
        odom_reliable=t.odom_reliability == "reliable", pose_reliable=t.pose_reliability == "reliable",
        pose_depth=t.pose_depth)
