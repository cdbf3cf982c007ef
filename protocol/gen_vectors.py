#!/usr/bin/env python3
"""Regenerate the golden vectors in protocol/vectors/ from the Python reference.

    python protocol/gen_vectors.py          # rewrite the JSON files
    python protocol/gen_vectors.py --check  # exit 1 if a committed file differs

The inputs (field values, event scripts, corruptions) are written out below; the expected
outputs come from pfdoa.protocol (codec and reference anchor model). tests/unit/test_protocol_*
re-derive several expected values by hand from SPEC arithmetic, independently of this file.
Schema: protocol/vectors/README.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

try:
    from pfdoa.protocol import (BY_NAME, BeaconFilter, ConfigSet, FilterSet, RssiReport, StreamDecoder,
                                beacons, cobs_encode, crc16, decode_can, decode_frame, defs, encode_can,
                                encode_raw, encode_uart, seal)
    from pfdoa.protocol import auth
    from pfdoa.protocol.anchor_model import AnchorConfig, ema_step_q8, fold_q8
    from pfdoa.protocol.filters import PeerMatch, default_table, match_reception, pack_table, table_hash
    from pfdoa.protocol.peers import anchor_adv_data, anchor_frame, anchor_payload
    from pfdoa.protocol.script import run_script
    from pfdoa.protocol.uart import HOST_TO_ANCHOR
except ImportError as exc:
    raise SystemExit(f"gen_vectors: the pfdoa package is not importable ({exc}); run it with the "
                     "project's .venv/bin/python or after `pip install -e .`") from None

OUT = ROOT / "protocol" / "vectors"
ANCHOR_TYPES = HOST_TO_ANCHOR - defs.TEST_ONLY
V1, V2 = defs.V1_PROTO_VERSION, defs.PROTO_VERSION


def _hexify(fields: dict) -> dict:
    """JSON form of a message's fields: byte arrays as hex."""
    return {k: (v.hex() if isinstance(v, bytes) else v) for k, v in fields.items()}


def _fields(msg) -> dict:
    return _hexify({f.name: getattr(msg, f.name) for f in dataclasses.fields(msg) if getattr(msg, f.name) is not None})


def _msg(name: str, **fields):
    return BY_NAME[name](**{k: (bytes.fromhex(v) if k in ("match", "frame") else v) for k, v in fields.items()})


# ------------------------------------------------------------------------- CRC, COBS

def crc_vectors() -> dict:
    vs = [{"name": "check_value", "data": b"123456789".hex(), "crc": crc16(b"123456789")},
          {"name": "empty", "data": "", "crc": crc16(b"")},
          {"name": "one_zero_byte", "data": "00", "crc": crc16(b"\x00")},
          {"name": "ff_x4", "data": "ffffffff", "crc": crc16(b"\xff" * 4)},
          {"name": "default_config_hash", "data": AnchorConfig().pack().hex(),
           "crc": AnchorConfig().hash},
          {"name": "default_filter_hash", "data": pack_table(default_table()).hex(),
           "crc": table_hash(default_table())}]
    for version in defs.VERSIONS:
        blob = "".join(m[5] for m in sorted(defs.MESSAGES.values())
                       if version in m[6] and m[0] not in defs.TEST_ONLY)
        vs.append({"name": f"defs_hash_v{version}", "data": blob.encode().hex(), "crc": crc16(blob.encode())})
    for key, (_t, _d, _l, extra, _f, definition, _v, _fmt) in defs.MESSAGES.items():
        c = crc16(definition.encode())
        assert (c & 0xFF) ^ (c >> 8) == extra
        vs.append({"name": f"definition_{key}", "data": definition.encode().hex(), "crc": c,
                   "crc_extra": extra})
    return {"description": "CRC-16/CCITT-FALSE over data (hex); crc as integer. "
                           "crc_extra = (crc & 0xFF) ^ (crc >> 8) for definition strings.",
            "vectors": vs}


def cobs_vectors() -> dict:
    nz = lambda n, start=1: bytes((start + i - 1) % 255 + 1 for i in range(n))  # noqa: E731
    cases = [
        ("empty", b""),
        ("one_zero", b"\x00"),
        ("two_zeros", b"\x00\x00"),
        ("zero_at_both_ends", b"\x00\x11\x22\x00"),
        ("inner_zero", b"\x11\x22\x00\x33"),
        ("no_zero", b"\x11\x22\x33\x44"),
        ("trailing_zeros", b"\x11\x00\x00\x00"),
        ("run_253_nonzero", nz(253)),
        ("run_254_nonzero", nz(254)),
        ("run_255_nonzero", nz(255)),
        ("zero_then_254_nonzero", b"\x00" + nz(254)),
        ("run_254_nonzero_then_zero", nz(254) + b"\x00"),
        ("run_253_nonzero_then_zero", nz(253) + b"\x00"),
        ("run_508_nonzero", nz(508, 7)),
        ("run_254_zero_254", nz(254) + b"\x00" + nz(254, 100)),
        ("max_raw_nonzero", nz(defs.MAX_RAW)),
    ]
    vs = [{"name": n, "decoded": d.hex(), "encoded": cobs_encode(d).hex()} for n, d in cases]
    bad = [
        ("code_past_end", "0511 2233"),
        ("code_past_end_last_group", "021103"),
        ("zero_inside", "0211003301"),
        ("empty_block", ""),
    ]
    errors = [{"name": n, "encoded": e.replace(" ", ""), "error": "bad_cobs"} for n, e in bad]
    return {"description": "COBS blocks without the 0x00 delimiter. `vectors`: encode(decoded) "
                           "== encoded and decode(encoded) == decoded. `errors`: decode fails.",
            "vectors": vs, "errors": errors}


# ------------------------------------------------------------------------- messages

_MATCH = bytes.fromhex("f7826da64fa24e988024bc5b71e0893e00010002")
UART_CASES = [  # (name, version, anchor, message, fields)
    ("report_typical", V2, 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=987654, rssi_q8=-15701, raw_dbm=-63, n_readings=3, channel=39, flags=8, beacon=0)),
    ("report_min_values", V2, 0, "RSSI_REPORT",
     dict(seq=0, tick_ms=0, rssi_q8=-32768, raw_dbm=-128, n_readings=1, channel=0, flags=0, beacon=0)),
    ("report_max_values", V2, 126, "RSSI_REPORT",
     dict(seq=65535, tick_ms=0xFFFFFFFF, rssi_q8=32767, raw_dbm=20, n_readings=3, channel=39, flags=63,
          beacon=3)),
    ("report_all_zero_payload", V2, 1, "RSSI_REPORT",
     dict(seq=0, tick_ms=0, rssi_q8=0, raw_dbm=0, n_readings=0, channel=0, flags=0, beacon=0)),
    ("report_zigbee", V2, 17, "RSSI_REPORT",
     dict(seq=300, tick_ms=65536, rssi_q8=-19200, raw_dbm=-75, n_readings=1, channel=26, flags=16 | 8, beacon=1)),
    ("report_no_seq_beacon_2", V2, 5, "RSSI_REPORT",
     dict(seq=7, tick_ms=1000, rssi_q8=-16000, raw_dbm=-62, n_readings=2, channel=38, flags=32 | 8, beacon=2)),
    ("status_boot", V2, 5, "STATUS",
     dict(fw_major=1, fw_minor=0, uptime_s=0, config_hash=AnchorConfig().hash, dropped_events=0,
          rx_errors=0, spikes=0, defs_hash=defs.DEFS_HASH, filter_hash=table_hash(default_table()),
          filter_slots=defs.BEACON_SLOTS)),
    ("status_saturated_counters", V2, 126, "STATUS",
     dict(fw_major=255, fw_minor=255, uptime_s=4294967, config_hash=0xFFFF, dropped_events=65535,
          rx_errors=65535, spikes=65535, defs_hash=defs.DEFS_HASH, filter_hash=0xFFFF, filter_slots=255)),
    ("config_set_defaults_broadcast", V2, 127, "CONFIG_SET",
     dict(token=1, offset_q8=0, alpha_q8=64, spike_db=12, report_mode=0, decimation=1)),
    ("config_set_extremes", V2, 3, "CONFIG_SET",
     dict(token=255, offset_q8=-32768, alpha_q8=256, spike_db=0, report_mode=2, decimation=255)),
    ("config_set_positive_offset", V2, 0, "CONFIG_SET",
     dict(token=0, offset_q8=32767, alpha_q8=1, spike_db=255, report_mode=1, decimation=10)),
    ("config_ack_ok", V2, 5, "CONFIG_ACK", dict(token=7, result=0, config_hash=AnchorConfig().hash)),
    ("config_ack_invalid", V2, 126, "CONFIG_ACK", dict(token=0, result=1, config_hash=0)),
    ("filter_set_ibeacon", V2, 5, "FILTER_SET",
     dict(token=9, index=1, kind=defs.FILTER_IBEACON, period_ms=100, match=_MATCH.hex())),
    ("filter_set_pfdoa_broadcast", V2, 127, "FILTER_SET",
     dict(token=0, index=0, kind=defs.FILTER_PFDOA, period_ms=0, match=bytes(20).hex())),
    ("filter_set_none", V2, 0, "FILTER_SET",
     dict(token=255, index=3, kind=defs.FILTER_NONE, period_ms=0, match=bytes(20).hex())),
    ("filter_ack_ok", V2, 5, "FILTER_ACK", dict(token=9, result=0, index=1, filter_hash=0x1234)),
    ("filter_ack_invalid", V2, 126, "FILTER_ACK", dict(token=1, result=1, index=200, filter_hash=0)),
    ("radio_inject_ble", V2, 5, "RADIO_INJECT",
     dict(seq=42, tick_ms=1000, rssi_dbm=-70, channel=37, lqi=0, radio=0)),
    ("radio_inject_invalid_rssi", V2, 127, "RADIO_INJECT",
     dict(seq=65535, tick_ms=0xFFFFFFFF, rssi_dbm=127, channel=26, lqi=255, radio=1)),
    ("radio_inject_raw_ble_pdu", V2, 5, "RADIO_INJECT_RAW",
     dict(tick_ms=500, rssi_dbm=-66, channel=38, lqi=0, radio=0,
          length=len(beacons.adv_pdu(bytes(range(1, 7)), beacons.pfdoa_adv_data(9, 0))),
          frame=beacons.adv_pdu(bytes(range(1, 7)), beacons.pfdoa_adv_data(9, 0)).ljust(39, b"\x00").hex())),
    # Version 1, as a version-1 anchor sends them: the gateway decodes these; an anchor
    # (version 2 only) rejects them as bad_version.
    ("v1_report_typical", V1, 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=987654, rssi_q8=-15701, raw_dbm=-63, n_readings=3, channel=39, flags=8, beacon=0)),
    ("v1_report_zigbee_all_zero", V1, 1, "RSSI_REPORT",
     dict(seq=0, tick_ms=0, rssi_q8=0, raw_dbm=0, n_readings=0, channel=0, flags=0, beacon=0)),
    ("v1_status_boot", V1, 5, "STATUS",
     dict(fw_major=1, fw_minor=0, uptime_s=0, config_hash=AnchorConfig().hash, dropped_events=0,
          rx_errors=0, spikes=0, defs_hash=defs.V1_DEFS_HASH, filter_hash=0, filter_slots=0)),
    ("v1_config_set", V1, 127, "CONFIG_SET",
     dict(token=1, offset_q8=0, alpha_q8=64, spike_db=12, report_mode=0, decimation=1)),
    ("v1_config_ack", V1, 5, "CONFIG_ACK", dict(token=7, result=0, config_hash=AnchorConfig().hash)),
    ("v1_status_example_of_issue_14", V1, 62, "STATUS",
     dict(fw_major=0, fw_minor=17, uptime_s=371261443, config_hash=4045, dropped_events=6596, rx_errors=6150,
          spikes=4825, defs_hash=7936, filter_hash=0, filter_slots=0)),
]


