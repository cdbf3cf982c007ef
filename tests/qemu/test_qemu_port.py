"""The QEMU mps2-an385 port itself: tick, UART, semihosting, RAM config and filter stores, the
production image (no RADIO_INJECT), warm reset. The anchor logic is covered by
test_qemu_identity.py (byte-identical to the host build) and test_qemu_e2e.py."""

from __future__ import annotations

import time

import pytest

from pfdoa.protocol import ConfigAck, ConfigSet, FilterAck, RssiReport, Status, StreamDecoder, defs, encode_uart
from pfdoa.protocol.anchor_model import AnchorConfig
from pfdoa.protocol.filters import BeaconFilter, default_table, table_hash
from pfdoasim.backends.qemu import PROD, SELFTEST, SIL, QemuAnchor, image_path, inject_frame

from qemu_support import build_qemu_images


@pytest.fixture(scope="module", autouse=True)
def images():
    return build_qemu_images()


def read_exactly(q: QemuAnchor, n: int, timeout_s: float = 10.0) -> bytes:
    buf = bytearray()
    end = time.monotonic() + timeout_s
    while len(buf) < n and time.monotonic() < end:
        buf += q.read(0.1, max_bytes=n - len(buf))
    return bytes(buf)


def run_selftest(anchor_id: int) -> tuple[int, int, bytes, int]:
    """(spin time in ms, id as the guest read it, echo + trailer, exit status)."""
    q = QemuAnchor(image_path(SELFTEST), anchor_id)
    try:
        banner = q.start()  # up to the first 0x00, inside the u32 below
        banner += read_exactly(q, 9 - len(banner))
        assert banner[:4] == b"PORT"
        sent = bytes(range(256)) * 4  # every byte value, and more than the 256-byte RX ring
        # A piece at a time, each echoed before the next: the ring wraps around several
        # times but never overflows, however slowly the host reads (a loaded machine).
        echo = b""
        for i in range(0, len(sent), 128):
            q.write(sent[i:i + 128])
            echo += q.read_exactly(128, 20.0)
        echo += q.read_exactly(4, 20.0)  # DONE (readable after QEMU exits: our own pty)
        status = q.wait(10)
    finally:
        q.stop()
    assert echo[: len(sent)] == sent
    return int.from_bytes(banner[4:8], "little"), banner[8], echo[len(sent):], status


def test_selftest_tick_is_deterministic_uart_is_binary_safe_and_exit_status_is_returned():
    dt1, id1, tail1, rc1 = run_selftest(42)
    dt2, id2, tail2, rc2 = run_selftest(7)
    # SysTick under -icount shift=0: the same workload takes the same number of ms, every run.
    assert dt1 == dt2 and dt1 > 0
    assert (id1, id2) == (42, 7)
    assert tail1 == tail2 == b"DONE"
    assert rc1 == rc2 == 3  # SYS_EXIT_EXTENDED status


def collect(q: QemuAnchor, dec: StreamDecoder, until, timeout_s: float = 6.0) -> list:
    """Decoded frames until `until(decoded)` is true for one of them (or the timeout)."""
    got = []
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for d in dec.feed(q.read(0.1)):
            got.append(d)
            if until(d):
                return got
    raise AssertionError(f"timed out; got {got}")


def test_production_image_ignores_radio_inject_applies_config_and_keeps_time():
    q = QemuAnchor(image_path(PROD), 9)
    dec = StreamDecoder()
    try:
        (banner,) = dec.feed(q.start())
        assert banner.anchor_id == 9 and isinstance(banner.message, Status)
        assert banner.message.uptime_s == 0 and banner.message.rx_errors == 0
        assert banner.message.config_hash == AnchorConfig().hash
        # Production: RADIO_INJECT is an unknown type (SPEC 1.5), counted, never a reading.
        q.write(inject_frame(9, 1, -60, 37, 0, 0, 100) * 3)
        cfg = AnchorConfig(offset_q8=-256, alpha_q8=128, spike_db=6)
        q.write(encode_uart(ConfigSet(7, cfg.offset_q8, cfg.alpha_q8, cfg.spike_db, 0, 1), 9))
        got = collect(q, dec, lambda d: isinstance(d.message, Status) and d.message.uptime_s >= 2)
    finally:
        assert q.stop() == 0
    acks = [d.message for d in got if isinstance(d.message, ConfigAck)]
    assert acks == [ConfigAck(token=7, result=0, config_hash=cfg.hash)]
    assert not [d for d in got if isinstance(d.message, RssiReport)]
    status = [d.message for d in got if isinstance(d.message, Status)]
    # The SysTick clock runs: STATUS once a second, uptime counting.
    assert [s.uptime_s for s in status] == [1, 2]
    assert all(s.rx_errors == 3 and s.config_hash == cfg.hash for s in status)


