#!/usr/bin/env python3
"""Writes the radio recordings that tests/replay.c plays (radio_events_ble.txt,
radio_events_154.txt): what an nRF52840 anchor's RADIO received, packet by packet, and
what the host sent it on the UART, in protocol version 2.

Synthetic (no board here), from a fixed seed, with what a real scan sees: our beacon (id
0, as firmware/beacon builds it) at an advertising interval of about 250 ms heard on one
to three advertising channels per event, a second robot's beacon (id 3) and an iBeacon
that become configured beacons when the host's FILTER_SETs arrive (and the iBeacon stops
being one when its entry is cleared), RSSI wandering with noise and spikes, CRC failures,
packets without an RSSI sample, strangers' advertisements (another iBeacon, SCAN_REQ, our
company id with the wrong magic, truncated AD structures, a version-1 beacon), repeated
sequence numbers, u16 sequence wrap, silent stretches, host frames (FILTER_SET valid and
invalid, for this anchor and another, CONFIG_SET broadcast, line noise), and a time span
that crosses a 24-bit RTC wrap and the anchor's u32 millisecond wrap. The 802.15.4
recording has our beacon's data frames (SPEC 6), frames of a device the host then
configures by its extended address (MAC64), and strangers.

Frames are built with pfdoa.protocol (beacons, messages, UART encoding): run it with the
project's .venv/bin/python. The files are committed; rerun this to regenerate them (same
seed, same bytes).
"""
from __future__ import annotations

import argparse
import random
from pathlib import Path

from pfdoa.protocol import ConfigSet, FilterSet, adv_pdu, encode_uart, ibeacon_adv_data, pfdoa_adv_data
from pfdoa.protocol.beacons import mac_frame, pfdoa_802154_frame, pfdoa_v1_adv_data
from pfdoa.protocol.filters import BeaconFilter

HERE = Path(__file__).resolve().parent
U32_WRAP_MS = 1 << 32
ANCHOR_ID = 5
ADV_A = bytes([0x11, 0x22, 0x33, 0x44, 0x55, 0xC6])
ADV_A_2 = bytes([0x21, 0x32, 0x43, 0x54, 0x65, 0xC7])
IB_UUID = bytes(range(0x10, 0x20))
IB_MAJOR, IB_MINOR = 7, 9
EXT_ADDR = bytes(range(1, 9))
DEVICE_ADDR = bytes([0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7])
FLAGS = bytes([0x02, 0x01, 0x06])


class Recording:
    """Lines with their times; host lines get 5 ms to themselves (the port collects a
    partial UART chunk 2 ms after the line goes quiet)."""

    def __init__(self, header: list[str]) -> None:
        self.header = header
        self.events: list[tuple[int, int, str]] = []  # (ms, order, line)

    def add(self, t: int, line: str) -> None:
        self.events.append((t, len(self.events), line))

    def host(self, t: int, data: bytes) -> None:
        self.add(t, f"H {t} {data.hex()}")

    def lines(self) -> list[str]:
        out = list(self.header)
        busy_until = -1
        for t, _, line in sorted(self.events):
            if line.startswith("H "):
                t = max(t, busy_until)
                line = f"H {t} {line.split()[2]}"
                busy_until = t + 5
            elif t < busy_until:  # a packet during a host burst: it arrives just after
                f = line.split()
                t = busy_until
                line = " ".join([f[0], str(t), *f[2:]])
            out.append(line)
            busy_until = max(busy_until, t)
        return out


def ble_stranger(rng: random.Random, seq: int, kind: str) -> bytes:
    ours = bytes([0x08, 0xFF, 0xFF, 0xFF, ord("P"), ord("F"), seq & 0xFF, seq >> 8, 0])
    if kind == "other-ibeacon":
        return adv_pdu(bytes(rng.randrange(256) for _ in range(6)),
                       ibeacon_adv_data(bytes(rng.randrange(256) for _ in range(16)), 1, 2))
    if kind == "wrong-magic":
        return adv_pdu(ADV_A, FLAGS + ours[:5] + b"G" + ours[6:])
    if kind == "truncated-ad":
        return adv_pdu(ADV_A, FLAGS + bytes([0x09]) + ours[1:])
    if kind == "zero-ad-first":
        return adv_pdu(ADV_A, bytes([0x00]) + ours)
    if kind == "scan-req":
        return bytes([0x03, 12]) + bytes(rng.randrange(256) for _ in range(12))
    raise ValueError(kind)


