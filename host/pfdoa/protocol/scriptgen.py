"""Seeded random event scripts for the differential checks of the anchor implementations.

One generator for `tests/firmware/test_differential.py` (C == MicroPython == Python model) and
`firmware/tools/diffcheck.py` (C == Python model inside `make test-c`). A script is an
`init` object and event-script lines (protocol/vectors/README.md):

* readings of entry 0 through `pfdoa_anchor_on_radio` (BLE events on 1..3 channels and
  invalid channels, 802.15.4 readings, unavailable RSSI, outliers and level changes);
* raw receptions (`B` advertising PDUs, `A` AdvA + AdvData, `Z` 802.15.4 frames) from a
  small world of beacons - several of ours with different ids, an iBeacon, an
  Eddystone-UID, an AltBeacon, a BLE tag and an 802.15.4 node matched by MAC address,
  our authenticated beacon over BLE and 802.15.4 (SPEC 9: replayed frames, damaged tags,
  stale and future counters among its own), other anchors' own advertisements (peer
  readings, SPEC 3.5) - interleaved, plus junk frames; an anchor with a radio of its own
  sends its advertisement (`T` lines);
* FILTER_SETs (valid and invalid, pointing entries at those beacons, or clearing them),
  a stored filter table at boot (valid or not);
* polls, tick jumps and u32 wraps; CONFIG_SETs valid and invalid over UART and CAN (own
  id, broadcast, another anchor, bad DLC, random ids); corrupted, garbage-prefixed, split
  and over-long frames, version-1 frames, and frames an anchor does not know.

`run_model` gives the reference output of a script.
"""

from __future__ import annotations

import random

from . import beacons, defs, peers
from .filters import KIND_NAMES, BeaconFilter, pack_table
from .messages import ConfigSet, FilterSet, RadioInject, RadioInjectRaw, RssiReport
from .script import run_script
from .uart import encode_block, seal

U32 = 0xFFFFFFFF

Script = tuple[dict, list[str]]

_UUID = bytes.fromhex("e2c56db5dffb48d2b060d0f5a71096e0")
_NS, _INST = bytes.fromhex("00112233445566778899"), bytes.fromhex("a0a1a2a3a4a5")
_ALT = bytes(range(100, 120))


