"""Our own UART frames as MQTT payloads: a Wi-Fi anchor publishes the bytes it would write.

Each anchor publishes on its own topic (default ``<prefix>/anchors/<name>/frames``) the
COBS frames of protocol/SPEC.md section 2, 0x00-delimited, one or more per message, exactly
the bytes of its UART. Every topic is one byte stream: the message becomes a
:class:`~pfdoa.gateway.transports.Chunk` with source ``mqtt:<topic>``, which the gateway
decodes with one ``StreamDecoder`` per source as it does a serial port (same counters,
same bounds). A frame split across two messages is reassembled by that decoder.

Bounds: payloads up to :data:`~pfdoa.gateway.transports.READ_MAX` bytes (a serial read's
bound; larger ones are ``oversized``), topic names to :data:`MAX_SOURCE_NAME` characters.
No table of topics is kept here: the gateway's decoder table is the one bound on sources
(64; a topic that never sent a valid frame, or fell silent, makes room for a new one:
:meth:`pfdoa.gateway.decoding.Gateway._make_room`). A table here, filled once by 64 one-off
junk topics, used to refuse the real anchors' topics for the rest of the run.
"""

from __future__ import annotations

from pfdoa.gateway.transports import READ_MAX, Chunk, OdomLine, TimeMark, Transport
from pfdoa.mqtt.client import MqttClient
from pfdoa.mqtt.inputs import DEFAULT_QUEUE, MqttInput

MAX_SOURCE_NAME = 200


def source_name(topic: str) -> str:
    """``mqtt:<topic>`` without white space (capture files separate fields by spaces)."""
    return "mqtt:" + "".join("_" if ch.isspace() else ch for ch in topic)[:MAX_SOURCE_NAME]


class FrameInput(MqttInput[Chunk]):
    kind = "frames"

    def __init__(self, client: MqttClient, topic_filter: str | None = None, *,
                 max_queue: int = DEFAULT_QUEUE) -> None:
        super().__init__(client, topic_filter or f"{client.prefix}/anchors/+/frames", max_payload=READ_MAX,
                         max_queue=max_queue)

    def parse(self, topic: str, payload: bytes, t: float) -> Chunk | str:
        if not payload:
            return "empty"
        return Chunk(source_name(topic), t, payload)


class FrameTransport(Transport):
    """A :class:`FrameInput` behind the gateway's Transport interface (for the Runner's readers).

    It never fails or ends: the client reconnects by itself, and while the broker is away
    ``read`` simply returns nothing.
    """

    buffered = True  # the input's inbox counts what it cannot hold (pfdoa.mqtt.inputs)

    def __init__(self, frame_input: FrameInput, name: str = "mqtt-frames") -> None:
        super().__init__()
        self.input = frame_input
        self.name = name

    def _open(self) -> None:
        self.input.start()

    def _read(self, timeout: float) -> list[Chunk | OdomLine | TimeMark]:
        items: list[Chunk | OdomLine | TimeMark] = list(self.input.read(timeout))  # only chunks
        # The chunks carry this clock's receive times: the live timers may run up to what
        # has been returned (MqttInput.caught_up_to).
        self.caught_up_to = self.input.caught_up_to(self.clock.now(), items[-1].t if items else None)
        return items

    def lost(self, item) -> None:
        self.input.lost(1)

    def counters(self) -> dict:
        """For the final counters: messages, accepted, queue_drops, lost, rejected by kind."""
        return self.input.counters()

    def _close(self) -> None:
        self.input.stop()
