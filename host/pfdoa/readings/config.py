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

Unknown keys and wrong types raise :class:`pfdoa.errors.ConfigError` (exit code 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from pfdoa.errors import ConfigError
from pfdoa.trace import DEFAULT_WINDOW_S

MODES = ("seq", "window")
FORMATS = ("jsonl", "csv")


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


# (minimum, maximum) for numeric keys; inclusive.
_RANGES: dict[str, tuple[float, float]] = {
    "set_timeout_s": (0.001, 3600.0),
    "window_s": (0.001, 3600.0),
    "max_open_sets": (1, 65536),
    "stale_after_s": (0.01, 86400.0),
    "health_interval_s": (0.0, 86400.0),
    "serial_baud": (50, 20_000_000),
    "reconnect_min_s": (0.001, 3600.0),
    "reconnect_max_s": (0.001, 3600.0),
    "queue_size": (16, 10_000_000),
    "odom_wait_s": (0.0, 60.0),
}


def _convert(source: str, key: str, value: Any, default: Any) -> Any:
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(source, key, f"must be a string, got {type(value).__name__} {_short(value)}")
        return value
    if isinstance(default, bool) or isinstance(value, bool):
        raise ConfigError(source, key, f"must be a number, got {_short(value)}")
    if isinstance(default, int):
        if not isinstance(value, int):
            raise ConfigError(source, key, f"must be an integer, got {type(value).__name__} {_short(value)}")
        return value
    if not isinstance(value, (int, float)):
        raise ConfigError(source, key, f"must be a number, got {type(value).__name__} {_short(value)}")
    try:
        finite = math.isfinite(float(value))
    except OverflowError:  # an integer beyond float range
        finite = False
    if not finite:
        raise ConfigError(source, key, f"must be a finite number, got {_short(value)}")
    return float(value)


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _build(cls, table: Any, source: str, section: str):
    if table is None:
        return cls()
    if not isinstance(table, dict):
        raise ConfigError(source, section, f"must be a table ([{section}])")
    defaults = {f.name: f.default for f in fields(cls)}
    values: dict[str, Any] = {}
    for key, value in table.items():
        where = f"{section}.{key}"
        if key not in defaults:
            raise ConfigError(source, where, f"unknown key (known: {', '.join(defaults)})")
        v = _convert(source, where, value, defaults[key])
        lo_hi = _RANGES.get(key)
        if lo_hi and not lo_hi[0] <= v <= lo_hi[1]:
            raise ConfigError(source, where, f"must be in [{lo_hi[0]}, {lo_hi[1]}], got {_short(v)}")
        values[key] = v
    return cls(**values)


def gateway_config(sections: dict[str, Any], source: str = "<site>") -> GatewayConfig:
    """Validate the ``[gateway]`` table (missing table -> defaults)."""
    cfg = _build(GatewayConfig, sections.get("gateway"), source, "gateway")
    if cfg.mode not in MODES:
        raise ConfigError(source, "gateway.mode", f"must be one of {', '.join(MODES)}, got {cfg.mode!r}")
    if cfg.reconnect_max_s < cfg.reconnect_min_s:
        raise ConfigError(source, "gateway.reconnect_max_s", "must be >= gateway.reconnect_min_s")
    return cfg


def output_config(sections: dict[str, Any], source: str = "<site>") -> OutputConfig:
    """Validate the ``[output]`` table (missing table -> defaults)."""
    cfg = _build(OutputConfig, sections.get("output"), source, "output")
    if cfg.format not in FORMATS:
        raise ConfigError(source, "output.format", f"must be one of {', '.join(FORMATS)}, got {cfg.format!r}")
    return cfg