def uart_vectors() -> dict:
    vs = []
    for name, version, anchor, mname, fields in UART_CASES:
        msg = _msg(mname, **fields)
        raw = encode_raw(msg, anchor, version)
        frame = encode_uart(msg, anchor, version)
        assert decode_frame(frame[:-1]).message == msg  # type: ignore[union-attr]
        vs.append({"name": name, "version": version, "message": mname, "anchor_id": anchor,
                   "type": msg.layout(version).type, "fields": fields, "raw": raw.hex(), "frame": frame.hex()})
    return {"description": "Valid UART frames: version + message + anchor_id + fields -> type, raw (what "
                           "COBS decodes to: the body in version 2, body + crc16 in version 1) and frame "
                           "(the exact wire bytes incl. the 00 delimiter).",
            "vectors": vs}


CAN_CASES = [  # (name, version, anchor, message, fields)
    ("report_typical", V2, 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=None, rssi_q8=-15701, raw_dbm=-63, n_readings=None, channel=None, flags=8, beacon=0)),
    ("report_min_values", V2, 0, "RSSI_REPORT",
     dict(seq=0, tick_ms=None, rssi_q8=-32768, raw_dbm=-128, n_readings=None, channel=None, flags=0, beacon=0)),
    ("report_max_values", V2, 126, "RSSI_REPORT",
     dict(seq=65535, tick_ms=None, rssi_q8=32767, raw_dbm=20, n_readings=None, channel=None, flags=63,
          beacon=3)),
    ("config_set_anchor", V2, 9, "CONFIG_SET",
     dict(token=3, offset_q8=-384, alpha_q8=128, spike_db=6, report_mode=1, decimation=4)),
    ("config_set_broadcast", V2, 127, "CONFIG_SET",
     dict(token=255, offset_q8=32767, alpha_q8=256, spike_db=0, report_mode=2, decimation=255)),
    ("config_ack", V2, 9, "CONFIG_ACK", dict(token=3, result=2, config_hash=0xBEEF)),
    ("status_three_frames", V2, 5, "STATUS",
     dict(fw_major=1, fw_minor=2, uptime_s=3600, config_hash=AnchorConfig().hash, dropped_events=7,
          rx_errors=1, spikes=65535, defs_hash=defs.DEFS_HASH, filter_hash=table_hash(default_table()),
          filter_slots=defs.BEACON_SLOTS)),
    ("status_max", V2, 126, "STATUS",
     dict(fw_major=255, fw_minor=255, uptime_s=0xFFFFFFFF, config_hash=0xFFFF, dropped_events=65535,
          rx_errors=65535, spikes=65535, defs_hash=0xFFFF, filter_hash=0xFFFF, filter_slots=255)),
    ("v1_report_typical", V1, 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=None, rssi_q8=-15701, raw_dbm=-63, n_readings=3, channel=39, flags=8, beacon=0)),
    ("v1_status_two_frames", V1, 5, "STATUS",
     dict(fw_major=1, fw_minor=2, uptime_s=3600, config_hash=AnchorConfig().hash, dropped_events=7,
          rx_errors=1, spikes=65535, defs_hash=defs.V1_DEFS_HASH)),
]


def can_vectors() -> dict:
    vs = []
    for name, version, anchor, mname, fields in CAN_CASES:
        msg = _msg(mname, **fields)
        frames = [{"id": f"{i:03x}", "data": d.hex()} for i, d in encode_can(msg, anchor, version)]
        vs.append({"name": name, "version": version, "message": mname, "anchor_id": anchor,
                   "fields": {k: v for k, v in fields.items() if v is not None}, "frames": frames})
    return {"description": "Valid CAN frames: version + message + anchor_id + fields -> frames (11-bit id "
                           "as 3 hex digits, data hex). STATUS gives STATUS_A, STATUS_B (and STATUS_C in "
                           "version 2); RSSI_REPORT on CAN has no tick_ms (and in version 2 no n_readings "
                           "or channel: fields absent here).",
            "vectors": vs}


# ------------------------------------------------------------------------- invalid input

def _block(ver: int, typ: int, anchor: int, payload: bytes, extra: int | None = None,
           crc_xor: int = 0, framing: int | None = None) -> bytes:
    """A COBS block (no delimiter) with a correct CRC for `extra` (default: the type's
    CRC_EXTRA) in the framing of `framing` (default: `ver`'s), the CRC xor-ed with crc_xor."""
    body = bytes((ver, typ, anchor)) + payload
    if extra is None:
        extra = next((m[3] for m in defs.MESSAGES.values() if m[0] == typ), 0)
    framing = framing if framing is not None else (V1 if ver == V1 else V2)
    if framing == V1:
        c = crc16(body + bytes((extra,))) ^ crc_xor
        return cobs_encode(body + c.to_bytes(2, "little"))
    good = seal(body, extra, V2)
    if not crc_xor:
        return good
    from pfdoa.protocol.uart import trailer, trailer_value
    return good[:-defs.TRAILER_LEN] + trailer(trailer_value(good[-defs.TRAILER_LEN:]) ^ crc_xor)


REPORT = RssiReport(1234, 987654, -15701, -63, 3, 39, 8, 1)
SET = ConfigSet(7, 0, 64, 12, 0, 1)
FSET = FilterSet(3, 1, defs.FILTER_IBEACON, 100, _MATCH)


def uart_invalid_vectors() -> dict:
    rp = REPORT.pack()
    rp1 = RssiReport(1234, 987654, -15701, -63, 3, 39, 8).pack(V1)
    sp = SET.pack()
    good_report = _block(V2, defs.MSG_RSSI_REPORT, 5, rp)
    flipped_marker = bytearray(good_report)
    k = next(k for k in (-3, -2, -1) if flipped_marker[k] != defs.TRAILER_MARKER)  # stays non-zero
    flipped_marker[k] ^= defs.TRAILER_MARKER
    high_bits = bytearray(good_report)
    high_bits[-1] |= 0x04
    cases = [
        ("bad_crc_low_bit", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, rp, crc_xor=0x0001), "bad_crc"),
        ("bad_crc_high_bit", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, rp, crc_xor=0x8000), "bad_crc"),
        ("bad_crc_trailer_marker_cleared", "host", bytes(flipped_marker), "bad_crc"),
        ("bad_crc_trailer_spare_bits_set", "host", bytes(high_bits), "bad_crc"),
        ("bad_crc_payload_bit_flip", "host",
         good_report[:-4] + bytes([good_report[-4] ^ 0x04]) + good_report[-3:], "bad_crc"),
        ("code_byte_flip_of_issue_14", "host", bytes([good_report[0] ^ 0x01]) + good_report[1:], "bad_cobs"),
        ("bad_crc_other_crc_extra", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, rp, extra=0), "bad_crc"),
        ("truncated_three_bytes", "host", bytes.fromhex("818181"), "truncated"),
        ("truncated_header_only", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, b""), "truncated"),
        ("truncated_two_byte_body", "host", seal(bytes((V2, defs.MSG_RSSI_REPORT)), 0), "truncated"),
        ("truncated_payload", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, rp[:-1]), "truncated"),
        ("overlong_66_bytes", "host", bytes([0x42]) * (defs.MAX_ENCODED + 1), "overlong"),
        ("max_encoded_65_bytes_checked_normally", "host",
         _block(V2, defs.MSG_RSSI_REPORT, 5, bytes(range(1, defs.MAX_BODY - 2))), "bad_length"),
        ("bad_cobs_code_past_end", "host", bytes.fromhex("0902050581818181"), "bad_cobs"),
        ("bad_cobs_zero_inside", "host", bytes.fromhex("0302050005818181"), "bad_cobs"),
        ("unknown_type_0x09", "host", _block(V2, 0x09, 5, rp), "unknown_type"),
        ("unknown_type_0x7f", "host", _block(V2, 0x7F, 5, b""), "unknown_type"),
        ("unknown_type_v1_report_in_v2_framing", "host", _block(V2, defs.MSG_V1_RSSI_REPORT, 5, rp1), "unknown_type"),
        ("unknown_type_before_length", "host", _block(V2, 0, 5, rp + rp), "unknown_type"),
        ("bad_version_0", "host", _block(0, defs.MSG_RSSI_REPORT, 5, rp, framing=V2), "bad_version"),
        ("bad_version_3", "host", _block(3, defs.MSG_RSSI_REPORT, 5, rp, framing=V2), "bad_version"),
        ("bad_version_before_crc", "host", _block(3, defs.MSG_RSSI_REPORT, 5, rp, crc_xor=0xFFFF, framing=V2),
         "bad_version"),
        ("bad_length_one_extra_byte", "host", _block(V2, defs.MSG_RSSI_REPORT, 5, rp + b"\x01"), "bad_length"),
        ("bad_length_before_crc", "host", _block(V2, defs.MSG_CONFIG_ACK, 5, rp, crc_xor=1), "bad_length"),
        ("bad_anchor_127_from_anchor", "host", _block(V2, defs.MSG_RSSI_REPORT, 127, rp), "bad_anchor"),
        ("bad_anchor_200", "host", _block(V2, defs.MSG_STATUS, 200, bytes(defs.MSG_STATUS_LEN)), "bad_anchor"),
        ("bad_anchor_128_config_set", "anchor", _block(V2, defs.MSG_CONFIG_SET, 128, sp), "bad_anchor"),
        ("bad_anchor_128_filter_set", "anchor", _block(V2, defs.MSG_FILTER_SET, 128, FSET.pack()), "bad_anchor"),
        ("report_is_unknown_to_an_anchor", "anchor", _block(V2, defs.MSG_RSSI_REPORT, 5, rp), "unknown_type"),
        ("radio_inject_unknown_to_production_anchor", "anchor",
         _block(V2, defs.MSG_RADIO_INJECT, 5, bytes(defs.MSG_RADIO_INJECT_LEN)), "unknown_type"),
        ("radio_inject_raw_unknown_to_production_anchor", "anchor",
         _block(V2, defs.MSG_RADIO_INJECT_RAW, 5, bytes(defs.MSG_RADIO_INJECT_RAW_LEN)), "unknown_type"),
        ("config_set_bad_crc_at_anchor", "anchor", _block(V2, defs.MSG_CONFIG_SET, 5, sp, crc_xor=0x0100), "bad_crc"),
        ("filter_set_bad_length_at_anchor", "anchor", _block(V2, defs.MSG_FILTER_SET, 5, FSET.pack()[:-1]),
         "truncated"),
        # version routing (SPEC 2.3 check 2) and the version-1 checks (SPEC 8.2)
        ("v1_config_set_at_a_v2_anchor", "anchor", _block(V1, defs.MSG_CONFIG_SET, 5, sp), "bad_version"),
        ("v1_bad_crc", "host", _block(V1, defs.MSG_V1_RSSI_REPORT, 5, rp1, crc_xor=0x0001), "bad_crc"),
        ("v1_truncated_four_bytes", "host", cobs_encode(b"\x01\x01\x05\x00"), "truncated"),
        ("v1_unknown_type_v2_report_in_v1_framing", "host", _block(V1, defs.MSG_RSSI_REPORT, 5, rp), "unknown_type"),
        ("v1_bad_length", "host", _block(V1, defs.MSG_V1_RSSI_REPORT, 5, rp1 + b"\x01"), "bad_length"),
        ("v1_bad_anchor", "host", _block(V1, defs.MSG_V1_RSSI_REPORT, 127, rp1), "bad_anchor"),
        ("v1_bad_cobs", "host", bytes.fromhex("0901010501"), "bad_cobs"),
    ]
    vs = []
    for name, receiver, frame, error in cases:
        if receiver == "anchor":
            got = decode_frame(frame, ANCHOR_TYPES, versions=(V2,))
        else:
            got = decode_frame(frame)
        assert got == error, (name, got)
        v1 = len(frame) >= 2 and frame[0] >= 2 and frame[1] == V1  # routed to the version-1 checks
        vs.append({"name": name, "receiver": receiver, "v1_frame": v1, "frame": frame.hex(), "error": error})
    # Whole streams: decoded messages and exact counters.
    good = encode_uart(REPORT, 5)
    good2 = encode_uart(RssiReport(1235, 987700, -15650, -60, 1, 37, 0, 0), 5)
    good_v1 = encode_uart(RssiReport(1236, 987800, -15600, -61, 2, 38, 0), 6, V1)
    bad_crc = _block(V2, defs.MSG_RSSI_REPORT, 5, rp, crc_xor=0x0001) + b"\x00"
    streams = [
        ("garbage_then_frame", bytes.fromhex("ff13370102") + b"\x00" + good),
        ("frame_without_leading_delimiter_after_partial", bytes.fromhex("4142") + good + good2),
        ("bad_crc_frame_does_not_swallow_next", bad_crc + good),
        ("back_to_back_delimiters", b"\x00\x00" + good + b"\x00\x00\x00" + good2),
        ("overlong_then_frame", bytes([0x55]) * 100 + b"\x00" + good),
        ("overlong_without_delimiter_swallows_until_next_zero",
         bytes([0x55]) * 70 + good + good2),
        ("v1_and_v2_anchors_on_one_stream", good + good_v1 + good2 + good_v1),
        ("every_error_once",
         b"".join(bytes.fromhex(v["frame"]) + b"\x00" for v in vs if v["receiver"] == "host"
                  and v["name"] in ("bad_crc_low_bit", "truncated_three_bytes", "overlong_66_bytes",
                                    "bad_cobs_code_past_end", "unknown_type_0x09", "bad_version_3",
                                    "bad_length_one_extra_byte", "bad_anchor_127_from_anchor"))
         + good + b"\x00" + good2),
    ]
    svs = []
    for name, stream in streams:
        dec = StreamDecoder()
        out = dec.feed(stream)
        v1_frames = sum(1 for p in stream.split(b"\x00") if len(p) >= 2 and p[0] >= 2 and p[1] == V1)
        svs.append({"name": name, "receiver": "host", "v1_frames": v1_frames, "stream": stream.hex(),
                    "decoded": [{"anchor_id": d.anchor_id, "message": d.message.NAME,
                                 "fields": _fields(d.message)} for d in out],
                    "counters": dict(dec.counters)})
    return {"description": "Invalid UART frames (bytes between delimiters, hex) with the error the "
                           "SPEC 2.3 checks must name; receiver 'host' (the gateway) knows every type of "
                           "both versions, 'anchor' only version 2 and CONFIG_SET, FILTER_SET; v1_frame: the "
                           "frame is routed to the version-1 checks (a version-2-only receiver says "
                           "bad_version). `streams`: "
                           "byte streams with the messages and the exact StreamDecoder counters they "
                           "produce.",
            "vectors": vs, "streams": svs}