class _Beacon:
    """One transmitter of the simulated world and the filter that matches it."""

    def __init__(self, rng: random.Random, kind: str, key: int) -> None:
        self.kind = kind
        self.addr = bytes(rng.randrange(256) for _ in range(6))
        self.ext = bytes(rng.randrange(256) for _ in range(8))
        self.key = key  # our beacon id, or the minor / instance / id byte that makes it unique
        self.seq = rng.randrange(65536)
        self.level = rng.randrange(-100, -40)
        period = rng.choice((1, 20, 50, 100, 250, rng.randrange(1, 2000)))
        # Our authenticated beacon (SPEC 9): its key, its counter at the script's tick t0
        # (set at its first advertisement), the frames it sent (replayed at times).
        self.auth_key = rng.randbytes(defs.AUTH_KEY_LEN)
        self.counter0 = rng.choice((0, rng.randrange(1 << 32), (1 << 32) - rng.randrange(1, 100)))
        self.t0: int | None = None
        self.sent: list[bytes] = []
        if kind in ("auth", "auth154"):
            self.filter = BeaconFilter.pfdoa_auth(self.auth_key)
        elif kind == "ours":
            self.filter = BeaconFilter.pfdoa(key)
        elif kind == "ours154":
            self.filter = BeaconFilter.pfdoa(key)
        elif kind == "ibeacon":
            self.filter = BeaconFilter.ibeacon(_UUID, 7, key, period)
        elif kind == "eddystone":
            self.filter = BeaconFilter.eddystone_uid(_NS, _INST[:5] + bytes((key,)), period)
        elif kind == "altbeacon":
            self.filter = BeaconFilter.altbeacon(_ALT[:19] + bytes((key,)), period)
        elif kind == "tag":
            self.filter = BeaconFilter.mac48(self.addr, period)
        elif kind in ("peer", "peer154"):  # another anchor (key: its id), its own advertisement
            self.filter = BeaconFilter.anchors(period)
        else:  # "node": an 802.15.4 device matched by its extended address
            self.filter = BeaconFilter.mac64(self.ext, period)

    @property
    def zigbee(self) -> bool:
        return self.kind in ("ours154", "node", "auth154", "peer154")

    def auth_frame(self, rng: random.Random, tick: int) -> bytes:
        """What our authenticated beacon sends now (AdvData, or an 802.15.4 frame), or what
        an attacker makes of it: a replay of an earlier frame, a damaged tag, a stale or
        future counter."""
        if self.t0 is None:
            self.t0 = tick
        counter = (self.counter0 + (((tick - self.t0) & U32) >> defs.AUTH_PERIOD_SHIFT)) & U32
        r = rng.random()
        if r < 0.08 and self.sent:
            return rng.choice(self.sent)
        if r < 0.11:
            counter = (counter - rng.randrange(1, 5000)) & U32
        elif r < 0.13:
            counter = (counter + rng.randrange(1, 100)) & U32
        if self.zigbee:
            frame = bytearray(beacons.pfdoa_auth_802154_frame(self.auth_key, counter, self.seq))
        else:
            frame = bytearray(beacons.pfdoa_auth_adv_data(self.auth_key, counter, self.seq))
        if rng.random() < 0.05:  # a forgery: the tag (the frame's last bytes) changed
            frame[-1 - rng.randrange(defs.AUTH_TAG_LEN)] ^= 1 << rng.randrange(8)
        self.sent = (self.sent + [bytes(frame)])[-8:]
        return bytes(frame)

    def adv_data(self, rng: random.Random) -> bytes:
        if self.kind == "peer":
            return peers.anchor_adv_data(self.seq, self.key)
        if self.kind == "ours":
            if rng.random() < 0.05 and self.key == 0:
                return beacons.pfdoa_v1_adv_data(self.seq)
            return beacons.pfdoa_adv_data(self.seq, self.key)
        if self.kind == "ibeacon":
            return beacons.ibeacon_adv_data(_UUID, 7, self.key)
        if self.kind == "eddystone":
            return beacons.eddystone_uid_adv_data(_NS, _INST[:5] + bytes((self.key,)), rfu=rng.random() < 0.7)
        if self.kind == "altbeacon":
            return beacons.altbeacon_adv_data(_ALT[:19] + bytes((self.key,)))
        return bytes((2, defs.BLE_AD_FLAGS, defs.BLE_FLAGS_GENERAL_NO_BREDR))  # a tag: anything

    def mac_frame(self, rng: random.Random) -> bytes:
        if self.kind == "ours154":
            return beacons.pfdoa_802154_frame(self.seq, self.key, self.ext)
        if self.kind == "peer154":
            return peers.anchor_frame(defs.RADIO_IEEE802154, self.ext, self.key, self.seq)
        return beacons.mac_frame(rng.randbytes(rng.randrange(0, 12)), seq=self.seq,
                                 version=rng.choice((0, 1, 2)), src_addr=self.ext)


