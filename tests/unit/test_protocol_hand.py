"""Protocol values computed by hand from SPEC arithmetic (not by the generator).

The expected bytes below were worked out from SPEC 2.1/2.2/1.x with a bitwise CRC written
here, so a bug shared by the codec and gen_vectors.py cannot hide.
"""

from pfdoa.protocol import (
    ConfigSet,
    RssiReport,
    StreamDecoder,
    cobs_decode,
    cobs_encode,
    crc16,
    crc16_table,
    decode_frame,
    encode_uart,
)
from pfdoa.protocol.anchor_model import AnchorConfig, ema_step_q8, fold_q8


def bitwise_crc(data: bytes, crc: int = 0xFFFF) -> int:
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc_check_value():
    assert bitwise_crc(b"123456789") == 0x29B1
    assert crc16(b"123456789") == 0x29B1
    assert crc16_table(b"123456789") == 0x29B1


def test_crc_extra_of_rssi_report():
    c = bitwise_crc(b"RSSI_REPORT u16 seq u32 tick_ms i16 rssi_q8 i8 raw_dbm u8 n_readings "
                    b"u8 channel u8 flags")
    assert c == 0xE677
    assert (c & 0xFF) ^ (c >> 8) == 0x77 ^ 0xE6 == 145


def test_cobs_by_hand():
    assert cobs_encode(b"") == b"\x01"
    assert cobs_encode(b"\x00") == b"\x01\x01"
    assert cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert cobs_encode(b"\x11\x00\x00\x00") == b"\x02\x11\x01\x01\x01"
    run254 = bytes(range(1, 255))
    assert cobs_encode(run254) == b"\xff" + run254  # no trailing code: the block ends
    assert cobs_encode(run254 + b"\x00") == b"\xff" + run254 + b"\x01\x01"
    assert cobs_encode(b"\x00" + run254) == b"\x01\xff" + run254
    run255 = bytes(range(1, 256))
    assert cobs_encode(run255) == b"\xff" + run255[:254] + b"\x02\xff"
    assert cobs_decode(b"\x03\x11\x22\x02\x33") == b"\x11\x22\x00\x33"


def test_v1_report_frame_by_hand():
    msg = RssiReport(seq=0x0102, tick_ms=0x03040506, rssi_q8=-15701, raw_dbm=-63,
                     n_readings=3, channel=39, flags=0x08)
    # ver type anchor | seq LE | tick LE | rssi_q8 0xC2AB LE | -63=0xC1 | 3 | 39 | 8
    body = bytes.fromhex("010105" "0201" "06050403" "abc2" "c1" "03" "27" "08")
    crc = bitwise_crc(body + bytes([145]))
    assert crc == 0xA4B9
    # No zero byte in the 17 raw bytes: one COBS group, code 18, then the delimiter.
    expected = bytes.fromhex("12" "010105020106050403abc2c1032708" "b9a4" "00")
    assert encode_uart(msg, 5, version=1) == expected
    assert len(expected) == 19
    assert decode_frame(expected[:-1]).message == msg
    assert msg.rssi_dbm == -15701 / 256


def test_v2_report_frame_by_hand():
    """SPEC 2.1: the CRC over the COBS bytes + CRC_EXTRA, carried 7 + 7 + 2 bits with bit 7 set."""
    msg = RssiReport(seq=0x0102, tick_ms=0x03040506, rssi_q8=-15701, raw_dbm=-63,
                     n_readings=3, channel=39, flags=0x08, beacon=2)
    body = bytes.fromhex("020505" "0201" "06050403" "abc2" "c1" "03" "27" "08" "02")
    enc = bytes([len(body) + 1]) + body  # no zero inside: one group
    extra = 116
    c = bitwise_crc(b"RSSI_REPORT u16 seq u32 tick_ms i16 rssi_q8 i8 raw_dbm u8 n_readings "
                    b"u8 channel u8 flags u8 beacon")
    assert (c & 0xFF) ^ (c >> 8) == extra
    crc = bitwise_crc(enc + bytes([extra]))
    trailer = bytes([0x80 | (crc & 0x7F), 0x80 | ((crc >> 7) & 0x7F), 0x80 | (crc >> 14)])
    expected = enc + trailer + b"\x00"
    assert encode_uart(msg, 5) == expected
    assert len(expected) == 21  # SPEC 7 budget
    assert decode_frame(expected[:-1]).message == msg


def test_v1_config_set_frame_by_hand():
    # Defaults: offset 0, alpha 64, spike 12, mode 0, decimation 1; token 7, anchor 5.
    body = bytes.fromhex("010305" "07" "0000" "4000" "0c" "00" "01")
    crc = bitwise_crc(body + bytes([119]))
    assert crc == 0x94CE
    # COBS groups: [01 03 05 07] 0 [] 0 [40] 0 [0c] 0 [01 ce 94]
    expected = bytes.fromhex("050103050701024002" "0c" "0401ce94" "00")
    assert encode_uart(ConfigSet(7), 5, version=1) == expected
    assert StreamDecoder().feed(expected)[0].message == ConfigSet(7)


def test_v2_config_set_frame_by_hand():
    # COBS groups of the body 02 03 05 07 | 00 00 | 40 00 | 0c 00 | 01: [02 03 05 07] 0 [] 0 [40] 0 [0c] 0 [01]
    enc = bytes.fromhex("0502030507" "01" "0240" "020c" "0201")
    crc = bitwise_crc(enc + bytes([119]))
    expected = enc + bytes([0x80 | (crc & 0x7F), 0x80 | ((crc >> 7) & 0x7F), 0x80 | (crc >> 14)]) + b"\x00"
    assert encode_uart(ConfigSet(7), 5) == expected
    assert StreamDecoder().feed(expected)[0].message == ConfigSet(7)