def can_invalid_vectors() -> dict:
    cases = [
        ("report_dlc_6", 0x105, bytes(6), "bad_length"),
        ("report_dlc_0", 0x105, b"", "bad_length"),
        ("config_set_dlc_4", 0x185, bytes(4), "bad_length"),
        ("config_ack_dlc_8", 0x205, bytes(8), "bad_length"),
        ("status_a_dlc_6", 0x285, bytes(6), "bad_length"),
        ("status_b_dlc_2", 0x305, bytes(2), "bad_length"),
        ("status_c_dlc_8", 0x385, bytes(8), "bad_length"),
        ("unknown_can_type_0", 0x005, bytes(8), "unknown_type"),
        ("unknown_can_type_1", 0x085, bytes(8), "unknown_type"),
        ("unknown_can_type_8", 0x405, bytes(8), "unknown_type"),
        ("unknown_can_type_f", 0x7FF, bytes(8), "unknown_type"),
        ("unknown_type_before_dlc", 0x4A0, bytes(3), "unknown_type"),
        ("report_from_anchor_127", 0x17F, bytes(7), "bad_anchor"),
        ("v1_report_from_anchor_127", 0x17F, bytes(8), "bad_anchor"),
        ("status_c_from_anchor_127", 0x3FF, bytes(3), "bad_anchor"),
        ("bad_length_before_anchor", 0x17F, bytes(5), "bad_length"),
    ]
    vs = []
    for name, can_id, data, error in cases:
        assert decode_can(can_id, data) == error, name
        vs.append({"name": name, "id": f"{can_id:03x}", "data": data.hex(), "error": error,
                   "error_v2": decode_can(can_id, data, versions=(V2,))})
    return {"description": "Invalid CAN frames (id 3 hex digits, data hex; DLC = data length) and "
                           "the error they must produce (checks: can_type, DLC, anchor): `error` at a "
                           "gateway (both versions), `error_v2` at a version-2-only receiver.",
            "vectors": vs}


# ------------------------------------------------------------------------- Q format

def qformat_vectors() -> dict:
    folds = [[-60], [-60, -61], [-60, -61, -61], [-60, -60, -61], [-1, -1, 0], [-1, 0, 0],
             [1, 1, 0], [1, 0, 0], [-128, -128, -128], [20, 20, 20], [-128, 20, -1], [0]]
    fv = [{"readings": r, "mean_q8": fold_q8(sum(r), len(r))} for r in folds]
    emas = [  # (ema_q8, mean_q8, alpha_q8): ties and the C-truncation trap
        (-15360, -15488, 1), (-15360, -15488, 3), (0, -1, 128), (0, -3, 128), (0, 1, 128),
        (0, 3, 128), (0, -1, 129), (0, -1, 127), (100, 99, 128), (-15360, -15616, 64),
        (-15360, -10240, 64), (-32768, 5120, 256), (5120, -32768, 256), (5120, -32768, 1),
        (-200, -300, 192), (0, -128, 2), (0, 128, 2),
    ]
    ev = [{"ema_q8": e, "mean_q8": m, "alpha_q8": a, "result": ema_step_q8(e, m, a)}
          for e, m, a in emas]
    return {"description": "fold: mean_q8 = floor((512*sum + n) / (2n)); ema: result = ema_q8 + "
                           "floor((alpha_q8*(mean_q8-ema_q8) + 128) / 256). Floor division is "
                           "towards minus infinity (C '/' truncates: not the same for negatives).",
            "fold": fv, "ema": ev}


# ------------------------------------------------------------------------- anchor scripts

def _cfg_frame(anchor: int, token: int, **kw) -> str:
    return encode_uart(ConfigSet(token, **kw), anchor).hex()


def _cfg_can(anchor: int, token: int, **kw) -> str:
    (can_id, data), = encode_can(ConfigSet(token, **kw), anchor)
    return f"{can_id:03x} {data.hex()}"


def _level(tick: int, seq: int, dbm: int, n: int = 3, channels=(37, 38, 39)) -> list[str]:
    """One BLE beacon event: n readings 1 ms apart on the advertising channels."""
    return [f"R {tick + i} {seq} {dbm} {channels[i]} 0 0" for i in range(n)]


def _script_list(anchor: int):
    """A list of anchor-script vectors and the function that adds one (its `init` over the
    defaults of anchor ``anchor``); :func:`_with_expected` fills in what the model emits."""
    S: list[dict] = []

    def add(name, desc, script, **init):
        base = {"anchor_id": anchor, "transport": "uart", "boot_tick_ms": 0, "fw_major": 1, "fw_minor": 0}
        base.update(init)
        S.append({"name": name, "description": desc, "init": base, "script": script})

    return S, add


def _with_expected(S: list[dict]) -> list[dict]:
    for v in S:
        v["expected"] = run_script(v["init"], v["script"])
    return S


