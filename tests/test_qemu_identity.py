"""The Cortex-M3 image under QEMU and the host build emit byte-identical UART frames.

1,000 RADIO_INJECT frames (BLE events of 1-3 readings, 802.15.4 readings, unavailable
RSSI, bad channels, spikes, repeated sequence numbers, u16 seq and u32 tick wraps), a few
CONFIG_SET frames (decimation, silent mode, calibration offset), garbage between frames
and injects for other anchors go into the SIL image's UART under QEMU. The same bytes go
to the host build (firmware/build/host/anchor_script_sil) as an event script, with the
poll the SIL image does at each injected reading's tick (`U t <frame>`, `P t`).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from pfdoa.protocol import ConfigSet, StreamDecoder, encode_uart
from pfdoasim.backends.qemu import SIL, QemuAnchor, image_path, inject_frame

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


def test_qemu_image_matches_host_build_byte_for_byte(images):
    data, script = make_stream()
    assert sum(1 for line in script if line.startswith("P ")) > N_INJECTS * 0.9
    expected = host_frames(script)

    q = QemuAnchor(image_path(SIL), ANCHOR_ID, boot_tick=BOOT_TICK)
    try:
        banner = q.start()
        got = banner + q.exchange(data, len(expected) - len(banner), timeout_s=120)
    finally:
        rc = q.stop()
    assert rc == 0, q.stderr_text()

    # What the comparison covers: every kind of frame the anchor sends.
    dec = StreamDecoder()
    kinds = [type(d.message).__name__ for d in dec.feed(expected)]
    assert kinds.count("RssiReport") > 300
    assert kinds.count("Status") >= 20
    assert kinds.count("ConfigAck") == 5
    assert sum(dec.counters[e] for e in ("bad_crc", "bad_cobs", "truncated")) == 0

    if got != expected:
        n = next((i for i, (a, b) in enumerate(zip(got, expected)) if a != b), min(len(got), len(expected)))
        pytest.fail(f"QEMU output differs from the host build at byte {n} of {len(expected)} "
                    f"(QEMU sent {len(got)} bytes): qemu {got[max(0, n - 20):n + 20].hex()} "
                    f"host {expected[max(0, n - 20):n + 20].hex()}")


def test_stream_generator_is_deterministic():
    assert make_stream(7) == make_stream(7)
    assert make_stream(7)[0] != make_stream(8)[0]
    assert REPO.joinpath("firmware", "ports", "qemu_mps2", "main.c").exists()
