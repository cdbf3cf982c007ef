"""What waits to be published: a bounded queue of events and the latest value of each state topic.

Two kinds of message, two policies:

* **Events** (every estimate): each one matters, in order. They wait in a FIFO of at most
  ``max_events`` while the broker is away; when it is full the *oldest* waiting event is
  dropped and counted (``dropped``): after a long outage the newest positions are the
  useful ones, and the count says how many went.
* **State** (retained: health, anchor status, discovery configs, availability): only the
  latest value of a topic matters. One slot per topic, overwritten in place, so a
  disconnected gateway holds one health message, not one per period. At most
  ``max_state_topics`` topics (new topics beyond are refused and counted). Every state
  topic is sent again after each (re)connect (:meth:`Outbox.resend_state`): a broker that
  restarted without persistence has lost its retained messages.

:meth:`Outbox.take` hands out state before events (availability and discovery first, so
a subscriber knows what the backlog of estimates belongs to), but never more than half of
a batch while events wait: a stream of state updates (discovery and ``home`` /
``not_home`` of devices coming and going) used to take every slot, and the estimates
waited until the outbox dropped them (a fleet of 60,000 passing device ids: 84 of 7,492
estimates delivered with the broker up). Not thread-safe: the client calls it under its
lock.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Message:
    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = False


@dataclass
class OutboxCounters:
    events: int = 0  # events accepted
    dropped: int = 0  # events dropped because the queue was full (the oldest go first)
    states: int = 0  # state updates accepted
    state_refused: int = 0  # updates of new state topics beyond max_state_topics


class Outbox:
    def __init__(self, max_events: int, max_state_topics: int = 4096) -> None:
        if max_events < 1 or max_state_topics < 1:
            raise ValueError("max_events and max_state_topics must be >= 1")
        self.max_events = int(max_events)
        self.max_state_topics = int(max_state_topics)
        self.counters = OutboxCounters()
        self._events: deque[Message] = deque()
        self._state: dict[str, Message] = {}
        self._dirty: dict[str, None] = {}  # insertion-ordered set of state topics to send

    def put_event(self, msg: Message) -> None:
        c = self.counters
        c.events += 1
        if len(self._events) >= self.max_events:
            self._events.popleft()
            c.dropped += 1
        self._events.append(msg)

    def put_state(self, msg: Message) -> bool:
        """Set the latest value of ``msg.topic``; False (counted) if the topic table is full."""
        c = self.counters
        if msg.topic not in self._state and len(self._state) >= self.max_state_topics:
            c.state_refused += 1
            return False
        c.states += 1
        self._state[msg.topic] = msg
        self._dirty.pop(msg.topic, None)  # re-inserted last: topics go out in update order
        self._dirty[msg.topic] = None
        return True

    def drop_state(self, topic: str) -> None:
        """Stop holding (and re-sending) ``topic``; what the broker retains stays there."""
        self._state.pop(topic, None)
        self._dirty.pop(topic, None)

    def state(self, topic: str) -> Message | None:
        return self._state.get(topic)

    def resend_state(self) -> None:
        """After a (re)connect: every state topic goes out again."""
        for topic in self._state:
            self._dirty[topic] = None

    def take(self, n: int) -> list[Message]:
        """Up to ``n`` messages to publish now: changed state topics first (at most half of
        them while events wait), then events in order, then more state if there is room."""
        out: list[Message] = []
        self._take_state(out, n if not self._events else max(1, n // 2))
        while self._events and len(out) < n:
            out.append(self._events.popleft())
        self._take_state(out, n)
        return out

    def _take_state(self, out: list[Message], n: int) -> None:
        while self._dirty and len(out) < n:
            topic = next(iter(self._dirty))
            del self._dirty[topic]
            out.append(self._state[topic])

    @property
    def pending_events(self) -> int:
        return len(self._events)

    def __len__(self) -> int:
        return len(self._events) + len(self._dirty)