def anchor_scripts() -> list[dict]:
    A = 5
    S, add = _script_list(A)

    add("ble_three_channel_fold", "BLE event closed by its 3rd reading; first event sets RESET.",
        ["P 0", "R 10 1 -60 37 0 0", "R 11 1 -61 38 0 0", "R 12 1 -63 39 0 0"])
    add("ble_close_by_timeout", "Two readings; poll at 19 ms keeps it open, 20 ms closes it "
        "at the poll's tick.", ["P 0", "R 100 2 -70 37 0 0", "R 101 2 -71 38 0 0", "P 119", "P 120"])
    add("ble_close_by_new_seq", "A new seq closes the open event at the new reading's tick.",
        ["R 50 7 -50 37 0 0", "R 51 7 -52 38 0 0", "R 60 8 -55 37 0 0", "P 80"])
    add("ble_seq_wrap_and_tick_wrap", "seq 65535 -> 0; event opened before the u32 tick wrap, "
        "timeout measured across it.",
        ["R 4294967280 65535 -60 37 0 0", "R 4294967290 0 -60 37 0 0", "P 13", "P 14"])
    add("ieee802154_single_reading", "802.15.4 events close right after their one reading; "
        "ZIGBEE flag.", ["R 5 300 -75 15 200 1", "R 6 301 -76 26 180 1", "R 7 301 -74 11 10 1"])
    add("radio_switch_closes_event", "A reading of the other radio closes the open BLE event "
        "first.", ["R 0 9 -60 37 0 0", "R 1 9 -62 20 99 1"])
    add("same_seq_after_close_opens_new_event", "A 4th reading with the seq of a closed event "
        "opens a new event.", _level(0, 3, -60) + ["R 3 3 -61 37 0 0", "P 30"])
    add("ema_sequence_default_alpha", "EMA with alpha 64 over a few levels inside the spike "
        "threshold.", _level(0, 1, -60) + _level(100, 2, -66) + _level(200, 3, -61, 2)
        + ["P 230"] + _level(300, 4, -65, 1) + ["P 330"])
    add("ema_negative_tie_rounding", "alpha_q8 = 1 and 3 with a -0.5 dB mean step: increments "
        "-0.5/256 -> 0 and -1.5/256 -> -1 (half up).",
        [f"U 0 {_cfg_frame(A, 1, alpha_q8=1)}"] + _level(10, 1, -60)
        + _level(20, 2, -60, 2, (37, 38)) + ["R 22 2 -61 39 0 0"]
        + ["R 30 3 -60 37 0 0", "R 31 3 -61 38 0 0", "P 60"]
        + [f"U 70 {_cfg_frame(A, 2, alpha_q8=3)}", "R 80 4 -60 37 0 0", "R 81 4 -61 38 0 0", "P 110"])
    add("spike_rejected", "Level -60; a -80 event is a spike (SPIKE, EMA unchanged, spikes=1); "
        "the next -60 event resets spike_run.",
        ["P 0"] + _level(10, 1, -60) + _level(20, 2, -60) + _level(30, 3, -80) + _level(40, 4, -61)
        + ["P 1000"])
    add("spike_run_reset", "A real level change: 3 spikes, then the 4th outlier re-initialises "
        "(RESET, spikes stays 3) and the EMA follows the new level.",
        ["P 0"] + _level(10, 1, -60) + _level(20, 2, -85) + _level(30, 3, -85) + _level(40, 4, -86)
        + _level(50, 5, -85) + _level(60, 6, -84) + ["P 1000"])
    add("spike_disabled", "spike_db 0 disables rejection: a 40 dB jump is filtered normally.",
        [f"U 0 {_cfg_frame(A, 9, spike_db=0)}"] + _level(10, 1, -40) + _level(20, 2, -80))
    add("spike_threshold_boundary", "alpha 256 (EMA = mean): |mean - ema| == 12 dB exactly is "
        "not a spike, 12 dB + 85/256 is (thirds from the fold), in both directions.",
        [f"U 0 {_cfg_frame(A, 1, alpha_q8=256)}", "R 10 1 -60 37 0 0", "R 11 1 -60 38 0 0",
         "R 12 1 -61 39 0 0", "R 20 2 -72 37 0 0", "R 21 2 -72 38 0 0", "R 22 2 -73 39 0 0"]
        + _level(30, 3, -60) + ["R 40 4 -60 37 0 0", "R 41 4 -60 38 0 0", "R 42 4 -61 39 0 0"]
        + _level(50, 5, -72) + ["R 60 6 -72 37 0 0", "R 61 6 -73 38 0 0", "R 62 6 -73 39 0 0"])
    add("saturation_input", "Readings above +20 dBm clamp to 20 and set SATURATED.",
        ["R 0 1 25 37 0 0", "R 1 1 20 38 0 0", "R 2 1 19 39 0 0", "R 10 2 126 37 0 0", "P 40"])
    add("saturation_output", "Output clamps to i16: ema -128 dBm with offset -1, then +20 dBm "
        "with offset +32767.",
        [f"U 0 {_cfg_frame(A, 1, offset_q8=-1, spike_db=0)}"] + _level(10, 1, -128)
        + [f"U 20 {_cfg_frame(A, 2, offset_q8=32767, alpha_q8=256, spike_db=0)}"] + _level(30, 2, 20)
        + [f"U 40 {_cfg_frame(A, 3, offset_q8=-32768, alpha_q8=256, spike_db=0)}"] + _level(50, 3, 0))
    add("rssi_127_and_bad_readings_dropped", "RSSI 127, a BLE channel 40, an 802.15.4 channel 10 "
        "and radio 2 are dropped, counted, and do not close the open event.",
        ["P 0", "R 10 1 -60 37 0 0", "R 11 2 127 38 0 0", "R 12 3 -61 40 0 0", "R 13 4 -61 10 0 1",
         "R 14 5 -61 37 0 2", "R 15 1 -62 38 0 0", "P 40", "P 1000"])
    add("calibration_offset", "offset_q8 -384 (-1.5 dB): CALIBRATED, output = ema + offset; "
        "status config_hash changes.",
        ["P 0", f"U 5 {_cfg_frame(A, 11, offset_q8=-384)}"] + _level(10, 1, -60) + _level(20, 2, -59)
        + ["P 1000"])
    add("calibration_config_at_boot", "A stored non-default configuration at boot (init.config).",
        ["P 0"] + _level(10, 1, -60), config={"offset_q8": 512, "alpha_q8": 128, "spike_db": 6,
                                              "report_mode": 0, "decimation": 1})
    add("decimation_every_third", "report_mode 1, decimation 3: one report per 3 closed events "
        "with the OR of their flags; a CONFIG_SET clears the counter.",
        [f"U 0 {_cfg_frame(A, 4, report_mode=1, decimation=3)}"]
        + _level(10, 1, -60) + _level(20, 2, -80) + _level(30, 3, -61)
        + _level(40, 4, -62) + _level(50, 5, -60) + _level(60, 6, -59, 1) + ["P 90"]
        + _level(100, 7, -60) + [f"U 110 {_cfg_frame(A, 5, report_mode=1, decimation=2)}"]
        + _level(120, 8, -60) + _level(130, 9, -60))
    add("silent_mode", "report_mode 2: no reports, STATUS continues and counts spikes.",
        ["P 0", f"U 1 {_cfg_frame(A, 6, report_mode=2)}"] + _level(10, 1, -60) + _level(20, 2, -90)
        + ["P 1000", f"U 1001 {_cfg_frame(A, 7)}"] + _level(1010, 3, -61))
    add("status_timing", "STATUS at the first poll, then when tick - last >= 1000; uptime "
        "truncates.", ["P 0", "P 500", "P 999", "P 1000", "P 1999", "P 2500", "P 3499", "P 3500",
                       "P 10999"])
    add("status_timing_late_first_poll_and_wrap", "Boot tick just before the u32 wrap; status "
        "and uptime wrap-safe.", ["P 4294967000", "P 4294967295", "P 703", "P 704", "P 1703", "P 1704"],
        boot_tick_ms=4294966296)
    add("config_set_ok", "Valid CONFIG_SET: ack result 0 with the new hash; STATUS shows it.",
        ["P 0", f"U 10 {_cfg_frame(A, 42, offset_q8=256, alpha_q8=128, spike_db=10, report_mode=0, decimation=1)}",
         "P 1000"])
    add("config_set_invalid", "alpha 0, alpha 257, mode 3, decimation 0: ack result 1 with the "
        "unchanged hash; nothing applied.",
        [f"U 0 {_cfg_frame(A, 1, alpha_q8=0)}", f"U 1 {_cfg_frame(A, 2, alpha_q8=257)}",
         f"U 2 {_cfg_frame(A, 3, report_mode=3)}", f"U 3 {_cfg_frame(A, 4, decimation=0, offset_q8=100)}",
         "P 4"] + _level(10, 1, -60))
    add("config_set_broadcast", "Id 127 reaches every anchor; the ack carries the anchor's own "
        "id.", [f"U 0 {_cfg_frame(127, 77, spike_db=3)}", "P 1"])
    add("config_set_other_anchor_ignored", "A CONFIG_SET for id 6 is ignored and not counted.",
        [f"U 0 {_cfg_frame(6, 1, report_mode=2)}", "P 1"] + _level(10, 1, -60))
    add("config_set_store_failed", "The store fails: applied, ack result 2.",
        [f"U 0 {_cfg_frame(A, 8, offset_q8=-256)}"] + _level(10, 1, -60), store_ok=False)
    good = _cfg_frame(A, 90, spike_db=20)
    rp = REPORT.pack()
    add("rx_errors_counting", "Each rejected host frame counts once in rx_errors (bad CRC, "
        "truncated, overlong, bad COBS, report type unknown to an anchor, bad version, a "
        "version-1 frame, bad length, bad anchor, garbage before the first delimiter); a valid "
        "frame right after a bad one is processed; frames split across U lines reassemble.",
        ["U 0 " + "4142" + good,
         "U 1 " + _block(V2, defs.MSG_CONFIG_SET, A, SET.pack(), crc_xor=1).hex() + "00" + good,
         "U 2 " + seal(bytes((V2, defs.MSG_CONFIG_SET)), 0).hex() + "00",
         "U 3 " + "55" * 70,
         "U 4 " + "55" * 10 + "00" + "0902050581818181" + "00",
         "U 5 " + _block(V2, defs.MSG_RSSI_REPORT, A, rp).hex() + "00",
         "U 6 " + _block(3, defs.MSG_CONFIG_SET, A, SET.pack(), framing=V2).hex() + "00",
         "U 6 " + _block(V1, defs.MSG_CONFIG_SET, A, SET.pack()).hex() + "00",
         "U 7 " + _block(V2, defs.MSG_CONFIG_SET, A, SET.pack() + b"\x01").hex() + "00",
         "U 8 " + _block(V2, defs.MSG_CONFIG_SET, 200, SET.pack()).hex() + "00",
         "U 9 " + good[:10], "U 10 " + good[10:],
         "U 11 000000",
         "P 12"])
    add("can_ble_fold_and_status", "CAN transport: reports without tick, STATUS as STATUS_A + "
        "STATUS_B.", ["P 0"] + _level(10, 1, -60) + ["R 20 2 -61 38 0 0", "P 40", "P 1000"],
        transport="can")
    add("can_config_set", "CAN transport: own and broadcast CONFIG_SET acked over CAN, another "
        "anchor's id filtered out, bad DLC counted in rx_errors.",
        ["C 0 " + _cfg_can(A, 5, offset_q8=-128), "C 1 " + _cfg_can(127, 6, alpha_q8=256),
         "C 2 " + _cfg_can(6, 7, report_mode=2), "C 3 185 0102030405", "C 4 105 0000000000000000",
         "P 5"] + _level(10, 1, -60) + _level(20, 2, -70), transport="can")
    add("can_anchor_config_over_uart", "A CAN-transport anchor answers a CONFIG_SET received on "
        "its UART on the UART; reports and STATUS stay on CAN; UART errors count in rx_errors.",
        [f"U 0 {_cfg_frame(A, 12, offset_q8=256)}", "U 1 0901010501" + "00", "P 2"] + _level(10, 1, -60),
        transport="can")
    add("can_anchor_id_126", "Highest anchor id on CAN.",
        ["P 0"] + _level(10, 1, -60), transport="can", anchor_id=126)
    add("uart_anchor_id_0", "Anchor id 0 on UART (COBS code for a zero id byte).",
        ["P 0"] + _level(10, 65535, -128), anchor_id=0)
    _beacon_scripts(add, A)
    _auth_scripts(add, A)
    return _with_expected(S)


ADV_A = bytes.fromhex("c0ffee000001")        # our beacon's address (on-air order)
TAG_A = bytes.fromhex("a1b2c3d4e5f6")        # some BLE tag
EXT_A = bytes.fromhex("0102030405060708")    # our 802.15.4 beacon's extended address
NODE_A = bytes.fromhex("1122334455667788")   # some 802.15.4 device
UUID = bytes.fromhex("f7826da64fa24e988024bc5b71e0893e")
NAMESPACE, INSTANCE = bytes.fromhex("edd1ebeac04e5defa017"), bytes.fromhex("0b0c0d0e0f10")
ALT_ID = bytes.fromhex("2f234454cf6d4a0fadf2f4911ba9ffa600010002")


def _fset(anchor: int, token: int, index: int, flt: BeaconFilter) -> str:
    return encode_uart(flt.set_message(token, index), anchor).hex()


def _ours(tick: int, seq: int, dbm: int, beacon_id: int = 0, n: int = 3, adv_a: bytes = ADV_A) -> list[str]:
    """One advertising event of our beacon as raw PDUs on the advertising channels."""
    pdu = beacons.adv_pdu(adv_a, beacons.pfdoa_adv_data(seq, beacon_id)).hex()
    return [f"B {tick + i} {dbm} {37 + i} {pdu}" for i in range(n)]


def _adv(tick: int, dbm: int, data: bytes, adv_a: bytes = TAG_A, n: int = 3) -> list[str]:
    """One advertising event of a standard beacon as AdvA + AdvData (`A` lines)."""
    return [f"A {tick + i} {dbm} {37 + i} {adv_a.hex()} {data.hex() or '-'}" for i in range(n)]


