"""The gateway's estimates, health and anchor status on an MQTT broker (``--mqtt URL``).

A thin sink over :class:`~pfdoa.mqtt.publisher.Publisher` (topics, QoS, retain and Home
Assistant discovery: docs/fleet.md). Every record is one pose on ``<prefix>/<beacon>/pose``
(the JSON output line's fields, so fields added to :mod:`pfdoa.output` appear here too);
every health period the snapshot the other sinks get goes to ``<prefix>/health`` and each
anchor's part of it to ``<prefix>/anchors/<id>/status``. The inputs that read from the
same connection (``--mqtt-input``, registered in :attr:`MqttSink.inputs`) add their
counters to the health (``inputs``) and, for ESPresense rooms, each room's ``room``,
``readings``, ``last_t`` and ``age_s`` to its anchor's status. A beacon the gateway lets
go (an ESPresense device timed out or evicted) turns ``not_home``. With ``places`` (the site
has rooms or floors, :mod:`pfdoa.rooms`) a tracked beacon's state is its room (else its
floor, else ``home``) and its pose carries ``confidence``, as ESPresense-companion's do.

The pipeline thread only queues (the client's bounded outbox); the broker being away
never blocks it. A refusal that retrying cannot change (:attr:`MqttSink.fatal`) ends the
gateway's run with exit status 2. On close the client delivers what is waiting (at most
``flush_timeout_s``; no wait when the broker has only refused the credentials) and
:attr:`undelivered` says how many messages it could not deliver.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from pfdoa.errors import InputError
from pfdoa.gateway.health import HealthSnapshot
from pfdoa.mqtt.client import MqttClient
from pfdoa.mqtt.config import MqttSettings
from pfdoa.mqtt.publisher import Publisher
from pfdoa.sinks.base import Sink


class MqttSink(Sink):
    name = "mqtt"

    def __init__(self, settings: MqttSettings, clock: Callable[[], float] = time.time,
                 default_beacon: str = "b0", flush_timeout_s: float = 10.0, places: bool = False) -> None:
        self.settings = settings
        self.default_beacon = default_beacon
        self.flush_timeout_s = float(flush_timeout_s)
        self.client = MqttClient(settings.client, clock=clock)
        self.publisher = Publisher(self.client, settings.publisher, places=places)
        self.undelivered = 0
        self.inputs: list = []  # pfdoa.mqtt.inputs.MqttInput on this client (pfdoa.sinks.options.mqtt_input)
        self.client.start()

    def write(self, record) -> None:
        self.publisher.estimate(getattr(record, "beacon", None) or self.default_beacon, record)

    def health(self, snapshot: HealthSnapshot) -> None:
        body = snapshot.to_json()
        anchors: dict[int, dict] = {int(a): st for a, st in body.get("anchors", {}).items()}
        if self.inputs:
            # Beside the snapshot's inputs (by input name), each broker input by its kind.
            body["inputs"] = {**body.get("inputs", {}), **{inp.kind: inp.counters() for inp in self.inputs}}
            for inp in self.inputs:
                status = getattr(inp, "anchor_status", None)
                if status is not None:
                    for aid, room in status(snapshot.t).items():
                        anchors[aid] = {**anchors.get(aid, {}), **room}
        self.publisher.health(body)
        for aid, st in anchors.items():
            self.publisher.anchor_status(aid, st)

    def beacon_gone(self, beacon: str, reason: str) -> None:
        self.publisher.beacon_gone(beacon)

    def fatal(self) -> InputError | None:
        """The broker refused for good (wrong password, not authorised): exit status 2."""
        why = self.client.fatal
        if why is None:
            return None
        return InputError(f"--mqtt {self.settings.client.url}: the broker refused the connection: {why} "
                          "(check the user name, the password and the broker's access rules; retrying would "
                          "get the same answer)")

    def counters(self) -> dict[str, Any] | None:
        """For the final counters: the client's, estimates published, undelivered at close."""
        d = self.client.summary()
        d.update(url=str(self.settings.client.url), estimates=self.publisher.estimates,
                 undelivered=self.undelivered)
        return d

    def _close(self) -> None:
        st = self.client.stats
        # A broker that has only ever refused our credentials will not take them now: no wait.
        refused_only = st.connects == 0 and st.refused > 0
        self.undelivered = self.client.stop(0.0 if refused_only else self.flush_timeout_s)