def test_issue_14_code_byte_flip_is_accepted_in_v1_and_rejected_in_v2():
    """The frame of issue 14: one flipped bit in a COBS code byte (04 -> 05) of a version-1
    STATUS decodes to another valid STATUS; the same damage to a version-2 frame is caught."""
    v1 = bytes.fromhex("0401023e0311030b2116cd0fc4190618d912041f105c00")
    bad = bytes([v1[0] ^ 0x01]) + v1[1:]
    a, b = StreamDecoder().feed(v1), StreamDecoder().feed(bad)
    assert len(a) == len(b) == 1 and a[0].message != b[0].message  # v1: accepted, wrong
    v2 = encode_uart(a[0].message, a[0].anchor_id)
    dec = StreamDecoder()
    assert dec.feed(bytes([v2[0] ^ 0x01]) + v2[1:]) == [] and dec.counters["frames_ok"] == 0


def test_generated_numbers_are_the_specs():
    # SPEC 1, 2.3, 4 and 8 by hand: what gen.py must have produced from messages.json.
    from pfdoa.protocol import defs
    assert (defs.PROTO_VERSION, defs.V1_PROTO_VERSION, defs.VERSIONS) == (2, 1, (1, 2))
    assert (defs.MSG_RSSI_REPORT, defs.MSG_STATUS, defs.MSG_CONFIG_SET, defs.MSG_CONFIG_ACK, defs.MSG_FILTER_SET,
            defs.MSG_FILTER_ACK, defs.MSG_RADIO_INJECT, defs.MSG_RADIO_INJECT_RAW) == (5, 6, 3, 4, 7, 8, 0x7E, 0x7D)
    assert (defs.MSG_V1_RSSI_REPORT, defs.MSG_V1_STATUS) == (1, 2)
    assert (defs.MSG_RSSI_REPORT_LEN, defs.MSG_STATUS_LEN, defs.MSG_FILTER_SET_LEN, defs.MSG_FILTER_ACK_LEN) == (
        13, 19, 25, 5)
    assert (defs.MAX_ENCODED, defs.MAX_BODY, defs.MAX_RAW, defs.TRAILER_LEN) == (65, 61, 64, 3)
    assert (defs.TRAILER_MARKER, defs.TRAILER_BITS, defs.TRAILER_VALUE_MASK, defs.TRAILER_LAST_VALUE_MASK) == (
        0x80, 7, 0x7F, 0x03)
    assert (defs.CAN_ANCHOR_BITS, defs.CAN_ANCHOR_MASK, defs.CAN_ID_MASK, defs.CAN_TYPE_MASK) == (7, 0x7F, 0x7FF, 0x780)
    assert (defs.CAN_RSSI_REPORT, defs.CAN_RSSI_REPORT_DLC, defs.CAN_STATUS_B_DLC, defs.CAN_STATUS_C,
            defs.CAN_STATUS_C_DLC) == (2, 7, 8, 7, 3)
    assert (defs.ERR_OVERLONG, defs.ERR_BAD_ANCHOR, defs.ERR_ARG, defs.ERR_CAPACITY) == (-1, -8, -9, -10)
    assert (defs.FLAG_ZIGBEE, defs.FLAG_NO_SEQ, defs.FLAGS_DEFINED) == (0x10, 0x20, 0x3F)
    assert (defs.ANCHOR_ID_MAX, defs.ANCHOR_BROADCAST, defs.BEACON_SLOTS) == (126, 127, 4)
    assert (defs.V1_DEFS_HASH, defs.CONFIG_DEFAULT_HASH) == (31273, bitwise_crc(bytes.fromhex("000040000c0001")))
    assert defs.FILTER_TABLE_DEFAULT_HASH == bitwise_crc(bytes((1,)) + bytes(22) + bytes(23 * 3))


def test_default_config_hash_by_hand():
    assert AnchorConfig().pack() == bytes.fromhex("00004000" "0c0001")
    assert AnchorConfig().hash == bitwise_crc(bytes.fromhex("000040000c0001")) == 0x85E6


def test_fold_by_hand():
    # -60, -61, -63: mean = -61.333.. dB = -15701.33/256 -> -15701 (nearest)
    assert fold_q8(-184, 3) == -15701
    # -60, -61: -60.5 dB exactly = -15488
    assert fold_q8(-121, 2) == -15488
    # -1, 0, 0: -85.33/256 -> -85; 1, 0, 0: 85.33 -> 85; -1,-1,0: -170.67 -> -171
    assert (fold_q8(-1, 3), fold_q8(1, 3), fold_q8(-2, 3)) == (-85, 85, -171)


def test_ema_rounding_by_hand():
    # increment -0.5/256 rounds half up to 0; -1.5/256 to -1; +0.5/256 to +1
    assert ema_step_q8(0, -1, 128) == 0
    assert ema_step_q8(0, -3, 128) == -1
    assert ema_step_q8(0, 1, 128) == 1
    # -129/256 = -0.504: nearest is -1 (C's truncating '/' would give 0)
    assert ema_step_q8(0, -1, 129) == -1
    # alpha 64 (0.25), -60 dB -> -61 dB: -64/256 exactly
    assert ema_step_q8(-15360, -15616, 64) == -15424
