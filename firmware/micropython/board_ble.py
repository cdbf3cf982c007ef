# Board glue for a MicroPython BLE anchor (ESP32, nRF, Pico W, STM32WB...): a passive
# BLE scan feeds beacon readings to the core (pfdoa_anchor.Anchor); frames go out on a
# UART and, when the port has one, a CAN controller; CONFIG_SET comes in on both. The
# configuration is kept in a small file on the board's flash filesystem.
#
# Not run by the unix-port tests (no radio there); they compile it to check its syntax.
#
# Beacon format (the beacons' advertising payload): a manufacturer-specific AD
# structure (type 0xFF) with company id BEACON_COMPANY (little-endian), the two bytes
# BEACON_MAGIC and the beacon's 16-bit sequence number, little-endian.
from micropython import const
import time

import bluetooth
import machine
import pfdoa_defs as D
from pfdoa_anchor import TRANSPORT_CAN, TRANSPORT_UART, Anchor, ReadingQueue, Tick32

try:
    from machine import CAN as _CAN  # MicroPython >= 1.28 on ports that have one
except ImportError:
    _CAN = None

_IRQ_SCAN_RESULT = const(5)
_IRQ_SCAN_DONE = const(6)
_AD_MANUFACTURER = const(0xFF)
BEACON_COMPANY = const(0xFFFF)  # the Bluetooth SIG id reserved for testing
BEACON_MAGIC = b"PF"
# MicroPython's scan IRQ does not say on which advertising channel a packet came;
# readings are reported on the first advertising channel.
BLE_CHANNEL = const(37)
_SCAN_INTERVAL_US = const(30000)
_SCAN_WINDOW_US = const(30000)  # window == interval: listen all the time
CONFIG_FILE = "pfdoa_cfg.bin"


def beacon_seq(adv):
    """The beacon sequence number in an advertising payload, or -1 if it is not ours.

    Walks the AD structures without allocating."""
    i = 0
    n = len(adv)
    while i + 1 < n:
        length = adv[i]
        if length == 0:
            break
        if (adv[i + 1] == _AD_MANUFACTURER and length >= 7 and i + length < n
                and adv[i + 2] == (BEACON_COMPANY & 0xFF) and adv[i + 3] == (BEACON_COMPANY >> 8)
                and adv[i + 4] == BEACON_MAGIC[0] and adv[i + 5] == BEACON_MAGIC[1]):
            return adv[i + 6] | (adv[i + 7] << 8)
        i += length + 1
    return -1


class BleScanner:
    """Passive scan; every beacon advertisement becomes a queued reading."""

    def __init__(self, queue, beacon_addr=None, ticks_ms=time.ticks_ms):
        self._queue = queue
        self._ticks_ms = ticks_ms
        self._addr = beacon_addr  # bytes(6) to accept one beacon only, None = any
        self._ble = bluetooth.BLE()
        self._ble.active(True)
        self._ble.irq(self._irq)

    def start(self):
        # duration 0: scan until stopped; passive (no scan requests).
        self._ble.gap_scan(0, _SCAN_INTERVAL_US, _SCAN_WINDOW_US, False)

    def _irq(self, event, data):
        if event == _IRQ_SCAN_RESULT:
            raw_tick = self._ticks_ms()
            addr_type, addr, adv_type, rssi, adv_data = data
            if self._addr is not None and bytes(addr) != self._addr:
                return
            seq = beacon_seq(adv_data)
            if seq >= 0:
                # The driver's RSSI is a dBm integer; 127 (not available) is passed on
                # for the core to count as dropped.
                self._queue.put(seq, max(-128, min(127, rssi)), BLE_CHANNEL, raw_tick)
        elif event == _IRQ_SCAN_DONE:
            self.start()  # a stack that ended the scan on its own: keep listening


