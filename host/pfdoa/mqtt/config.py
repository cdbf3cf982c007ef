"""The site file's optional ``[mqtt]`` table, and the settings it and the command line give.

Every key has a default (shown); the command line (``--mqtt URL``, ``--mqtt-password-file``,
``--mqtt-ca-file``) overrides the file::

    [mqtt]
    url = ""                 # mqtt[s]://[user@]host[:port]/prefix (no password here)
    ca_file = ""             # mqtts: CA bundle to verify the broker ("" = the system's)
    client_id = ""           # "" = pfdoa-<random>
    keepalive_s = 30
    clean_session = true
    reconnect_min_s = 0.5    # backoff while the broker is away ...
    reconnect_max_s = 30.0   # ... doubling up to this
    queue_size = 10000       # estimates held while the broker is away (oldest dropped beyond, counted)
    inflight = 64            # QoS 1 messages on the wire before their acknowledgement
    node_id = "pfdoa"        # this gateway's name in Home Assistant discovery
    discovery = true         # Home Assistant MQTT discovery
    discovery_prefix = "homeassistant"
    retain_pose = false      # retain the latest pose of each beacon
    expire_after_s = 0       # Home Assistant sensors go unavailable after this silence (0 = never)
    inputs = []              # subscribe: "frames" (our frames), "espresense" (see [espresense])
    frames_topic = ""        # "" = <prefix>/anchors/+/frames

Every key's type, range and default: :mod:`pfdoa.schema` (docs/site-file.md). Unknown keys,
wrong types and out-of-range values are one :class:`~pfdoa.errors.ConfigError`
line naming the key (exit status 2), like the ``[gateway]`` table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from pfdoa import schema
from pfdoa.errors import ConfigError, InputError
from pfdoa.mqtt.client import ClientConfig
from pfdoa.mqtt.publisher import PublisherConfig
from pfdoa.mqtt.url import check_credentials, check_topic_filter, check_topic_prefix, parse_url, read_password

INPUT_KINDS = schema.row("mqtt", "inputs").choices


@dataclass(frozen=True)
class MqttTable:
    url: str = ""
    ca_file: str = ""
    client_id: str = ""
    keepalive_s: int = 30
    clean_session: bool = True
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 30.0
    queue_size: int = 10000
    inflight: int = 64
    node_id: str = "pfdoa"
    discovery: bool = True
    discovery_prefix: str = "homeassistant"
    retain_pose: bool = False
    expire_after_s: int = 0
    inputs: tuple = ()
    frames_topic: str = ""


def check_table(cls, table: Any, source: str, section: str, special: Mapping[str, Any] | None = None):
    """Validate ``table`` by its rows in :mod:`pfdoa.schema` (types, ranges, choices, unknown
    keys, defaults) into dataclass ``cls``; ``special`` maps a key to ``f(where, value) ->
    converted`` for what only its owner can judge (a ROS 2 name)."""
    return cls(**schema.check_table(source, section, table, special))


def mqtt_table(sections: Mapping[str, Any], source: str = "<site>") -> MqttTable:
    """Validate the ``[mqtt]`` table (missing -> defaults)."""
    t = check_table(MqttTable, sections.get("mqtt"), source, "mqtt")
    if t.reconnect_max_s < t.reconnect_min_s:
        raise ConfigError(source, "mqtt.reconnect_max_s", "must be >= mqtt.reconnect_min_s")
    try:
        check_topic_prefix(t.discovery_prefix, "discovery prefix")
    except ValueError as exc:
        raise ConfigError(source, "mqtt.discovery_prefix", str(exc)) from None
    if t.frames_topic:
        try:
            check_topic_filter(t.frames_topic, "frames topic")
        except ValueError as exc:
            raise ConfigError(source, "mqtt.frames_topic", str(exc)) from None
    return t


@dataclass(frozen=True)
class MqttSettings:
    client: ClientConfig
    publisher: PublisherConfig
    table: MqttTable

    @property
    def frames_topic(self) -> str:
        return self.table.frames_topic or f"{self.client.url.prefix}/anchors/+/frames"


def mqtt_settings(sections: Mapping[str, Any], source: str = "<site>", url: str | None = None,
                  password_file: str | None = None, ca_file: str | None = None,
                  environ: Mapping[str, str] | None = None) -> MqttSettings | None:
    """Everything the MQTT client and publisher need; None when no broker URL is given anywhere.

    ``url``, ``password_file`` and ``ca_file`` are the command-line values (they win).
    Raises ConfigError (site file) or InputError (command line, password file).
    """
    t = mqtt_table(sections, source)
    spec = url or t.url
    if not spec:
        return None
    u = parse_url(spec, "--mqtt" if url else f"{source}: mqtt.url")
    password = read_password(password_file, dict(environ) if environ is not None else None)
    check_credentials(u, password)
    ca = ca_file or t.ca_file or None
    if ca and not u.tls:
        where = "--mqtt-ca-file" if ca_file else f"{source}: mqtt.ca_file"
        raise InputError(f"{where}: a CA file is only used with mqtts:// (the URL is {u})")
    client = ClientConfig(url=u, password=password, ca_file=ca, client_id=t.client_id, keepalive_s=t.keepalive_s,
                          clean_session=t.clean_session, reconnect_min_s=t.reconnect_min_s,
                          reconnect_max_s=t.reconnect_max_s, queue_size=t.queue_size, inflight=t.inflight)
    pub = PublisherConfig(node_id=t.node_id, discovery=t.discovery, discovery_prefix=t.discovery_prefix,
                          retain_pose=t.retain_pose, expire_after_s=t.expire_after_s)
    return MqttSettings(client, pub, t)
