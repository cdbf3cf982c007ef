"""ROS 2 message types from their ``.msg`` definitions: fields, DDS names, REP-2011 type hashes.

The definitions are the concatenated ``.msg`` texts of :mod:`pfdoa.sinks.ros` (the message's
own fields, then each sub-message after a line of ``=`` and ``MSG: pkg/Type``), so every
layout we publish is written once. :func:`parse_msgdef` turns one into :class:`MsgType`
descriptions (constants, comments and default values dropped: they are not on the wire);
the DDS binding (:mod:`pfdoa.ros2.dds`) builds its types from them and this module gives:

* the names ROS 2's DDS middlewares use: topic ``/a/b`` is DDS topic ``rt/a/b``, type
  ``pkg/msg/T`` is DDS type ``pkg::msg::dds_::T_`` (:func:`dds_topic_name`, :func:`dds_type_name`);
* the type hash ``RIHS01_<sha256 hex>`` of REP-2011 (ROS Interface Hashing Standard, version
  1), which ROS 2 Iron and later put into every endpoint's USER_DATA QoS as
  ``typehash=RIHS01_...;`` (:func:`type_hash`, :func:`user_data`).

The hash is the SHA-256 of a JSON text of the type's description (the fields of
``type_description_interfaces/msg/TypeDescription``): the type and, sorted by name, every
type it refers to, directly or not; each field as its name and its type (``type_id`` of
``type_description_interfaces/msg/FieldType``, ``capacity``, ``string_capacity``,
``nested_type_name``), without default values; keys in that order, ``", "`` and ``": "``
as separators, ASCII. ``tests/unit/test_ros2_typedesc.py`` checks every type we use against the
hashes ROS 2 generated for them.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass

# Primitive .msg types -> type_description_interfaces/msg/FieldType ids. In ROS 2 a .msg
# `char` is an unsigned 8-bit integer and `byte` an octet (design.ros2.org, "Interfaces").
PRIMITIVE_IDS = {
    "int8": 2, "uint8": 3, "char": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8, "uint64": 9,
    "float32": 10, "float64": 11, "bool": 15, "byte": 16, "string": 17, "wstring": 18,
}
NESTED_ID = 1
BOUNDED_STRING_IDS = {"string": 21, "wstring": 22}
# FieldType ids of the containers: the element's id plus this.
ARRAY_OFFSET, BOUNDED_SEQUENCE_OFFSET, SEQUENCE_OFFSET = 48, 96, 144

RIHS01_PREFIX = "RIHS01_"
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*$")
_TYPE = re.compile(r"(?P<base>[A-Za-z][A-Za-z0-9_/]*)(?:<=(?P<strbound>\d+))?(?:\[(?P<arr>(?:<=)?\d*)\])?$")


@dataclass(frozen=True)
class FieldType:
    """One field's type: a primitive (``base`` as in .msg) or a nested ``pkg/msg/T``."""

    base: str
    nested: bool = False
    array: int | None = None  # fixed length T[N]
    sequence: bool = False  # T[] or T[<=N]
    bound: int | None = None  # T[<=N]
    string_bound: int | None = None  # string<=N

    def type_id(self) -> int:
        if self.nested:
            element = NESTED_ID
        elif self.string_bound is not None:
            element = BOUNDED_STRING_IDS[self.base]
        else:
            element = PRIMITIVE_IDS[self.base]
        if self.array is not None:
            return element + ARRAY_OFFSET
        if self.sequence:
            return element + (BOUNDED_SEQUENCE_OFFSET if self.bound is not None else SEQUENCE_OFFSET)
        return element


@dataclass(frozen=True)
class Field:
    name: str
    type: FieldType


@dataclass(frozen=True)
class MsgType:
    name: str  # pkg/msg/T
    fields: tuple[Field, ...]

    def field(self, name: str) -> Field:
        return next(f for f in self.fields if f.name == name)


def full_name(name: str, package: str) -> str:
    """``T`` (in ``package``), ``pkg/T`` or ``pkg/msg/T`` -> ``pkg/msg/T``."""
    parts = name.split("/")
    if len(parts) == 1:
        return f"{package}/msg/{parts[0]}"
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and parts[1] == "msg":
        return name
    raise ValueError(f"not a message type name: {name!r}")


