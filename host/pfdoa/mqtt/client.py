"""One broker connection (paho-mqtt 2.x): reconnect with backoff, a bounded outbox, subscriptions.

Threads and locks. paho's network loop runs in its own thread (``loop_start``): it
connects, reconnects with exponential backoff (``reconnect_min_s`` doubling up to
``reconnect_max_s``) for as long as the client runs, and calls our callbacks. The
gateway thread only appends to the :class:`~pfdoa.mqtt.outbox.Outbox` under our lock and
never calls paho. A third thread, the *pump*, is the only one that calls
``paho.publish``, and never while holding our lock: paho calls ``on_publish`` with its
own message mutex held, and that callback takes our lock, so holding ours while calling
into paho could deadlock.

Delivery (QoS 1, the default for events and state). The pump hands paho at most
``inflight`` unacknowledged messages at a time, and only while connected; the rest wait
in the outbox. A message handed to paho stays in paho's session until the broker's
PUBACK: paho re-sends it (DUP) after a reconnect, even with a clean session. So an
estimate is either in the outbox, or in paho's window, or acknowledged by the broker:
none is lost while the broker is away, unless the outbox overflows (counted, oldest
first). QoS 1 is at-least-once: a re-sent message can arrive twice.

Availability: the last will is ``offline`` on ``<prefix>/status`` (retained, QoS 1); on
every connect the client sets ``online`` there, and a clean :meth:`MqttClient.stop`
publishes ``offline`` itself (the broker sends the will only when the connection breaks).

Subscriptions are renewed on every connect (a clean session forgets them). Handlers run
in paho's thread: they must be quick (the inputs push into bounded queues) and may not
raise (an exception is counted and logged, never allowed to stop paho's loop).

Refusals that retrying cannot change (CONNACK: bad user name or password, not authorized,
client identifier not valid, unsupported protocol version; MQTT 5's banned and bad
authentication method) stop the client at once: no more attempts, :attr:`MqttClient.fatal`
says why (the gateway ends with exit status 2 on it). A broker that is down, or refuses
with "server unavailable", is retried with backoff; the log says so once, then every
:data:`RETRY_LOG_S` while it lasts.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Callable

from pfdoa.errors import InputError
from pfdoa.mqtt.outbox import Message, Outbox
from pfdoa.mqtt.url import MqttUrl

log = logging.getLogger(__name__)

ONLINE = b"online"
OFFLINE = b"offline"
# CONNACK reason codes (MQTT 5 values; paho maps 3.1.1's return codes 1, 2, 4, 5 onto them)
# that retrying cannot change: unsupported protocol version, client identifier not valid,
# bad user name or password, not authorized, banned, bad authentication method.
PERMANENT_REFUSALS = frozenset((0x84, 0x85, 0x86, 0x87, 0x8A, 0x8C))
RETRY_LOG_S = 60.0  # while the broker stays away, "still cannot connect" this often

Handler = Callable[[str, bytes, float], None]  # (topic, payload, receive time)


@dataclass(frozen=True)
class ClientConfig:
    url: MqttUrl
    password: str | None = None
    ca_file: str | None = None  # mqtts: CA bundle to verify the broker (None: the system's)
    client_id: str = ""  # "" = pfdoa-<random>: two clients with one id throw each other off
    keepalive_s: int = 30
    clean_session: bool = True
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 30.0
    queue_size: int = 10000  # events held while the broker is away (oldest dropped beyond)
    max_state_topics: int = 4096
    inflight: int = 64  # QoS >= 1 messages handed to paho before their PUBACK
    event_qos: int = 1
    state_qos: int = 1


@dataclass
class ClientStats:
    connects: int = 0
    connect_failures: int = 0  # TCP/TLS attempts that failed (broker down, refused port, DNS)
    disconnects: int = 0
    refused: int = 0  # CONNACK refusals (bad credentials, not authorised, ...)
    last_refusal: str = ""
    sent: int = 0  # messages handed to paho
    delivered: int = 0  # acknowledged by the broker (QoS 1) or written to the socket (QoS 0)
    lost_qos0: int = 0  # QoS 0 messages that met a broken connection
    publish_errors: int = 0
    received: int = 0
    unexpected: int = 0  # messages on topics no handler subscribed to
    handler_errors: int = 0
    subscribe_refused: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _paho():
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        raise InputError("--mqtt needs the paho-mqtt package: pip install 'pfdoa[mqtt]'") from None
    return mqtt


class MqttClient:
    """A broker connection shared by the publisher and the inputs (see the module doc)."""

    def __init__(self, cfg: ClientConfig, clock: Callable[[], float] = time.time,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        """``clock``: the receive times handed to the handlers; ``monotonic``: when the
        log repeats that the broker is still away."""
        mqtt = _paho()
        self.cfg = cfg
        self.clock = clock
        self.monotonic = monotonic
        self.fatal: str | None = None  # a refusal that retrying cannot change (see the module doc)
        self.prefix = cfg.url.prefix
        self.status_topic = f"{self.prefix}/status"
        self.stats = ClientStats()
        self.outbox = Outbox(cfg.queue_size, cfg.max_state_topics)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._connected = False
        self._running = False
        self._inflight = 0
        self._subs: dict[str, tuple[int, Handler]] = {}
        self._sub_mids: dict[int, list[str]] = {}  # SUBSCRIBE packet id -> its filters
        self._active: set[str] = set()  # filters the broker has acknowledged on this connection
        self._refusals_logged: set[str] = set()
        self._outage: tuple[float, int] | None = None  # (monotonic start, failures then) of the outage
        self._outage_logged = 0.0  # monotonic time of its last log line
        self._pump: threading.Thread | None = None
        self.client_id = cfg.client_id or f"pfdoa-{uuid.uuid4().hex[:12]}"
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=self.client_id,
                        clean_session=cfg.clean_session, protocol=mqtt.MQTTv311)
        if cfg.url.user:
            c.username_pw_set(cfg.url.user, cfg.password)
        if cfg.url.tls:
            try:
                c.tls_set(ca_certs=cfg.ca_file)
            except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
                raise InputError(f"--mqtt-ca-file {cfg.ca_file or '(the system CA store)'}: {exc}") from None
        c.will_set(self.status_topic, OFFLINE, qos=1, retain=True)
        c.reconnect_delay_set(cfg.reconnect_min_s, cfg.reconnect_max_s)
        c.max_inflight_messages_set(cfg.inflight)
        c.max_queued_messages_set(0)  # the outbox bounds the queue; paho holds <= inflight
        c.on_socket_open = self._on_socket_open
        c.on_connect = self._on_connect
        c.on_connect_fail = self._on_connect_fail
        c.on_disconnect = self._on_disconnect
        c.on_publish = self._on_publish
        c.on_message = self._on_unexpected
        c.on_subscribe = self._on_subscribe
        self._paho = c
        self._mqtt = mqtt

    # -- life cycle -------------------------------------------------------------------

    def start(self) -> "MqttClient":
        """Connect in the background (retrying with backoff until it succeeds) and return."""
        with self._lock:
            if self._running:
                return self
            self._running = True
        self.outbox.put_state(Message(self.status_topic, ONLINE, self.cfg.state_qos, True))
        self._pump = threading.Thread(target=self._pump_loop, name="mqtt-pump", daemon=True)
        self._pump.start()
        self._paho.connect_async(self.cfg.url.host, self.cfg.url.port, keepalive=self.cfg.keepalive_s)
        self._paho.loop_start()
        return self

    def stop(self, flush_timeout_s: float = 5.0) -> int:
        """Deliver what is waiting (up to ``flush_timeout_s``), say ``offline``, disconnect.

        Returns the number of messages not delivered (also logged): never a silent loss.
        """
        with self._lock:
            if not self._running:
                return 0
        self.flush(flush_timeout_s)
        with self._lock:
            self._running = False
            undelivered = len(self.outbox) + self._inflight
            connected = self._connected
            self._cond.notify_all()
        if self._pump is not None:
            self._pump.join(timeout=2.0)
        if connected:
            with self._lock:  # counted like every other message (its PUBACK is counted delivered)
                self._inflight += 1
                self.stats.sent += 1
            info = self._paho.publish(self.status_topic, OFFLINE, qos=1, retain=True)
            try:
                info.wait_for_publish(timeout=1.0)
            except (RuntimeError, ValueError):
                pass
        self._paho.disconnect()
        self._paho.loop_stop()
        if undelivered and self.fatal is None:  # a refused client says why once, elsewhere
            log.warning("mqtt: %d message(s) not delivered at shutdown", undelivered)
        return undelivered

    def __enter__(self) -> "MqttClient":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def inflight(self) -> int:
        return self._inflight

    def wait_connected(self, timeout_s: float) -> bool:
        """False on timeout, or at once when the broker refused for good (:attr:`fatal`)."""
        with self._cond:
            return bool(self._cond.wait_for(lambda: self._connected or self.fatal is not None, timeout_s)) \
                and self._connected

    def flush(self, timeout_s: float) -> bool:
        """Wait until everything queued has been delivered; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not len(self.outbox) and self._inflight == 0, timeout_s)

    # -- publishing -------------------------------------------------------------------

    def publish(self, topic: str, payload: bytes, qos: int | None = None) -> None:
        """Queue an event (not retained): delivered in order, held while disconnected."""
        msg = Message(topic, payload, self.cfg.event_qos if qos is None else qos, False)
        with self._cond:
            self.outbox.put_event(msg)
            self._cond.notify_all()

    def set_state(self, topic: str, payload: bytes, qos: int | None = None) -> bool:
        """Set a retained state topic (latest value wins; re-sent after every reconnect)."""
        msg = Message(topic, payload, self.cfg.state_qos if qos is None else qos, True)
        with self._cond:
            ok = self.outbox.put_state(msg)
            self._cond.notify_all()
        return ok

    def drop_state(self, topic: str) -> None:
        """Stop holding and re-sending a state topic (the broker keeps what it retained)."""
        with self._lock:
            self.outbox.drop_state(topic)

    def summary(self) -> dict:
        """Counters for the health message: connection, delivery, queue."""
        with self._lock:
            d = self.stats.as_dict()
            c = self.outbox.counters
            d.update(connected=self._connected, inflight=self._inflight, queued=self.outbox.pending_events,
                     queue_dropped=c.dropped, state_refused=c.state_refused)
        return d

    def _pump_loop(self) -> None:
        window = max(1, self.cfg.inflight)
        while True:
            with self._cond:
                self._cond.wait_for(lambda: not self._running or (
                    self._connected and len(self.outbox) > 0 and self._inflight < window))
                if not self._running:
                    return
                batch = self.outbox.take(window - self._inflight)
                self._inflight += len(batch)
            for m in batch:
                self._send(m)

    def _send(self, m: Message) -> None:
        mqtt = self._mqtt
        try:
            info = self._paho.publish(m.topic, m.payload, qos=m.qos, retain=m.retain)
            rc = info.rc
        except ValueError as exc:  # an invalid topic: a bug upstream, never a reason to stop
            log.error("mqtt: cannot publish on %r: %s", m.topic, exc)
            rc = None
        with self._cond:
            self.stats.sent += 1
            if rc == mqtt.MQTT_ERR_SUCCESS:
                pass
            elif rc == mqtt.MQTT_ERR_NO_CONN and m.qos > 0:
                pass  # paho keeps it and sends it after the reconnect
            elif rc == mqtt.MQTT_ERR_NO_CONN:
                self.stats.lost_qos0 += 1
                self._inflight -= 1
            else:
                self.stats.publish_errors += 1
                self._inflight -= 1
            self._cond.notify_all()

    # -- subscriptions ----------------------------------------------------------------

    def subscribe(self, topic_filter: str, handler: Handler, qos: int = 1) -> None:
        """Call ``handler(topic, payload, t)`` for every message matching ``topic_filter``."""

        def on_message(_client, _userdata, msg) -> None:
            t = self.clock()
            self.stats.received += 1
            try:
                handler(msg.topic, bytes(msg.payload), t)
            except Exception:  # a handler bug must not stop paho's network loop
                self.stats.handler_errors += 1
                log.exception("mqtt: handler for %s failed", topic_filter)

        self._paho.message_callback_add(topic_filter, on_message)
        with self._lock:
            self._subs[topic_filter] = (qos, handler)
            connected = self._connected
        if connected:
            self._subscribe([(topic_filter, qos)])

    def _subscribe(self, subs: list[tuple[str, int]]) -> None:
        with self._lock:  # the SUBACK may come before paho returns: hold it until the mid is known
            _rc, mid = self._paho.subscribe(subs)
            if mid is not None:
                self._sub_mids[mid] = [f for f, _q in subs]

    def wait_subscribed(self, topic_filter: str, timeout_s: float) -> bool:
        """Wait until the broker has acknowledged ``topic_filter`` on the current connection."""
        with self._cond:
            return self._cond.wait_for(lambda: topic_filter in self._active, timeout_s)

    def is_subscribed(self, topic_filter: str) -> bool:
        """Has the broker acknowledged ``topic_filter`` on the current connection?"""
        with self._lock:
            return topic_filter in self._active

    def unsubscribe(self, topic_filter: str) -> None:
        with self._lock:
            known = self._subs.pop(topic_filter, None) is not None
            connected = self._connected
        if known:
            self._paho.message_callback_remove(topic_filter)
            with self._lock:
                self._active.discard(topic_filter)
            if connected:
                self._paho.unsubscribe(topic_filter)

    # -- paho callbacks (paho's thread) -----------------------------------------------

    @staticmethod
    def _on_socket_open(_client, _userdata, sock) -> None:
        # Estimates are small messages that should leave at once: without TCP_NODELAY,
        # Nagle's algorithm holds one back until the previous one is acknowledged, and the
        # peer's delayed ACK makes that ~40 ms (docs/fleet.md: the broker's set_tcp_nodelay).
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except (OSError, AttributeError):  # not a TCP socket (a proxy, a test double)
            pass

    def _on_connect(self, client, _userdata, _flags, reason_code, _properties) -> None:
        if reason_code.is_failure:
            why = str(reason_code)
            permanent = reason_code.value in PERMANENT_REFUSALS
            with self._cond:
                self.stats.refused += 1
                self.stats.last_refusal = why
                if permanent:
                    self.fatal = why
                self._cond.notify_all()
            if permanent:  # no more attempts: the same credentials get the same answer
                client.disconnect()
            elif why not in self._refusals_logged:  # once per reason: paho retries with backoff
                self._refusals_logged.add(why)
                log.error("mqtt: %s refused the connection: %s; retrying", self.cfg.url, why)
            return
        if self._outage is not None:
            log.info("mqtt: %s reachable again after %d failed attempt(s)", self.cfg.url,
                     self.stats.connect_failures - self._outage[1])
            self._outage = None
        with self._cond:
            self._connected = True
            self.stats.connects += 1
            self.outbox.resend_state()
            subs = [(f, q) for f, (q, _h) in self._subs.items()]
            self._cond.notify_all()
        log.info("mqtt: connected to %s as %s", self.cfg.url, self.client_id)
        if subs:
            self._subscribe(subs)

    def _on_connect_fail(self, _client, _userdata) -> None:
        with self._cond:
            self.stats.connect_failures += 1
        now = self.monotonic()
        # Once when an outage starts, then every RETRY_LOG_S: paho retries with backoff and
        # would fill the log, yet a broker that stays away should not go unsaid.
        if self._outage is None:
            self._outage = (now, self.stats.connect_failures - 1)
            self._outage_logged = now
            log.warning("mqtt: cannot connect to %s (broker down or unreachable); retrying every %.1f..%.1f s",
                        self.cfg.url, self.cfg.reconnect_min_s, self.cfg.reconnect_max_s)
        elif now - self._outage_logged >= RETRY_LOG_S:
            self._outage_logged = now
            log.warning("mqtt: still cannot connect to %s: %d attempts in %.0f s; retrying", self.cfg.url,
                        self.stats.connect_failures - self._outage[1], now - self._outage[0])

    def _on_disconnect(self, _client, _userdata, _flags, reason_code, _properties) -> None:
        with self._cond:
            was = self._connected
            self._connected = False
            self._active.clear()
            if was:
                self.stats.disconnects += 1
            self._cond.notify_all()
        if was and self._running:
            log.warning("mqtt: disconnected from %s (%s); reconnecting", self.cfg.url, reason_code)

    def _on_publish(self, _client, _userdata, _mid, _reason_code, _properties) -> None:
        with self._cond:
            self._inflight -= 1
            self.stats.delivered += 1
            self._cond.notify_all()

    def _on_subscribe(self, _client, _userdata, mid, reason_codes, _properties) -> None:
        with self._cond:
            filters = self._sub_mids.pop(mid, [])
            for f, rc in zip(filters, reason_codes):
                if not rc.is_failure:
                    self._active.add(f)
            self._cond.notify_all()
        bad = [rc for rc in reason_codes if rc.is_failure]
        if bad:
            self.stats.subscribe_refused += len(bad)
            log.error("mqtt: subscription refused: %s", ", ".join(str(rc) for rc in bad))

    def _on_unexpected(self, _client, _userdata, _msg) -> None:
        self.stats.unexpected += 1
