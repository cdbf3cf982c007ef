"""``can:INTERFACE:CHANNEL[@BITRATE][,key=value...]`` or ``can:config[:PATH]``: a CAN bus
through python-can.

The interface is any of python-can's (``socketcan:can0``, ``slcan:/dev/ttyACM0@500000``,
``virtual:vc0``, ``pcan:PCAN_USBBUS1@250000``, ...; an unknown one is named at open with
the list python-can knows); ``key=value`` options go to ``can.Bus`` as they are (numbers and
true/false converted). ``config[:PATH]`` takes python-can's own configuration file. The
acceptance filters pass only the identifiers of protocol/SPEC.md section 4 (anchor-to-host
types); error, remote and extended frames are counted (``ignored``). For ``slcan``,
python-can's 2 s wait after opening is off (``,sleep_after_open=2`` restores it).
Bidirectional: ``pfdoa anchors`` configures anchors on it.
"""

from __future__ import annotations

import os
import re
from typing import Any

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import (
    Chunk,
    Item,
    Transport,
    TransportAbsent,
    TransportError,
    TransportFatal,
    open_error,
)


# Anchor-to-host CAN identifiers (protocol/SPEC.md section 4).
def _default_can_filters() -> list[dict]:
    from pfdoa.protocol.can import GATEWAY_CAN_FILTERS

    return [dict(f) for f in GATEWAY_CAN_FILTERS]


def _coerce(value: str):
    low = value.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(value)
        except ValueError:
            pass
    return value


def parse_can_spec(spec: str, where: str | None = None) -> dict:
    """``INTERFACE:CHANNEL[@BITRATE][,key=value...]`` or ``config[:PATH]`` -> python-can kwargs
    (InputError naming ``where``, default ``--can SPEC``)."""
    where = where or f"--can {spec}"
    head, *opts = spec.split(",")
    kwargs: dict = {}
    if head == "config" or head.startswith("config:"):
        from can.util import load_config

        path = head[len("config:"):] or None
        if path and not os.path.exists(path):
            raise InputError(f"{where}: no such configuration file {path!r}")
        try:
            kwargs.update(load_config(path=path))
        except Exception as exc:  # python-can raises several types for bad files
            raise InputError(f"{where}: {exc}") from None
    else:
        iface, sep, channel = head.partition(":")
        if not sep or not iface or not channel:
            raise InputError(
                f"{where}: expected INTERFACE:CHANNEL[@BITRATE] (e.g. socketcan:can0, "
                "slcan:/dev/ttyACM0@500000, virtual:vc0) or config[:PATH]"
            )
        m = re.fullmatch(r"(.+)@(\d+)", channel)
        if m:
            channel, kwargs["bitrate"] = m.group(1), int(m.group(2))
        kwargs["interface"], kwargs["channel"] = iface, channel
    for opt in opts:
        key, sep, value = opt.partition("=")
        if not sep or not key:
            raise InputError(f"{where}: option {opt!r} is not key=value")
        kwargs[key.strip()] = _coerce(value.strip())
    return kwargs


class CanTransport(Transport):
    bidirectional = True
    is_can = True

    def __init__(self, spec: str, name: str | None = None, filters: list[dict] | None = None,
                 clock: Clock | None = None, where: str | None = None) -> None:
        super().__init__(clock)
        self.spec = spec
        self.where = where or f"--can {spec}"
        self.kwargs = parse_can_spec(spec, self.where)
        if self.kwargs.get("interface") == "slcan":
            # python-can waits 2 s after opening an SLCAN port by default; adapters that need
            # it can still ask with ",sleep_after_open=2".
            self.kwargs.setdefault("sleep_after_open", 0)
        self.filters = _default_can_filters() if filters is None else filters
        self.name = name or f"can:{self.kwargs.get('channel', 'config')}"
        self._bus: Any = None  # a python-can bus while open
        self.ignored = 0  # error/remote/extended frames

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "CanTransport":
        return cls(spec.arg, name=f"can{index}", clock=ctx.clock,
                   where=None if spec.option == "--can" else spec.where())

    def counters(self) -> dict:
        """For the final counters: frames ignored (error, remote, extended id)."""
        return {"ignored": self.ignored} if self.ignored else {}

    def _open(self) -> None:
        import can

        iface = self.kwargs.get("interface")
        if iface is not None and iface not in can.VALID_INTERFACES:
            raise TransportFatal(f"{self.where}: unknown interface {iface!r} "
                                 f"(python-can knows: {', '.join(sorted(can.VALID_INTERFACES))})")
        channel = str(self.kwargs.get("channel", ""))
        if iface == "slcan" and "://" not in channel and channel and not os.path.exists(channel.split("@")[0]):
            raise TransportAbsent("--can", self.spec, self.where)  # the adapter's serial port is not plugged in
        try:
            self._bus = can.Bus(can_filters=self.filters, **self.kwargs)
        except (ValueError, ImportError) as exc:  # bad parameters or a missing driver: permanent
            raise TransportFatal(f"{self.where}: {exc}") from None
        except (can.CanError, OSError) as exc:
            raise open_error("--can", self.spec, exc, iface == "slcan", self.where) from None
        except TypeError as exc:  # unknown keyword option
            raise TransportFatal(f"{self.where}: {exc}") from None

    def _read(self, timeout: float) -> list[Item]:
        import can

        out: list[Item] = []
        try:
            msg = self._bus.recv(timeout)
            while True:
                if msg is None:
                    t = self.clock.now()  # stamp, then look (see SerialTransport._read)
                    msg = self._bus.recv(0.0)
                    if msg is None:
                        self.caught_up_to = t
                        return out
                if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                    self.ignored += 1
                else:
                    out.append(Chunk(self.name, self.clock.now(), bytes(msg.data), msg.arbitration_id))
                    if len(out) >= 256:
                        return out  # more may be waiting: caught_up_to stays None
                msg = self._bus.recv(0.0)
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None

    def _send(self, data: bytes, can_id: int | None) -> None:
        import can

        if can_id is None:
            raise TransportFatal(f"{self.name}: a CAN bus carries CAN frames, not UART bytes")
        try:
            self._bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        except (can.CanError, OSError) as exc:
            raise TransportError(f"{self.spec}: {exc}") from None

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()
