"""Anchor readings from the broker: the small base class of the broker's inputs.

An input subscribes to a topic filter on a shared :class:`~pfdoa.mqtt.client.MqttClient`
and turns each message into an item (a :class:`~pfdoa.gateway.transports.Chunk` of our
frames, or a :class:`~pfdoa.gateway.beacons.BeaconReading` from ESPresense) in a bounded
inbox that the gateway thread drains with :meth:`MqttInput.read`. Subclasses implement
:meth:`MqttInput.parse`, which returns the item or the name of a rejection.

Untrusted messages never crash anything or grow memory: a payload above
``max_payload`` bytes is rejected before it is looked at (``oversized``); every
rejection is counted by kind (``rejected``); the inbox holds at most ``max_queue``
items (``queue_drops`` beyond, the newest dropped as the gateway's reader queue does);
subclasses cap whatever they track per topic or device.

Every message accepted is either processed or counted lost: ``offered`` (accepted +
queue_drops) = what the gateway processed + ``lost``, where ``lost`` = ``queue_drops`` +
``unread`` (read from the inbox but never handed to the pipeline, or still in the inbox
when the input stopped).

The two kinds are inputs of the gateway (:mod:`pfdoa.gateway.inputs.mqtt_frames`, our frames;
:mod:`pfdoa.gateway.inputs.espresense`, ESPresense nodes' JSON), registered as ``mqtt:``.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections import Counter, deque
from typing import Any, Generic, TypeVar

from pfdoa.mqtt.client import MqttClient

Item = TypeVar("Item")
_Input = TypeVar("_Input", bound="MqttInput")  # start() returns the subclass it was called on
DEFAULT_QUEUE = 8192
READ_BATCH = 1024


class MqttInput(ABC, Generic[Item]):
    kind: str = ""

    def __init__(self, client: MqttClient, topic_filter: str, *, max_payload: int,
                 max_queue: int = DEFAULT_QUEUE, qos: int = 1) -> None:
        if max_payload < 1 or max_queue < 1:
            raise ValueError("max_payload and max_queue must be >= 1")
        self.client = client
        self.topic_filter = topic_filter
        self.max_payload = int(max_payload)
        self.max_queue = int(max_queue)
        self.qos = qos
        self.messages = 0
        self.accepted = 0
        self.queue_drops = 0
        self.unread = 0  # accepted, never handed to the pipeline (see the module doc)
        self.rejected: Counter[str] = Counter()  # by kind; the kinds are a fixed small set
        self._q: deque[Item] = deque()
        self._cond = threading.Condition()
        self._started = False

    def start(self: _Input) -> _Input:
        if not self._started:
            self._started = True
            self.client.subscribe(self.topic_filter, self._on_message, self.qos)
        return self

    def stop(self) -> None:
        if self._started:
            self._started = False
            self.client.unsubscribe(self.topic_filter)
        with self._cond:  # what still waits will never be read: counted, not kept
            self.unread += len(self._q)
            self._q.clear()

    def lost(self, n: int) -> None:
        """``n`` items returned by :meth:`read` that the pipeline never got."""
        with self._cond:
            self.unread += n

    def _on_message(self, topic: str, payload: bytes, t: float) -> None:
        """paho's thread: check, parse, queue (never raises for any payload).

        Under the inbox lock, so :meth:`counters` (another thread) sees consistent counts
        and a parser's tables never change while they are read.
        """
        with self._cond:
            self.messages += 1
            if len(payload) > self.max_payload:
                self.rejected["oversized"] += 1
                return
            item = self.parse(topic, payload, t)
            if isinstance(item, str):
                self.rejected[item] += 1
                return
            if len(self._q) >= self.max_queue:
                self.queue_drops += 1
                return
            self._q.append(item)
            self.accepted += 1
            self._cond.notify()

    @abstractmethod
    def parse(self, topic: str, payload: bytes, t: float) -> Item | str:
        """The item for one message, or the name of the rejection (counted)."""

    def read(self, timeout: float, max_items: int = READ_BATCH) -> list[Item]:
        """What has arrived (waiting up to ``timeout`` s for the first item); [] on timeout."""
        with self._cond:
            if not self._q and timeout > 0:
                self._cond.wait(timeout)
            n = min(len(self._q), max_items)
            return [self._q.popleft() for _ in range(n)]

    @property
    def pending(self) -> int:
        return len(self._q)

    def caught_up_to(self, now: float, last_returned_t: float | None) -> float | None:
        """Up to which receive time everything that arrived has been returned by :meth:`read`.

        An empty inbox: up to ``now``. Otherwise up to the receive time of the last item
        returned (the inbox is first in, first out, and paho's thread stamps the items in
        arrival order), so at a high message rate, where the inbox is seldom empty, the live
        timers still follow the input instead of waiting for a quiet moment.
        """
        with self._cond:
            return now if not self._q else last_returned_t

    def counters(self) -> dict[str, Any]:
        """Messages, accepted, queue_drops, pending (in the inbox now), offered, unread, lost
        (see the module doc), rejected by kind, and whether the broker has acknowledged the
        subscription (on the current connection)."""
        subscribed = self._started and self.client.is_subscribed(self.topic_filter)
        with self._cond:
            return {"subscribed": subscribed, "messages": self.messages, "accepted": self.accepted,
                    "queue_drops": self.queue_drops, "pending": len(self._q),
                    "offered": self.accepted + self.queue_drops, "unread": self.unread,
                    "lost": self.queue_drops + self.unread, "rejected": dict(sorted(self.rejected.items())),
                    **self._more_counters()}

    def _more_counters(self) -> dict[str, Any]:
        """A subclass's own counters (called under the inbox lock)."""
        return {}
