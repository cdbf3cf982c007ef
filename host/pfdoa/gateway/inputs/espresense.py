"""ESPresense nodes as anchors: ``espresense/devices/<device-id>/<room>`` JSON -> beacon readings.

An ESPresense node (ESP32 firmware, ESPresense/ESPresense) publishes, for every device it
hears, a JSON object on ``espresense/devices/<device-id>/<room>`` (QoS 0, not retained):
``id`` (the device id, the same as the topic's), ``mac``, ``rssi`` (dBm, after the node's
``rxAdj``, filtered), ``rssi@1m`` (the device's reference RSSI at 1 m), ``rxAdj``,
``rssiVar``, ``distance``, ``var``, ``int``, ... (fields written by its
``BleFingerprint::fill``; the companion reads ``rssi``, ``rssi@1m``, ``distance``,
``var``, ``rxAdj``, ``rssiVar``, ``name`` from the same topics). ``<room>`` is the node's
room name, slugified. Messages carry no time stamp.

Each message becomes ``BeaconReading(device-id, Reading(anchor, rssi, t))``: the room is
mapped to an anchor id by the site file's ``[espresense]`` table, ``t`` is the receive
time (or, with ``time_field``, a time the publisher put in the message: the simulator
does, so results do not depend on how fast messages travel). With ``normalize_1m`` the
RSSI is shifted by ``radio.rssi_at_1m_dbm - rssi@1m``, so beacons with other transmit
powers fit the site's one radio model. Only ``rssi`` (and ``rssi@1m``) are used:
ESPresense's ``distance`` is its own path-loss inversion of the same number.

The table (``rooms`` is required)::

    [espresense]
    rooms = { kitchen = 3, hall = 4, office = 7 }   # room (as in the topic) -> anchor id
    topic_prefix = "espresense"
    devices = []             # fnmatch patterns of device ids to track ([] = every device)
    normalize_1m = true
    time_field = ""          # "" = receive time; else a key holding seconds (simulator: "t")

Rejections, counted by kind: ``oversized`` (> 2048 bytes), ``bad_topic``, ``bad_json``
(not UTF-8, not an object, too deep), ``bad_rssi`` (missing, not a number, outside
-130..20 dBm), ``bad_rssi_1m``, ``bad_time``, ``bad_device`` (id longer than 128
characters), ``unknown_room`` (per room, at most 256 rooms named), ``ignored_device``
(not matched by ``devices``: not an error, but counted).

:class:`pfdoa.gateway.inputs.mqtt.EspresenseTransport` puts the input behind the gateway's
Transport interface (``pfdoa gateway --input mqtt:espresense``).
"""

from __future__ import annotations

import fnmatch
import json
import re
from collections import Counter
from dataclasses import dataclass
from typing import Any, Mapping

from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconReading
from pfdoa.gateway.msgtime import MessageClock
from pfdoa.jsonnum import finite_number
from pfdoa.mqtt.client import MqttClient
from pfdoa.mqtt.inputs import DEFAULT_QUEUE, MqttInput
from pfdoa.mqtt.url import check_topic_prefix
from pfdoa.readings.reassembly import Reading

MAX_PAYLOAD = 2048  # a node's message is ~200 bytes
MAX_UNKNOWN_ROOMS = 256
RSSI_RANGE = (-130.0, 20.0)
MAX_TIME = 1e11  # seconds: beyond any Unix time this code will meet, and finite
_ROOM = re.compile(r"^[^/+#\x00]{1,64}$")


@dataclass(frozen=True)
class EspresenseConfig:
    rooms: Mapping[str, int]
    topic_prefix: str = "espresense"
    devices: tuple[str, ...] = ()
    normalize_1m: bool = True
    time_field: str = ""
    rssi_at_1m_dbm: float | None = None  # the site's radio model A (needed by normalize_1m)

    @property
    def topic_filter(self) -> str:
        return f"{self.topic_prefix}/devices/+/+"


def espresense_config(sections: Mapping[str, Any], source: str = "<site>", anchor_ids=None,
                      rssi_at_1m_dbm: float | None = None) -> EspresenseConfig:
    """Validate the ``[espresense]`` table; ConfigError naming the key (exit status 2).

    ``anchor_ids`` (the site's) are the ids a room may map to.
    """
    table = sections.get("espresense")
    if table is None:
        raise ConfigError(source, "espresense", "missing table [espresense] (rooms = { ROOM = ANCHOR_ID, ... })")
    if not isinstance(table, dict):
        raise ConfigError(source, "espresense", "must be a table")
    values = schema.check_table(source, "espresense", table)  # types, defaults, unknown keys
    rooms = table.get("rooms")
    if not isinstance(rooms, dict) or not rooms:
        raise ConfigError(source, "espresense.rooms", "must be a non-empty table of ROOM = ANCHOR_ID")
    ids = set(anchor_ids) if anchor_ids is not None else None
    out_rooms: dict[str, int] = {}
    for room, aid in rooms.items():
        where = f"espresense.rooms.{room}"
        if not _ROOM.match(room):
            raise ConfigError(source, where, "a room is one topic level: 1..64 characters, no / + # or NUL")
        if isinstance(aid, bool) or not isinstance(aid, int):
            raise ConfigError(source, where, f"must be an anchor id (integer), got {aid!r}")
        if ids is not None and aid not in ids:
            raise ConfigError(source, where, f"anchor {aid} is not in the site's [[anchors]]")
        if aid in out_rooms.values():
            raise ConfigError(source, where, f"anchor {aid} is already the anchor of another room")
        out_rooms[room] = aid
    prefix = values["topic_prefix"]
    try:
        check_topic_prefix(prefix)
    except ValueError as exc:
        raise ConfigError(source, "espresense.topic_prefix", str(exc)) from None
    devices = values["devices"]
    if not all(devices):
        raise ConfigError(source, "espresense.devices", f"must be a list of device id patterns, got {list(devices)!r}")
    norm, tf = values["normalize_1m"], values["time_field"]
    if norm and rssi_at_1m_dbm is None:
        raise ConfigError(source, "espresense.normalize_1m", "needs the site's radio.rssi_at_1m_dbm")
    return EspresenseConfig(rooms=out_rooms, topic_prefix=prefix, devices=tuple(devices), normalize_1m=norm,
                            time_field=tf, rssi_at_1m_dbm=rssi_at_1m_dbm)


