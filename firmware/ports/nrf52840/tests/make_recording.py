#!/usr/bin/env python3
"""Writes the radio recordings that tests/replay.c plays (radio_events_ble.txt,
radio_events_154.txt): what an nRF52840 anchor's RADIO received, packet by packet.

Synthetic (no board here), from a fixed seed, with what a real scan sees: our beacon at
an advertising interval of about 250 ms heard on one to three advertising channels per
event, RSSI wandering with noise and spikes, CRC failures, packets without an RSSI sample,
strangers' advertisements (iBeacon-like, SCAN_REQ, our company id with the wrong magic,
truncated AD structures), repeated sequence numbers, u16 sequence wrap, silent stretches,
and a time span that crosses a 24-bit RTC wrap and the anchor's u32 millisecond wrap.
The file is committed; rerun this to regenerate it (same seed, same bytes).
"""
from __future__ import annotations

import argparse
import random
from pathlib import Path

HERE = Path(__file__).resolve().parent
U32_WRAP_MS = 1 << 32
ANCHOR_ID = 5


def ble_pdu(rng: random.Random, seq: int, kind: str) -> bytes:
    adva = bytes([0x11, 0x22, 0x33, 0x44, 0x55, 0xC6])
    flags = bytes([0x02, 0x01, 0x06])
    ours = bytes([0x07, 0xFF, 0xFF, 0xFF, ord("P"), ord("F"), seq & 0xFF, seq >> 8])
    ptype = 0x42  # ADV_NONCONN_IND, random address
    if kind == "ours":
        ad = flags + ours
    elif kind == "ours-after-name":
        ad = flags + bytes([0x05, 0x09]) + b"anch" + ours
        ptype = 0x40  # ADV_IND
    elif kind == "scan-rsp":
        ad = ours
        ptype = 0x44
    elif kind == "ibeacon":
        adva = bytes(rng.randrange(256) for _ in range(6))
        ad = flags + bytes([0x1A, 0xFF, 0x4C, 0x00, 0x02, 0x15]) + bytes(rng.randrange(256) for _ in range(21))
    elif kind == "wrong-magic":
        ad = flags + bytes([0x07, 0xFF, 0xFF, 0xFF, ord("P"), ord("G"), seq & 0xFF, seq >> 8])
    elif kind == "truncated-ad":
        ad = flags + bytes([0x08, 0xFF, 0xFF, 0xFF, ord("P"), ord("F"), seq & 0xFF, seq >> 8])
    elif kind == "zero-ad-first":
        ad = bytes([0x00]) + ours
    elif kind == "scan-req":
        return bytes([0x03, 12]) + bytes(rng.randrange(256) for _ in range(12))
    else:
        raise ValueError(kind)
    payload = adva + ad
    return bytes([ptype, len(payload)]) + payload


def ieee_mpdu(rng: random.Random, seq: int, kind: str) -> bytes:
    tail = b"PF" + bytes([seq & 0xFF, seq >> 8])
    if kind == "ours":  # data, PAN id compression, short dst and src
        return bytes([0x41, 0x88, rng.randrange(256), 0xCD, 0xAB, 0xFF, 0xFF, 0x34, 0x12]) + tail
    if kind == "ours-ext":  # extended source address
        return bytes([0x41, 0xC8, rng.randrange(256), 0xCD, 0xAB, 0xFF, 0xFF]) + bytes(range(8)) + tail
    if kind == "secured":
        return bytes([0x49, 0x88, 1, 0xCD, 0xAB, 0xFF, 0xFF, 0x34, 0x12]) + tail
    if kind == "ack":
        return bytes([0x02, 0x00, rng.randrange(256)])
    if kind == "other":
        return bytes([0x41, 0x88, 1, 0xCD, 0xAB, 0xFF, 0xFF, 0x34, 0x12]) + b"ZB" + bytes([1, 2, 3])
    raise ValueError(kind)