def ble_ours(seq: int, kind: str) -> bytes:
    if kind == "ours":
        return adv_pdu(ADV_A, pfdoa_adv_data(seq, 0))
    if kind == "ours-after-name":  # ADV_IND with a name before our data
        return adv_pdu(ADV_A, bytes([0x05, 0x09]) + b"anch" + pfdoa_adv_data(seq, 0)[3:], pdu_type=0x0)
    if kind == "scan-rsp":
        return adv_pdu(ADV_A, pfdoa_adv_data(seq, 0)[3:], pdu_type=0x4)
    if kind == "ours-v1":  # the version-1 beacon without the id byte: read as id 0
        return adv_pdu(ADV_A, pfdoa_v1_adv_data(seq))
    raise ValueError(kind)


def damage(rng: random.Random, pdu: bytes) -> bytes:
    """What arrives with a bad CRC is damaged."""
    i = rng.randrange(2, len(pdu))
    return pdu[:i] + bytes([pdu[i] ^ (1 << rng.randrange(8))]) + pdu[i + 1:]


def advertising_event(rec: Recording, rng: random.Random, t: int, pdu_of, level: float, heard_max: int = 3) -> None:
    """One advertising event: 37, 38, 39 one or two ms apart, some of them heard."""
    first = rng.choice([37, 37, 37, 38, 39])
    heard = min(heard_max, rng.choice([1, 1, 2, 3, 3, 3]) if first == 37 else 1)
    for j in range(heard):
        ch = first + j
        pdu = pdu_of()
        rssi = int(round(level + rng.gauss(0, 2.5)))
        if rng.random() < 0.04:
            rssi += rng.choice([-25, 20])  # a spike
        sample = str(min(127, max(0, -rssi)))
        if rng.random() < 0.01:
            sample = "-"  # no RSSI sample for this packet
        crc = 0 if rng.random() < 0.06 else 1
        if crc == 0:
            pdu = damage(rng, pdu)
        rec.add(t + 2 * j, f"B {t + 2 * j} {ch} {crc} {sample} {pdu.hex()}")


def ble_recording(seed: int) -> list[str]:
    rng = random.Random(seed)
    rec = Recording([f"# BLE recording, seed {seed} (firmware/ports/nrf52840/tests/make_recording.py)",
                     f"I {ANCHOR_ID}", "M ble"])
    t0 = U32_WRAP_MS - 320_000  # 9 s before a 24-bit RTC wrap, 320 s before the u32 ms wrap
    end = U32_WRAP_MS + 15_000
    # Our beacon, id 0.
    t, seq, level = t0, 65_200, -70.0  # seq wraps after ~335 beacons
    kinds = ["ours"] * 80 + ["ours-after-name"] * 4 + ["scan-rsp"] * 3 + ["ours-v1"] * 3
    strangers = ["other-ibeacon"] * 6 + ["wrong-magic"] * 2 + ["truncated-ad"] * 2 + ["zero-ad-first"] + \
        ["scan-req"] * 2
    while t < end:
        t += rng.randrange(240, 262)
        if rng.random() < 0.01:
            t += rng.randrange(1500, 6000)  # the beacon out of range for a while
            u = t - rng.randrange(100, 900)
            rec.add(u, f"T {u}")
        if rng.random() > 0.03:
            seq = (seq + 1) & 0xFFFF  # else: the same sequence number again
        level = min(-40.0, max(-100.0, level + rng.gauss(0, 1.2)))
        kind = rng.choice(kinds)
        advertising_event(rec, rng, t, lambda s=seq, k=kind: ble_ours(s, k), level)
        if rng.random() < 0.15:
            u = t + rng.randrange(60, 120)
            rec.add(u, f"B {u} 37 1 {rng.randrange(50, 90)} {ble_stranger(rng, seq, rng.choice(strangers)).hex()}")
        if rng.random() < 0.05:
            u = t + rng.randrange(21, 200)
            rec.add(u, f"T {u}")  # the 20 ms event timeout at a poll
    # A second robot's beacon, id 3, every ~400 ms: a stranger until entry 2 is set.
    t, seq2, level2 = t0 + 97, 100, -80.0
    while t < end:
        t += rng.randrange(390, 410)
        seq2 = (seq2 + 1) & 0xFFFF
        level2 = min(-40.0, max(-100.0, level2 + rng.gauss(0, 1.0)))
        advertising_event(rec, rng, t, lambda s=seq2: adv_pdu(ADV_A_2, pfdoa_adv_data(s, 3)), level2)
    # An iBeacon every ~700 ms: no sequence number; a stranger until entry 1 is set, and
    # again after the entry is cleared.
    t, level3 = t0 + 173, -65.0
    ib = adv_pdu(bytes([0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xE6]), ibeacon_adv_data(IB_UUID, IB_MAJOR, IB_MINOR))
    while t < end:
        t += rng.randrange(680, 720)
        level3 = min(-40.0, max(-100.0, level3 + rng.gauss(0, 1.0)))
        advertising_event(rec, rng, t, lambda: ib, level3)
    # What the host sends.
    ib_entry = BeaconFilter.ibeacon(IB_UUID, IB_MAJOR, IB_MINOR, period_ms=200)
    rec.host(t0 + 20_000, encode_uart(ib_entry.set_message(1, 1), ANCHOR_ID))
    rec.host(t0 + 60_000, encode_uart(BeaconFilter.pfdoa(3).set_message(2, 2), ANCHOR_ID))
    rec.host(t0 + 60_500, encode_uart(BeaconFilter.pfdoa(4).set_message(3, 3), ANCHOR_ID + 1))  # not ours
    rec.host(t0 + 100_000, encode_uart(ConfigSet(4, 512, 128, 10, 0, 1), 127) +
             encode_uart(FilterSet(5, 3, 9, 0, b""), ANCHOR_ID))  # broadcast CONFIG_SET; an invalid kind
    rec.host(t0 + 150_000, bytes([0x03, 0x01, 0x02, 0x00, 0x55, 0xAA]))  # line noise: rx_errors
    rec.host(t0 + 250_000, encode_uart(BeaconFilter.none().set_message(6, 1), ANCHOR_ID))
    return rec.lines()


