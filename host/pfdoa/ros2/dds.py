"""DDS for the ROS 2 output: one Cyclone DDS participant, ROS 2's types, names and QoS.

Needs the optional extra ``ros2`` (PyPI ``cyclonedds``). The DDS types are built from the
``.msg`` definitions (:mod:`pfdoa.ros2.typedesc`), named as ROS 2's middlewares name them
(``pkg::msg::dds_::T_``), final (plain CDR, XCDR1, as ROS 2 sends); every endpoint carries
``typehash=RIHS01_...;`` in its USER_DATA (what ROS 2 Iron and later read; Humble ignores
it) and the participant ``enclave=/;`` (what ROS 2 participants carry).

Configuration: Cyclone DDS's own (``$CYCLONEDDS_URI``: network interfaces, peers,
multicast; ROS 2's ``rmw_cyclonedds_cpp`` reads the same variable), plus two settings of
ours added after it: no sample larger than :data:`MAX_SAMPLE_BYTES` is taken from the
network (what is larger is dropped by Cyclone DDS), so a peer cannot make the gateway hold
large messages (a reader keeps at most its history depth); and the discovery messages carry
key hashes, which Fast DDS (ROS 2's default middleware) needs to see our writers and the
participant leave at once (without them its nodes keep them until the participant's lease
runs out).
"""

from __future__ import annotations

import logging
import os
from typing import Any, Iterable, Mapping

import cyclonedds.idl.types as T
from cyclonedds.core import DDSException, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from pfdoa.ros2 import typedesc as td
from pfdoa.ros2.typedesc import FieldType, MsgType

log = logging.getLogger(__name__)

# Our largest message is the DiagnosticArray: ~330 bytes an anchor (300 anchors: 97 kB). A
# reader holds at most its depth of samples this size (the odometry's: 200 x 256 KiB).
MAX_SAMPLE_BYTES = 256 * 1024
WRITE_BLOCK_S = 0.01  # a reliable write waits at most this for room in its history (then: dropped)
_OURS = ('<CycloneDDS><Domain id="any"><Internal><MaxSampleSize>%dB</MaxSampleSize>'
         '<GenerateKeyhash>true</GenerateKeyhash></Internal></Domain></CycloneDDS>' % MAX_SAMPLE_BYTES)

# The binding's generic containers are subscripted at run time (their own __class_getitem__).
_ARRAY: Any = T.array
_SEQUENCE: Any = T.sequence
_BOUNDED_STR: Any = T.bounded_str
_PRIMITIVES: dict[str, Any] = {
    "bool": bool, "byte": T.byte, "char": T.uint8, "int8": T.int8, "uint8": T.uint8, "int16": T.int16,
    "uint16": T.uint16, "int32": T.int32, "uint32": T.uint32, "int64": T.int64, "uint64": T.uint64,
    "float32": T.float32, "float64": T.float64, "string": str,
}


class Types:
    """The DDS classes of ``msgdefs`` (ROS type name -> concatenated .msg text), and samples
    of them from the plain dicts :mod:`pfdoa.sinks.ros` makes."""

    def __init__(self, msgdefs: Mapping[str, str]) -> None:
        self.types: dict[str, MsgType] = {}
        for name, text in msgdefs.items():
            self.types.update(td.parse_msgdef(name, text))
        self.classes: dict[str, type[IdlStruct]] = {}
        for name in self.types:
            self.idl(name)

    def idl(self, name: str) -> type[IdlStruct]:
        cls = self.classes.get(name)
        if cls is None:
            t = self.types[name]
            annotations = {f.name: self._annotation(f.type) for f in t.fields}
            cls = self.classes[name] = make_idl_struct(name.split("/")[-1] + "_", td.dds_type_name(name), annotations)
        return cls

    def _annotation(self, ft: FieldType) -> Any:
        if ft.nested:
            base = self.idl(ft.base)
        elif ft.string_bound is not None and ft.base == "string":
            base = _BOUNDED_STR[ft.string_bound]
        elif ft.base in _PRIMITIVES:
            base = _PRIMITIVES[ft.base]
        else:
            raise ValueError(f"no DDS type for .msg {ft.base!r}")
        if ft.array is not None:
            return _ARRAY[base, ft.array]
        if ft.sequence:
            return _SEQUENCE[base, ft.bound] if ft.bound is not None else _SEQUENCE[base]
        return base

    def hash(self, name: str) -> str:
        return td.type_hash(name, self.types)

    def sample(self, name: str, value: Mapping[str, Any]) -> IdlStruct:
        """An instance of ``name``'s class from a dict (missing fields: zero, empty)."""
        t = self.types[name]
        return self.classes[name](**{f.name: self._value(f.type, value.get(f.name)) for f in t.fields})

    def _value(self, ft: FieldType, v: Any) -> Any:
        if ft.array is not None or ft.sequence:
            items = [self._scalar(ft, x) for x in (v or ())]
            if ft.array is not None and len(items) != ft.array:
                raise ValueError(f"{ft.base}[{ft.array}] needs {ft.array} values, got {len(items)}")
            return items
        return self._scalar(ft, v)

    def _scalar(self, ft: FieldType, v: Any) -> Any:
        if ft.nested:
            return self.sample(ft.base, v or {})
        if ft.base == "string":
            return "" if v is None else str(v)
        if ft.base.startswith("float"):
            return 0.0 if v is None else float(v)
        if ft.base == "bool":
            return bool(v)
        return 0 if v is None else int(v)


