#!/usr/bin/env python3
"""Regenerate the golden vectors in protocol/vectors/ from the Python reference.

    python protocol/gen_vectors.py          # rewrite the JSON files
    python protocol/gen_vectors.py --check  # exit 1 if a committed file differs

The inputs (field values, event scripts, corruptions) are written out below; the expected
outputs come from pfdoa.protocol (codec and reference anchor model). tests/test_protocol_*
re-derive several expected values by hand from SPEC arithmetic, independently of this file.
Schema: protocol/vectors/README.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

try:
    from pfdoa.protocol import (BY_NAME, ConfigSet, RssiReport, StreamDecoder, cobs_encode, crc16,
                                decode_can, decode_frame, defs, encode_can, encode_raw, encode_uart)
    from pfdoa.protocol.anchor_model import AnchorConfig, ema_step_q8, fold_q8
    from pfdoa.protocol.script import run_script
    from pfdoa.protocol.uart import HOST_TO_ANCHOR
except ImportError as exc:
    raise SystemExit(f"gen_vectors: the pfdoa package is not importable ({exc}); run it with the "
                     "project's .venv/bin/python or after `pip install -e .`") from None

OUT = ROOT / "protocol" / "vectors"
ANCHOR_TYPES = HOST_TO_ANCHOR - {defs.MSG_RADIO_INJECT}


def _fields(msg) -> dict:
    return {f: getattr(msg, f) for f in msg.__slots__ if getattr(msg, f) is not None}


def _msg(name: str, **fields):
    return BY_NAME[name](**fields)


# ------------------------------------------------------------------------- CRC, COBS

def crc_vectors() -> dict:
    vs = [{"name": "check_value", "data": b"123456789".hex(), "crc": crc16(b"123456789")},
          {"name": "empty", "data": "", "crc": crc16(b"")},
          {"name": "one_zero_byte", "data": "00", "crc": crc16(b"\x00")},
          {"name": "ff_x4", "data": "ffffffff", "crc": crc16(b"\xff" * 4)},
          {"name": "default_config_hash", "data": AnchorConfig().pack().hex(),
           "crc": AnchorConfig().hash}]
    defs_blob = "".join(m[5] for m in sorted(defs.MESSAGES.values()) if 1 <= m[0] <= 4)
    vs.append({"name": "defs_hash", "data": defs_blob.encode().hex(), "crc": crc16(defs_blob.encode())})
    for name, (_t, _d, _l, extra, _f, definition) in defs.MESSAGES.items():
        c = crc16(definition.encode())
        assert (c & 0xFF) ^ (c >> 8) == extra
        vs.append({"name": f"definition_{name}", "data": definition.encode().hex(), "crc": c,
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

UART_CASES = [
    ("report_typical", 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=987654, rssi_q8=-15701, raw_dbm=-63, n_readings=3, channel=39, flags=8)),
    ("report_min_values", 0, "RSSI_REPORT",
     dict(seq=0, tick_ms=0, rssi_q8=-32768, raw_dbm=-128, n_readings=1, channel=0, flags=0)),
    ("report_max_values", 126, "RSSI_REPORT",
     dict(seq=65535, tick_ms=0xFFFFFFFF, rssi_q8=32767, raw_dbm=20, n_readings=3, channel=39, flags=31)),
    ("report_zigbee_all_zero_payload", 1, "RSSI_REPORT",
     dict(seq=0, tick_ms=0, rssi_q8=0, raw_dbm=0, n_readings=0, channel=0, flags=0)),
    ("report_zigbee", 17, "RSSI_REPORT",
     dict(seq=300, tick_ms=65536, rssi_q8=-19200, raw_dbm=-75, n_readings=1, channel=26, flags=16 | 8)),
    ("status_boot", 5, "STATUS",
     dict(fw_major=1, fw_minor=0, uptime_s=0, config_hash=AnchorConfig().hash, dropped_events=0,
          rx_errors=0, spikes=0, defs_hash=defs.DEFS_HASH)),
    ("status_saturated_counters", 126, "STATUS",
     dict(fw_major=255, fw_minor=255, uptime_s=4294967, config_hash=0xFFFF, dropped_events=65535,
          rx_errors=65535, spikes=65535, defs_hash=defs.DEFS_HASH)),
    ("config_set_defaults_broadcast", 127, "CONFIG_SET",
     dict(token=1, offset_q8=0, alpha_q8=64, spike_db=12, report_mode=0, decimation=1)),
    ("config_set_extremes", 3, "CONFIG_SET",
     dict(token=255, offset_q8=-32768, alpha_q8=256, spike_db=0, report_mode=2, decimation=255)),
    ("config_set_positive_offset", 0, "CONFIG_SET",
     dict(token=0, offset_q8=32767, alpha_q8=1, spike_db=255, report_mode=1, decimation=10)),
    ("config_ack_ok", 5, "CONFIG_ACK", dict(token=7, result=0, config_hash=AnchorConfig().hash)),
    ("config_ack_invalid", 126, "CONFIG_ACK", dict(token=0, result=1, config_hash=0)),
    ("radio_inject_ble", 5, "RADIO_INJECT",
     dict(seq=42, tick_ms=1000, rssi_dbm=-70, channel=37, lqi=0, radio=0)),
    ("radio_inject_invalid_rssi", 127, "RADIO_INJECT",
     dict(seq=65535, tick_ms=0xFFFFFFFF, rssi_dbm=127, channel=26, lqi=255, radio=1)),
]


def uart_vectors() -> dict:
    vs = []
    for name, anchor, mname, fields in UART_CASES:
        msg = _msg(mname, **fields)
        raw = encode_raw(msg, anchor)
        frame = encode_uart(msg, anchor)
        assert decode_frame(frame[:-1]).message == msg  # type: ignore[union-attr]
        vs.append({"name": name, "message": mname, "anchor_id": anchor, "fields": fields,
                   "raw": raw.hex(), "frame": frame.hex()})
    return {"description": "Valid UART frames: message + anchor_id + fields -> raw (decoded frame, "
                           "CRC included) and frame (COBS + 00 delimiter, the exact wire bytes).",
            "vectors": vs}


CAN_CASES = [
    ("report_typical", 5, "RSSI_REPORT",
     dict(seq=1234, tick_ms=None, rssi_q8=-15701, raw_dbm=-63, n_readings=3, channel=39, flags=8)),
    ("report_min_values", 0, "RSSI_REPORT",
     dict(seq=0, tick_ms=None, rssi_q8=-32768, raw_dbm=-128, n_readings=1, channel=0, flags=0)),
    ("report_max_values", 126, "RSSI_REPORT",
     dict(seq=65535, tick_ms=None, rssi_q8=32767, raw_dbm=20, n_readings=3, channel=39, flags=31)),
    ("config_set_anchor", 9, "CONFIG_SET",
     dict(token=3, offset_q8=-384, alpha_q8=128, spike_db=6, report_mode=1, decimation=4)),
    ("config_set_broadcast", 127, "CONFIG_SET",
     dict(token=255, offset_q8=32767, alpha_q8=256, spike_db=0, report_mode=2, decimation=255)),
    ("config_ack", 9, "CONFIG_ACK", dict(token=3, result=2, config_hash=0xBEEF)),
    ("status_two_frames", 5, "STATUS",
     dict(fw_major=1, fw_minor=2, uptime_s=3600, config_hash=AnchorConfig().hash, dropped_events=7,
          rx_errors=1, spikes=65535, defs_hash=defs.DEFS_HASH)),
    ("status_max", 126, "STATUS",
     dict(fw_major=255, fw_minor=255, uptime_s=0xFFFFFFFF, config_hash=0xFFFF, dropped_events=65535,
          rx_errors=65535, spikes=65535, defs_hash=0xFFFF)),
]


def can_vectors() -> dict:
    vs = []
    for name, anchor, mname, fields in CAN_CASES:
        msg = _msg(mname, **fields)
        frames = [{"id": f"{i:03x}", "data": d.hex()} for i, d in encode_can(msg, anchor)]
        vs.append({"name": name, "message": mname, "anchor_id": anchor,
                   "fields": {k: v for k, v in fields.items() if v is not None}, "frames": frames})
    return {"description": "Valid CAN frames: message + anchor_id + fields -> frames (11-bit id as "
                           "3 hex digits, data hex). STATUS gives STATUS_A then STATUS_B; "
                           "RSSI_REPORT on CAN has no tick_ms.",
            "vectors": vs}


# ------------------------------------------------------------------------- invalid input

def _raw(ver: int, typ: int, anchor: int, payload: bytes, extra: int | None = None,
         crc_xor: int = 0) -> bytes:
    """A decoded frame with a correct CRC for `extra` (default: the type's CRC_EXTRA)."""
    body = bytes((ver, typ, anchor)) + payload
    if extra is None:
        extra = next((m[3] for m in defs.MESSAGES.values() if m[0] == typ), 0)
    c = crc16(body + bytes((extra,))) ^ crc_xor
    return body + c.to_bytes(2, "little")


REPORT = RssiReport(1234, 987654, -15701, -63, 3, 39, 8)
SET = ConfigSet(7, 0, 64, 12, 0, 1)


def uart_invalid_vectors() -> dict:
    rp = REPORT.pack()
    sp = SET.pack()
    cases = [
        ("bad_crc_low_byte", "host", cobs_encode(_raw(1, 1, 5, rp, crc_xor=0x0001)), "bad_crc"),
        ("bad_crc_high_byte", "host", cobs_encode(_raw(1, 1, 5, rp, crc_xor=0x8000)), "bad_crc"),
        ("bad_crc_payload_bit_flip", "host",
         cobs_encode(bytearray(_raw(1, 1, 5, rp))[:4] + bytes([_raw(1, 1, 5, rp)[4] ^ 0x04])
                     + _raw(1, 1, 5, rp)[5:]), "bad_crc"),
        ("bad_crc_other_crc_extra", "host", cobs_encode(_raw(1, 1, 5, rp, extra=0)), "bad_crc"),
        ("truncated_header_only", "host", cobs_encode(b"\x01\x01\x05"), "truncated"),
        ("truncated_four_bytes", "host", cobs_encode(b"\x01\x01\x05\x00"), "truncated"),
        ("truncated_payload", "host", cobs_encode(_raw(1, 1, 5, rp[:-1])), "truncated"),
        ("truncated_before_version_check", "host", cobs_encode(b"\x02\x01\x05\x00"), "truncated"),
        ("overlong_66_bytes", "host", bytes([0x42]) * (defs.MAX_ENCODED + 1), "overlong"),
        ("max_encoded_65_bytes_checked_normally", "host",
         cobs_encode(_raw(1, 1, 5, bytes(range(1, defs.MAX_RAW - 4)))), "bad_length"),
        ("bad_cobs_code_past_end", "host", bytes.fromhex("0901010501"), "bad_cobs"),
        ("bad_cobs_zero_inside", "host", bytes.fromhex("0301010005"), "bad_cobs"),
        ("unknown_type_0x05", "host", cobs_encode(_raw(1, 5, 5, rp)), "unknown_type"),
        ("unknown_type_0x7f", "host", cobs_encode(_raw(1, 0x7F, 5, b"")), "unknown_type"),
        ("unknown_type_before_length", "host", cobs_encode(_raw(1, 0, 5, rp + rp)), "unknown_type"),
        ("bad_version_0", "host", cobs_encode(_raw(0, 1, 5, rp)), "bad_version"),
        ("bad_version_2", "host", cobs_encode(_raw(2, 1, 5, rp)), "bad_version"),
        ("bad_version_before_crc", "host", cobs_encode(_raw(2, 1, 5, rp, crc_xor=0xFFFF)), "bad_version"),
        ("bad_length_one_extra_byte", "host", cobs_encode(_raw(1, 1, 5, rp + b"\x01")), "bad_length"),
        ("bad_length_before_crc", "host", cobs_encode(_raw(1, 4, 5, rp, crc_xor=1)), "bad_length"),
        ("bad_anchor_127_from_anchor", "host", cobs_encode(_raw(1, 1, 127, rp)), "bad_anchor"),
        ("bad_anchor_200", "host", cobs_encode(_raw(1, 2, 200, bytes(16))), "bad_anchor"),
        ("bad_anchor_128_config_set", "anchor", cobs_encode(_raw(1, 3, 128, sp)), "bad_anchor"),
        ("report_is_unknown_to_an_anchor", "anchor", cobs_encode(_raw(1, 1, 5, rp)), "unknown_type"),
        ("radio_inject_unknown_to_production_anchor", "anchor",
         cobs_encode(_raw(1, 0x7E, 5, bytes(10))), "unknown_type"),
        ("config_set_bad_crc_at_anchor", "anchor", cobs_encode(_raw(1, 3, 5, sp, crc_xor=0x0100)), "bad_crc"),
    ]
    vs = []
    for name, receiver, frame, error in cases:
        types = ANCHOR_TYPES if receiver == "anchor" else None
        got = decode_frame(frame, types)
        assert got == error, (name, got)
        vs.append({"name": name, "receiver": receiver, "frame": frame.hex(), "error": error})
    # Whole streams: decoded messages and exact counters.
    good = encode_uart(REPORT, 5)
    good2 = encode_uart(RssiReport(1235, 987700, -15650, -60, 1, 37, 0), 5)
    bad_crc = cobs_encode(_raw(1, 1, 5, rp, crc_xor=0x0001)) + b"\x00"
    streams = [
        ("garbage_then_frame", bytes.fromhex("ff13370102") + b"\x00" + good),
        ("frame_without_leading_delimiter_after_partial", bytes.fromhex("4142") + good + good2),
        ("bad_crc_frame_does_not_swallow_next", bad_crc + good),
        ("back_to_back_delimiters", b"\x00\x00" + good + b"\x00\x00\x00" + good2),
        ("overlong_then_frame", bytes([0x55]) * 100 + b"\x00" + good),
        ("overlong_without_delimiter_swallows_until_next_zero",
         bytes([0x55]) * 70 + good + good2),
        ("every_error_once",
         b"".join(bytes.fromhex(v["frame"]) + b"\x00" for v in vs if v["receiver"] == "host"
                  and v["name"] in ("bad_crc_low_byte", "truncated_four_bytes", "overlong_66_bytes",
                                    "bad_cobs_code_past_end", "unknown_type_0x05", "bad_version_2",
                                    "bad_length_one_extra_byte", "bad_anchor_127_from_anchor"))
         + good + b"\x00" + good2),
    ]
    svs = []
    for name, stream in streams:
        dec = StreamDecoder()
        out = dec.feed(stream)
        svs.append({"name": name, "receiver": "host", "stream": stream.hex(),
                    "decoded": [{"anchor_id": d.anchor_id, "message": d.message.NAME,
                                 "fields": _fields(d.message)} for d in out],
                    "counters": dict(dec.counters)})
    return {"description": "Invalid UART frames (bytes between delimiters, hex) with the error the "
                           "SPEC 2.3 checks must name; receiver 'host' knows every v1 type, 'anchor' "
                           "only CONFIG_SET. `streams`: byte streams with the messages and the exact "
                           "StreamDecoder counters they produce.",
            "vectors": vs, "streams": svs}


def can_invalid_vectors() -> dict:
    cases = [
        ("report_dlc_7", 0x105, bytes(7), "bad_length"),
        ("report_dlc_0", 0x105, b"", "bad_length"),
        ("config_set_dlc_4", 0x185, bytes(4), "bad_length"),
        ("config_ack_dlc_8", 0x205, bytes(8), "bad_length"),
        ("status_a_dlc_6", 0x285, bytes(6), "bad_length"),
        ("status_b_dlc_2", 0x305, bytes(2), "bad_length"),
        ("unknown_can_type_0", 0x005, bytes(8), "unknown_type"),
        ("unknown_can_type_1", 0x085, bytes(8), "unknown_type"),
        ("unknown_can_type_7", 0x385, bytes(8), "unknown_type"),
        ("unknown_can_type_f", 0x7FF, bytes(8), "unknown_type"),
        ("unknown_type_before_dlc", 0x3A0, bytes(3), "unknown_type"),
        ("report_from_anchor_127", 0x17F, bytes(8), "bad_anchor"),
        ("status_b_from_anchor_127", 0x37F, bytes(8), "bad_anchor"),
        ("bad_length_before_anchor", 0x17F, bytes(5), "bad_length"),
    ]
    vs = []
    for name, can_id, data, error in cases:
        assert decode_can(can_id, data) == error, name
        vs.append({"name": name, "id": f"{can_id:03x}", "data": data.hex(), "error": error})
    return {"description": "Invalid CAN frames (id 3 hex digits, data hex; DLC = data length) and "
                           "the error they must produce (checks: can_type, DLC, anchor).",
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


def anchor_scripts() -> list[dict]:
    A = 5
    S: list[dict] = []

    def add(name, desc, script, **init):
        base = {"anchor_id": A, "transport": "uart", "boot_tick_ms": 0, "fw_major": 1, "fw_minor": 0}
        base.update(init)
        S.append({"name": name, "description": desc, "init": base, "script": script})

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
        "truncated, overlong, bad COBS, report type unknown to an anchor, bad version, bad "
        "length, bad anchor, garbage before the first delimiter); a valid frame right after a "
        "bad one is processed; frames split across U lines reassemble.",
        ["U 0 " + "4142" + good,
         "U 1 " + cobs_encode(_raw(1, 3, A, SET.pack(), crc_xor=1)).hex() + "00" + good,
         "U 2 " + cobs_encode(b"\x01\x03\x05").hex() + "00",
         "U 3 " + "55" * 70,
         "U 4 " + "55" * 10 + "00" + "0901010501" + "00",
         "U 5 " + cobs_encode(_raw(1, 1, A, rp)).hex() + "00",
         "U 6 " + cobs_encode(_raw(2, 3, A, SET.pack())).hex() + "00",
         "U 7 " + cobs_encode(_raw(1, 3, A, SET.pack() + b"\x01")).hex() + "00",
         "U 8 " + cobs_encode(_raw(1, 3, 200, SET.pack())).hex() + "00",
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
    for v in S:
        v["expected"] = run_script(v["init"], v["script"])
    return S


def anchor_vectors() -> dict:
    return {"description": "Anchor vectors: run `script` (event-script format, README) on an anchor "
                           "initialised from `init`; it must emit exactly `expected`, in order.",
            "vectors": anchor_scripts()}


# ------------------------------------------------------------------------- main

def build() -> dict[str, dict]:
    return {"crc.json": crc_vectors(), "cobs.json": cobs_vectors(), "uart.json": uart_vectors(),
            "can.json": can_vectors(), "uart_invalid.json": uart_invalid_vectors(),
            "can_invalid.json": can_invalid_vectors(), "qformat.json": qformat_vectors(),
            "anchor.json": anchor_vectors()}


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
