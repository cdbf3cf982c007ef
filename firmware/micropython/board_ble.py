# Board glue for a MicroPython BLE anchor (ESP32, nRF, Pico W, STM32WB...): a passive
# BLE scan feeds advertisements to the core (pfdoa_anchor.Anchor), which matches them
# against its beacon filter table (our beacons, iBeacon, Eddystone-UID, AltBeacon, MAC
# addresses: protocol/SPEC.md 3.1-3.2); frames go out on a UART and, when the port has
# one, a CAN controller; CONFIG_SET comes in on both, FILTER_SET on the UART. The
# configuration and the filter table are kept in small files on the board's flash. With an
# ANCHORS entry in the table (SPEC 3.5) the anchor also advertises itself (non-connectable,
# the AdvData of SPEC 6.1, renewed with each sequence number) for the other anchors to hear.
#
# Not run on a board by the unix-port tests (no radio there); they compile it and run its
# pure parts against stand-in modules.
from micropython import const
import time

import bluetooth
import machine
import pfdoa_defs as D
import pfdoa_match as M
from pfdoa_anchor import TRANSPORT_CAN, TRANSPORT_UART, Anchor, ReadingQueue, Tick32

try:
    from machine import CAN as _CAN  # MicroPython >= 1.28 on ports that have one
except ImportError:
    _CAN = None

_ADV_DATA_AT = const(8)  # AdvData's place in an advertising PDU: header (2), AdvA (6)
_IRQ_SCAN_RESULT = const(5)
_IRQ_SCAN_DONE = const(6)
# MicroPython's scan IRQ does not say on which advertising channel a packet came;
# readings are reported on the first advertising channel.
BLE_CHANNEL = const(37)
_SCAN_INTERVAL_US = const(30000)
_SCAN_WINDOW_US = const(30000)  # window == interval: listen all the time
CONFIG_FILE = "pfdoa_cfg.bin"
FILTERS_FILE = "pfdoa_flt.bin"


class BleScanner:
    """Passive scan; every advertisement that matches an entry of the anchor's filter
    table becomes a queued reading. The match runs in the scan IRQ (it does not allocate)
    so that only readings of configured beacons take queue room; it reads the table the
    main loop writes on a FILTER_SET, so the one advertisement matched during that write
    may see a half-written entry (one reading at worst, never a crash). When the table
    has a PFDOA_AUTH entry, an advertisement carrying our authenticated beacon's payload
    (SPEC 9) is queued with a copy of it, unverified: the core verifies it when the queue
    is drained, and counts what it rejects (such an advertisement then never goes to a
    MAC48 entry: its address rolls anyway)."""

    def __init__(self, queue, filters, ticks_ms=time.ticks_ms):
        self._queue = queue
        self.filters = filters  # the anchor's table (bytearray, updated in place)
        self._air = _AirAddr()
        self._ticks_ms = ticks_ms
        self._ble = bluetooth.BLE()
        self._ble.active(True)
        self._ble.irq(self._irq)

    def start(self):
        # duration 0: scan until stopped; passive (no scan requests).
        self._ble.gap_scan(0, _SCAN_INTERVAL_US, _SCAN_WINDOW_US, False)

    def address(self):
        """This radio's address in on-air order (least significant byte first)."""
        return bytes(reversed(self._ble.config("mac")[1]))

    def advertise(self, pdu, period_ms):
        """The anchor's own advertisement (an ADV_NONCONN_IND PDU from the core): the stack
        takes its AdvData and sends it at about the anchor's period (BLE's longest interval
        is 10.24 s), non-connectable, until the next one replaces it."""
        interval_us = min(max(period_ms, 20), 10240) * 1000
        self._ble.gap_advertise(interval_us, adv_data=bytes(pdu[_ADV_DATA_AT:]), connectable=False)
        return True

    def _irq(self, event, data):
        if event == _IRQ_SCAN_RESULT:
            raw_tick = self._ticks_ms()
            addr_type, addr, adv_type, rssi, adv_data = data
            # MicroPython gives the address most significant byte first; the filter
            # table holds it in on-air order (least significant first, SPEC 3.1).
            # The driver's RSSI is a dBm integer; 127 (not available) is passed on for
            # the core to count as dropped.
            rssi = max(-128, min(127, rssi))
            n = len(adv_data)
            if self._has_auth():
                at = M.auth_adv(adv_data, 0, n)
                if at >= 0:
                    self._queue.put_auth(adv_data, at, rssi, BLE_CHANNEL, raw_tick)
                    return
            air = self._air
            air.addr = addr
            m = M.match_adv(self.filters, air, 0, adv_data, 0, n)
            if m >= 0:
                self._queue.put_match(m, rssi, BLE_CHANNEL, raw_tick)
        elif event == _IRQ_SCAN_DONE:
            self.start()  # a stack that ended the scan on its own: keep listening


    def _has_auth(self):
        for i in range(D.BEACON_SLOTS):
            if M.kind(self.filters, i) == D.FILTER_PFDOA_AUTH:
                return True
        return False


