"""The grouper the ``[gateway]`` table asks for: the one place one is made from the settings
(the gateway and its replay, calibration's gateway sets, the simulators)."""

from __future__ import annotations

from typing import Sequence

from pfdoa.readings.config import GatewayConfig
from pfdoa.readings.reassembly import SeqReassembler, WindowGrouper


def make_grouper(anchor_ids: Sequence[int], cfg: GatewayConfig, mode: str | None = None,
                 window_s: float | None = None) -> SeqReassembler | WindowGrouper:
    """The reassembler for ``mode`` ("seq" or "window"; default from the config)."""
    mode = mode or cfg.mode
    if mode == "seq":
        return SeqReassembler(anchor_ids, set_timeout_s=cfg.set_timeout_s, max_open_sets=cfg.max_open_sets,
                              stale_after_s=cfg.stale_after_s)
    # Windows close on time, live and in replay alike (the same sets from the same readings).
    return WindowGrouper(anchor_ids, window_s=window_s or cfg.window_s, stale_after_s=cfg.stale_after_s)
