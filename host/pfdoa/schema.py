"""The site file's schema: every table and key, in one declarative table (:data:`KEYS`).

Each row says a key's table, name, type, range (``min``/``max``, or ``choices``), default,
unit, whether it is required and whether its table is an array of tables (``[[floors]]``),
with a one-line doc. The validators (:mod:`pfdoa.site`, :mod:`pfdoa.readings.config`,
:mod:`pfdoa.gateway.beacons`, :mod:`pfdoa.mqtt.config`, :mod:`pfdoa.gateway.inputs.espresense`,
:mod:`pfdoa.ros2.config`, :mod:`pfdoa.rooms`, :mod:`pfdoa.radiomap`,
:mod:`pfdoa.estimators.common`) take types, ranges, defaults and the known keys from here
(:func:`check_value`, :func:`check_table`, :func:`check_keys`); what only a module can judge
(a polygon is simple, a floor's anchors, a key file's mode) stays with that module. A bad
value is one :class:`~pfdoa.errors.ConfigError` line naming ``table.key``, the value and
what is allowed (exit status 2).

From the same rows, ``python -m pfdoa.schema`` writes ``docs/site-file.md`` and
``examples/site.full.toml`` (``--check``: exit 1 when either is stale).

**Ranges stated once.** A range here is what a site file may say; where an estimator models
less, the row's ``modelled`` range says so and loading notes it once
(:func:`modelled_notes`). ``radio.path_loss_exponent`` accepts 0.5-10 (a fit of a
reflective room or a near field can fall below 2, and ``pfdoa calibrate`` holds a lower fit
at 0.5); pf-doa models 1.6-8.0 (pfdoa.estimators.pf_model.MIN_EXPONENT: below, it keeps 1.6
and weights the path-loss evidence by fit / 1.6), the other methods use the value as given.

This module is low in the layers: it imports nothing of the gateway or the estimators
(they import it).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

from pfdoa.errors import ConfigError
from pfdoa.protocol import defs

log = logging.getLogger(__name__)

SCALARS = ("float", "int", "bool", "string", "string list")  # types checked here; others by their owner


@dataclass(frozen=True)
class Key:
    """One key of the site file."""

    table: str
    key: str
    type: str  # one of SCALARS, or a shape its owner checks (e.g. "[x, y, yaw]")
    doc: str
    default: Any = None  # the value when absent (None with `required`, or with `default_doc`)
    unit: str = ""
    min: float | None = None
    max: float | None = None
    min_open: bool = False  # the minimum itself is not allowed
    choices: tuple[str, ...] = ()
    required: bool = False
    array: bool = False  # the table is an array of tables ([[table]])
    kinds: tuple[str, ...] = ()  # [[beacons]]: the entry kinds the key belongs to (() = every kind)
    default_doc: str = ""  # a default computed from other keys (the text the docs show)
    example: Any = None  # the value examples/site.full.toml shows (None: the default)
    commented: str = ""  # why examples/site.full.toml shows the key commented out ("": it is set)
    modelled: tuple[float, float] | None = None  # what pf-doa models of the range (a note beyond)
    modelled_doc: tuple[str, str] = ("", "")  # what pf-doa does with a value below, above `modelled`

    @property
    def name(self) -> str:
        return f"{self.table}.{self.key}"

    def range_text(self) -> str:
        """What is allowed, as the error messages and the docs say it."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.min is None and self.max is None:
            return ""
        if self.type == "int":
            return f"{_num(self.min)}..{_num(self.max)}"
        return f"{'(' if self.min_open else '['}{_num(self.min)}, {_num(self.max)}]"


def _num(v: float | None) -> str:
    if v is None:
        return ""
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v)) if abs(v) >= 1e6 else f"{v:g}"
    return f"{v:g}" if isinstance(v, float) else str(v)


_SEQ = ("pfdoa", "pfdoa_auth")
_NO_SEQ = ("ibeacon", "eddystone_uid", "altbeacon", "mac48", "mac64")
BEACON_KINDS = _SEQ + _NO_SEQ
MAX_HEIGHT_M = 1000.0  # anchor z, target heights: a building's floors, not a mountain
MAX_COORDINATE_M = 1e7  # |x|, |y| of a site frame: a projected map's metres (UTM) fit
SITE_ANCHOR_ID_MAX = 2**31 - 1  # any id a recorded dataset may use; our frames narrow it (site.require_wire_ids)
_TAU = 2.0 * math.pi


def _k(table: str, key: str, type_: str, doc: str, default: Any = None, **kw: Any) -> Key:
    return Key(table, key, type_, doc, default, **kw)