def _beacon_scripts(add, A: int) -> None:
    ib = beacons.ibeacon_adv_data(UUID, 1, 2)
    ib_other = beacons.ibeacon_adv_data(UUID, 1, 3)
    ed = beacons.eddystone_uid_adv_data(NAMESPACE, INSTANCE)
    ed_short = beacons.eddystone_uid_adv_data(NAMESPACE, INSTANCE, rfu=False)
    alt = beacons.altbeacon_adv_data(ALT_ID)
    f_ib = BeaconFilter.ibeacon(UUID, 1, 2, period_ms=100)
    add("raw_pdu_default_table", "At first boot entry 0 is our beacon id 0: its advertising PDUs "
        "form events by seq (beacon 0); id 1, another company and a v1 beacon (read as id 0) "
        "as given; STATUS shows the default filter hash.",
        ["P 0"] + _ours(10, 1, -60) + _ours(20, 1, -61, beacon_id=1)
        + [f"B 30 -62 37 {beacons.adv_pdu(ADV_A, beacons.pfdoa_v1_adv_data(2)).hex()}", "P 60"]
        + _ours(70, 3, -59, n=2) + ["P 100", "P 1000"])
    add("ibeacon_events_by_time", "FILTER_SET puts an iBeacon in entry 1 (period 100 ms): its "
        "advertisements form events by time (NO_SEQ, seq = the entry's own count): closed by the "
        "3rd reading, by the period at a poll, or by a reading beyond the period; another minor is "
        "ignored.",
        ["P 0", f"U 1 {_fset(A, 9, 1, f_ib)}"] + _adv(10, -70, ib) + _adv(110, -71, ib, n=2)
        + _adv(150, -80, ib_other) + ["P 209", "P 210"] + _adv(300, -72, ib, n=1) + _adv(399, -73, ib, n=1)
        + _adv(400, -74, ib, n=1) + ["P 520", "P 1000"])
    add("two_of_our_beacons_interleaved", "Two robots: our beacon id 0 (entry 0) and id 7 "
        "(entry 2) advertise interleaved; each entry has its own events and EMA, reports name "
        "the entry.",
        [f"U 0 {_fset(A, 1, 2, BeaconFilter.pfdoa(7))}"]
        + [ln for k in range(3) for pair in zip(_ours(10 + 40 * k, 100 + k, -60 - k),
                                                 _ours(11 + 40 * k, 500 + k, -80 + k, beacon_id=7))
           for ln in pair] + ["P 200", "P 1000"])
    add("eddystone_altbeacon_and_mac48", "Eddystone-UID (with and without its RFU bytes), "
        "AltBeacon and a MAC address in entries 1-3; the MAC entry matches whatever the "
        "advertisement carries; the first matching entry wins.",
        [f"U 0 {_fset(A, 2, 1, BeaconFilter.eddystone_uid(NAMESPACE, INSTANCE, 50))}",
         f"U 0 {_fset(A, 3, 2, BeaconFilter.altbeacon(ALT_ID, 200))}",
         f"U 0 {_fset(A, 4, 3, BeaconFilter.mac48(TAG_A, 1000))}"]
        + _adv(10, -65, ed, adv_a=ADV_A) + _adv(100, -66, ed_short, adv_a=ADV_A, n=1) + ["P 160"]
        + _adv(200, -67, alt, adv_a=ADV_A) + _adv(300, -68, b"\x02\x01\x06", n=2)
        + _adv(400, -69, ed, n=1) + ["P 1300", "P 2000"])
    ours_z = beacons.pfdoa_802154_frame(300, 0, EXT_A).hex()
    node = beacons.mac_frame(b"hello", seq=9, src_addr=NODE_A).hex()
    node_beacon = beacons.mac_frame(b"", frame_type=defs.IEEE802154_FRAME_BEACON, src_addr=NODE_A,
                                    dst_mode=defs.IEEE802154_ADDR_NONE, pan_id_compression=False).hex()
    node_2015 = beacons.mac_frame(b"x", version=defs.IEEE802154_VERSION_2015, seq_suppressed=True,
                                  src_addr=NODE_A).hex()
    add("ieee802154_raw_ours_and_mac64", "Raw 802.15.4 frames: our beacon's data frame (entry 0, "
        "seq from the payload, ZIGBEE), then a MAC64 entry for another node: its data, beacon and "
        "2015-version frames are one-reading events numbered by the anchor (NO_SEQ).",
        [f"Z 5 -75 15 200 {ours_z}", f"U 6 {_fset(A, 5, 1, BeaconFilter.mac64(NODE_A, 10))}",
         f"Z 10 -80 20 100 {node}", f"Z 11 -81 20 100 {node_beacon}", f"Z 12 -82 20 100 {node_2015}",
         f"Z 13 -83 20 100 {beacons.mac_frame(b'', src_addr=EXT_A).hex()}", "P 1000"])
    add("filter_set_invalid_then_replace", "Invalid FILTER_SETs change nothing (index 4, kind 9, "
        "a non-zero unused match byte, period 0 for an iBeacon, a period for our beacon); a valid "
        "one replaces entry 0 while its event is open: the event is dropped and the entry starts "
        "afresh (RESET).",
        _ours(0, 1, -60, n=2)
        + [f"U 3 {encode_uart(FilterSet(1, 4, defs.FILTER_PFDOA, 0, b''), A).hex()}",
           f"U 3 {encode_uart(FilterSet(2, 1, 9, 100, b''), A).hex()}",
           f"U 3 {encode_uart(FilterSet(3, 1, defs.FILTER_PFDOA, 0, bytes((1, 1))), A).hex()}",
           f"U 3 {encode_uart(FilterSet(4, 1, defs.FILTER_IBEACON, 0, f_ib.match), A).hex()}",
           f"U 3 {encode_uart(FilterSet(5, 1, defs.FILTER_PFDOA, 10, bytes((1,))), A).hex()}",
           f"U 4 {_fset(A, 6, 0, BeaconFilter.pfdoa(3))}", "P 30"]
        + _ours(40, 2, -60) + _ours(50, 3, -90, beacon_id=3) + ["P 1000"])
    add("filter_set_broadcast_other_anchor_and_store_failure", "FILTER_SET to 127 applies, to "
        "another anchor is ignored; the store fails: applied, result 2.",
        [f"U 0 {_fset(127, 7, 3, f_ib)}", f"U 1 {_fset(6, 8, 2, f_ib)}", "P 2"] + _adv(10, -60, ib),
        store_ok=False)
    table = [BeaconFilter.pfdoa(4), BeaconFilter(), f_ib, BeaconFilter.mac48(TAG_A, 500)]
    add("filter_table_at_boot", "A stored table at boot (init.filters): our id 4 in entry 0, the "
        "iBeacon in entry 2.", ["P 0"] + _ours(10, 1, -60, beacon_id=4) + _adv(20, -70, ib) + ["P 1000"],
        filters=pack_table(table).hex())
    bad = bytearray(pack_table(table))
    bad[2 * defs.FILTER_ENTRY_LEN + 1] = 0  # the iBeacon entry with period 0: the table is invalid
    add("filter_table_at_boot_invalid", "A stored table with one invalid entry is ignored: the "
        "default table.", ["P 0"] + _ours(10, 1, -60, beacon_id=4) + _ours(20, 2, -61) + ["P 1000"],
        filters=bytes(bad).hex())
    add("matched_readings_dropped_and_others_ignored", "A matched reception with RSSI 127 or a "
        "bad channel is dropped and counted; an unmatched one (another company, a directed or "
        "malformed PDU, a broken AD structure) is ignored and not counted.",
        ["P 0", f"B 1 127 37 {beacons.adv_pdu(ADV_A, beacons.pfdoa_adv_data(1, 0)).hex()}",
         f"B 2 -60 40 {beacons.adv_pdu(ADV_A, beacons.pfdoa_adv_data(1, 0)).hex()}",
         f"B 3 127 37 {beacons.adv_pdu(ADV_A, ib).hex()}",
         f"B 4 -60 37 {beacons.adv_pdu(ADV_A, beacons.pfdoa_adv_data(1, 0), pdu_type=1).hex()}",
         "B 5 -60 37 " + (bytes((2, 0x30)) + beacons.adv_pdu(ADV_A, beacons.pfdoa_adv_data(1, 0))[2:]).hex(),
         f"A 6 -60 37 {ADV_A.hex()} {beacons.pfdoa_adv_data(1, 0)[:-1].hex()}",
         f"A 7 -60 37 {ADV_A.hex()} 0208ffffff50460100",
         f"Z 8 127 15 0 {ours_z}", "P 1000"])
    add("decimation_per_beacon", "report_mode 1, decimation 2, two of our beacons: each entry "
        "counts its own closed events.",
        [f"U 0 {_cfg_frame(A, 4, report_mode=1, decimation=2)}", f"U 0 {_fset(A, 1, 1, BeaconFilter.pfdoa(2))}"]
        + _ours(10, 1, -60) + _ours(20, 1, -70, beacon_id=2) + _ours(30, 2, -61) + _ours(40, 3, -62)
        + _ours(50, 2, -71, beacon_id=2) + ["P 100"])
    add("on_radio_and_raw_share_entry_0", "pfdoa_anchor_on_radio readings are entry 0 with their "
        "seq, like our beacon's raw PDUs.", ["R 0 5 -60 37 0 0"] + _ours(1, 5, -61, n=2)[1:] + ["P 40"])
    add("can_two_beacons", "CAN transport: version-2 reports (7 bytes, with the beacon entry) "
        "and STATUS_A/B/C.",
        ["P 0", f"U 1 {_fset(A, 1, 1, f_ib)}"] + _ours(10, 1, -60) + _adv(20, -70, ib) + ["P 200", "P 1000"],
        transport="can")


def _auth_pdus(tick: int, dbm: int, key: bytes, counter: int, seq: int, n: int = 3) -> list[str]:
    """One advertising event of our authenticated beacon as raw PDUs (SPEC 9.3)."""
    pdu = beacons.pfdoa_auth_pdu(key, counter, seq).hex()
    return [f"B {tick + i} {dbm - i} {37 + i} {pdu}" for i in range(n)]


def _auth_scripts(add, A: int) -> None:
    key, other, c = AUTH_KEY, AUTH_KEY_B, AUTH_COUNTER
    table = [BeaconFilter.pfdoa_auth(key), BeaconFilter(), BeaconFilter(), BeaconFilter()]
    forged = bytearray(beacons.pfdoa_auth_pdu(key, c, 4))
    forged[-1] ^= 0x80
    adv_a = auth.derive(key, c).adv_a
    add("auth_accept_replay_stale_forged", "Our authenticated beacon in entry 0 (stored table): its events "
        "are AUTH_REPORTs (decrypted seq, counter, tag); AUTH_STATUS follows each STATUS. A replay of the "
        "first event 100 ms later (3 receptions), a counter 5 periods old, a damaged tag are rejected and "
        "counted by reason; an 802.15.4 frame is accepted (ZIGBEE).",
        ["P 0"] + _auth_pdus(10, -60, key, c, 1)
        + [f"A {20 + i} -61 {37 + i} {adv_a.hex()} {beacons.pfdoa_auth_adv_data(key, c, 2).hex()}" for i in range(2)]
        + ["P 45"] + _auth_pdus(110, -40, key, c, 1)
        + _auth_pdus(120, -40, key, c - 5, 3, n=1)
        + [f"B 130 -40 37 {bytes(forged).hex()}",
           f"Z 140 -70 15 80 {beacons.pfdoa_auth_802154_frame(key, c, 5).hex()}", "P 1000"],
        filters=pack_table(table).hex())
    add("auth_entry_by_filter_set", "FILTER_SET puts an authenticated beacon in entry 1 (the ack's hash "
        "covers its key check value); our plain beacon stays in entry 0. Another key's advertisement is "
        "claimed by no entry: ignored, not counted. A counter change closes the open event.",
        ["P 0", f"U 1 {_fset(A, 3, 1, BeaconFilter.pfdoa_auth(key))}"] + _ours(10, 7, -55)
        + _auth_pdus(20, -65, other, c, 1) + _auth_pdus(30, -62, key, c, 9, n=2)
        + _auth_pdus(35, -63, key, c + 1, 9, n=2) + ["P 100", "P 1000"])
    add("auth_board_reading_dropped", "With an authenticated beacon in entry 0 a board's own match "
        "(pfdoa_anchor_on_radio) cannot vouch for it: dropped and counted.",
        ["P 0", "R 5 1 -60 37 0 0", "R 6 1 -61 38 0 0"] + _auth_pdus(10, -60, key, c, 1) + ["P 1000"],
        filters=pack_table(table).hex())
    add("auth_can_transport", "CAN transport: an authenticated beacon's events are RSSI_REPORTs (the "
        "anchor verified them; no AUTH_STATUS on CAN).",
        ["P 0"] + _auth_pdus(10, -60, key, c, 1) + _auth_pdus(110, -40, key, c, 2) + ["P 1000"],
        filters=pack_table(table).hex(), transport="can")
    add("auth_decimation", "report_mode 1, decimation 2: the AUTH_REPORT carries the last event's counter "
        "and tag.",
        [f"U 0 {_cfg_frame(A, 4, report_mode=1, decimation=2)}"] + _auth_pdus(10, -60, key, c, 1)
        + _auth_pdus(20, -61, key, c + 1, 2) + ["P 100"],
        filters=pack_table(table).hex())


