"""Reference anchor model: SPEC section 3 (and the anchor side of 1, 2 and 4), exactly.

This is the executable specification the C core and the MicroPython anchor are compared
with byte for byte (golden vectors in protocol/vectors/anchor.json and the differential
check). It favours clarity over speed: plain integers, every rounding and wrap explicit.
An anchor speaks the current protocol version only (SPEC 8.1).

Outputs are wire units: `bytes` (a UART frame including its 0x00 delimiter) for the
"uart" transport, `(can_id, data)` tuples for "can", and :class:`Transmitted` for the
anchor's own advertisement going out on its radio (SPEC 3.5, 6.1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence, Union

from . import defs
from .auth import Verifier, parse_payload
from .can import decode_can, encode_can
from .config import AnchorConfig
from .filters import (
    BeaconFilter,
    Match,
    PeerMatch,
    auth_payload_802154,
    auth_payload_ble_adv,
    auth_payload_ble_pdu,
    default_table,
    match_802154,
    match_ble_adv,
    match_ble_pdu,
    table_hash,
    unpack_table,
)
from .messages import (
    AuthReport,
    AuthStatus,
    ConfigAck,
    ConfigSet,
    FilterAck,
    FilterSet,
    RadioInject,
    RadioInjectRaw,
    RssiReport,
    Status,
)
from .peers import ADDRESS_LEN, anchor_frame
from .uart import HOST_TO_ANCHOR, Decoded, StreamDecoder, encode_uart

U32 = 0xFFFFFFFF
U16_MAX = 0xFFFF
Q8_MIN, Q8_MAX = -32768, 32767


class Transmitted(NamedTuple):
    """A frame the anchor's radio sent: its own advertisement (SPEC 6.1)."""

    radio: int
    frame: bytes


WireUnit = Union[bytes, tuple[int, bytes], Transmitted]


def fold_q8(total: int, n: int) -> int:
    """Mean of n readings summing to `total` dBm, Q7.8, rounded half up (SPEC 3 Fold)."""
    return (512 * total + n) // (2 * n)


def ema_step_q8(ema_q8: int, mean_q8: int, alpha_q8: int) -> int:
    """One EMA update with the increment rounded half up to 1/256 dB (SPEC 3 EMA)."""
    return ema_q8 + (alpha_q8 * (mean_q8 - ema_q8) + 128) // 256


@dataclass
class _Event:
    seq: int
    has_seq: bool
    radio: int
    first_tick: int
    total: int = 0
    n: int = 0
    raw_dbm: int = 0
    channel: int = 0
    saturated: bool = False
    counter: int | None = None  # our authenticated beacon's period (SPEC 9.4), else None
    tag: bytes = b""


@dataclass
class _Slot:
    """The state of one filter entry (SPEC 3.4)."""

    ema_q8: int = 0
    have_ema: bool = False
    spike_run: int = 0
    event: _Event | None = None
    closed_count: int = 0   # mode 1
    pending_flags: int = 0  # mode 1
    noseq_next: int = 0     # seq of the next event formed by time
    auth: Verifier | None = None  # a PFDOA_AUTH entry's key and counter window (SPEC 9.4)


def _sat_inc(v: int) -> int:
    return v + 1 if v < U16_MAX else v


