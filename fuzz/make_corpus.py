#!/usr/bin/env python3
"""Write the small seed corpora under fuzz/corpus/<target>/ (deterministic; re-run to refresh).

Seeds are valid inputs of each format so the fuzzers start past the parsers' front doors.
They are built with the protocol code, so a protocol change changes them: re-run this and
commit the result (tests/unit/test_fuzz_regressions.py fails while a committed seed differs).

Usage: python fuzz/make_corpus.py [--out DIR]   (default: fuzz/corpus)
"""

from __future__ import annotations

import argparse
import struct
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "host"))

from pfdoa.protocol import (  # noqa: E402
    ConfigAck,
    ConfigSet,
    RssiReport,
    Status,
    cobs_encode,
    defs,
    encode_uart,
)
from pfdoa.protocol.auth import tag as auth_tag  # noqa: E402
from pfdoa.protocol.beacons import (  # noqa: E402
    adv_pdu,
    altbeacon_adv_data,
    eddystone_uid_adv_data,
    ibeacon_adv_data,
    mac_frame,
    pfdoa_802154_frame,
    pfdoa_adv_data,
    pfdoa_auth_802154_frame,
    pfdoa_auth_adv_data,
    pfdoa_auth_pdu,
)
from pfdoa.protocol.can import encode_can  # noqa: E402
from pfdoa.protocol.filters import BeaconFilter, pack_table  # noqa: E402

OUT = ROOT / "fuzz" / "corpus"