def _b(key: str, type_: str, doc: str, default: Any = None, **kw: Any) -> Key:
    return Key("beacons", key, type_, doc, default, array=True, **kw)


KEYS: tuple[Key, ...] = (
    # [site]
    _k("site", "name", "string", "the site's name", default_doc="the site file's folder name",
       example="example-lab"),
    _k("site", "area", "[xmin, ymin, xmax, ymax]", "where the target can be (each side > 0 and at most 10 km); no "
       "wider: with anchors on a circle, or at the midpoints of a room's walls, a point and its mirror "
       "image beyond them give the same RSS differences", unit="m",
       default_doc="the anchors' box and the estimator's margin", example=[-0.5, -0.5, 2.84, 2.25]),
    _k("site", "target_z", "float", "the beacon's height (anchor z minus this is each anchor's height above it; "
       "with [[floors]], its height on the lowest floor)", 0.0, unit="m", min=-MAX_HEIGHT_M, max=MAX_HEIGHT_M,
       example=0.0),
    _k("site", "map_pose", "[x, y, yaw]", "where the site frame lies in the robot's map: origin (m, within 100 km) "
       "and x axis (rad, within +-2 pi)", unit="m, m, rad", default_doc="none: the site frame is the map", example=[0.0, 0.0, 0.0],
       commented="with it, the commands need --frame-id NAME (the positions are in the site frame, not map)"),
    # [radio]
    _k("radio", "rssi_at_1m_dbm", "float", "RSSI 1 m from an anchor (the path-loss model's A)", unit="dBm",
       min=-150.0, max=30.0, required=True, example=-39.0),
    _k("radio", "path_loss_exponent", "float", "the path-loss exponent n (RSSI falls 10 n dB per decade of "
       "distance); pf-doa models 1.6-8.0 (loading notes it beyond)", min=0.5, max=10.0, required=True,
       modelled=(1.6, 8.0), modelled_doc=(
           "it keeps 1.6 (each particle its own exponent around it) and weights the path-loss evidence by n / 1.6",
           "it uses 8.0"),
       example=2.0),
    # [[anchors]]
    _k("anchors", "id", "int", f"the anchor's id (our frames carry 0..{defs.ANCHOR_ID_MAX}; recorded traces any)", min=0,
       max=SITE_ANCHOR_ID_MAX, required=True, array=True, example=0),
    _k("anchors", "x", "float", "position in the site frame", unit="m", min=-MAX_COORDINATE_M, max=MAX_COORDINATE_M,
       required=True, array=True, example=0.0),
    _k("anchors", "y", "float", "position in the site frame", unit="m", min=-MAX_COORDINATE_M, max=MAX_COORDINATE_M,
       required=True, array=True, example=0.0),
    _k("anchors", "z", "float", "the anchor's height", 0.0, unit="m", min=-MAX_HEIGHT_M, max=MAX_HEIGHT_M,
       array=True, example=0.0),
    _k("anchors", "rssi_offset_db", "float", "added to the model's RSSI for this anchor (its receiver's bias; "
       "pfdoa calibrate fits it; pfdoa anchors apply sends -128..127.996 dB)", 0.0, unit="dB", array=True),
    _k("anchors", "name", "string", "a label, kept when the file is written back", "", array=True, example="corner"),
    # [estimator]: pfdoa.estimators.common.OPTION_CHECKS builds its checks from these rows
    _k("estimator", "method", "string", "the estimator (pfdoa replay --method overrides it; the names: "
       "pfdoa replay --help)", "pf-doa"),
    _k("estimator", "particles", "int", "number of particles", min=1, max=1_000_000, default_doc="the method's",
       example=2000),
    _k("estimator", "history", "int", "pf-doa-paper: DOA observations in the weight product (M)", min=1, max=1000,
       default_doc="the method's", example=5),
    _k("estimator", "window", "int", "pf-doa-paper: DOA smoothing window (k)", min=1, max=1000,
       default_doc="the method's", example=3),
    _k("estimator", "sigma_doa", "float", "DOA error, 1 sigma", unit="rad", min=0.0, max=_TAU, min_open=True,
       default_doc="the method's", example=0.5),
    _k("estimator", "sigma_rss", "float", "RSS noise scale (pf-doa: its online estimate's start)", unit="dB",
       min=0.0, max=100.0, min_open=True, default_doc="the method's", example=4.0),
    _k("estimator", "estimate", "string", "pf-doa-paper: the max-weight particle (the paper) or the weighted mean",
       choices=("max", "mean"), default_doc="the method's", example="mean"),
    _k("estimator", "resolution", "float", "grid cell size (grid methods)", unit="m", min=0.0, max=100.0,
       min_open=True, default_doc="the method's", example=0.1),
    _k("estimator", "speed", "float", "process noise of the random walk per second", unit="m/s", min=0.0,
       max=100.0, default_doc="the method's", example=0.5),
    _k("estimator", "margin", "float", "added around the anchors' box where there is no [site] area", unit="m",
       min=0.0, max=1000.0, default_doc="5 % of the anchors' box", example=0.5),
    _k("estimator", "odometry_noise", "float", "odometry error, a fraction of each increment (1 sigma)", min=0.0,
       max=10.0, default_doc="the method's", example=0.1),
    _k("estimator", "resample_threshold", "float", "resample when the effective sample size < this x N", min=0.0,
       max=1.0, default_doc="the method's", example=0.5),
    _k("estimator", "iterations", "int", "trilateration: Gauss-Newton/LM iterations", min=1, max=1000,
       default_doc="the method's", example=20),
    _k("estimator", "min_anchors", "int", "fewer anchors heard: no measurement update", min=3, max=1000,
       default_doc="the method's", example=3),
    _k("estimator", "jump_probability", "float", "per observation: the target left the cloud", min=0.0, max=1.0,
       min_open=True, default_doc="the method's", example=0.01),
    _k("estimator", "speed_range", "float", "each particle's speed log-uniform in [speed / r, speed x r]", min=1.0,
       max=1000.0, default_doc="the method's", example=3.0),
    _k("estimator", "velocity_time", "float", "correlation time of the velocity state (0 = random walk)", unit="s",
       min=0.0, max=1e6, default_doc="the method's", example=2.0),
    _k("estimator", "leap_rate", "float", "pf-doa without odometry: rate at which a particle leaps (0 = never)",
       unit="1/s", min=0.0, max=100.0, default_doc="the method's", example=0.05),
    _k("estimator", "leap_m", "float", "pf-doa: a leap's displacement, 1 sigma per axis", unit="m", min=0.0,
       max=1000.0, default_doc="the method's", example=1.0),
    _k("estimator", "radio_map", "bool", "pf-doa: add the site's [radio_map] to the model RSSI",
       default_doc="the method's", example=True),
    # [gateway]
    _k("gateway", "mode", "string", "group reports by beacon sequence (seq) or by time window", "seq",
       choices=("seq", "window")),
    _k("gateway", "set_timeout_s", "float", "emit an incomplete set this long after its first report", 0.25,
       unit="s", min=0.001, max=3600.0),
    _k("gateway", "window_s", "float", "window length in window mode", 1.0, unit="s", min=0.001, max=3600.0),
    _k("gateway", "max_open_sets", "int", "open sets kept at most; the oldest is emitted early beyond", 64,
       min=1, max=65536),
    _k("gateway", "stale_after_s", "float", "an anchor silent this long is reported stale", 3.0, unit="s",
       min=0.01, max=86400.0),
    _k("gateway", "health_interval_s", "float", "period of the health line on stderr (0 = never)", 5.0, unit="s",
       min=0.0, max=86400.0),
    _k("gateway", "serial_baud", "int", "for serial ports given without a baud rate", 115200, unit="baud",
       min=50, max=20_000_000),
    _k("gateway", "reconnect_min_s", "float", "backoff when a serial port disappears ...", 0.5, unit="s",
       min=0.001, max=3600.0),
    _k("gateway", "reconnect_max_s", "float", "... doubling up to this (>= reconnect_min_s)", 8.0, unit="s",
       min=0.001, max=3600.0),
    _k("gateway", "queue_size", "int", "chunks (<= 4 KiB each) queued from the transports (a live device's excess "
       "is dropped, counted)", 1024, min=16, max=10_000_000),
    _k("gateway", "odom_wait_s", "float", "a set waits at most this long for the odometry up to its time", 0.25,
       unit="s", min=0.0, max=60.0),
    # [output]
    _k("output", "format", "string", "the estimates' format", "jsonl", choices=("jsonl", "csv")),
    _k("output", "path", "string", "where the estimates go (- = standard output)", "-"),
    # [beacons]: the table of limits (ESPresense and named beacons)
    _k("beacons", "max_beacons", "int", "beacons tracked at once; beyond, the least recently heard is let go", 32,
       min=1, max=100_000),
    _k("beacons", "idle_timeout_s", "float", "a beacon silent this long is let go", 60.0, unit="s", min=0.1,
       max=86400.0),
    # [[beacons]]: the beacons the anchors listen to, one per filter table entry (instead of the table above)
    _b("name", "string", "the output's beacon field (1 to 64 printable characters)", default_doc="b<index>; "
       "anchors for kind anchors", example="robot1"),
    _b("kind", "string", "what the entry is: a beacon kind, or anchors (the anchors hear each other: live "
       "calibration)", choices=BEACON_KINDS + ("anchors",), required=True, example="pfdoa"),
    _b("index", "int", "the anchors' filter table entry", min=0, max=defs.BEACON_SLOTS - 1,
       default_doc="its place in the list; the last for kind anchors", example=0),
    _b("odometry", "bool", "the robot's odometry belongs to this beacon (one at most)", False, kinds=BEACON_KINDS,
       default_doc="the first entry's", example=True),
    _b("target_z", "float", "this beacon's height, in place of [site] target_z", unit="m", min=-MAX_HEIGHT_M,
       max=MAX_HEIGHT_M, kinds=BEACON_KINDS, default_doc="[site] target_z", example=1.0),
    _b("id", "int", "our beacon's id byte", defs.FILTER_DEFAULT_ID, min=0, max=255, kinds=("pfdoa",)),
    _b("key_file", "string", "the beacon's secret key, a file of its own (mode 0600; relative to the site file; "
       "pfdoa anchors keygen writes one)", required=True, kinds=("pfdoa_auth",), example="robot2.key"),
    _b("uuid", "string", "the iBeacon's proximity UUID", required=True, kinds=("ibeacon",),
       example="f7826da6-4fa2-4e98-8024-bc5b71e0893e"),
    _b("major", "int", "the iBeacon's major", min=0, max=0xFFFF, required=True, kinds=("ibeacon",), example=1),
    _b("minor", "int", "the iBeacon's minor", min=0, max=0xFFFF, required=True, kinds=("ibeacon",), example=2),
    _b("namespace", "string", "the Eddystone-UID namespace (20 hex digits)", required=True, kinds=("eddystone_uid",),
       example="00112233445566778899"),
    _b("instance", "string", "the Eddystone-UID instance (12 hex digits)", required=True, kinds=("eddystone_uid",),
       example="aabbccddeeff"),
    _b("beacon_id", "string", "the AltBeacon's beacon id (40 hex digits)", required=True, kinds=("altbeacon",),
       example="00112233445566778899aabbccddeeff00010002"),
    _b("address", "string", "the device address (MAC-48 or 64-bit, hex)", required=True, kinds=("mac48", "mac64"),
       example="aa:bb:cc:dd:ee:ff"),
    _b("period_ms", "int", "the anchor's event window for it", 100, unit="ms", min=defs.FILTER_PERIOD_MIN,
       max=defs.FILTER_PERIOD_MAX, kinds=_NO_SEQ),
    _b("window_s", "float", "the gateway's grouping window", unit="s", min=0.001, max=3600.0, kinds=_NO_SEQ,
       default_doc="period_ms / 1000", example=0.1),
    _b("period_ms", "int", "the anchors' own advertisement period", 1000, unit="ms", min=defs.FILTER_PERIOD_MIN,
       max=defs.FILTER_PERIOD_MAX, kinds=("anchors",)),
    _b("refit_s", "float", "the gateway's live refit period", 60.0, unit="s", min=1.0, max=86400.0,
       kinds=("anchors",)),
    _b("apply", "bool", "use the live fit for the estimates (false: only report it)", True, kinds=("anchors",)),
    # [mqtt]
    _k("mqtt", "url", "string", "mqtt[s]://[user@]host[:port]/prefix (no password here; --mqtt overrides it)", "",
       example=""),
    _k("mqtt", "ca_file", "string", "mqtts: CA bundle to verify the broker (\"\" = the system's)", ""),
    _k("mqtt", "client_id", "string", "the client id (\"\" = pfdoa-<random>)", ""),
    _k("mqtt", "keepalive_s", "int", "MQTT keepalive", 30, unit="s", min=5, max=3600),
    _k("mqtt", "clean_session", "bool", "start a clean session", True),
    _k("mqtt", "reconnect_min_s", "float", "backoff while the broker is away ...", 0.5, unit="s", min=0.01,
       max=3600.0),
    _k("mqtt", "reconnect_max_s", "float", "... doubling up to this (>= reconnect_min_s)", 30.0, unit="s",
       min=0.01, max=3600.0),
    _k("mqtt", "queue_size", "int", "estimates held while the broker is away (oldest dropped beyond, counted)",
       10000, min=1, max=10_000_000),
    _k("mqtt", "inflight", "int", "QoS 1 messages on the wire before their acknowledgement", 64, min=1, max=65535),
    _k("mqtt", "node_id", "string", "this gateway's name in Home Assistant discovery", "pfdoa"),
    _k("mqtt", "discovery", "bool", "Home Assistant MQTT discovery", True),
    _k("mqtt", "discovery_prefix", "string", "Home Assistant's discovery topic prefix", "homeassistant"),
    _k("mqtt", "retain_pose", "bool", "retain the latest pose of each beacon", False),
    _k("mqtt", "expire_after_s", "int", "Home Assistant sensors go unavailable after this silence (0 = never)", 0,
       unit="s", min=0, max=86400 * 7),
    _k("mqtt", "inputs", "string list", "subscribe: frames (our frames), espresense (see [espresense])", [],
       choices=("frames", "espresense")),
    _k("mqtt", "frames_topic", "string", "where our frames are subscribed (\"\" = <prefix>/anchors/+/frames)", ""),
    # [espresense]
    _k("espresense", "rooms", "{ ROOM = ANCHOR_ID }", "ESPresense room (as in the topic) -> the site's anchor id",
       required=True, example={"kitchen": 0, "hall": 1, "office": 2, "den": 3}),
    _k("espresense", "topic_prefix", "string", "the ESPresense topics' prefix", "espresense"),
    _k("espresense", "devices", "string list", "fnmatch patterns of device ids to track ([] = every device)", [],
       example=["iBeacon:*"]),
    _k("espresense", "normalize_1m", "bool", "shift each RSSI by radio.rssi_at_1m_dbm - the device's rssi@1m", True),
    _k("espresense", "time_field", "string", "\"\" = receive time; else a message key holding seconds", ""),
    # [ros2]
    _k("ros2", "domain_id", "int", "ROS_DOMAIN_ID (when absent: $ROS_DOMAIN_ID, else 0)", 0, min=0, max=232),
    _k("ros2", "namespace", "string", "prefix of the relative topics (\"/robot1\": /robot1/pfdoa/pose)", ""),
    _k("ros2", "odom_topic", "string", "nav_msgs/msg/Odometry to subscribe to (\"\" = none)", "odom"),
    _k("ros2", "odom_reliability", "string", "the odometry subscription's QoS", "best_effort",
       choices=("reliable", "best_effort")),
    _k("ros2", "pose_reliability", "string", "/pfdoa/pose's QoS", "reliable", choices=("reliable", "best_effort")),
    _k("ros2", "pose_depth", "int", "keep-last depth of /pfdoa/pose", 10, min=1, max=1000),
    # [radio_map]: pfdoa calibrate writes it (pfdoa.radiomap)
    _k("radio_map", "trust", "float", "share of the map's in-sample fit it kept on passes it had not seen",
       min=0.0, max=1.0, required=True, example=0.5),
    _k("radio_map", "length_m", "float", "the kernel length", unit="m", min=0.05, max=20.0, required=True,
       example=1.0),
    _k("radio_map", "prior_windows", "float", "windows' worth of residual 0 at every point", min=0.01, max=1e4,
       required=True, example=5.0),
    _k("radio_map", "anchors", "[ANCHOR_ID, ...]", "the anchors of the rows below (distinct ids of this site)",
       required=True, example=[0, 1, 2, 3]),
    _k("radio_map", "x", "[float, ...]", "the cells' x (within 100 km)", unit="m", required=True,
       example=[0.5, 1.5]),
    _k("radio_map", "y", "[float, ...]", "the cells' y, one per x", unit="m", required=True, example=[0.5, 1.0]),
    _k("radio_map", "residual_db", "[[float, ...], ...]", "per anchor, per cell: the mean residual (within "
       "+-100 dB)", unit="dB", required=True, example=[[1.0, -1.0], [0.0, 0.5], [-0.5, 0.0], [0.0, 0.0]]),
    _k("radio_map", "count", "[[int, ...], ...]", "per anchor, per cell: the windows binned there", required=True,
       example=[[3, 2], [3, 2], [3, 2], [3, 2]]),
    # [[floors]], [[rooms]] (pfdoa.rooms)
    _k("floors", "name", "string", "the floor's name (1 to 64 printable characters, unique)", required=True,
       array=True, example="ground"),
    _k("floors", "z", "[zmin, zmax]", "the floor's heights: an anchor whose z is in [zmin, zmax) is on it",
       unit="m", required=True, array=True, example=[-1.0, 3.0]),
    _k("floors", "target_z", "float", "the beacon's height on this floor (its estimates use this floor's anchors, "
       "their heights above it)", unit="m", min=-MAX_HEIGHT_M, max=MAX_HEIGHT_M, array=True,
       default_doc="[site] target_z + zmin - the lowest floor's zmin", example=0.0),
    _k("rooms", "name", "string", "the room's name (1 to 64 printable characters, unique)", required=True,
       array=True, example="lab"),
    _k("rooms", "floor", "string", "its [[floors]] name: required with floors, absent without", array=True,
       default_doc="none (required with [[floors]])", example="ground"),
    _k("rooms", "polygon", "[[x, y], ...]", "the room's corners in order around it (3 to 128, a simple polygon)",
       unit="m", required=True, array=True,
       example=[[-0.5, -0.5], [2.84, -0.5], [2.84, 2.25], [-0.5, 2.25]]),
)

