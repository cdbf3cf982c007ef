"""The sinks' command-line options, shared by ``pfdoa gateway`` and ``pfdoa replay``.

A command adds the options it supports and builds one :class:`~pfdoa.sinks.base.Fanout`
from the parsed arguments, before its pipeline::

    from pfdoa.sinks import options as sink_options
    sink_options.add_arguments(p)                                  # in add_arguments
    sinks = sink_options.open_sinks(args, site, args.config, particles=..., metadata=...)   # in run
    pipe = build_pipeline(..., sinks=sinks, frame_id=args.frame_id)  # readings, records; closed with it
    Runner(..., sinks=sinks)                                         # odometry, timer marks, health

Every bad value is an :class:`~pfdoa.errors.InputError` naming the option (exit 2), raised
before anything is opened, so a bad ``--web`` does not leave an empty recording behind.
``--frame-id`` is the frame of every position (the JSON/CSV output too), so it is always
there.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from pfdoa.errors import InputError
from pfdoa.output import DEFAULT_FRAME
from pfdoa.sinks import sink_class
from pfdoa.sinks.base import Fanout, Sink, WriterSink

OPTIONS = ("record", "web", "health-json", "readings-out", "mqtt", "ros2")


def add_arguments(p: argparse.ArgumentParser, which: Iterable[str] = OPTIONS) -> None:
    which = tuple(which)
    unknown = set(which) - set(OPTIONS)
    if unknown:
        raise ValueError(f"unknown sink options: {sorted(unknown)}")
    g = p.add_argument_group("robot outputs (docs/robot.md)")
    g.add_argument("--frame-id", metavar="ID",
                   help="frame of the positions (output frame_id, recorded poses and markers; default map, "
                        "or a recording's own)")
    if "record" in which:
        g.add_argument("--record", metavar="RUN.mcap",
                       help="also write a ROS 2 recording (MCAP): poses, readings, odometry, diagnostics, "
                            "anchor markers; 'pfdoa replay RUN.mcap' reproduces its estimates "
                            "(needs pip install 'pfdoa[ros]')")
    if "web" in which:
        g.add_argument("--web", metavar="[HOST:]PORT",
                       help="serve the live view on HOST:PORT (default host 127.0.0.1; 0.0.0.0:PORT for all)")
    if "health-json" in which:
        g.add_argument("--health-json", metavar="PATH",
                       help="also write each health period as one JSON line to PATH ('-' = standard output)")
    if "readings-out" in which:
        g.add_argument("--readings-out", metavar="TRACE.csv",
                       help="also write every reading in the trace format t,anchor,rssi_dbm,seq "
                            "(for replay, calibrate and eval)")
        g.add_argument("--ground-truth", metavar="TRUTH.csv",
                       help="with --readings-out: add gt_x,gt_y interpolated from this file (columns t and "
                            "gt_x,gt_y or x,y, times on this host's clock)")
    if "ros2" in which:
        r = p.add_argument_group("ROS 2 (docs/robot.md; needs pip install 'pfdoa[ros2]')")
        r.add_argument("--ros2", action="store_true",
                       help="join the robot's ROS 2 graph over DDS: publish every estimate on pfdoa/pose "
                            "(geometry_msgs/msg/PoseWithCovarianceStamped; pfdoa/<beacon>/pose with several beacons), "
                            "the health on /diagnostics and, with [site] map_pose, the site frame on /tf_static; "
                            "subscribe to the robot's odometry ([ros2] odom_topic, default /odom) unless --odom "
                            "is given. Domain, namespace, frames and QoS: the site's [ros2] table")
    if "mqtt" in which:
        m = p.add_argument_group("MQTT broker (docs/fleet.md; needs pip install 'pfdoa[mqtt]')")
        m.add_argument("--mqtt", metavar="mqtt[s]://[USER@]HOST[:PORT]/PREFIX",
                       help="publish every estimate, health, anchor status and Home Assistant discovery there "
                            "(default: [mqtt] url); no password in the URL")
        m.add_argument("--mqtt-password-file", metavar="PATH",
                       help="the broker password is this file's first line (else $PFDOA_MQTT_PASSWORD)")
        m.add_argument("--mqtt-ca-file", metavar="PATH",
                       help="mqtts://: CA bundle that verifies the broker (default: [mqtt] ca_file, else the "
                            "system's)")
        m.add_argument("--mqtt-input", action="append", default=[], choices=("frames", "espresense"),
                       help="also read anchors from the broker (repeatable; --input mqtt:KIND; default: [mqtt] "
                            "inputs): 'frames' = "
                            "our frames as binary payloads on [mqtt] frames_topic (default PREFIX/anchors/+/frames), "
                            "one byte stream per topic; 'espresense' = ESPresense nodes' "
                            "espresense/devices/<device>/<room> JSON, rooms mapped to anchors by [espresense], "
                            "one estimator per device")


SINK_OPTIONS = {"output": "--out", "mcap": "--record", "web": "--web", "health-json": "--health-json",
                "readings": "--readings-out", "mqtt": "--mqtt", "ros2": "--ros2"}


def failed_outputs(args: argparse.Namespace, fan: Fanout | None) -> list[str]:
    """"OPTION PATH" of each sink that failed (for the command's one line; the log said why)."""
    paths = {**output_paths(args), "--web": getattr(args, "web", None), "--mqtt": getattr(args, "mqtt", None)}
    out = []
    for name in (fan.failed if fan is not None else ()):
        option = SINK_OPTIONS.get(name, name)
        where = paths.get(option)
        out.append(f"{option} {where}" if isinstance(where, str) and where else option)
    return out


def output_paths(args: argparse.Namespace) -> dict[str, str | None]:
    """The files the sink options write, by option (for the commands' input/output check)."""
    return {"--record": getattr(args, "record", None), "--health-json": getattr(args, "health_json", None),
            "--readings-out": getattr(args, "readings_out", None)}


def input_paths(args: argparse.Namespace) -> dict[str, list[str]]:
    truth = getattr(args, "ground_truth", None)
    return {"--ground-truth": [truth] if truth else [],
            **{o: [v] for o, v in (("--mqtt-password-file", getattr(args, "mqtt_password_file", None)),
                                    ("--mqtt-ca-file", getattr(args, "mqtt_ca_file", None))) if v}}


def open_sinks(args: argparse.Namespace, site, site_path: str | Path | None = None, writer=None,
               particles: Callable | None = None, metadata: Mapping[str, str] | None = None,
               ground_truth: Callable | None = None, out_path: str | None = None,
               default_beacon: str = "b0", per_beacon: bool = False, existing: str = "replace") -> Fanout:
    """A Fanout of the sinks the options ask for (and of the position ``writer``, if given).

    ``ground_truth``: a source of true positions for ``--readings-out`` (else ``--ground-truth``'s file).
    ``out_path``: where the positions go ('-': standard output, which then no sink may take).
    ``default_beacon``: the MQTT topic of records that name no beacon.
    ``per_beacon``: the gateway tracks several beacons (ROS 2: a pose topic each).
    ``existing``: what the files do with what is at their paths (pfdoa.outfiles): the
    gateway keeps it ("keep": text continued, a recording moved aside), a replay replaces it.
    """
    record = getattr(args, "record", None)
    web = getattr(args, "web", None)
    health_json = getattr(args, "health_json", None)
    readings_out = getattr(args, "readings_out", None)
    truth_path = getattr(args, "ground_truth", None)
    frame_id = getattr(args, "frame_id", DEFAULT_FRAME) or DEFAULT_FRAME

    # Validate everything first: nothing is opened when one option is bad.
    mqtt = None
    if hasattr(args, "mqtt"):  # the command offers --mqtt: the site's [mqtt] url counts too
        from pfdoa.mqtt.config import mqtt_settings

        mqtt = mqtt_settings(getattr(site, "sections", {}), str(site_path or "<site>"), url=args.mqtt,
                             password_file=args.mqtt_password_file, ca_file=args.mqtt_ca_file)
        wanted = mqtt_input_kinds(args, getattr(site, "sections", {}), str(site_path or "<site>"))
        if wanted and mqtt is None:
            from pfdoa.gateway.inputs import specs_from_args

            named = [s.where() for s in specs_from_args(args) if s.kind == "mqtt"]
            where = named[0] if named else f"{site_path}: mqtt.inputs"
            raise InputError(f"{where}: needs a broker (--mqtt URL or [mqtt] url)")
        if mqtt is not None:
            sink_class("mqtt")  # a missing paho-mqtt is reported here, before anything is opened
    if web is not None:
        from pfdoa.sinks.web import parse_address

        web_address = parse_address(web)
    check_frame_id(frame_id)
    if hasattr(site, "sections"):
        from pfdoa.frames import site_frame

        site_frame(site, frame_id)  # [site] map_pose with --frame-id map is an error, said here
    ros2 = ros2_settings(args, site, site_path)
    on_stdout = [o for o, v in (("--out", out_path), ("--health-json", health_json), ("--readings-out", readings_out))
                 if v == "-"]
    if len(on_stdout) > 1:
        raise InputError(f"{' and '.join(on_stdout)} both go to standard output ('-'): give one of them a file")
    if truth_path is not None:
        if readings_out is None:
            raise InputError(f"--ground-truth {truth_path}: it goes into --readings-out; give that too")
        from pfdoa.sinks.readings import GroundTruthFile

        ground_truth = GroundTruthFile(truth_path)
    if record is not None:
        if not str(record).endswith(".mcap"):
            raise InputError(f"--record {record}: the file name must end in .mcap")
        mcap_cls = sink_class("mcap")  # a missing 'ros' extra is reported here
        site_text = None
        if site_path is not None:
            try:
                site_text = Path(site_path).read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError):
                site_text = None

    fan = Fanout([WriterSink(writer)] if writer is not None else [])
    try:
        if web is not None:  # first: a port in use fails before any file is created
            from pfdoa.sinks.web import WebSink

            fan.add(WebSink(web_address, site, particles=particles))
        if record is not None:
            fan.add(mcap_cls(record, site, frame_id=frame_id, site_toml=site_text, metadata=metadata,
                             existing=existing))
        if health_json is not None:
            from pfdoa.sinks.healthjson import HealthJsonSink

            fan.add(HealthJsonSink(health_json, existing))
        if readings_out is not None:
            from pfdoa.sinks.readings import ReadingsCsvSink

            fan.add(ReadingsCsvSink(readings_out, ground_truth=ground_truth, existing=existing))
        if mqtt is not None:
            from pfdoa.rooms import site_plan
            from pfdoa.sinks.mqtt import MqttSink

            places = hasattr(site, "sections") and site_plan(site) is not None
            fan.add(MqttSink(mqtt, default_beacon=default_beacon, places=places))
        if ros2 is not None:
            from pfdoa.sinks.ros2 import Ros2Sink

            try:
                fan.add(Ros2Sink(ros2, site if hasattr(site, "sections") else None, frame_id=frame_id,
                                 per_beacon=per_beacon, default_beacon=default_beacon))
            except OSError as exc:  # DDS could not start (a bad $CYCLONEDDS_URI, no interface)
                raise InputError(f"--ros2: {exc}") from None
    except BaseException:
        fan.close()
        raise
    return fan