def ble_recording(seed: int) -> list[str]:
    rng = random.Random(seed)
    lines = [f"# BLE recording, seed {seed} (firmware/ports/nrf52840/tests/make_recording.py)",
             f"I {ANCHOR_ID}", "M ble"]
    t = U32_WRAP_MS - 320_000  # 9 s before a 24-bit RTC wrap, 320 s before the u32 ms wrap
    end = U32_WRAP_MS + 15_000
    seq = 65_200  # wraps after ~335 beacons
    level = -70.0
    kinds = ["ours"] * 80 + ["ours-after-name"] * 4 + ["scan-rsp"] * 3 + ["ibeacon"] * 6 + ["wrong-magic"] * 2 \
        + ["truncated-ad"] * 2 + ["zero-ad-first"] * 1 + ["scan-req"] * 2
    while t < end:
        t += rng.randrange(240, 262)
        if rng.random() < 0.01:
            t += rng.randrange(1500, 6000)  # the beacon out of range for a while
            lines.append(f"T {t - rng.randrange(100, 900)}")
        if rng.random() > 0.03:
            seq = (seq + 1) & 0xFFFF  # else: the same sequence number again
        level = min(-40.0, max(-100.0, level + rng.gauss(0, 1.2)))
        first = rng.choice([37, 37, 37, 38, 39])
        heard = rng.choice([1, 1, 2, 3, 3]) if first == 37 else 1
        for j in range(heard):
            ch = first + j
            kind = rng.choice(kinds)
            pdu = ble_pdu(rng, seq, kind)
            rssi = int(round(level + rng.gauss(0, 2.5)))
            if rng.random() < 0.04:
                rssi += rng.choice([-25, 20])  # a spike
            sample = str(min(127, max(0, -rssi)))
            if rng.random() < 0.01:
                sample = "-"  # no RSSI sample for this packet
            crc = 0 if rng.random() < 0.06 else 1
            if crc == 0:  # what arrives with a bad CRC is damaged
                i = rng.randrange(2, len(pdu))
                pdu = pdu[:i] + bytes([pdu[i] ^ (1 << rng.randrange(8))]) + pdu[i + 1:]
            lines.append(f"B {t + 2 * j} {ch} {crc} {sample} {pdu.hex()}")
        if rng.random() < 0.05:
            lines.append(f"T {t + rng.randrange(21, 200)}")  # the 20 ms event timeout at a poll
    return lines


def ieee_recording(seed: int) -> list[str]:
    rng = random.Random(seed)
    lines = [f"# IEEE 802.15.4 recording, seed {seed} (firmware/ports/nrf52840/tests/make_recording.py)",
             f"I {ANCHOR_ID}", "M 154 15"]
    t = 1_000
    seq = 65_450
    val = 40.0
    kinds = ["ours"] * 85 + ["ours-ext"] * 5 + ["secured"] * 3 + ["ack"] * 4 + ["other"] * 3
    for _ in range(600):
        t += rng.randrange(90, 130)
        seq = (seq + 1) & 0xFFFF
        val = min(90.0, max(0.0, val + rng.gauss(0, 1.5)))
        kind = rng.choice(kinds)
        mpdu = ieee_mpdu(rng, seq, kind)
        crc = 0 if rng.random() < 0.05 else 1
        lqi = max(0, min(255, int(round(val + rng.gauss(0, 2)))))
        if rng.random() < 0.02:
            lqi = rng.choice([0, 200, 255])  # edges of the conversion
        lines.append(f"Z {t} {crc} {lqi} {mpdu.hex()}")
        if rng.random() < 0.03:
            t += rng.randrange(1000, 3000)
            lines.append(f"T {t}")
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out-dir", type=Path, default=HERE)
    p.add_argument("--seed", type=int, default=18)
    args = p.parse_args()
    (args.out_dir / "radio_events_ble.txt").write_text("\n".join(ble_recording(args.seed)) + "\n")
    (args.out_dir / "radio_events_154.txt").write_text("\n".join(ieee_recording(args.seed)) + "\n")


if __name__ == "__main__":
    main()