# The tables in the order of the docs, with what each is for.
TABLES: dict[str, str] = {
    "site": "the site itself (optional)",
    "radio": "the path-loss model (required)",
    "anchors": "the anchors, one [[anchors]] entry each (at least 3, not all on a line)",
    "estimator": "the estimator and its options (optional; an option only other methods use is ignored)",
    "gateway": "reassembly and the gateway's inputs (optional; pfdoa gateway and replay)",
    "output": "where the estimates go (optional; the command line overrides it)",
    "beacons": "limits on the beacons tracked at once (ESPresense, named beacons; optional)",
    "mqtt": "the MQTT broker (optional; pfdoa gateway --mqtt)",
    "espresense": "ESPresense nodes as anchors (optional; --input mqtt:espresense)",
    "ros2": "the ROS 2 graph (optional; pfdoa gateway --ros2)",
    "radio_map": "the radio map pfdoa calibrate fits (optional; written, not hand-made)",
    "floors": "the building's floors (optional)",
    "rooms": "the rooms (optional; on a floor when there are floors)",
}
# [beacons] is either the table above or this array (one form per site file).
ARRAY_FORM = {"beacons": "instead of the [beacons] table: the beacons the anchors listen to, one entry per filter "
                         "table entry (at most 4), each kind with its own keys; kind anchors is the anchors' own entry "
                         "(live calibration)"}