def seeds() -> list[tuple[str, str, bytes]]:
    """Every seed as (target, file name, bytes)."""
    out: list[tuple[str, str, bytes]] = []

    def put(target: str, name: str, data: bytes) -> None:
        out.append((target, name, data))

    reports = b"".join(encode_uart(RssiReport(k, 1000 * k, -15000 + 37 * k, -60, 3, 37, 8), k % 5) for k in range(6))
    status = encode_uart(Status(1, 0, 42, 0x1234, 1, 2, 3, defs.DEFS_HASH), 2)
    ack = encode_uart(ConfigAck(7, 0, 0xBEEF), 3)
    # host side
    put("stream", "reports", b"\x00" + reports)
    put("stream", "mixed", b"\x00" + reports[:30] + status + b"\x55" * 70 + b"\x00" + ack)
    put("stream", "records", bytes([1]) + bytes([0x40 | 15, 0, 0]) + bytes(13) + bytes([0x40 | 19, 0, 1]) + bytes(17))
    cans = b""
    for m, a in ((RssiReport(5, None, -12000, -70, 1, 11, 16), 4), (ConfigAck(1, 1, 2), 9),
                 (Status(1, 0, 9, 1, 2, 3, 4, defs.DEFS_HASH), 126), (ConfigSet(3, 0, 64, 12, 0, 1), 127)):
        for cid, data in encode_can(m, a):
            cans += cid.to_bytes(2, "little") + bytes([len(data)]) + data
    put("can", "frames", cans)
    rec = struct.Struct("<BHbBB")
    seqs = b"".join(rec.pack(a, k, -60 - a, 2 if a == 0 else 0, 0x80) for k in range(8) for a in range(5))
    put("reassembler", "seq_clean", b"\x01" + seqs)
    lossy = b"".join(rec.pack(a, k, -60 - a, 3, 0x80 | (0x20 if a == 4 else 0)) for k in range(12) for a in range(5)
                     if (k + a) % 4)
    put("reassembler", "seq_lossy_polls", b"\x01" + lossy)
    put("reassembler", "window", b"\x02" + seqs)
    esp = (b'{"id":"tag-1","mac":"e2c56db5dffb","rssi@1m":-63,"rssi":-71.25,"rxAdj":0,"distance":2.1,'
           b'"int":100,"t":17.25}')
    put("espresense", "message", b"espresense/devices/tag-1/hall\n" + esp)
    put("espresense", "rooms_and_devices", b"\x00".join((
        b"espresense/devices/tag-1/kitchen\n" + esp, b"espresense/devices/iBeacon:e2c5-1-2/office\n" + esp,
        b"espresense/devices/tag-2/cellar\n" + esp, b"espresense/devices/phone/hall\n" + esp,
        b'espresense/devices/tag-3/hall\n{"rssi": -80}', b"espresense/devices/tag-1/hall\n{")))
    put("trace", "trace.csv", b"t,anchor,rssi_dbm,gt_x,gt_y,seq\n0.0,1,-60,0.5,0.5,0\n0.0,2,-71.5,0.5,0.5,0\n"
                              b"0.1,1,-61,0.6,0.5,1\n# comment\n0.2,3,-80,,,2\n")
    put("trace", "odom.csv", b"t,dx,dy,dtheta\n0.0,0.01,0,0.001\n0.1,0.02,0.001,-0.002\n")
    put("site", "site.toml", b"[radio]\nrssi_at_1m_dbm = -59.0\npath_loss_exponent = 2.1\n\n"
                             b"[[anchors]]\nid = 1\nx = 0.0\ny = 0.0\n\n[[anchors]]\nid = 2\nx = 6.0\ny = 0.0\n"
                             b"rssi_offset_db = 1.5\n\n[[anchors]]\nid = 3\nx = 6\ny = 6\nname = \"c\"\n\n"
                             b"[gateway]\nmode = \"seq\"\n")
    put("capture", "capture.txt", b"# pfdoa capture v1\n(0.000000) ttyUSB0 S " + reports[:19].hex().encode()
        + b"\n(0.010000) can0 C 101#0500a0d1bb010b10\n(0.020000) ttyUSB0 S " + reports[19:38].hex().encode() + b"\n")
    # the command line's file inputs, end to end (fuzz/py/harnesses.py cli_*: pfdoa replay / gateway)
    site = (b"[site]\nname = \"hall \\\"A\\\" \\u00e9\"\n\n[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.5\n"
            + b"".join(b"\n[[anchors]]\nid = %d\nx = %d\ny = %d\n" % (i + 1, x, y)
                       for i, (x, y) in enumerate(((0, 0), (0, 6), (6, 6), (6, 0))))
            + b"\n[gateway]\nmode = \"window\"\nwindow_s = 0.5\n\n[estimator]\nmethod = \"wcl\"\n"
            + b"\n[output]\nformat = \"csv\"\n")
    put("cli_site", "site.toml", site)
    put("cli_site", "bom-crlf.toml", b"\xef\xbb\xbf" + site.replace(b"\n", b"\r\n"))
    # pfdoa calibrate's [radio_map] (pfdoa.radiomap), small: its validation is a front door too
    radio_map = (b"\n[radio_map]\ntrust = 0.6\nlength_m = 1.0\nprior_windows = 5.0\nanchors = [1, 2, 3]\n"
                 b"x = [1.125, 1.375, 4.875]\ny = [0.625, 0.625, 3.125]\n"
                 b"residual_db = [[1.5, -0.25, 0.0], [-3.0, 2.0, 0.0], [1.5, -1.75, 0.5]]\n"
                 b"count = [[2, 1, 0], [2, 1, 3], [2, 1, 3]]\n")
    put("cli_site", "radio-map.toml", site.split(b"\n[estimator]")[0] + b"\n[estimator]\nmethod = \"pf-doa\"\n"
        + radio_map)
    put("site", "radio-map.toml", b"[radio]\nrssi_at_1m_dbm = -59.0\npath_loss_exponent = 2.1\n"
        + b"".join(b"\n[[anchors]]\nid = %d\nx = %d\ny = %d\n" % (i + 1, x, y)
                   for i, (x, y) in enumerate(((0, 0), (6, 0), (6, 6))))
        + radio_map)
    rows = b"".join(b"%.1f,%d,%d,3.0,%.1f,%d\n" % (k * 0.1, a, -55 - 3 * a, 1 + 0.1 * k, k)
                    for k in range(10) for a in (1, 2, 3, 4))
    put("cli_trace", "trace.csv", b"t,anchor,rssi_dbm,gt_x,gt_y,seq\n" + rows)
    put("cli_trace", "window.csv", b"t,anchor,rssi_dbm\n" + b"".join(b"%d,%d,-6%d\n" % (k // 8, 1 + k % 4, k % 10)
                                                                      for k in range(64)))
    put("cli_trace", "unknown-ids.csv", b"t,anchor,rssi_dbm\n0.0,7,-60\n0.0,1,-61\n0.1,8,-62\n")
    put("cli_odometry", "odom.csv", b"t,dx,dy,dtheta\n" + b"".join(b"%.1f,0.02,0.0,0.001\n" % (k * 0.1)
                                                                  for k in range(10)))
    put("cli_odometry", "overlong.csv", b"t,dx,dy,dtheta\n0.0,0.01,0,0\n" + b"9" * 5000 + b"\n0.2,0.01,0,0\n")
    cap = [b"# pfdoa capture v2"]
    for k in range(6):
        for a in (1, 2, 3, 4):
            cap.append(b"(%.3f) serial%d S %s" % (k * 0.1 + 0.001 * a, a,
                       encode_uart(RssiReport(k, 1000 * k, -15000 - 300 * a, -60, 3, 37, 8), a).hex().encode()))
        cap.append(b"(%.3f) odom O %.1f,0.01,0,0.001" % (k * 0.1 + 0.005, k * 0.1))
        cap.append(b"(%.3f) - T" % (k * 0.1 + 0.006))
    put("cli_capture", "capture.txt", b"\n".join(cap) + b"\n")
    # firmware side
    put("cobs", "frame", cobs_encode(bytes(range(20))))
    put("cobs", "long", cobs_encode(bytes(range(1, 256)) + b"\x00\x01"))
    sets = b"".join(encode_uart(ConfigSet(k, -k, 64 + k, 3, k % 3, 1 + k), 127 if k % 2 else 9) for k in range(4))
    put("uart_rx", "config_sets", b"\x00\x09\x00" + sets + b"\x01" * 70 + b"\x00" + reports)
    put("uart_rx", "records", b"\x01\x09" + bytes([0x40 | 13, 0, 0, 9]) + bytes([1, 0, 0, 64, 0, 12, 0, 1]) + b"\x00\x00"
        + bytes([0x40 | 13, 0, 0, 127]) + bytes([2, 0, 1, 0, 1, 3, 1, 5]) + b"\x00\x00")
    can_in = bytes([9])
    for k, (cid, dlc) in enumerate(((0x189, 8), (0x1FF, 8), (0x189, 4), (0x180, 8))):
        can_in += bytes([cid & 0xFF, (cid >> 8) | (dlc << 4)]) + bytes([k, 0, 0, 64 + k, 0, 12, 0, 1])[:dlc]
    put("can_rx", "config_sets", can_in)
    # protocol v2 (SPEC 3): raw receptions against a table of every kind, and FILTER_SET
    uuid, ns, inst, alt = bytes(range(16)), bytes(range(10)), bytes(range(6)), bytes(range(20))
    table = pack_table((BeaconFilter.pfdoa(0), BeaconFilter.ibeacon(uuid, 1, 2, 50),
                        BeaconFilter.eddystone_uid(ns, inst, 60), BeaconFilter.mac64(bytes(range(8)), 80)))
    table2 = pack_table((BeaconFilter.mac48(bytes(range(6)), 40), BeaconFilter.altbeacon(alt, 70),
                         BeaconFilter.pfdoa(3), BeaconFilter.none()))
    ble = {"pfdoa": adv_pdu(bytes(6), pfdoa_adv_data(7, 0)), "pfdoa3": adv_pdu(bytes(6), pfdoa_adv_data(8, 3)),
           "ibeacon": adv_pdu(bytes(6), ibeacon_adv_data(uuid, 1, 2)),
           "eddystone": adv_pdu(bytes(6), eddystone_uid_adv_data(ns, inst)),
           "altbeacon": adv_pdu(bytes(6), altbeacon_adv_data(alt)), "mac48": adv_pdu(bytes(range(6)), b"\x02\x01\x06")}
    for name, pdu in ble.items():
        put("match", f"ble_{name}", b"\x00" + (table2 if name in ("mac48", "altbeacon", "pfdoa3") else table) + pdu)
    put("match", "154_pfdoa", b"\x01" + table + pfdoa_802154_frame(9, 0, bytes(8)))
    put("match", "154_mac64", b"\x01" + table + mac_frame(b"hi", seq=3, src_addr=bytes(range(8))))
    fsets = [BeaconFilter.ibeacon(uuid, 1, 2, 50).set_message(1, 1), BeaconFilter.mac64(bytes(8), 80).set_message(2, 3),
            BeaconFilter.none().set_message(3, 1), BeaconFilter.pfdoa(2).set_message(4, 9)]  # the last: bad index
    fs = b"\x05"
    for k, m in enumerate(fsets):
        fs += bytes([1 if k % 2 else 0]) + m.pack()
    fs += bytes([3]) + fsets[0].pack()  # damaged
    put("filter_set", "sets", fs)
    put("filter_set", "store_fails", b"\x85" + fs[1:])
    put("anchor", "mixed", bytes([9, 1]) + bytes([0, 1, 0, 200, 37, 5, 4, 1, 0, 190, 38, 5, 5, 8 << 2 | 2]) + sets[:30])
    # Our authenticated beacon (SPEC 9). C: key, parser, then records [tick delta u16, kind,
    # length, bytes]; kind bit 0 = the beacon's own frame for (counter u32, seq u16).
    key = bytes(range(16))

    def own(dt: int, counter: int, seq: int) -> bytes:
        return struct.pack("<HBB", dt, 1, 6) + struct.pack("<IH", counter, seq)

    def raw(dt: int, frame: bytes) -> bytes:
        return struct.pack("<HBB", dt, 0, len(frame)) + frame

    c0 = 432_900_000
    for which, name in ((0, "adv"), (1, "pdu"), (2, "802154")):
        recs = own(0, c0, 1) + own(1, c0, 1) + own(30, c0, 2) + own(60, c0, 1) + own(40000, c0 + 2, 3)
        recs += own(20, c0 - 5, 9) + own(5, c0 + 1000, 0xFFFF) + own(5, c0 + 1000, 0)
        frames = (pfdoa_auth_adv_data(key, c0, 7), pfdoa_auth_pdu(key, c0, 7), pfdoa_auth_802154_frame(key, c0, 7))
        forged = bytearray(frames[which])
        forged[-1] ^= 1
        recs += raw(10, bytes(forged)) + raw(10, frames[which][: len(frames[which]) - 3])
        put("auth", f"beacon_{name}", key + bytes((which,)) + recs)
        put("auth_py", f"beacon_{name}", key + bytes((which,)) + b"\xfe".join(
            (frames[which], bytes(forged), struct.pack("<IH", c0, 7) + auth_tag(key, c0, 7) + b"\x00\x02",
             struct.pack("<IH", c0, 7) + bytes(8) + b"\x01\x02", b"")))
    return out


def recording_seed(path: Path) -> None:
    """A small gateway recording (McapSink): readings with and without a beacon id, an
    odometry increment, timer marks, a pose and the anchor markers. Not among seeds(): the
    file carries the mcap library's and pfdoa's versions, so it is written once and kept."""
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.gateway.transports import OdomLine
    from pfdoa.sinks.mcap import McapSink
    from pfdoa.site import parse_site
    from pfdoa.types import Estimate

    site = parse_site({"radio": {"rssi_at_1m_dbm": -45.0, "path_loss_exponent": 2.0},
                       "anchors": [{"id": i + 1, "x": x, "y": y} for i, (x, y) in enumerate(((0, 0), (0, 4), (4, 4)))]})
    with McapSink(path, site, site_toml="[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.0\n") as sink:
        for k in range(3):
            for a in (1, 2, 3):
                sink.reading(Reading(a, -55.0 - a - k, 0.1 * k, k, 100 * k, 8))
            sink.timer(0.1 * k + 0.05)
        sink.reading(Reading(1, -60.0, 0.35, None), "tag-1")
        sink.odometry(OdomLine(0.3, 0.29, 0.05, 0.0, 0.01))
        sink.write(Estimate(0.3, 1.0, 2.0, 0.5, None, (1, 2, 3), {}, r95=1.2, cov=(0.2, 0.0, 0.2)))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Write the fuzz targets' hand-made seed inputs.")
    ap.add_argument("--out", type=Path, default=OUT, help="corpus folder (default: %(default)s)")
    ap.add_argument("--recording", action="store_true", help="also (re)write the recording target's seed")
    args = ap.parse_args(argv)
    root = args.out
    if args.recording:
        (root / "recording").mkdir(parents=True, exist_ok=True)
        recording_seed(root / "recording" / "run.mcap")
    for target, name, data in seeds():
        d = root / target
        d.mkdir(parents=True, exist_ok=True)
        (d / name).write_bytes(data)


if __name__ == "__main__":
    main()
