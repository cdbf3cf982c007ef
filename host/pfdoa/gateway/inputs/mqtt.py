"""``mqtt:frames`` and ``mqtt:espresense``: anchors' readings from the broker of ``--mqtt``.

An :class:`~pfdoa.mqtt.inputs.MqttInput` (:mod:`pfdoa.mqtt`: a subscription with a bounded
inbox, every rejection counted) behind the Transport interface, for the runner's readers.
It shares the MQTT output's connection, so it is made when it opens (by the command's
``InputContext.mqtt``: pfdoa.sinks.options.mqtt_input), once that connection exists.

* :class:`FrameTransport` (``frames``): our UART frames as payloads, a topic per anchor, each
  topic a byte stream decoded like a serial port (:mod:`pfdoa.gateway.inputs.mqtt_frames`).
* :class:`EspresenseTransport` (``espresense``): ESPresense nodes' messages, read as batches
  of :class:`~pfdoa.gateway.beacons.BeaconBatch` readings for the gateway's tracker of named
  beacons (:mod:`pfdoa.gateway.inputs.espresense`). With the site's ``espresense.time_field`` the
  readings carry message time and the runner's timers run on it (``message_time``);
  otherwise this host's receive time, and the timers run up to it whenever the inbox is empty.

Neither fails or ends: the client reconnects by itself, and while the broker is away
``read`` simply returns nothing.
"""

from __future__ import annotations

from typing import Any, Callable

from pfdoa.errors import InputError
from pfdoa.gateway.beacons import BeaconBatch
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import Item, Transport

# An ESPresense read is one BeaconBatch item of at most this many readings (the reader
# queue bounds items, so at most queue_size x READ_ITEMS readings wait there: 1024 x 64 by
# default, ~13 MB).
READ_ITEMS = 64


class MqttTransport(Transport):
    """One MqttInput (``inp``, or made by ``connect`` when the transport opens)."""

    kind = ""  # the MqttInput kind: "frames", "espresense"
    carries_frames = True
    buffered = True  # the input's inbox counts what it cannot hold (pfdoa.mqtt.inputs)

    def __init__(self, inp: Any = None, name: str = "", connect: Callable[[], Any] | None = None) -> None:
        super().__init__()
        if inp is None and connect is None:
            raise ValueError("an MQTT input, or how to make one")
        self.input = inp
        self._connect = connect
        self.name = name or f"mqtt-{self.kind}"

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "MqttTransport":
        sub = {c.kind: c for c in (FrameTransport, EspresenseTransport)}.get(spec.arg)
        if sub is None:
            raise InputError(f"{spec.where()}: expected mqtt:frames or mqtt:espresense")
        mqtt = ctx.mqtt
        if mqtt is None:
            raise InputError(f"{spec.where()}: needs a broker (--mqtt URL or [mqtt] url)")
        t = sub(connect=lambda: mqtt(spec.arg), **sub.options(ctx))
        t.clock, t.where = ctx.clock, spec.where()
        return t

    @classmethod
    def options(cls, ctx: InputContext) -> dict:
        return {}

    def _open(self) -> None:
        if self.input is None:
            assert self._connect is not None
            self.input = self._connect()
        self.input.start()

    def counters(self) -> dict:
        """Messages, accepted, queue_drops, lost, rejected by kind (pfdoa.mqtt.inputs)."""
        return self.input.counters() if self.input is not None else {}

    def _close(self) -> None:
        self.input.stop()


class FrameTransport(MqttTransport):
    """A :class:`~pfdoa.gateway.inputs.mqtt_frames.FrameInput`: its chunks carry this clock's receive times."""

    kind = "frames"

    def _read(self, timeout: float) -> list[Item]:
        items: list[Item] = list(self.input.read(timeout))  # only chunks
        # The live timers may run up to what has been returned (MqttInput.caught_up_to).
        self.caught_up_to = self.input.caught_up_to(self.clock.now(), items[-1].t if items else None)
        return items

    def lost(self, item) -> None:
        self.input.lost(1)


class EspresenseTransport(MqttTransport):
    """An :class:`~pfdoa.gateway.inputs.espresense.EspresenseInput` (see the module doc)."""

    kind = "espresense"
    carries_frames = False

    def __init__(self, inp: Any = None, name: str = "", connect: Callable[[], Any] | None = None,
                 time_field: str | None = None) -> None:
        super().__init__(inp, name, connect)
        # Stamped by the publisher: the runner's timers follow the readings' own times.
        self.message_time = bool(inp.parser.cfg.time_field if inp is not None else time_field)

    @classmethod
    def options(cls, ctx: InputContext) -> dict:
        if ctx.espresense is None:
            raise InputError("mqtt:espresense: the site file has no [espresense] table (rooms = { ROOM = "
                             "ANCHOR_ID, ... })")
        return {"time_field": ctx.espresense.time_field}

    def _read(self, timeout: float) -> list:
        items = self.input.read(timeout, READ_ITEMS)
        if not self.message_time:
            # The readings carry this clock's receive times: the live timers may run up to
            # what has been returned (EspresenseInput.caught_up_to).
            self.caught_up_to = self.input.caught_up_to(self.clock.now(), items[-1].t if items else None)
        return [BeaconBatch(items)] if items else []

    def lost(self, item) -> None:
        self.input.lost(len(item.readings))

    def anchor_status(self, now: float | None = None) -> dict[int, dict]:
        return self.input.anchor_status(now) if self.input is not None else {}