ARRAY_TABLES = ("anchors", "floors", "rooms")  # always arrays of tables; [beacons] may be either
TOP_LEVEL = tuple(TABLES)


def keys_of(table: str, *, array: bool | None = None, kind: str | None = None) -> tuple[Key, ...]:
    """The rows of ``table`` (``array``: only the array form's or the table form's; ``kind``:
    a [[beacons]] entry's kind, its keys only)."""
    rows = (k for k in KEYS if k.table == table and (array is None or k.array == array))
    if kind is not None:
        rows = (k for k in rows if not k.kinds or kind in k.kinds)
    return tuple(rows)


def names_of(table: str, *, array: bool | None = None, kind: str | None = None) -> tuple[str, ...]:
    return tuple(dict.fromkeys(k.key for k in keys_of(table, array=array, kind=kind)))


def row(table: str, key: str, *, array: bool | None = None, kind: str | None = None) -> Key:
    """The row of ``table.key`` (KeyError when there is none)."""
    for k in keys_of(table, array=array, kind=kind):
        if k.key == key:
            return k
    raise KeyError(f"{table}.{key}")


def defaults(table: str, *, array: bool | None = None, kind: str | None = None) -> dict[str, Any]:
    """The defaults of a table's optional keys that have one."""
    return {k.key: (tuple(k.default) if isinstance(k.default, list) else k.default)
            for k in keys_of(table, array=array, kind=kind)
            if not k.required and not k.default_doc and k.default is not None}