def _field_type(text: str, package: str) -> FieldType:
    m = _TYPE.match(text)
    if not m:
        raise ValueError(f"not a field type: {text!r}")
    base, strbound, arr = m["base"], m["strbound"], m["arr"]
    kw: dict = {}
    if arr is not None:
        if arr == "":
            kw["sequence"] = True
        elif arr.startswith("<="):
            kw.update(sequence=True, bound=int(arr[2:]))
        else:
            kw["array"] = int(arr)
    if base in PRIMITIVE_IDS:
        if strbound is not None:
            if base not in BOUNDED_STRING_IDS:
                raise ValueError(f"only strings have a bound: {text!r}")
            kw["string_bound"] = int(strbound)
        return FieldType(base, **kw)
    if strbound is not None:
        raise ValueError(f"only strings have a bound: {text!r}")
    return FieldType(full_name(base, package), nested=True, **kw)


def _fields(text: str, package: str) -> tuple[Field, ...]:
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        type_text, _, rest = line.partition(" ")
        rest = rest.strip()
        name = re.split(r"[\s=]", rest, maxsplit=1)[0]
        if rest[len(name):].lstrip().startswith("="):
            continue  # a constant (NAME=VALUE): not a field
        if not _NAME.match(name):
            raise ValueError(f"not a field name: {name!r} in {raw!r}")
        out.append(Field(name, _field_type(type_text, package)))
    return tuple(out)


def parse_msgdef(type_name: str, text: str) -> dict[str, MsgType]:
    """Every type of a concatenated definition (``type_name``'s own fields first), by ``pkg/msg/T``."""
    sections = re.split(r"^=+\s*$", text, flags=re.M)
    types: dict[str, MsgType] = {}
    for i, section in enumerate(sections):
        if i == 0:
            name = full_name(type_name, "")
            body = section
        else:
            head, _, body = section.strip("\n").partition("\n")
            if not head.startswith("MSG: "):
                raise ValueError(f"a sub-message section must start with 'MSG: pkg/Type', got {head!r}")
            name = full_name(head[5:].strip(), "")
        types[name] = MsgType(name, _fields(body, name.split("/")[0]))
    for t in types.values():
        for f in t.fields:
            if f.type.nested and f.type.base not in types:
                raise ValueError(f"{t.name}.{f.name}: {f.type.base} is not defined in the text")
    return types


def referenced(name: str, types: dict[str, MsgType]) -> list[str]:
    """Every type ``name`` refers to, directly or through others, sorted by name."""
    seen: set[str] = set()
    todo = [f.type.base for f in types[name].fields if f.type.nested]
    while todo:
        n = todo.pop()
        if n not in seen:
            seen.add(n)
            todo.extend(f.type.base for f in types[n].fields if f.type.nested)
    return sorted(seen)


def _individual(t: MsgType) -> dict:
    return {"type_name": t.name, "fields": [{"name": f.name, "type": {
        "type_id": f.type.type_id(),
        "capacity": f.type.array if f.type.array is not None else (f.type.bound or 0),
        "string_capacity": f.type.string_bound or 0,
        "nested_type_name": f.type.base if f.type.nested else "",
    }} for f in t.fields]}


def hashable_json(name: str, types: dict[str, MsgType]) -> str:
    """The text REP-2011's RIHS01 hashes (see the module doc)."""
    doc = {"type_description": _individual(types[name]),
           "referenced_type_descriptions": [_individual(types[n]) for n in referenced(name, types)]}
    return json.dumps(doc, ensure_ascii=True, separators=(", ", ": "), sort_keys=False, allow_nan=False)


def type_hash(name: str, types: dict[str, MsgType]) -> str:
    """``RIHS01_<hex>`` of ``name`` (``pkg/msg/T``) described by ``types``."""
    return RIHS01_PREFIX + hashlib.sha256(hashable_json(name, types).encode("utf-8")).hexdigest()


def user_data(name: str, types: dict[str, MsgType]) -> bytes:
    """The endpoint USER_DATA of ROS 2 Iron and later: ``typehash=RIHS01_...;``."""
    return f"typehash={type_hash(name, types)};".encode("ascii")


def dds_type_name(name: str) -> str:
    """``pkg/msg/T`` -> ``pkg::msg::dds_::T_`` (the DDS type of ROS 2's middlewares)."""
    pkg, sub, t = full_name(name, "").split("/")
    return f"{pkg}::{sub}::dds_::{t}_"


def dds_topic_name(topic: str) -> str:
    """A fully qualified ROS 2 topic ``/a/b`` -> DDS topic ``rt/a/b``."""
    if not topic.startswith("/"):
        raise ValueError(f"not a fully qualified topic name: {topic!r}")
    return "rt" + topic
