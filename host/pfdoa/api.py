"""What the simulator (``pfdoasim``), the tools, the benchmarks and the fuzzers use of the product.

They import from here, or from the public modules (:data:`PUBLIC`): the wire protocol, the
file formats and the libraries below the gateway whose names are their interface. The
gateway's, the readings', calibration's, the sinks' and the commands' other names are
internal: a module may move inside its package without those programs noticing
(tests/unit/test_architecture.py checks both). This module only re-exports; importing it loads
no optional dependency (MCAP, paho-mqtt, python-can and pyserial load when used).
"""

from __future__ import annotations

from pfdoa import _toml as toml
from pfdoa.calibration.calibrate import calibrate_traces
from pfdoa.calibration.peercal import PeerFit, fit_peers, peer_mean_rssi
from pfdoa.commands._common import check_number, check_outputs, check_seed
from pfdoa.gateway.auth import AuthCounters, AuthGuard, write_key_file
from pfdoa.gateway.beacons import MAX_ID_LEN, BeaconReading
from pfdoa.gateway.decoding import Gateway
from pfdoa.gateway.health import Health
from pfdoa.gateway.inputs.can import CanTransport
from pfdoa.gateway.inputs.capture import CAPTURE_MAX_LINE, CAPTURE_V1, CaptureReader, capture_chunks, capture_line
from pfdoa.gateway.inputs.espresense import MAX_TIME as ESPRESENSE_MAX_TIME
from pfdoa.gateway.inputs.espresense import MAX_UNKNOWN_ROOMS as ESPRESENSE_MAX_UNKNOWN_ROOMS
from pfdoa.gateway.inputs.espresense import EspresenseInput, EspresenseParser, espresense_config
from pfdoa.gateway.localizer import Localizer
from pfdoa.gateway.odomsource import MAX_LINE as ODOM_MAX_LINE
from pfdoa.gateway.odomsource import OdometryReader
from pfdoa.gateway.peers import read_captures
from pfdoa.gateway.setup import build_pipeline, load_settings
from pfdoa.gateway.transports import Chunk, OdomLine, TimeMark, TransportEOF, TransportError
from pfdoa.mqtt.client import ClientConfig, MqttClient
from pfdoa.mqtt.publisher import Publisher, PublisherConfig, pose_payload
from pfdoa.mqtt.url import parse_url
from pfdoa.readings.reassembly import Reading, SeqReassembler, WindowGrouper
from pfdoa.sinks.base import Sink

# Modules (and their submodules) used directly: the wire protocol, the file formats and the
# libraries whose module names are their interface. "pfdoa" alone is the package's version.
PUBLIC: tuple[str, ...] = (
    "pfdoa", "pfdoa.api", "pfdoa.cli", "pfdoa.errors", "pfdoa.clock", "pfdoa.signals", "pfdoa.types",
    "pfdoa.jsonnum", "pfdoa.paths", "pfdoa.plotting", "pfdoa.radio", "pfdoa.radiomap", "pfdoa.odometry",
    "pfdoa.outfiles", "pfdoa.output", "pfdoa.site", "pfdoa.trace", "pfdoa.sinks.mcap",
    "pfdoa.protocol", "pfdoa.estimators", "pfdoa.evaluation",
)

__all__ = [
    "toml",
    # calibration
    "calibrate_traces", "PeerFit", "fit_peers", "peer_mean_rssi",
    # the commands' checks of their options (the simulator's command takes the same)
    "check_number", "check_outputs", "check_seed",
    # the gateway
    "AuthCounters", "AuthGuard", "write_key_file", "MAX_ID_LEN", "BeaconReading", "Gateway", "Health",
    "CanTransport", "CAPTURE_MAX_LINE", "CAPTURE_V1", "CaptureReader", "capture_chunks", "capture_line",
    "ESPRESENSE_MAX_TIME", "ESPRESENSE_MAX_UNKNOWN_ROOMS", "EspresenseInput", "EspresenseParser",
    "espresense_config", "Localizer", "ODOM_MAX_LINE", "OdometryReader", "read_captures", "build_pipeline",
    "load_settings", "Chunk", "OdomLine", "TimeMark", "TransportEOF", "TransportError",
    # the broker client
    "ClientConfig", "MqttClient", "Publisher", "PublisherConfig", "pose_payload", "parse_url",
    # readings
    "Reading", "SeqReassembler", "WindowGrouper",
    # sinks
    "Sink",
]