def ieee_recording(seed: int) -> list[str]:
    rng = random.Random(seed)
    rec = Recording([f"# IEEE 802.15.4 recording, seed {seed} (firmware/ports/nrf52840/tests/make_recording.py)",
                     f"I {ANCHOR_ID}", "M 154 15"])
    t = 1_000
    seq = 65_450
    val = 40.0
    kinds = ["ours"] * 80 + ["device"] * 8 + ["secured"] * 3 + ["ack"] * 4 + ["other"] * 3 + ["interim"] * 2
    for _ in range(600):
        t += rng.randrange(90, 130)
        seq = (seq + 1) & 0xFFFF
        val = min(90.0, max(0.0, val + rng.gauss(0, 1.5)))
        kind = rng.choice(kinds)
        if kind == "ours":
            mpdu = pfdoa_802154_frame(seq, 0, EXT_ADDR)
        elif kind == "device":  # a Zigbee device's long data frame: configured later by its address
            mpdu = mac_frame(bytes(rng.randrange(256) for _ in range(rng.randrange(10, 100))), seq=seq,
                             src_addr=DEVICE_ADDR)
        elif kind == "secured":
            mpdu = mac_frame(b"PF" + bytes([seq & 0xFF, seq >> 8, 0]), seq=seq, src_addr=EXT_ADDR, security=True)
        elif kind == "ack":
            mpdu = bytes([0x02, 0x00, rng.randrange(256)])
        elif kind == "other":
            mpdu = mac_frame(b"ZB" + bytes([1, 2, 3]), seq=seq, src_addr=EXT_ADDR)
        else:  # the port's version-1 stand-in ("PF" + seq, no id): not a beacon any more
            mpdu = bytes([0x41, 0x88, seq & 0xFF, 0xCD, 0xAB, 0xFF, 0xFF, 0x34, 0x12]) + b"PF" + \
                bytes([seq & 0xFF, seq >> 8])
        crc = 0 if rng.random() < 0.05 else 1
        if crc == 0:
            mpdu = damage(rng, mpdu)
        lqi = max(0, min(255, int(round(val + rng.gauss(0, 2)))))
        if rng.random() < 0.02:
            lqi = rng.choice([0, 200, 255])  # edges of the conversion
        rec.add(t, f"Z {t} {crc} {lqi} {mpdu.hex()}")
        if rng.random() < 0.03:
            t += rng.randrange(1000, 3000)
            rec.add(t, f"T {t}")
    rec.host(30_000, encode_uart(BeaconFilter.mac64(DEVICE_ADDR, period_ms=300).set_message(1, 1), ANCHOR_ID))
    return rec.lines()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out-dir", type=Path, default=HERE)
    p.add_argument("--seed", type=int, default=18)
    args = p.parse_args()
    (args.out_dir / "radio_events_ble.txt").write_text("\n".join(ble_recording(args.seed)) + "\n")
    (args.out_dir / "radio_events_154.txt").write_text("\n".join(ieee_recording(args.seed)) + "\n")


if __name__ == "__main__":
    main()