def short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def check_value(source: str, where: str, spec: Key, value: Any) -> Any:
    """``value`` of ``spec``'s key checked and converted (ints stay ints, numbers of a float key
    become floats); ConfigError naming ``where`` otherwise. Shapes that are not SCALARS pass
    through: their owner checks them."""
    t = spec.type
    if t == "bool":
        if not isinstance(value, bool):
            raise ConfigError(source, where, f"must be true or false, got {short(value)}")
        return value
    if t == "string":
        if not isinstance(value, str):
            raise ConfigError(source, where, f"must be a string, got {type(value).__name__} {short(value)}")
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:  # a lone surrogate: not writable as TOML
            raise ConfigError(source, where, "must be valid Unicode text") from None
        if spec.choices and value not in spec.choices:
            raise ConfigError(source, where, f"must be one of {', '.join(spec.choices)}, got {short(value)}")
        return value
    if t == "string list":
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise ConfigError(source, where, f"must be a list of strings, got {short(value)}")
        for x in value:
            if spec.choices and x not in spec.choices:
                raise ConfigError(source, where, f"unknown entry {x!r} (known: {', '.join(spec.choices)})")
        return tuple(dict.fromkeys(value))  # a name listed twice means it once
    if t not in ("int", "float"):
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(source, where, f"must be a number, got {type(value).__name__} {short(value)}")
    if t == "int" and not isinstance(value, int):
        raise ConfigError(source, where, f"must be an integer, got {type(value).__name__} {short(value)}")
    try:
        f = float(value)
    except OverflowError:  # a TOML integer beyond float range
        f = math.inf
    if not math.isfinite(f):
        if t == "int":  # an integer beyond any range: say the range
            raise ConfigError(source, where, f"must be in {spec.range_text()}, got {short(value)}")
        raise ConfigError(source, where, f"must be a finite number, got {short(value)}")
    lo, hi = spec.min, spec.max
    if (lo is not None and (f < lo or (spec.min_open and f == lo))) or (hi is not None and f > hi):
        unit = f" {spec.unit}" if spec.unit else ""
        raise ConfigError(source, where, f"must be in {spec.range_text()}{unit}, got {short(value)}")
    return value if t == "int" else f


