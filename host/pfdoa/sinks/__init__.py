"""Sinks: where the gateway's readings, records and health go besides the position output.

One module per sink behind :class:`~pfdoa.sinks.base.Sink` (python-can style), named in
:data:`SINKS` and imported only when used (``mcap`` needs the optional ``ros`` extra):

=============  ===============================================  ============================================
name           class                                            gets
=============  ===============================================  ============================================
output         :class:`~pfdoa.sinks.base.WriterSink`            records (JSON lines / CSV)
mcap           :class:`~pfdoa.sinks.mcap.McapSink`              readings, odometry, timers, records, health
web            :class:`~pfdoa.sinks.web.WebSink`                records, health, particles
health-json    :class:`~pfdoa.sinks.healthjson.HealthJsonSink`  health
readings       :class:`~pfdoa.sinks.readings.ReadingsCsvSink`   readings
mqtt           :class:`~pfdoa.sinks.mqtt.MqttSink`              records, health (an MQTT broker; ``mqtt`` extra)
ros2           :class:`~pfdoa.sinks.ros2.Ros2Sink`              records, health (live ROS 2 over DDS; ``ros2`` extra)
=============  ===============================================  ============================================

:mod:`pfdoa.sinks.options` turns the command-line options into one
:class:`~pfdoa.sinks.base.Fanout` for ``pfdoa gateway`` and ``pfdoa replay``;
:mod:`pfdoa.sinks.ros2odom` is the robot's odometry read on the ROS 2 sink's participant.
"""

from __future__ import annotations

import importlib

from pfdoa.gateway.health import HealthSampler, HealthSnapshot
from pfdoa.sinks.base import Fanout, Sink, WriterSink

SINKS = {
    "output": "pfdoa.sinks.base:WriterSink",
    "mcap": "pfdoa.sinks.mcap:McapSink",
    "web": "pfdoa.sinks.web:WebSink",
    "health-json": "pfdoa.sinks.healthjson:HealthJsonSink",
    "readings": "pfdoa.sinks.readings:ReadingsCsvSink",
    "mqtt": "pfdoa.sinks.mqtt:MqttSink",
    "ros2": "pfdoa.sinks.ros2:Ros2Sink",
}
# Optional dependencies by top-level module: the extra that installs them.
EXTRAS = {"mcap": "ros", "mcap_ros2": "ros", "cyclonedds": "ros2"}


def sink_class(name: str) -> type[Sink]:
    """The class registered as ``name``; a missing optional dependency is an InputError."""
    from pfdoa.errors import InputError

    try:
        module, cls = SINKS[name].split(":")
    except KeyError:
        raise ValueError(f"unknown sink {name!r} (known: {', '.join(SINKS)})") from None
    try:
        return getattr(importlib.import_module(module), cls)
    except ModuleNotFoundError as exc:
        extra = EXTRAS.get((exc.name or "").split(".")[0])
        if extra:
            raise InputError(f"the {name} sink needs the '{extra}' extra: pip install 'pfdoa[{extra}]' "
                             f"(missing module {exc.name})") from None
        raise


__all__ = ["Fanout", "HealthSampler", "HealthSnapshot", "SINKS", "Sink", "WriterSink", "sink_class"]
