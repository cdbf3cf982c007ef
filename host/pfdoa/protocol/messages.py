"""Message dataclasses (SPEC section 1), one per message, for every protocol version.

A class is one message whatever the version that carries it: a version-1 and a version-2
`RSSI_REPORT` both decode to :class:`RssiReport` (version 1 without `beacon`, so 0, beacon
entry 0). Field order is wire order; `pack(version)` gives the payload of that version's
layout, `unpack(payload, version)` parses it. Layouts come from the generated `defs`
(messages.json); a test checks the field names.
"""

from __future__ import annotations

import dataclasses
import struct
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, NamedTuple, Sequence, TypeVar, Union

from . import defs


class Layout(NamedTuple):
    """One message layout: a type code, the fields it carries, their struct."""

    key: str                  # defs.MESSAGES key (V1_ for older versions)
    type: int
    direction: str
    payload_len: int
    crc_extra: int
    fields: tuple[str, ...]
    struct: struct.Struct
    versions: tuple[int, ...]


LAYOUTS: dict[int, Layout] = {
    spec[0]: Layout(key, spec[0], spec[1], spec[2], spec[3], tuple(f for f, _ in spec[4]),
                    struct.Struct(spec[7]), spec[6])
    for key, spec in defs.MESSAGES.items()
}


def _layout_for(name: str, version: int) -> Layout:
    for lay in LAYOUTS.values():
        if defs.MESSAGES[lay.key][5].split(" ", 1)[0] == name and version in lay.versions:
            return lay
    raise ValueError(f"{name} does not exist in protocol version {version}")


class _Message:
    NAME: ClassVar[str]
    TYPE: ClassVar[int]  # type code in the current version

    def layout(self, version: int = defs.PROTO_VERSION) -> Layout:
        return _layout_for(self.NAME, version)

    def pack(self, version: int = defs.PROTO_VERSION) -> bytes:
        lay = self.layout(version)
        self._check_fits(lay)
        try:
            return lay.struct.pack(*[getattr(self, f) for f in lay.fields])
        except struct.error as e:
            raise ValueError(f"{self.NAME}: field out of range: {e}") from None

    def _check_fits(self, lay: Layout) -> None:
        """A field the layout does not carry must hold its default (it would be lost)."""

    @classmethod
    def unpack(cls, payload: bytes, version: int = defs.PROTO_VERSION):
        lay = _layout_for(cls.NAME, version)
        return cls(**dict(zip(lay.fields, lay.struct.unpack(payload))))


def _bytes_field(obj: object, name: str, n: int) -> None:
    """Normalise a u8[n] field to exactly n bytes (shorter values are zero-padded)."""
    v = bytes(getattr(obj, name))
    if len(v) > n:
        raise ValueError(f"{name}: {len(v)} bytes, at most {n}")
    object.__setattr__(obj, name, v.ljust(n, b"\x00"))


@dataclass(frozen=True, slots=True)
class RssiReport(_Message):
    """RSSI_REPORT. `tick_ms` is None when received over CAN (no tick there); `n_readings`
    and `channel` are None over CAN in version 2. `beacon` is the anchor's filter entry
    (0 for a version-1 anchor: its one beacon)."""

    NAME: ClassVar[str] = "RSSI_REPORT"
    TYPE: ClassVar[int] = defs.MSG_RSSI_REPORT

    seq: int
    tick_ms: int | None
    rssi_q8: int
    raw_dbm: int
    n_readings: int | None
    channel: int | None
    flags: int
    beacon: int = 0

    @property
    def rssi_dbm(self) -> float:
        return self.rssi_q8 / 256.0

    @property
    def has_seq(self) -> bool:
        """False for a beacon without sequence numbers (NO_SEQ): group such reports by time."""
        return not self.flags & defs.FLAG_NO_SEQ

    @property
    def peer(self) -> int | None:
        """The other anchor whose own advertisement this report is about (a peer reading,
        ``beacon`` = PEER_BEACON_BASE + its id, SPEC 3.5); None for a beacon's report."""
        return self.beacon - defs.PEER_BEACON_BASE if self.beacon >= defs.PEER_BEACON_BASE else None

    def _check_fits(self, lay: Layout) -> None:
        if "beacon" not in lay.fields and self.beacon != 0:
            raise ValueError("a version-1 RSSI_REPORT is about beacon 0 only")


