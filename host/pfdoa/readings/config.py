"""Gateway and output settings: the optional ``[gateway]`` and ``[output]`` tables of a site file.

Every key has a default, so a site file with only ``[radio]`` and ``[[anchors]]`` works::

    [gateway]
    mode = "seq"             # "seq": group by beacon sequence; "window": by time window
    set_timeout_s = 0.25     # emit an incomplete set this long after its first report
    window_s = 1.0           # window length in "window" mode
    max_open_sets = 64       # open sets kept at most; the oldest is emitted early beyond
    stale_after_s = 3.0      # an anchor silent this long is reported stale
    health_interval_s = 5.0  # period of the health line on stderr (0 = never)
    serial_baud = 115200     # for serial ports given without a baud rate
    reconnect_min_s = 0.5    # backoff when a serial port disappears ...
    reconnect_max_s = 8.0    # ... doubling up to this
    queue_size = 1024        # chunks (<= 4 KiB each) queued from transports (finite inputs wait;
                             # a live device's excess is dropped, counted)
    odom_wait_s = 0.25       # a set waits at most this long for the odometry up to its time

    [output]
    format = "jsonl"         # or "csv"
    path = "-"               # "-" = standard output

Every key's type, range and default: :mod:`pfdoa.schema` (docs/site-file.md). Unknown keys,
wrong types and values out of range raise :class:`pfdoa.errors.ConfigError` (exit code 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.trace import DEFAULT_WINDOW_S

MODES = schema.row("gateway", "mode").choices
FORMATS = schema.row("output", "format").choices


@dataclass(frozen=True)
class GatewayConfig:
    mode: str = "seq"
    set_timeout_s: float = 0.25
    window_s: float = DEFAULT_WINDOW_S
    max_open_sets: int = 64
    stale_after_s: float = 3.0
    health_interval_s: float = 5.0
    serial_baud: int = 115200
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 8.0
    queue_size: int = 1024
    odom_wait_s: float = 0.25


@dataclass(frozen=True)
class OutputConfig:
    format: str = "jsonl"
    path: str = "-"


def _build(cls, table: Any, source: str, section: str):
    """The table checked by its rows in :mod:`pfdoa.schema` (types, ranges, choices, unknown keys)."""
    return cls(**schema.check_table(source, section, table))


def gateway_config(sections: dict[str, Any], source: str = "<site>") -> GatewayConfig:
    """Validate the ``[gateway]`` table (missing table -> defaults)."""
    cfg = _build(GatewayConfig, sections.get("gateway"), source, "gateway")
    if cfg.reconnect_max_s < cfg.reconnect_min_s:
        raise ConfigError(source, "gateway.reconnect_max_s", "must be >= gateway.reconnect_min_s")
    return cfg


def output_config(sections: dict[str, Any], source: str = "<site>") -> OutputConfig:
    """Validate the ``[output]`` table (missing table -> defaults)."""
    return _build(OutputConfig, sections.get("output"), source, "output")
