"""The sinks' command-line options, shared by ``pfdoa gateway`` and ``pfdoa replay``.

A command adds the options it supports and builds one :class:`~pfdoa.sinks.base.Fanout`
from the parsed arguments::

    from pfdoa.sinks import options as sink_options
    sink_options.add_arguments(p)                                  # in add_arguments
    sinks = sink_options.open_sinks(args, site, args.config, writer, particles=...)   # in run
    loc = Localizer(site, estimator, sinks, ...)   # records: sinks.write; close: sinks.close()
    # each Reading: sinks.reading(r); each health period: sinks.health(snapshot)

Every bad value is an :class:`~pfdoa.errors.InputError` naming the option (exit 2), raised
before anything is opened, so a bad ``--web`` does not leave an empty recording behind.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable, Iterable, Mapping

from pfdoa.errors import InputError
from pfdoa.sinks.base import Fanout, WriterSink

OPTIONS = ("record", "web", "health-json", "readings-out")


def add_arguments(p: argparse.ArgumentParser, which: Iterable[str] = OPTIONS) -> None:
    which = tuple(which)
    unknown = set(which) - set(OPTIONS)
    if unknown:
        raise ValueError(f"unknown sink options: {sorted(unknown)}")
    g = p.add_argument_group("robot outputs")
    if "record" in which:
        g.add_argument("--record", metavar="RUN.mcap",
                       help="also write a ROS 2 recording (MCAP): poses, readings, diagnostics, anchor markers "
                            "(needs pip install 'pfdoa[ros]')")
        g.add_argument("--frame-id", default="map", metavar="ID",
                       help="frame_id of the recorded poses and markers (default map; see docs/robot.md)")
    if "web" in which:
        g.add_argument("--web", metavar="[HOST:]PORT",
                       help="serve the live view on HOST:PORT (default host 127.0.0.1; 0.0.0.0:PORT for all)")
    if "health-json" in which:
        g.add_argument("--health-json", metavar="PATH",
                       help="also write each health period as one JSON line to PATH ('-' = standard output)")
    if "readings-out" in which:
        g.add_argument("--readings-out", metavar="TRACE.csv",
                       help="also write every reading in the trace format t,anchor,rssi_dbm,seq")


def open_sinks(args: argparse.Namespace, site, site_path: str | Path | None = None, writer=None,
               particles: Callable | None = None, metadata: Mapping[str, str] | None = None,
               ground_truth: Callable | None = None) -> Fanout:
    """A Fanout of the position ``writer`` (if any) and the sinks the options ask for."""
    record = getattr(args, "record", None)
    web = getattr(args, "web", None)
    health_json = getattr(args, "health_json", None)
    readings_out = getattr(args, "readings_out", None)
    frame_id = getattr(args, "frame_id", "map") or "map"

    # Validate everything first: nothing is opened when one option is bad.
    if web is not None:
        from pfdoa.sinks.web import parse_address

        web_address = parse_address(web)
    if not frame_id.replace("_", "").replace("/", "").isalnum():
        raise InputError(f"--frame-id {frame_id!r}: letters, digits, '_' and '/' only (a ROS frame name)")
    if record is not None:
        if not str(record).endswith(".mcap"):
            raise InputError(f"--record {record}: the file name must end in .mcap")
        from pfdoa.sinks import sink_class

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
            fan.add(mcap_cls(record, site, frame_id=frame_id, site_toml=site_text, metadata=metadata))
        if health_json is not None:
            from pfdoa.sinks.healthjson import HealthJsonSink

            fan.add(HealthJsonSink(health_json))
        if readings_out is not None:
            from pfdoa.sinks.readings import ReadingsCsvSink

            fan.add(ReadingsCsvSink(readings_out, ground_truth=ground_truth))
    except BaseException:
        fan.close()
        raise
    return fan
