"""Our own UART frames as MQTT payloads: a Wi-Fi anchor publishes the bytes it would write.

Each anchor publishes on its own topic (default ``<prefix>/anchors/<name>/frames``) the
COBS frames of protocol/SPEC.md section 2, 0x00-delimited, one or more per message, exactly
the bytes of its UART. Every topic is one byte stream: the message becomes a
:class:`~pfdoa.gateway.transports.Chunk` with source ``mqtt:<topic>``, which the gateway
decodes with one ``StreamDecoder`` per source as it does a serial port (same counters,
same bounds). A frame split across two messages is reassembled by that decoder.
:class:`pfdoa.gateway.inputs.mqtt.FrameTransport` puts the input behind the gateway's
Transport interface (``pfdoa gateway --input mqtt:frames``).

Bounds: payloads up to :data:`~pfdoa.gateway.transports.READ_MAX` bytes (a serial read's
bound; larger ones are ``oversized``), topic names to :data:`MAX_SOURCE_NAME` characters.
No table of topics is kept here: the gateway's decoder table is the one bound on sources
(64; a topic that never sent a valid frame, or fell silent, makes room for a new one:
:meth:`pfdoa.gateway.decoding.Gateway._make_room`). A table here, filled once by 64 one-off
junk topics, used to refuse the real anchors' topics for the rest of the run.
"""

from __future__ import annotations

from pfdoa.gateway.transports import READ_MAX, Chunk
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
