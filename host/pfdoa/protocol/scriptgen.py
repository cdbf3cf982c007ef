"""Seeded random event scripts for the differential checks of the anchor implementations.

One generator for `tests/test_differential.py` (C == MicroPython == Python model) and
`firmware/tools/diffcheck.py` (C == Python model inside `make test-c`). A script is an
`init` object and event-script lines (protocol/vectors/README.md): BLE beacon events on
1..3 channels (and invalid channels), 802.15.4 readings, unavailable RSSI, outliers and
level changes (spikes, re-initialisation), polls, tick jumps and u32 wraps, CONFIG_SETs
valid and invalid over UART and CAN (own id, broadcast, another anchor, bad DLC, random
ids), corrupted, garbage-prefixed, split and over-long frames, and frames an anchor does
not know. `run_model` gives the reference output of a script.
"""

from __future__ import annotations

import random

from . import defs
from .anchor_model import AnchorModel
from .config import AnchorConfig
from .cobs import cobs_encode
from .crc import crc16
from .messages import ConfigSet, RadioInject, RssiReport
from .script import format_unit, run_script, step
from .uart import encode_raw

U32 = 0xFFFFFFFF

Script = tuple[dict, list[str]]


def _frame(raw: bytes) -> bytes:
    return cobs_encode(raw) + b"\x00"


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

    # -- time
    def advance(self, lo: int, hi: int) -> int:
        self.tick = (self.tick + self.rng.randrange(lo, hi + 1)) & U32
        return self.tick

    # -- events
    def rssi(self) -> int:
        rng = self.rng
        r = rng.random()
        if r < 0.03:
            return rng.choice((-128, 20, 127, 21, 126, rng.randrange(-128, 128)))
        if r < 0.10:  # outlier, drives spikes and spike runs
            return max(-128, min(126, self.level + rng.choice((-1, 1)) * rng.randrange(13, 40)))
        return max(-128, min(126, self.level + rng.randrange(-4, 5)))

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
            aid = self.anchor_id if self.rng.random() < 0.95 else (self.anchor_id + 1) % 127
            self.uart(_frame(encode_raw(RadioInject(seq, self.tick, rssi, ch, lqi, radio),
                                        aid)))
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

    def poll(self) -> None:
        self.lines.append(f"P {self.tick}")

    # -- host input
    def config_frame(self) -> None:
        rng = self.rng
        cfg = self._random_config(valid=rng.random() < 0.8)
        token = rng.randrange(256)
        aid = rng.choice((self.anchor_id, self.anchor_id, 127, (self.anchor_id + 1) % 127))
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
        raw = encode_raw(payload, aid)
        frame = _frame(raw)
        r = rng.random()
        if r < 0.15:  # corrupted somewhere inside the frame
            b = bytearray(raw)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            frame = _frame(bytes(b))
        elif r < 0.2:
            frame = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 90))) + frame
        self.uart(frame)

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
            data = _frame(encode_raw(RadioInject(self.seq, self.tick, -50, 37, 0, 0),
                                     self.anchor_id))
        elif r < 0.45:
            data = _frame(encode_raw(RssiReport(1, 2, -3, -4, 1, 37, 0), self.anchor_id))
        elif r < 0.6:
            data = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(60, 140)))
            data += b"\x00"
        elif r < 0.7:
            raw = bytes((defs.PROTO_VERSION, defs.MSG_CONFIG_SET, defs.ANCHOR_BROADCAST + 1)) + ConfigSet(1).pack()
            c = crc16(bytes((defs.MSG_CONFIG_SET_CRC_EXTRA,)), crc16(raw))
            data = _frame(raw + bytes((c & 0xFF, c >> 8)))  # anchor id 128: bad_anchor
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        self.uart(data)

    def build(self) -> tuple[dict, list[str]]:
        rng = self.rng
        self.poll()
        n = rng.randrange(5, 50)
        for _ in range(n):
            r = rng.random()
            if r < 0.55:
                self.ble_event()
                self.next_seq()
                self.advance(0, 40)
            elif r < 0.7:
                self.zigbee_reading()
                self.next_seq()
            elif r < 0.8:
                self.poll()
                self.advance(0, 30)
            elif r < 0.85:
                self.advance(500, 2500)
                self.poll()
            elif r < 0.91:
                self.config_frame()
            elif r < 0.95:
                self.odd_frame()
            elif r < 0.98:
                self.level = rng.randrange(-110, -20)  # real level change
            else:  # a reading whose tick wraps around 2^32
                self.tick = (U32 - rng.randrange(0, 30)) & U32
        self.advance(0, 1200)
        self.poll()
        return self.init, self.lines


def generate(n: int, seed: int, both: bool = False, inject: bool = False) -> list[Script]:
    """n random scripts; both=True gives anchors reporting on UART and CAN at once;
    inject=True delivers most readings as RADIO_INJECT frames (init sil_inject)."""
    rng = random.Random(seed)
    seqs = [_Gen(rng, both, inject).build() for _ in range(n)]
    if inject:
        for init, _ in seqs:
            init["sil_inject"] = True
    return seqs


def run_model(init: dict, lines: list[str]) -> list[str]:
    """The reference anchor's output lines for one script (also for sil_inject anchors)."""
    if not init.get("sil_inject"):
        return run_script(init, lines)
    cfg = AnchorConfig(**init["config"]) if "config" in init else None  # run_script: production only
    model = AnchorModel(init["anchor_id"], init.get("transport", "uart"),
                        boot_tick_ms=init.get("boot_tick_ms", 0), config=cfg,
                        store_ok=init.get("store_ok", True), sil_inject=True)
    return [format_unit(u) for ln in lines for u in step(model, ln)]


__all__ = ["Script", "generate", "run_model"]
