#!/usr/bin/env python3
"""The replay's byte-identity check: a recording of radio events and host bytes played
through the nRF52840 port on the register fake (tests/replay.c) sends exactly the UART
frames that the host build of the core (firmware/build/host/anchor_script, linked from
libpfdoa_anchor.a) sends when it is given the same receptions directly.

What the host build is given is derived from the recording here, independently of the
port's C code: which packets reach the core (those with a good CRC; the host build's core
ignores those that match no filter entry, as the port's radio filter drops them), each
one's tick (the recording's ms mod 2^32), RSSI (-RSSISAMPLE dBm for BLE, 127 without a
sample; ED_RSSIOFFS + value for 802.15.4, as PS v1.7 6.20.12 with nRF52840 errata 236
gives it), LQI (min(4 value, 255)) and channel, the raw frame (`B` / `Z` script lines: the
core's raw entry points), the host bytes as the port's UARTE hands them over (whole
16-byte chunks at once, the rest UARTE_RX_IDLE_MS = 2 ms later, uarte.h), and the poll
the port's main loop makes after each event.

Every output frame is decoded with pfdoa.protocol (version 2) and classified; the check
fails unless the recording covers enough (reports of several filter entries, reports
without a sequence number, STATUS, acks, CRC failures, packets of no configured beacon,
judged with pfdoa.protocol's own matcher and the FILTER_SETs the recording holds). Exit 0
when identical, 1 with the first difference (or what is missing) otherwise. Needs the
pfdoa package (the project's .venv/bin/python; make test-c passes it).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from collections import Counter
from pathlib import Path

try:
    from pfdoa.protocol import (
        ANCHOR_TO_HOST,
        HOST_TO_ANCHOR,
        Decoded,
        FilterSet,
        RssiReport,
        StreamDecoder,
        decode_frame,
        default_table,
        defs,
        match_802154,
        match_ble_pdu,
    )
    from pfdoa.protocol.filters import BeaconFilter
except ImportError as exc:  # pragma: no cover - a usage error, not a test path
    raise SystemExit(f"replay_check: the pfdoa package is not importable ({exc}); run it with the "
                     "project's .venv/bin/python (make test-c does) or `pip install -e .`") from None

ED_RSSIOFFS = -92
ED_RSSISCALE = 4
RSSISAMPLE_MASK = 0x7F  # RSSISAMPLE is 7 bits
UARTE_RX_CHUNK = 16
UARTE_RX_IDLE_MS = 2


class Table:
    """The anchor's filter table as the recording's FILTER_SETs leave it (for coverage)."""

    def __init__(self, anchor: int) -> None:
        self.anchor = anchor
        self.entries = list(default_table())
        self.rx = StreamDecoder(types=HOST_TO_ANCHOR, versions=[defs.PROTO_VERSION])

    def host(self, data: bytes) -> None:
        for d in self.rx.feed(data):
            m = d.message
            if isinstance(m, FilterSet) and d.anchor_id in (self.anchor, defs.ANCHOR_BROADCAST):
                f = BeaconFilter.of_message(m)
                if m.index < defs.BEACON_SLOTS and f.is_valid():
                    self.entries[m.index] = f


def event_script(lines: list[str]) -> tuple[int, list[str], Counter]:
    """(anchor id, the host build's event script, counts of what the recording holds)."""
    anchor = None
    channel_154 = None
    table: Table | None = None
    script = ["P 0"]  # the port's first main-loop pass, at boot
    counts: Counter = Counter()
    for raw in lines:
        f = raw.split()
        if not f or f[0].startswith("#"):
            continue
        if f[0] == "I":
            anchor = int(f[1])
            table = Table(anchor)
            continue
        if f[0] == "M":
            channel_154 = int(f[2]) if f[1] == "154" else None
            continue
        assert table is not None, "the first line must be I <anchor id>"
        ms = int(f[1])
        t = ms & 0xFFFFFFFF
        if f[0] == "B":
            ch, crc, sample, pdu = int(f[2]), int(f[3]), f[4], bytes.fromhex(f[5])
            if not crc:
                counts["crc_failed"] += 1
            else:
                rssi = 127 if sample == "-" else -(int(sample) & RSSISAMPLE_MASK)
                script.append(f"B {t} {rssi} {ch} {pdu.hex()}")
                m = match_ble_pdu(table.entries, pdu)
                counts["strangers" if m is None else f"entry{m.index}"] += 1
                counts["no_rssi"] += m is not None and sample == "-"
        elif f[0] == "Z":
            crc, val, mpdu = int(f[2]), int(f[3]), bytes.fromhex(f[4])
            if not crc:
                counts["crc_failed"] += 1
            else:
                rssi = min(ED_RSSIOFFS + val, 126)
                lqi = min(ED_RSSISCALE * val, 255)
                script.append(f"Z {t} {rssi} {channel_154} {lqi} {mpdu.hex()}")
                m = match_802154(table.entries, mpdu)
                counts["strangers" if m is None else f"entry{m.index}"] += 1
        elif f[0] == "H":
            data = bytes.fromhex(f[2])
            table.host(data)
            counts["host_bursts"] += 1
            whole = len(data) - len(data) % UARTE_RX_CHUNK
            if whole:
                script.append(f"U {t} {data[:whole].hex()}")
            if whole < len(data):
                script.append(f"P {t}")
                t = (ms + UARTE_RX_IDLE_MS) & 0xFFFFFFFF
                script.append(f"P {t}")  # the pass that stops reception on the quiet line
                script.append(f"U {t} {data[whole:].hex()}")
        elif f[0] == "T":
            counts["idle"] += 1
        script.append(f"P {t}")
    if anchor is None:
        raise SystemExit("recording has no I line")
    return anchor, script, counts


def classify(frames: list[str]) -> Counter:
    """Every output frame decoded (version 2, anchor-to-host types) and counted by kind."""
    kinds: Counter = Counter()
    for line in frames:
        wire = bytes.fromhex(line[2:])
        d = decode_frame(wire[:-1], types=ANCHOR_TO_HOST, versions=[defs.PROTO_VERSION])
        if not line.startswith("U ") or wire[-1:] != b"\x00" or not isinstance(d, Decoded):
            kinds["undecodable"] += 1
            continue
        m = d.message
        kinds[m.NAME] += 1
        if isinstance(m, RssiReport):
            kinds[f"reports_beacon{m.beacon}"] += 1
            kinds["reports_no_seq"] += bool(m.flags & defs.FLAG_NO_SEQ)
    return kinds


def covered(counts: Counter, kinds: Counter) -> list[str]:
    """What the recording fails to cover (empty: enough)."""
    need = []
    entries = sorted(k for k in kinds if k.startswith("reports_beacon"))
    if kinds["RSSI_REPORT"] < 100 or len(entries) < 2:
        need.append("at least 100 reports, of at least two filter entries")
    for k in ("reports_no_seq", "STATUS", "FILTER_ACK"):
        if kinds[k] == 0:
            need.append(k)
    if kinds["undecodable"]:
        need.append("every output frame decodes as version 2")
    for k in ("crc_failed", "strangers", "host_bursts"):
        if counts[k] == 0:
            need.append(k)
    return need


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
    if want != got:
        n = next((i for i, (a, b) in enumerate(zip(want, got)) if a != b), min(len(want), len(got)))
        print(f"FAIL {args.recording.name}: frame {n} of {len(want)} differs (port sent {len(got)}):\n"
              f"  host {want[n] if n < len(want) else '-'}\n  port {got[n] if n < len(got) else '-'}")
        return 1
    kinds = classify(got)
    missing = covered(counts, kinds)
    if missing:
        print(f"FAIL {args.recording.name}: the recording does not cover enough: {', '.join(missing)} "
              f"({dict(counts)}, {dict(kinds)})")
        return 1
    summary = ", ".join(f"{k} {v}" for k, v in sorted(kinds.items()))
    print(f"ok {args.recording.name}: {len(got)} frames byte-identical to the host build ({summary}); "
          f"receptions {dict(sorted(counts.items()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