class EspresenseParser:
    """Topic + payload -> :class:`BeaconReading` or the name of the rejection (no I/O, no threads)."""

    def __init__(self, cfg: EspresenseConfig) -> None:
        self.cfg = cfg
        self._levels = len(cfg.topic_prefix.split("/")) + 3
        self._patterns = tuple(re.compile(fnmatch.translate(p)) for p in cfg.devices)
        self.unknown_rooms: Counter[str] = Counter()
        # Per configured room: accepted readings and the time of the latest (anchor status),
        # as far as it is plausible: one device's stamp 9e10 must not make a room's
        # status say it was heard in thousands of years (pfdoa.gateway.msgtime).
        self._room_n: dict[str, int] = dict.fromkeys(cfg.rooms, 0)
        self._room_t: dict[str, MessageClock] = {room: MessageClock() for room in cfg.rooms}

    def anchor_status(self, now: float | None = None) -> dict[int, dict]:
        """Per anchor (room): readings accepted, time of the latest, its age at ``now``."""
        out = {}
        for room, aid in self.cfg.rooms.items():
            last = self._room_t[room].now
            st = {"room": room, "readings": self._room_n[room], "last_t": last}
            if now is not None:
                st["age_s"] = None if last is None else round(now - last, 3)
            out[aid] = st
        return out

    def parse(self, topic: str, payload: bytes, t: float) -> BeaconReading | str:
        cfg = self.cfg
        levels = topic.split("/")
        if len(levels) != self._levels or levels[-3] != "devices":
            return "bad_topic"
        device, room = levels[-2], levels[-1]
        anchor = cfg.rooms.get(room)
        if anchor is None:
            key = room[:64]
            if key in self.unknown_rooms or len(self.unknown_rooms) < MAX_UNKNOWN_ROOMS:
                self.unknown_rooms[key] += 1
            return "unknown_room"
        if not device or len(device) > MAX_ID_LEN:
            return "bad_device"
        if self._patterns and not any(p.match(device) for p in self._patterns):
            return "ignored_device"
        try:
            doc = json.loads(payload.decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError):
            return "bad_json"
        if not isinstance(doc, dict):
            return "bad_json"
        rssi = finite_number(doc.get("rssi"))
        if rssi is None or not RSSI_RANGE[0] <= rssi <= RSSI_RANGE[1]:
            return "bad_rssi"
        if cfg.normalize_1m and "rssi@1m" in doc:
            ref = finite_number(doc["rssi@1m"])
            if ref is None or not RSSI_RANGE[0] <= ref <= RSSI_RANGE[1]:
                return "bad_rssi_1m"
            rssi += cfg.rssi_at_1m_dbm - ref  # type: ignore[operator]
        if cfg.time_field:
            ts = finite_number(doc.get(cfg.time_field))
            if ts is None or not 0.0 <= ts <= MAX_TIME:
                return "bad_time"
            t = ts
        self._room_n[room] += 1
        self._room_t[room].admit(t)
        return BeaconReading(device, Reading(anchor, rssi, t))


class EspresenseInput(MqttInput[BeaconReading]):
    kind = "espresense"

    def __init__(self, client: MqttClient, cfg: EspresenseConfig, *, max_queue: int = DEFAULT_QUEUE,
                 qos: int = 0) -> None:
        # QoS 0 by default: what the nodes publish with; a reading late by a retry is worth little.
        super().__init__(client, cfg.topic_filter, max_payload=MAX_PAYLOAD, max_queue=max_queue, qos=qos)
        self.parser = EspresenseParser(cfg)

    def parse(self, topic: str, payload: bytes, t: float) -> BeaconReading | str:
        return self.parser.parse(topic, payload, t)

    def _more_counters(self) -> dict[str, Any]:
        return {"unknown_rooms": dict(self.parser.unknown_rooms.most_common(16))}

    def anchor_status(self, now: float | None = None) -> dict[int, dict]:
        """Per anchor (room): readings accepted, the latest one's time and age (see the parser)."""
        with self._cond:
            return self.parser.anchor_status(now)