@dataclass(frozen=True, slots=True)
class AuthReport(RssiReport):
    """AUTH_REPORT (SPEC 9.5): a report about our authenticated beacon, with what the
    gateway needs to verify it again: the period's `counter` and the advertisement's
    `tag` (its `seq` is the beacon's sequence number, decrypted). UART only: over CAN an
    anchor sends the RSSI_REPORT."""

    NAME: ClassVar[str] = "AUTH_REPORT"
    TYPE: ClassVar[int] = defs.MSG_AUTH_REPORT

    counter: int = 0
    tag: bytes = b""

    def __post_init__(self) -> None:
        _bytes_field(self, "tag", defs.MSG_AUTH_REPORT_TAG_LEN)


@dataclass(frozen=True, slots=True)
class AuthStatus(_Message):
    """AUTH_STATUS (SPEC 9.5): the anchor's rejected advertisements of its PFDOA_AUTH
    entries, by reason (saturating u16 counts since boot), sent after each STATUS."""

    NAME: ClassVar[str] = "AUTH_STATUS"
    TYPE: ClassVar[int] = defs.MSG_AUTH_STATUS

    auth_bad_tag: int
    auth_stale: int
    auth_replayed: int


@dataclass(frozen=True, slots=True)
class Status(_Message):
    """STATUS. `filter_hash` and `filter_slots` are 0 from a version-1 anchor (not sent)."""

    NAME: ClassVar[str] = "STATUS"
    TYPE: ClassVar[int] = defs.MSG_STATUS

    fw_major: int
    fw_minor: int
    uptime_s: int
    config_hash: int
    dropped_events: int
    rx_errors: int
    spikes: int
    defs_hash: int
    filter_hash: int = 0
    filter_slots: int = 0

    @property
    def version(self) -> int | None:
        """The protocol version whose schema the anchor reports (None: unknown schema)."""
        return {defs.DEFS_HASH: defs.PROTO_VERSION, defs.V1_DEFS_HASH: defs.V1_PROTO_VERSION}.get(self.defs_hash)

    @classmethod
    def from_halves(cls, a: "StatusA", b: "StatusB", c: "StatusC | None" = None) -> "Status":
        """Join the CAN parts of a STATUS (the caller pairs them by anchor; no C from v1)."""
        return cls(a.fw_major, a.fw_minor, a.uptime_s, a.config_hash, b.dropped_events, b.rx_errors,
                   b.spikes, b.defs_hash, c.filter_hash if c else 0, c.filter_slots if c else 0)


@dataclass(frozen=True, slots=True)
class ConfigSet(_Message):
    NAME: ClassVar[str] = "CONFIG_SET"
    TYPE: ClassVar[int] = defs.MSG_CONFIG_SET

    token: int
    offset_q8: int = defs.DEFAULT_OFFSET_Q8
    alpha_q8: int = defs.DEFAULT_ALPHA_Q8
    spike_db: int = defs.DEFAULT_SPIKE_DB
    report_mode: int = defs.DEFAULT_REPORT_MODE
    decimation: int = defs.DEFAULT_DECIMATION


@dataclass(frozen=True, slots=True)
class ConfigAck(_Message):
    NAME: ClassVar[str] = "CONFIG_ACK"
    TYPE: ClassVar[int] = defs.MSG_CONFIG_ACK

    token: int
    result: int
    config_hash: int


@dataclass(frozen=True, slots=True)
class FilterSet(_Message):
    """FILTER_SET: set entry `index` of the anchor's beacon filter table. Build one from a
    :class:`pfdoa.protocol.filters.BeaconFilter` with its `set_message(token, index)`."""

    NAME: ClassVar[str] = "FILTER_SET"
    TYPE: ClassVar[int] = defs.MSG_FILTER_SET

    token: int
    index: int
    kind: int
    period_ms: int
    match: bytes = b""

    def __post_init__(self) -> None:
        _bytes_field(self, "match", defs.MSG_FILTER_SET_MATCH_LEN)


@dataclass(frozen=True, slots=True)
class FilterAck(_Message):
    NAME: ClassVar[str] = "FILTER_ACK"
    TYPE: ClassVar[int] = defs.MSG_FILTER_ACK

    token: int
    result: int
    index: int
    filter_hash: int


@dataclass(frozen=True, slots=True)
class RadioInject(_Message):
    NAME: ClassVar[str] = "RADIO_INJECT"
    TYPE: ClassVar[int] = defs.MSG_RADIO_INJECT

    seq: int
    tick_ms: int
    rssi_dbm: int
    channel: int
    lqi: int
    radio: int