def anchor_vectors() -> dict:
    return {"description": "Anchor vectors: run `script` (event-script format, README) on an anchor "
                           "initialised from `init`; it must emit exactly `expected`, in order.",
            "vectors": anchor_scripts()}


# ------------------------------------------------------------------------- main

# ------------------------------------------------------------------------- beacons


def _match_vector(name: str, table, kind: str, adv_a: bytes | None, data: bytes, peer: bool = False) -> dict:
    """One "matches" vector: the table, the reception and what matches it (with ``peer``,
    the anchor an ANCHORS entry heard, peer.json's)."""
    m = match_reception(table, kind, data, adv_a)
    found = None if m is None else {"index": m.index, "seq": m.seq}
    if found is not None and peer:
        found["peer"] = m.peer if isinstance(m, PeerMatch) else None
    return {"name": name, "filters": pack_table(table).hex(), "input": kind,
            "adv_a": adv_a.hex() if adv_a is not None else "", "data": data.hex(), "match": found}


def beacon_vectors() -> dict:
    builds = []
    for seq, bid in ((0, 0), (1, 0), (258, 7), (65535, 255), (0x1234, 0x56)):
        adv = beacons.pfdoa_adv_data(seq, bid)
        builds.append({"name": f"ours_seq_{seq}_id_{bid}", "seq": seq, "beacon_id": bid,
                       "adv_a": ADV_A.hex(), "adv_data": adv.hex(), "pdu": beacons.adv_pdu(ADV_A, adv).hex(),
                       "ext_addr": EXT_A.hex(), "pan_id": defs.BEACON_PAN_ID_DEFAULT,
                       "mpdu": beacons.pfdoa_802154_frame(seq, bid, EXT_A).hex()})
    builds.append({"name": "ours_802154_other_pan", "seq": 9, "beacon_id": 1, "adv_a": ADV_A.hex(),
                   "adv_data": beacons.pfdoa_adv_data(9, 1).hex(),
                   "pdu": beacons.adv_pdu(ADV_A, beacons.pfdoa_adv_data(9, 1)).hex(), "ext_addr": NODE_A.hex(),
                   "pan_id": 0x1A2B, "mpdu": beacons.pfdoa_802154_frame(9, 1, NODE_A, 0x1A2B).hex()})
    ib = beacons.ibeacon_adv_data(UUID, 1, 2)
    ed = beacons.eddystone_uid_adv_data(NAMESPACE, INSTANCE)
    alt = beacons.altbeacon_adv_data(ALT_ID)
    full = [BeaconFilter.pfdoa(0), BeaconFilter.ibeacon(UUID, 1, 2, 100),
            BeaconFilter.eddystone_uid(NAMESPACE, INSTANCE, 100), BeaconFilter.altbeacon(ALT_ID, 100)]
    macs = [BeaconFilter.pfdoa(5), BeaconFilter.mac48(TAG_A, 10), BeaconFilter.mac64(NODE_A, 10), BeaconFilter()]
    order = [BeaconFilter.mac48(ADV_A, 10), BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter.pfdoa(0)]
    ours = beacons.pfdoa_adv_data(77, 0)
    auth_t = [BeaconFilter.pfdoa_auth(AUTH_KEY), BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter()]
    auth_mac = [BeaconFilter.pfdoa_auth(AUTH_KEY_B), BeaconFilter.mac48(auth.derive(AUTH_KEY, AUTH_COUNTER).adv_a, 10),
                BeaconFilter(), BeaconFilter()]
    cases = [  # (name, table, input kind, adv_a or None, bytes)
        ("ours_adv", full, "adv", ADV_A, ours),
        ("ours_pdu", full, "pdu", None, beacons.adv_pdu(ADV_A, ours)),
        ("ours_pdu_adv_ind_public", full, "pdu", None, beacons.adv_pdu(ADV_A, ours, defs.BLE_PDU_ADV_IND, False)),
        ("ours_pdu_scan_ind", full, "pdu", None, beacons.adv_pdu(ADV_A, ours, defs.BLE_PDU_ADV_SCAN_IND)),
        ("ours_pdu_scan_rsp", full, "pdu", None, beacons.adv_pdu(ADV_A, ours, defs.BLE_PDU_SCAN_RSP)),
        ("ours_pdu_trailing_bytes_ignored", full, "pdu", None, beacons.adv_pdu(ADV_A, ours) + b"\xaa\xbb"),
        ("ours_pdu_direct_ind_no_adv_data", full, "pdu", None, beacons.adv_pdu(ADV_A, ours, 1)),
        ("ours_pdu_length_past_end", full, "pdu", None, beacons.adv_pdu(ADV_A, ours)[:-1]),
        ("ours_pdu_length_under_6", full, "pdu", None, b"\x42\x05" + ADV_A[:5]),
        ("ours_pdu_length_over_37", full, "pdu", None, b"\x42\x26" + ADV_A + bytes(32)),
        ("ours_pdu_one_byte", full, "pdu", None, b"\x42"),
        ("ours_other_id", full, "adv", ADV_A, beacons.pfdoa_adv_data(77, 1)),
        ("ours_v1_format_is_id_0", full, "adv", ADV_A, beacons.pfdoa_v1_adv_data(78)),
        ("ours_wrong_company", full, "adv", ADV_A, bytes.fromhex("020106") + bytes.fromhex("08fffeff50464d0000")),
        ("ours_wrong_magic", full, "adv", ADV_A, bytes.fromhex("08ffffff50474d0000")),
        ("ours_too_long", full, "adv", ADV_A, bytes.fromhex("09ffffff50464d000000")),
        ("ours_truncated_ad", full, "adv", ADV_A, bytes.fromhex("08ffffff50464d00")),
        ("ours_after_zero_length_ad", full, "adv", ADV_A, bytes.fromhex("0008ffffff50464d0000")),
        ("ours_second_structure", full, "adv", ADV_A, bytes.fromhex("03ff4c00") + ours),
        ("ibeacon", full, "adv", TAG_A, ib),
        ("ibeacon_other_minor", full, "adv", TAG_A, beacons.ibeacon_adv_data(UUID, 1, 3)),
        ("ibeacon_wrong_type_byte", full, "adv", TAG_A, ib[:5] + b"\x03" + ib[6:]),
        ("eddystone_uid", full, "adv", TAG_A, ed),
        ("eddystone_uid_without_rfu", full, "adv", TAG_A, beacons.eddystone_uid_adv_data(NAMESPACE, INSTANCE, rfu=False)),
        ("eddystone_tlm_frame_ignored", full, "adv", TAG_A, ed[:-20] + b"\x20" + ed[-19:]),
        ("altbeacon", full, "adv", TAG_A, alt),
        ("altbeacon_other_company", full, "adv", TAG_A, beacons.altbeacon_adv_data(ALT_ID, company_id=0xFFFF)),
        ("altbeacon_other_id", full, "adv", TAG_A, beacons.altbeacon_adv_data(ALT_ID[:-1] + b"\x03")),
        ("empty_adv_data", full, "adv", TAG_A, b""),
        ("mac48", macs, "adv", TAG_A, b"\x02\x01\x06"),
        ("mac48_pdu_any_data", macs, "pdu", None, beacons.adv_pdu(TAG_A, ib)),
        ("mac48_first_match_wins", order, "pdu", None, beacons.adv_pdu(ADV_A, ours)),
        ("pfdoa_twice_first_wins", [BeaconFilter(), BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter.pfdoa(0)],
         "adv", TAG_A, ours),
        ("ours_802154", full, "802154", None, beacons.pfdoa_802154_frame(300, 0, EXT_A)),
        ("ours_802154_other_id", full, "802154", None, beacons.pfdoa_802154_frame(300, 2, EXT_A)),
        ("ours_802154_v2006_short_source", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(301, 0), version=1, src_mode=defs.IEEE802154_ADDR_SHORT,
                           src_addr=b"\x34\x12")),
        ("ours_802154_no_compression", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(302, 0), pan_id_compression=False, src_pan=0x1234, src_addr=EXT_A)),
        ("ours_802154_2015_seq_suppressed", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(303, 0), version=2, seq_suppressed=True, src_addr=EXT_A)),
        ("ours_802154_2015_both_ext_compressed", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(304, 0), version=2, dst_mode=3, dst_addr=NODE_A, src_addr=EXT_A)),
        ("ours_802154_2015_no_addresses", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(305, 0), version=2, dst_mode=0, src_mode=0)),
        ("ours_802154_secured_unreadable", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(306, 0), security=True, src_addr=EXT_A)),
        ("ours_802154_2015_ie_unreadable", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(307, 0), version=2, ie_present=True, src_addr=EXT_A)),
        ("ours_802154_command_frame", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(308, 0), frame_type=3, src_addr=EXT_A)),
        ("ours_802154_version_3", full, "802154", None, beacons.mac_frame(beacons.pfdoa_payload(309, 0), version=3)),
        ("ours_802154_reserved_address_mode", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(310, 0), src_mode=1)),
        ("ours_802154_truncated_address", full, "802154", None, beacons.pfdoa_802154_frame(311, 0, EXT_A)[:10]),
        ("ours_802154_payload_too_long", full, "802154", None,
         beacons.mac_frame(beacons.pfdoa_payload(312, 0) + b"\x00", src_addr=EXT_A)),
        ("ieee802154_one_byte", full, "802154", None, b"\x41"),
        ("mac64_data_frame", macs, "802154", None, beacons.mac_frame(b"data", src_addr=NODE_A)),
        ("mac64_secured_frame", macs, "802154", None, beacons.mac_frame(b"\x00" * 9, security=True, src_addr=NODE_A)),
        ("mac64_short_source_no_match", macs, "802154", None,
         beacons.mac_frame(b"", src_mode=defs.IEEE802154_ADDR_SHORT, src_addr=NODE_A[:2])),
        ("mac64_other_node", macs, "802154", None, beacons.mac_frame(b"", src_addr=EXT_A)),
        # Our authenticated beacon: a PFDOA_AUTH entry holds a key and is never matched here
        # (the anchor verifies, SPEC 9.4); its rolling address can still be a MAC48 entry's.
        ("auth_entry_never_matches", auth_t, "pdu", None, beacons.pfdoa_auth_pdu(AUTH_KEY, AUTH_COUNTER, 1)),
        ("auth_802154_entry_never_matches", auth_t, "802154", None,
         beacons.pfdoa_auth_802154_frame(AUTH_KEY, AUTH_COUNTER, 1)),
        ("auth_rolling_address_as_mac48", auth_mac, "pdu", None, beacons.pfdoa_auth_pdu(AUTH_KEY, AUTH_COUNTER, 1)),
    ]
    matches = [_match_vector(*c) for c in cases]
    entries = [
        ("none", BeaconFilter(), True), ("pfdoa", BeaconFilter.pfdoa(9), True),
        ("ibeacon", BeaconFilter.ibeacon(UUID, 1, 2, 100), True),
        ("eddystone", BeaconFilter.eddystone_uid(NAMESPACE, INSTANCE, 1), True),
        ("altbeacon", BeaconFilter.altbeacon(ALT_ID, 65535), True),
        ("mac48", BeaconFilter.mac48(TAG_A, 20), True), ("mac64", BeaconFilter.mac64(NODE_A, 20), True),
        ("pfdoa_auth", BeaconFilter.pfdoa_auth(AUTH_KEY), True),
        ("pfdoa_auth_with_period", BeaconFilter(defs.FILTER_PFDOA_AUTH, 4096, AUTH_KEY), False),
        ("pfdoa_auth_byte_16", BeaconFilter(defs.FILTER_PFDOA_AUTH, 0, AUTH_KEY + b"\x01"), False),
        ("kind_9", BeaconFilter(9, 1, b""), False),
        ("none_with_period", BeaconFilter(defs.FILTER_NONE, 1, b""), False),
        ("none_with_match", BeaconFilter(defs.FILTER_NONE, 0, b"\x01"), False),
        ("pfdoa_with_period", BeaconFilter(defs.FILTER_PFDOA, 5, b"\x01"), False),
        ("pfdoa_second_byte", BeaconFilter(defs.FILTER_PFDOA, 0, b"\x01\x01"), False),
        ("ibeacon_period_0", BeaconFilter(defs.FILTER_IBEACON, 0, UUID), False),
        ("eddystone_byte_16", BeaconFilter(defs.FILTER_EDDYSTONE_UID, 5, bytes(16) + b"\x01"), False),
        ("mac48_byte_6", BeaconFilter(defs.FILTER_MAC48, 5, bytes(6) + b"\x01"), False),
        ("mac64_byte_8", BeaconFilter(defs.FILTER_MAC64, 5, bytes(8) + b"\x01"), False),
    ]
    assert all(f.is_valid() == ok for _, f, ok in entries)
    return {"description": "Beacons. `builds`: what our beacon (C and MicroPython) builds for seq and "
                           "beacon_id: AdvData, the ADV_NONCONN_IND PDU from adv_a, and the 802.15.4 frame "
                           "(no FCS) from ext_addr and pan_id. `matches`: an anchor's filter table (stored "
                           "form, hex) and a reception (input adv: adv_a + data as AdvData; pdu: data is "
                           "an advertising PDU; 802154: data is a MAC frame) -> the matching entry and its "
                           "seq (null: none), or null. `entries`: a filter entry (stored form) -> valid.",
            "builds": builds, "matches": matches,
            "entries": [{"name": n, "entry": f.pack().hex(), "valid": ok} for n, f, ok in entries]}


