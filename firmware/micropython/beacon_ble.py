# BLE glue for the MicroPython beacon (pfdoa_beacon.Beacon): advertises our beacon's AdvData
# with bluetooth.BLE.gap_advertise, non-connectable, and puts the next sequence number in
# every interval. Runs on any port with the `bluetooth` module (ESP32, nRF, Pico W,
# STM32WB...). Not run by the unix-port tests (no radio); they drive it with a stand-in.
#
# Each gap_advertise() call replaces the advertising data and keeps advertising at the
# interval until the next call; the beacon calls it once per interval, so each sequence
# number goes out in about one advertising event (a stack may send it twice, or skip one
# when the call lands just before an event: an anchor folds repeats of one seq into one
# event, and a gap is a lost beacon for the gateway).
#
# With a key it is our authenticated rolling beacon (protocol/SPEC.md 9). MicroPython's
# BLE cannot set a chosen device address, so instead of SPEC 9.2's derived AdvA the glue
# asks the stack for a fresh non-resolvable private address (BLE.config(addr_mode=3)) at
# each new period, with advertising stopped in between: the address still changes with
# the identifier and links nothing (anchors verify the payload, not the address). A port
# without addr_mode keeps its address: `address_rolls` is then False and the beacon is
# linkable by it (use the nRF52840 beacon image, firmware/ports/README.md).
import time

import bluetooth
from pfdoa_beacon import RADIO_BLE, Beacon

_ADDR_MODE_NRPA = 3  # BLE.config addr_mode: non-resolvable private address
_PERIOD_MS = 4096  # SPEC 9.1 (pfdoa_defs.AUTH_PERIOD_MS)
_UNIX_2000_MS = 946684800000  # 2000-01-01 in Unix ms: the epoch of many MicroPython ports


class BleBeacon:
    """Our beacon on the board's BLE radio. tx_power_dbm is applied with
    BLE.config(txpower=...) where the port has that setting; elsewhere the port's
    default power is used and `tx_power_applied` is False. key (16 bytes): the
    authenticated rolling beacon, silent until set_time()."""

    def __init__(self, beacon_id=0, interval_ms=100, tx_power_dbm=0, ble=None, key=None):
        self._ble = ble if ble is not None else bluetooth.BLE()
        self._ble.active(True)
        self.tx_power_applied = self._set_tx_power(tx_power_dbm)
        self.beacon = Beacon(self._send, beacon_id, interval_ms, tx_power_dbm, RADIO_BLE, key=key)
        self._period_addr = None  # the beacon's period (its adv_a) the current address is for
        self.address_rolls = key is not None

    def _set_tx_power(self, dbm):
        try:
            self._ble.config(txpower=dbm)
            return True
        except (ValueError, TypeError, OSError, AttributeError):
            return False  # no such setting on this port

    def set_time(self, unix_ms, now_ms):
        """The site's time (Unix ms) at the beacon's tick now_ms."""
        self.beacon.set_time(unix_ms // _PERIOD_MS, unix_ms % _PERIOD_MS, now_ms)

    def _send(self, radio, frame, tx_power_dbm):
        if self.beacon.adv_a is not None and self.beacon.adv_a is not self._period_addr:
            # A new period: a new address before its first advertisement goes out.
            self._ble.gap_advertise(None)
            if self.address_rolls:
                try:
                    self._ble.config(addr_mode=_ADDR_MODE_NRPA)
                except (ValueError, TypeError, OSError, AttributeError):
                    self.address_rolls = False
            self._period_addr = self.beacon.adv_a
        self._ble.gap_advertise(self.beacon.interval_ms * 1000, frame, connectable=False)

    def step(self, now_ms):
        return self.beacon.poll(now_ms)

    def stop(self):
        self._ble.gap_advertise(None)


def unix_ms():
    """The board's clock in Unix ms (its RTC: set by ntptime, or `mpremote rtc --set`)."""
    ms = time.time_ns() // 1000000 if hasattr(time, "time_ns") else int(time.time()) * 1000
    return ms + _UNIX_2000_MS if time.gmtime(0)[0] == 2000 else ms


def read_key(path):
    """A key file as `pfdoa anchors keygen` writes it: 32 hex digits, # comments."""
    with open(path) as f:
        text = "".join(line.split("#", 1)[0].strip() for line in f)
    key = bytes.fromhex(text)
    if len(key) != 16:
        raise ValueError("a key file holds 32 hex digits")
    return key


_RESYNC_MS = 60000  # the authenticated beacon takes the board's clock again this often


def run(beacon_id=0, interval_ms=100, tx_power_dbm=0, key_file=None):
    """Advertises forever (with key_file: the authenticated beacon, on the board's clock).
    The tick is a u32 count of ms (the port's ticks_ms wraps sooner)."""
    key = read_key(key_file) if key_file else None
    b = BleBeacon(beacon_id, interval_ms, tx_power_dbm, key=key)
    last = time.ticks_ms()
    tick = 0
    synced = None
    while True:
        now = time.ticks_ms()
        tick = (tick + time.ticks_diff(now, last)) & 0xFFFFFFFF
        last = now
        if key is not None and (synced is None or (tick - synced) & 0xFFFFFFFF >= _RESYNC_MS):
            b.set_time(unix_ms(), tick)
            synced = tick
        b.step(tick)
        time.sleep_ms(1)