@dataclass(frozen=True, slots=True)
class RadioInjectRaw(_Message):
    """RADIO_INJECT_RAW: one received frame (BLE advertising PDU or 802.15.4 MAC frame)."""

    NAME: ClassVar[str] = "RADIO_INJECT_RAW"
    TYPE: ClassVar[int] = defs.MSG_RADIO_INJECT_RAW

    tick_ms: int
    rssi_dbm: int
    channel: int
    lqi: int
    radio: int
    length: int
    frame: bytes = b""

    def __post_init__(self) -> None:
        _bytes_field(self, "frame", defs.MSG_RADIO_INJECT_RAW_FRAME_LEN)

    @classmethod
    def of(cls, tick_ms: int, rssi_dbm: int, channel: int, lqi: int, radio: int,
           frame: bytes) -> "RadioInjectRaw":
        return cls(tick_ms, rssi_dbm, channel, lqi, radio, len(frame), frame)


@dataclass(frozen=True, slots=True)
class RadioTx(_Message):
    """RADIO_TX (test builds): a frame the anchor's radio transmitted (its own advertisement,
    SPEC 6.1), for a simulator to deliver to the other anchors."""

    NAME: ClassVar[str] = "RADIO_TX"
    TYPE: ClassVar[int] = defs.MSG_RADIO_TX

    tick_ms: int
    radio: int
    length: int
    frame: bytes = b""

    def __post_init__(self) -> None:
        _bytes_field(self, "frame", defs.MSG_RADIO_TX_FRAME_LEN)

    @property
    def sent(self) -> bytes:
        """The frame as transmitted (``length`` bytes; empty when ``length`` is out of range)."""
        return self.frame[:self.length] if self.length <= len(self.frame) else b""


@dataclass(frozen=True, slots=True)
class StatusA:
    """First CAN part of STATUS (can_type 0x5)."""

    fw_major: int
    fw_minor: int
    uptime_s: int
    config_hash: int


@dataclass(frozen=True, slots=True)
class StatusB:
    """Second CAN part of STATUS (can_type 0x6)."""

    dropped_events: int
    rx_errors: int
    spikes: int
    defs_hash: int


@dataclass(frozen=True, slots=True)
class StatusC:
    """Third CAN part of STATUS (can_type 0x7, version 2 only)."""

    filter_hash: int
    filter_slots: int


Message = Union[RssiReport, AuthReport, AuthStatus, Status, ConfigSet, ConfigAck, FilterSet, FilterAck, RadioInject,
                RadioInjectRaw, RadioTx]
CanMessage = Union[RssiReport, ConfigSet, ConfigAck, StatusA, StatusB, StatusC]

MESSAGE_CLASSES: tuple[type[Message], ...] = (RssiReport, AuthReport, AuthStatus, Status, ConfigSet, ConfigAck,
                                              FilterSet, FilterAck, RadioInject, RadioInjectRaw, RadioTx)
BY_NAME: dict[str, type[Message]] = {cls.NAME: cls for cls in MESSAGE_CLASSES}
_T = TypeVar("_T")


def positional_maker(cls: type[_T]) -> Callable[[Sequence[Any]], _T]:
    """A function ``make(values)`` equal to ``cls(*values)`` (every field given, in order) for
    a frozen, slotted message dataclass, for the receivers' hot paths.

    A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` (about
    100 ns a field, most of a report's decoding); this sets the same slots through their
    descriptors directly (what ``object.__setattr__`` ends in) and then runs
    ``__post_init__`` as ``__init__`` would, so the object is the same."""
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    env: dict[str, Any] = {"new": object.__new__, "cls": cls}
    env.update({f"set_{n}": getattr(cls, n).__set__ for n in names})
    lines = [f"def make({', '.join(['values'] + [f'{k}={k}' for k in env])}):",
             f"    {', '.join(names)}{',' if len(names) == 1 else ''} = values",
             "    obj = new(cls)"]
    lines += [f"    set_{n}(obj, {n})" for n in names]
    if hasattr(cls, "__post_init__"):
        lines.append("    obj.__post_init__()")
    lines.append("    return obj")
    ns: dict[str, Any] = {}
    exec("\n".join(lines), env, ns)  # generated once per class, as dataclasses does for __init__
    make: Callable[[Sequence[Any]], _T] = ns["make"]
    return make


# type code (any version) -> class
BY_TYPE: dict[int, type[Message]] = {code: BY_NAME[defs.MESSAGES[lay.key][5].split(" ", 1)[0]]
                            for code, lay in LAYOUTS.items()}
