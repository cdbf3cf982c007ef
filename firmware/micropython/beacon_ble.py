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
import time

import bluetooth
from pfdoa_beacon import RADIO_BLE, Beacon


class BleBeacon:
    """Our beacon on the board's BLE radio. tx_power_dbm is applied with
    BLE.config(txpower=...) where the port has that setting; elsewhere the port's
    default power is used and `tx_power_applied` is False."""

    def __init__(self, beacon_id=0, interval_ms=100, tx_power_dbm=0, ble=None):
        self._ble = ble if ble is not None else bluetooth.BLE()
        self._ble.active(True)
        self.tx_power_applied = self._set_tx_power(tx_power_dbm)
        self.beacon = Beacon(self._send, beacon_id, interval_ms, tx_power_dbm, RADIO_BLE)

    def _set_tx_power(self, dbm):
        try:
            self._ble.config(txpower=dbm)
            return True
        except (ValueError, TypeError, OSError, AttributeError):
            return False  # no such setting on this port

    def _send(self, radio, frame, tx_power_dbm):
        self._ble.gap_advertise(self.beacon.interval_ms * 1000, frame, connectable=False)

    def step(self, now_ms):
        return self.beacon.poll(now_ms)

    def stop(self):
        self._ble.gap_advertise(None)


def run(beacon_id=0, interval_ms=100, tx_power_dbm=0):
    """Advertises forever."""
    b = BleBeacon(beacon_id, interval_ms, tx_power_dbm)
    start = time.ticks_ms()
    while True:
        b.step(time.ticks_diff(time.ticks_ms(), start))
        time.sleep_ms(1)