class _Gen:
    """One random script: an `init` object and the event lines."""

    def __init__(self, rng: random.Random, both: bool = False, inject: bool = False) -> None:
        self.rng = rng
        self.inject = inject
        r = rng.random()
        self.anchor_id = rng.choice((0, 1, 5, 126)) if r < 0.3 else rng.randrange(127)
        self.can = rng.random() < 0.25
        boot = rng.choice((0, 0, rng.randrange(1 << 32), (1 << 32) - rng.randrange(1, 3000)))
        self.tick = (boot + rng.randrange(0, 50)) & U32 if rng.random() < 0.5 else boot
        self.init: dict = {"anchor_id": self.anchor_id, "boot_tick_ms": boot}
        if both:
            self.init["transport"] = "both"
        elif self.can:
            self.init["transport"] = "can"
        if rng.random() < 0.3:
            self.init["config"] = self._random_config(valid=True)
        if rng.random() < 0.1:
            self.init["store_ok"] = False
        kinds = ["ours", "ours", "ibeacon", "eddystone", "altbeacon", "tag", "ours154", "node", "auth", "auth",
                 "auth154", "peer", "peer154"]
        self.world = [_Beacon(rng, k, key) for key, k in enumerate(rng.sample(kinds, rng.randrange(2, 6)))]
        if rng.random() < 0.3:
            table = [self._random_filter() for _ in range(defs.BEACON_SLOTS)]
            packed = bytearray(pack_table(table))
            if rng.random() < 0.2:  # one invalid entry: the anchor keeps the default table
                packed[rng.randrange(defs.BEACON_SLOTS) * defs.FILTER_ENTRY_LEN] = len(KIND_NAMES)
            self.init["filters"] = bytes(packed).hex()
        if rng.random() < 0.4:  # a radio to send its own advertisement on (SPEC 3.5)
            radio = rng.choice(("ble", "802154"))
            self.init["peer_radio"] = radio
            self.init["peer_address"] = rng.randbytes(6 if radio == "ble" else 8).hex()
        self.seq = rng.choice((0, rng.randrange(65536), 65535 - rng.randrange(4)))
        self.level = rng.randrange(-100, -30)
        self.lines: list[str] = []

    def _random_config(self, valid: bool) -> dict:
        rng = self.rng
        cfg = {
            "offset_q8": rng.choice((0, 0, rng.randrange(-2048, 2048), -32768, 32767,
                                     rng.randrange(-32768, 32768))),
            "alpha_q8": rng.choice((1, 64, 128, 256, rng.randrange(1, 257))),
            "spike_db": rng.choice((0, 3, 12, 12, rng.randrange(256))),
            "report_mode": rng.choice((0, 0, 1, 1, 2)),
            "decimation": rng.choice((1, 2, 3, rng.randrange(1, 256))),
        }
        if not valid:
            k = rng.choice(("alpha_q8", "report_mode", "decimation"))
            cfg[k] = {"alpha_q8": rng.choice((0, 257, 65535)),
                      "report_mode": rng.randrange(3, 256),
                      "decimation": 0}[k]
        return cfg

    def _random_filter(self) -> BeaconFilter:
        rng = self.rng
        r = rng.random()
        if r < 0.65:
            return rng.choice(self.world).filter
        if r < 0.85:
            return BeaconFilter()
        return BeaconFilter.pfdoa(rng.randrange(256))

    # -- time
    def advance(self, lo: int, hi: int) -> int:
        self.tick = (self.tick + self.rng.randrange(lo, hi + 1)) & U32
        return self.tick

    # -- readings of entry 0 (pfdoa_anchor_on_radio)
    def rssi(self, level: int | None = None) -> int:
        rng = self.rng
        level = self.level if level is None else level
        r = rng.random()
        if r < 0.03:
            return rng.choice((-128, 20, 127, 21, 126, rng.randrange(-128, 128)))
        if r < 0.10:  # outlier, drives spikes and spike runs
            return max(-128, min(126, level + rng.choice((-1, 1)) * rng.randrange(13, 40)))
        return max(-128, min(126, level + rng.randrange(-4, 5)))

    def ble_event(self) -> None:
        rng = self.rng
        k = rng.choice((1, 2, 3, 3, 3, 4))
        for i in range(k):
            ch = 37 + i % 3 if rng.random() < 0.9 else rng.choice((0, 12, 39, 40, 255))
            self.reading(self.seq, self.rssi(), ch, 0, 0)
            self.advance(0, 4)
            if rng.random() < 0.05:
                self.poll()

    def zigbee_reading(self) -> None:
        rng = self.rng
        ch = rng.randrange(11, 27) if rng.random() < 0.9 else rng.choice((0, 10, 27, 39))
        radio = 1 if rng.random() < 0.97 else rng.choice((2, 255))
        self.reading(self.seq, self.rssi(), ch, rng.randrange(256), radio)
        self.advance(0, 3)

    def reading(self, seq: int, rssi: int, ch: int, lqi: int, radio: int) -> None:
        if self.inject and self.rng.random() < 0.7:
            # the same reading as a RADIO_INJECT frame (SIL builds), sometimes for
            # another anchor (ignored)
            aid = self.anchor_id if self.rng.random() < 0.95 else (self.anchor_id + 1) % defs.ANCHOR_BROADCAST
            self.uart(encode_block(RadioInject(seq, self.tick, rssi, ch, lqi, radio), aid) + b"\x00")
        else:
            self.lines.append(f"R {self.tick} {seq} {rssi} {ch} {lqi} {radio}")

    def next_seq(self) -> None:
        r = self.rng.random()
        if r < 0.8:
            d = 1
        elif r < 0.9:
            d = self.rng.randrange(2, 10)
        elif r < 0.95:
            d = 0  # duplicate: a new event with the same seq after the old one closed
        else:
            d = self.rng.randrange(65536)
        self.seq = (self.seq + d) & 0xFFFF

    # -- raw receptions (B, A, Z) from the world
    def _raw(self, kind: str, rssi: int, ch: int, lqi: int, frame: bytes, adv_a: bytes | None = None) -> None:
        rng = self.rng
        if self.inject and kind != "A" and len(frame) <= defs.MSG_RADIO_INJECT_RAW_FRAME_LEN and rng.random() < 0.6:
            radio = defs.RADIO_IEEE802154 if kind == "Z" else defs.RADIO_BLE
            aid = self.anchor_id if rng.random() < 0.95 else 127
            self.uart(encode_block(RadioInjectRaw.of(self.tick, rssi, ch, lqi, radio, frame), aid) + b"\x00")
        elif kind == "A":
            self.lines.append(f"A {self.tick} {rssi} {ch} {(adv_a or bytes(6)).hex()} {frame.hex() or '-'}")
        elif kind == "B":
            self.lines.append(f"B {self.tick} {rssi} {ch} {frame.hex() or '-'}")
        else:
            self.lines.append(f"Z {self.tick} {rssi} {ch} {lqi} {frame.hex() or '-'}")

    def beacon_event(self) -> None:
        rng = self.rng
        b = rng.choice(self.world)
        if b.zigbee:
            ch = rng.randrange(11, 27) if rng.random() < 0.95 else rng.choice((10, 27))
            frame = b.auth_frame(rng, self.tick) if b.kind == "auth154" else b.mac_frame(rng)
            self._raw("Z", self.rssi(b.level), ch, rng.randrange(256), frame)
        else:
            data = b.auth_frame(rng, self.tick) if b.kind == "auth" else b.adv_data(rng)
            for i in range(rng.choice((1, 2, 3, 3, 3))):
                ch = 37 + i if rng.random() < 0.95 else rng.choice((0, 40))
                if rng.random() < 0.5:
                    pdu_type = rng.choice((defs.BLE_PDU_ADV_NONCONN_IND, defs.BLE_PDU_ADV_IND,
                                           defs.BLE_PDU_ADV_SCAN_IND, defs.BLE_PDU_SCAN_RSP, 1))
                    self._raw("B", self.rssi(b.level), ch, 0, beacons.adv_pdu(b.addr, data, pdu_type))
                else:
                    self._raw("A", self.rssi(b.level), ch, 0, data, b.addr)
                self.advance(0, 4)
        r = rng.random()  # the next advertisement: the same seq again (a duplicate) or the next
        b.seq = (b.seq + (0 if r < 0.05 else (rng.randrange(2, 9) if r < 0.15 else 1))) & 0xFFFF
        if rng.random() < 0.05:
            b.level = rng.randrange(-110, -20)

    def junk_reception(self) -> None:
        rng = self.rng
        kind = rng.choice("BAZ")
        frame = rng.randbytes(rng.randrange(0, 45))
        if kind == "B" and frame and rng.random() < 0.5:
            frame = bytes((frame[0] & 0x4F, rng.randrange(6, 38))) + frame[2:]
        self._raw(kind, self.rssi(), rng.randrange(0, 41), rng.randrange(256), frame, rng.randbytes(6))

    def poll(self) -> None:
        self.lines.append(f"P {self.tick}")

    # -- host input
    def config_frame(self) -> None:
        rng = self.rng
        cfg = self._random_config(valid=rng.random() < 0.8)
        token = rng.randrange(256)
        aid = rng.choice((self.anchor_id, self.anchor_id, defs.ANCHOR_BROADCAST, (self.anchor_id + 1) % defs.ANCHOR_BROADCAST))
        payload = ConfigSet(token, **cfg)
        # Mostly the anchor's own transport; sometimes the other one (the ack then goes
        # back on the transport the CONFIG_SET came from, SPEC 3 Configuration).
        if rng.random() < (0.8 if self.can else 0.1):
            data = payload.pack()
            if rng.random() < 0.1:
                data = data[: rng.randrange(1, 8)]  # (DLC 0 has no script syntax)
            cid = (defs.CAN_CONFIG_SET << defs.CAN_ANCHOR_BITS) | aid
            if rng.random() < 0.05:
                cid = rng.randrange(defs.CAN_ID_MASK + 1)
            self.lines.append(f"C {self.tick} {cid:03x} {data.hex()}")
            return
        self.host_frame(encode_block(payload, aid, rng.choice((defs.PROTO_VERSION,) * 9 + (defs.V1_PROTO_VERSION,))))

    def filter_frame(self) -> None:
        rng = self.rng
        aid = rng.choice((self.anchor_id, self.anchor_id, self.anchor_id, defs.ANCHOR_BROADCAST, (self.anchor_id + 1) % defs.ANCHOR_BROADCAST))
        f = self._random_filter()
        index = rng.randrange(defs.BEACON_SLOTS) if rng.random() < 0.9 else rng.randrange(256)
        msg = f.set_message(rng.randrange(256), index)
        r = rng.random()
        if r < 0.1:  # an invalid entry
            k = rng.choice(("kind", "period", "match"))
            if k == "kind":
                msg = FilterSet(msg.token, index, rng.randrange(len(KIND_NAMES), 256), msg.period_ms, msg.match)
            elif k == "period":
                msg = FilterSet(msg.token, index, msg.kind, 0 if msg.period_ms else rng.randrange(1, 65536),
                                msg.match)
            else:
                m = bytearray(msg.match)
                m[-1] ^= 1 + rng.randrange(255)
                msg = FilterSet(msg.token, index, msg.kind, msg.period_ms, bytes(m))
        self.host_frame(encode_block(msg, aid))

    def host_frame(self, block: bytes) -> None:
        rng = self.rng
        r = rng.random()
        if r < 0.1:  # one corrupted bit somewhere inside the frame (may become a zero)
            b = bytearray(block)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            block = bytes(b)
        elif r < 0.15:
            block = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 90))) + block
        self.uart(block + b"\x00")

    def uart(self, data: bytes) -> None:
        rng = self.rng
        if len(data) > 2 and rng.random() < 0.2:  # split across two reads
            cut = rng.randrange(1, len(data))
            self.lines.append(f"U {self.tick} {data[:cut].hex()}")
            self.advance(0, 2)
            if rng.random() < 0.3:  # STATUS shows rx_errors counted so far (overlong)
                self.advance(0, 1500)
                self.poll()
            data = data[cut:]
        self.lines.append(f"U {self.tick} {data.hex()}")

    def odd_frame(self) -> None:
        rng = self.rng
        r = rng.random()
        if r < 0.25:
            data = encode_block(RadioInject(self.seq, self.tick, -50, 37, 0, 0), self.anchor_id) + b"\x00"
        elif r < 0.45:
            data = encode_block(RssiReport(1, 2, -3, -4, 1, 37, 0), self.anchor_id) + b"\x00"
        elif r < 0.6:
            data = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(60, 140)))
            data += b"\x00"
        elif r < 0.7:
            body = bytes((defs.PROTO_VERSION, defs.MSG_CONFIG_SET, defs.ANCHOR_BROADCAST + 1)) + ConfigSet(1).pack()
            data = seal(body, defs.MSG_CONFIG_SET_CRC_EXTRA) + b"\x00"  # anchor id 128: bad_anchor
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        self.uart(data)

    def build(self) -> Script:
        rng = self.rng
        self.poll()
        n = rng.randrange(5, 60)
        for _ in range(n):
            r = rng.random()
            if r < 0.30:
                self.ble_event()
                self.next_seq()
                self.advance(0, 40)
            elif r < 0.40:
                self.zigbee_reading()
                self.next_seq()
            elif r < 0.62:
                self.beacon_event()
                self.advance(0, 60)
            elif r < 0.65:
                self.junk_reception()
            elif r < 0.73:
                self.poll()
                self.advance(0, 30)
            elif r < 0.77:
                self.advance(500, 2500)
                self.poll()
            elif r < 0.83:
                self.config_frame()
            elif r < 0.89:
                self.filter_frame()
            elif r < 0.93:
                self.odd_frame()
            elif r < 0.97:
                self.level = rng.randrange(-110, -20)  # real level change
            else:  # a reading whose tick wraps around 2^32
                self.tick = (U32 - rng.randrange(0, 30)) & U32
        self.advance(0, 2500)
        self.poll()
        return self.init, self.lines


def generate(n: int, seed: int, both: bool = False, inject: bool = False) -> list[Script]:
    """n random scripts; both=True gives anchors reporting on UART and CAN at once;
    inject=True delivers most readings as RADIO_INJECT / RADIO_INJECT_RAW frames (init
    sil_inject)."""
    rng = random.Random(seed)
    seqs = [_Gen(rng, both, inject).build() for _ in range(n)]
    if inject:
        for init, _ in seqs:
            init["sil_inject"] = True
    return seqs


def run_model(init: dict, lines: list[str]) -> list[str]:
    """The reference anchor's output lines for one script (also for sil_inject anchors)."""
    return run_script(init, lines)


__all__ = ["Script", "generate", "run_model"]