class _AirAddr:
    """A MicroPython BLE address (most significant byte first) read in on-air order,
    without copying it (one instance, re-pointed at each address)."""

    def __init__(self):
        self.addr = bytes(6)

    def __getitem__(self, i):
        return self.addr[5 - i]


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


def _load(name, n):
    try:
        with open(name, "rb") as f:
            return f.read(n + 1)  # one more: a longer file is not a stored form
    except OSError:
        return None


def _store(name, data):
    try:
        with open(name + ".tmp", "wb") as f:
            f.write(data)
        import os
        os.rename(name + ".tmp", name)
        return True
    except OSError:
        return False


def load_config():
    return _load(CONFIG_FILE, D.CONFIG_LEN)


def store_config(cfg):
    return _store(CONFIG_FILE, cfg)


def load_filters():
    return _load(FILTERS_FILE, D.FILTER_TABLE_LEN)


def store_filters(table):
    return _store(FILTERS_FILE, table)


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

    def __init__(self, anchor_id, uart, can=None, report_on_can=False, queue_size=32,
                 ticks_ms=time.ticks_ms, ticks_diff=time.ticks_diff, load=load_config,
                 store=store_config, load_table=load_filters, store_table=store_filters):
        self.tick = Tick32(ticks_ms, ticks_diff)
        self._uart = uart
        self._can = can
        transports = TRANSPORT_CAN if (report_on_can and can is not None) else TRANSPORT_UART
        self.queue = ReadingQueue(queue_size)
        self.scanner = BleScanner(self.queue, None, ticks_ms)
        self.anchor = Anchor(anchor_id, self.tick.now(), uart_write=uart.write,
                             can_send=can.send if can is not None else None,
                             transports=transports, config=load(), store=store,
                             filters=load_table(), store_filters=store_table,
                             peer_send=self._advertise, peer_radio=D.RADIO_BLE,
                             peer_address=self.scanner.address())
        self.scanner.filters = self.anchor.filters  # matched in the scan IRQ, set before the scan starts
        self._rx = bytearray(64)
        self._rx_mv = memoryview(self._rx)

    def start(self):
        self.scanner.start()

    def _advertise(self, pdu):
        f = self.anchor.filters
        for i in range(D.BEACON_SLOTS):
            if M.kind(f, i) == D.FILTER_ANCHORS:
                return self.scanner.advertise(pdu, M.period(f, i))
        return False

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
        can_bitrate=500000, report_on_can=False, queue_size=32):
    """Runs the anchor forever. uart_pins: (tx, rx) or None for the port's default;
    can_id: the machine.CAN controller id, None = no CAN."""
    uart = open_uart(uart_id, baudrate, uart_pins)
    can = None
    if can_id is not None and _CAN is not None:
        can = CanPort(can_id, can_bitrate, anchor_id)
    node = Node(anchor_id, uart, can, report_on_can, queue_size)
    node.start()
    while True:
        node.step()
        time.sleep_ms(1)