def ros2_settings(args: argparse.Namespace, site, site_path: str | Path | None):
    """The ``[ros2]`` settings when ``--ros2`` is given (else None); a missing ``cyclonedds``
    is one InputError line, before anything opens."""
    if not getattr(args, "ros2", False):
        return None
    from pfdoa.ros2.config import ros2_settings as settings_of

    settings = settings_of(getattr(site, "sections", {}), str(site_path or "<site>"))
    sink_class("ros2")  # a missing 'ros2' extra is reported here
    return settings


def ros2_odometry(fan: Fanout, clock=None):
    """The robot's odometry on the ROS 2 sink's participant ([ros2] odom_topic), or None
    (no ROS 2 sink, or no topic)."""
    from pfdoa.sinks.ros2 import Ros2Sink
    from pfdoa.sinks.ros2odom import Ros2OdometrySource

    sink = next((s for s in fan.sinks if isinstance(s, Ros2Sink)), None)
    if sink is None or not sink.settings.odom_topic:
        return None

    source = Ros2OdometrySource(sink.node, sink.settings.odom_topic, reliable=sink.settings.odom_reliable, clock=clock)
    sink.inputs.append(source)
    return source


def check_frame_id(frame_id: str) -> None:
    """A ROS frame name: letters, digits, '_' and '/' (InputError naming --frame-id otherwise)."""
    if not frame_id.replace("_", "").replace("/", "").isalnum():
        raise InputError(f"--frame-id {frame_id!r}: letters, digits, '_' and '/' only (a ROS frame name)")