def test_factory_config_and_config_store_across_a_warm_reset():
    factory = AnchorConfig(alpha_q8=32, report_mode=1, decimation=4)
    q = QemuAnchor(image_path(PROD), 3, config=factory.pack().hex())
    dec = StreamDecoder()
    try:
        (banner,) = dec.feed(q.start())
        assert banner.message.config_hash == factory.hash  # cfg= is what "flash" held at first boot
        stored = AnchorConfig(offset_q8=512, alpha_q8=200)
        q.write(encode_uart(ConfigSet(1, stored.offset_q8, stored.alpha_q8, stored.spike_db, 0, 1), 3))
        collect(q, dec, lambda d: isinstance(d.message, ConfigAck))
        q.reset()
        after = collect(q, dec, lambda d: isinstance(d.message, Status) and d.message.uptime_s == 0)
    finally:
        assert q.stop() == 0
    # The firmware booted again (uptime 0) and found the stored configuration (RAM kept
    # across the warm reset, CRC-checked), not the factory one.
    assert after[-1].message.config_hash == stored.hash


def test_sil_image_cold_start_banner_and_reboot_at_power_on():
    q = QemuAnchor(image_path(SIL), 4, boot_tick=10_000)
    dec = StreamDecoder()
    try:
        (banner,) = dec.feed(q.start())  # cold start: up at once, at tick=, with a banner
        for k, tick in enumerate(range(10_100, 15_100, 500)):
            q.write(b"".join(inject_frame(4, k, -70, 37 + j, 0, 0, tick + j) for j in range(3)))
        before = collect(q, dec, lambda d: isinstance(d.message, RssiReport) and d.message.seq == 9)
        q.reset()  # warm reset: the simulator powered the anchor off and on
        # Nothing until power is back, i.e. the first reading it hears (a CONFIG_SET sent
        # before then is not seen: no ack).
        q.write(encode_uart(ConfigSet(9, 0, 128, 12, 0, 1), 4))
        assert dec.feed(q.read(0.3)) == []
        q.write(b"".join(inject_frame(4, 50, -60, 37 + j, 0, 0, 3_000 + j) for j in range(3)))
        after = collect(q, dec, lambda d: isinstance(d.message, RssiReport))
    finally:
        assert q.stop() == 0
    assert banner.message.uptime_s == 0
    uptimes = [d.message.uptime_s for d in before if isinstance(d.message, Status)]
    assert uptimes == [1, 2, 3, 4]  # STATUS at 11.1, 12.1, 13.1, 14.1 s of injected time
    # Booted at its first reading's tick (3.000 s: whatever the tick base, as the host
    # build booted there): uptime restarts, which is how the gateway tells a reboot; a
    # fresh filter (RESET); the CONFIG_SET sent while it was off changed nothing.
    st, rep = after[0].message, after[-1].message
    assert isinstance(st, Status) and st.uptime_s == 0 and st.config_hash == AnchorConfig().hash
    assert [type(d.message) for d in after] == [Status, RssiReport]
    assert rep.seq == 50 and rep.tick_ms == 3_002 and rep.flags & 8


def test_filter_table_stored_and_kept_across_a_warm_reset():
    tag = BeaconFilter.ibeacon("f7826da6-4fa2-4e98-8024-bc5b71e0893e", 1, 2, 50)
    table = (default_table()[0], tag) + default_table()[2:]
    q = QemuAnchor(image_path(PROD), 5)
    dec = StreamDecoder()
    try:
        (banner,) = dec.feed(q.start())
        assert banner.message.filter_hash == defs.FILTER_TABLE_DEFAULT_HASH  # nothing stored at a cold start
        q.write(encode_uart(tag.set_message(9, 1), 5))
        got = collect(q, dec, lambda d: isinstance(d.message, FilterAck))
        q.reset()
        after = collect(q, dec, lambda d: isinstance(d.message, Status) and d.message.uptime_s == 0)
    finally:
        assert q.stop() == 0
    # Stored (result 0, not ACK_STORE_FAILED: the port gives the core its filter storage),
    # and found again after the warm reset (.noinit RAM, CRC-checked).
    assert got[-1].message == FilterAck(token=9, result=defs.ACK_OK, index=1, filter_hash=table_hash(table))
    assert after[-1].message.filter_hash == table_hash(table) != defs.FILTER_TABLE_DEFAULT_HASH
