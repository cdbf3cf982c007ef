"""The Cortex-M3 image under QEMU and the host build emit byte-identical UART frames.

1,000 RADIO_INJECT frames (BLE events of 1-3 readings, 802.15.4 readings, unavailable
RSSI, bad channels, spikes, repeated sequence numbers, u16 seq and u32 tick wraps), a few
CONFIG_SET frames (decimation, silent mode, calibration offset), garbage between frames
and injects for other anchors go into the SIL image's UART under QEMU. The same bytes go
to the host build (firmware/build/host/anchor_script_sil) as an event script, with the
poll the SIL image does at each injected reading's tick (`U t <frame>`, `P t`).

Protocol version 2: 1,000 RADIO_INJECT_RAW frames (BLE advertising PDUs of our beacon with
ids 0 and 3, of an iBeacon and of strangers, IEEE 802.15.4 frames of ours and of a device
configured by MAC64, truncated and malformed frames) with FILTER_SETs that configure and
later clear those entries (one invalid), mixed with RADIO_INJECTs: the same comparison.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from pfdoa.protocol import BeaconFilter, ConfigSet, FilterSet, StreamDecoder, defs, encode_uart
from pfdoa.protocol.beacons import adv_pdu, ibeacon_adv_data, mac_frame, pfdoa_802154_frame, pfdoa_adv_data
from pfdoasim.backends.qemu import SIL, QemuAnchor, image_path, inject_frame, inject_raw_frame

from qemu_support import REPO, build_host_script, build_qemu_images

ANCHOR_ID = 5
BOOT_TICK = 2**32 - 40_000  # the tick wraps about 40 s into the run
N_INJECTS = 1000


def make_stream(seed: int = 7) -> tuple[bytes, list[str]]:
    """(bytes for the anchor's UART, the equivalent event script for the host build)."""
    rng = np.random.default_rng(seed)
    data = bytearray()
    script = [f"P {BOOT_TICK}"]  # the image's first poll, at boot
    t = BOOT_TICK
    seq = 65_500  # wraps after ~36 beacons
    injects = 0

    def send(frame: bytes, tick: int, poll: bool) -> None:
        data.extend(frame)
        script.append(f"U {tick} {frame.hex()}")
        if poll:
            script.append(f"P {tick}")

    configs = {
        150: ConfigSet(token=1, offset_q8=0, alpha_q8=96, spike_db=8, report_mode=1, decimation=3),
        300: ConfigSet(token=2, offset_q8=-512, alpha_q8=64, spike_db=0, report_mode=0, decimation=1),
        450: ConfigSet(token=3, offset_q8=0, alpha_q8=300, spike_db=12, report_mode=0, decimation=1),  # invalid
        600: ConfigSet(token=4, offset_q8=128, alpha_q8=64, spike_db=12, report_mode=2, decimation=1),
        650: ConfigSet(token=5, offset_q8=0, alpha_q8=64, spike_db=12, report_mode=0, decimation=1),
    }
    level = -70.0
    while injects < N_INJECTS:
        for at, cfg in list(configs.items()):
            if injects >= at:
                target = ANCHOR_ID if cfg.token != 3 else 127
                send(encode_uart(cfg, target), t & 0xFFFFFFFF, poll=False)
                del configs[at]
        u = rng.random()
        t += int(rng.choice([rng.integers(1, 60), rng.integers(60, 400), rng.integers(900, 2500)], p=[0.5, 0.45, 0.05]))
        if u < 0.03:  # line noise; the trailing delimiter keeps it from swallowing the next frame
            junk = bytes(rng.integers(1, 256, size=int(rng.integers(1, 30)), dtype=np.uint8)) + b"\x00"
            data.extend(junk)
            script.append(f"U {t & 0xFFFFFFFF} {junk.hex()}")
            continue
        if rng.random() > 0.05:
            seq = (seq + 1) & 0xFFFF  # else: the same beacon again, after its event closed
        level += float(rng.normal(0, 1.5))
        level = min(-40.0, max(-100.0, level))
        zigbee = rng.random() < 0.1
        n = 1 if zigbee else int(rng.choice([1, 2, 3], p=[0.15, 0.2, 0.65]))
        for j in range(n):
            if injects >= N_INJECTS:
                break
            rssi = int(round(level + rng.normal(0, 3)))
            if rng.random() < 0.05:
                rssi += int(rng.choice([-30, 25]))  # a spike
            if rng.random() < 0.02:
                rssi = 127  # not available
            rssi = max(-128, min(127, rssi))
            channel = int(rng.integers(11, 27)) if zigbee else (37 + j)
            if rng.random() < 0.01:
                channel = 40  # not a valid channel
            lqi = int(rng.integers(0, 256)) if zigbee else 0
            target = ANCHOR_ID
            if rng.random() < 0.02:
                target = int(rng.choice([ANCHOR_ID + 1, 127]))  # another anchor's, or broadcast
            tick = (t + 2 * j) & 0xFFFFFFFF
            frame = inject_frame(target, seq, rssi, channel, lqi, 1 if zigbee else 0, tick)
            send(frame, tick, poll=target in (ANCHOR_ID, 127))
            injects += 1
    return bytes(data), script


IBEACON_UUID = bytes.fromhex("f7826da64fa24e988024bc5b71e0893e")
MAC64 = bytes.fromhex("0011223344556677")


def make_v2_stream(seed: int = 11) -> tuple[bytes, list[str]]:
    """As make_stream, for the version-2 receive path: raw frames matched by the firmware."""
    rng = np.random.default_rng(seed)
    data = bytearray()
    script = [f"P {BOOT_TICK}"]
    t = BOOT_TICK
    seqs = {0: 65_000, 3: 10}  # our beacon ids 0 (entry 0) and 3 (entry 2, once set)

    def send(frame: bytes, tick: int, poll: bool) -> None:
        data.extend(frame)
        script.append(f"U {tick} {frame.hex()}")
        if poll:
            script.append(f"P {tick}")

    sets = {  # injection count -> FILTER_SET (index, filter)
        100: (1, BeaconFilter.ibeacon(IBEACON_UUID, 1, 2, period_ms=50)),
        200: (2, BeaconFilter.pfdoa(3)),
        300: (3, BeaconFilter.mac64(MAC64, period_ms=80)),
        500: (1, FilterSet(0, 1, 99, 0, b"")),  # unknown kind: refused, the table unchanged
        700: (1, BeaconFilter.none()),
        800: (2, BeaconFilter.none()),
    }
    injects = 0
    token = 0
    level = -70.0
    while injects < N_INJECTS:
        for at in [k for k in sets if injects >= k]:
            index, f = sets.pop(at)
            token += 1
            msg = f if isinstance(f, FilterSet) else f.set_message(token, index)
            send(encode_uart(msg, ANCHOR_ID), t & 0xFFFFFFFF, poll=False)
        t += int(rng.choice([rng.integers(1, 60), rng.integers(60, 400)], p=[0.6, 0.4]))
        level = min(-40.0, max(-100.0, level + float(rng.normal(0, 1.5))))
        u = rng.random()
        if u < 0.08:  # RADIO_INJECT as in version 1, entry 0
            seqs[0] = (seqs[0] + 1) & 0xFFFF
            frames = [(inject_frame(ANCHOR_ID, seqs[0], int(level), 37 + j, 0, 0, (t + 2 * j) & 0xFFFFFFFF),
                       (t + 2 * j) & 0xFFFFFFFF) for j in range(3)]
        else:
            if u < 0.45:
                bid = 0 if rng.random() < 0.7 else 3
                seqs[bid] = (seqs[bid] + 1) & 0xFFFF
                pdu = adv_pdu(bytes(rng.integers(0, 256, 6, dtype=np.uint8)), pfdoa_adv_data(seqs[bid], bid))
                kind = ("ble", pdu)
            elif u < 0.65:
                kind = ("ble", adv_pdu(bytes.fromhex("0a0b0c0d0e0f"), ibeacon_adv_data(IBEACON_UUID, 1, 2)))
            elif u < 0.72:
                kind = ("ble", adv_pdu(bytes(6), ibeacon_adv_data(IBEACON_UUID, 1, 9)))  # a stranger
            elif u < 0.85:
                seqs[0] = (seqs[0] + 1) & 0xFFFF
                kind = ("154", pfdoa_802154_frame(seqs[0], 0, bytes(8)))
            elif u < 0.95:
                kind = ("154", mac_frame(b"hello", seq=int(rng.integers(0, 256)), src_addr=MAC64))
            else:
                junk = bytes(rng.integers(0, 256, int(rng.integers(0, 39)), dtype=np.uint8))
                kind = ("ble" if rng.random() < 0.5 else "154", junk)  # truncated / malformed
            radio, frame = kind
            n = 3 if radio == "ble" else 1
            frames = []
            for j in range(n):
                rssi = max(-128, min(127, int(round(level + rng.normal(0, 3)))))
                tick = (t + 2 * j) & 0xFFFFFFFF
                if radio == "ble":
                    raw = inject_raw_frame(ANCHOR_ID, frame, rssi, 37 + j, 0, defs.RADIO_BLE, tick)
                else:
                    raw = inject_raw_frame(ANCHOR_ID, frame, rssi, int(rng.integers(11, 27)),
                                           int(rng.integers(0, 256)), defs.RADIO_IEEE802154, tick)
                frames.append((raw, tick))
        for raw, tick in frames:
            if injects >= N_INJECTS:
                break
            send(raw, tick, poll=True)
            injects += 1
    return bytes(data), script


def host_frames(script: list[str]) -> bytes:
    exe = build_host_script()
    r = subprocess.run([str(exe), "-a", str(ANCHOR_ID), "-b", str(BOOT_TICK)], input="\n".join(script) + "\n",
                       capture_output=True, text=True, timeout=60, check=True)
    lines = r.stdout.split()
    assert lines[0::2] == ["U"] * (len(lines) // 2)
    return bytes.fromhex("".join(lines[1::2]))


@pytest.fixture(scope="module")
def images():
    return build_qemu_images()


def run_sil_image(data: bytes, n_bytes: int) -> bytes:
    """What the SIL image under QEMU sends (its banner first) for ``data``, ``n_bytes`` in all;
    the guest must exit cleanly."""
    q = QemuAnchor(image_path(SIL), ANCHOR_ID, boot_tick=BOOT_TICK)
    try:
        banner = q.start()
        got = banner + q.exchange(data, n_bytes - len(banner), timeout_s=120)
    finally:
        rc = q.stop()
    assert rc == 0, q.stderr_text()
    return got


def assert_same_bytes(got: bytes, expected: bytes) -> None:
    """Fail naming the first byte where QEMU's output leaves the host build's, with context."""
    if got != expected:
        n = next((i for i, (a, b) in enumerate(zip(got, expected)) if a != b), min(len(got), len(expected)))
        pytest.fail(f"QEMU output differs from the host build at byte {n} of {len(expected)} "
                    f"(QEMU sent {len(got)} bytes): qemu {got[max(0, n - 20):n + 20].hex()} "
                    f"host {expected[max(0, n - 20):n + 20].hex()}")


def test_qemu_image_matches_host_build_byte_for_byte(images):
    data, script = make_stream()
    assert sum(1 for line in script if line.startswith("P ")) > N_INJECTS * 0.9
    expected = host_frames(script)

    got = run_sil_image(data, len(expected))

    # What the comparison covers: every kind of frame the anchor sends.
    dec = StreamDecoder()
    kinds = [type(d.message).__name__ for d in dec.feed(expected)]
    assert kinds.count("RssiReport") > 300
    assert kinds.count("Status") >= 20
    assert kinds.count("ConfigAck") == 5
    assert sum(dec.counters[e] for e in ("bad_crc", "bad_cobs", "truncated")) == 0

    assert_same_bytes(got, expected)


def test_stream_generator_is_deterministic():
    assert make_stream(7) == make_stream(7)
    assert make_stream(7)[0] != make_stream(8)[0]
    assert make_v2_stream(11) == make_v2_stream(11)
    assert REPO.joinpath("firmware", "ports", "qemu_mps2", "main.c").exists()


def test_qemu_image_matches_host_build_on_v2_raw_injections(images):
    data, script = make_v2_stream()
    expected = host_frames(script)
    got = run_sil_image(data, len(expected))

    dec = StreamDecoder()
    msgs = [d.message for d in dec.feed(expected)]
    reports = [m for m in msgs if type(m).__name__ == "RssiReport"]
    acks = [m for m in msgs if type(m).__name__ == "FilterAck"]
    # Coverage: reports of four entries (ours by seq, the iBeacon and MAC64 by time), the
    # acks (one refused), every version-2 STATUS.
    assert {r.beacon for r in reports} == {0, 1, 2, 3}
    assert any(r.flags & defs.FLAG_NO_SEQ for r in reports)
    assert [a.result for a in acks] == [0, 0, 0, 1, 0, 0]
    assert sum(type(m).__name__ == "Status" for m in msgs) >= 20
    assert sum(dec.counters[e] for e in ("bad_crc", "bad_cobs", "truncated")) == 0
    assert_same_bytes(got, expected)
