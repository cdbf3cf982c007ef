#!/usr/bin/env python3
"""The replay's byte-identity check: a recording of radio events played through the
nRF52840 port on the register fake (tests/replay.c) sends exactly the UART frames that
the host build of the core (firmware/build/host/anchor_script, linked from
libpfdoa_anchor.a) sends when it is given the same readings directly.

The readings are taken from the recording here, independently of the port's C code: which
packets are our beacon (the format firmware/micropython/board_ble.py documents; for 802.15.4
the port's interim format in beacon.h), their sequence numbers, RSSI (-RSSISAMPLE dBm for
BLE; ED_RSSIOFFS + value for 802.15.4, as PS v1.7 6.20.12 with nRF52840 errata 236 gives
it), and the poll the port's main loop makes after each event. Exit 0 when identical, 1 with
the first difference otherwise.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ED_RSSIOFFS = -92
ED_RSSISCALE = 4
COMPANY = 0xFFFF
MAGIC = b"PF"


def ble_seq(pdu: bytes) -> int | None:
    if len(pdu) < 2:
        return None
    ptype, plen = pdu[0] & 0x0F, pdu[1]
    # ADV_IND, ADV_NONCONN_IND, SCAN_RSP, ADV_SCAN_IND; a legacy payload is 6..37 bytes.
    if ptype not in (0x0, 0x2, 0x4, 0x6) or not 6 <= plen <= 37 or len(pdu) < 2 + plen:
        return None
    ad = pdu[8:2 + plen]
    i = 0
    while i + 1 < len(ad):
        n = ad[i]
        if n == 0:
            break
        if (ad[i + 1] == 0xFF and n >= 7 and i + n < len(ad) and ad[i + 2] == COMPANY & 0xFF
                and ad[i + 3] == COMPANY >> 8 and ad[i + 4:i + 6] == MAGIC):
            return ad[i + 6] | (ad[i + 7] << 8)
        i += n + 1
    return None


def ieee_seq(mpdu: bytes) -> int | None:
    if len(mpdu) < 3:
        return None
    fcf = mpdu[0] | (mpdu[1] << 8)
    if fcf & 0x7 != 0x1 or fcf & 0x8 or ((fcf >> 12) & 3 == 2 and fcf & 0x200):
        return None
    sizes = {0: 0, 2: 2, 3: 8}
    dst_mode, src_mode = (fcf >> 10) & 3, (fcf >> 14) & 3
    if dst_mode not in sizes or src_mode not in sizes:
        return None
    off = 3
    if sizes[dst_mode]:
        off += 2 + sizes[dst_mode]
    if sizes[src_mode]:
        off += (0 if (fcf & 0x40 and sizes[dst_mode]) else 2) + sizes[src_mode]
    if len(mpdu) < off + 4 or mpdu[off:off + 2] != MAGIC:
        return None
    return mpdu[off + 2] | (mpdu[off + 3] << 8)


def event_script(lines: list[str]) -> tuple[int, list[str], dict[str, int]]:
    """(anchor id, the host build's event script, counts of what the recording holds)."""
    anchor = None
    channel_154 = None
    script = ["P 0"]  # the port's first main-loop pass, at boot
    counts = {"ours": 0, "crc_failed": 0, "strangers": 0, "no_rssi": 0, "idle": 0}
    for raw in lines:
        f = raw.split()
        if not f or f[0].startswith("#"):
            continue
        if f[0] == "I":
            anchor = int(f[1])
            continue
        if f[0] == "M":
            channel_154 = int(f[2]) if f[1] == "154" else None
            continue
        t = int(f[1]) & 0xFFFFFFFF
        if f[0] == "B":
            ch, crc, sample, pdu = int(f[2]), int(f[3]), f[4], bytes.fromhex(f[5])
            seq = ble_seq(pdu) if crc else None
            if not crc:
                counts["crc_failed"] += 1
            elif seq is None:
                counts["strangers"] += 1
            else:
                counts["ours"] += 1
                rssi = 127 if sample == "-" else -(int(sample) & 0x7F)
                counts["no_rssi"] += sample == "-"
                script.append(f"R {t} {seq} {rssi} {ch} 0 0")
        elif f[0] == "Z":
            crc, val, mpdu = int(f[2]), int(f[3]), bytes.fromhex(f[4])
            seq = ieee_seq(mpdu) if crc else None
            if not crc:
                counts["crc_failed"] += 1
            elif seq is None:
                counts["strangers"] += 1
            else:
                counts["ours"] += 1
                rssi = min(ED_RSSIOFFS + val, 126)
                lqi = min(ED_RSSISCALE * val, 255)
                script.append(f"R {t} {seq} {rssi} {channel_154} {lqi} 1")
        elif f[0] == "T":
            counts["idle"] += 1
        script.append(f"P {t}")
    if anchor is None:
        raise SystemExit("recording has no I line")
    return anchor, script, counts


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recording", type=Path)
    p.add_argument("--replay", type=Path, required=True, help="tests/replay.c built for the recording's mode")
    p.add_argument("--anchor-script", type=Path, required=True, help="firmware/build/host/anchor_script")
    args = p.parse_args()
    lines = args.recording.read_text().splitlines()
    anchor, script, counts = event_script(lines)
    host = subprocess.run([str(args.anchor_script), "-a", str(anchor), "-b", "0"], input="\n".join(script) + "\n",
                          capture_output=True, text=True, timeout=120)
    if host.returncode != 0:
        print(f"anchor_script failed: {host.stderr.strip()}")
        return 1
    port = subprocess.run([str(args.replay), str(args.recording)], capture_output=True, text=True, timeout=120)
    if port.returncode != 0:
        print(f"replay failed ({port.returncode}): {port.stderr.strip()}")
        return 1
    want, got = host.stdout.splitlines(), port.stdout.splitlines()
    kinds: dict[str, int] = {}
    for line in want:
        kind = {"01": "reports", "02": "status"}.get(bytes.fromhex(line[2:])[2:3].hex(), "other")
        kinds[kind] = kinds.get(kind, 0) + 1
    if want != got:
        n = next((i for i, (a, b) in enumerate(zip(want, got)) if a != b), min(len(want), len(got)))
        print(f"FAIL {args.recording.name}: frame {n} of {len(want)} differs (port sent {len(got)}):\n"
              f"  host {want[n] if n < len(want) else '-'}\n  port {got[n] if n < len(got) else '-'}")
        return 1
    if kinds.get("reports", 0) < 100 or counts["crc_failed"] == 0 or counts["strangers"] == 0:
        print(f"FAIL {args.recording.name}: the recording does not cover enough ({counts}, {kinds})")
        return 1
    print(f"ok {args.recording.name}: {len(got)} frames byte-identical to the host build "
          f"({sum(1 for s in script if s.startswith('R '))} readings, {counts['crc_failed']} CRC failures, "
          f"{counts['strangers']} other packets, {counts['no_rssi']} without RSSI, {counts['idle']} idle polls)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
