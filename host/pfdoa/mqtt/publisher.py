"""What the gateway publishes, on which topics, with which QoS and retain flag.

=====================================  ==========  ======  ===========================================
topic                                  QoS         retain  payload
=====================================  ==========  ======  ===========================================
``<prefix>/<beacon>/pose``             1           no [1]  every estimate: the JSON output line's fields
                                                           plus ``beacon`` (the beacon's id) and, with a
                                                           room, ``confidence`` (room_p in %) [2]
``<prefix>/<beacon>/state``            1           yes     ``home`` while tracked, ``not_home`` once it
                                                           timed out or was evicted (Home Assistant);
                                                           with rooms or floors: the room, else the
                                                           floor, else ``home`` [2]
``<prefix>/health``                    1           yes     the gateway's counters (JSON), periodically
``<prefix>/anchors/<id>/status``       1           yes     one anchor's counters and liveness (JSON)
``<prefix>/status``                    1           yes     ``online`` / ``offline`` (the last will)
``homeassistant/.../config``           1           yes     discovery (:mod:`pfdoa.mqtt.discovery`)
=====================================  ==========  ======  ===========================================

[1] Estimates are a stream (10 per second per beacon): every one is delivered (QoS 1,
held while the broker is away), none retained, so a subscriber arriving late does not
take an old position for a current one (``retain_pose = true`` retains the latest, for
dashboards that show the last known position). State topics are retained: a subscriber
arriving late gets the current value, and after a broker restart the client sends them
again.

[2] The shape ESPresense-companion gives Home Assistant: a device tracker whose state is the
room and whose attributes (the pose) carry ``x``, ``y``, ``room``, ``floor`` and
``confidence`` (0-100). The state is set when it changes (retained: latest wins).

Beacon ids become one topic level: ``/``, ``+``, ``#`` and NUL (which would change the
topic's meaning) are replaced by ``_`` and a short hash of the id is appended, so two
ids never share a topic. The payload's ``beacon`` field keeps the id itself.
"""

from __future__ import annotations

import json
import math
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from pfdoa.mqtt import discovery as ha
from pfdoa.mqtt.client import MqttClient
from pfdoa.mqtt.url import TOPIC_SPECIAL
from pfdoa.output import Record, record_values

HOME = b"home"
NOT_HOME = b"not_home"
MAX_ANNOUNCED = 1024  # beacons whose discovery configs the client holds (and re-sends)


def topic_level(name: str) -> str:
    """``name`` as one topic level (see the module doc)."""
    safe = "".join("_" if ch in TOPIC_SPECIAL else ch for ch in name)[:128] or "_"
    if safe == name:
        return safe
    return f"{safe}_{zlib.crc32(name.encode('utf-8')):08x}"


def pose_payload(beacon: str, rec: Record) -> bytes:
    """The JSON output line's fields (pfdoa.output), ``beacon`` and, when the record has a
    ``room_p``, ``confidence``: it in percent (ESPresense-companion's attribute)."""
    v = record_values(rec)
    v["beacon"] = beacon
    if v.get("room_p") is not None:
        v["confidence"] = int(round(100.0 * v["room_p"]))
    return json.dumps(v, separators=(",", ":")).encode("utf-8")


@dataclass(frozen=True)
class PublisherConfig:
    node_id: str = "pfdoa"  # names this gateway in discovery topics and unique ids
    discovery: bool = True
    discovery_prefix: str = ha.DEFAULT_DISCOVERY_PREFIX
    retain_pose: bool = False
    expire_after_s: int = 0  # Home Assistant sensors turn unavailable after this silence (0 = never)


class Publisher:
    """Publishes estimates, health and anchor status through an :class:`MqttClient`.
    ``places``: the site has rooms or floors (the state is the room; discovery adds them)."""

    def __init__(self, client: MqttClient, cfg: PublisherConfig = PublisherConfig(), places: bool = False) -> None:
        self.client = client
        self.cfg = cfg
        self.places = places
        self.prefix = client.prefix
        self.node = ha.object_id(cfg.node_id)
        self.health_topic = f"{self.prefix}/health"
        self.estimates = 0
        # beacon -> the state topics held for it (discovery configs), least recently seen first
        self._announced: OrderedDict[str, list[str]] = OrderedDict()
        self.forgotten = 0  # beacons whose discovery configs were let go (beyond MAX_ANNOUNCED)
        self._state: dict[str, bytes] = {}  # beacon -> its state while tracked ("home", or its room)
        if cfg.discovery:
            for topic, c in ha.gateway_configs(self.node, cfg.discovery_prefix, self.health_topic,
                                                      client.status_topic):
                client.set_state(topic, _json(c))

    def pose_topic(self, beacon: str) -> str:
        return f"{self.prefix}/{topic_level(beacon)}/pose"

    def state_topic(self, beacon: str) -> str:
        return f"{self.prefix}/{topic_level(beacon)}/state"

    def anchor_topic(self, anchor_id: int) -> str:
        return f"{self.prefix}/anchors/{int(anchor_id)}/status"

    def estimate(self, beacon: str, rec: Record) -> None:
        """One estimate for ``beacon``: its pose (and, the first time, its discovery configs)."""
        if beacon in self._announced:
            self._announced.move_to_end(beacon)
        else:
            self._announce(beacon)
        state = HOME
        if self.places:
            where = rec.room or rec.floor
            state = where.encode("utf-8") if where else HOME
        if self._state.get(beacon) != state:
            self._state[beacon] = state
            self.client.set_state(self.state_topic(beacon), state)
        payload = pose_payload(beacon, rec)
        if self.cfg.retain_pose:
            self.client.set_state(self.pose_topic(beacon), payload)
        else:
            self.client.publish(self.pose_topic(beacon), payload)
        self.estimates += 1

    def _announce(self, beacon: str) -> None:
        topics = [self.state_topic(beacon)]
        if self.cfg.retain_pose:
            topics.append(self.pose_topic(beacon))
        if self.cfg.discovery:
            for topic, c in ha.beacon_configs(self.node, beacon, self.cfg.discovery_prefix,
                                                     self.pose_topic(beacon), self.state_topic(beacon),
                                                     self.client.status_topic, self.cfg.expire_after_s or None,
                                                     places=self.places):
                if self.client.set_state(topic, _json(c)):
                    topics.append(topic)
        self._announced[beacon] = topics
        if len(self._announced) > MAX_ANNOUNCED:
            old_beacon, old = self._announced.popitem(last=False)
            self._state.pop(old_beacon, None)
            for topic in old:
                self.client.drop_state(topic)
            self.forgotten += 1

    def beacon_gone(self, beacon: str) -> None:
        """The tracker let the beacon go (idle or evicted): Home Assistant shows ``not_home``."""
        if self._state.pop(beacon, None) is not None:
            self.client.set_state(self.state_topic(beacon), NOT_HOME)

    def health(self, summary: dict[str, Any]) -> None:
        """The gateway's counters (retained). ``mqtt`` (this client's counters) is added."""
        body = dict(summary)
        body["mqtt"] = self.client.summary()
        self.client.set_state(self.health_topic, _json(_plain(body)))

    def anchor_status(self, anchor_id: int, status: dict[str, Any]) -> None:
        body = {"anchor": int(anchor_id), **status}
        self.client.set_state(self.anchor_topic(anchor_id), _json(_plain(body)))


def _json(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _plain(obj: Any) -> Any:
    """Counters as JSON values: numpy scalars to numbers, sets and tuples to lists, keys to
    strings, NaN and infinities to null (JSON has none)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [_plain(v) for v in sorted(obj)]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return str(obj)