def config(environ: Mapping[str, str] | None = None) -> str:
    """Cyclone DDS's configuration: ``$CYCLONEDDS_URI`` (if set), then ours (see the module doc)."""
    env = (os.environ if environ is None else environ).get("CYCLONEDDS_URI", "").strip()
    return f"{env},{_OURS}" if env else _OURS


class Node:
    """One DDS participant on ``domain_id`` with writers and readers of ``types``."""

    def __init__(self, domain_id: int, types: Types) -> None:
        self.types = types
        self.domain_id = int(domain_id)
        self._entities: list = []
        try:
            self._domain = Domain(self.domain_id, config())
            self.participant = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
        except DDSException as exc:
            raise OSError(f"DDS domain {self.domain_id}: {exc}") from None
        self._topics: dict[str, Topic] = {}

    def _topic(self, ros_topic: str, type_name: str) -> Topic:
        name = td.dds_topic_name(ros_topic)
        topic = self._topics.get(name)
        if topic is None:
            topic = self._topics[name] = Topic(self.participant, name, self.types.classes[type_name])
            self._entities.append(topic)
        return topic

    def qos(self, type_name: str, *, reliable: bool, depth: int, transient_local: bool = False,
            keep_all: bool = False) -> Qos:
        """ROS 2's QoS of a topic: reliability, keep-last ``depth`` (``keep_all``: every sample,
        at most ``depth`` held), durability; its type hash."""
        history = [Policy.History.KeepAll, Policy.ResourceLimits(max_samples=depth)] if keep_all \
            else [Policy.History.KeepLast(depth)]
        return Qos(
            Policy.Reliability.Reliable(duration(seconds=WRITE_BLOCK_S)) if reliable else Policy.Reliability.BestEffort,
            Policy.Durability.TransientLocal if transient_local else Policy.Durability.Volatile,
            *history,
            Policy.Userdata(td.user_data(type_name, self.types.types)),
            Policy.DataRepresentation(use_cdrv0_representation=True),
        )

    def writer(self, ros_topic: str, type_name: str, qos: Qos) -> DataWriter:
        w = DataWriter(self.participant, self._topic(ros_topic, type_name), qos)
        self._entities.append(w)
        return w

    def reader(self, ros_topic: str, type_name: str, qos: Qos) -> DataReader:
        r = DataReader(self.participant, self._topic(ros_topic, type_name), qos)
        self._entities.append(r)
        return r

    def delete(self, entity) -> None:
        """Delete one writer or reader now (a beacon that went away)."""
        if entity in self._entities:
            self._entities.remove(entity)
            _delete(entity)

    def close(self) -> None:
        for e in reversed(self._entities):
            _delete(e)
        self._entities.clear()
        self._topics.clear()
        _delete(self.participant)
        _delete(self._domain)


def _delete(entity) -> None:
    # The binding deletes an entity when its Python object is collected; closing must not
    # wait for that (the participant would stay on the network), so it is done here, once.
    try:
        entity.__del__()
    except DDSException as exc:
        log.debug("DDS delete: %s", exc)


def matched(writer: DataWriter) -> int:
    """Subscriptions matched to ``writer`` now."""
    return int(writer.get_publication_matched_status().current_count)


class Waiter:
    """Waits (a bounded time) for data on readers."""

    def __init__(self, node: Node, readers: Iterable[DataReader]) -> None:
        self._ws = WaitSet(node.participant)
        self._conds = [ReadCondition(r, SampleState.NotRead | ViewState.Any | InstanceState.Any) for r in readers]
        for c in self._conds:
            self._ws.attach(c)

    def wait(self, timeout_s: float) -> bool:
        return self._ws.wait(duration(seconds=max(0.0, timeout_s))) > 0

    def close(self) -> None:
        for c in self._conds:
            _delete(c)
        _delete(self._ws)