def mqtt_input_kinds(args: argparse.Namespace, sections: Mapping, source: str) -> tuple[str, ...]:
    """The broker inputs asked for: ``--mqtt-input`` and ``--input mqtt:KIND`` (each once),
    else ``[mqtt] inputs``."""
    from pfdoa.gateway.inputs import specs_from_args

    given = tuple(dict.fromkeys(s.arg for s in specs_from_args(args) if s.kind == "mqtt"))
    if given or not hasattr(args, "mqtt_input"):
        return given
    from pfdoa.mqtt.config import mqtt_table

    return tuple(mqtt_table(sections, source).inputs)


def check_mqtt_inputs(args: argparse.Namespace, settings, *, stream: bool,
                      others: Iterable[str] = ()) -> tuple[str, ...]:
    """The broker inputs of ``pfdoa gateway`` (:func:`mqtt_input_kinds`), checked against
    the other options before anything is opened (InputError/ConfigError, exit 2).

    ESPresense input needs the site's ``[espresense]`` table; it is not written to
    ``--capture`` (a capture holds byte streams), so the two are not combined; and with
    ``espresense.time_field`` (message time: the runner's timers follow the messages'
    stamps) no input on this host's clock may join it (``others``: the other live inputs,
    as the user named them)."""
    from pfdoa.errors import ConfigError

    if stream:  # a replay reads its capture only: the site's [mqtt] inputs are for live runs
        return ()
    kinds = mqtt_input_kinds(args, settings.site.sections, settings.source)
    if "espresense" not in kinds:
        return kinds
    esp = settings.espresense
    if esp is None:
        raise ConfigError(settings.source, "espresense", "missing table [espresense] (rooms = { ROOM = ANCHOR_ID, "
                          "... }): ESPresense input needs it")
    if getattr(args, "capture", None):
        raise InputError(f"--capture {args.capture}: a capture holds byte streams; ESPresense readings would be "
                         "missing from it (leave out --capture or the espresense input)")
    if esp.time_field:
        host_clock = [*others, *(["--odom"] if args.odom else []), *(["mqtt:frames"] if "frames" in kinds else [])]
        if host_clock:
            raise InputError(f"{settings.source}: espresense.time_field = {esp.time_field!r}: the timers run on "
                             f"the messages' time, which {host_clock[0]} does not share (remove one of them)")
    return kinds


