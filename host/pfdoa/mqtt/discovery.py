"""Home Assistant MQTT discovery: a beacon appears as a device with its position.

Per beacon, retained configs (Home Assistant reads them when it starts or subscribes):

* ``<discovery>/device_tracker/<node>/<object>/config``: a ``device_tracker`` whose state
  (``home`` / ``not_home``) is on ``<prefix>/<beacon>/state`` and whose attributes are the
  JSON pose on ``<prefix>/<beacon>/pose`` (``x``, ``y``, ``sigma``, ``t``, ... as in the
  JSON output line). No ``latitude``/``longitude``: positions are metres in the site frame.
* ``<discovery>/sensor/<node>/<object>_x/config`` (and ``_y``, ``_sigma``): numeric
  sensors taken from the same pose topic with ``value_template``, unit ``m``, so the
  position can be graphed and used in automations.
* With rooms or floors in the site (``places``): the tracker's state is the room (the
  shape ESPresense-companion users know: state = room, attributes ``x``, ``y``, ``room``,
  ``floor``, ``confidence``), and a ``<object>_confidence`` sensor (%) from the pose's
  ``confidence`` (room_p in percent).
* One gateway device (``<discovery>/sensor/<node>/estimates/config``) that the beacons
  name in ``via_device``.

Every entity has a ``unique_id`` (required for the device registry) and the gateway's
availability topic ``<prefix>/status`` (the last will: ``offline`` when the gateway
goes away). ``node`` and ``object`` are restricted to ``[a-zA-Z0-9_-]`` as Home
Assistant's discovery topic rules require; a beacon id with other characters
(ESPresense ids such as ``iBeacon:e2c5...-1-2``) becomes a slug plus a short hash of the
id, so two ids that slug alike still get two entities.
"""

from __future__ import annotations

import re
import zlib
from typing import Any

from pfdoa import __version__ as PFDOA_VERSION

DEFAULT_DISCOVERY_PREFIX = "homeassistant"
_NOT_ID = re.compile(r"[^a-zA-Z0-9_-]")
SENSOR_FIELDS = ("x", "y", "sigma")


def object_id(name: str) -> str:
    """``name`` as a discovery topic level: ``[a-zA-Z0-9_-]``, unique per distinct ``name``."""
    slug = _NOT_ID.sub("_", name)[:64] or "_"
    if slug == name:
        return slug
    return f"{slug}_{zlib.crc32(name.encode('utf-8')):08x}"


def _origin() -> dict:
    return {"name": "pfdoa", "sw_version": PFDOA_VERSION}


def gateway_device(node: str) -> dict:
    return {"identifiers": [f"pfdoa_{node}"], "name": f"pfdoa gateway {node}", "manufacturer": "pfdoa",
            "model": "PF-DOA gateway", "sw_version": PFDOA_VERSION}


def gateway_configs(node: str, discovery_prefix: str, health_topic: str, status_topic: str) -> list[tuple[str, dict]]:
    """The gateway's own device: a sensor with the number of estimates made."""
    cfg = {
        "name": "estimates",
        "unique_id": f"pfdoa_{node}_estimates",
        "state_topic": health_topic,
        "value_template": "{{ value_json.estimates }}",
        "state_class": "total_increasing",
        "availability_topic": status_topic,
        "device": gateway_device(node),
        "origin": _origin(),
    }
    return [(f"{discovery_prefix}/sensor/{node}/estimates/config", cfg)]


def beacon_configs(node: str, beacon: str, discovery_prefix: str, pose_topic: str, state_topic: str,
                   status_topic: str, expire_after_s: int | None = None,
                   places: bool = False) -> list[tuple[str, dict]]:
    """(topic, config) for the beacon's device_tracker, its x / y / sigma sensors and, with
    ``places``, its room confidence sensor."""
    obj = object_id(beacon)
    device = {"identifiers": [f"pfdoa_{node}_{obj}"], "name": beacon, "manufacturer": "pfdoa",
              "model": "beacon", "via_device": f"pfdoa_{node}"}
    tracker = {
        "name": None,  # the entity is named after its device
        "unique_id": f"pfdoa_{node}_{obj}_tracker",
        "state_topic": state_topic,
        "json_attributes_topic": pose_topic,
        "source_type": "bluetooth_le",
        "availability_topic": status_topic,
        "device": device,
        "origin": _origin(),
    }
    out = [(f"{discovery_prefix}/device_tracker/{node}/{obj}/config", tracker)]
    for f in SENSOR_FIELDS + (("confidence",) if places else ()):
        unit = {"unit_of_measurement": "%"} if f == "confidence" else {"unit_of_measurement": "m",
                                                                       "device_class": "distance"}
        s: dict[str, Any] = {
            "name": f,
            "unique_id": f"pfdoa_{node}_{obj}_{f}",
            "state_topic": pose_topic,
            "value_template": f"{{{{ value_json.{f} }}}}",
            **unit,
            "state_class": "measurement",
            "availability_topic": status_topic,
            "device": {"identifiers": device["identifiers"]},
            "origin": _origin(),
        }
        if expire_after_s:
            s["expire_after"] = int(expire_after_s)
        out.append((f"{discovery_prefix}/sensor/{node}/{obj}_{f}/config", s))
    return out