def check_keys(source: str, where: str, entry: Mapping[str, Any], known: Iterable[str], what: str = "") -> None:
    """ConfigError naming the first key of ``entry`` not in ``known`` (``what``: whose keys,
    e.g. "for a pfdoa beacon")."""
    known = tuple(known)
    for key in entry:
        if key not in known:
            raise ConfigError(source, f"{where}.{key}", f"unknown key{' ' + what if what else ''} "
                              f"(known: {', '.join(known)})")


def check_table(source: str, section: str, table: Any,
                special: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A plain table ``[section]`` (None: absent): every key known, checked by its row (or by
    ``special[key](where, value)``), the defaults filled in. ConfigError naming the key."""
    values = defaults(section, array=False)
    if table is None:
        return values
    if not isinstance(table, dict):
        raise ConfigError(source, section, f"must be a table ([{section}])")
    rows = {k.key: k for k in keys_of(section, array=False)}
    check_keys(source, section, table, rows)
    for key, v in table.items():
        where = f"{section}.{key}"
        values[key] = special[key](where, v) if special and key in special else check_value(source, where,
                                                                                            rows[key], v)
    return values


def required(source: str, where: str, entry: Mapping[str, Any], rows: Iterable[Key]) -> None:
    """ConfigError naming the first required key of ``rows`` missing from ``entry``."""
    for k in rows:
        if k.required and k.key not in entry:
            raise ConfigError(source, f"{where}.{k.key}", "missing key")


_noted: set[tuple[str, str]] = set()


def modelled_notes(source: str, table: str, values: Mapping[str, Any]) -> None:
    """One note per key and source (a file loaded again stays quiet) where a value is
    allowed but beyond what pf-doa models (a row's ``modelled``). A note, not a warning:
    the filter handles such a value by design (a calibrated room whose RSS barely follows
    distance, the shipped example), and a user's first command should not look broken."""
    for k in keys_of(table):
        v = values.get(k.key)
        if k.modelled is None or not isinstance(v, (int, float)) or (source, k.name) in _noted:
            continue
        lo, hi = k.modelled
        if not lo <= v <= hi:
            _noted.add((source, k.name))
            below = v < lo
            log.info("%s: %s = %g is %s what pf-doa models (%g-%g): %s (docs/site-file.md)", source, k.name, v,
                     "below" if below else "above", lo, hi, k.modelled_doc[0 if below else 1])


# -- generated documents ----------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[2]
DOC_PATH = ROOT / "docs" / "site-file.md"
EXAMPLE_PATH = ROOT / "examples" / "site.full.toml"
GENERATED = "Generated by `python -m pfdoa.schema` from host/pfdoa/schema.py. Do not edit."


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    raise ValueError(f"no TOML for {type(v).__name__}")


def _default_text(k: Key) -> str:
    if k.required:
        return "required"
    if k.default_doc:
        return k.default_doc
    return f"`{_toml(k.default)}`"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|")


def render_markdown() -> str:
    out = [
        "# The site file, key by key",
        "",
        f"<!-- {GENERATED} -->",
        "",
        "Every table and key a site file may hold (`--config SITE.toml` of `pfdoa gateway`, `replay`,",
        "`calibrate`, `anchors`). Unknown tables and keys, wrong types and values out of range are one",
        "error line naming `table.key`, the value and what is allowed (exit status 2). A commented file",
        "with every key: [examples/site.full.toml](../examples/site.full.toml). Ranges are stated once,",
        "here: where pf-doa models less than the file may say, the row says what it does (and loading",
        "the site notes it once, at INFO). `radio.path_loss_exponent` accepts 0.5-10; pf-doa models 1.6-8.0 and, for",
        "a site below 1.6, keeps 1.6 and weights the path-loss evidence by n / 1.6; the other methods",
        "use the value as given.",
        "",
    ]
    for table, what in TABLES.items():
        for array in (False, True):
            rows = keys_of(table, array=array)
            if not rows:
                continue
            head = f"[[{table}]]" if array else f"[{table}]"
            text = ARRAY_FORM.get(table, what) if array else what
            out += [f"## `{head}`", "", f"{text[0].upper()}{text[1:]}.", ""]
            with_kinds = any(k.kinds for k in rows)
            out.append("| key | type | range | default | unit | " + ("kinds | " if with_kinds else "") + "doc |")
            out.append("|---|---|---|---|---|" + ("---|" if with_kinds else "") + "---|")
            for k in rows:
                cells = [f"`{k.key}`", _md_cell(k.type), _md_cell(k.range_text()), _md_cell(_default_text(k)),
                         k.unit]
                if with_kinds:
                    cells.append("every" if not k.kinds else "every beacon kind" if k.kinds == BEACON_KINDS
                                 else ", ".join(k.kinds))
                cells.append(_md_cell(k.doc))
                out.append("| " + " | ".join(cells) + " |")
            out.append("")
    return "\n".join(out)


def _example(k: Key) -> Any:
    return k.example if k.example is not None else k.default


def _toml_rows(rows: Iterable[Key], comment_out: bool = False) -> list[str]:
    out = []
    for k in rows:
        bits = [k.doc]
        if k.unit:
            bits.append(k.unit)
        if k.range_text():
            bits.append(k.range_text())
        bits.append("required" if k.required else f"default {_default_text(k).strip('`')}")
        if k.kinds and k.kinds != BEACON_KINDS:
            bits.append("kind " + " or ".join(k.kinds))
        out += textwrap.wrap(f"{k.key}: " + "; ".join(bits), 100, initial_indent="# ", subsequent_indent="#   ")
        if k.commented:
            out.append(f"# ({k.commented})")
        out.append(("# " if comment_out or k.commented else "") + f"{k.key} = {_toml(_example(k))}")
    return out


# The example's anchors (the robot traces' site, examples/site.toml): four corners.
_EXAMPLE_ANCHORS = ((0, 0.0, 0.0), (1, 0.0, 1.75), (2, 2.34, 1.75), (3, 2.34, 0.0))


def render_toml() -> str:
    """examples/site.full.toml: every key with its doc and a valid value; the [[beacons]]
    array (an alternative to the [beacons] table) commented out."""
    out = [f"# {GENERATED}", "#",
           "# Every key of a site file with its doc, unit, range and default (docs/site-file.md), for the",
           "# robot traces' site (examples/run.csv). The values are valid, not calibrated: examples/site.toml",
           "# holds this site's radio values. `pfdoa replay examples/run.csv --config examples/site.full.toml`",
           "# runs with it.", ""]
    for table, what in TABLES.items():
        out.append(f"# -- {table}: {what}")
        if table == "anchors":
            first = True
            for aid, x, y in _EXAMPLE_ANCHORS:
                out.append("[[anchors]]")
                vals = {"id": aid, "x": x, "y": y}
                rows = keys_of("anchors")
                if first:
                    body = _toml_rows(rows)
                    out += [ln if ln.startswith("#") or ln.split(" = ")[0] not in vals
                            else f"{ln.split(' = ')[0]} = {_toml(vals[ln.split(' = ')[0]])}" for ln in body]
                    first = False
                else:
                    out += [f"{k} = {_toml(v)}" for k, v in vals.items()]
                out.append("")
            continue
        plain, arr = keys_of(table, array=False), keys_of(table, array=True)
        if plain:
            out.append(f"[{table}]")
            out += _toml_rows(plain)
            out.append("")
        if arr and table == "beacons":
            out += textwrap.wrap(f"{ARRAY_FORM[table][0].upper()}{ARRAY_FORM[table][1:]}: every key shown, each kind "
                                 "takes its own (docs/site-file.md).", 100, initial_indent="# ", subsequent_indent="# ")
            out.append("# [[beacons]]")
            out += _toml_rows(arr, comment_out=True)
            out.append("")
        elif arr:
            out.append(f"[[{table}]]")
            out += _toml_rows(arr)
            out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pfdoa.schema",
                                 description="write docs/site-file.md and examples/site.full.toml from the schema")
    ap.add_argument("--check", action="store_true", help="exit 1 if either file is stale (write nothing)")
    args = ap.parse_args(argv)
    stale = []
    for path, text in ((DOC_PATH, render_markdown()), (EXAMPLE_PATH, render_toml())):
        current = path.read_text(encoding="utf-8") if path.exists() else None
        if current == text:
            continue
        if args.check:
            stale.append(str(path))
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path}")
    if stale:
        print("stale: " + ", ".join(stale) + " (run python -m pfdoa.schema)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