def mqtt_input(fan: Fanout, kind: str, espresense=None):
    """A broker input of ``kind`` (``frames``: our frames, pfdoa.gateway.inputs.mqtt_frames; ``espresense``:
    ESPresense nodes' messages for the gateway's tracker of named beacons, with the site's
    EspresenseConfig ``espresense``, pfdoa.gateway.inputs.espresense) on the mqtt sink's connection,
    registered with the sink (its counters go into the MQTT health). The registry's MQTT
    inputs make theirs with it when they open (pfdoa.gateway.inputs.mqtt)."""
    from pfdoa.gateway.transports import TransportFatal
    from pfdoa.sinks.mqtt import MqttSink

    sink = next((s for s in fan.sinks if isinstance(s, MqttSink)), None)
    inp: Any
    if sink is None:
        raise TransportFatal(f"mqtt:{kind}: no broker connection (--mqtt URL or [mqtt] url, and it must not have "
                             "failed)")
    if kind == "frames":
        from pfdoa.gateway.inputs.mqtt_frames import FrameInput

        inp = FrameInput(sink.client, sink.settings.frames_topic)
    else:
        from pfdoa.gateway.inputs.espresense import EspresenseInput

        if espresense is None:
            raise ValueError("the espresense input needs the site's EspresenseConfig")
        inp = EspresenseInput(sink.client, espresense)
    sink.inputs.append(inp)
    return inp


def sink_counters(fan: Fanout | None) -> dict:
    """The final counters of the sinks that keep some (``mqtt``: delivery), by sink name."""
    return {} if fan is None else fan.collect("counters")


def web_url(fan: Fanout) -> str | None:
    """The live view's address, when the fan-out serves one."""
    return next((getattr(s, "url", None) for s in fan.sinks if s.name == "web"), None)


def record_odometry_file(sink: Sink, path: str) -> None:
    """Hand a whole odometry file (read before the run: ``--odom`` of a replay) to ``sink``
    as increments that arrived at their own times."""
    from pfdoa.gateway.transports import OdomLine
    from pfdoa.trace import read_odometry

    od = read_odometry(path)
    for t, dx, dy, dth in zip(od.t.tolist(), od.dx.tolist(), od.dy.tolist(), od.dtheta.tolist()):
        sink.odometry(OdomLine(t, t, dx, dy, dth))