class AnchorModel:
    """One anchor: radio input, polls and host bytes in; frames out, in order."""

    def __init__(self, anchor_id: int, transport: str = "uart", *, boot_tick_ms: int = 0,
                 fw_major: int = 1, fw_minor: int = 0, config: AnchorConfig | None = None,
                 filters: Sequence[BeaconFilter] | bytes | None = None,
                 store_ok: bool = True, sil_inject: bool = False,
                 peer_radio: tuple[int, bytes] | None = None) -> None:
        if not 0 <= anchor_id <= defs.ANCHOR_ID_MAX:
            raise ValueError(f"anchor id {anchor_id} out of range 0..{defs.ANCHOR_ID_MAX}")
        if transport not in ("uart", "can"):
            raise ValueError(f"transport must be 'uart' or 'can', not {transport!r}")
        self.anchor_id = anchor_id
        self.transport = transport
        self.fw_major, self.fw_minor = fw_major, fw_minor
        self.store_ok = store_ok  # False simulates a failing non-volatile store (ack result 2)
        self.config = config if config is not None else AnchorConfig()
        if not self.config.is_valid():
            raise ValueError(f"invalid configuration {self.config}")
        # A stored table that is invalid in any entry leaves the default table (SPEC 3.1).
        table = unpack_table(filters) if isinstance(filters, (bytes, bytearray)) else filters
        self.filters: list[BeaconFilter] = list(default_table())
        if table is not None and len(table) == defs.BEACON_SLOTS and all(f.is_valid() for f in table):
            self.filters = list(table)
        self.boot_tick = boot_tick_ms & U32
        self.last_status_tick: int | None = None  # None until the first poll
        self.slots = [self._fresh_slot(f) for f in self.filters]
        # Counters (u16, saturating)
        self.dropped_events = 0
        self.rx_errors = 0
        self.spikes = 0
        self.auth_bad_tag = 0  # SPEC 9.4: rejected advertisements of PFDOA_AUTH entries
        self.auth_stale = 0
        self.auth_replayed = 0
        types = set(HOST_TO_ANCHOR) if sil_inject else HOST_TO_ANCHOR - defs.TEST_ONLY
        self._rx = StreamDecoder(types, versions=(defs.PROTO_VERSION,))
        # The radio the anchor sends its own advertisement on: (radio, its address), or None
        # when the board gives none (pfdoa_anchor_use_peer_radio).
        if peer_radio is not None and (peer_radio[0] not in ADDRESS_LEN
                                       or len(peer_radio[1]) != ADDRESS_LEN[peer_radio[0]]):
            raise ValueError(f"peer radio {peer_radio!r}: radio 0 with a 6-byte or 1 with an 8-byte address")
        self.peer_radio = peer_radio
        self.peer_seq = 0  # the next advertisement's sequence number
        self.peer_last_tick: int | None = None  # None: the next poll sends (SPEC 3.5)

    @property
    def filter_hash(self) -> int:
        return table_hash(self.filters)

    @staticmethod
    def _fresh_slot(f: BeaconFilter) -> _Slot:
        key = f.match[:defs.AUTH_KEY_LEN] if f.kind == defs.FILTER_PFDOA_AUTH else None
        return _Slot(auth=Verifier(key) if key is not None else None)

    # ---------------------------------------------------------------- inputs

    def reading(self, tick_ms: int, seq: int, rssi_dbm: int, channel: int, lqi: int,
                radio: int) -> list[WireUnit]:
        """One reading of filter entry 0 with its sequence number, as the radio driver
        delivers it through pfdoa_anchor_on_radio at `tick_ms` (the board matched it)."""
        if not -128 <= rssi_dbm <= 127 or not 0 <= seq <= 0xFFFF or not 0 <= channel <= 255:
            raise ValueError("reading field out of range (rssi i8, seq u16, channel u8)")
        if self.filters[0].kind == defs.FILTER_PFDOA_AUTH:
            # SPEC 9.4: a board cannot vouch for an authenticated beacon: dropped, counted.
            self.dropped_events = _sat_inc(self.dropped_events)
            return []
        return self._reading(0, True, seq, rssi_dbm, channel, lqi, radio, tick_ms)

    def ble_adv(self, tick_ms: int, rssi_dbm: int, channel: int, adv_a: bytes, adv_data: bytes) -> list[WireUnit]:
        """A BLE advertisement given as AdvA + AdvData (pfdoa_anchor_on_ble_adv)."""
        if len(adv_a) == defs.BLE_ADV_A_LEN:
            done = self._auth(auth_payload_ble_adv(adv_data), rssi_dbm, channel, 0, defs.RADIO_BLE, tick_ms)
            if done is not None:
                return done
        return self._matched(match_ble_adv(self.filters, adv_a, adv_data), rssi_dbm, channel, 0,
                             defs.RADIO_BLE, tick_ms)

    def ble_pdu(self, tick_ms: int, rssi_dbm: int, channel: int, pdu: bytes) -> list[WireUnit]:
        """A raw BLE advertising PDU (pfdoa_anchor_on_ble_pdu)."""
        found = auth_payload_ble_pdu(pdu)
        done = self._auth(found[1] if found else None, rssi_dbm, channel, 0, defs.RADIO_BLE, tick_ms)
        if done is not None:
            return done
        return self._matched(match_ble_pdu(self.filters, pdu), rssi_dbm, channel, 0, defs.RADIO_BLE, tick_ms)

    def ieee802154(self, tick_ms: int, rssi_dbm: int, channel: int, lqi: int, mpdu: bytes) -> list[WireUnit]:
        """A raw IEEE 802.15.4 MAC frame without FCS (pfdoa_anchor_on_802154)."""
        done = self._auth(auth_payload_802154(mpdu), rssi_dbm, channel, lqi, defs.RADIO_IEEE802154, tick_ms)
        if done is not None:
            return done
        return self._matched(match_802154(self.filters, mpdu), rssi_dbm, channel, lqi,
                             defs.RADIO_IEEE802154, tick_ms)

    def poll(self, tick_ms: int) -> list[WireUnit]:
        """The main loop's periodic poll: event timeouts in entry order, then STATUS."""
        tick_ms &= U32
        out: list[WireUnit] = []
        for i, slot in enumerate(self.slots):
            ev = slot.event
            if ev is not None:
                timeout = defs.EVENT_TIMEOUT_MS if ev.has_seq else self.filters[i].period_ms
                if ((tick_ms - ev.first_tick) & U32) >= timeout:
                    out += self._close(i, tick_ms)
        if (self.last_status_tick is None
                or ((tick_ms - self.last_status_tick) & U32) >= defs.STATUS_PERIOD_MS):
            self.last_status_tick = tick_ms
            out += self._emit(self._status(tick_ms))
            if self.transport == "uart" and any(s.auth is not None for s in self.slots):
                out += self._emit(AuthStatus(self.auth_bad_tag, self.auth_stale, self.auth_replayed))
        period = self.peer_period_ms
        if self.peer_radio is not None and period and (
                self.peer_last_tick is None or ((tick_ms - self.peer_last_tick) & U32) >= period):
            self.peer_last_tick = tick_ms
            radio, address = self.peer_radio
            out.append(Transmitted(radio, anchor_frame(radio, address, self.anchor_id, self.peer_seq)))
            self.peer_seq = (self.peer_seq + 1) & U16_MAX
        return out

    @property
    def peer_period_ms(self) -> int:
        """The first ANCHORS entry's period: how often the anchor sends its own advertisement
        (0: no such entry, it sends none)."""
        return next((f.period_ms for f in self.filters if f.kind == defs.FILTER_ANCHORS), 0)

    def uart_rx(self, tick_ms: int, data: bytes) -> list[WireUnit]:
        """Bytes arriving on the anchor's UART at `tick_ms`."""
        out: list[WireUnit] = []
        before = self._rx.counters.copy()
        for decoded in self._rx.feed(data):
            out += self._host_message(tick_ms, decoded, "uart")
        rejected = sum(self._rx.counters[e] - before[e] for e in defs.ERRORS)
        # Frames are rejected one by one in stream order; acks do not depend on rx_errors,
        # so counting the batch afterwards gives the same state as counting each at once.
        for _ in range(rejected):
            self.rx_errors = _sat_inc(self.rx_errors)
        return out

    def can_rx(self, tick_ms: int, can_id: int, data: bytes) -> list[WireUnit]:
        """One CAN frame on the bus; the anchor's acceptance filter applies first."""
        if can_id not in (((defs.CAN_CONFIG_SET << defs.CAN_ANCHOR_BITS) | self.anchor_id),
                          ((defs.CAN_CONFIG_SET << defs.CAN_ANCHOR_BITS) | defs.ANCHOR_BROADCAST)):
            return []  # filtered out by the controller: not seen, not counted
        r = decode_can(can_id, data)
        if isinstance(r, str):
            self.rx_errors = _sat_inc(self.rx_errors)
            return []
        return self._host_message(tick_ms, r, "can")

    # ---------------------------------------------------------------- internals

    @staticmethod
    def _channel_ok(radio: int, channel: int) -> bool:
        if radio == defs.RADIO_BLE:
            return defs.CHANNEL_BLE_MIN <= channel <= defs.CHANNEL_BLE_MAX
        if radio == defs.RADIO_IEEE802154:
            return defs.CHANNEL_IEEE802154_MIN <= channel <= defs.CHANNEL_IEEE802154_MAX
        return False

    def _auth(self, payload: bytes | None, rssi_dbm: int, channel: int, lqi: int, radio: int,
              tick_ms: int) -> list[WireUnit] | None:
        """Our authenticated beacon (SPEC 9.4): offered to the PFDOA_AUTH entries in index
        order; the first whose rolling identifier it carries decides it. None: no such entry
        (the reception goes on to the other entries)."""
        fields = None if payload is None else parse_payload(payload)
        if fields is None:
            return None
        for i, slot in enumerate(self.slots):
            if slot.auth is None:
                continue
            v = slot.auth.verify(fields, tick_ms)
            if v.result == defs.AUTH_NONE:
                continue
            if v.result == defs.AUTH_ACCEPT:
                return self._reading(i, True, v.seq, rssi_dbm, channel, lqi, radio, tick_ms, (v.counter, v.tag))
            if v.result == defs.AUTH_BAD_TAG:
                self.auth_bad_tag = _sat_inc(self.auth_bad_tag)
            elif v.result == defs.AUTH_STALE:
                self.auth_stale = _sat_inc(self.auth_stale)
            else:
                self.auth_replayed = _sat_inc(self.auth_replayed)
            return []
        return None

    def _matched(self, m: Match | PeerMatch | None, rssi_dbm: int, channel: int, lqi: int, radio: int,
                 tick_ms: int) -> list[WireUnit]:
        if m is None:
            return []  # not a configured beacon: ignored, not counted
        if isinstance(m, PeerMatch):
            return self._peer(m, rssi_dbm, channel, radio, tick_ms)
        return self._reading(m.index, m.seq is not None, m.seq or 0, rssi_dbm, channel, lqi, radio, tick_ms)

    def _reading(self, index: int, has_seq: bool, seq: int, rssi_dbm: int, channel: int, lqi: int,
                 radio: int, tick_ms: int, auth: tuple[int, bytes] | None = None) -> list[WireUnit]:
        del lqi  # carried for completeness; the filter does not use it
        tick_ms &= U32
        out: list[WireUnit] = []
        if rssi_dbm == defs.RSSI_INVALID or not self._channel_ok(radio, channel):
            self.dropped_events = _sat_inc(self.dropped_events)
            return out
        saturated = False
        if rssi_dbm > defs.RSSI_MAX_DBM:  # RSSI_MIN_DBM is the i8 minimum: no low clamp
            rssi_dbm, saturated = defs.RSSI_MAX_DBM, True
        slot = self.slots[index]
        ev = slot.event
        counter = None if auth is None else auth[0]
        if ev is not None and (ev.radio != radio or ev.has_seq != has_seq
                               or (has_seq and (ev.seq != seq or ev.counter != counter))
                               or (not has_seq and ((tick_ms - ev.first_tick) & U32) >= self.filters[index].period_ms)):
            out += self._close(index, tick_ms)
            ev = None
        if ev is None:
            if not has_seq:
                seq, slot.noseq_next = slot.noseq_next, (slot.noseq_next + 1) & U16_MAX
            ev = slot.event = _Event(seq=seq, has_seq=has_seq, radio=radio, first_tick=tick_ms)
            if auth is not None:
                ev.counter, ev.tag = auth
        ev.total += rssi_dbm
        ev.n += 1
        ev.raw_dbm = rssi_dbm
        ev.channel = channel
        ev.saturated = ev.saturated or saturated
        if radio == defs.RADIO_IEEE802154 or ev.n >= defs.BLE_EVENT_MAX_READINGS:
            out += self._close(index, tick_ms)
        return out

    def _peer(self, m: PeerMatch, rssi_dbm: int, channel: int, radio: int, tick_ms: int) -> list[WireUnit]:
        """A peer reading (SPEC 3.5): reported on its own, calibrated, not filtered."""
        if m.peer == self.anchor_id:
            return []  # another anchor with our id: not a peer, ignored
        if rssi_dbm == defs.RSSI_INVALID or not self._channel_ok(radio, channel):
            self.dropped_events = _sat_inc(self.dropped_events)
            return []
        flags = defs.FLAG_ZIGBEE if radio == defs.RADIO_IEEE802154 else 0
        if rssi_dbm > defs.RSSI_MAX_DBM:
            rssi_dbm, flags = defs.RSSI_MAX_DBM, flags | defs.FLAG_SATURATED
        out_q8 = 256 * rssi_dbm + self.config.offset_q8
        if out_q8 > Q8_MAX or out_q8 < Q8_MIN:
            out_q8, flags = (Q8_MAX if out_q8 > Q8_MAX else Q8_MIN), flags | defs.FLAG_SATURATED
        if self.config.offset_q8 != 0:
            flags |= defs.FLAG_CALIBRATED
        if self.config.report_mode == defs.REPORT_SILENT:
            return []
        return self._emit(RssiReport(m.seq, tick_ms & U32, out_q8, rssi_dbm, 1, channel, flags,
                                     defs.PEER_BEACON_BASE + m.peer))

    def _host_message(self, tick_ms: int, decoded: Decoded, via: str) -> list[WireUnit]:
        if decoded.anchor_id not in (self.anchor_id, defs.ANCHOR_BROADCAST):
            return []  # for another anchor: ignored, not counted
        msg = decoded.message
        if isinstance(msg, ConfigSet):
            return self._config_set(msg, via)
        if isinstance(msg, FilterSet):
            return self._filter_set(msg)
        if isinstance(msg, RadioInject):  # only known with sil_inject
            return self.reading(msg.tick_ms, msg.seq, msg.rssi_dbm, msg.channel, msg.lqi, msg.radio)
        if isinstance(msg, RadioInjectRaw):  # only known with sil_inject
            if msg.length > len(msg.frame):
                return []
            frame = msg.frame[:msg.length]
            if msg.radio == defs.RADIO_BLE:
                return self.ble_pdu(msg.tick_ms, msg.rssi_dbm, msg.channel, frame)
            if msg.radio == defs.RADIO_IEEE802154:
                return self.ieee802154(msg.tick_ms, msg.rssi_dbm, msg.channel, msg.lqi, frame)
        return []

    def _config_set(self, msg: ConfigSet, via: str) -> list[WireUnit]:
        new = AnchorConfig(msg.offset_q8, msg.alpha_q8, msg.spike_db, msg.report_mode,
                           msg.decimation)
        if not new.is_valid():
            result = defs.ACK_INVALID
        else:
            self.config = new
            for slot in self.slots:
                slot.closed_count = 0
                slot.pending_flags = 0
            result = defs.ACK_OK if self.store_ok else defs.ACK_STORE_FAILED
        # The ack answers on the transport the CONFIG_SET came from (SPEC 3 Configuration).
        return self._emit(ConfigAck(msg.token, result, self.config.hash), via)

    def _filter_set(self, msg: FilterSet) -> list[WireUnit]:
        new = BeaconFilter.of_message(msg)
        if msg.index >= defs.BEACON_SLOTS or not new.is_valid():
            result = defs.ACK_INVALID
        else:
            self.filters[msg.index] = new
            self.slots[msg.index] = self._fresh_slot(new)  # a new beacon: its state starts afresh
            self.peer_last_tick = None  # the advertisement's schedule restarts (SPEC 3.5)
            result = defs.ACK_OK if self.store_ok else defs.ACK_STORE_FAILED
        return self._emit(FilterAck(msg.token, result, msg.index, self.filter_hash), "uart")

    def _status(self, tick_ms: int) -> Status:
        return Status(self.fw_major, self.fw_minor, ((tick_ms - self.boot_tick) & U32) // 1000,
                      self.config.hash, self.dropped_events, self.rx_errors, self.spikes,
                      defs.DEFS_HASH, self.filter_hash, defs.BEACON_SLOTS)

    def _close(self, index: int, tick_ms: int) -> list[WireUnit]:
        slot = self.slots[index]
        ev = slot.event
        assert ev is not None
        slot.event = None
        cfg = self.config
        flags = defs.FLAG_SATURATED if ev.saturated else 0
        if ev.radio == defs.RADIO_IEEE802154:
            flags |= defs.FLAG_ZIGBEE
        if not ev.has_seq:
            flags |= defs.FLAG_NO_SEQ
        mean_q8 = fold_q8(ev.total, ev.n)
        outlier = (slot.have_ema and cfg.spike_db > 0
                   and abs(mean_q8 - slot.ema_q8) > 256 * cfg.spike_db)
        if outlier and slot.spike_run < defs.SPIKE_RUN_RESET:
            self.spikes = _sat_inc(self.spikes)
            slot.spike_run += 1
            flags |= defs.FLAG_SPIKE
        elif outlier or not slot.have_ema:
            slot.ema_q8 = mean_q8
            slot.have_ema = True
            slot.spike_run = 0
            flags |= defs.FLAG_RESET
        else:
            slot.ema_q8 = ema_step_q8(slot.ema_q8, mean_q8, cfg.alpha_q8)
            slot.spike_run = 0
        out_q8 = slot.ema_q8 + cfg.offset_q8
        if out_q8 > Q8_MAX or out_q8 < Q8_MIN:
            out_q8 = Q8_MAX if out_q8 > Q8_MAX else Q8_MIN
            flags |= defs.FLAG_SATURATED
        if cfg.offset_q8 != 0:
            flags |= defs.FLAG_CALIBRATED

        if cfg.report_mode == defs.REPORT_SILENT:
            return []
        if cfg.report_mode == defs.REPORT_DECIMATE:
            slot.closed_count += 1
            slot.pending_flags |= flags
            if slot.closed_count < cfg.decimation:
                return []
            flags = slot.pending_flags
            slot.closed_count = 0
            slot.pending_flags = 0
        if ev.counter is not None and self.transport == "uart":
            return self._emit(AuthReport(ev.seq, tick_ms, out_q8, ev.raw_dbm, ev.n, ev.channel, flags, index,
                                         ev.counter, ev.tag))
        return self._emit(RssiReport(ev.seq, tick_ms, out_q8, ev.raw_dbm, ev.n, ev.channel, flags, index))

    def _emit(self, msg, transport: str | None = None) -> list[WireUnit]:
        if (transport or self.transport) == "uart":
            return [encode_uart(msg, self.anchor_id)]
        return list(encode_can(msg, self.anchor_id))


__all__ = ["AnchorConfig", "AnchorModel", "Transmitted", "WireUnit", "fold_q8", "ema_step_q8"]
