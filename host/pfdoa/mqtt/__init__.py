"""MQTT for fleets: publish estimates, health and anchor status; take anchor readings from a broker.

Modules (python-can style: small ones behind small interfaces):

* :mod:`.url` - ``mqtt[s]://[user@]host[:port]/prefix``, the password from a file or the
  environment (never the command line).
* :mod:`.outbox` - what waits to be published: a bounded FIFO of events (estimates) and the
  latest value of each retained state topic.
* :mod:`.client` - one broker connection (paho-mqtt 2.x): reconnect with backoff, last will,
  QoS 1 delivery of everything queued, subscriptions renewed on reconnect.
* :mod:`.publisher` - topics, QoS and retain of estimates, health and anchor status.
* :mod:`.discovery` - Home Assistant MQTT discovery configs.
* :mod:`.inputs` - the base class of inputs (bounded inbox, rejections counted); its two
  kinds are the gateway's (:mod:`pfdoa.gateway.inputs.mqtt_frames`, our UART frames as
  payloads, and :mod:`pfdoa.gateway.inputs.espresense`, ESPresense nodes' JSON).
* :mod:`.config` - the site file's ``[mqtt]`` table and the command-line overrides.

paho-mqtt is an optional dependency (``pip install 'pfdoa[mqtt]'``): it is imported when
a client is created, so importing this package does not need it.
"""