class CanPort:
    """The anchor's CAN interface over machine.CAN (MicroPython >= 1.28)."""

    def __init__(self, can_id, bitrate, anchor_id):
        self._can = _CAN(can_id, bitrate)
        base = D.CAN_CONFIG_SET << D.CAN_ANCHOR_BITS
        # Acceptance filters of SPEC 4: own CONFIG_SET id and the broadcast one. The
        # core applies the same filter in software, so a controller that cannot take
        # them still works (it just wakes up more often).
        try:
            self._can.set_filters(((base | anchor_id, D.CAN_ID_MASK, 0),
                                   (base | D.ANCHOR_BROADCAST, D.CAN_ID_MASK, 0)))
        except (AttributeError, TypeError, ValueError):
            pass

    def send(self, can_id, data):
        self._can.send(can_id, data)

    def poll(self, anchor):
        while True:
            msg = self._can.recv()
            if msg is None:
                return
            anchor.can_rx(msg[0], msg[1])


def load_config():
    try:
        with open(CONFIG_FILE, "rb") as f:
            return f.read(D.CONFIG_LEN + 1)
    except OSError:
        return None


def store_config(cfg):
    try:
        with open(CONFIG_FILE + ".tmp", "wb") as f:
            f.write(cfg)
        import os
        os.rename(CONFIG_FILE + ".tmp", CONFIG_FILE)
        return True
    except OSError:
        return False


def open_uart(uart_id, baudrate, pins):
    kw = {"baudrate": baudrate}
    if pins is not None:
        kw["tx"] = pins[0]
        kw["rx"] = pins[1]
    try:
        return machine.UART(uart_id, rxbuf=256, **kw)  # room for a few CONFIG_SETs
    except TypeError:  # ports without the rxbuf option
        return machine.UART(uart_id, **kw)


class Node:
    """One anchor on a board: radio queue, UART, optional CAN and the core.

    uart: a machine.UART (any(), readinto(), write()); can: a CanPort or None;
    ticks_ms/ticks_diff: the port's tick functions."""

    def __init__(self, anchor_id, uart, can=None, report_on_can=False, beacon_addr=None,
                 queue_size=32, ticks_ms=time.ticks_ms, ticks_diff=time.ticks_diff,
                 load=load_config, store=store_config):
        self.tick = Tick32(ticks_ms, ticks_diff)
        self._uart = uart
        self._can = can
        transports = TRANSPORT_CAN if (report_on_can and can is not None) else TRANSPORT_UART
        self.anchor = Anchor(anchor_id, self.tick.now(), uart_write=uart.write,
                             can_send=can.send if can is not None else None,
                             transports=transports, config=load(), store=store)
        self.queue = ReadingQueue(queue_size)
        self.scanner = BleScanner(self.queue, beacon_addr, ticks_ms)
        self._rx = bytearray(64)
        self._rx_mv = memoryview(self._rx)

    def start(self):
        self.scanner.start()

    def step(self):
        """One pass of the main loop: queued readings, host input, then the poll."""
        now = self.tick.now()
        self.queue.drain(self.anchor, D.RADIO_BLE, self.tick)
        if self._uart.any():
            n = self._uart.readinto(self._rx)
            if n:
                self.anchor.uart_rx(self._rx_mv[:n])
        if self._can is not None:
            self._can.poll(self.anchor)
        self.anchor.poll(now)


def run(anchor_id, uart_id=1, baudrate=115200, uart_pins=None, can_id=None,
        can_bitrate=500000, report_on_can=False, beacon_addr=None, queue_size=32):
    """Runs the anchor forever. uart_pins: (tx, rx) or None for the port's default;
    can_id: the machine.CAN controller id, None = no CAN."""
    uart = open_uart(uart_id, baudrate, uart_pins)
    can = None
    if can_id is not None and _CAN is not None:
        can = CanPort(can_id, can_bitrate, anchor_id)
    node = Node(anchor_id, uart, can, report_on_can, beacon_addr, queue_size)
    node.start()
    while True:
        node.step()
        time.sleep_ms(1)