# ------------------------------------------------------------------------- authenticated beacon

AUTH_KEY = bytes.fromhex("000102030405060708090a0b0c0d0e0f")
AUTH_KEY_B = bytes.fromhex("f0e1d2c3b4a5968778695a4b3c2d1e0f")
AUTH_COUNTER = 432_900_000  # floor(Unix time ms / 4096) in mid-2025


def _sha(name: str, data: bytes, repeat: int = 1) -> dict:
    return {"name": name, "data": data.hex(), "repeat": repeat,
            "digest": hashlib.sha256(data * repeat).hexdigest()}


def auth_vectors() -> dict:
    sha = [_sha("empty", b""), _sha("abc", b"abc"),
           _sha("fips_448_bits", b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
           _sha("fips_896_bits", b"abcdefghbcdefghicdefghijdefghijkefghijklfghijklmghijklmnhijklmnoijklmnopjklmnopq"
                                 b"klmnopqrlmnopqrsmnopqrstnopqrstu"),
           _sha("fips_million_a", b"a", 1_000_000)]
    sha += [_sha(f"length_{n}", bytes(range(n))) for n in (55, 56, 63, 64, 65, 119, 120, 128)]
    hm = [("rfc4231_1", b"\x0b" * 20, b"Hi There"), ("rfc4231_2", b"Jefe", b"what do ya want for nothing?"),
          ("rfc4231_3", b"\xaa" * 20, b"\xdd" * 50), ("rfc4231_4", bytes(range(1, 26)), b"\xcd" * 50),
          ("rfc4231_6", b"\xaa" * 131, b"Test Using Larger Than Block-Size Key - Hash Key First"),
          ("rfc4231_7", b"\xaa" * 131, b"This is a test using a larger than block-size key and a larger than "
                                      b"block-size data. The key needs to be hashed before being used by the HMAC "
                                      b"algorithm."),
          ("key_64_bytes", bytes(range(64)), b"x"), ("empty_key", b"", b"")]
    hmacs = [{"name": n, "key": k.hex(), "data": d.hex(), "mac": auth.hmac_sha256(k, d).hex()} for n, k, d in hm]
    derive = []
    for name, key, counter in (("key_a", AUTH_KEY, AUTH_COUNTER), ("key_a_next_period", AUTH_KEY, AUTH_COUNTER + 1),
                               ("key_b", AUTH_KEY_B, AUTH_COUNTER), ("counter_0", AUTH_KEY, 0),
                               ("counter_max", AUTH_KEY_B, 0xFFFFFFFF)):
        ids = auth.derive(key, counter)
        derive.append({"name": name, "key": key.hex(), "counter": counter, "rid": ids.rid.hex(),
                       "adv_a": ids.adv_a.hex(), "ext_addr": ids.ext_addr.hex(), "pad": ids.pad,
                       "key_check": auth.key_check(key).hex()})
    builds = []
    for name, key, counter, seq, pan in (("first", AUTH_KEY, AUTH_COUNTER, 0, defs.BEACON_PAN_ID_DEFAULT),
                                         ("next_seq", AUTH_KEY, AUTH_COUNTER, 1, defs.BEACON_PAN_ID_DEFAULT),
                                         ("seq_max", AUTH_KEY, AUTH_COUNTER + 1, 0xFFFF, defs.BEACON_PAN_ID_DEFAULT),
                                         ("key_b_other_pan", AUTH_KEY_B, AUTH_COUNTER, 0x1234, 0x1A2B)):
        builds.append({"name": name, "key": key.hex(), "counter": counter, "seq": seq, "pan_id": pan,
                       "tag": auth.tag(key, counter, seq).hex(), "payload": auth.payload(key, counter, seq).hex(),
                       "adv_data": beacons.pfdoa_auth_adv_data(key, counter, seq).hex(),
                       "pdu": beacons.pfdoa_auth_pdu(key, counter, seq).hex(),
                       "mpdu": beacons.pfdoa_auth_802154_frame(key, counter, seq, pan).hex()})
    c, p = AUTH_COUNTER, auth.payload
    forged = bytearray(p(AUTH_KEY, c, 9))
    forged[-1] ^= 0x01
    shifted = bytearray(p(AUTH_KEY, c, 9))
    shifted[6] ^= 0x01  # eseq changed, tag left: the decrypted seq is another one
    steps = [  # (tick, payload, comment)
        (0, p(AUTH_KEY, c, 5), "the first one: accepted"),
        (1, p(AUTH_KEY, c, 5), "the same advertising event on another channel"),
        (19, p(AUTH_KEY, c, 5), "still within 20 ms of its first acceptance"),
        (20, p(AUTH_KEY, c, 5), "20 ms later: a replay"),
        (30, p(AUTH_KEY, c, 6), "the next advertisement"),
        (31, p(AUTH_KEY, c, 4), "an older one of the same period"),
        (40, p(AUTH_KEY, c - 1, 60000), "an older period within the window"),
        (50, bytes(forged), "the tag damaged"),
        (51, bytes(shifted), "eseq changed: the tag does not cover that seq"),
        (60, p(AUTH_KEY_B, c, 6), "another beacon's: not this one"),
        (70, p(AUTH_KEY, c, 65535), "65535 is 7 before 6 in serial-number arithmetic: a replay"),
        (71, p(AUTH_KEY, c, 30000), "30000 is after 6"),
        (72, p(AUTH_KEY, c, 62000), "62000 is after 30000"),
        (80, p(AUTH_KEY, c, 3), "3 is after 62000 (wrapped)"),
        (4096 * 10 + 80, p(AUTH_KEY, c + 7, 20), "10 periods on the counter is expected at c + 10: c + 7 is stale"),
        (4096 * 10 + 81, p(AUTH_KEY, c + 8, 21), "c + 8 is the oldest within the window"),
        (4096 * 10 + 82, p(AUTH_KEY, c + 1000, 22), "a counter from the future: only the key makes one"),
        (0xFFFFFFF0, p(AUTH_KEY, c + 1000, 23), "the verifier's u32 tick far on: expected c + 1000 + 1048565"),
        (0xFFFFFFF1, p(AUTH_KEY, c + 1000 + 1048563, 24), "within the window across the tick's range"),
    ]
    v = auth.Verifier(AUTH_KEY)
    out = []
    for tick, payload, comment in steps:
        verdict = v.verify(auth.parse_payload(payload), tick)
        step = {"tick": tick, "payload": payload.hex(), "result": auth.RESULT_NAMES[verdict.result],
                "comment": comment}
        if verdict.result != defs.AUTH_NONE:
            step.update(seq=verdict.seq, counter=verdict.counter)
        out.append(step)
    return {"description": "Our authenticated beacon (SPEC 9). `sha256`: data (hex) repeated `repeat` times "
                           "-> digest (FIPS 180-4). `hmac`: HMAC-SHA-256 (RFC 2104; the rfc4231_* are RFC "
                           "4231's test cases). `derive`: key, counter -> rid, adv_a, ext_addr (on-air order), "
                           "pad and the key check value. `builds`: key, counter, seq -> tag, payload, AdvData, "
                           "the ADV_NONCONN_IND PDU and the 802.15.4 frame (no FCS) on pan_id. `verify`: one "
                           "verifier's state for `key` through the steps in order: each payload at the "
                           "verifier's tick -> result (none, accept, bad_tag, stale, replayed) and, past the "
                           "rolling identifier, the decrypted seq and the counter.",
            "sha256": sha, "hmac": hmacs, "derive": derive, "builds": builds,
            "verify": [{"name": "window", "key": AUTH_KEY.hex(), "steps": out}]}


# ------------------------------------------------------------------------- peer readings

PEER_BLE_A = bytes.fromhex("a00000000005")        # an anchor's BLE address (on-air order)
PEER_EXT_A = bytes.fromhex("a0a1a2a3a4a5a6a7")    # an anchor's 802.15.4 extended address


def _peer_pdu(anchor: int, seq: int) -> str:
    return anchor_frame(defs.RADIO_BLE, bytes((0xB0, 0, 0, 0, 0, anchor)), anchor, seq).hex()


def _peer_mpdu(anchor: int, seq: int) -> str:
    return anchor_frame(defs.RADIO_IEEE802154, bytes(7) + bytes((anchor,)), anchor, seq).hex()


def peer_scripts() -> list[dict]:
    A = 5
    S, add = _script_list(A)

    ble = {"peer_radio": "ble", "peer_address": PEER_BLE_A.hex()}
    z = {"peer_radio": "802154", "peer_address": PEER_EXT_A.hex()}
    anchors = BeaconFilter.anchors(1000)
    add("peer_ble_send_and_hear", "FILTER_SET puts ANCHORS (period 1000 ms) in entry 3: the next poll sends "
        "the anchor's own advertisement (after STATUS), then every 1000 ms with seq + 1; every reception of "
        "anchor 3's advertisement is one report (beacon 128 + 3, n_readings 1, its raw RSSI, its seq), as a PDU "
        "or as AdvA + AdvData; its own id, id 127 and our beacon's advertisement are not peer readings; RSSI 127 "
        "and channel 40 are dropped and counted.",
        ["P 0", f"U 1 {_fset(A, 1, 3, anchors)}", "P 2", "P 999", "P 1001", "P 1002"]
        + [f"B {1010 + i} {-70 - i} {37 + i} {_peer_pdu(3, 40)}" for i in range(3)]
        + [f"A 1020 -66 38 {bytes((0xB0, 0, 0, 0, 0, 4)).hex()} {anchor_adv_data(7, 4).hex()}",
           f"B 1021 -60 37 {_peer_pdu(5, 1)}",
           f"A 1022 -60 37 {TAG_A.hex()} {(anchor_adv_data(1, 3)[:-1] + bytes((127,))).hex()}",
           f"B 1023 127 37 {_peer_pdu(3, 41)}", f"B 1024 -61 40 {_peer_pdu(3, 41)}", "P 2002", "P 2003"],
        **ble)
    add("peer_802154", "IEEE 802.15.4: the advertisement is a data frame from the anchor's extended address "
        "(MAC sequence number = seq & 0xFF); another anchor's frame is one report with ZIGBEE; a frame with "
        "the payload one byte longer is not an advertisement.",
        [f"U 0 {_fset(A, 1, 1, BeaconFilter.anchors(250))}", "P 0", "P 249", "P 250",
         f"Z 300 -82 15 120 {_peer_mpdu(9, 65535)}",
         f"Z 301 -82 15 120 {beacons.mac_frame(anchor_payload(3, 9) + b'x', src_addr=NODE_A).hex()}", "P 500"],
        **z)
    add("peer_calibrated_saturated_silent", "The configured offset applies to peer readings (CALIBRATED), "
        "RSSI above 20 dBm is clamped (SATURATED), report_mode 1 reports every peer reading, report_mode 2 "
        "none; the anchor keeps sending its advertisement.",
        ["P 0", f"U 1 {_cfg_frame(A, 2, offset_q8=-384, report_mode=1, decimation=3)}",
         f"U 2 {_fset(A, 3, 2, anchors)}", f"B 10 -70 37 {_peer_pdu(8, 2)}", f"B 11 25 38 {_peer_pdu(8, 2)}",
         f"U 20 {_cfg_frame(A, 4, report_mode=2)}", f"B 30 -70 37 {_peer_pdu(8, 3)}", "P 1000", "P 1010"],
        **ble)
    add("peer_can", "CAN: a peer report is a 7-byte report frame whose beacon is 128 + the peer's id.",
        ["P 0", f"U 1 {_fset(A, 1, 1, anchors)}", f"B 10 -72 39 {_peer_pdu(126, 9)}", "P 20"],
        transport="can", **ble)
    table = [BeaconFilter.pfdoa(0), BeaconFilter.anchors(500), BeaconFilter(), BeaconFilter()]
    add("peer_table_at_boot_without_radio", "A stored table with ANCHORS at boot and no radio to send on: "
        "the anchor hears its peers but sends nothing; our beacon still goes to entry 0.",
        ["P 0", f"B 10 -70 37 {_peer_pdu(2, 5)}"] + _ours(20, 1, -60) + ["P 600", "P 1000"],
        filters=pack_table(table).hex())
    add("peer_schedule_restarts_and_wraps", "Booted at tick 2^32 - 1000 with the table stored: the first poll "
        "sends; any applied FILTER_SET makes the next poll send again (seq goes on); the period is measured "
        "across the tick's wrap; an invalid FILTER_SET changes nothing; MAC48 before ANCHORS wins.",
        ["P 4294966296", "P 4294966795", "P 4294966796", f"U 4294966900 {_fset(A, 1, 0, BeaconFilter.pfdoa(1))}",
         "P 4294966901", "P 104", "P 105", f"U 106 {encode_uart(FilterSet(2, 3, defs.FILTER_ANCHORS, 0, b''), A).hex()}",
         "P 107", "P 605", f"U 606 {_fset(A, 3, 0, BeaconFilter.mac48(bytes((0xB0, 0, 0, 0, 0, 3)), 10))}",
         f"B 607 -70 37 {_peer_pdu(3, 1)}", f"B 608 -70 37 {_peer_pdu(4, 1)}", "P 700"],
        boot_tick_ms=4294966296, filters=pack_table(table).hex(), **ble)
    key, c = AUTH_KEY, AUTH_COUNTER
    forged = bytearray(beacons.pfdoa_auth_pdu(key, c, 2))
    forged[-1] ^= 0x01
    short_pa = bytes((defs.BEACON_MAGIC0, defs.AUTH_MAGIC1)) + anchor_payload(3, 3)[2:]  # 'P' 'A', the peer's length
    both = [BeaconFilter.pfdoa_auth(key), BeaconFilter(), BeaconFilter(), BeaconFilter.anchors(1000)]
    add("peer_and_auth_in_one_table", "Our authenticated beacon in entry 0 and ANCHORS in entry 3 (stored "
        "table): the poll sends STATUS, AUTH_STATUS and the anchor's own advertisement; the beacon's event "
        "is verified and reported (AUTH_REPORT), anchor 3's advertisement is a peer reading (beacon 131); "
        "a payload 'P' 'A' of the peer advertisement's length is neither (ignored), a damaged tag is "
        "rejected and counted in the next AUTH_STATUS.",
        ["P 0"] + _auth_pdus(10, -60, key, c, 1) + [f"B 20 -70 37 {_peer_pdu(3, 7)}",
         f"A 25 -70 37 {TAG_A.hex()} {(bytes.fromhex('08ffffff') + short_pa).hex()}",
         f"B 30 -60 37 {bytes(forged).hex()}", "P 1000"],
        filters=pack_table(both).hex(), **ble)
    return _with_expected(S)


def peer_vectors() -> dict:
    builds = []
    for radio, address in ((defs.RADIO_BLE, PEER_BLE_A), (defs.RADIO_IEEE802154, PEER_EXT_A)):
        for anchor, seq in ((0, 0), (5, 1), (17, 258), (126, 65535)):
            builds.append({"name": f"{'ble' if radio == defs.RADIO_BLE else '802154'}_anchor_{anchor}_seq_{seq}",
                           "radio": radio, "address": address.hex(), "anchor_id": anchor, "seq": seq,
                           "frame": anchor_frame(radio, address, anchor, seq).hex()})
    anchors = BeaconFilter.anchors(1000)
    peers = [BeaconFilter.pfdoa(0), BeaconFilter.ibeacon(UUID, 1, 2, 100), BeaconFilter(), anchors]
    first = [anchors, BeaconFilter.mac48(TAG_A, 10), BeaconFilter(), BeaconFilter()]
    no_peers = [BeaconFilter.pfdoa(0), BeaconFilter(), BeaconFilter(), BeaconFilter()]
    adv = anchor_adv_data(300, 3)
    cases = [  # (name, table, input kind, adv_a or None, bytes)
        ("anchor_adv", peers, "adv", TAG_A, adv),
        ("anchor_pdu", peers, "pdu", None, beacons.adv_pdu(TAG_A, adv)),
        ("anchor_802154", peers, "802154", None, bytes.fromhex(_peer_mpdu(12, 513))),
        ("anchor_id_126", peers, "adv", TAG_A, anchor_adv_data(1, 126)),
        ("anchor_id_127_no_anchor", peers, "adv", TAG_A, adv[:-1] + bytes((127,))),
        ("anchor_802154_id_200_no_anchor", peers, "802154", None,
         beacons.mac_frame(anchor_payload(4, 0)[:-1] + bytes((200,)), src_addr=NODE_A)),
        ("anchor_ad_too_long", peers, "adv", TAG_A, bytes.fromhex("09ffffff") + anchor_payload(300, 3) + b"\x00"),
        ("anchor_wrong_company", peers, "adv", TAG_A, bytes.fromhex("08fffeff") + anchor_payload(300, 3)),
        ("anchor_802154_payload_too_long", peers, "802154", None,
         beacons.mac_frame(anchor_payload(4, 3) + b"\x00", src_addr=NODE_A)),
        ("anchor_802154_secured_unreadable", peers, "802154", None,
         beacons.mac_frame(anchor_payload(4, 3), security=True, src_addr=NODE_A)),
        ("our_beacon_not_a_peer", [anchors] + no_peers[1:], "adv", TAG_A, beacons.pfdoa_adv_data(1, 0)),
        ("our_beacon_beside_peers", peers, "adv", TAG_A, beacons.pfdoa_adv_data(1, 0)),
        ("no_anchors_entry", no_peers, "adv", TAG_A, adv),
        ("anchors_entry_first_wins", first, "adv", TAG_A, adv),
        ("mac48_first_wins", [BeaconFilter.mac48(TAG_A, 10), anchors, BeaconFilter(), BeaconFilter()], "adv",
         TAG_A, adv),
        ("anchor_after_other_structures", peers, "adv", TAG_A, bytes.fromhex("03ff4c00") + adv),
    ]
    matches = [_match_vector(*c, peer=True) for c in cases]
    entries = [("anchors", anchors, True), ("anchors_period_1", BeaconFilter.anchors(1), True),
               ("anchors_period_65535", BeaconFilter.anchors(65535), True),
               ("anchors_period_0", BeaconFilter(defs.FILTER_ANCHORS, 0, b""), False),
               ("anchors_with_match", BeaconFilter(defs.FILTER_ANCHORS, 100, b"\x01"), False)]
    assert all(f.is_valid() == ok for _, f, ok in entries)
    return {"description": "Peer readings (SPEC 3.5, 6.1). `builds`: the anchor's own advertisement for "
                           "radio (0 BLE: an ADV_NONCONN_IND PDU from address as AdvA; 1 IEEE 802.15.4: a data "
                           "frame, no FCS, from address as extended source), anchor_id and seq -> frame. "
                           "`matches`: as in beacon.json, a match of an ANCHORS entry also names the anchor "
                           "heard (`peer`; null for other matches). `entries`: an ANCHORS entry (stored form) "
                           "-> valid. `vectors`: anchor scripts as in anchor.json; `init` may give the radio "
                           "the anchor sends its advertisement on (`peer_radio` \"ble\" or \"802154\", "
                           "`peer_address` hex), and `T <hex>` lines of `expected` are what it sent.",
            "builds": builds, "matches": matches,
            "entries": [{"name": n, "entry": f.pack().hex(), "valid": ok} for n, f, ok in entries],
            "vectors": peer_scripts()}


def build() -> dict[str, dict]:
    return {"crc.json": crc_vectors(), "cobs.json": cobs_vectors(), "uart.json": uart_vectors(),
            "can.json": can_vectors(), "uart_invalid.json": uart_invalid_vectors(),
            "can_invalid.json": can_invalid_vectors(), "qformat.json": qformat_vectors(),
            "anchor.json": anchor_vectors(), "beacon.json": beacon_vectors(), "auth.json": auth_vectors(),
            "peer.json": peer_vectors()}


def render(doc: dict) -> str:
    return json.dumps(doc, indent=1) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args(argv)
    stale = []
    for fname, doc in build().items():
        path = OUT / fname
        text = render(doc)
        if path.exists() and path.read_text() == text:
            continue
        if args.check:
            stale.append(fname)
        else:
            path.write_text(text)
            print(f"wrote protocol/vectors/{fname}")
    if stale:
        print("stale vectors (run python protocol/gen_vectors.py): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
